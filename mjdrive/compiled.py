"""Compiled code with numba: the decorators that compile mjdrive's kernels, where numba keeps the compiled code,
and the debug switch that runs the same functions interpreted.

A kernel is the one implementation of its rule (there is no numpy twin). `jit` compiles it (cached on disk);
the compiled function keeps the Python source as `.py_func`. With MJDRIVE_INTERPRETED=1 in the environment
(read once, at import) `jit` and `inline` return the functions undecorated: every kernel then runs as plain
Python, with the same numbers (`tests/test_trajectory_hash.py` checks a short run's hash), slowly, and a
debugger steps through it line by line.

numba reads NUMBA_CACHE_DIR once, when it is imported: it is set here (`numba_cache_dir`) before numba is
imported, by this module or by the worker processes' preload (`mjdrive.envs.preload`), so that every process
looks for the compiled kernels in the same place. Without it numba would look beside the sources (unwritable in
a site install) and compile them again in every process.
"""

from __future__ import annotations

import hashlib
import os
import sys
from collections.abc import Callable
from pathlib import Path


def source_digest() -> str:
    """A digest of the package's Python sources. numba invalidates a cached kernel when its own module changes, not
    when a helper it inlines from another module does; a cache directory per source digest never serves a kernel
    compiled from older code (an edit costs one recompilation)."""
    digest = hashlib.sha1()
    for path in sorted(Path(__file__).resolve().parent.rglob("*.py")):
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def numba_cache_dir() -> Path:
    """NUMBA_CACHE_DIR, set to ~/.cache/mjdrive/numba/SOURCE_DIGEST (under XDG_CACHE_HOME where set) unless already
    set."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "mjdrive" / "numba" / source_digest()
    return Path(os.environ.setdefault("NUMBA_CACHE_DIR", str(default)))


numba_cache_dir()  # before numba's import
from numba import njit  # noqa: E402  (after its cache directory is set)

INTERPRETED = os.environ.get("MJDRIVE_INTERPRETED", "") not in ("", "0")  # the debug switch: kernels as Python


# numpy's error model: a float division by zero gives inf or nan (as numpy's arithmetic does) instead of raising;
# without the raise paths numba drops the reference counting of arrays read from NamedTuples inside loops (with them,
# a zone's rules took three times as long). A division by zero is a bug in any kernel here either way.
OPTIONS = {"cache": True, "nogil": True, "error_model": "numpy"}


def jit(fn: Callable) -> Callable:
    """Compile `fn` (cached on disk; releases the GIL); interpreted: `fn` itself."""
    return fn if INTERPRETED else njit(**OPTIONS)(fn)


def inline(fn: Callable) -> Callable:
    """A helper of kernels, inlined into them (no call, no reference counting of its array arguments); interpreted:
    `fn` itself."""
    return fn if INTERPRETED else njit(inline="always", **OPTIONS)(fn)


def helper(fn: Callable) -> Callable:
    """A large part of a kernel, compiled on its own and called from it (not inlined: an inlined copy of every large
    part would make one function that LLVM optimises for minutes); interpreted: `fn` itself."""
    if INTERPRETED:
        return fn
    compiled = njit(**OPTIONS)(fn)
    HELPERS.add(compiled)
    return compiled


HELPERS: set = set()  # the `helper`s (kernels call them; Python does not)


@helper
def maximum(a: float, b: float) -> float:
    """np.maximum of two floats (NaN wins), for kernels."""
    if a != a or a >= b:
        return a
    return b


@helper
def minimum(a: float, b: float) -> float:
    """np.minimum of two floats (NaN wins), for kernels."""
    if a != a or a <= b:
        return a
    return b


def announce_compilation() -> None:
    """Say on stderr, once per process, that the kernels are being compiled when the cache holds none yet (the
    first env on a machine would otherwise wait some seconds in silence)."""
    global _announced
    if _announced or INTERPRETED:
        return
    _announced = True
    if not any(numba_cache_dir().rglob("*.nbi")):
        print(f"mjdrive: compiling the kernels once for this machine (about 35 s; cache {numba_cache_dir()})",
              file=sys.stderr, flush=True)


_announced = False
