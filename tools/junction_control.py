"""Junction control at study 002's crossroad: give-way lines, stop signs on the minor road, traffic lights. Traffic
alone (violations, overlaps, throughput per approach against the give-way crossroad), then the ego: the autopilot
and an always-go driver (the route at the speed limit, blind to traffic and signals) on `urban/crossroad`.

    python -m tools.junction_control --minutes 10 --seeds 3 --episodes 100 --out results/urban/junction_control.md

Exit status 1 if traffic runs a red light or a stop sign, two road users overlap, or the autopilot fails an
episode or commits a violation under stop signs or lights.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.roads.urban import concatenated
from mjdrive.traffic.junction_control import CONTROLS, SignalTiming
from tools.report import publish
from tools.urban_table2 import run as run_episodes
from tools.urban_traffic import run as run_traffic

ARMS = ("approach", "straight", "left", "right")  # the crossroad's arms: minor road (the ego's), then main road


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=positive_float, default=10.0, help="simulated traffic minutes per seed")
    parser.add_argument("--seeds", type=int_at_least(1), default=3, help="traffic seeds 0..N-1 per control")
    parser.add_argument("--episodes", type=int_at_least(1), default=100, help="ego episodes per control and driver")
    parser.add_argument("--seed", type=int_at_least(0), default=50000, help="seed of the first ego episode")
    parser.add_argument("--time-limit", type=positive_float, default=120.0,
                        help="the ego's episodes' time limit [s] (urban/crossroad's default, 90 s, is set for "
                        "give-way; a stop sign adds a full stop and a new start)")
    parser.add_argument("--workers", type=int_at_least(0), default=0, metavar="N")
    parser.add_argument("--out", default=None, help="write the markdown report here")
    args = parser.parse_args(argv)
    rm = concatenated(order=("crossroad",)).road_map
    entry = {arm: rm.lane_id(f"crossroad/{arm}_in_0") for arm in ARMS}
    timing = SignalTiming()
    lines = [
        "# Junction control at the crossroad: give-way, stop signs, traffic lights", "",
        f"`python -m tools.junction_control --minutes {args.minutes:g} --seeds {args.seeds} --episodes "
        f"{args.episodes} --time-limit {args.time_limit:g}`. Study 002's crossroad (`urban/crossroad`: the minor road, "
        "the ego's approach and the arm across, meets the main road), its default traffic (8 cars, 2 motorcycles), "
        "`junction_control` = give_way "
        "(the conflict zones' right of way alone), stop (stop signs on the minor road: come to rest at the line, "
        f"then give way) or lights (main green {timing.green_main:g} s, amber {timing.amber:g} s, all red "
        f"{timing.all_red:g} s, minor green {timing.green_minor:g} s, amber, all red: a {timing.cycle:g} s cycle; "
        "left turns still yield to oncoming traffic within a green).", "",
        f"## Traffic alone: {args.minutes:g} simulated minutes on each of seeds 0-{args.seeds - 1}", "",
        "Violations: vehicles that entered the junction from a red light, or from a stop sign they had not come to "
        "rest at (counted by the traffic at its decisions); free stop: the longest stop of a vehicle not queued "
        "(waiting at a red light or a line counts); throughput: vehicles per minute entering the junction from "
        "each arm, mean over seeds.", "",
        "| control | red-light violations | stop-sign violations | overlaps | free stop max [s] | "
        + " | ".join(f"{arm} [veh/min]" for arm in ARMS) + " | all [veh/min] |",
        "| --- | ---: | ---: | ---: | ---: | " + " | ".join("---:" for _ in ARMS) + " | ---: |",
    ]
    bad, start = False, time.perf_counter()
    for control in CONTROLS:
        runs = [run_traffic("crossroad", seed, args.minutes, control) for seed in range(args.seeds)]
        red = sum(r["stats"]["red_light_violations"] for r in runs)
        stop = sum(r["stats"]["stop_sign_violations"] for r in runs)
        overlaps = sum(r["overlaps"] for r in runs)
        through = np.mean([r["lane_throughput"] for r in runs], axis=0)
        per_arm = [through[entry[arm]] for arm in ARMS]
        lines.append(f"| {control} | {red} | {stop} | {overlaps} | {max(r['stop_free'] for r in runs):.1f} | "
                     + " | ".join(f"{x:.1f}" for x in per_arm) + f" | {sum(per_arm):.1f} |")
        bad |= red > 0 or stop > 0 or overlaps > 0
        print(f"traffic, {control}: violations {red} + {stop}, overlaps {overlaps} "
              f"({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)
    lines += ["", f"## The ego on urban/crossroad: {args.episodes} episodes per control and driver (seeds "
              f"{args.seed}-{args.seed + args.episodes - 1}, {args.time_limit:g} s limit)", "",
              "An episode ends on a violation (the ego's front bumper 0.5 m past a line showing red, or past a stop "
              "sign's line without having come to rest within 5 m of it: `info['violation']`, the summary's `end`). "
              "Time: mean over the successful episodes.", "",
              "| control | driver | success [%] | red lights run | stop signs run | collisions | time limits | "
              "time [s] |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for control in CONTROLS:
        for driver in ("autopilot", "always_go"):
            rows = run_episodes("crossroad", driver, args.episodes, args.seed, args.workers,
                                task_kwargs={"junction_control": control, "time_limit": args.time_limit})
            ends = [r["end"] for r in rows]
            times = [r["time"] for r in rows if r["end"] == "success"]
            success = 100.0 * ends.count("success") / len(ends)
            lines.append(f"| {control} | {driver} | {success:.0f} | {ends.count('red_light')} | "
                         f"{ends.count('stop_sign')} | {ends.count('collision')} | {ends.count('time_limit')} | "
                         f"{np.mean(times) if times else float('nan'):.1f} |")
            if driver == "autopilot" and control != "give_way":
                bad |= success < 100.0
    publish("\n".join(lines) + "\n", args.out)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
