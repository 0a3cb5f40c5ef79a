"""Kinematic traffic on a road map's lane graph: every road user as arrays, no Python loop per user.

One module per behaviour, each holding its own compiled kernels (numba; `mjdrive.compiled`), over state passed as
named structures of arrays (state.py); `Traffic` (model.py) owns the state and orchestrates. docs/layout.md says
what each module reads and writes.
"""

from mjdrive.traffic.geometry import overlapping_pairs
from mjdrive.traffic.lanes import TrafficMap
from mjdrive.traffic.model import GiveWay, Traffic
from mjdrive.traffic.params import (
    KIND_INDEX,
    KIND_NAMES,
    ROAD_USER_TYPES,
    EgoState,
    RoadUserType,
    TrafficConfig,
    counts_to_kinds,
    slots,
)

__all__ = [
    "KIND_INDEX", "KIND_NAMES", "ROAD_USER_TYPES", "EgoState", "GiveWay", "RoadUserType", "Traffic", "TrafficConfig",
    "TrafficMap", "counts_to_kinds", "overlapping_pairs", "slots",
]
