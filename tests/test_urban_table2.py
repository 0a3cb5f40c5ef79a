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
