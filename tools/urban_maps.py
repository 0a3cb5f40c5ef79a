"""Maps as data, checked: traffic health (`tools.urban_traffic`) and the privileged autopilot on maps given only
as the urban tasks' `map` keyword: a route in a new order with changed pieces, the same kind of map read from a
file, and a sweep of each piece's parameters over their validated ranges (each piece alone, on its scenario task).

    python -m tools.urban_maps --episodes 100 --minutes 10 --seeds 3 --workers 2 --out results/urban/maps.md

Per map: traffic alone for MINUTES simulated minutes on each of SEEDS seeds (overlapping road users, the longest
stop of a vehicle that is not queued, `Traffic.queued`), then the autopilot on EPISODES episodes (seeds SEED...).
Exit status 1 if a map has an overlap, an unqueued stop over 40 s, or the autopilot under 98%.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from pathlib import Path

import numpy as np

from mjdrive.assets import MAPS_DIR
from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.roads.urban import concatenated
from mjdrive.roads.urban_params import UrbanMap
from tools.report import publish
from tools.urban_table2 import run as run_episodes
from tools.urban_traffic import run as run_traffic

MAP_FILE = "results/urban/maps/merge_first.yaml"  # the committed example map file
REORDERED = {"order": ["crossroad", "roundabout", "road", "merge"], "lane_width": 3.0,
             "roundabout": {"radius": 20.0, "arms": 5, "exit_arm": 4},
             "crossroad": {"crossing_angle": math.radians(70), "turn": "left"},
             "merge": {"main_lanes": 2, "merge_angle": math.radians(45), "slip_radius": 30.0}}
# (label, task, map): each piece alone on its scenario task, one parameter moved to the edges of its range
SWEEP: list[tuple[str, str, dict]] = [
    *[(f"roundabout lane_width {w:g} m", "roundabout", {"lane_width": w}) for w in (3.0, 5.0)],
    ("roundabout 3 arms", "roundabout", {"roundabout": {"arms": 3, "entry_arm": 2, "exit_arm": 1}}),
    ("roundabout 5 arms", "roundabout", {"roundabout": {"arms": 5, "exit_arm": 4}}),
    ("roundabout 8 arms, radius 30 m", "roundabout", {"roundabout": {"arms": 8, "radius": 30.0, "entry_arm": 4}}),
    ("roundabout 1 ring lane", "roundabout", {"roundabout": {"lanes": 1}}),
    ("roundabout 3 ring lanes", "roundabout", {"roundabout": {"lanes": 3, "radius": 20.0}}),
    *[(f"road lane_width {w:g} m", "lane_change", {"lane_width": w}) for w in (2.5, 5.0)],
    ("road 3 lanes, 2 opposite", "lane_change", {"road": {"lanes": 3, "opposite_lanes": 2, "taper_length": 60.0}}),
    *[(f"crossroad lane_width {w:g} m", "crossroad", {"lane_width": w}) for w in (2.5, 3.0, 5.0)],
    *[(f"crossroad angle {a} deg", "crossroad", {"crossroad": {"crossing_angle": math.radians(a)}})
      for a in (50, 130)],
    ("crossroad main road 2 lanes", "crossroad", {"crossroad": {"main_lanes": 2}}),
    ("crossroad minor road 2 lanes", "crossroad", {"crossroad": {"minor_lanes": 2}}),
    *[(f"crossroad turn {turn}", "crossroad", {"crossroad": {"turn": turn}}) for turn in ("left", "right")],
    *[(f"merge lane_width {w:g} m", "merge", {"lane_width": w}) for w in (2.5, 5.0)],
    ("merge angle 20 deg", "merge", {"merge": {"merge_angle": math.radians(20), "slip_radius": 120.0}}),
    ("merge angle 90 deg", "merge", {"merge": {"merge_angle": math.radians(90), "slip_radius": 12.0}}),
    ("merge main road 3 lanes", "merge", {"merge": {"main_lanes": 3}}),
]
SCENARIO_PIECE = {"roundabout": "roundabout", "lane_change": "road", "crossroad": "crossroad", "merge": "merge"}
TIME_LIMIT = {"concatenated": 600.0}  # [s] a route of the same pieces reordered: the registered 400 s and more


def time_limit(task: str, urban_map: UrbanMap) -> float:
    """[s] the autopilot's time limit on a map: the task's registered limit (or TIME_LIMIT's), longer in proportion
    where the map's route is longer than the task's own (a bigger roundabout, longer arms)."""
    from mjdrive import suite
    from mjdrive.roads.urban import route_through
    from mjdrive.tasks.urban import PIECES

    _, defaults = suite.task_config("urban", task)
    limit = TIME_LIMIT.get(task, defaults["time_limit"])
    own = route_through(concatenated(order=PIECES[task])).length
    length = route_through(concatenated(dataclasses.replace(urban_map, order=urban_map.pieces(PIECES[task])))).length
    return limit * max(1.0, length / own)


def maps(sweep: bool) -> list[tuple[str, str, dict | str]]:
    """(label, task, map keyword) of every map the run checks."""
    out: list[tuple[str, str, dict | str]] = [("reordered, changed pieces (keywords)", "concatenated", REORDERED),
                                              (f"map file {MAP_FILE}", "concatenated", MAP_FILE)]
    if sweep:
        out += [(label, task, {"order": [SCENARIO_PIECE[task]], **value}) for label, task, value in SWEEP]
    return out


IMPORTED = ("four_way", "four_way_lights", "multilane", "roundabout")  # the shipped OpenDRIVE maps (urban/opendrive)


def check_map(task: str, value: dict | str) -> UrbanMap:
    """The UrbanMap of one map keyword, built once (a bad map fails here, before any run)."""
    urban_map = UrbanMap.load(value, "map")
    concatenated(urban_map)
    return urban_map


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int_at_least(1), default=100, help="autopilot episodes per map")
    parser.add_argument("--seed", type=int_at_least(0), default=40000, help="seed of the first episode")
    parser.add_argument("--minutes", type=positive_float, default=10.0, help="simulated traffic minutes per seed")
    parser.add_argument("--seeds", type=int_at_least(1), default=3, help="traffic seeds 0..N-1 per map")
    parser.add_argument("--workers", type=int_at_least(0), default=0, metavar="N", help="autopilot episodes' workers")
    parser.add_argument("--no-sweep", action="store_true", help="only the two example maps")
    parser.add_argument("--opendrive", action="store_true", help="instead: the shipped OpenDRIVE maps on "
                        "urban/opendrive (their default route across the map)")
    parser.add_argument("--out", default=None, help="write the markdown report here")
    args = parser.parse_args(argv)
    if args.opendrive:
        publish(imported_report(args), args.out)
        return 0
    chosen = maps(not args.no_sweep)
    built = [check_map(task, value) for _, task, value in chosen]
    lines = [
        "# Maps as data: traffic and the autopilot on maps given as keywords", "",
        f"`python -m tools.urban_maps --episodes {args.episodes} --minutes {args.minutes:g} --seeds {args.seeds}"
        f"{' --no-sweep' if args.no_sweep else ''}`. Each map is only the urban tasks' `map` keyword (the first row's "
        f"is below, the second is the file `{MAP_FILE}`); the sweep moves one parameter of one piece to the edges of "
        "its validated range, that piece alone on its scenario task, everything else at its default.", "",
        f"- traffic: the map's default traffic alone (no ego), {args.minutes:g} simulated minutes on each of seeds "
        f"0-{args.seeds - 1}: substeps with overlapping road users, and the longest stop of a vehicle that is not "
        "queued (`Traffic.queued`; waiting at a give-way line counts);",
        f"- autopilot: the privileged autopilot (`--policy autopilot`) on {args.episodes} episodes, seeds "
        f"{args.seed}-{args.seed + args.episodes - 1}, with the map's default traffic, within the task's time limit "
        "(600 s on the whole route) stretched in proportion to the route's length where the map's is longer; time: "
        "mean over the successful episodes.", "",
        "| map | task | road users | overlaps | free stop max [s] | autopilot success [%] | collisions | time limits "
        "| off route | time [s] |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    bad, start = False, time.perf_counter()
    for k, ((label, task, value), urban_map) in enumerate(zip(chosen, built, strict=True)):
        traffic = [run_traffic(urban_map, seed, args.minutes) for seed in range(args.seeds)]
        overlaps = sum(r["overlaps"] for r in traffic)
        free = max(r["stop_free"] for r in traffic)
        kwargs = {"map": urban_map.to_dict() if isinstance(value, str) else value}
        kwargs["time_limit"] = time_limit(task, urban_map)
        rows = run_episodes(task, "autopilot", args.episodes, args.seed, args.workers, task_kwargs=kwargs)
        ends = [r["end"] for r in rows]
        success = 100.0 * ends.count("success") / len(ends)
        times = [r["time"] for r in rows if r["end"] == "success"]
        counts = ", ".join(f"{n} {kind}s" for kind, n in traffic[0]["counts"].items())
        lines.append(f"| {label} | urban/{task} | {counts} | {overlaps} | {free:.1f} | {success:.0f} | "
                     f"{ends.count('collision')} | {ends.count('time_limit')} | {ends.count('off_route')} | "
                     f"{np.mean(times) if times else float('nan'):.1f} |")
        bad |= overlaps > 0 or free > 40.0 or success < 98.0
        print(f"[{k + 1}/{len(chosen)}] {label}: overlaps {overlaps}, free stop {free:.1f} s, autopilot "
              f"{success:.0f}% ({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)
    lines += ["", "The first row's map, as given to `--task-kwarg map=...` (YAML):", "", "```yaml",
              *_yaml(REORDERED), "```", "", "(angles in radians: crossing_angle 70 deg, merge_angle 45 deg)"]
    publish("\n".join(lines) + "\n", args.out)
    return 1 if bad else 0


def imported_report(args) -> str:
    """Traffic health and the autopilot on the shipped OpenDRIVE maps (`--opendrive`)."""
    from mjdrive.roads.opendrive import read_opendrive
    from mjdrive.roads.ports import ComposedMap

    lines = ["# OpenDRIVE maps: traffic and the autopilot", "",
             f"`python -m tools.urban_maps --opendrive --episodes {args.episodes} --minutes {args.minutes:g} --seeds "
             f"{args.seeds}`. The maps shipped in mjdrive/maps (written by `python -m tools.opendrive_maps`, drawn in "
             "docs/opendrive_maps.png), read by pyxodr into lanes, the lane graph and conflict zones (right of way "
             "from the junctions' priority records: the roundabout's ring over its arms; four_way has none, first "
             "come, first served; four_way_lights has the file's traffic lights, in force as under "
             "`junction_control=map`, the task's default); `urban/opendrive` drives the longest route across "
             f"each with its default traffic (1 car per 60 m of lane). Traffic alone {args.minutes:g} simulated "
             f"minutes on each of seeds 0-{args.seeds - 1}; the autopilot on {args.episodes} episodes (seeds "
             f"{args.seed}-{args.seed + args.episodes - 1}, 300 s limit).", "",
             "| map | lanes | road users | overlaps | red lights / stop signs run | free stop max [s] | autopilot "
             "success [%] | collisions | time limits | time [s] | time max [s] |",
             "| --- | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name in IMPORTED:
        composed = ComposedMap(read_opendrive(MAPS_DIR / f"{name}.xodr"), [])
        traffic = [run_traffic(composed, seed, args.minutes, "map") for seed in range(args.seeds)]
        rows = run_episodes("opendrive", "autopilot", args.episodes, args.seed, args.workers,
                            task_kwargs={"opendrive": name})
        ends = [r["end"] for r in rows]
        times = [r["time"] for r in rows if r["end"] == "success"]
        counts = ", ".join(f"{n} {kind}s" for kind, n in traffic[0]["counts"].items())
        lines.append(f"| {name}.xodr | {len(composed.road_map.lanes)} | {counts} | "
                     f"{sum(r['overlaps'] for r in traffic)} | "
                     f"{sum(r['stats']['red_light_violations'] for r in traffic)} / "
                     f"{sum(r['stats']['stop_sign_violations'] for r in traffic)} | "
                     f"{max(r['stop_free'] for r in traffic):.1f} | "
                     f"{100.0 * ends.count('success') / len(ends):.0f} | {ends.count('collision')} | "
                     f"{ends.count('time_limit')} | {np.mean(times) if times else float('nan'):.1f} | "
                     f"{max(times) if times else float('nan'):.1f} |")
    return "\n".join(lines) + "\n"


def _yaml(value: dict, indent: str = "") -> list[str]:
    """A small map dict as YAML lines (flow lists, nested mappings indented)."""
    out = []
    for key, item in value.items():
        if isinstance(item, dict):
            out += [f"{indent}{key}:", *_yaml(item, indent + "  ")]
        elif isinstance(item, list | tuple):
            out.append(f"{indent}{key}: [{', '.join(str(x) for x in item)}]")
        else:
            out.append(f"{indent}{key}: {item}")
    return out


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
