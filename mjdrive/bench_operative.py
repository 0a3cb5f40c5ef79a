"""`mjdrive bench --operative`: what study 002's operative level costs, measured in one run.

The decision env (`urban/concatenated` with `decisions=True`: one env step = one 0.5 s decision period, the
operative level at 10 Hz underneath) against the throttle/steer/brake env of the same task (one env step = one
0.1 s control period), in interleaved rounds, each standing at the route's start ("stop"; the brake) while the
traffic flows: the overhead of the level per simulated second. Then the decision env driving the route
("drive" everywhere, episodes restarted as they end): the MPC's solve time and the whole level's time per control
period (MPC, LQR, pedals), the time of its OSQP calls (`OSQPSolver.solve`: the vectors handed over, the C solve, the
solution read back) within the MPC's solve, and the share of a decision step spent in the control periods' work (the
level and the ground truth it reads).
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable

import mujoco
import numpy as np

from mjdrive import suite
from mjdrive.bench import HOLD_ACTION, ROUNDS, calls_per_second
from mjdrive.control.mpc import OSQPSolver

OPERATIVE_PARTS = 1 + 2 * ROUNDS + 1
STOP, DRIVE = 1, 0  # the concatenated route's decisions: drive, stop, left, right


def _no_tick(label: str) -> None:
    """A `tick` that shows nothing."""


def bench_operative(seconds: float = 3.0, tick: Callable[[str], None] = _no_tick) -> dict[str, float]:
    """The measurements of the module docstring (`tick` after each of `OPERATIVE_PARTS` parts)."""
    decisions = suite.load("urban", "concatenated", {"random": 0, "decisions": True})
    pedals = suite.load("urban", "concatenated", {"random": 0})
    decisions.reset()
    pedals.reset()
    tick("operative: envs built")

    def stepping(env, action):
        def go():
            if env.step(action).last():
                env.reset()
        return go

    rates = {"decision": [], "pedal": []}
    for _ in range(ROUNDS):
        rates["decision"].append(calls_per_second(stepping(decisions, STOP), seconds / ROUNDS))
        tick("operative: decision env")
        rates["pedal"].append(calls_per_second(stepping(pedals, HOLD_ACTION), seconds / ROUNDS))
        tick("operative: throttle/steer/brake env")
    task = decisions.task
    control_tick = task.control_tick
    tick_time = [0.0]

    def timed_tick(physics, k):
        start = time.perf_counter()
        control_tick(physics, k)
        tick_time[0] += time.perf_counter() - start

    task.control_tick = timed_tick
    osqp_solve = OSQPSolver.solve
    osqp_ms: list[float] = []  # [ms] each OSQP call

    def timed_osqp(solver, *args, **kwargs):
        call_start = time.perf_counter()
        result = osqp_solve(solver, *args, **kwargs)
        osqp_ms.append(1e3 * (time.perf_counter() - call_start))
        return result

    OSQPSolver.solve = timed_osqp
    try:
        decisions.reset()
        solve, level, steps = [], [], 0
        start = time.perf_counter()
        while time.perf_counter() - start < seconds:
            if decisions.step(DRIVE).last():
                decisions.reset()
            steps += 1
            solve += [t["solve_ms"] for t in task.ticks]
            level += [t["step_ms"] for t in task.ticks]
        elapsed = time.perf_counter() - start
    finally:
        OSQPSolver.solve = osqp_solve
        del task.control_tick
    tick("operative: driving")
    solve, level = np.array(solve), np.array(level)
    return {"decision_steps_per_s": max(rates["decision"]), "pedal_steps_per_s": max(rates["pedal"]),
            "decision_dt": decisions.control_timestep(), "pedal_dt": pedals.control_timestep(),
            "solve_median_ms": float(np.median(solve)), "solve_p99_ms": float(np.percentile(solve, 99)),
            "level_median_ms": float(np.median(level)), "level_p99_ms": float(np.percentile(level, 99)),
            "osqp_median_ms": float(np.median(osqp_ms)), "osqp_p99_ms": float(np.percentile(osqp_ms, 99)),
            "osqp_share": float(np.sum(osqp_ms) / np.sum(solve)), "osqp_calls": len(osqp_ms) / len(solve),
            "level_share": 1e-3 * float(level.sum()) / elapsed, "ticks_share": tick_time[0] / elapsed,
            "driving_steps_per_s": steps / elapsed, "ticks": len(solve)}


def run_operative_benchmark(seconds: float = 3.0, tick: Callable[[str], None] = _no_tick) -> str:
    """A markdown report of `bench_operative`."""
    r = bench_operative(seconds, tick)
    decision_sim = r["decision_steps_per_s"] * r["decision_dt"]
    pedal_sim = r["pedal_steps_per_s"] * r["pedal_dt"]
    return "\n".join([
        f"# mjdrive bench, operative level ({platform.processor() or platform.machine()}, "
        f"{mujoco.__version__=}, one thread)", "",
        "| env (urban/concatenated, standing, traffic flowing) | env step [s] | env [steps/s] | env [sim-s/wall-s] "
        "| decisions / throttle-steer-brake |",
        "| --- | ---: | ---: | ---: | ---: |",
        f"| decisions (operative level underneath) | {r['decision_dt']:g} | {r['decision_steps_per_s']:,.0f} "
        f"| {decision_sim:.1f} | {decision_sim / pedal_sim:.2f}x |",
        f"| throttle, steer, brake | {r['pedal_dt']:g} | {r['pedal_steps_per_s']:,.0f} | {pedal_sim:.1f} | - |",
        "",
        "| driving the route (decision env, \"drive\") | median [ms] | p99 [ms] |",
        "| --- | ---: | ---: |",
        f"| MPC solve (OSQP) | {r['solve_median_ms']:.3f} | {r['solve_p99_ms']:.3f} |",
        f"| its OSQP calls, each (vectors in, C solve, solution out) | {r['osqp_median_ms']:.3f} "
        f"| {r['osqp_p99_ms']:.3f} |",
        f"| operative level per control period (MPC, LQR, pedals) | {r['level_median_ms']:.3f} "
        f"| {r['level_p99_ms']:.3f} |",
        "",
        f"The OSQP calls take {r['osqp_share']:.0%} of the MPC's solve time ({r['osqp_calls']:.2f} calls per solve: a "
        "plan that comes too close is solved again within firmer bounds).",
        "",
        f"Driving: {r['driving_steps_per_s']:,.0f} decision steps/s ({r['ticks']} control periods); the operative "
        f"level takes {r['level_share']:.0%} of a decision step, its control periods' work with the ground truth "
        f"it reads {r['ticks_share']:.0%}. Standing rows: the best of {ROUNDS} interleaved rounds; their ratio is "
        "simulated seconds per wall second.",
    ])
