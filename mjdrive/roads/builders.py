"""Road builders: straight and curved roads, a two-lane road for overtaking, a motorway merge, the crafted
routes of study 004, and spawn points. Junction builders live in `junctions`.

Lane names (k counts from the centre line outward, 0 = next to it):
  straight, curve, two_lane_road: "fwd_k" drive along the reference line (east at the start, on its
      right), "bwd_k" against it; a one-way road has only "fwd_k", centred on the reference line.
  merge: main carriageway "main_k_p" (k = 0 leftmost) in sections p = 0 (before the merge), 1 (beside the
      acceleration lane), 2 (after it); on-ramp "ramp_0" (approach) -> "ramp_1" (acceleration lane, right
      neighbour of the rightmost main lane in section 1; it ends, so drivers change lane left).
  crafted_routes: the pieces of `junction`, `straight` and `curve` prefixed "left_turn/", "straight/",
      "soft_right/", "soft_left/".
"""

from __future__ import annotations

import math

import numpy as np

from mjdrive.roads.geometry import Path
from mjdrive.roads.junctions import junction
from mjdrive.roads.lane import Lane, Marking
from mjdrive.roads.pieces import add_road
from mjdrive.roads.roadmap import RoadMap

CRAFTED_GAP = 300.0  # [m] empty space between the pieces of the crafted-routes map


def _road_map(name: str, path: Path, lanes_per_direction: int, two_way: bool, lane_width: float,
              speed_limit: float, centre_marking: Marking) -> RoadMap:
    rm = RoadMap(name)
    n = lanes_per_direction
    add_road(rm, path, n, n if two_way else 0, "fwd_{k}", "bwd_{k}", lane_width, speed_limit,
             centre_marking=centre_marking, centred=not two_way)
    return rm.freeze()


def straight(
    length: float = 200.0,
    lanes_per_direction: int = 1,
    two_way: bool = True,
    lane_width: float = 3.5,
    speed_limit: float = 30 / 3.6,
    centre_marking: Marking = Marking.SOLID,
) -> RoadMap:
    """Straight road from (0, 0) east to (length, 0) [m]."""
    path = Path((0.0, 0.0), 0.0).line(length)
    return _road_map("straight", path, lanes_per_direction, two_way, lane_width, speed_limit, centre_marking)


def curve(
    radius: float = 60.0,
    angle: float = math.pi / 4,
    direction: str = "left",
    straight_before: float = 30.0,
    straight_after: float = 30.0,
    lanes_per_direction: int = 1,
    two_way: bool = True,
    lane_width: float = 3.5,
    speed_limit: float = 30 / 3.6,
    centre_marking: Marking = Marking.SOLID,
) -> RoadMap:
    """Road from (0, 0) heading east: `straight_before` [m], an arc of `radius` [m] turning `angle` [rad]
    to the `direction` ("left" or "right"), then `straight_after` [m]."""
    if direction not in ("left", "right"):
        raise ValueError(f"direction must be 'left' or 'right', got {direction!r}")
    sign = 1.0 if direction == "left" else -1.0
    path = Path((0.0, 0.0), 0.0).line(straight_before).arc(radius, sign * angle).line(straight_after)
    return _road_map(f"curve_{direction}", path, lanes_per_direction, two_way, lane_width, speed_limit,
                     centre_marking)


def two_lane_road(length: float = 400.0, lane_width: float = 3.5, speed_limit: float = 50 / 3.6) -> RoadMap:
    """Straight two-way road, one lane each way, BROKEN centre line (overtaking in the opposite lane)."""
    rm = straight(length, 1, True, lane_width, speed_limit, centre_marking=Marking.BROKEN)
    rm.name = "two_lane_road"
    return rm


def merge(
    length: float = 300.0,
    lanes: int = 2,
    merge_start: float = 120.0,
    merge_length: float = 80.0,
    ramp_angle: float = math.radians(15),
    ramp_radius: float = 120.0,
    ramp_length: float = 60.0,
    lane_width: float = 3.5,
    speed_limit: float = 80 / 3.6,
) -> RoadMap:
    """One-way main road of `lanes` lanes from (0, 0) east (left edge on y = 0); an on-ramp joins from the
    right at x = merge_start [m] (arriving at `ramp_angle` [rad] through an arc of `ramp_radius` [m])
    and runs as an acceleration lane for `merge_length` [m], where the main road's edge is BROKEN."""
    w = lane_width
    if not 0 < merge_start < merge_start + merge_length < length:
        raise ValueError("need 0 < merge_start < merge_start + merge_length < length")
    rm = RoadMap("merge")
    cuts = [0.0, merge_start, merge_start + merge_length, length]
    sections = []
    for p in range(3):
        path = Path((cuts[p], 0.0), 0.0).line(cuts[p + 1] - cuts[p])
        fwd, _ = add_road(rm, path, lanes, 0, f"main_{{k}}_{p}", "", w, speed_limit)
        sections.append(fwd)
    for p in range(2):
        for a, b in zip(sections[p], sections[p + 1], strict=True):
            rm.connect(a, b)
    rm.lanes[sections[1][-1]].right_marking = Marking.BROKEN
    y = -(lanes + 0.5) * w
    back = Path((merge_start, y), math.pi).arc(ramp_radius, ramp_angle).line(ramp_length)  # ramp, reversed
    ramp0 = _single_lane(rm, back.sample()[::-1], "ramp_0", w, speed_limit, Marking.SOLID)
    ramp1 = _single_lane(rm, Path((merge_start, y), 0.0).line(merge_length).sample(), "ramp_1", w,
                         speed_limit, Marking.BROKEN)
    rm.connect(ramp0, ramp1)
    rm.set_neighbours(sections[1][-1], ramp1)
    return rm.freeze()


def _single_lane(rm: RoadMap, pts: np.ndarray, name: str, width: float, speed_limit: float,
                 left: Marking) -> int:
    return rm.add_lane(Lane(pts, width, left, Marking.SOLID, speed_limit, name))


def crafted_routes() -> tuple[RoadMap, dict[str, list[int]]]:
    """Study 004's four routes on one map, as disjoint pieces CRAFTED_GAP [m] apart along x:
    "left_turn" (sharp left in a four-way junction), "straight" (a 110 m one-lane road, SOLID both
    sides), "soft_right" and "soft_left" (45 deg arcs of 60 m radius within a lane of a two-way road)."""
    pieces = {
        "left_turn": (junction(arm_length=60.0), ["S_in_0", "S->W_0", "W_out_0"]),
        "straight": (straight(length=110.0, two_way=False), ["fwd_0"]),
        "soft_right": (curve(60.0, math.pi / 4, "right"), ["fwd_0"]),
        "soft_left": (curve(60.0, math.pi / 4, "left"), ["fwd_0"]),
    }
    rm = RoadMap("crafted_routes")
    routes, x = {}, 0.0
    for key, (piece, names) in pieces.items():
        x0, y0, x1, y1 = piece.bounds()
        rm.add_map(piece, offset=(x - x0, -(y0 + y1) / 2), prefix=f"{key}/")
        routes[key] = [rm.lane_id(f"{key}/{name}") for name in names]
        x += x1 - x0 + CRAFTED_GAP
    return rm.freeze(), routes


def spawn_points(rm: RoadMap, spacing: float = 10.0, margin: float = 5.0) -> list[tuple[int, float]]:
    """Start places (lane id, s [m]) every `spacing` [m] on lanes outside junctions, `margin` [m] from
    the lane ends."""
    out = []
    for i, lane in enumerate(rm.lanes):
        if lane.in_junction or lane.length < 2 * margin:
            continue
        out.extend((i, float(s)) for s in np.arange(margin, lane.length - margin + 1e-9, spacing))
    return out
