"""Planar geometry: angle wrapping, points of oriented boxes (vehicle corners) and constant-curvature
reference paths for road building.

A `Path` is a start pose plus pieces of constant curvature (lines and circular arcs). Sampling it at a
lateral offset gives the exact parallel curve (an arc of radius R offset by d to its inside has radius
R - d), so lane centres and edges of curved roads are exact, not offsets of polylines.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

STEP = 0.5  # [m] largest spacing of sampled polyline points


def wrap_angle(angle: ArrayLike):
    """Wrap an angle [rad] (scalar or array) to [-pi, pi); a Python float gives a float (the same number: Python's
    float % is numpy's floored remainder)."""
    if type(angle) is float:  # the per-step path: no array round trip
        return (angle + math.pi) % (2 * math.pi) - math.pi
    return (np.asarray(angle, dtype=float) + np.pi) % (2 * np.pi) - np.pi


BOX_CORNERS = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]])  # front-left, front-right, rear-right, rear-left


def box_points(centre: ArrayLike, heading: ArrayLike, local: ArrayLike) -> np.ndarray:
    """World points (..., M, 2) [m] of points `local` (M,2) [m] given in the frames of boxes at `centre`
    (..., 2) [m] with `heading` (...) [rad] (x ahead, y to the left)."""
    centre, local = np.asarray(centre, dtype=float), np.asarray(local, dtype=float)
    heading = np.asarray(heading, dtype=float)
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    lx, ly = local[:, 0], local[:, 1]
    return np.stack([centre[..., :1] + c * lx - s * ly, centre[..., 1:] + s * lx + c * ly], axis=-1)


def footprint(x: float, y: float, yaw: float, length: float, width: float, centre: bool = False,
              cos_sin: tuple[float, float] | None = None) -> np.ndarray:
    """The four corners (4,2) [m] of a vehicle's rectangle: front-left, front-right, rear-right, rear-left
    (`box_points` of one box, in scalars for the per-step path: the same operations, libm's cosine and sine as
    numpy's). `centre`: (5,2), (x, y) first; `cos_sin`: the cosine and sine of `yaw` when the caller has them."""
    c, s = (math.cos(yaw), math.sin(yaw)) if cos_sin is None else (float(cos_sin[0]), float(cos_sin[1]))
    x, y = float(x), float(y)
    hl, hw = 0.5 * length, 0.5 * width
    corners = [[x + c * hl - s * hw, y + s * hl + c * hw], [x + c * hl - s * -hw, y + s * hl + c * -hw],
               [x + c * -hl - s * -hw, y + s * -hl + c * -hw], [x + c * -hl - s * hw, y + s * -hl + c * hw]]
    return np.array([[x, y], *corners] if centre else corners)


def unit(heading: float) -> np.ndarray:
    """Unit vector (2,) of a heading [rad]."""
    return np.array([math.cos(heading), math.sin(heading)])


def left_normal(heading: float) -> np.ndarray:
    """Unit vector (2,) pointing left of a heading [rad]."""
    return np.array([-math.sin(heading), math.cos(heading)])


@dataclass
class Path:
    """A reference line: start point [m], start heading [rad], pieces (length [m], curvature [1/m]).

    Curvature > 0 turns left. Methods that add pieces return the path, so calls chain.
    """

    start: np.ndarray
    heading: float
    pieces: list[tuple[float, float]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.start = np.asarray(self.start, dtype=float).reshape(2)
        self.heading = float(self.heading)

    def line(self, length: float) -> Path:
        """Append a straight piece of `length` [m]."""
        if length < 0:
            raise ValueError(f"negative line length {length}")
        if length > 1e-9:
            self.pieces.append((float(length), 0.0))
        return self

    def arc(self, radius: float, angle: float) -> Path:
        """Append a circular arc of `radius` [m] turning by `angle` [rad] (> 0 left, < 0 right)."""
        if radius <= 0:
            raise ValueError(f"arc radius must be positive, got {radius}")
        if abs(angle) > 1e-12:
            self.pieces.append((float(radius * abs(angle)), math.copysign(1.0 / radius, angle)))
        return self

    @property
    def length(self) -> float:
        """Length of the reference line [m]."""
        return float(sum(length for length, _ in self.pieces))

    def end(self) -> tuple[np.ndarray, float]:
        """End point (2,) [m] and end heading [rad] (unwrapped)."""
        p, h = self.start.copy(), self.heading
        for length, k in self.pieces:
            p, h = _advance(p, h, length, k)
        return p, h

    def sample(self, offset: float = 0.0, step: float = STEP) -> np.ndarray:
        """Points (N,2) [m] of the curve parallel to the path at `offset` [m] (> 0 left), spacing <= step."""
        p, h = self.start.copy(), self.heading
        out = [p + offset * left_normal(h)]
        for length, k in self.pieces:
            scale = 1.0 - k * offset  # offset curve length / reference length
            if scale <= 1e-9:
                raise ValueError(f"offset {offset} m reaches the centre of an arc of radius {1 / abs(k):.2f}")
            n = max(1, math.ceil(length * scale / step - 1e-9))
            u = np.linspace(0.0, length, n + 1)[1:]
            if k == 0.0:
                pts = p + u[:, None] * unit(h) + offset * left_normal(h)
            else:
                hu = h + k * u
                centre = p + left_normal(h) / k
                pts = centre + (offset - 1.0 / k) * np.column_stack([-np.sin(hu), np.cos(hu)])
            out.append(pts)
            p, h = _advance(p, h, length, k)
        return np.vstack(out)


def _advance(p: np.ndarray, h: float, length: float, k: float) -> tuple[np.ndarray, float]:
    """Pose after driving `length` [m] at curvature `k` [1/m] from (p, h)."""
    if k == 0.0:
        return p + length * unit(h), h
    h1 = h + k * length
    return p + (left_normal(h) - left_normal(h1)) / k, h1


def fillet(a: ArrayLike, ha: float, b: ArrayLike, hb: float, radius: float | None = None) -> Path:
    """Line - arc - line path from pose (a, ha) to pose (b, hb) [m, rad].

    The arc is tangent to both rays; its radius is the largest that fits (or `radius` [m] if given and it
    fits). Parallel rays must be collinear (a straight connection). Raises ValueError if impossible.
    """
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    ta, tb = unit(ha), unit(hb)
    phi = float(wrap_angle(hb - ha))
    rel = b - a
    if abs(phi) < 1e-9:
        along, lateral = float(ta @ rel), float(ta[0] * rel[1] - ta[1] * rel[0])
        if abs(lateral) > 1e-6 or along <= 0:
            raise ValueError("parallel poses that are not on one line need an s_curve, not a fillet")
        return Path(a, ha).line(along)
    la, lb = np.linalg.solve(np.column_stack([ta, tb]), rel)  # a + la*ta == b - lb*tb
    if la < -1e-9 or lb < -1e-9:
        raise ValueError(f"no fillet: the rays meet behind a pose (la={la:.3f} m, lb={lb:.3f} m)")
    half = math.tan(abs(phi) / 2)
    tangent = min(la, lb) if radius is None else radius * half
    if tangent > min(la, lb) + 1e-9:
        raise ValueError(f"fillet radius {radius} m does not fit")
    return Path(a, ha).line(max(la - tangent, 0.0)).arc(tangent / half, phi).line(max(lb - tangent, 0.0))


def s_curve(a: ArrayLike, heading: float, length: float, shift: float) -> Path:
    """Two opposite arcs moving sideways by `shift` [m] (> 0 left) over `length` [m] along `heading`."""
    if abs(shift) < 1e-9:
        return Path(a, heading).line(length)
    angle = 2.0 * math.atan2(abs(shift), length)
    radius = length / (2.0 * math.sin(angle))
    sign = math.copysign(1.0, shift)
    return Path(a, heading).arc(radius, sign * angle).arc(radius, -sign * angle)


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (K,2) of points (N,2), counter-clockwise (monotone chain)."""
    pts = sorted({(round(float(px), 9), round(float(py), 9)) for px, py in points})

    def half(seq):
        out: list[tuple[float, float]] = []
        for q in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (q[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (q[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(q)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])
