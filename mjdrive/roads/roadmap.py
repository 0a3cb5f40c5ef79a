"""RoadMap: lanes, their graph (successors, same-direction neighbours), paved areas, crosswalks, and the
queries a driving task needs every step (lane frame, on-road, solid-marking crossings).

Queries run on flat numpy tables of every lane segment / solid marking segment, built once by `freeze()`
(called lazily; the mutating methods below invalidate it — call `freeze()` again after editing the public
lists or lane markings directly). Uniform grids prefilter the candidates (with chunk bounding circles as
an exact fallback far from the lanes), so a query does no Python loop over lanes.
"""

from __future__ import annotations

import difflib
import heapq
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from mjdrive.roads import _spatial as sp
from mjdrive.roads.geometry import STEP, wrap_angle
from mjdrive.roads.lane import Lane, Marking

MAIN_ROAD, MINOR_ROAD = 0, 1  # the groups of `RoadMap.junction_entries` (a junction's signal groups)


LANE_CELL = 5.0  # [m] grid cell for `locate`
LANE_MARGIN = 8.0  # [m] lane segments within this distance of a cell are listed in it
CHUNK = 16  # segments per chunk (bounding circle) for `locate` far from the lanes
STRIP_CELL = 4.0  # [m] grid cell for `on_road` (lists the segments whose strips touch the cell)
SOLID_CELL = 5.0  # [m] grid cell for solid-marking queries
LANE_CHANGE_LENGTH = 20.0  # [m] length of the lane-change transition in `route_polyline`
HEADING_WEIGHT = 2.0  # [m] `locate` cost of a lane pointing the other way is 2 * HEADING_WEIGHT


@dataclass
class Crosswalk:
    """A pedestrian crossing: centre (2,) [m], walking direction [rad], length across the road [m] and
    width along it [m]."""

    centre: np.ndarray
    heading: float
    length: float
    width: float = 3.0

    def polygon(self) -> np.ndarray:
        """Corners (4,2) [m], counter-clockwise."""
        along = np.array([math.cos(self.heading), math.sin(self.heading)])
        across = np.array([-along[1], along[0]])
        c = np.asarray(self.centre, dtype=float)
        return np.array([c + a * self.length / 2 * along + b * self.width / 2 * across
                         for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


@dataclass
class LaneQuery:
    """Result of `RoadMap.locate`: lane id, lane frame (s, d) [m], heading error [rad], on_road."""

    lane: int
    s: float  # [m]
    d: float  # [m] > 0 left of the lane centre
    heading_error: float  # [rad] query heading - lane heading, in [-pi, pi); nan without a heading
    on_road: bool  # the point is on some lane strip or paved area (not only on `lane`)


class _Frozen:
    """Query tables of a RoadMap (see `RoadMap.freeze`)."""

    def __init__(self, rm: RoadMap):
        tables = []
        for i, lane in enumerate(rm.lanes):
            table = lane._table.copy()
            table[:, sp.LANE] = i
            tables.append(table)
        self.table = np.vstack(tables) if tables else np.zeros((0, sp.NCOL))
        t = self.table
        x0, y0, x1, y1 = t[:, sp.P0X], t[:, sp.P0Y], t[:, sp.P0X] + t[:, sp.DX], t[:, sp.P0Y] + t[:, sp.DY]
        self.max_half_width = float(t[:, sp.HW].max()) if len(t) else 0.0
        # |d| in a segment's cell is >= cos(half the vertex turn) * the distance to the segment
        scale = np.concatenate([np.hypot(t[:, sp.N0X], t[:, sp.N0Y]), np.ones(1),
                                np.hypot(t[:, sp.N0X] + t[:, sp.DNX], t[:, sp.N0Y] + t[:, sp.DNY])])
        self.min_cos = float(1.0 / scale.max())
        lo, hi = np.column_stack([np.minimum(x0, x1), np.minimum(y0, y1)]), np.column_stack(
            [np.maximum(x0, x1), np.maximum(y0, y1)])
        self.grid = sp.GridIndex(np.hstack([lo - LANE_MARGIN, hi + LANE_MARGIN]), LANE_CELL)
        # Chunks of <= CHUNK consecutive segments of one lane, with bounding circles (centre, radius).
        counts = [len(lane._table) for lane in rm.lanes]
        first = np.concatenate([[0], np.cumsum(counts)[:-1]]) if counts else np.zeros(0, dtype=int)
        chunks = [np.arange(a, a + n, CHUNK) for a, n in zip(first, counts, strict=True)]
        self.chunk_first = np.concatenate(chunks) if chunks else np.zeros(0, dtype=np.int64)
        self.chunk_count = np.diff(np.concatenate([self.chunk_first, [len(t)]]))
        if len(t):
            owner = np.repeat(np.arange(len(self.chunk_first)), self.chunk_count)
            first = self.chunk_first
            self.chunk_centre = (np.minimum.reduceat(lo, first) + np.maximum.reduceat(hi, first)) / 2
            c = self.chunk_centre[owner]
            far = np.maximum(np.hypot(*(lo - c).T), np.hypot(*(hi - c).T))  # >= distance to the endpoints
            self.chunk_radius = np.maximum.reduceat(far, self.chunk_first)
            self.chunk_hw = t[self.chunk_first, sp.HW]
        # A strip point is within half width * mitre scale (<= 2) of its segment.
        reach = 2.0 * t[:, sp.HW:sp.HW + 1] + 1e-6 if len(t) else 0.0
        self.strip_grid = sp.GridIndex(np.hstack([lo - reach, hi + reach]), STRIP_CELL)
        # Convex areas as half-planes: edge starts (E,2), edge vectors (E,2); area k starts at area_first[k]
        starts, vecs = [], []
        for poly in rm.areas:
            p = _ccw(np.asarray(poly, dtype=float))
            starts.append(p)
            vecs.append(np.roll(p, -1, axis=0) - p)
        self.area_start = np.vstack(starts) if starts else np.zeros((0, 2))
        self.area_vec = np.vstack(vecs) if vecs else np.zeros((0, 2))
        sizes = [len(p) for p in starts]
        self.area_first = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if sizes else None
        self.n_areas = len(rm.areas)
        self.lines = rm._marking_lines()
        solid = [np.stack([ln[:-1], ln[1:]], axis=1) for ln, kind in self.lines if kind == Marking.SOLID]
        self.solid = np.vstack(solid) if solid else np.zeros((0, 2, 2))
        self.solid_grid = sp.GridIndex(np.column_stack([self.solid.min(axis=1), self.solid.max(axis=1)]),
                                       SOLID_CELL)


def _ccw(poly: np.ndarray) -> np.ndarray:
    """The polygon (K,2) in counter-clockwise order."""
    x, y = poly[:, 0], poly[:, 1]
    area2 = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return poly if area2 >= 0 else poly[::-1]


class RoadMap:
    """Lanes and their connectivity plus paved areas and crosswalks. Lane ids are list indices."""

    def __init__(self, name: str = "map"):
        self.name = name
        self.lanes: list[Lane] = []
        self.successors: list[list[int]] = []
        self.left_neighbour: list[int | None] = []  # same-direction lane directly to the left
        self.right_neighbour: list[int | None] = []  # same-direction lane directly to the right
        self.areas: list[np.ndarray] = []  # convex polygons (K,2) [m] of paved area outside lane strips
        self.crosswalks: list[Crosswalk] = []
        self.give_way: list[tuple[int, float]] = []  # give-way lines across lanes: (lane id, s [m])
        # lanes entering a junction that signals or signs can control: (lane id, group: MAIN_ROAD or MINOR_ROAD)
        self.junction_entries: list[tuple[int, int]] = []
        # the signs and signals the map itself puts at junction entries: lane id -> "stop" (a stop sign) or "lights"
        # (traffic lights); entries not in it give way by the conflict zones' right of way (`junction_control="map"`)
        self.entry_signs: dict[int, str] = {}
        self._names: dict[str, int] = {}
        self._frozen: _Frozen | None = None

    def __repr__(self) -> str:
        return f"RoadMap({self.name!r}, {len(self.lanes)} lanes, {len(self.areas)} areas)"

    # --- construction --------------------------------------------------------------------------------
    def add_lane(self, lane: Lane) -> int:
        """Append a lane; returns its id. Names must be unique (empty names are not indexed)."""
        if lane.name and lane.name in self._names:
            raise ValueError(f"duplicate lane name {lane.name!r}")
        idx = len(self.lanes)
        self.lanes.append(lane)
        self.successors.append([])
        self.left_neighbour.append(None)
        self.right_neighbour.append(None)
        if lane.name:
            self._names[lane.name] = idx
        self._frozen = None
        return idx

    def connect(self, a: int, b: int) -> None:
        """Lane b continues lane a (b's start is a's end)."""
        if b not in self.successors[a]:
            self.successors[a].append(b)

    def set_neighbours(self, left: int, right: int) -> None:
        """Lanes `left` and `right` run side by side in one direction, `left` directly left of `right`."""
        self.right_neighbour[left] = right
        self.left_neighbour[right] = left
        self._frozen = None

    def add_area(self, polygon: ArrayLike) -> int:
        """Append a convex paved polygon (K,2) [m]; returns its index."""
        self.areas.append(_ccw(np.asarray(polygon, dtype=float).reshape(-1, 2)))
        self._frozen = None
        return len(self.areas) - 1

    def add_map(self, other: RoadMap, offset: ArrayLike = (0.0, 0.0), rotation: float = 0.0,
                prefix: str = "") -> int:
        """Copy `other` in, rotated by `rotation` [rad] about the origin then shifted by `offset` [m], its
        lane names prefixed. Returns the id offset of the copied lanes."""
        c, s = math.cos(rotation), math.sin(rotation)
        rot = np.array([[c, -s], [s, c]])
        off = np.asarray(offset, dtype=float)
        base = len(self.lanes)

        def tf(p):
            return np.asarray(p, dtype=float) @ rot.T + off

        for lane in other.lanes:
            self.add_lane(Lane(tf(lane.centre), lane.width, lane.left_marking, lane.right_marking,
                               lane.speed_limit, prefix + lane.name, lane.in_junction, lane.priority))
        for i in range(len(other.lanes)):
            self.successors[base + i] = [base + j for j in other.successors[i]]
            ln, rn = other.left_neighbour[i], other.right_neighbour[i]
            self.left_neighbour[base + i] = None if ln is None else base + ln
            self.right_neighbour[base + i] = None if rn is None else base + rn
        for poly in other.areas:
            self.add_area(tf(poly))
        for cw in other.crosswalks:
            self.crosswalks.append(Crosswalk(tf(cw.centre), cw.heading + rotation, cw.length, cw.width))
        self.give_way.extend((base + lane, s) for lane, s in other.give_way)
        self.junction_entries.extend((base + lane, group) for lane, group in other.junction_entries)
        self.entry_signs.update({base + lane: sign for lane, sign in other.entry_signs.items()})
        return base

    def freeze(self) -> RoadMap:
        """Build the query tables now (otherwise built on the first query). Returns self."""
        self._frozen = _Frozen(self)
        return self

    @property
    def _f(self) -> _Frozen:
        if self._frozen is None:
            self._frozen = _Frozen(self)
        return self._frozen

    # --- look-ups ------------------------------------------------------------------------------------
    def lane_id(self, name: str) -> int:
        """Id of the lane called `name`; KeyError listing close names if unknown."""
        try:
            return self._names[name]
        except KeyError:
            close = difflib.get_close_matches(name, list(self._names), n=5, cutoff=0.5)
            raise KeyError(f"no lane {name!r} in {self.name!r}; close names: {close}") from None

    def predecessors(self, lane: int) -> list[int]:
        """Lanes that `lane` continues."""
        return [i for i, succ in enumerate(self.successors) if lane in succ]

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) [m] of all lane strips and areas."""
        pts = [lane.left_edge() for lane in self.lanes] + [lane.right_edge() for lane in self.lanes]
        pts += [np.asarray(a) for a in self.areas]
        if not pts:
            raise ValueError("empty road map")
        allp = np.vstack(pts)
        (x0, y0), (x1, y1) = allp.min(axis=0), allp.max(axis=0)
        return float(x0), float(y0), float(x1), float(y1)

    # --- routing -------------------------------------------------------------------------------------
    def shortest_route(self, start: int, goal: int, allow_lane_change: bool = True,
                       lane_change_cost: float = 30.0) -> list[int]:
        """Lane ids from `start` to `goal` minimising driven length [m] (Dijkstra).

        A lane change to a same-direction neighbour (not across a SOLID line) costs `lane_change_cost` [m].
        Raises ValueError if the goal cannot be reached.
        """
        best = {start: 0.0}
        previous: dict[int, int] = {}
        heap = [(0.0, start)]
        while heap:
            cost, i = heapq.heappop(heap)
            if i == goal:
                route = [goal]
                while route[-1] != start:
                    route.append(previous[route[-1]])
                return route[::-1]
            if cost > best[i]:
                continue
            edges = [(j, self.lanes[i].length) for j in self.successors[i]]
            if allow_lane_change:
                lane = self.lanes[i]
                ln, rn = self.left_neighbour[i], self.right_neighbour[i]
                if ln is not None and lane.left_marking != Marking.SOLID:
                    edges.append((ln, lane_change_cost))
                if rn is not None and lane.right_marking != Marking.SOLID:
                    edges.append((rn, lane_change_cost))
            for j, w in edges:
                c = cost + w
                if c < best.get(j, math.inf):
                    best[j] = c
                    previous[j] = i
                    heapq.heappush(heap, (c, j))
        raise ValueError(f"no route from lane {start} ({self.lanes[start].name!r}) "
                         f"to lane {goal} ({self.lanes[goal].name!r})")

    def route_polyline(self, route: list[int]) -> np.ndarray:
        """Centre line (M,2) [m] along a route. Consecutive neighbours in the route are lane changes, drawn
        as a smooth transition of ~LANE_CHANGE_LENGTH m centred on the stretch driven on those lanes."""
        if not route:
            raise ValueError("empty route")
        parts: list[np.ndarray] = []
        k = 0
        while k < len(route):
            run = [route[k]]
            while k + 1 < len(route) and route[k + 1] not in self.successors[route[k]]:
                nxt = route[k + 1]
                if nxt not in (self.left_neighbour[route[k]], self.right_neighbour[route[k]]):
                    raise ValueError(f"route is not connected at lanes {route[k]} -> {nxt}")
                run.append(nxt)
                k += 1
            k += 1
            part = self.lanes[run[0]].centre if len(run) == 1 else self._lane_change(run)
            if parts and np.hypot(*(part[0] - parts[-1][-1])) < 1e-3:
                part = part[1:]
            parts.append(part)
        return np.vstack(parts)

    def _lane_change(self, run: list[int]) -> np.ndarray:
        """Polyline over parallel lanes `run`, changing lane m = len(run)-1 times (one per 1/m of the way)."""
        lanes = [self.lanes[i] for i in run]
        m = len(run) - 1
        mean = float(np.mean([lane.length for lane in lanes]))
        u = np.linspace(0.0, 1.0, max(2, math.ceil(mean / (0.5 * STEP)) + 1))
        pts = [lane.position(u * lane.length) for lane in lanes]
        out = pts[0].copy()
        du = min(LANE_CHANGE_LENGTH / mean, 1.0 / m)
        for c in range(m):
            x = np.clip((u - ((c + 0.5) / m - du / 2)) / du, 0.0, 1.0)
            w = x * x * (3 - 2 * x)  # smoothstep
            out += w[:, None] * (pts[c + 1] - pts[c])
        return out

    def waypoints(self, route: list[int], spacing: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
        """Points (M,2) [m] every `spacing` [m] of arc length along the route polyline, from its start (the
        last one within `spacing` of the end), and the route headings (M,) [rad] there."""
        path = Lane(self.route_polyline(route), name="route")
        s = np.arange(0.0, path.length + 1e-9, spacing)
        return path.position(s), path.heading(s)

    # --- lane-frame queries ----------------------------------------------------------------------------
    def locate(self, xy: ArrayLike, heading: float | None = None) -> LaneQuery:
        """Nearest lane and lane frame of point xy (2,) [m]; with a heading [rad], lanes pointing the same
        way are preferred (a point inside a lane strip pointing the other way may get the lane next to it)."""
        f = self._f
        if not len(f.table):
            raise ValueError("empty road map")
        x, y = float(xy[0]), float(xy[1])
        cand = f.grid.box(x, y, x, y)
        best = None
        if cand is not None and len(cand):
            best = self._locate_in(f.table[cand], x, y, heading)
        # Exact if no segment farther than LANE_MARGIN could cost less; else prune by chunk bounding circles.
        if best is None or best[0] > f.min_cos * LANE_MARGIN - f.max_half_width:
            best = self._locate_in(f.table[self._chunk_rows(x, y, heading)], x, y, heading)
        _, lane, s, d, lane_heading, on_lane = best
        on = on_lane or (f.n_areas > 0 and bool(self._in_areas(np.array([[x, y]]))[0]))
        herr = math.nan if heading is None else float(wrap_angle(heading - lane_heading))
        return LaneQuery(lane, s, d, herr, on)

    def _chunk_rows(self, x: float, y: float, heading: float | None) -> np.ndarray:
        """Rows of every chunk whose lower bound on the `locate` cost is <= the least upper bound."""
        f = self._f
        dc = np.hypot(f.chunk_centre[:, 0] - x, f.chunk_centre[:, 1] - y)
        lb, ub = f.min_cos * np.maximum(dc - f.chunk_radius, 0.0), dc + f.chunk_radius
        if heading is not None:
            lb = np.maximum(lb - f.chunk_hw, 0.0) + 0.01 * lb
            ub = np.maximum(ub - f.chunk_hw, 0.0) + 2 * HEADING_WEIGHT + 0.01 * ub
        sel = np.flatnonzero(lb <= ub.min())
        counts = f.chunk_count[sel]
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        return np.repeat(f.chunk_first[sel], counts) + local

    @staticmethod
    def _locate_in(rows: np.ndarray, x: float, y: float, heading: float | None):
        t, d, dist, inside = sp.project(rows, x, y)
        if heading is None:
            cost = dist
        else:
            seg_heading = rows[:, sp.H0] + np.clip(t, 0, 1) * rows[:, sp.DH]
            excess = np.maximum(dist - rows[:, sp.HW], 0.0)
            cost = excess + HEADING_WEIGHT * (1.0 - np.cos(heading - seg_heading)) + 0.01 * dist
        j = int(np.argmin(cost))
        lane_col = rows[:, sp.LANE]
        lane = int(lane_col[j])
        j = int(np.argmin(np.where(lane_col == lane, dist, np.inf)))  # the lane's nearest segment
        tc = min(max(float(t[j]), 0.0), 1.0)
        r = rows[j]
        on_lane = bool(np.any(inside & (np.abs(d) <= rows[:, sp.HW])))
        return (float(cost.min()), lane, float(r[sp.S0] + tc * r[sp.LEN]), float(d[j]),
                float(r[sp.H0] + tc * r[sp.DH]), on_lane)

    def on_road(self, xy: ArrayLike) -> bool | np.ndarray:
        """Whether point(s) xy (2,) or (K,2) [m] lie on a lane strip (|d| <= width/2) or a paved area."""
        xy = np.asarray(xy, dtype=float)
        f = self._f
        if xy.ndim == 1:  # one point: a plain cell look-up
            x, y = float(xy[0]), float(xy[1])
            cand = f.strip_grid.box(x, y, x, y)
            if cand is not None and len(cand):
                rows = f.table[cand]
                _, d, _, inside = sp.project(rows, x, y)
                if np.any(inside & (np.abs(d) <= rows[:, sp.HW])):
                    return True
            return f.n_areas > 0 and bool(self._in_areas(xy[None])[0])
        pts = xy.reshape(-1, 2)
        out = np.zeros(len(pts), dtype=bool)
        for k0 in range(0, len(pts), 2048):
            chunk = pts[k0:k0 + 2048]
            point, seg = f.strip_grid.points(chunk)
            if len(seg):
                rows = f.table[seg]
                _, d, _, inside = sp.project(rows, chunk[point, 0], chunk[point, 1])
                out[k0 + point[inside & (np.abs(d) <= rows[:, sp.HW])]] = True
        if f.n_areas:
            out |= self._in_areas(pts)
        return out

    def _in_areas(self, pts: np.ndarray) -> np.ndarray:
        f = self._f
        r = pts[:, None, :] - f.area_start[None]
        cross = f.area_vec[None, :, 0] * r[..., 1] - f.area_vec[None, :, 1] * r[..., 0]  # (K, E)
        outside = np.logical_or.reduceat(cross < -1e-9, f.area_first, axis=1)  # (K, areas)
        return ~outside.all(axis=1)

    # --- markings ------------------------------------------------------------------------------------
    def marking_lines(self) -> list[tuple[np.ndarray, Marking]]:
        """Every painted lane boundary once: (polyline (N,2) [m], BROKEN or SOLID). A boundary shared by two
        lanes (same-direction neighbours, or the centre line of a two-way road) appears once, with the
        stronger of the two markings; junction connectors and unmarked boundaries give nothing."""
        return list(self._f.lines)

    def _marking_lines(self) -> list[tuple[np.ndarray, Marking]]:
        lines: list[list] = []  # [polyline, marking]
        open_left: list[tuple[int, int]] = []  # (line index, lane) of left boundaries with no neighbour
        for i, lane in enumerate(self.lanes):
            if lane.in_junction:
                continue
            rn = self.right_neighbour[i]
            kind = lane.right_marking if rn is None else max(lane.right_marking, self.lanes[rn].left_marking)
            lines.append([lane.right_edge(), kind])
            if self.left_neighbour[i] is not None:
                continue  # drawn by the left neighbour as its right boundary
            left = lane.left_edge()
            for k, j in open_left:  # the centre line of a two-way road: a reversed, coincident boundary
                other = lines[k][0]
                if (np.hypot(*(other[0] - left[-1])) < 0.05 and np.hypot(*(other[-1] - left[0])) < 0.05
                        and abs(self.lanes[j].length - lane.length) < 0.05 * lane.length + 0.5
                        and np.hypot(*(other[len(other) // 2] - left[::-1][len(left) // 2])) < 0.5):
                    lines[k][1] = max(lines[k][1], lane.left_marking)
                    break
            else:
                open_left.append((len(lines), i))
                lines.append([left, lane.left_marking])
        return [(line, Marking(kind)) for line, kind in lines if kind != Marking.NONE]

    def solid_segments(self) -> np.ndarray:
        """All SOLID marking segments (K,2,2) [m] (cached)."""
        return self._f.solid

    def crossed_solid(self, p0: ArrayLike, p1: ArrayLike) -> bool:
        """Whether any of the P moves p0 (P,2) -> p1 (P,2) [m] touches or crosses a SOLID marking segment."""
        f = self._f
        p0, p1 = np.asarray(p0, dtype=float).reshape(-1, 2), np.asarray(p1, dtype=float).reshape(-1, 2)
        if not len(f.solid):
            return False
        lo, hi = np.minimum(p0.min(axis=0), p1.min(axis=0)), np.maximum(p0.max(axis=0), p1.max(axis=0))
        cand = f.solid_grid.box(lo[0], lo[1], hi[0], hi[1])
        seg = f.solid if cand is None else f.solid[cand]
        if not len(seg):
            return False
        ax, ay = p0[:, 0:1], p0[:, 1:2]
        bx, by = p1[:, 0:1] - ax, p1[:, 1:2] - ay  # (P,1) motion
        cx, cy = seg[:, 0, 0], seg[:, 0, 1]
        ex, ey = seg[:, 1, 0] - cx, seg[:, 1, 1] - cy  # (C,) marking segment
        o1 = ex * (ay - cy) - ey * (ax - cx)  # side of p0 w.r.t. the marking
        o2 = ex * (ay + by - cy) - ey * (ax + bx - cx)  # side of p1
        o3 = bx * (cy - ay) - by * (cx - ax)  # side of the marking start w.r.t. the motion
        o4 = bx * (cy + ey - ay) - by * (cx + ex - ax)  # side of the marking end
        hit = (o1 * o2 <= 0) & (o3 * o4 <= 0) & ((o1 != 0) | (o2 != 0))
        return bool(hit.any())
