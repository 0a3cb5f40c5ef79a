"""Compile the traffic's kernels and the route frame's into the on-disk cache, by running a route frame and a few
decisions of roundabout and urban traffic; `python -m mjdrive.envs.compile_kernels` (which `make install` runs)
calls it, then compiles the tasks' kernels."""

from __future__ import annotations

import sys
import time

import numpy as np

from mjdrive import roads
from mjdrive.roads.lane import Lane
from mjdrive.roads.route_frame import RouteFrame
from mjdrive.traffic import conflicts, following, intentions, lane_changes, lanes, merges, motion, pedestrians, spawning
from mjdrive.traffic import state as traffic_state
from mjdrive.traffic.model import Traffic
from mjdrive.traffic.params import counts_to_kinds
from mjdrive.traffic.urban import urban_traffic

MODULES = (traffic_state, lanes, intentions, motion, following, conflicts, merges, lane_changes, pedestrians,
           spawning)


def compile_kernels() -> float:
    """Run every kernel: a route frame's projection, and real traffic (the roundabout with pedestrians, the
    concatenated urban map, each half full so that spawns are checked); the wall time [s] it took (the
    compilation, or loading it from the cache)."""
    start = time.perf_counter()
    rm = roads.roundabout()
    route = next(iter(roads.roundabout_routes(rm).values()))
    frame = RouteFrame(Lane(rm.route_polyline(route), name="route"))
    frame(np.zeros((5, 2)), full=True)
    frame.point(0.0, 0.0)
    for traffic in (Traffic(rm, counts_to_kinds({"car": 6, "motorcycle": 1, "pedestrian": 2})),
                    urban_traffic(roads.concatenated())):
        traffic.reset(np.random.default_rng(0), density=0.5)
        for _ in range(3):
            traffic.advance(traffic.config.decision_period)
    return time.perf_counter() - start


def uncompiled() -> list[str]:
    """The traffic's kernels this process has not compiled (or loaded) yet: none after `compile_kernels`."""
    return [f"{module.__name__}.{name}" for module in MODULES for name, fn in vars(module).items()
            if hasattr(fn, "signatures") and fn.py_func.__module__ == module.__name__ and not fn.signatures
            and not getattr(fn, "targetoptions", {}).get("inline") == "always"]


if __name__ == "__main__":
    print(f"{compile_kernels():.1f} s; not compiled: {uncompiled() or 'none'}")
    sys.exit(0)
