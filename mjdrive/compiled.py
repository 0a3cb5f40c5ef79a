"""Compiled kernels with numba (the `fast` extra): where numba keeps compiled code, whether kernels are on, and
the decorators that compile them.

numba reads NUMBA_CACHE_DIR once, when it is imported: it is set here (`numba_cache_dir`) before numba is
imported, by this module or by the worker processes' preload (`mjdrive.envs.preload`), so that every process
looks for the compiled kernels in the same place. Without it numba would look beside the sources (unwritable in
a site install) and compile them again (~20 s) in every process.

A kernel repeats numpy code operation for operation and is checked against it bit for bit; without numba
(`KERNELS` False: not installed, or MJDRIVE_NO_KERNELS=1) the numpy code runs, and the decorators leave the
kernels as plain Python (which the tests still compare with the numpy code).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path


def numba_cache_dir() -> Path:
    """NUMBA_CACHE_DIR, set to ~/.cache/mjdrive/numba (under XDG_CACHE_HOME where set) unless already set."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "mjdrive" / "numba"
    return Path(os.environ.setdefault("NUMBA_CACHE_DIR", str(default)))


numba_cache_dir()  # before numba's import
try:
    from numba import njit
except ImportError:  # the numpy code runs instead
    KERNELS = False
else:
    KERNELS = os.environ.get("MJDRIVE_NO_KERNELS", "") in ("", "0")


def jit(fn: Callable) -> Callable:
    """Compile `fn` (cached on disk) when kernels are on; else leave it as Python."""
    return njit(cache=True, nogil=True)(fn) if KERNELS else fn


def inline(fn: Callable) -> Callable:
    """A helper of kernels, inlined into them (no call, no reference counting of its array arguments)."""
    return njit(inline="always", cache=True, nogil=True)(fn) if KERNELS else fn


def announce_compilation() -> None:
    """Say on stderr, once per process, that the kernels are being compiled when the cache holds none yet (the
    first env on a machine would otherwise wait some seconds in silence)."""
    global _announced
    if _announced or not KERNELS:
        return
    _announced = True
    if not any(numba_cache_dir().rglob("*.nbi")):
        print(f"mjdrive: compiling the kernels once for this machine (about 20 s; cache {numba_cache_dir()})",
              file=sys.stderr, flush=True)


_announced = False
