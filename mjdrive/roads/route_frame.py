"""Route coordinates of points near a vehicle that moves along a route, searched in a window of segments.

`Lane.local_coordinates` / `Lane.frame` give a lane's own frame (the exact inverse of `Lane.position`, along
mitred normals). A `RouteFrame` reads the same segments (the lane's segment table) but projects each point
orthogonally onto its nearest segment, searching a window that follows the ego: the progress and offsets
that the roundabout and urban tasks reward (their logs replay bit for bit against it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mjdrive.compiled import announce_compilation, inline, jit
from mjdrive.roads import _spatial as sp
from mjdrive.roads.lane import Lane


class Segments(NamedTuple):
    """A route lane's centre polyline as the kernels read it, each (S,): start x, y [m], unit tangent x, y, length
    [m], start s [m]."""

    x0: np.ndarray
    y0: np.ndarray
    tx: np.ndarray
    ty: np.ndarray
    length: np.ndarray
    s0: np.ndarray


class RouteFrame:
    """Route coordinates (s along, d to the left) [m] of points near a route lane: the nearest point on its
    centre polyline (~0.5 m segments), searching only the segments near the ego's last position (all of them
    with `full`, on reset)."""

    WINDOW = (-8, 20)  # segments searched around the last one [-]

    def __init__(self, lane: Lane):
        table = lane._table  # the lane's segments: start, unit tangent, start s, length
        self.x0, self.y0 = table[:, sp.P0X].copy(), table[:, sp.P0Y].copy()
        self.length = table[:, sp.LEN].copy()
        self.tangent = table[:, sp.TX:sp.TY + 1].copy()
        self.tx, self.ty = table[:, sp.TX].copy(), table[:, sp.TY].copy()
        self.s0 = table[:, sp.S0].copy()
        self.segments = Segments(self.x0, self.y0, self.tx, self.ty, self.length, self.s0)  # the same arrays
        self.segment = 0
        announce_compilation()

    def window(self) -> tuple[int, int]:
        """The segments lo..hi searched next: those near the last point's segment."""
        n = len(self.x0)
        return max(self.segment + self.WINDOW[0], 0), min(self.segment + self.WINDOW[1], n)

    def __call__(self, points: np.ndarray, full: bool = False,
                 window: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) arrays (K,) for points (K,2); the first point moves the search window (`window`: search these
        segments lo..hi instead)."""
        lo, hi = (0, len(self.x0)) if full else window or self.window()
        points = np.ascontiguousarray(points, dtype=np.float64)
        s, d, self.segment = _project(points, self.x0, self.y0, self.tx, self.ty, self.length, self.s0, lo, hi)
        return s, d

    def project(self, points: np.ndarray, s_min: float, s_max: float) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) arrays (K,) of points (K, 2) on their nearest segment between s_min and s_max [m] along the route,
        leaving the search window where it is (other road users near the ego)."""
        lo = max(int(np.searchsorted(self.s0, s_min, side="right")) - 1, 0)
        hi = max(min(int(np.searchsorted(self.s0, s_max, side="right")), len(self.s0)), lo + 1)
        if not len(points):
            return np.zeros(0), np.zeros(0)
        segment = self.segment
        s, d = self(np.ascontiguousarray(points, dtype=np.float64), window=(lo, hi))
        self.segment = segment
        return s, d

    def point(self, x: float, y: float) -> tuple[float, float]:
        """(s, d) [m] of one point (x, y) [m], which moves the search window: `self(np.array([[x, y]]))`'s numbers
        as floats (without arrays)."""
        lo, hi = self.window()
        s, d, segment = nearest_on_segments(float(x), float(y), self.x0, self.y0, self.tx, self.ty, self.length,
                                            self.s0, lo, hi)
        self.segment = int(segment)
        return float(s), float(d)


@inline
def nearest_on_segments(x, y, x0, y0, tx, ty, length, s0, lo, hi):
    """(s, d) [m] of the point (x, y) on its nearest of the segments lo..hi (the first of equally near ones), and
    that segment: inlined into `_project` and the tasks' kernels, called from Python by `RouteFrame.point`."""
    best, best_j, best_along, best_side = np.inf, -1, 0.0, 0.0
    for j in range(lo, hi):
        px, py = x - x0[j], y - y0[j]
        along = px * tx[j] + py * ty[j]
        side = tx[j] * py - ty[j] * px
        clamped = min(max(along, 0.0), length[j])
        beyond = along - clamped
        distance = beyond * beyond + side * side
        if distance < best or best_j < 0:
            best, best_j, best_along, best_side = distance, j, clamped, side
    return s0[best_j] + best_along, best_side, best_j


@jit
def _project(points, x0, y0, tx, ty, length, s0, lo, hi):
    """`RouteFrame.__call__` for the segments lo..hi: (s, d) (K,) and the first point's segment (the first of equally
    near segments)."""
    n_k = len(points)
    s = np.empty(n_k)
    d = np.empty(n_k)
    first = lo
    for k in range(n_k):
        s[k], d[k], j = nearest_on_segments(points[k, 0], points[k, 1], x0, y0, tx, ty, length, s0, lo, hi)
        if k == 0:
            first = j
    return s, d, first
