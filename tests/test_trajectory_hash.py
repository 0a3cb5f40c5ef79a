"""Trajectories do not move (`tools.trajectory_hash`): short runs of the roundabout, the urban tasks, a waypoint task
and the batched env hash to the values recorded on b4686a2, before the traffic's rules became one source
(issue 39), by this tool; and the debug mode that runs every kernel as Python (MJDRIVE_INTERPRETED=1) gives the
same. A golden hash is a regression guard: a change of any number of the traffic, the ego or the observations
breaks it (and a deliberate change of behaviour records new values here, saying why)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tools.trajectory_hash import FIRST_SEED, batched_hash, case_hash

ROOT = Path(__file__).resolve().parents[1]

STEPS = 120  # control steps (12 s): some 20 traffic decisions
GOLDEN = {  # (domain, task, policy): hash of STEPS steps from FIRST_SEED, recorded on b4686a2
    ("roundabout", "d210", "autopilot"): "ec94bbcc1104eaa8",
    ("roundabout", "d120", "random"): "2f0bdaa31e33c801",
    # urban: re-recorded when oncoming vehicles left the corridor check under urban rules (the narrow-crossroad
    # gridlock of issue 44) and a vehicle standing first at its give-way line counts as arriving now at equal ranks;
    # study 000's roundabouts keep their values; re-recorded again when each piece of a chain kept its own traffic
    # (vehicles leave at the piece borders), courteous vehicles opened gaps within 60 m of a merge point (was 40 m:
    # the two-lane road's 40 m taper) and the autopilot overtook on the two-lane road; and again when a yielding
    # vehicle counted a priority agent's time to a crossing with the acceleration it may take (`conflicts.reach_time`)
    ("urban", "concatenated", "autopilot"): "dc6e6a007bf98dbc",
    ("urban", "lane_change", "always_go"): "d558e82f58989ae1",
    ("urban", "crossroad", "always_go"): "6a06776b25ff6708",
    ("urban", "merge", "autopilot"): "fc5b55b5642b788e",
    ("waypoints", "four_routes", "pure_pursuit"): "0d1c9d13db39c8c2",
}
GOLDEN_BATCHED = "11a75e5fabbd4beb"  # roundabout d120 + d210 stepped together


@pytest.mark.parametrize("case", list(GOLDEN), ids=lambda case: "/".join(case))
def test_trajectory_hash_is_unchanged(case):
    assert case_hash(*case, FIRST_SEED, STEPS) == GOLDEN[case]


def test_batched_trajectory_hash_is_unchanged():
    assert batched_hash(FIRST_SEED, STEPS) == GOLDEN_BATCHED


def test_interpreted_kernels_give_the_same_hashes():
    """Every kernel run as plain Python (the debug switch: `compiled.jit` returns the function itself) gives the
    compiled run's numbers: the same hashes (in a fresh process, which reads the switch at import)."""
    cases = [("roundabout", "d210", "autopilot"), ("urban", "concatenated", "autopilot"),
             ("urban", "lane_change", "always_go")]
    code = ("import sys; from mjdrive.compiled import INTERPRETED; from tools.trajectory_hash import case_hash, "
            f"batched_hash; assert INTERPRETED; print(*[case_hash(*c, {FIRST_SEED}, {STEPS}) for c in {cases}], "
            f"batched_hash({FIRST_SEED}, {STEPS}))")
    env = {**os.environ, "MJDRIVE_INTERPRETED": "1", "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env, cwd=ROOT)
    assert out.stdout.split() == [GOLDEN[case] for case in cases] + [GOLDEN_BATCHED]


def test_compile_kernels_compiles_every_kernel():
    """`python -m mjdrive.envs.compile_kernels` (which `make install` runs) runs every kernel called from Python (a
    fresh process: none compiled or loaded before)."""
    code = ("from mjdrive.envs.compile_kernels import compile_kernels, uncompiled; compile_kernels(); "
            "print(uncompiled())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    assert out.strip().splitlines()[-1] == "[]"
