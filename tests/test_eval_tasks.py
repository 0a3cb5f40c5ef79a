"""`mjdrive eval` on one task of each domain (route completion only where the task has one), a checkpoint refused
up front on a task it cannot run on (in one line, before any file is written), and an interrupted run's
unfinished logs that never block the next run."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rsl_rl")

from mjdrive import cli  # noqa: E402
from mjdrive.agents.algorithms import agent_class  # noqa: E402
from mjdrive.agents.checkpoints import save_checkpoint  # noqa: E402
from mjdrive.agents.config import load_config  # noqa: E402
from mjdrive.envs import make_env  # noqa: E402
from mjdrive.run_folder import lock_part  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINTS = ROOT / "results" / "checkpoints"
WAYPOINTS = CHECKPOINTS / "ppo_features_straight.pt"  # trained on waypoints/straight, features
ROUNDABOUT = CHECKPOINTS / "sac_features_roundabout.pt"  # trained on roundabout/d210 with exits=[1]


@pytest.fixture(scope="module")
def urban_checkpoint(tmp_path_factory) -> Path:
    """An untrained PPO policy.pt for urban/merge (features): what eval reads, without the training."""
    config = {**load_config("ppo"), "task": "urban/merge", "task_kwargs": {"observation": "features"}}
    env = make_env("urban", "merge", actions=config["actions"], **config["task_kwargs"])
    agent = agent_class("ppo")(config, env.observation_space, env.action_space)
    env.close()
    path = tmp_path_factory.mktemp("checkpoints") / "ppo_urban_merge.pt"
    return save_checkpoint(path, "ppo", config, {"actor_state_dict": agent.actor.state_dict()}, 0,
                           {"inference_only": True})


def _eval(capsys, *args: str) -> tuple[int, str, str]:
    status = cli.main(["eval", *args])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


@pytest.mark.parametrize("domain", ["waypoints", "roundabout", "urban"])
def test_eval_runs_on_a_task_of_each_domain(domain, urban_checkpoint, tmp_path, capsys):
    checkpoint, task = {"waypoints": (WAYPOINTS, "waypoints/straight"), "roundabout": (ROUNDABOUT, "roundabout/d120"),
                        "urban": (urban_checkpoint, "urban/merge")}[domain]
    out = tmp_path / "eval"
    status, stdout, err = _eval(capsys, "--checkpoint", str(checkpoint), "--task", task, "--episodes", "2",
                                "--task-kwarg", "time_limit=2", "--out", str(out))
    assert status == 0, err
    result = json.loads(out.with_suffix(".json").read_text())
    assert result["task"] == task and len(result["rows"]) == 2
    assert all(row["steps"] > 0 and row["log"] for row in result["rows"])
    assert len(list(out.glob("*.mcap"))) == 2
    markdown = out.with_suffix(".md").read_text()
    completion = any(row["route_completion"] is not None for row in result["rows"])
    assert completion == (domain == "waypoints")  # only the waypoints tasks have route completion
    assert ("route_completion_mean" in result["summary"]) == completion
    assert ("route completion" in markdown) == completion
    lines = markdown.splitlines()
    header = next(line for line in lines if line.startswith("| episode |"))
    episodes = lines[lines.index(header) + 1:]  # the rule, then one row per episode
    assert len(episodes) == 3 and all(line.count("|") == header.count("|") for line in episodes)
    if domain == "urban":
        assert "| success % | collision % | avg reward |" in markdown


@pytest.mark.parametrize("args, message", [
    (["--checkpoint", str(WAYPOINTS), "--task", "urban/concatenated"],
     f"checkpoint {WAYPOINTS} reads the observation of waypoints/straight and cannot read that of "
     "urban/concatenated: no 'heading_error'; no 'lane_offset'; no 'speed'; no 'waypoint_angles'"),
    (["--checkpoint", str(ROUNDABOUT), "--task", "urban/roundabout"],
     f"checkpoint {ROUNDABOUT} was trained on roundabout/d210 with the task keyword exits=[1], which "
     "urban/roundabout does not take"),
    (["--checkpoint", str(WAYPOINTS), "--task-kwarg", "actions=pedal"],
     "'actions' is not a task keyword: the action set is the checkpoint's own"),
    (["--checkpoint", str(WAYPOINTS), "--task-kwarg", "observation=camera"],
     "cannot read that of waypoints/straight with observation='camera': no 'lane_offset'"),
])
def test_a_checkpoint_that_cannot_run_on_the_task_is_refused_before_anything_is_written(args, message, tmp_path,
                                                                                       capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    status, _, err = _eval(capsys, *args, "--episodes", "1", "--out", "evaluation")
    assert status == 2
    assert err.splitlines() == [f"mjdrive eval: error: {err.split('error: ', 1)[1].strip()}"]
    assert message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # no OUT.md, OUT.json, logs folder or .part


def test_unfinished_logs_of_an_interrupted_run_never_block_the_next_one_a_live_ones_do(tmp_path, capsys):
    logs = tmp_path / "evaluation"
    logs.mkdir()
    stale = logs / "waypoints-straight_10000_00000.mcap.part"  # what a killed evaluation leaves
    stale.write_bytes(b"\x89MCAP0\r\n")
    status, _, err = _eval(capsys, "--checkpoint", str(WAYPOINTS), "--episodes", "1", "--task-kwarg", "time_limit=1",
                           "--out", str(logs))
    assert status == 0, err
    assert f"note: removed 1 unfinished log ({stale.name}) left in {logs} by an interrupted run" in err
    assert sorted(p.name for p in logs.iterdir()) == ["waypoints-straight_10000_00000.mcap"]
    # a .part whose writer still runs (it holds the lock, as EpisodeRecorder does): a run in progress
    other = tmp_path / "busy"
    other.mkdir()
    live = other / "waypoints-straight_5_00000.mcap.part"
    descriptor = lock_part(os.open(live, os.O_CREAT | os.O_WRONLY, 0o644))
    try:
        status, _, err = _eval(capsys, "--checkpoint", str(WAYPOINTS), "--episodes", "1", "--out", str(other))
        assert status == 2 and live.exists()
        assert f"is in use: a running process is writing {live.name} there" in err
        for command in (["run", "--out", str(other), "--episodes", "1"],
                        ["run", "--out", str(other), "--overwrite"]):  # not even --overwrite removes it
            assert cli.main(command) == 2 and live.exists()
            assert "is in use" in capsys.readouterr().err
    finally:
        os.close(descriptor)
    assert cli.main(["run", "--task", "waypoints/straight", "--task-kwarg", "time_limit=1", "--no-video",
                     "--out", str(other)]) == 0  # its writer gone: removed, the run goes ahead
    assert not live.exists() and "note: removed 1 unfinished log" in capsys.readouterr().err


@pytest.mark.parametrize("kwarg, message", [
    ("actions=pedal", "'actions' is not a task keyword: the action set is the config's `actions` (here 'continuous')"),
    ("time_limt=3", "unknown keyword 'time_limt' for waypoints/straight (did you mean 'time_limit'?)"),
])
def test_train_refuses_a_bad_task_keyword_before_writing_its_run_folder(kwarg, message, tmp_path, capsys):
    assert cli.main(["train", "--algo", "ppo", "--steps", "100", "--task-kwarg", kwarg, "--out",
                     str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mjdrive train: error: ") and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "run").exists()
