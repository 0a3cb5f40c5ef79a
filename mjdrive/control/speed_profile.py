"""The route's speed reference (study 002 §4.3: "a velocity command derived from the curvature radius of the
trajectory"): the lanes' speed limits, lowered in curves so that the lateral acceleration and the lateral jerk
stay within comfort bounds, and lowered ahead of every slower stretch so that it is reached braking at most
`decel`.

Curvature: the route's centre line is made of straight lines and arcs, so its curvature jumps where they
meet. The reference reads a smoothed curvature (a Hann-weighted average over a window that is longer where the
route curves gently): the curvature a car can follow, changing its steering rate smoothly, and the
feed-forward the lateral controller uses. The path of that curvature runs `offset` [m] beside the route (inside
the arcs, by about `deviation`): the path the lateral controller tracks, so that its feedback does not fight its
feed-forward. A car steering its rear axle along curvature k at
speed v has, at a point `reference` metres ahead of the rear axle (its centre, where comfort is measured), the
lateral acceleration v^2 k plus a side-slip term and the lateral jerk v^3 (dk/ds + reference d2k/ds2); each
is bounded by its largest value within a car's `footprint` around s:

    v_ref(s) = min(limit(s), sqrt(a_lat / max |k|), (j_lat / max |dk/ds + reference d2k/ds2|)^(1/3)),

then v_ref(s) <= sqrt(v_ref(s')^2 + 2 decel (s' - s)) for every s' ahead (a backward pass).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mjdrive.roads import Lane

SPACING = 0.5  # [m] between the profile's samples
REGION = 40.0  # [m] the curvature smoothing's window follows the sharpest curvature this close


@dataclass(frozen=True)
class SpeedProfile:
    """Samples of the reference along the route: arc length s (M,) [m], speed v (M,) [m/s], the smoothed
    curvature (M,) [1/m] and the offset (M,) [m] from the route of the path that has it; read by linear
    interpolation (constant beyond the ends)."""

    s: np.ndarray
    v: np.ndarray
    curvature: np.ndarray
    offset: np.ndarray
    heading: np.ndarray  # [rad] the smoothed path's heading relative to the route's

    def speed(self, s: float | np.ndarray) -> float | np.ndarray:
        """v_ref [m/s] at arc length(s) s [m]."""
        out = np.interp(s, self.s, self.v)
        return float(out) if np.ndim(out) == 0 else out

    def kappa(self, s: float) -> float:
        """The smoothed curvature [1/m] at arc length s [m]."""
        return float(np.interp(s, self.s, self.curvature))

    def path_offset(self, s: float) -> tuple[float, float]:
        """(offset [m] (left > 0) from the route, heading [rad] relative to the route's) of the smoothed path at
        arc length s [m]."""
        return float(np.interp(s, self.s, self.offset)), float(np.interp(s, self.s, self.heading))


def route_speed_profile(path: Lane, starts: np.ndarray, limits: np.ndarray, lateral_accel: float = 2.0,
                        lateral_jerk: float = 3.0, decel: float = 1.5, deviation: float = 0.2,
                        smoothing: tuple[float, float] = (6.0, 20.0), footprint: float = 6.0,
                        reference: float = 1.375) -> SpeedProfile:
    """The reference along `path` whose stretches from `starts` [m] (ascending, the first 0) have the speed
    limits `limits` [m/s]; comfort bounds `lateral_accel` [m/s^2], `lateral_jerk` [m/s^3], braking `decel`
    [m/s^2]; curvature smoothed over (shortest, longest) `smoothing` [m] windows keeping the smoothed path within
    about `deviation` [m] of the route; the bounds hold over `footprint` [m] around each point
    (a car's length and more: its rear is still in the curve its front has left); `reference` [m]: how far ahead
    of the steered path's point (the rear axle) the comfort is measured (the car's centre)."""
    starts, limits = np.asarray(starts, float), np.asarray(limits, float)
    if starts.shape != limits.shape or not len(starts) or np.any(np.diff(starts) < 0):
        raise ValueError("starts and limits must be equal-length arrays, starts ascending")
    if min(lateral_accel, lateral_jerk, decel, deviation, *smoothing) <= 0 or smoothing[0] > smoothing[1]:
        raise ValueError("lateral_accel, lateral_jerk, decel, deviation and smoothing must be > 0, smoothing "
                         "(shortest, longest)")
    s = np.arange(0.0, path.length + SPACING, SPACING)
    raw = path.curvature(s)
    kappa = _smooth(raw, deviation, *smoothing)
    peak = _window(np.abs(kappa), footprint, np.max)  # the sharpest curvature under the car
    limit = limits[np.clip(np.searchsorted(starts, s, side="right") - 1, 0, len(limits) - 1)]
    slope = np.gradient(kappa, SPACING)
    change = _window(np.abs(slope) + reference * np.abs(np.gradient(slope, SPACING)), footprint, np.max)
    with np.errstate(divide="ignore"):
        v = np.minimum(limit, np.sqrt(lateral_accel / peak))
        v = np.minimum(v, np.cbrt(lateral_jerk / change))
    for i in range(len(v) - 2, -1, -1):  # reach every slower stretch braking at most `decel`
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2.0 * decel * SPACING))
    heading = np.cumsum(kappa - raw) * SPACING  # d'' = kappa_smooth - kappa (small angles)
    return SpeedProfile(s, v, kappa, np.cumsum(heading) * SPACING, heading)


def _hann(values: np.ndarray, half: int) -> np.ndarray:
    """`values` (samples SPACING apart) averaged under a Hann window of 2 half + 1 samples (its slope is continuous:
    a car steering along it never has to change its steering rate at once), the end values repeated."""
    weights = np.hanning(2 * half + 3)[1:-1]
    padded = np.concatenate([np.full(half, values[0]), values, np.full(half, values[-1])])
    return np.convolve(padded, weights / weights.sum(), mode="valid")


def _smooth(kappa: np.ndarray, deviation: float, shortest: float, longest: float) -> np.ndarray:
    """The curvature smoothed over a window as long as keeps the smoothed path within about `deviation` [m] of the
    route: in an arc of curvature k a window W moves it inward by ~ k W^2 / 24 (`shortest` <= W <= `longest` [m]).
    W follows the sharpest curvature within REGION of each point, so it changes only along arcs and straights,
    never across a curvature change (where a changing window would turn the path away for good)."""
    sharpest = _window(np.abs(kappa), REGION, np.max)
    with np.errstate(divide="ignore"):
        width = np.clip(np.sqrt(24.0 * deviation / sharpest), shortest, longest)  # [m]
    halves = np.maximum(1, np.round(0.5 * width / SPACING).astype(int))
    out = np.empty_like(kappa)
    for half in np.unique(halves):  # a handful of distinct widths
        rows = halves == half
        out[rows] = _hann(kappa, int(half))[rows]
    return out


def _window(values: np.ndarray, length: float, reduce) -> np.ndarray:
    """`reduce` (np.mean, np.max) of `values` (samples SPACING apart) over a centred window `length` [m] long
    (the end values repeated beyond the ends)."""
    half = max(1, int(round(0.5 * length / SPACING)))
    padded = np.concatenate([np.full(half, values[0]), values, np.full(half, values[-1])])
    windows = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return reduce(windows, axis=1)
