"""Kinematic traffic on a road map's lane graph: every road user as numpy arrays, no Python loop per user.

One module per behaviour over the shared state of `Traffic` (model.py):
  params.py        road-user kinds, TrafficConfig (validated), EgoState
  lanes.py         the map as flat build-time tables (TrafficMap): polylines, successors, merges, crosswalks
  following.py     IDM over one table of gaps (leaders, corridor, stop lines) with a safety cap
  merges.py        right of way at merges (gap acceptance)
  lane_changes.py  lane changes to same-direction neighbours
  pedestrians.py   kerb waits, crossings, occupied crosswalks
  spawning.py      (re)entry at the map's sources
  geometry.py      smooth lane-change profile, quaternions, box overlaps
  model.py         Traffic: state, decisions, closed-form motion, the MuJoCo binding (mocap poses), queries
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
