"""Cost of recording: env throughput with and without `RecordEpisodes` (no camera images unless asked).

    python -m tools.bench_record --tasks waypoints/straight waypoints/random_routes --out results/bench_record.md

Both runs drive the same env instance with the pure-pursuit driver; only the time inside reset/step is
counted (the policy is excluded), episodes included (file open, road scene, summary, rename). Rounds of
plain and recorded driving alternate so that machine noise hits both alike; the medians are reported.
Time is this process's CPU time (all its threads, so a writer thread would count), which other jobs on a
shared machine disturb far less than wall time; wall-time rates are reported beside it.
"""

from __future__ import annotations

import platform
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import mujoco

from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.envs import make_env
from mjdrive.policies import make_policy
from mjdrive.record import RecordEpisodes, RecordOptions


def _drive(env, policy, seconds: float, seed: int) -> tuple[float, float, int, int]:
    """(env CPU seconds, env wall seconds, env steps, episodes) over about `seconds` of env CPU time."""
    cpu, wall, steps, episodes = 0.0, 0.0, 0, 0
    while cpu < seconds:
        c, w = time.process_time(), time.perf_counter()
        observation, _ = env.reset(seed=seed + episodes)
        cpu, wall = cpu + time.process_time() - c, wall + time.perf_counter() - w
        episodes += 1
        while True:
            action = policy(observation)
            c, w = time.process_time(), time.perf_counter()
            observation, _, terminated, truncated, _ = env.step(action)
            cpu, wall = cpu + time.process_time() - c, wall + time.perf_counter() - w
            steps += 1
            if terminated or truncated or cpu >= seconds:
                break
    return cpu, wall, steps, episodes


def bench_task(name: str, rounds: int, seconds: float, options: RecordOptions) -> dict:
    domain, task = name.split("/")
    env = make_env(domain, task)
    policy = make_policy("pure_pursuit", env)
    out = tempfile.mkdtemp(prefix="bench_record_")
    recorded = RecordEpisodes(env, out, options)
    plain_rates, rec_rates, plain_wall, rec_wall, files, episodes = [], [], [], [], 0, 0
    try:
        _drive(env, policy, 0.5, 0)  # warm-up both paths
        _drive(recorded, policy, 0.5, 0)
        for r in range(rounds):
            cpu, wall, steps, _ = _drive(env, policy, seconds, 1000 * r)
            plain_rates.append(steps / cpu)
            plain_wall.append(steps / wall)
            cpu, wall, steps, n = _drive(recorded, policy, seconds, 1000 * r)
            rec_rates.append(steps / cpu)
            rec_wall.append(steps / wall)
            episodes += n
        recorded.close()
        files = len(recorded.recorder.paths)
    finally:
        shutil.rmtree(out, ignore_errors=True)
    plain, rec = statistics.median(plain_rates), statistics.median(rec_rates)
    wall_ratio = statistics.median(rec_wall) / statistics.median(plain_wall)
    return {"task": name, "plain": plain, "recorded": rec, "ratio": rec / plain, "wall_ratio": wall_ratio,
            "overhead_ms": 1e3 / rec - 1e3 / plain, "files": files, "episodes": episodes}


def main() -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["waypoints/straight", "waypoints/four_routes",
                                                       "waypoints/random_routes"])
    parser.add_argument("--rounds", type=int_at_least(1), default=5)
    parser.add_argument("--seconds", type=positive_float, default=2.0, help="env time per round and mode [s]")
    parser.add_argument("--camera-every", type=int_at_least(0), default=0)
    parser.add_argument("--out", default=None)
    args = parser.parse_args()
    options = RecordOptions(camera_every=args.camera_every)
    lines = [
        f"# Recording cost ({platform.processor() or platform.machine()}, mujoco {mujoco.__version__}, one thread)",
        "",
        f"`python -m tools.bench_record --tasks {' '.join(args.tasks)} --rounds {args.rounds} "
        f"--seconds {args.seconds:g} --camera-every {args.camera_every}` ({args.rounds} alternating rounds of "
        f"{args.seconds:g} CPU-s of env time per mode, medians; camera images "
        f"{f'every {args.camera_every} steps' if args.camera_every else 'off'}).",
        "",
        "| task | env [steps/CPU-s] | env + recording [steps/CPU-s] | recorded / plain | recording [ms/step] "
        "| recorded / plain (wall) | files |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name in args.tasks:
        r = bench_task(name, args.rounds, args.seconds, options)
        lines.append(f"| {name} | {r['plain']:,.0f} | {r['recorded']:,.0f} | {r['ratio']:.0%} "
                     f"| {r['overhead_ms']:.3f} | {r['wall_ratio']:.0%} | {r['files']} |")
        print(lines[-1], flush=True)
    report = "\n".join(lines)
    print(report)
    if args.out:
        with open(args.out, "w") as f:
            f.write(report + "\n")


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
