"""A lane: a centre polyline with a width, markings on both sides and a speed limit.

Lane frame: s [m] is the arc length along the centre polyline, d [m] the lateral offset, > 0 to the LEFT
of the direction of travel. Vertex normals are mitred (scaled by 1/cos of half the turn), so the curve at
constant d is the exact parallel polyline and `local_coordinates` inverts `position` exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import ArrayLike

from mjdrive.compiled import jit
from mjdrive.roads import _spatial as sp
from mjdrive.roads.geometry import wrap_angle

_MAX_END_TURN = 0.3  # [rad] turn at the 2nd / 2nd-last vertex up to which end headings are extrapolated


class Marking(IntEnum):
    """Painted line on a lane boundary."""

    NONE = 0
    BROKEN = 1
    SOLID = 2


@dataclass(eq=False)
class Lane:
    """One directed lane. `centre` (N,2) [m] runs in the direction of travel."""

    centre: np.ndarray  # (N, 2) [m]
    width: float = 3.5  # [m]
    left_marking: Marking = Marking.NONE
    right_marking: Marking = Marking.NONE
    speed_limit: float = 30 / 3.6  # [m/s]
    name: str = ""
    in_junction: bool = False  # connector inside a junction / roundabout entry or exit: no markings
    priority: int = 0  # right-of-way rank where lanes cross or merge: the lower rank yields
    s: np.ndarray = field(init=False, repr=False)  # (N,) [m] arc length at the vertices
    length: float = field(init=False)  # [m]
    seg_length: np.ndarray = field(init=False, repr=False)  # (N-1,) [m]
    seg_tangent: np.ndarray = field(init=False, repr=False)  # (N-1, 2) unit tangents
    seg_heading: np.ndarray = field(init=False, repr=False)  # (N-1,) [rad]
    vertex_heading: np.ndarray = field(init=False, repr=False)  # (N,) [rad], unwrapped
    vertex_curvature: np.ndarray = field(init=False, repr=False)  # (N,) [1/m], > 0 turning left
    normals: np.ndarray = field(init=False, repr=False)  # (N, 2) mitred left normals

    def __post_init__(self) -> None:
        c = np.array(self.centre, dtype=float).reshape(-1, 2)
        if len(c) > 1:
            keep = np.concatenate([[True], np.hypot(*np.diff(c, axis=0).T) > 1e-9])
            c = c[keep]
        if len(c) < 2:
            raise ValueError(f"lane {self.name!r} needs at least 2 distinct points")
        self.centre = c
        self.width = float(self.width)
        self.left_marking, self.right_marking = Marking(self.left_marking), Marking(self.right_marking)
        chord = np.diff(c, axis=0)
        self.seg_length = np.hypot(chord[:, 0], chord[:, 1])
        self.seg_tangent = chord / self.seg_length[:, None]
        self.s = np.concatenate([[0.0], np.cumsum(self.seg_length)])
        self.length = float(self.s[-1])
        raw = np.arctan2(self.seg_tangent[:, 1], self.seg_tangent[:, 0])
        turn = wrap_angle(np.diff(raw))  # (N-2,) turn at the interior vertices
        hseg = raw[0] + np.concatenate([[0.0], np.cumsum(turn)])  # unwrapped segment headings
        self.seg_heading = wrap_angle(hseg)
        vh = np.empty(len(c))
        vh[1:-1] = hseg[:-1] + turn / 2
        vh[0], vh[-1] = hseg[0], hseg[-1]
        if len(turn) and abs(turn[0]) < _MAX_END_TURN:  # tangent at the ends, assuming constant curvature
            vh[0] -= turn[0] * self.seg_length[0] / (self.seg_length[0] + self.seg_length[1])
        if len(turn) and abs(turn[-1]) < _MAX_END_TURN:
            vh[-1] += turn[-1] * self.seg_length[-1] / (self.seg_length[-1] + self.seg_length[-2])
        self.vertex_heading = vh
        ref = np.concatenate([hseg, hseg[-1:]])  # a segment heading adjacent to each vertex
        scale = 1.0 / np.maximum(np.cos(vh - ref), 0.5)
        self.normals = np.column_stack([-np.sin(vh), np.cos(vh)]) * scale[:, None]
        k = np.zeros(len(c))
        if len(c) > 2:  # Menger curvature of consecutive vertex triples (exact on circles)
            a, b = chord[:-1], chord[1:]
            cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
            k[1:-1] = 2 * cross / (self.seg_length[:-1] * self.seg_length[1:] * np.hypot(*(a + b).T))
            k[0], k[-1] = k[1], k[-2]
        self.vertex_curvature = k
        self._table = sp.segment_table(c, self.normals, vh, self.width / 2)

    # --- evaluation along s ------------------------------------------------------------------------
    def _locate_s(self, s: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        s = np.asarray(s, dtype=float)
        sc = np.clip(s, 0.0, self.length)
        i = np.clip(np.searchsorted(self.s, sc, side="right") - 1, 0, len(self.s) - 2)
        t = (sc - self.s[i]) / self.seg_length[i]
        return s, sc, i, t

    def position(self, s: ArrayLike, d: ArrayLike = 0.0) -> np.ndarray:
        """World point(s) (..., 2) [m] at arc length s [m] and lateral offset d [m] (left > 0).

        Beyond the ends the lane is extended along its end tangents.
        """
        s, sc, i, t = self._locate_s(s)
        d = np.asarray(d, dtype=float)[..., None]
        t2 = t[..., None]
        normal = self.normals[i] + t2 * (self.normals[i + 1] - self.normals[i])
        p = self.centre[i] + t2 * (self.centre[i + 1] - self.centre[i]) + d * normal
        over = (s - sc)[..., None]
        if np.any(over != 0):
            h = np.where(s < 0, self.vertex_heading[0], self.vertex_heading[-1])[..., None]
            p = p + over * np.concatenate([np.cos(h), np.sin(h)], axis=-1)
        return p

    def point(self, s: float) -> tuple[float, float]:
        """The centre-line point (x, y) [m] at arc length s [m], as floats: `position(s)`'s numbers (in one compiled
        pass within [0, length])."""
        if 0.0 <= s <= self.length:
            return _centre_point(self.s, self.seg_length, self.centre, self.normals, float(s))
        x, y = self.position(s).tolist()
        return x, y

    def heading(self, s: ArrayLike):
        """Direction of travel [rad] in [-pi, pi) at arc length s [m] (interpolated vertex headings)."""
        _, _, i, t = self._locate_s(s)
        vh = self.vertex_heading
        return wrap_angle(vh[i] + t * (vh[i + 1] - vh[i]))

    def curvature(self, s: ArrayLike):
        """Signed curvature [1/m] (> 0 turning left) at arc length s [m]."""
        _, _, i, t = self._locate_s(s)
        k = self.vertex_curvature
        return k[i] + t * (k[i + 1] - k[i])

    def max_abs_curvature(self, start: float, stop: float, n: int = 8) -> float:
        """max |curvature| [1/m] at the n evenly spaced arc lengths from `start` to `stop` [m]
        (`np.max(np.abs(self.curvature(np.linspace(start, stop, n))))`, the same number, in one compiled pass)."""
        return _max_abs_curvature(self.s, self.seg_length, self.vertex_curvature, self.length, float(start),
                                  float(stop), int(n))

    # --- projection --------------------------------------------------------------------------------
    def local_coordinates(self, xy: ArrayLike, near_s: float | None = None, window: float = 25.0):
        """(s, d) [m] of world point(s) xy (2,) or (K,2); s is clamped to [0, length].

        For a single point returns floats, else arrays (K,). With `near_s` (a single point whose s is known
        to be within `window` [m] of near_s, e.g. last step's), only those segments are searched: O(window)
        instead of O(length) on long routes.
        """
        xy = np.asarray(xy, dtype=float)
        single = xy.ndim == 1
        if single and near_s is not None:
            return self.frame(xy, near_s, window)[:2]
        if single:  # in one compiled pass
            s, d = sp.nearest_point(self._table, float(xy[0]), float(xy[1]))
            return float(s), float(d)
        pts = xy.reshape(-1, 2)
        s_out, d_out = np.empty(len(pts)), np.empty(len(pts))
        chunk = max(1, 2_000_000 // len(self._table))
        for k0 in range(0, len(pts), chunk):
            p = pts[k0:k0 + chunk]
            t, d, dist, _ = sp.project(self._table, p[:, 0:1], p[:, 1:2])
            j = np.argmin(dist, axis=1)
            rows = np.arange(len(p))
            s_out[k0:k0 + chunk] = self._table[j, sp.S0] + np.clip(t[rows, j], 0, 1) * self._table[j, sp.LEN]
            d_out[k0:k0 + chunk] = d[rows, j]
        if single:
            return float(s_out[0]), float(d_out[0])
        return s_out, d_out

    def frame(self, xy: ArrayLike, near_s: float | None = None, window: float = 25.0
              ) -> tuple[float, float, float]:
        """(s [m], d [m], lane heading [rad]) at the projection of one point, searching only within
        `window` [m] of `near_s` when given (the fast path for a car tracked along a long route)."""
        rows = self._table
        if near_s is not None:
            lo, hi = np.searchsorted(rows[:, sp.S0], (near_s - window, near_s + window))
            rows = rows[max(lo - 1, 0) : max(hi, 1)]
        t, d, dist, _ = sp.project(rows, xy[0], xy[1])
        j = int(np.argmin(dist))
        tc = min(max(float(t[j]), 0.0), 1.0)
        row = rows[j]
        heading = wrap_angle(row[sp.H0] + tc * row[sp.DH])
        return float(row[sp.S0] + tc * row[sp.LEN]), float(d[j]), float(heading)

    # --- outline ------------------------------------------------------------------------------------
    def left_edge(self) -> np.ndarray:
        """Left boundary polyline (N,2) [m] (parallel at +width/2)."""
        return self.centre + 0.5 * self.width * self.normals

    def right_edge(self) -> np.ndarray:
        """Right boundary polyline (N,2) [m] (parallel at -width/2)."""
        return self.centre - 0.5 * self.width * self.normals

    def polygon(self) -> np.ndarray:
        """Outline (2N,2) [m] of the lane strip, counter-clockwise."""
        return np.vstack([self.right_edge(), self.left_edge()[::-1]])

    def __repr__(self) -> str:
        return f"Lane({self.name!r}, length={self.length:.1f} m, width={self.width} m)"


def resample(polyline: np.ndarray, step: float = 0.5) -> np.ndarray:
    """Polyline (N,2) with points inserted so consecutive points are <= step [m] apart."""
    polyline = np.asarray(polyline, dtype=float)
    out = [polyline[:1]]
    for a, b in zip(polyline[:-1], polyline[1:], strict=True):
        n = max(1, math.ceil(np.hypot(*(b - a)) / step - 1e-9))
        out.append(a + np.linspace(0, 1, n + 1)[1:, None] * (b - a))
    return np.vstack(out)


@jit
def _max_abs_curvature(s_vertex, seg_length, curvature, length, start, stop, n):
    """`Lane.max_abs_curvature`: numpy's linspace points (i * step + start, the last one `stop`), each located as
    `Lane._locate_s` does and interpolated as `Lane.curvature`, operation for operation."""
    step = (stop - start) / (n - 1) if n > 1 else 0.0
    last = len(s_vertex) - 2
    best = 0.0
    for k in range(n):
        if n > 1 and k == n - 1:
            s = stop
        elif step == 0.0:
            s = k / (n - 1) * (stop - start) + start if n > 1 else start
        else:
            s = k * step + start
        sc = min(max(s, 0.0), length)
        i = min(max(np.searchsorted(s_vertex, sc, side="right") - 1, 0), last)
        t = (sc - s_vertex[i]) / seg_length[i]
        value = abs(curvature[i] + t * (curvature[i + 1] - curvature[i]))
        if value > best:
            best = value
    return best


@jit
def _centre_point(s_vertex, seg_length, centre, normals, s):
    """`Lane.point` for s in [0, length]: `Lane._locate_s` and `Lane.position` at d = 0, operation for operation
    (the zero offset along the interpolated normal included)."""
    i = min(max(np.searchsorted(s_vertex, s, side="right") - 1, 0), len(s_vertex) - 2)
    t = (s - s_vertex[i]) / seg_length[i]
    nx = normals[i, 0] + t * (normals[i + 1, 0] - normals[i, 0])
    ny = normals[i, 1] + t * (normals[i + 1, 1] - normals[i, 1])
    x = centre[i, 0] + t * (centre[i + 1, 0] - centre[i, 0]) + 0.0 * nx
    y = centre[i, 1] + t * (centre[i + 1, 1] - centre[i, 1]) + 0.0 * ny
    return x, y
