"""Where numba keeps mjdrive's compiled code (the traffic kernels, `mjdrive.traffic.kernels`).

numba reads NUMBA_CACHE_DIR once, when it is imported: whoever imports numba first (the kernels, or the worker
processes' preload, `mjdrive.envs.preload`) sets it here beforehand, so that every process looks for the
compiled kernels in the same place. Without it numba would look beside the sources (unwritable in a site
install) and compile them again (~10 s) in every process.
"""

from __future__ import annotations

import os
from pathlib import Path


def numba_cache_dir() -> Path:
    """NUMBA_CACHE_DIR, set to ~/.cache/mjdrive/numba (under XDG_CACHE_HOME where set) unless already set."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "mjdrive" / "numba"
    return Path(os.environ.setdefault("NUMBA_CACHE_DIR", str(default)))
