"""`python -m mjdrive.envs.compile_kernels`: compile every numba kernel into the on-disk cache once (`make install`
runs it), so that no env or worker pays the compilation later: by stepping a roundabout env (with pedestrians) and
the concatenated urban route (the traffic's kernels, the tasks' ego updates and observations, the substep loop),
querying a leader and the queues, a decision env (the operative level's MPC check, the ego's give-way query), and
the scripted drivers' lane kernels on their routes. Prints where the cache is and how long it took; `uncompiled()`
names the kernels a process has not compiled or loaded yet."""

from __future__ import annotations

import sys
import time

import numpy as np

from mjdrive import suite, vehicle
from mjdrive.compiled import HELPERS, INTERPRETED, numba_cache_dir
from mjdrive.control import mpc
from mjdrive.roads import _spatial, lane, route_frame
from mjdrive.tasks import kernels, stepping
from mjdrive.traffic import (
    conflicts,
    following,
    intentions,
    lane_changes,
    lanes,
    merges,
    motion,
    pedestrians,
    spawning,
    state,
)

WARM_STEPS = 12  # control steps per env: over two traffic decisions on each
MODULES = (state, lanes, intentions, motion, following, conflicts, merges, lane_changes, pedestrians, spawning,
           kernels, stepping, lane, route_frame, _spatial, vehicle, mpc)  # those that hold kernels


def compile_kernels() -> float:
    """Run every kernel; the wall time [s] it took (compiling, or loading the cache)."""
    start = time.perf_counter()
    for domain, task, kwargs in (("roundabout", "d120", {"road_users": {"car": 6, "motorcycle": 1, "pedestrian": 2}}),
                                 ("urban", "concatenated", {}), ("urban", "crossroad", {"decisions": True})):
        env = suite.load(domain, task, {"random": 0, **kwargs})
        env.reset()
        action = 0 if kwargs.get("decisions") else np.array([0.3, 0.0, 0.0])
        for _ in range(WARM_STEPS):
            env.step(action)
        traffic, route = env.task.traffic, env.task.route_lane
        traffic.leader(traffic.vehicles.path[0], 0.0)
        traffic.queued()
        if domain == "urban":
            env.task.relevant_point()
            traffic.give_way(env.task.ego_state(env.physics))
        route.local_coordinates(route.centre[3])  # the scripted drivers' lane kernels
        route.max_abs_curvature(0.0, 20.0)
        route.point(1.0)
        env.close()
    mpc.Leader(10.0, 5.0, -1.0).positions(np.linspace(0.0, 2.0, 3))  # a leader's predicted rear, as the tests read it
    return time.perf_counter() - start


def uncompiled() -> list[str]:
    """The kernels (called from Python; not the helpers inlined into others or called by them) this process has not
    compiled or loaded yet: none after `compile_kernels`."""
    return [f"{module.__name__}.{name}" for module in MODULES for name, fn in vars(module).items()
            if hasattr(fn, "signatures") and fn.py_func.__module__ == module.__name__ and not fn.signatures
            and fn.targetoptions.get("inline") != "always" and fn not in HELPERS]


def main() -> int:
    if INTERPRETED:
        print("kernels: MJDRIVE_INTERPRETED is set: the kernels run as Python, nothing to compile")
        return 0
    print(f"kernels: compiling into {numba_cache_dir()} ...", flush=True)
    print(f"kernels: ready in {compile_kernels():.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
