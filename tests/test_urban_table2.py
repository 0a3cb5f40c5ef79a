"""The Table 2 tool (tools.urban_table2): the same rows with worker processes as in one process, and a
markdown table with the paper's rows beside ours."""

from __future__ import annotations

from tools.urban_table2 import markdown, run


def test_rows_are_the_same_with_two_workers_and_the_table_has_the_papers_rows():
    here = run("merge", "autopilot", 2, seed=7, workers=0)
    spread = run("merge", "autopilot", 2, seed=7, workers=2)
    assert here == spread
    assert [row["seed"] for row in here] == [7, 8]
    text = markdown("merge", "autopilot", here, 7)
    assert "| mjdrive autopilot |" in text and "CARLA Autopilot (paper)" in text


def test_the_table_adds_the_unfiltered_jerk_of_the_same_samples():
    """The two extra columns: p95 and max of the jerk by finite differences of the comfort samples, which
    no filter shrinks (a pulsed brake gives steps in acceleration: far above the smoothed figures)."""
    rows = run("merge", "autopilot", 1, seed=7)
    row = rows[0]
    assert 0 < row["jerk_p95_raw"] <= row["jerk_max_raw"]
    assert row["jerk_p95_raw"] > row["jerk_p95"] and row["jerk_max_raw"] > row["jerk_max"]
    text = markdown("merge", "autopilot", rows, 7)
    header = next(line for line in text.splitlines() if line.startswith("| driver |"))
    assert header.endswith("| p95 jerk unfiltered [m/s^3] | max jerk unfiltered [m/s^3] |")
    ours = next(line for line in text.splitlines() if line.startswith("| mjdrive autopilot |"))
    assert ours.endswith(f"| {row['jerk_p95_raw']:.2f} | {row['jerk_max_raw']:.2f} |")
    assert all(line.endswith("| - | - |") for line in text.splitlines() if "(paper" in line)


def test_a_checkpoint_is_a_driver_whose_episodes_match_mjdrive_eval(tmp_path, decision_agent_file):
    """`--checkpoint NAME=PATH` (e.g. the hybrid agent): its row drives the episodes `mjdrive eval` drives on the
    same seeds, and the table names it and the command."""
    import pytest

    pytest.importorskip("torch")
    from mjdrive.agents.evaluate import evaluate
    from mjdrive.agents.hybrid import save_hybrid
    from tools.urban_table2 import main

    path = save_hybrid({"crossroad": decision_agent_file(tmp_path, "crossroad", 1)}, tmp_path / "hybrid.pt",
                       task="urban/crossroad")
    out = tmp_path / "table.md"
    assert main(["--task", "crossroad", "--checkpoint", f"hybrid (test)={path}", "--episodes", "2", "--seed", "3",
                 "--out", str(out)]) == 0
    text = out.read_text()
    assert f'--checkpoint "hybrid (test)={path}" --episodes 2 --seed 3' in text
    rows = run("crossroad", f"checkpoint={path}", 2, seed=3)
    evaluated = evaluate(path, episodes=2, seed=3)["rows"]
    assert [round(r["time"], 2) for r in rows] == [r["time_s"] for r in evaluated]
    ours = next(line for line in text.splitlines() if line.startswith("| mjdrive hybrid (test) |"))
    assert ours.startswith(f"| mjdrive hybrid (test) | {100 * sum(r['end'] == 'success' for r in rows) / 2:.2f} |")


def test_the_decisions_report_sets_the_agent_against_the_baselines_on_the_same_seeds(tmp_path,
                                                                                    decision_agent_file):
    import pytest

    pytest.importorskip("torch")
    from tools.urban_decisions import main, row

    agent = decision_agent_file(tmp_path, "crossroad", 1)
    out = tmp_path / "decisions.md"
    assert main(["--agent", f"crossroad={agent}", "--episodes", "1", "--seed", "4", "--out", str(out)]) == 0
    text = out.read_text()
    table = [line for line in text.splitlines() if line.startswith("| ") and "driver" not in line and "---" not in line]
    assert [line.split(" | ")[0] for line in table] == [f"| agent `{agent.split('/')[-1]}`", "| always_drive",
                                                        "| always_stop", "| rules"]
    assert table[2].startswith("| always_stop | 0 | 0 | 100 | - |")  # never arrives, never collides
    assert table[0] == row(f"agent `{agent.split('/')[-1]}`", run("crossroad", f"checkpoint={agent}", 1, seed=4))


def test_a_checkpoint_drives_with_its_own_action_set():
    """The end-to-end baseline acts with (pedal, steer): the tool builds its env with the checkpoint's actions."""
    from pathlib import Path

    import pytest

    pytest.importorskip("torch")
    path = Path(__file__).parents[1] / "results/checkpoints/ppo_urban_end_to_end.pt"
    (row,) = run("merge", f"checkpoint={path}", 1, seed=3)
    assert row["end"] in ("success", "collision", "off_route", "time_limit") and row["time"] > 0
