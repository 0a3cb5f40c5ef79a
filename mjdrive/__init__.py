"""mjdrive: driving-simulation suite for RL research on MuJoCo."""

from __future__ import annotations

import os as _os

# Off-screen rendering needs a GL backend chosen before mujoco is imported; EGL is the default
# on headless machines, OSMesa the fallback (set MUJOCO_GL=osmesa yourself to force it).
_os.environ.setdefault("MUJOCO_GL", "egl")
# Software GL (llvmpipe) renders small observation images best on one thread: its worker threads would
# otherwise wake up after every physics step and compete with it (and with other envs) for the cores.
_os.environ.setdefault("LP_NUM_THREADS", "1")

from mjdrive.assets import XML_DIR as XML_DIR  # noqa: E402  (MJCF assets: vehicles/, scenes/)
from mjdrive.config import ConfigError as ConfigError  # noqa: E402  (a ValueError: bad keyword, name or value)

# Register the gymnasium ids (cheap: entry points are strings, nothing heavy is imported here).
from mjdrive.envs.registration import register_all as _register_all  # noqa: E402
from mjdrive.version import __version__ as __version__  # noqa: E402

_register_all()
