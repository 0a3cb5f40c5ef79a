"""Build-time tables of a RoadMap for traffic: every lane polyline in flat arrays, successors,
same-direction neighbours, merges (where entering lanes yield), crosswalk crossings and spawn points; and the
kernels that read a lane's polyline (`centre_point`, `curve_speed`).

Everything here is computed once per map (Python loops over lanes and crosswalks are fine at build time); the
kernels take the tables as NamedTuples (`LaneTables`, `Polylines`, `Crossings`, `Merges`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mjdrive.compiled import inline, jit, maximum, minimum
from mjdrive.roads import Marking, RoadMap, spawn_points
from mjdrive.roads.geometry import BOX_CORNERS, box_points

LANE_GAP = 1.0  # [m] gap between consecutive lanes in the flat arc-length coordinate
REFERENCE_HALF_SIZE = (2.4, 1.0)  # [m] half length and half width of the largest vehicle (stop lines)
STOP_CLEARANCE = 1.0  # [m] a vehicle waiting at a merge stop line stays this far outside the priority lane
SPAWN_STEP = 3.0  # [m] candidate spawn points along each lane
SPAWN_MARGIN = 5.0  # [m] from the lane ends


class LaneTables(NamedTuple):
    """Every lane (L,) of a TrafficMap, for kernels: size, graph, speeds (the map's attributes of the same names)."""

    length: np.ndarray  # [m]
    width: np.ndarray  # [m]
    speed_limit: np.ndarray  # [m/s]
    successors: np.ndarray  # (L, W) int, -1 padded
    n_successors: np.ndarray  # int
    right: np.ndarray  # int: the same-direction neighbour a vehicle may change to (-1: none)
    left: np.ndarray  # int
    ends_at_merge: np.ndarray  # bool
    starts_at_merge: np.ndarray  # bool
    ending: np.ndarray  # bool: ends beside a neighbour that goes on (an on-ramp)
    in_junction: np.ndarray  # bool
    entry_speed: np.ndarray  # [m/s] the curve speed at each lane's start, anticipating its successors
    anticipation: float  # [m/s^2] braking for the curves ahead


class Polylines(NamedTuple):
    """Every lane's centre line in one flat arc-length coordinate, for kernels (the map's attributes of the same
    names; per vertex or segment: g, inv ... dk)."""

    length: np.ndarray  # (L,) [m]
    base: np.ndarray  # (L,) [m] the lane's start in the flat arc-length coordinate
    first: np.ndarray  # int: the lane's first vertex
    last_segment: np.ndarray  # int: the lane's last segment
    g: np.ndarray  # (V,) [m] flat arc length of every vertex
    inv: np.ndarray  # (V - 1,) [1/m] 1 / segment length
    x0: np.ndarray  # (V - 1,) [m] segment start and step, x
    dx: np.ndarray
    y0: np.ndarray  # ... y [m]
    dy: np.ndarray
    h0: np.ndarray  # ... heading [rad]
    dh: np.ndarray
    v0: np.ndarray  # ... curve speed [m/s]
    dv: np.ndarray
    k0: np.ndarray  # ... curvature [1/m]
    dk: np.ndarray


class Crossings(NamedTuple):
    """Where lanes cross crosswalks (K,), and the crosswalks' centres (C, 2) [m]."""

    lane: np.ndarray  # int
    s: np.ndarray  # (K, 2) [m] interval along the lane
    crosswalk: np.ndarray  # int
    u: np.ndarray  # (K, 2) [m] the lane's strip along the crosswalk
    centre: np.ndarray  # (C, 2) [m]


class Merges(NamedTuple):
    """Roundabout entries (Y,) (junction lanes that join a lane which also continues a ring lane): the entering
    lane, its stop line [m] (front bumper), the lane it joins and that lane's start (the merge point) (Y, 2) [m]."""

    lane: np.ndarray
    stop: np.ndarray
    merge: np.ndarray
    xy: np.ndarray


def polyline_distance(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Distance (K,) [m] from points (K,2) to a polyline (N,2) (exact, over all segments)."""
    a, b = polyline[:-1], polyline[1:]
    ab = b - a
    t = np.clip(np.einsum("kni,ni->kn", points[:, None] - a[None], ab) / np.einsum("ni,ni->n", ab, ab), 0, 1)
    closest = a[None] + t[..., None] * ab[None]
    return np.hypot(*(points[:, None] - closest).transpose(2, 0, 1)).min(axis=1)


FOOTPRINT_POINTS = np.vstack([BOX_CORNERS, [[1, 0], [-1, 0]]])  # corners, then front and rear midpoints


def footprint_points(centre: np.ndarray, heading: np.ndarray, half_length: float, half_width: float) -> np.ndarray:
    """Footprint corners and front/rear midpoints (K,6,2) [m] of boxes at centre (K,2), heading (K,)."""
    return box_points(centre, heading, FOOTPRINT_POINTS * (half_length, half_width))


class TrafficMap:
    """Flat numpy tables of a road map for traffic (see the module docstring). Lane ids are the map's."""

    def __init__(self, road_map: RoadMap, lateral_accel: float = 2.5, anticipation: float = 1.5):
        """`lateral_accel` [m/s^2] sets the curve speed sqrt(lateral_accel / curvature); vehicles slow down
        for curves ahead (also on the next lanes) at `anticipation` [m/s^2]."""
        self.road_map = road_map
        lanes = road_map.lanes
        n = len(lanes)
        if n == 0:
            raise ValueError("traffic needs a road map with lanes")
        self.n_lanes = n
        self.length = np.array([lane.length for lane in lanes])  # [m]
        self.width = np.array([lane.width for lane in lanes])  # [m]
        self.speed_limit = np.array([lane.speed_limit for lane in lanes])  # [m/s]
        self.in_junction = np.array([lane.in_junction for lane in lanes])
        self._flatten()
        self._graph()
        self._curve_speed(lateral_accel, anticipation)
        self._find_merges()
        self._find_crossings()
        goes_on = lambda lane: (lane >= 0) & (self.n_successors[np.maximum(lane, 0)] > 0)  # noqa: E731
        # (L,) lanes without successors beside a same-direction neighbour that goes on (an on-ramp; not the
        # lanes of a road leaving the map, which all end)
        self.ending = (self.n_successors == 0) & (goes_on(self.left) | goes_on(self.right))
        self.lane_tables = LaneTables(*(getattr(self, name) for name in LaneTables._fields))
        self.polylines = Polylines(*(getattr(self, name) for name in Polylines._fields))
        self._spawn_points()

    # --- flat polylines --------------------------------------------------------------------------------
    def _flatten(self) -> None:
        lanes = self.road_map.lanes
        counts = np.array([len(lane.centre) for lane in lanes])
        self.first = np.concatenate([[0], np.cumsum(counts)[:-1]])  # first vertex of each lane
        self.last_segment = self.first + counts - 2  # last segment index of each lane
        self.base = np.concatenate([[0.0], np.cumsum(self.length + LANE_GAP)[:-1]])  # [m] flat offset
        g = np.concatenate([b + lane.s for b, lane in zip(self.base, lanes, strict=True)])
        xy = np.concatenate([lane.centre for lane in lanes])
        h = np.concatenate([lane.vertex_heading for lane in lanes])  # unwrapped within each lane
        k = np.concatenate([lane.vertex_curvature for lane in lanes])
        self.g = g
        # Per segment (vertex i to i+1); segments that join two lanes are never selected by `lookup`.
        dg = np.diff(g)
        self.inv = 1.0 / np.where(dg > 1e-12, dg, 1.0)
        self.x0, self.dx = xy[:-1, 0], np.diff(xy[:, 0])
        self.y0, self.dy = xy[:-1, 1], np.diff(xy[:, 1])
        self.h0, self.dh = h[:-1], np.diff(h)
        self.k0, self.dk = k[:-1], np.diff(k)

    def lookup(self, lane: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centre-line x, y [m] and heading [rad] at arc length s [m] on `lane` (arrays of one shape; s is clamped
        to the lane)."""
        lane, s = np.broadcast_arrays(np.asarray(lane, dtype=np.int64), np.asarray(s, dtype=float))
        x, y, h = centre_points(self.polylines, lane.ravel(), s.ravel())
        return x.reshape(lane.shape), y.reshape(lane.shape), h.reshape(lane.shape)

    def _curve_speed(self, lateral_accel: float, anticipation: float) -> None:
        """Per vertex: the highest speed from which every curve ahead (this lane and, at its end, the slowest
        successor, recursively) can be taken at `lateral_accel` after braking at `anticipation`."""
        lanes = self.road_map.lanes
        own = [np.sqrt(lateral_accel / np.maximum(np.abs(lane.vertex_curvature), 1e-4)).clip(max=40.0)
               for lane in lanes]
        within = []
        for lane, c in zip(lanes, own, strict=True):
            ahead = lane.s[None, :] - lane.s[:, None]  # (N, N) distance from vertex a to vertex b
            cap = np.where(ahead >= 0, np.sqrt(c[None] ** 2 + 2 * anticipation * np.maximum(ahead, 0)), np.inf)
            within.append(cap.min(axis=1))
        entry = np.array([c[0] for c in within])  # [m/s] anticipated cap at each lane's start
        for _ in range(4):  # successors of successors (conservative: the slowest of them)
            new = entry.copy()
            for i, lane in enumerate(lanes):
                succ = self.successors[i, : self.n_successors[i]]
                if len(succ):
                    new[i] = min(within[i][0], np.sqrt(entry[succ].min() ** 2 + 2 * anticipation * lane.length))
            entry = new
        self.entry_speed = entry  # [m/s] (L,) the curve speed at each lane's start, anticipating its successors
        self.anticipation = anticipation
        v = np.concatenate(within)  # the curves of the lane itself; the next lane is added at run time
        self.v0, self.dv = v[:-1], np.diff(v)

    # --- lane graph ------------------------------------------------------------------------------------
    def _graph(self) -> None:
        rm = self.road_map
        n = self.n_lanes
        width = max(1, max(len(s) for s in rm.successors))
        self.successors = np.full((n, width), -1, dtype=np.int64)
        self.n_successors = np.zeros(n, dtype=np.int64)
        for i, succ in enumerate(rm.successors):
            self.successors[i, : len(succ)] = succ
            self.n_successors[i] = len(succ)
        n_pred = np.zeros(n, dtype=np.int64)
        for succ in rm.successors:
            n_pred[succ] += 1
        self.predecessors = [rm.predecessors(i) for i in range(n)]
        self.sources = np.flatnonzero((n_pred == 0) & ~self.in_junction)  # where traffic enters the map
        self.source_xy = np.array([rm.lanes[i].centre[0] for i in self.sources]).reshape(-1, 2)  # [m]
        # Same-direction neighbours a vehicle may change to (not across a SOLID line); -1 if none.
        self.right = np.full(n, -1, dtype=np.int64)
        self.left = np.full(n, -1, dtype=np.int64)
        for i, lane in enumerate(rm.lanes):
            r, left = rm.right_neighbour[i], rm.left_neighbour[i]
            if r is not None and lane.right_marking != Marking.SOLID:
                self.right[i] = r
            if left is not None and lane.left_marking != Marking.SOLID:
                self.left[i] = left

    # --- merges ------------------------------------------------------------------------------------------
    def _find_merges(self) -> None:
        """Junction lanes (entries) that join a lane which also continues a non-junction lane (the ring)
        yield there; each gets a stop line: the farthest front-bumper position [m] along it from which a
        vehicle stays STOP_CLEARANCE outside the priority lanes."""
        rm = self.road_map
        hl, hw = REFERENCE_HALF_SIZE
        rows = []
        for m in range(self.n_lanes):
            preds = self.predecessors[m]
            priority = [p for p in preds if not self.in_junction[p]]
            if len(preds) < 2 or not priority:
                continue
            for y in preds:
                if not self.in_junction[y]:
                    continue
                lane = rm.lanes[y]
                front = np.arange(-10.0, lane.length + 1e-9, 0.1)
                centre_s = front - hl
                centre = lane.position(centre_s)
                pts = footprint_points(centre, lane.heading(centre_s), hl, hw).reshape(-1, 2)
                clear = np.ones(len(front), dtype=bool)
                for p in [*priority, m]:
                    other = rm.lanes[p]
                    dist = polyline_distance(pts, other.centre).reshape(len(front), -1).min(axis=1)
                    clear &= dist >= other.width / 2 + STOP_CLEARANCE
                blocked = np.flatnonzero(~clear)
                stop = front[blocked[0] - 1] if len(blocked) and blocked[0] > 0 else front[0]
                if not len(blocked):
                    stop = front[-1]
                rows.append((y, m, float(stop)))
        rows = rows or [(-1, -1, 0.0)]
        self.starts_at_merge = np.zeros(self.n_lanes, dtype=bool)  # lanes that entering lanes join
        self.ends_at_merge = np.zeros(self.n_lanes, dtype=bool)  # priority lanes ending where they join
        for y, m, _ in rows:
            if m >= 0:
                self.starts_at_merge[m] = True
                self.ends_at_merge[[p for p in self.predecessors[m] if p != y]] = True
        merges = Merges(np.array([r[0] for r in rows], dtype=np.int64), np.array([r[2] for r in rows]),
                        np.array([r[1] for r in rows], dtype=np.int64),
                        np.array([rm.lanes[r[1]].centre[0] if r[1] >= 0 else (0.0, 0.0) for r in rows]))
        self.merges = Merges(*(a[:0] for a in merges)) if merges.lane[0] < 0 else merges

    # --- crosswalks --------------------------------------------------------------------------------------
    def _find_crossings(self) -> None:
        """Where lane centre lines cross crosswalks: lane, s interval [m], crosswalk, u interval [m] (the
        lane's strip in the crosswalk's walking coordinate u, 0 at the crosswalk centre)."""
        rm = self.road_map
        cws = rm.crosswalks
        self.n_crosswalks = len(cws)
        self.cw_centre = np.array([np.asarray(c.centre, float) for c in cws]).reshape(-1, 2)
        self.cw_heading = np.array([c.heading for c in cws])
        self.cw_along = np.column_stack([np.cos(self.cw_heading), np.sin(self.cw_heading)]).reshape(-1, 2)
        self.cw_across = np.column_stack([-self.cw_along[:, 1], self.cw_along[:, 0]]).reshape(-1, 2)
        self.cw_half_length = np.array([c.length / 2 for c in cws])  # [m] half the road width it spans
        self.cw_width = np.array([c.width for c in cws])  # [m] along the road
        rows = []
        for c in range(self.n_crosswalks):
            for i, lane in enumerate(rm.lanes):
                rel = lane.centre - self.cw_centre[c]
                u, v = rel @ self.cw_along[c], rel @ self.cw_across[c]
                inside = (np.abs(u) <= self.cw_half_length[c]) & (np.abs(v) <= self.cw_width[c] / 2)
                if not inside.any():
                    continue
                s_in = lane.s[inside]
                uc = float(np.mean(u[inside]))
                rows.append((i, s_in.min() - 0.25, s_in.max() + 0.25, c, uc - lane.width / 2,
                             uc + lane.width / 2))
        table = np.array(rows, dtype=float).reshape(-1, 6)
        self.crossings = Crossings(table[:, 0].astype(np.int64), table[:, 1:3], table[:, 3].astype(np.int64),
                                   table[:, 4:6], self.cw_centre)

    # --- spawn points ------------------------------------------------------------------------------------
    def _spawn_points(self) -> None:
        """Places (lane, s) among `roads.spawn_points` (on non-junction lanes), off crosswalks, pairwise far
        enough apart that any two vehicles placed on them never overlap (greedy, in lane order)."""
        candidates = spawn_points(self.road_map, SPAWN_STEP, SPAWN_MARGIN)
        lane = np.array([i for i, _ in candidates], dtype=np.int64)
        s = np.array([s for _, s in candidates], dtype=float)
        on_cw = np.zeros(len(s), dtype=bool)
        for k in range(len(self.crossings.lane)):
            lo, hi = self.crossings.s[k]
            on_cw |= (lane == self.crossings.lane[k]) & (s > lo - 3.0) & (s < hi + 3.0)
        lane, s = lane[~on_cw], s[~on_cw]
        x, y, h = self.lookup(lane, s)
        keep: list[int] = []
        for k in range(len(lane)):
            if keep:
                dx, dy = x[keep] - x[k], y[keep] - y[k]
                dist = np.hypot(dx, dy)
                lateral = np.abs(-np.sin(h[k]) * dx + np.cos(h[k]) * dy)
                if np.any((dist < 4.5) | ((dist < 10.0) & (lateral < 2.8))):
                    continue
            keep.append(k)
        self.spawn_lane = lane[keep].astype(np.int64)
        self.spawn_s = s[keep]
        self.spawn_xy = np.column_stack([x[keep], y[keep]])


@inline
def find_segment(g, gq: float, first: int, last: int) -> int:
    """The segment (first..last: a lane's) holding flat arc length gq [m]: np.searchsorted(g, gq, side="right") - 1
    clamped to [first, last], searched among the lane's own vertices (the same index: g is sorted, so the vertices
    before `first` and after `last` only move the unclamped index outside [first, last])."""
    if gq != gq:  # NaN sorts past the end
        return last
    lo, hi = first, last + 1
    while lo < hi:
        mid = (lo + hi) >> 1
        if g[mid] <= gq:
            lo = mid + 1
        else:
            hi = mid
    return max(lo - 1, first)


@inline
def flat_position(lines, lane: int, s: float) -> float:
    """The flat arc length [m] of s [m] on `lane`, s clamped to the lane (NaN kept)."""
    return lines.base[lane] + minimum(maximum(s, 0.0), lines.length[lane])


@inline
def segment_at(lines, lane: int, s: float) -> tuple[int, float]:
    """The segment of `lane` at s [m] (clamped to the lane) and the share u of it passed there."""
    gq = flat_position(lines, lane, s)
    seg = find_segment(lines.g, gq, lines.first[lane], lines.last_segment[lane])
    return seg, (gq - lines.g[seg]) * lines.inv[seg]


@jit
def centre_points(lines, lane, s):
    """Centre-line x, y [m] and heading [rad] (K,) at s (K,) [m] on `lane` (K,) (s clamped to the lane)."""
    n = len(s)
    x, y, h = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        seg, u = segment_at(lines, lane[k], s[k])
        x[k], y[k] = lines.x0[seg] + u * lines.dx[seg], lines.y0[seg] + u * lines.dy[seg]
        h[k] = lines.h0[seg] + u * lines.dh[seg]
    return x, y, h


@inline
def curve_speed(lines, lane, s):
    """The anticipated curve speed [m/s] (the curves ahead on `lane`, at `anticipation` braking; the next lane's
    are added with `entry_speed`) and the curvature [1/m] (F,) at s (F,) [m] on `lane` (F,)."""
    n = len(s)
    speed, kappa = np.empty(n), np.empty(n)
    for f in range(n):
        seg, u = segment_at(lines, lane[f], s[f])
        speed[f], kappa[f] = lines.v0[seg] + u * lines.dv[seg], lines.k0[seg] + u * lines.dk[seg]
    return speed, kappa
