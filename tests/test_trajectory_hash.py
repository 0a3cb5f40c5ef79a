"""Trajectories do not move (`tools.trajectory_hash`): short runs of the roundabout, the urban tasks, a waypoint task
and the batched env hash to the values recorded on b4686a2, before the traffic's rules became one source
(issue 39). A golden hash is a regression guard: a change of any number of the traffic, the ego or the
observations breaks it (and a deliberate change of behaviour records new values here, saying why)."""

from __future__ import annotations

import pytest

from tools.trajectory_hash import FIRST_SEED, batched_hash, case_hash

STEPS = 120  # control steps (12 s): some 20 traffic decisions
GOLDEN = {  # (domain, task, policy): hash of STEPS steps from FIRST_SEED, recorded on b4686a2
    ("roundabout", "d210", "autopilot"): "5cf9f6251589a66d",
    ("roundabout", "d120", "random"): "2f0bdaa31e33c801",
    ("urban", "concatenated", "autopilot"): "92803b303067b0ee",
    ("urban", "lane_change", "always_go"): "45c9f336146b05e2",
    ("urban", "crossroad", "always_go"): "595832ac02263a4b",
    ("urban", "merge", "autopilot"): "d8bc02c58a149520",
    ("waypoints", "four_routes", "pure_pursuit"): "0d1c9d13db39c8c2",
}
GOLDEN_BATCHED = "11a75e5fabbd4beb"  # roundabout d120 + d210 stepped together


@pytest.mark.parametrize("case", list(GOLDEN), ids=lambda case: "/".join(case))
def test_trajectory_hash_is_unchanged(case):
    assert case_hash(*case, FIRST_SEED, STEPS) == GOLDEN[case]


def test_batched_trajectory_hash_is_unchanged():
    assert batched_hash(FIRST_SEED, STEPS) == GOLDEN_BATCHED
