"""What a user sees at the keyboard: progress with totals (plain lines in logs), one run per folder, the
summary schema of run, eval and logs."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mjdrive.progress import PLAIN_INTERVAL, Progress
from mjdrive.record.summary import (
    ROW_FIELDS,
    SCHEMA,
    SUMMARY_FIELDS,
    markdown_reference,
    relative_exit,
    roundabout_arms,
)

ROOT = Path(__file__).resolve().parents[1]


def mjdrive(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """`mjdrive ARGS` with stdout and stderr captured (so neither is a terminal)."""
    return subprocess.run([sys.executable, "-m", "mjdrive.cli", *args], capture_output=True, text=True,
                          cwd=cwd or ROOT, timeout=120)


def test_progress_writes_plain_lines_with_a_total_and_keeps_talking_during_a_long_step():
    stream = io.StringIO()
    with Progress(total=3, desc="work", unit="step", file=stream) as bar:
        bar.update()
        time.sleep(2 * PLAIN_INTERVAL + 0.6)  # one long step: the heartbeat must still write lines
        bar.update(2)
    text = stream.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert all(line.startswith("work: ") for line in lines)
    assert "work: 3/3 (100%)" in lines[-1]
    assert sum("1/3" in line for line in lines) >= 2, lines  # the heartbeat spoke during the long step


def test_progress_over_an_iterable_never_counts_past_its_total(monkeypatch):
    import re

    from mjdrive import progress

    monkeypatch.setattr(progress, "PLAIN_INTERVAL", 0.02)  # heartbeat redraws between the loop's own updates
    monkeypatch.setattr(progress, "HEARTBEAT", 0.005)
    for _ in range(5):
        stream = io.StringIO()
        for _ in Progress(range(200), desc="work", unit="step", file=stream, mininterval=0.02):
            time.sleep(0.001)
        counts = [int(n) for n in re.findall(r"work: (\d+)/", stream.getvalue())]
        assert max(counts) == counts[-1] == 200 and "/?" not in stream.getvalue(), stream.getvalue()


def test_a_slow_start_is_announced_and_a_quick_one_is_not(monkeypatch):
    from mjdrive import progress

    quick = io.StringIO()
    with progress.Starting("cmd: loading", delay=0.5, file=quick):
        pass  # a quick error or a quick command: nothing said
    assert quick.getvalue() == ""
    slow = io.StringIO()
    starting = progress.Starting("cmd: loading", delay=0.3, file=slow)
    time.sleep(0.3 + PLAIN_INTERVAL + 0.3)
    assert slow.getvalue().startswith("cmd: loading [00:0")
    log, out = io.StringIO(), io.StringIO()  # a wait that may end in a user's mistake: stderr keeps quiet in a
    monkeypatch.setattr(sys, "stdout", out)  # log (the error stays one line), stdout hears the wait
    with progress.Starting("cmd: checking", delay=0.0, stdout_in_logs=True, file=log):
        time.sleep(PLAIN_INTERVAL + 0.3)
    assert log.getvalue() == "" and out.getvalue().startswith("cmd: checking [00:0")
    with Progress(total=1, desc="work", file=io.StringIO()) as bar:  # the real progress takes over
        assert starting.disable or progress._STARTING is None
        bar.update()


def test_a_delayed_status_shows_once_its_delay_passed_not_a_plain_interval_later():
    from mjdrive import progress

    stream = io.StringIO()
    with progress.Starting("cmd: loading", delay=0.2, file=stream):
        time.sleep(0.2 + 2 * progress.HEARTBEAT)
        shown = stream.getvalue()
    assert shown.startswith("cmd: loading [00:00]") and PLAIN_INTERVAL > 0.2 + 2 * progress.HEARTBEAT


def test_progress_on_a_terminal_redraws_in_place():
    stream = io.StringIO()
    with Progress(total=2, desc="work", file=stream, plain=False) as bar:
        bar.update(2)
    assert "\r" in stream.getvalue()


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> tuple[Path, subprocess.CompletedProcess]:
    out = tmp_path_factory.mktemp("cli") / "run"
    result = mjdrive("run", "--task", "waypoints/straight", "--episodes", "2", "--no-video",
                     "--task-kwarg", "time_limit=3", "--out", str(out))
    assert result.returncode == 0, result.stderr
    return out, result


def test_run_shows_steps_out_of_the_episode_length_without_carriage_returns(run_folder):
    _, result = run_folder
    assert "\r" not in result.stderr
    assert "episode 1/2 (seed 0): " in result.stderr
    assert "/30 (" in result.stderr, result.stderr  # 3 s at 10 Hz: the bar's total is the episode length


def test_run_refuses_a_folder_that_holds_a_run_and_overwrite_replaces_it(run_folder, tmp_path):
    out = tmp_path / "run"
    shutil.copytree(run_folder[0], out)
    again = mjdrive("run", "--task", "waypoints/straight", "--episodes", "1", "--no-video", "--no-record",
                    "--task-kwarg", "time_limit=1", "--out", str(out))
    assert again.returncode == 2
    assert "is not empty" in again.stderr and "--overwrite" in again.stderr
    assert len(list(out.glob("*.mcap"))) == 2  # untouched
    (out / "notes.txt").write_text("mine")
    refused = mjdrive("run", "--task", "waypoints/straight", "--episodes", "1", "--no-video",
                      "--task-kwarg", "time_limit=1", "--out", str(out), "--overwrite")
    assert refused.returncode == 2 and "notes.txt" in refused.stderr
    assert (out / "notes.txt").read_text() == "mine"  # a user's file is never deleted
    (out / "notes.txt").unlink()
    replaced = mjdrive("run", "--task", "waypoints/straight", "--episodes", "1", "--no-video", "--seed", "7",
                       "--task-kwarg", "time_limit=1", "--out", str(out), "--overwrite")
    assert replaced.returncode == 0, replaced.stderr
    assert [p.name for p in out.glob("*.mcap")] == ["waypoints-straight_7_00000.mcap"]


def test_eval_writes_its_logs_beside_out_not_under_the_current_folder(tmp_path):
    work = tmp_path / "cwd"
    work.mkdir()
    out = tmp_path / "elsewhere" / "x"
    result = mjdrive("eval", "--checkpoint", str(ROOT / "results/checkpoints/ppo_features_straight.pt"),
                     "--episodes", "1", "--task-kwarg", "time_limit=1", "--out", str(out), cwd=work)
    assert result.returncode == 0, result.stderr
    assert out.with_suffix(".md").is_file() and out.with_suffix(".json").is_file()
    assert len(list(out.glob("*.mcap"))) == 1
    assert not (work / "runs").exists()
    assert "Resolved observation sets" not in result.stdout and "Actor Model" not in result.stdout  # no rsl-rl dump


def test_run_summary_is_one_documented_schema_shared_with_logs(run_folder, tmp_path):
    out, _ = run_folder
    summary = json.loads((out / "summary.json").read_text())
    assert summary["schema"] == SCHEMA and summary["command"] == "run"
    assert (summary["task"], summary["policy"], summary["seed"], summary["episodes"]) == \
        ("waypoints/straight", "pure_pursuit", 0, 2)
    assert set(summary["summary"]) <= set(SUMMARY_FIELDS)
    for row in summary["rows"]:
        assert list(row) == list(ROW_FIELDS)
        for value in row.values():  # rounded: no float noise such as 22.799999999998242
            assert not isinstance(value, float) or len(repr(value).split(".")[1]) <= 4, row
    assert summary["rows"][0]["end"] == "time_limit" and summary["rows"][0]["time_s"] == 3.0
    logs = mjdrive("logs", str(out), "--out", str(tmp_path / "logs.json"))
    assert logs.returncode == 0, logs.stderr
    from_logs = json.loads((tmp_path / "logs.json").read_text())
    assert from_logs["schema"] == SCHEMA and from_logs["command"] == "logs"
    assert from_logs["rows"] == summary["rows"]  # the same rows, read back from the MCAP files
    assert f"{summary['summary']['avg_speed_m_s']:.2f} (mean)" in logs.stdout


def test_docs_describe_every_summary_field():
    assert markdown_reference() in (ROOT / "docs/summary.md").read_text()


def test_roundabout_exit_is_counted_from_the_entry():
    from mjdrive.envs import make_env

    assert relative_exit({"entry": 3, "exit": 0}, 4) == 1 and relative_exit({"entry": 1, "exit": 0}, 4) == 3
    for exit_number in (1, 2, 3):
        env = make_env("roundabout", "d120", exits=[exit_number], road_users={"car": 1})
        for seed in range(3):
            _, info = env.reset(seed=seed)
            assert relative_exit(info, roundabout_arms("roundabout", "d120", {})) == exit_number
        env.close()


def test_gymnasium_ids_are_named_after_their_tasks_and_the_old_id_warns():
    import gymnasium

    from mjdrive.envs import GYM_IDS

    assert GYM_IDS["mjdrive/Waypoints-RandomRoutes-v0"][:2] == ("waypoints", "random_routes")
    assert "mjdrive/Waypoints-Random-v0" not in GYM_IDS
    with pytest.warns(DeprecationWarning, match="Waypoints-RandomRoutes-v0"):
        env = gymnasium.make("mjdrive/Waypoints-Random-v0")
    assert env.unwrapped.task_name == "random_routes"
    env.close()


@pytest.mark.parametrize("env_id", ["mjdrive/Waypoints-RandomRoutes-v0", "mjdrive/Roundabout-D210-v0"])
def test_observation_spaces_are_finite_and_hold_a_reckless_drive(env_id):
    """Every observation has finite bounds (no gymnasium warning) that hold while the car crashes about."""
    import gymnasium

    env = gymnasium.make(env_id, off_route=None) if "Roundabout" in env_id else gymnasium.make(env_id)
    for space in env.observation_space.values():
        assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))
    observation, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    for step in range(150):
        assert env.observation_space.contains(observation), (step, observation)
        action = np.array([1.0, rng.choice([-1.0, 1.0]), 0.0], np.float32)
        observation, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            observation, _ = env.reset()
    env.close()


def test_ppo_training_prints_no_rsl_rl_model_dump_and_explains_its_rounded_steps(tmp_path, capfd):
    from mjdrive.agents.config import apply_overrides, load_config
    from mjdrive.agents.train import train

    config = apply_overrides(load_config("ppo"), ["steps=40", "num_envs=2", "rsl_rl.num_steps_per_env=32",
                                                  "tensorboard=false", "torch_threads=1", "nthread=1"])
    train(config, tmp_path, progress=False)
    out, _ = capfd.readouterr()
    assert "Actor Model" not in out and "Resolved observation sets" not in out, out
    assert "PPO collects rollouts of 2 envs x 32 steps = 64: training for 64 env steps (asked 40)" in out


def test_every_option_of_every_command_has_help_and_says_its_default():
    import argparse

    from mjdrive.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    assert set(commands) == {"list", "run", "drive", "replay", "logs", "bench", "train", "eval", "ensemble", "hybrid"}
    for name, command in commands.items():
        text = command.format_help()
        assert "(default: None)" not in text and "(default: [])" not in text, name
        formatter = command._get_formatter()
        for action in command._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help, (name, action.dest)
            shown = formatter._get_help_string(action)
            flag = isinstance(action, argparse._StoreConstAction)  # off unless given
            if action.option_strings and not (action.required or flag):
                assert "default" in shown, (name, action.option_strings, shown)
