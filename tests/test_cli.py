"""The subcommands no other test runs to success, as a user runs them (`python -m mjdrive.cli ...`): `list`,
`bench` with tiny settings and `train` for a few hundred steps (its policy then read by `eval`). Exit status 0
and the outputs each promises: the task table, files written, table rows.

Run elsewhere: `run` and `logs` (tests/test_cli_outputs.py), `replay` (tests/test_record.py), `eval`
(tests/test_cli_outputs.py, tests/test_parallel.py), `ensemble` (tests/test_ensemble.py), `drive` (tests/test_drive.py,
under Xvfb: the viewer needs a display)."""

from __future__ import annotations

import csv
import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from mjdrive import cli, suite
from mjdrive.envs import GYM_IDS

ROOT = Path(__file__).resolve().parents[1]


def mjdrive(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """`python -m mjdrive.cli ARGS` in `cwd`, output captured; fails the test unless it exits with status 0."""
    done = subprocess.run([sys.executable, "-m", "mjdrive.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=180)
    assert done.returncode == 0, (args, done.stdout[-2000:], done.stderr[-2000:])
    return done


def table_rows(text: str, first_cell: str) -> list[list[str]]:
    """The cells of the markdown table rows of `text` whose first cell is `first_cell`."""
    rows = [[cell.strip() for cell in line.strip().strip("|").split("|")] for line in text.splitlines()
            if line.startswith("|")]
    return [row for row in rows if row[0] == first_cell]


def test_list_names_every_task_and_gymnasium_id_and_each_tasks_keywords(tmp_path, capsys):
    listing = mjdrive("list", cwd=tmp_path).stdout
    lines = listing.splitlines()
    for domain, task in suite.ALL_TASKS:
        description = (suite.task_description(domain, task) or "").split("\n")[0]
        row = [line for line in lines if line.split()[:1] == [f"{domain}/{task}"]]
        assert len(row) == 1 and row[0].rstrip().endswith(description), (domain, task, row)
    ids = [line.strip() for line in lines[lines.index("gymnasium ids (gymnasium.make(id)):") + 1:]]
    assert ids == list(GYM_IDS)
    assert cli.main(["list", "--kwargs", "roundabout/d120"]) == 0  # in process: the variants of the same command
    keywords = capsys.readouterr().out
    config_class, _ = suite.task_config("roundabout", "d120")
    for field in dataclasses.fields(config_class):
        assert len(table_rows(keywords, f"`{field.name}`")) == 1, field.name
    assert cli.main(["list", "--kwargs", "all"]) == 0
    assert capsys.readouterr().out == (ROOT / "docs" / "task_kwargs.md").read_text()  # the file it says it generates


def test_bench_with_tiny_settings_prints_and_writes_its_tables(tmp_path):
    out = tmp_path / "bench.md"
    done = mjdrive("bench", "--tasks", "waypoints/straight", "--roundabout", "d120", "--urban", "--no-highway",
                   "--sensors", "--no-operative", "--seconds", "0.2", "--image-size", "16", "--out", str(out),
                   cwd=tmp_path)
    report = out.read_text()
    assert report.strip() in done.stdout and f"wrote {out}" in done.stdout
    waypoints = table_rows(report, "waypoints/straight")
    roundabout = table_rows(report, "roundabout/d120")
    assert len(waypoints) == 1 and len(roundabout) == 1, report
    assert len(table_rows(report, "urban/concatenated")) == 0  # --urban with no task: no urban table
    for row in (waypoints[0], roundabout[0]):  # every throughput cell is a positive measurement
        numbers = [float(cell.rstrip("%x").replace(",", "")) for cell in row[1:]
                   if re.fullmatch(r"[\d,.]+[%x]?", cell)]
        assert len(numbers) >= 8 and all(n > 0 for n in numbers), row
    assert int(roundabout[0][1]) == 22  # d120's road users
    progress = [line for line in done.stderr.splitlines() if line.startswith("bench: ")]
    assert progress[-1].endswith("roundabout/d120: camera env]"), progress  # each part named by its task


def test_bench_of_the_operative_level_measures_its_cost(tmp_path):
    done = mjdrive("bench", "--tasks", "--roundabout", "--urban", "--sensors", "--operative", "--seconds", "0.5",
                   cwd=tmp_path)
    decision = table_rows(done.stdout, "decisions (operative level underneath)")
    pedal = table_rows(done.stdout, "throttle, steer, brake")
    solve = table_rows(done.stdout, "MPC solve (OSQP)")
    level = table_rows(done.stdout, "operative level per control period (MPC, LQR, pedals)")
    osqp = table_rows(done.stdout, "its OSQP calls, each (vectors in, C solve, solution out)")
    assert len(decision) == len(pedal) == len(solve) == len(level) == len(osqp) == 1, done.stdout
    assert decision[0][1] == "0.5" and pedal[0][1] == "0.1"  # [s] env steps
    assert float(decision[0][4].rstrip("x")) > 0 and float(decision[0][3]) > 0 and float(pedal[0][3]) > 0
    median, p99 = float(solve[0][1]), float(solve[0][2])
    assert 0 < median <= p99 and 0 < float(level[0][1]) <= float(level[0][2])
    assert float(level[0][1]) >= median  # the level's step includes its MPC solve
    assert 0 < float(osqp[0][1]) <= median  # ... and the solve its OSQP call
    share = re.search(r"The OSQP calls take (\d+)% of the MPC's solve time", done.stdout)
    assert share and 0 < int(share.group(1)) < 100, done.stdout


def test_train_a_few_hundred_steps_writes_a_run_folder_that_eval_reads(tmp_path):
    pytest.importorskip("torch")
    pytest.importorskip("rsl_rl")
    from mjdrive.agents.checkpoints import load_checkpoint

    run = tmp_path / "run"
    done = mjdrive("train", "--algo", "ppo", "--task", "waypoints/straight", "--steps", "256", "--num-envs", "2",
                   "--seed", "3", "--task-kwarg", "time_limit=3", "--set", "rsl_rl.num_steps_per_env=32",
                   "--set", "checkpoint_every=128", "--set", "tensorboard=false", "--set", "nthread=1",
                   "--out", str(run), "--no-progress", cwd=tmp_path)
    assert "trained ppo on waypoints/straight for 256 env steps in " in done.stdout
    assert f"wrote {run}/ (policy: {run / 'policy.pt'})" in done.stdout
    config = (run / "config.yaml").read_text()
    assert "seed: 3" in config and "time_limit: 3" in config
    with open(run / "episodes.csv", newline="") as f:
        episodes = list(csv.DictReader(f))
    assert len(episodes) >= 2 * (256 // 2 // 30)  # 3 s episodes: 30 steps each, two copies
    assert all(row["task"] == "waypoints/straight" and int(row["length"]) <= 30 for row in episodes)
    assert json.loads((run / "scalars.json").read_text())["env_steps"] == 256
    assert sorted(p.name for p in (run / "checkpoints").glob("*.pt")) == ["step_128.pt", "step_256.pt"]
    policy = load_checkpoint(run / "policy.pt", "ppo")
    assert policy["step"] == 256 and policy["extra"]["inference_only"] and set(policy["state"]) == {
        "actor_state_dict"}
    assert load_checkpoint(run / "checkpoint.pt", "ppo")["step"] == 256
    evaluation = tmp_path / "eval" / "ppo"
    done = mjdrive("eval", "--checkpoint", str(run / "policy.pt"), "--episodes", "2", "--task-kwarg",
                   "time_limit=1", "--out", str(evaluation), cwd=tmp_path)
    result = json.loads(evaluation.with_suffix(".json").read_text())
    assert (result["command"], result["algo"], result["train_steps"], result["episodes"]) == ("eval", "ppo", 256, 2)
    assert [row["steps"] for row in result["rows"]] == [10, 10]  # 1 s episodes at 10 Hz: the task kwarg reached it
    assert evaluation.with_suffix(".md").read_text().strip() in done.stdout
    assert len(list(evaluation.glob("*.mcap"))) == 2  # one log per episode beside OUT.md
