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
