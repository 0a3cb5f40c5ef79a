"""Vectorised lane-frame projection over segment tables and a uniform-grid spatial index.

A segment table is a float array (S, NCOL), one row per polyline segment of a lane: start point, unit
tangent, chord, mitred start normal and its change over the segment, lane arc length at the start,
segment length, half lane width, vertex heading at the start and its change, lane index. Within a
segment a lane point is p0 + t*chord + d*(n0 + t*dn), t in [0,1]; because the mitred normals have unit
projection on the segment normal, d is exactly the perpendicular distance to the segment's line.
"""

from __future__ import annotations

import math

import numpy as np

from mjdrive.compiled import jit

P0X, P0Y, TX, TY, DX, DY, N0X, N0Y, DNX, DNY, S0, LEN, HW, H0, DH, LANE = range(16)
NCOL = 16


def segment_table(
    centre: np.ndarray, normals: np.ndarray, vertex_heading: np.ndarray, half_width: float, lane: int = 0
) -> np.ndarray:
    """Segment table (N-1, NCOL) of a polyline centre (N,2) with mitred vertex normals (N,2)."""
    chord = np.diff(centre, axis=0)
    length = np.hypot(chord[:, 0], chord[:, 1])
    table = np.empty((len(chord), NCOL))
    table[:, P0X:P0Y + 1] = centre[:-1]
    table[:, TX:TY + 1] = chord / length[:, None]
    table[:, DX:DY + 1] = chord
    table[:, N0X:N0Y + 1] = normals[:-1]
    table[:, DNX:DNY + 1] = np.diff(normals, axis=0)
    table[:, S0] = np.concatenate([[0.0], np.cumsum(length)[:-1]])
    table[:, LEN] = length
    table[:, HW] = half_width
    table[:, H0] = vertex_heading[:-1]
    table[:, DH] = np.diff(vertex_heading)
    table[:, LANE] = lane
    return table


def project(table: np.ndarray, x, y) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lane-frame coordinates of points (x, y) against segment rows (broadcast together).

    Returns t (position along the segment, in [0,1] inside it), d [m] (signed lateral offset), dist [m]
    (|d| when the point lies in the segment's cell, else the distance to the segment) and inside (bool).
    """
    rx, ry = x - table[..., P0X], y - table[..., P0Y]
    dx, dy = table[..., DX], table[..., DY]
    d = table[..., TX] * ry - table[..., TY] * rx
    ex, ey = dx + d * table[..., DNX], dy + d * table[..., DNY]
    ee = np.maximum(ex * ex + ey * ey, 1e-12)
    t = ((rx - d * table[..., N0X]) * ex + (ry - d * table[..., N0Y]) * ey) / ee
    inside = (t >= 0.0) & (t <= 1.0) & (ex * dx + ey * dy > 0.0)
    tc = np.clip((rx * dx + ry * dy) / (table[..., LEN] ** 2), 0.0, 1.0)
    dist = np.where(inside, np.abs(d), np.hypot(rx - tc * dx, ry - tc * dy))
    return t, d, dist, inside


@jit
def nearest_point(table: np.ndarray, x: float, y: float) -> tuple[float, float]:
    """(s, d) [m] of the point (x, y) on the nearest of all the segment rows of `table` (the first of equally
    near ones): `project` on every row and the argmin of its dist, operation for operation, in one pass (no
    (S,) temporaries; compiled with numba)."""
    best, best_j, best_t, best_d = np.inf, -1, 0.0, 0.0
    for j in range(table.shape[0]):
        rx, ry = x - table[j, P0X], y - table[j, P0Y]
        dx, dy = table[j, DX], table[j, DY]
        d = table[j, TX] * ry - table[j, TY] * rx
        ex, ey = dx + d * table[j, DNX], dy + d * table[j, DNY]
        ee = max(ex * ex + ey * ey, 1e-12)
        t = ((rx - d * table[j, N0X]) * ex + (ry - d * table[j, N0Y]) * ey) / ee
        if t >= 0.0 and t <= 1.0 and ex * dx + ey * dy > 0.0:
            dist = abs(d)
        else:
            length = table[j, LEN]
            tc = min(max((rx * dx + ry * dy) / (length * length), 0.0), 1.0)
            ax, ay = abs(rx - tc * dx), abs(ry - tc * dy)
            if ax > best or ay > best:  # hypot >= max(|ax|, |ay|) > best: not nearer (skips the libm call)
                continue
            dist = math.hypot(ax, ay)
        if dist < best or best_j < 0:
            best, best_j, best_t, best_d = dist, j, t, d
    return table[best_j, S0] + min(max(best_t, 0.0), 1.0) * table[best_j, LEN], best_d


class GridIndex:
    """Uniform grid over axis-aligned boxes: which items' boxes touch a cell (CSR lists per cell)."""

    def __init__(self, boxes: np.ndarray, cell: float):
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)  # (n, 4): xmin, ymin, xmax, ymax
        self.cell = float(cell)
        self.n_items = len(boxes)
        if self.n_items == 0:
            self.origin = np.zeros(2)
            self.shape = (0, 0)
            self.offsets = np.zeros(1, dtype=np.int64)
            self.items = np.zeros(0, dtype=np.int64)
            return
        self.origin = boxes[:, :2].min(axis=0)
        top = boxes[:, 2:].max(axis=0)
        gx, gy = (np.floor((top - self.origin) / self.cell).astype(int) + 1).tolist()
        self.shape = (gx, gy)
        lo = np.floor((boxes[:, :2] - self.origin) / self.cell).astype(np.int64)
        hi = np.floor((boxes[:, 2:] - self.origin) / self.cell).astype(np.int64)
        nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
        counts = nx * ny
        item = np.repeat(np.arange(self.n_items), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        cx = lo[item, 0] + local // ny[item]
        cy = lo[item, 1] + local % ny[item]
        cells = cx * gy + cy
        order = np.argsort(cells, kind="stable")
        self.items = item[order]
        self.offsets = np.concatenate([[0], np.cumsum(np.bincount(cells, minlength=gx * gy))])

    def box(self, xmin: float, ymin: float, xmax: float, ymax: float,
            max_cells: int = 64) -> np.ndarray | None:
        """Items whose boxes touch the cells under a query box (may repeat); None if it spans > max_cells."""
        gx, gy = self.shape
        c, ox, oy = self.cell, self.origin[0], self.origin[1]
        ix0, ix1 = max(math.floor((xmin - ox) / c), 0), min(math.floor((xmax - ox) / c), gx - 1)
        iy0, iy1 = max(math.floor((ymin - oy) / c), 0), min(math.floor((ymax - oy) / c), gy - 1)
        if ix0 > ix1 or iy0 > iy1:
            return self.items[:0]
        if (ix1 - ix0 + 1) * (iy1 - iy0 + 1) > max_cells:
            return None
        off = self.offsets
        if ix0 == ix1:
            return self.items[off[ix0 * gy + iy0]:off[ix0 * gy + iy1 + 1]]
        parts = [self.items[off[ix * gy + iy0]:off[ix * gy + iy1 + 1]] for ix in range(ix0, ix1 + 1)]
        return np.concatenate(parts)

    def points(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point index, item) pairs for every item listed in the cell of each point (K,2)."""
        gx, gy = self.shape
        if self.n_items == 0:
            return np.zeros(0, dtype=np.int64), self.items
        cxy = np.floor((xy - self.origin) / self.cell).astype(np.int64)
        valid = (cxy[:, 0] >= 0) & (cxy[:, 0] < gx) & (cxy[:, 1] >= 0) & (cxy[:, 1] < gy)
        cells = np.where(valid, cxy[:, 0] * gy + cxy[:, 1], 0)
        start = self.offsets[cells]
        counts = np.where(valid, self.offsets[cells + 1] - start, 0)
        point = np.repeat(np.arange(len(xy)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        return point, self.items[np.repeat(start, counts) + local]
