"""What the worker processes' forkserver loads once, so that every worker forks with it (`vector.FORKSERVER_PRELOAD`).

A worker would otherwise pay these at its first episode, in the middle of a batched step or an evaluation
(measured on the 2-core machine, per worker): scipy.signal ~1 s (`mjdrive.comfort`'s Savitzky-Golay filter, at
the first episode end) and numba's CPU target ~0.8 s (import and typing/target registries, at the first call of
a cached traffic kernel). A stalled worker stalls the whole vector env's step, and each worker stalls at its own
moment, so the stalls add up with the workers. Nothing here opens a GL display or starts a thread (both must
happen in the worker itself, after the fork). Last, the objects loaded so far are frozen out of the garbage
collector (`gc.freeze`): a worker's full collection would otherwise walk all ~400,000 of them (~170 ms, and
its start-up, which imports the tasks, triggers some).
"""

from __future__ import annotations

import gc
import importlib
import importlib.util

from mjdrive.compiled import numba_cache_dir

PRELOADED = ("scipy.signal",)  # imported when installed


def _installed(name: str) -> bool:
    try:
        return importlib.util.find_spec(name) is not None
    except ModuleNotFoundError:  # its parent package is missing
        return False


def warm_numba() -> bool:
    """Import numba (after setting its cache directory, `mjdrive.compiled`) and fill its CPU typing and
    target registries (what loading any cached kernel needs first); False when numba is not installed."""
    if not _installed("numba"):
        return False
    numba_cache_dir()
    from numba.core.registry import cpu_target

    cpu_target.typing_context.refresh()
    cpu_target.target_context.refresh()
    return True


def preload() -> list[str]:
    """Load everything above that is installed; the names of what was loaded."""
    loaded = [name for name in PRELOADED if _installed(name)]
    for name in loaded:
        importlib.import_module(name)
    if warm_numba():
        loaded.append("numba")
    return loaded


preload()
gc.freeze()  # the forkserver's objects live as long as it does: no collector pass needs to visit them
