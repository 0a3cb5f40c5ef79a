"""Study 002's traffic (§5.3) on a composed urban map: urban rules, default road users per map, and spawn
points at the scenarios' critical points (slow vehicles keeping the right lane of the two-lane road, so
that overtaking pays; faster ones in its left lane).

    composed = roads.concatenated()
    traffic = urban_traffic(composed)            # Traffic over the map's conflict zones
"""

from __future__ import annotations

import functools
from collections.abc import Mapping

import numpy as np

from mjdrive.roads.conflicts import conflict_zones
from mjdrive.roads.ports import ComposedMap
from mjdrive.roads.urban import concatenated
from mjdrive.traffic.intentions import KEEP
from mjdrive.traffic.model import Traffic
from mjdrive.traffic.params import TrafficConfig, counts_to_kinds
from mjdrive.traffic.spawning import SpawnPoints

URBAN_CONFIG = TrafficConfig(lane_changes="intention", desired_speed=(5.0, 15.0),  # §5.3: 5-15 m/s
                             spawn_rate=0.2)  # [1/s] arrivals spread out: flows leave gaps
SLOW_SPEED = (4.0, 6.0)  # [m/s] vehicles spawned in the right lane of the two-lane road
FAST_SPEED = (11.0, 15.0)  # [m/s] ... and in its left lane
SPAWN_S = 8.0  # [m] along the lane

# Road users of each registered map at its default parameters: keys are the piece names joined by "+". A single
# piece's row is also its density (road users per metre of its lanes) on any map that holds it.
DEFAULT_COUNTS: dict[str, dict[str, int]] = {
    "roundabout": {"car": 16, "motorcycle": 2},
    "overtaking_road": {"car": 10, "motorcycle": 2},
    "crossroad": {"car": 8, "motorcycle": 2},
    "merge_road": {"car": 10, "motorcycle": 2},
    "roundabout+overtaking_road+crossroad+merge_road": {"car": 26, "motorcycle": 6},
}
CHAIN_SHARE = 0.6  # a chain of pieces carries this share of its pieces' densities (the study's route: 26 of 44 cars)
JUNCTIONS = ("crossroad",)  # pieces whose traffic scales with their roads' length, not their lanes'
PIECE_PARAMS = {"roundabout": "roundabout", "overtaking_road": "road", "crossroad": "crossroad",
                "merge_road": "merge"}  # piece name -> its UrbanMap keyword


def map_key(composed: ComposedMap) -> str:
    """The key of `composed` in DEFAULT_COUNTS (its piece names in order)."""
    return "+".join(piece.name for piece in composed.pieces)


@functools.cache
def _default_lane_length(piece: str) -> float:
    """Total lane length [m] of a piece at its default parameters."""
    return _lane_lengths(concatenated(order=(PIECE_PARAMS[piece],)))[piece]


def _lane_lengths(composed: ComposedMap) -> dict[str, float]:
    """Total lane length [m] of each piece of `composed`, by piece name; a junction's (JUNCTIONS): the length of its
    arms, one lane each way: what a junction carries is set by its conflicts, not by its lanes (at the one-lane
    density, a main road of two lanes each way, or a skewed crossing's longer connectors, would queue the minor
    road for minutes)."""
    out = {piece.name: 0.0 for piece in composed.pieces}
    rm = composed.road_map
    for i, lane in enumerate(rm.lanes):
        prefix = lane.name.partition("/")[0]
        if prefix in JUNCTIONS and (lane.in_junction or rm.right_neighbour[i] is not None):
            continue
        out[prefix] = out.get(prefix, 0.0) + lane.length
    return out


def default_counts(composed: ComposedMap) -> dict[str, int]:
    """Road users by kind at the map's default traffic: the registered maps' rows of DEFAULT_COUNTS; any other
    map (pieces reordered, resized, a chain the table lacks) its pieces' densities times their lane lengths,
    times CHAIN_SHARE for a chain (at least 2 cars)."""
    lengths = _lane_lengths(composed)
    names = [piece.name for piece in composed.pieces]
    if not names or not set(names) <= set(PIECE_PARAMS):  # imported, or pieces built elsewhere: 1 car per 60 m
        return {"car": max(2, int(sum(lengths.values()) / 60.0))}
    scale = {name: lengths[name] / _default_lane_length(name) for name in names}
    key = map_key(composed)
    if key in DEFAULT_COUNTS and all(abs(x - 1.0) < 1e-3 for x in scale.values()):
        return dict(DEFAULT_COUNTS[key])
    share = 1.0 if len(names) == 1 else CHAIN_SHARE
    kinds = sorted({kind for name in names for kind in DEFAULT_COUNTS[name]})
    counts = {kind: int(round(share * sum(DEFAULT_COUNTS[name].get(kind, 0) * scale[name] for name in names)))
              for kind in kinds}
    counts["car"] = max(2, counts.get("car", 0))
    return counts


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


def piece_exits(composed: ComposedMap) -> np.ndarray:
    """The lanes of a chain of pieces that lead into another piece (its borders, both ways): where each piece's
    traffic leaves the map when the pieces keep their own traffic (`urban_traffic(own_traffic=True)`)."""
    if len(composed.pieces) < 2:
        return np.zeros(0, dtype=np.int64)
    rm = composed.road_map
    piece = [lane.name.partition("/")[0] for lane in rm.lanes]
    return np.array([i for i, successors in enumerate(rm.successors) if any(piece[j] != piece[i] for j in successors)],
                    dtype=np.int64)


def urban_traffic(composed: ComposedMap, counts: Mapping[str, int] | None = None,
                  config: TrafficConfig | None = None, own_traffic: bool = True,
                  closed: tuple[int, ...] = ()) -> Traffic:
    """Traffic with urban rules on `composed`: its conflict zones, `counts` road users by kind (default:
    `default_counts`), `config` (default URBAN_CONFIG) and the map's spawn points. own_traffic: on a chain of
    pieces each piece keeps its own traffic (vehicles leave the map where their lane passes into the next piece,
    `piece_exits`, as §5.3 spawns and destroys vehicles at the scenarios' critical points); else they drive on.
    closed: lanes where no vehicle enters (`Traffic`)."""
    kinds = counts_to_kinds(default_counts(composed) if counts is None else dict(counts))
    return Traffic(composed.road_map, kinds, config or URBAN_CONFIG, conflicts=conflict_zones(composed.road_map),
                   spawn_points=spawn_points(composed), exits=piece_exits(composed) if own_traffic else (),
                   closed=closed)
