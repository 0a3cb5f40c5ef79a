"""`python -m mjdrive.envs.compile_kernels`: compile every numba kernel into the on-disk cache once (`make install`
runs it), so that no env or worker pays the compilation later: the traffic's and the route frame's
(`mjdrive.traffic.compile_kernels`), then the tasks' per-step kernels (ego updates, observations) and the substep
loop (`tasks.stepping`), by stepping a roundabout env (with pedestrians) and the concatenated urban route, and the
scripted drivers' lane kernels on their routes. Prints where the cache is and how long it took."""

from __future__ import annotations

import sys
import time

import numpy as np

from mjdrive import suite
from mjdrive.compiled import INTERPRETED, numba_cache_dir
from mjdrive.traffic import compile_kernels as traffic_kernels

WARM_STEPS = 12  # control steps per env: over two traffic decisions on each


def compile_kernels() -> float:
    """The traffic's kernels, then envs whose observations call the tasks' kernels; the wall time [s] it took
    (compiling, or loading the cache)."""
    start = time.perf_counter()
    traffic_kernels.compile_kernels()
    for domain, task, kwargs in (("roundabout", "d120", {"road_users": {"car": 6, "motorcycle": 1, "pedestrian": 2}}),
                                 ("urban", "concatenated", {})):
        env = suite.load(domain, task, {"random": 0, **kwargs})
        env.reset()
        for _ in range(WARM_STEPS):
            env.step(np.array([0.3, 0.0, 0.0]))
        route = env.task.route_lane  # the scripted drivers' lane kernels
        route.local_coordinates(route.centre[3])
        route.max_abs_curvature(0.0, 20.0)
        route.point(1.0)
        env.close()
    return time.perf_counter() - start


def main() -> int:
    if INTERPRETED:
        print("kernels: MJDRIVE_INTERPRETED is set: the kernels run as Python, nothing to compile")
        return 0
    print(f"kernels: compiling into {numba_cache_dir()} ...", flush=True)
    print(f"kernels: ready in {compile_kernels():.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
