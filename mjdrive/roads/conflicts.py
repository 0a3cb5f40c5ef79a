"""Conflict zones of a road map: where two lanes cross or merge, and who yields (pure numpy, built once).

A zone is a row (lane_a, s_a_in, s_a_out, lane_b, s_b_in, s_b_out, who_yields, kind): on lane a the
stretch [s_a_in, s_a_out] [m] of centre line along which a's lane strip overlaps b's (likewise on b).
`kind` is CROSSING (the centre lines cross) or MERGE (the lanes share a successor; the zone runs to both
lane ends). `who_yields` compares `Lane.priority`: YIELD_A (lane a ranks lower), YIELD_B, or TIE (equal
ranks: first come, first served). Rows have lane_a < lane_b. `point` is where the centre lines cross, or
the merge point (the start of the shared successor), at s_a_point / s_b_point along the two lanes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mjdrive.roads.lane import Lane
from mjdrive.roads.roadmap import RoadMap

CROSSING, MERGE = 0, 1  # kind
YIELD_A, YIELD_B, TIE = 0, 1, -1  # who_yields
SAMPLE_STEP = 0.1  # [m] resolution of the zone limits
ZONE_WINDOW = 80.0  # [m] a zone's limits are searched this far from its point along each lane
OVERLAP_TOLERANCE = 0.05  # [m] lane strips closer than their half widths by less than this do not overlap
END_TOLERANCE = 1e-3  # [m] centre lines touching at an end of both lanes (a fork or a join) do not cross
CLUSTER = 1.0  # [m] crossings of one lane pair closer than this along lane a are one crossing


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class RouteConflicts:
    """Zones on a route, ordered by `s_in`: positions are arc lengths [m] along the route polyline."""

    zone: np.ndarray  # (K,) row of the map's ConflictZones
    s_in: np.ndarray  # (K,) [m]
    s_out: np.ndarray  # (K,) [m]
    s_point: np.ndarray  # (K,) [m] the crossing / merge point
    route_lane: np.ndarray  # (K,) the route's lane in the zone
    other_lane: np.ndarray  # (K,) the lane it conflicts with
    ego_yields: np.ndarray  # (K,) bool: the route's lane ranks lower
    kind: np.ndarray  # (K,) CROSSING or MERGE

    def __len__(self) -> int:
        return len(self.zone)


@dataclass(frozen=True)
class ConflictZones:
    """Conflict-zone table of one map (see the module docstring); arrays are read-only, one row per zone."""

    lane_a: np.ndarray  # (K,) int
    s_a_in: np.ndarray  # (K,) [m]
    s_a_out: np.ndarray  # (K,) [m]
    lane_b: np.ndarray  # (K,) int
    s_b_in: np.ndarray  # (K,) [m]
    s_b_out: np.ndarray  # (K,) [m]
    who_yields: np.ndarray  # (K,) YIELD_A, YIELD_B or TIE
    kind: np.ndarray  # (K,) CROSSING or MERGE
    point: np.ndarray  # (K, 2) [m]
    s_a_point: np.ndarray  # (K,) [m]
    s_b_point: np.ndarray  # (K,) [m]

    def __post_init__(self) -> None:
        for name in self.__dataclass_fields__:
            object.__setattr__(self, name, _readonly(getattr(self, name)))

    def __len__(self) -> int:
        return len(self.lane_a)

    @property
    def yielding_lane(self) -> np.ndarray:
        """(K,) the lane that yields in each zone (-1 on a tie)."""
        return np.select([self.who_yields == YIELD_A, self.who_yields == YIELD_B], [self.lane_a, self.lane_b], -1)

    @property
    def priority_lane(self) -> np.ndarray:
        """(K,) the lane that goes first in each zone (-1 on a tie)."""
        return np.select([self.who_yields == YIELD_A, self.who_yields == YIELD_B], [self.lane_b, self.lane_a], -1)

    def involving(self, lane: int) -> np.ndarray:
        """Rows (indices) of the zones on `lane`."""
        return np.flatnonzero((self.lane_a == lane) | (self.lane_b == lane))

    def between(self, a: int, b: int) -> np.ndarray:
        """Rows of the zones between lanes `a` and `b` (either order)."""
        lo, hi = min(a, b), max(a, b)
        return np.flatnonzero((self.lane_a == lo) & (self.lane_b == hi))

    def on_route(self, road_map: RoadMap, route: Sequence[int]) -> RouteConflicts:
        """The zones whose lane a or b is on `route` (lane ids as `RoadMap.shortest_route` returns them),
        located along the route polyline. A lane change (consecutive neighbours) keeps the arc length,
        so positions after one are approximate by the length difference of the parallel lanes."""
        route = list(route)
        offset = np.zeros(len(route))
        for k in range(1, len(route)):
            joined = route[k] in road_map.successors[route[k - 1]]
            offset[k] = offset[k - 1] + (road_map.lanes[route[k - 1]].length if joined else 0.0)
        where = {lane: k for k, lane in enumerate(route)}
        rows = []
        for z in range(len(self)):
            for mine, other, s_in, s_out, s_pt, yields in (
                    (self.lane_a[z], self.lane_b[z], self.s_a_in[z], self.s_a_out[z], self.s_a_point[z], YIELD_A),
                    (self.lane_b[z], self.lane_a[z], self.s_b_in[z], self.s_b_out[z], self.s_b_point[z], YIELD_B)):
                if int(mine) in where:
                    o = offset[where[int(mine)]]
                    rows.append((z, o + s_in, o + s_out, o + s_pt, mine, other, self.who_yields[z] == yields,
                                 self.kind[z]))
        rows.sort(key=lambda r: r[1])
        cols = list(zip(*rows, strict=True)) if rows else [()] * 8
        types = (np.int64, float, float, float, np.int64, np.int64, bool, np.int8)
        return RouteConflicts(*(np.array(c, dtype=t) for c, t in zip(cols, types, strict=True)))


def _point_polyline_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance (K,) [m] from points (K,2) to a polyline (N,2)."""
    a, ab = polyline[:-1], np.diff(polyline, axis=0)
    rel = points[:, None, :] - a[None]
    t = np.clip(np.einsum("kni,ni->kn", rel, ab) / np.einsum("ni,ni->n", ab, ab), 0.0, 1.0)
    gap = rel - t[..., None] * ab[None]
    return np.sqrt(np.einsum("kni,kni->kn", gap, gap).min(axis=1))


def _overlap(lane: Lane, other: Lane, s_point: float) -> tuple[float, float]:
    """[s_in, s_out] [m] on `lane` around `s_point` where its strip overlaps `other`'s."""
    s = np.arange(max(s_point - ZONE_WINDOW, 0.0), min(s_point + ZONE_WINDOW, lane.length), SAMPLE_STEP)
    s = np.union1d(s, [max(s_point - ZONE_WINDOW, 0.0), min(s_point + ZONE_WINDOW, lane.length), s_point])
    near = _point_polyline_distance(lane.position(s), other.centre) < (lane.width + other.width) / 2 - OVERLAP_TOLERANCE
    k = int(np.searchsorted(s, s_point))
    k = min(k, len(s) - 1)
    if not near[k]:
        return float(s_point), float(s_point)
    outside = np.flatnonzero(~near)
    before, after = outside[outside < k], outside[outside > k]
    lo = s[before[-1] + 1] if len(before) else s[0]
    hi = s[after[0] - 1] if len(after) else s[-1]
    return float(lo), float(hi)


def _crossings(a: Lane, b: Lane) -> list[tuple[float, float, np.ndarray]]:
    """(s_a, s_b, point) where the centre lines of a and b cross (not where they only touch at ends)."""
    p, r = a.centre[:-1], np.diff(a.centre, axis=0)
    q, v = b.centre[:-1], np.diff(b.centre, axis=0)
    denom = r[:, None, 0] * v[None, :, 1] - r[:, None, 1] * v[None, :, 0]
    qp = q[None] - p[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * v[None, :, 1] - qp[..., 1] * v[None, :, 0]) / denom
        u = (qp[..., 0] * r[:, None, 1] - qp[..., 1] * r[:, None, 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    i, j = np.nonzero(hit)
    s_a = a.s[i] + t[i, j] * a.seg_length[i]
    s_b = b.s[j] + u[i, j] * b.seg_length[j]
    at_end_a = (s_a < END_TOLERANCE) | (s_a > a.length - END_TOLERANCE)
    at_end_b = (s_b < END_TOLERANCE) | (s_b > b.length - END_TOLERANCE)
    keep = ~(at_end_a & at_end_b)
    order = np.argsort(s_a[keep])
    s_a, s_b = s_a[keep][order], s_b[keep][order]
    out, last = [], -np.inf
    for sa, sb in zip(s_a, s_b, strict=True):
        if sa - last >= CLUSTER:
            out.append((float(sa), float(sb), a.position(sa)))
        last = sa
    return out


def conflict_zones(road_map: RoadMap) -> ConflictZones:
    """The conflict-zone table of `road_map`: every crossing of two lane centre lines and every pair of
    lanes sharing a successor, with the right of way from `Lane.priority`."""
    lanes = road_map.lanes
    rows = []
    reach = np.array([lane.width / 2 for lane in lanes])
    lo = np.array([lane.centre.min(axis=0) for lane in lanes]) - reach[:, None]
    hi = np.array([lane.centre.max(axis=0) for lane in lanes]) + reach[:, None]
    touching = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=-1)
    for ia, ib in zip(*np.nonzero(np.triu(touching, k=1)), strict=True):
        a, b = lanes[ia], lanes[ib]
        for s_a, s_b, point in _crossings(a, b):
            rows.append((int(ia), int(ib), *_overlap(a, b, s_a), *_overlap(b, a, s_b), CROSSING, point, s_a, s_b))
    for m in range(len(lanes)):
        preds = sorted(road_map.predecessors(m))
        point = lanes[m].centre[0]
        for x, ia in enumerate(preds):
            for ib in preds[x + 1:]:
                a, b = lanes[ia], lanes[ib]
                ra, rb = _overlap(a, b, a.length), _overlap(b, a, b.length)
                rows.append((ia, ib, *ra, *rb, MERGE, point, a.length, b.length))
    rows.sort(key=lambda r: (r[0], r[2], r[1]))  # (lane_a, lane_b, s_a_in, s_a_out, s_b_in, s_b_out, ...)
    if not rows:
        empty_i, empty_f = np.zeros(0, dtype=np.int64), np.zeros(0)
        return ConflictZones(empty_i, empty_f, empty_f, empty_i, empty_f, empty_f, np.zeros(0, np.int8),
                             np.zeros(0, np.int8), np.zeros((0, 2)), empty_f, empty_f)
    col = list(zip(*rows, strict=True))
    la, lb = np.array(col[0], dtype=np.int64), np.array(col[1], dtype=np.int64)
    pa = np.array([lanes[i].priority for i in la])
    pb = np.array([lanes[i].priority for i in lb])
    who = np.select([pa < pb, pa > pb], [YIELD_A, YIELD_B], TIE).astype(np.int8)
    f = [np.array(c, dtype=float) for c in col[2:6]]
    return ConflictZones(la, f[0], f[1], lb, f[2], f[3], who, np.array(col[6], dtype=np.int8),
                         np.array(col[7], dtype=float).reshape(-1, 2), np.array(col[8], dtype=float),
                         np.array(col[9], dtype=float))
