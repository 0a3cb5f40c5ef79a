"""Building blocks of the map builders: multi-lane roads along a reference path, junction connectors and
junction boxes.

Lane index k counts from the road's centre line outward (k = 0 is next to the centre line, the largest k
is at the road edge), for both directions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from mjdrive.roads.geometry import Path, fillet, left_normal, unit, wrap_angle
from mjdrive.roads.lane import Lane, Marking
from mjdrive.roads.roadmap import RoadMap

STRAIGHT_TOLERANCE = 0.35  # [rad] turns smaller than this are "straight on" in a junction


def add_road(
    rm: RoadMap,
    path: Path,
    n_fwd: int,
    n_bwd: int,
    fwd_name: str,
    bwd_name: str,
    width: float = 3.5,
    speed_limit: float = 30 / 3.6,
    centre_marking: Marking = Marking.SOLID,
    edge_marking: Marking = Marking.SOLID,
    lane_marking: Marking = Marking.BROKEN,
    centred: bool = False,
) -> tuple[list[int], list[int]]:
    """Add lanes along `path`: n_fwd in its direction (on its right), n_bwd against it (on its left).

    Names are format strings with a `{k}` field. The path is the line between the two directions, or the
    road's middle if `centred`. Returns (forward lane ids, backward lane ids), both ordered by k.
    """
    shift = (n_fwd - n_bwd) * width / 2 if centred else 0.0
    ids: list[list[int]] = []
    for n, other, sign, fmt in ((n_fwd, n_bwd, -1.0, fwd_name), (n_bwd, n_fwd, 1.0, bwd_name)):
        lanes = []
        for k in range(n):
            left = (centre_marking if other else edge_marking) if k == 0 else lane_marking
            right = edge_marking if k == n - 1 else lane_marking
            pts = path.sample(shift + sign * (k + 0.5) * width)
            lane = Lane(pts if sign < 0 else pts[::-1], width, left, right, speed_limit, fmt.format(k=k))
            lanes.append(rm.add_lane(lane))
        for k in range(1, n):
            rm.set_neighbours(lanes[k - 1], lanes[k])
        ids.append(lanes)
    return ids[0], ids[1]


@dataclass
class Arm:
    """A road meeting a junction: name, direction [rad] from the junction out along the road, inbound
    lane ids (arriving, ordered by k) and outbound lane ids (leaving)."""

    name: str
    angle: float
    inbound: list[int]
    outbound: list[int]


def connector(rm: RoadMap, src: int, dst: int, name: str, speed_limit: float | None = None) -> int:
    """Add an unmarked junction lane from the end of lane `src` to the start of lane `dst` (line or
    line-arc-line fillet), connected to both. Returns its id."""
    a, b = rm.lanes[src], rm.lanes[dst]
    start, end = a.centre[-1], b.centre[0]
    pts = fillet(start, a.vertex_heading[-1], end, b.vertex_heading[0]).sample()
    pts[0], pts[-1] = start, end
    limit = min(a.speed_limit, b.speed_limit) if speed_limit is None else speed_limit
    idx = rm.add_lane(Lane(pts, a.width, Marking.NONE, Marking.NONE, limit, name, in_junction=True))
    rm.connect(src, idx)
    rm.connect(idx, dst)
    return idx


def add_connectors(rm: RoadMap, arms: list[Arm], prefix: str = "") -> list[int]:
    """Connectors "{prefix}{from}->{to}_{k}" between every pair of arms (no U-turns): straight on from every
    inbound lane k to outbound lane k, left turns from the leftmost inbound lane (k = 0) to the leftmost
    outbound lane, right turns from the rightmost inbound lane to the rightmost outbound lane."""
    ids = []
    for a in arms:
        for b in arms:
            if a is b:
                continue
            turn = float(wrap_angle(b.angle - a.angle - math.pi))  # > 0 left
            if abs(turn) < STRAIGHT_TOLERANCE:
                pairs = [(k, k) for k in range(min(len(a.inbound), len(b.outbound)))]
            elif turn > 0:
                pairs = [(0, 0)]
            else:
                pairs = [(len(a.inbound) - 1, len(b.outbound) - 1)]
            for ki, ko in pairs:
                ids.append(connector(rm, a.inbound[ki], b.outbound[ko], f"{prefix}{a.name}->{b.name}_{ki}"))
    return ids


def junction_box(centre: ArrayLike, half_size: float, road_half_width: float,
                 arm_angles: list[float]) -> np.ndarray:
    """Convex paved polygon of an axis-aligned junction: for each compass direction with an arm, the
    arm's mouth at `half_size` [m] from the centre; without one, the crossing road's edge."""
    c = np.asarray(centre, dtype=float)
    pts = []
    for theta in (0.0, math.pi / 2, math.pi, -math.pi / 2):
        present = any(abs(float(wrap_angle(theta - a))) < 1e-6 for a in arm_angles)
        reach = half_size if present else road_half_width
        for lateral in (-road_half_width, road_half_width):
            pts.append(c + reach * unit(theta) + lateral * left_normal(theta))
    poly = [pts[0]]
    for p in pts[1:]:
        if np.hypot(*(p - poly[-1])) > 1e-9 and np.hypot(*(p - poly[0])) > 1e-9:
            poly.append(p)
    return np.array(poly)
