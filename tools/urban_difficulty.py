"""Study 002's difficulty check: the scripted "always go" driver (`--policy always_go`: pure pursuit along
the route at the lane's speed limit, ignoring traffic) on each urban scenario task.

    python -m tools.urban_difficulty --episodes 100 --out results/urban/always_go.md

Episode i of every task runs with seed SEED + i (the same seeds as `tools.urban_table2`). A scenario is
difficult when this driver collides in a good share of its episodes (goal: >= 30% at the roundabout, the
crossroad and the merge); the lane change is listed for reference.
"""

from __future__ import annotations

import sys
from pathlib import Path

from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from mjdrive.policies import POLICIES
from tools.report import publish
from tools.urban_table2 import run

TASKS = ("roundabout", "lane_change", "crossroad", "merge")
ENDS = ("success", "collision", "off_route", "time_limit")


def markdown(results: dict[str, list[dict]], episodes: int, seed: int, policy: str) -> str:
    lines = [f"# Difficulty: the {policy} driver on each urban scenario", "",
             f"`python -m tools.urban_difficulty --policy {policy} --episodes {episodes} --seed {seed}`: "
             f"{episodes} episodes per task (seeds {seed}-{seed + episodes - 1}), each starting 25 m before its "
             "scenario at the default traffic. The driver follows the route at the lane's speed limit and "
             "ignores traffic and give-way lines; the traffic reacts to it as to any road user (it brakes for "
             "what is ahead of it and gives way by the conflict-zone rules), so a collision means the ego "
             "drove into a vehicle or cut one off too closely for it to stop.", "",
             "| task | episodes | collision [%] | success [%] | off route [%] | time limit [%] | "
             "mean time to collision [s] |", "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for task, rows in results.items():
        n = len(rows)
        share = {e: 100.0 * sum(r["end"] == e for r in rows) / n for e in ENDS}
        hit = [r["time"] for r in rows if r["end"] == "collision"]
        mean_hit = f"{sum(hit) / len(hit):.1f}" if hit else "-"
        lines.append(f"| urban/{task} | {n} | {share['collision']:.0f} | {share['success']:.0f} | "
                     f"{share['off_route']:.0f} | {share['time_limit']:.0f} | {mean_hit} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="*", default=list(TASKS), choices=TASKS)
    parser.add_argument("--policy", default="always_go", choices=POLICIES, help="the driver")
    parser.add_argument("--episodes", type=int_at_least(1), default=100)
    parser.add_argument("--seed", type=int_at_least(0), default=20000, help="seed of the first episode")
    parser.add_argument("--out", default=None, help="write the markdown table here")
    args = parser.parse_args(argv)
    results = {task: run(task, args.policy, args.episodes, args.seed) for task in args.tasks}
    text = markdown(results, args.episodes, args.seed, args.policy)
    publish(text, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
