"""Study 002's Table 2 on `urban/concatenated` (or another urban task) for a driver, beside the paper's rows.

    python -m tools.urban_table2 --policy autopilot --episodes 200 --out results/urban/table2_autopilot.md

Episode i runs with seed SEED + i. Metrics per episode from the task's `info` (comfort metrics sampled at the
control rate, 10 Hz, Savitzky-Golay smoothed: `mjdrive.comfort`); the table shows their means over episodes,
like the paper's; comfort and time over successful episodes only.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from mjdrive.envs import make_env
from mjdrive.policies import POLICIES, make_policy

PAPER = {"Ours (paper, hybrid DRL)": (95.76, 4.37, 6.20, 3.33, 76.85, 7.60),
         "CARLA Autopilot (paper)": (100.0, 8.63, 11.94, 2.98, 140.23, 2.75)}
COLUMNS = ("success [%]", "p95 jerk [m/s^3]", "max jerk [m/s^3]", "p95 accel [m/s^2]", "time [s]", "speed [m/s]")


def run(task: str, policy: str, episodes: int, seed: int) -> list[dict]:
    rows = []
    start = time.perf_counter()
    for i in range(episodes):
        env = make_env("urban", task, random=seed + i)
        act = make_policy(policy, env, seed + i)
        observation, info = env.reset(seed=seed + i)
        while True:
            observation, _, terminated, truncated, info = env.step(act(observation))
            if terminated or truncated:
                break
        end = ("success" if info["success"] else "collision" if info["collision"] else
               "off_route" if info["off_route"] else "time_limit")
        rows.append({"seed": seed + i, "end": end, "time": info["elapsed_time"], "speed": info["average_speed"],
                     "jerk_p95": info["jerk_p95_mps3"], "jerk_max": info["jerk_max_mps3"],
                     "accel_p95": info["accel_p95_mps2"], "scenario": info["scenario"]})
        env.close()
        print(f"[{i + 1}/{episodes}] seed {seed + i}: {end} after {info['elapsed_time']:.1f} s "
              f"({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)
    return rows


def markdown(task: str, policy: str, rows: list[dict], seed: int) -> str:
    ok = [r for r in rows if r["end"] == "success"]
    ends = {e: sum(r["end"] == e for r in rows) for e in ("success", "collision", "off_route", "time_limit")}
    mean = (lambda key: float(np.mean([r[key] for r in ok])) if ok else float("nan"))  # noqa: E731
    ours = (100.0 * len(ok) / len(rows), mean("jerk_p95"), mean("jerk_max"), mean("accel_p95"), mean("time"),
            mean("speed"))
    lines = [f"# Table 2 on urban/{task}: {policy}", "",
             f"`python -m tools.urban_table2 --task {task} --policy {policy} --episodes {len(rows)} --seed {seed}`: "
             f"{len(rows)} episodes (seeds {seed}-{seed + len(rows) - 1}); ends: "
             + ", ".join(f"{n} {e}" for e, n in ends.items()) + ". Means over episodes (comfort, time and speed "
             "over the successful ones), beside the paper's rows (CARLA Town03, its own route and traffic: a "
             "comparison of magnitudes, not of the same world).", "",
             "| driver | " + " | ".join(COLUMNS) + " |", "| --- |" + " ---: |" * len(COLUMNS),
             f"| mjdrive {policy} | " + " | ".join(f"{v:.2f}" for v in ours) + " |"]
    lines += [f"| {name} | " + " | ".join(f"{v:.2f}" for v in values) + " |" for name, values in PAPER.items()]
    failed = [r for r in rows if r["end"] != "success"]
    if failed:
        lines += ["", "Episodes that did not arrive: " + ", ".join(
            f"seed {r['seed']} ({r['end']} in {r['scenario']} at {r['time']:.0f} s)" for r in failed) + "."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="concatenated", choices=("roundabout", "lane_change", "crossroad",
                                                                   "merge", "concatenated"))
    parser.add_argument("--policy", default="autopilot", choices=POLICIES)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=20000, help="seed of the first episode")
    parser.add_argument("--out", default=None, help="write the markdown table here")
    args = parser.parse_args(argv)
    rows = run(args.task, args.policy, args.episodes, args.seed)
    text = markdown(args.task, args.policy, rows, args.seed)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)
        print(f"wrote {args.out}")
    else:
        print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
