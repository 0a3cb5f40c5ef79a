"""Urban traffic health: each scenario map and the concatenated map at their default traffic, several
seeds, so many simulated minutes each (traffic alone, no ego); or a map of your own (`--map`: the urban tasks'
`map` keywords as YAML/JSON, or the path of a map file).

    python -m tools.urban_traffic --minutes 10 --seeds 5 --out results/urban/traffic.md
    python -m tools.urban_traffic --map '{order: [crossroad], crossroad: {lane_width: 2.5}}' --seeds 3

Checked at every traffic substep: overlapping road users (oriented boxes). Reported: the longest stop of a
vehicle that is not queued (`Traffic.queued`: within QUEUE_GAP behind a slow leader on its path), the longest
stop of any vehicle, the throughput of every conflict zone (vehicles per minute leaving either of its lanes),
and the traffic update's wall time per simulated second.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.config import parse_value
from mjdrive.roads.conflicts import CROSSING
from mjdrive.roads.ports import ComposedMap
from mjdrive.roads.urban import concatenated
from mjdrive.roads.urban_params import UrbanMap
from mjdrive.traffic import overlapping_pairs
from mjdrive.traffic.model import QUEUE_GAP, STOPPED_SPEED
from mjdrive.traffic.urban import default_counts, urban_traffic
from tools.report import publish

MAPS = {"roundabout": ("roundabout",), "lane_change": ("road",), "crossroad": ("crossroad",),
        "merge": ("merge",), "concatenated": ("roundabout", "road", "crossroad", "merge")}


def run(name: str | UrbanMap | ComposedMap, seed: int, minutes: float, control: str = "give_way") -> dict:
    """One map (a registered map's name, an UrbanMap, or a map already built, e.g. an imported one), one seed, its
    junctions under `control`: overlap substeps, stops, zone throughput, vehicles per minute leaving each lane, cost,
    the traffic's stats (violations among them)."""
    composed = (name if isinstance(name, ComposedMap) else concatenated(order=MAPS[name]) if isinstance(name, str)
                else concatenated(name))
    traffic = urban_traffic(composed)
    traffic.set_junction_control(control, offset=float(seed))
    traffic.reset(np.random.default_rng(seed))
    dt = traffic.config.substep
    zones = traffic.zones
    n_steps = int(round(minutes * 60.0 / dt))
    stopped, excused_free, worst_free, worst_any = np.zeros(traffic.nv), np.zeros(traffic.nv), 0.0, 0.0
    overlap_substeps = 0
    passes = np.zeros(traffic.map.n_lanes, dtype=np.int64)  # vehicles that left each lane
    lane_before = traffic.vehicles.path[:, 0].copy()
    traffic.cpu_time = 0.0
    decision = traffic.n_plan
    for step in range(n_steps):
        traffic.advance(dt)
        present = traffic.present
        if len(overlapping_pairs(traffic.poses()[present], traffic.half_size[present])):
            overlap_substeps += 1
        lane_now = np.where(traffic.vehicles.active, traffic.vehicles.path[:, 0], -1)
        left = (lane_before >= 0) & (lane_now != lane_before)
        np.add.at(passes, lane_before[left], 1)
        lane_before = lane_now
        still = traffic.stopped()
        stopped = np.where(still, stopped + dt, 0.0)
        if step % decision == 0:
            queued = traffic.queued()
        excused_free = np.where(still & ~queued, excused_free + dt, 0.0)
        worst_any, worst_free = max(worst_any, stopped.max()), max(worst_free, excused_free.max())
    throughput = (passes[zones.lane_a] + passes[zones.lane_b]) / minutes  # (Z,) vehicles per minute
    return {"overlaps": overlap_substeps, "stop_free": worst_free, "stop_any": worst_any,
            "throughput": throughput, "lane_throughput": passes / minutes,
            "cost": traffic.cpu_time / (minutes * 60.0), "stats": dict(traffic.stats),
            "zones": zones, "road_map": composed.road_map, "counts": default_counts(composed)}


def map_argument(text: str) -> UrbanMap:
    """`--map`: UrbanMap keywords as YAML/JSON, or a map file's path; argparse's one-line error otherwise."""
    try:
        map_config = UrbanMap.load(parse_value(text), "--map")
        concatenated(map_config)  # pieces that overlap: refused here, not after the first run
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return map_config


def bench(seconds: float = 60.0, control_period: float = 0.1, seed: int = 0) -> str:
    """Traffic's share of a control step on the concatenated map at its default traffic, in a MuJoCo world
    (ego car, road, traffic mocap bodies): physics at the default step and the traffic substeps, without an
    observation or reward, so the share is an upper bound of its share of an env step."""
    from dm_control.mujoco import wrapper

    from mjdrive import world
    from mjdrive.tasks.base import Physics
    from mjdrive.traffic import slots
    from mjdrive.vehicle import Vehicle

    composed = concatenated()
    traffic = urban_traffic(composed)
    model = world.build(composed.road_map, traffic=slots(traffic.kinds))
    physics = Physics.from_model(wrapper.MjModel(model))
    traffic.bind(model)
    ego = Vehicle(model, prefix="ego/")
    start = composed.road_map.lanes[composed.start_lane]
    x, y = start.position(10.0)
    ego.reset(physics.raw_data, float(x), float(y), float(start.heading(10.0)))
    traffic.reset(np.random.default_rng(seed))
    physics.set_substeps(lambda ph, dt: traffic.advance(dt, None, ph.raw_data), traffic.config.substep)
    n_sub = int(round(control_period / physics.timestep()))
    steps = int(round(seconds / control_period))
    traffic.cpu_time = 0.0
    start_wall = time.perf_counter()
    for _ in range(steps):
        ego.apply(physics.raw_data, 0.0, 0.0, 1.0)
        physics.step(n_sub)
    wall = time.perf_counter() - start_wall
    share = traffic.cpu_time / wall
    n = traffic.n
    return (f"traffic on the concatenated map ({n} road users, default traffic): {1e3 * wall / steps:.2f} ms per "
            f"{control_period:g} s control step (physics {physics.timestep() * 1e3:g} ms + traffic), traffic "
            f"{1e3 * traffic.cpu_time / steps:.2f} ms = {100 * share:.1f}% of it; {seconds / wall:.0f} simulated s "
            "per wall s")


def report(results: dict[str, list[dict]], minutes: float, seeds: int) -> str:
    lines = [
        "# Urban traffic at the default density",
        "",
        f"Made by `python -m tools.urban_traffic --minutes {minutes:g} --seeds {seeds}`: each map of study 002 "
        f"alone and concatenated, {minutes:g} simulated minutes per seed, seeds 0-{seeds - 1}, traffic only "
        "(no ego), urban rules (`mjdrive.traffic.urban`).",
        "",
        "- overlaps: traffic substeps (every 0.02 s) in which two road users' boxes overlap;",
        f"- free stop: the longest time a vehicle stood still (< {STOPPED_SPEED} m/s) while not queued "
        f"(`Traffic.queued`: within {QUEUE_GAP:g} m behind a slow leader) (waiting at a give-way line counts);",
        "- any stop: the longest stop of any vehicle, queued or not;",
        "- throughput: vehicles per minute through each conflict zone (leaving either of its lanes), mean over "
        "seeds; min / median / max over the map's zones;",
        "- cost: wall time of the traffic update per simulated second (one core).",
        "",
        "| map | road users | overlaps | free stop max [s] | any stop max [s] | zones | throughput min / median / "
        "max [veh/min] | spawned per min | cost [ms per sim-s] |",
        "| --- | --- | ---: | ---: | ---: | ---: | --- | ---: | ---: |",
    ]
    for name, runs in results.items():
        tp = np.mean([r["throughput"] for r in runs], axis=0)
        counts = ", ".join(f"{n} {k}s" for k, n in runs[0]["counts"].items())
        spawned = np.mean([r["stats"]["spawned"] for r in runs]) / minutes
        tp_text = f"{tp.min():.1f} / {np.median(tp):.1f} / {tp.max():.1f}" if len(tp) else "-"
        lines.append(f"| {name} | {counts} | {sum(r['overlaps'] for r in runs)} | "
                     f"{max(r['stop_free'] for r in runs):.1f} | {max(r['stop_any'] for r in runs):.1f} | {len(tp)} | "
                     f"{tp_text} | {spawned:.1f} | {1e3 * np.mean([r['cost'] for r in runs]):.2f} |")
    for name, runs in results.items():
        zones, rm = runs[0]["zones"], runs[0]["road_map"]
        tp = np.mean([r["throughput"] for r in runs], axis=0)
        lines += ["", f"## {name}: throughput per conflict zone", "",
                  "| zone | kind | lane a | lane b | gives way | veh/min |", "| ---: | --- | --- | --- | --- | ---: |"]
        for z in range(len(zones)):
            who = {0: "a", 1: "b"}.get(int(zones.who_yields[z]), "first come")
            kind = "crossing" if zones.kind[z] == CROSSING else "merge"
            lines.append(f"| {z} | {kind} | {rm.lanes[zones.lane_a[z]].name} | {rm.lanes[zones.lane_b[z]].name} | "
                         f"{who} | {tp[z]:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=positive_float, default=10.0, help="simulated minutes per map and seed")
    parser.add_argument("--seeds", type=int_at_least(1), default=5, help="seeds 0..N-1")
    parser.add_argument("--maps", nargs="*", default=list(MAPS), choices=list(MAPS))
    parser.add_argument("--out", default=None, help="write the markdown report here")
    parser.add_argument("--bench", action="store_true", help="only the traffic cost in a MuJoCo world")
    parser.add_argument("--map", default=None, type=map_argument,
                        help="a map of your own instead of --maps: the urban tasks' map keywords as YAML/JSON, or "
                        "the path of a map file")
    args = parser.parse_args(argv)
    maps: list[str | UrbanMap] = [args.map] if args.map is not None else args.maps
    if args.bench:
        print(bench())
        return 0
    results: dict[str, list[dict]] = {}
    total, done, start = len(maps) * args.seeds, 0, time.perf_counter()
    for chosen in maps:
        name = chosen if isinstance(chosen, str) else "map"
        for seed in range(args.seeds):
            result = run(chosen, seed, args.minutes)
            results.setdefault(name, []).append(result)
            done += 1
            print(f"[{done}/{total}] {name} seed {seed}: overlaps {result['overlaps']}, free stop "
                  f"{result['stop_free']:.1f} s, any stop {result['stop_any']:.1f} s "
                  f"({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)
    text = report(results, args.minutes, args.seeds)
    publish(text, args.out)
    bad = any(r["overlaps"] or r["stop_free"] > 30.0 for runs in results.values() for r in runs)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
