"""Worker processes fork from a forkserver that has loaded what a worker would otherwise import at its first
episode (scipy.signal, numba's registries: a stall of the whole batch there), and nothing that must happen in
the worker itself (a GL display, threads)."""

from __future__ import annotations

import os
import subprocess
import sys

from mjdrive.envs.fanout import fan_out
from mjdrive.envs.vector import FORKSERVER_PRELOAD

PRELOADED = ("scipy.signal", "numba")


def _loaded(names: tuple[str, ...], index: int) -> dict[str, bool]:
    """In a worker, before its job imports anything: which of `names` it has (this module imports none)."""
    return {name: name in sys.modules for name in names}


def test_workers_start_with_scipy_signal_and_numba_loaded():
    assert "mjdrive.envs.preload" in FORKSERVER_PRELOAD
    assert fan_out(_loaded, PRELOADED, [0], workers=1) == {0: dict.fromkeys(PRELOADED, True)}


def test_the_preload_opens_no_gl_display_and_starts_no_thread():
    code = ("import sys, threading; import mjdrive.envs.preload as p; "
            "print(threading.active_count(), sorted(p.preload()), "
            "[m for m in sys.modules if m.split('.')[0] in ('dm_control', 'mujoco', 'OpenGL')])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split("\n")[0] == "1 ['numba', 'scipy.signal'] []"


def test_the_traffic_kernels_keep_their_cache_directory_after_the_preload():
    """numba reads NUMBA_CACHE_DIR at its import: imported by the preload first, it must still find the
    kernels' compiled code where `mjdrive.traffic.following` keeps it (not in the source tree)."""
    code = ("{}import mjdrive.traffic.following as k; from mjdrive.compiled import numba_cache_dir; "
            "from numba.core import config; "
            "print(config.CACHE_DIR, numba_cache_dir(), k.gap_summary._cache._cache_path)")
    env = {key: value for key, value in os.environ.items() if key != "NUMBA_CACHE_DIR"}

    def paths(prefix: str) -> list[str]:
        out = subprocess.run([sys.executable, "-c", code.format(prefix)], capture_output=True, text=True,
                             check=True, env=env).stdout
        return out.split()

    plain, preloaded = paths(""), paths("import mjdrive.envs.preload; ")
    assert preloaded == plain
    assert preloaded[0] == preloaded[1] and preloaded[2].startswith(preloaded[0])
