"""Do the learned decisions matter? Per scenario task, a trained decision agent against the constant decisions
(always drive, always stop) and the rule-based decisions, on the same seeds (study 002's question behind Table 2).

    python -m tools.urban_decisions --agent roundabout=results/checkpoints/trpo_roundabout.pt \\
        --agent crossroad=... --episodes 100 --seed 30000 --workers 2 --out results/urban/decisions.md

Episode i of every driver on a scenario runs with seed SEED + i (`tools.urban_table2.run`: the same rows for
any number of workers). Per driver: success, collisions, time limits, and over the successful episodes the
time, speed and comfort (means over episodes, as Table 2).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from tools.report import publish
from tools.urban_table2 import CHECKPOINT, checkpoint_policy, run

SCENARIOS = ("roundabout", "lane_change", "crossroad", "merge")
BASELINES = ("always_drive", "always_stop", "rules")
COLUMNS = ("success [%]", "collision [%]", "time limit [%]", "time [s]", "speed [m/s]", "p95 jerk [m/s^3]",
           "max jerk [m/s^3]", "p95 accel [m/s^2]")


def row(name: str, episodes: list[dict]) -> str:
    """One markdown row: ends in percent, then means over the successful episodes."""
    n = len(episodes)
    share = {end: 100.0 * sum(r["end"] == end for r in episodes) / n for end in ("success", "collision",
                                                                              "time_limit")}
    ok = [r for r in episodes if r["end"] == "success"]
    mean = (lambda key: f"{np.mean([r[key] for r in ok]):.2f}" if ok else "-")  # noqa: E731
    cells = [f"{share['success']:.0f}", f"{share['collision']:.0f}", f"{share['time_limit']:.0f}", mean("time"),
             mean("speed"), mean("jerk_p95"), mean("jerk_max"), mean("accel_p95")]
    return f"| {name} | " + " | ".join(cells) + " |"


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--agent", action="append", default=[], metavar="SCENARIO=PATH", required=True,
                        help="the decision agent trained on urban/SCENARIO (repeatable; scenarios without one are "
                             "left out)")
    parser.add_argument("--episodes", type=int_at_least(1), default=100)
    parser.add_argument("--seed", type=int_at_least(0), default=30000, help="seed of the first episode")
    parser.add_argument("--workers", type=int_at_least(0), default=0, metavar="N")
    parser.add_argument("--out", default=None, help="write the markdown report here")
    args = parser.parse_args(argv)
    agents = {}
    for item in args.agent:
        scenario, sep, path = item.partition("=")
        if not sep or scenario not in SCENARIOS:
            parser.error(f"--agent {item!r}: write SCENARIO=PATH with SCENARIO one of {', '.join(SCENARIOS)}")
        if not Path(path).is_file():
            parser.error(f"--agent {item!r}: no file {path}")
        checkpoint_policy(path)  # a bad checkpoint: its one-line error before any episode runs
        agents[scenario] = path
    command = " ".join(f"--agent {s}={p}" for s, p in agents.items())
    lines = ["# Do the learned decisions matter?", "",
             f"`python -m tools.urban_decisions {command} --episodes {args.episodes} --seed {args.seed}`: "
             f"{args.episodes} episodes per driver and scenario task (seeds {args.seed}-"
             f"{args.seed + args.episodes - 1}, the same for every driver), each starting 25 m before its scenario, "
             "the operative level driving underneath every driver. The agent acts greedily. Time, speed and "
             "comfort: means over the successful episodes.", ""]
    for scenario, path in agents.items():
        print(f"{scenario}: the agent, then {', '.join(BASELINES)}", file=sys.stderr, flush=True)
        lines += [f"## urban/{scenario}", "", "| driver | " + " | ".join(COLUMNS) + " |",
                  "| --- |" + " ---: |" * len(COLUMNS)]
        lines.append(row(f"agent `{Path(path).name}`", run(scenario, CHECKPOINT + path, args.episodes, args.seed,
                                                            args.workers)))
        for baseline in BASELINES:
            lines.append(row(baseline, run(scenario, baseline, args.episodes, args.seed, args.workers)))
        lines.append("")
    publish("\n".join(lines), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
