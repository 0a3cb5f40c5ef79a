"""Study 002's traffic (§5.3) on a composed urban map: urban rules, default road users per map, and spawn
points at the scenarios' critical points (slow vehicles keeping the right lane of the two-lane road, so
that overtaking pays; faster ones in its left lane).

    composed = roads.concatenated()
    traffic = urban_traffic(composed)            # Traffic over the map's conflict zones
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from mjdrive.roads.conflicts import conflict_zones
from mjdrive.roads.ports import ComposedMap
from mjdrive.traffic.intentions import KEEP
from mjdrive.traffic.model import Traffic
from mjdrive.traffic.params import TrafficConfig, counts_to_kinds
from mjdrive.traffic.spawning import SpawnPoints

URBAN_CONFIG = TrafficConfig(lane_changes="intention", desired_speed=(5.0, 15.0),  # §5.3: 5-15 m/s
                             spawn_rate=0.2)  # [1/s] arrivals spread out: flows leave gaps
SLOW_SPEED = (4.0, 6.0)  # [m/s] vehicles spawned in the right lane of the two-lane road
FAST_SPEED = (11.0, 15.0)  # [m/s] ... and in its left lane
SPAWN_S = 8.0  # [m] along the lane

# Road users of each map at its default traffic: keys are the composed map's piece names joined by "+".
DEFAULT_COUNTS: dict[str, dict[str, int]] = {
    "roundabout": {"car": 16, "motorcycle": 2},
    "overtaking_road": {"car": 10, "motorcycle": 2},
    "crossroad": {"car": 8, "motorcycle": 2},
    "merge_road": {"car": 10, "motorcycle": 2},
    "roundabout+overtaking_road+crossroad+merge_road": {"car": 26, "motorcycle": 6},
}


def map_key(composed: ComposedMap) -> str:
    """The key of `composed` in DEFAULT_COUNTS (its piece names in order)."""
    return "+".join(piece.name for piece in composed.pieces)


def default_counts(composed: ComposedMap) -> dict[str, int]:
    """Road users by kind at the map's default traffic (two per 100 m of lane for an unknown chain)."""
    key = map_key(composed)
    if key in DEFAULT_COUNTS:
        return dict(DEFAULT_COUNTS[key])
    lane_length = sum(lane.length for lane in composed.road_map.lanes)
    return {"car": max(2, int(lane_length / 50.0))}


def spawn_points(composed: ComposedMap) -> SpawnPoints:
    """The scenarios' critical points: the start of each two-lane road's lanes (slow vehicles that keep the
    right lane, fast ones on the left)."""
    rows = []
    for i, lane in enumerate(composed.road_map.lanes):
        piece, _, name = lane.name.partition("/")
        if piece.startswith("overtaking_road") and name.startswith("main_"):
            right = composed.road_map.right_neighbour[i] is None
            rows.append((i, SPAWN_S, *(SLOW_SPEED if right else FAST_SPEED), KEEP if right else -1))
    table = np.array(rows, dtype=float).reshape(-1, 5)
    return SpawnPoints(table[:, 0].astype(np.int64), table[:, 1], table[:, 2:4], table[:, 4].astype(np.int64))


def urban_traffic(composed: ComposedMap, counts: Mapping[str, int] | None = None,
                  config: TrafficConfig | None = None) -> Traffic:
    """Traffic with urban rules on `composed`: its conflict zones, `counts` road users by kind (default:
    `default_counts`), `config` (default URBAN_CONFIG) and the map's spawn points."""
    kinds = counts_to_kinds(default_counts(composed) if counts is None else dict(counts))
    return Traffic(composed.road_map, kinds, config or URBAN_CONFIG, conflicts=conflict_zones(composed.road_map),
                   spawn_points=spawn_points(composed))
