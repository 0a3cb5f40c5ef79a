"""Kinematic traffic on a road map's lane graph: every road user as arrays, no Python loop per user.

One module per behaviour, each holding its own compiled kernels (numba; `mjdrive.compiled`), over state passed
as named structures of arrays (state.py); docs/layout.md says what each reads and writes:
  params.py        road-user kinds, TrafficConfig (validated) and its Constants, EgoState
  state.py         Vehicles, Pedestrians, Poses, Agents, Followers, Obstacles; where agents are on the lane graph
  lanes.py         the map as flat build-time tables (TrafficMap): polylines, successors, merges, crosswalks
  intentions.py    intentions by scenario, lane roles, the choice of successors that honours them
  motion.py        closed-form motion over a decision period: plans of poses, commits, lanes passed
  following.py     IDM against the most constraining obstacle (leaders, corridor, stop lines) with a safety cap
  conflicts.py     right of way at conflict zones (urban rules)
  merges.py        right of way at roundabout merges (gap acceptance)
  lane_changes.py  lane changes to same-direction neighbours
  pedestrians.py   kerb waits, crossings, occupied crosswalks
  spawning.py      (re)entry at the map's sources and spawn points
  geometry.py      smooth lane-change profile, box overlaps
  model.py         Traffic: owns the state, orchestrates a decision, the MuJoCo binding (mocap poses), queries
"""

from mjdrive.traffic.geometry import overlapping_pairs
from mjdrive.traffic.lanes import TrafficMap
from mjdrive.traffic.model import Traffic
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
    "KIND_INDEX", "KIND_NAMES", "ROAD_USER_TYPES", "EgoState", "RoadUserType", "Traffic", "TrafficConfig",
    "TrafficMap", "counts_to_kinds", "overlapping_pairs", "slots",
]
