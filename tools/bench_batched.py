"""Throughput of BatchedEnv: env steps/s for N copies, 1 or 2 threads, each physics backend.

    python -m tools.bench_batched --out results/bench_batched.md

Env steps/s counts transitions (N per batched step). Scaling = steps/s with 2 threads over 1 thread for the
same N and backend. The single-env `DrivingGymEnv` is measured in the same run as the reference.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.envs import make_env
from mjdrive.envs.batched import BatchedEnv

CRUISE = np.array([0.4, 0.0, 0.0], np.float32)  # throttle, steer, brake


def rate(step, seconds: float) -> float:
    """Calls of `step` per wall second over about `seconds` (after one warm-up call)."""
    step()
    calls, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        step()
        calls += 1
    return calls / elapsed


def bench_single(task: str, seconds: float, rounds: int, **task_kwargs) -> float:
    domain, name = task.split("/")
    env = make_env(domain, name, **task_kwargs)
    env.reset(seed=0)

    def step():
        _, _, terminated, truncated, _ = env.step(CRUISE)
        if terminated or truncated:
            env.reset()

    result = max(rate(step, seconds) for _ in range(rounds))
    env.close()
    return result


def bench_batched(task: str, num_envs: int, nthread: int, backend: str, seconds: float, rounds: int,
                  **task_kwargs) -> float:
    """Best of `rounds` measurements (the best is the least disturbed by other jobs on the machine)."""
    domain, name = task.split("/")
    env = BatchedEnv(domain, name, num_envs=num_envs, nthread=nthread, backend=backend, **task_kwargs)
    env.reset(seed=0)
    actions = np.repeat(CRUISE[None], num_envs, axis=0)
    result = max(rate(lambda: env.step(actions), seconds) for _ in range(rounds)) * num_envs
    env.close()
    return result


def bench_physics(task: str, num_envs: int, nthread: int, backend: str, seconds: float, rounds: int) -> float:
    """The physics call alone (BatchedEnv.step_physics), env steps/s: the part that threads can speed up."""
    domain, name = task.split("/")
    env = BatchedEnv(domain, name, num_envs=num_envs, nthread=nthread, backend=backend)
    env.reset(seed=0)
    for base in env.bases:
        base.before_physics(CRUISE)
    result = max(rate(env.step_physics, seconds) for _ in range(rounds)) * num_envs
    env.close()
    return result


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="waypoints/straight")
    parser.add_argument("--sizes", type=int_at_least(1), nargs="+", default=[1, 8, 32])
    parser.add_argument("--threads", type=int_at_least(1), nargs="+", default=[1, 2])
    parser.add_argument("--backends", nargs="+", default=["serial", "threads", "rollout"])
    parser.add_argument("--seconds", type=positive_float, default=1.5, help="wall time per measurement [s]")
    parser.add_argument("--rounds", type=int_at_least(1), default=3, help="measurements per figure; the best is kept")
    parser.add_argument("--camera", action="store_true", help="also measure the camera observation")
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)

    observations = ["features"] + (["camera"] if args.camera else [])
    load = os.getloadavg()[0]
    lines = [
        f"# BatchedEnv throughput ({args.task}; {platform.machine()}, {os.cpu_count()} cores, "
        f"python {platform.python_version()})",
        "",
        f"Command: `python -m tools.bench_batched {' '.join(argv if argv is not None else sys.argv[1:])}`",
        "",
        "| observation | backend | N | steps/s, 1 thread | steps/s, 2 threads | scaling 2/1 "
        "| vs single env |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: |",
    ]
    for observation in observations:
        single = bench_single(args.task, args.seconds, args.rounds, observation=observation)
        lines.append(f"| {observation} | single DrivingGymEnv | 1 | {single:,.0f} | | | 1.00 |")
        for backend in args.backends:
            for n in args.sizes:
                rates = {}
                for nthread in args.threads:
                    if backend == "serial" and nthread > 1:
                        continue
                    rates[nthread] = bench_batched(args.task, n, nthread, backend, args.seconds,
                                                   args.rounds, observation=observation)
                    print(f"{observation} {backend} N={n} threads={nthread}: {rates[nthread]:,.0f} steps/s",
                          flush=True)
                one, two = rates.get(1), rates.get(2)
                scaling = f"{two / one:.2f}" if one and two else ""
                best = max(rates.values())
                lines.append(f"| {observation} | {backend} | {n} | {one or 0:,.0f} | "
                             f"{f'{two:,.0f}' if two else ''} | {scaling} | {best / single:.2f} |")
    lines += ["", "Physics call alone (no task Python), env steps/s:", "",
              "| backend | N | 1 thread | 2 threads | scaling 2/1 |", "| --- | ---: | ---: | ---: | ---: |"]
    for backend in [b for b in args.backends if b != "serial"]:
        for n in [n for n in args.sizes if n > 1]:
            one, two = (bench_physics(args.task, n, t, backend, args.seconds, args.rounds) for t in (1, 2))
            print(f"physics {backend} N={n}: {one:,.0f} / {two:,.0f}", flush=True)
            lines.append(f"| {backend} | {n} | {one:,.0f} | {two:,.0f} | {two / one:.2f} |")
    lines += [
        "",
        "steps/s: transitions per wall second (N per batched step), features observation unless stated.",
        "scaling 2/1: the same N and backend with 2 threads over 1 thread. Only the physics call runs in "
        "threads; the tasks' Python (sensors, rewards, observations, rendering) runs on one core.",
        f"Best of {args.rounds} x {args.seconds} s per figure. The machine is shared with other jobs "
        f"(1-min load average {load:.1f} at the start; 2 cores), so figures vary between runs; the scaling "
        "column is the one to compare.",
    ]
    report = "\n".join(lines)
    print(report)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(report + "\n")
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
