"""Route coordinates of points near a vehicle that moves along a route, searched in a window of segments."""

from __future__ import annotations

import numpy as np


class RouteFrame:
    """Route coordinates (s along, d to the left) [m] of points, searching only the route segments near the
    ego's last position (the route is a polyline of ~0.5 m segments; a full search on `reset`)."""

    WINDOW = (-8, 20)  # segments searched around the last one [-]

    def __init__(self, polyline: np.ndarray):
        self.x0, self.y0 = polyline[:-1, 0].copy(), polyline[:-1, 1].copy()
        delta = np.diff(polyline, axis=0)
        self.length = np.hypot(delta[:, 0], delta[:, 1])
        self.tangent = delta / self.length[:, None]
        self.tx, self.ty = self.tangent[:, 0].copy(), self.tangent[:, 1].copy()
        self.s0 = np.concatenate([[0.0], np.cumsum(self.length)[:-1]])
        self.segment = 0

    def __call__(self, points: np.ndarray, full: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """(s, d) arrays (K,) for points (K,2); the first point moves the search window."""
        n = len(self.x0)
        lo, hi = (0, n) if full else (max(self.segment + self.WINDOW[0], 0), min(self.segment + self.WINDOW[1], n))
        tx, ty = self.tx[lo:hi], self.ty[lo:hi]
        px, py = points[:, 0:1] - self.x0[lo:hi], points[:, 1:2] - self.y0[lo:hi]  # (K, W)
        along = px * tx + py * ty
        side = tx * py - ty * px
        clamped = np.minimum(np.maximum(along, 0.0), self.length[lo:hi])
        beyond = along - clamped
        j = np.argmin(beyond * beyond + side * side, axis=1)
        rows = np.arange(len(points))
        self.segment = lo + int(j[0])
        return self.s0[lo + j] + clamped[rows, j], side[rows, j]
