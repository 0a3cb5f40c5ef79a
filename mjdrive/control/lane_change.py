"""The lane-change manoeuvre: a lateral offset from the path that moves the car by one lane width, as a quintic
polynomial in time (zero lateral speed and acceleration at both ends), its duration the shortest that keeps the
lateral acceleration and jerk of the offset within their bounds:

    d(t) = d0 + w (10 u^3 - 15 u^4 + 6 u^5),  u = t / T,
    max |d'| = 1.875 |w| / T,   max |d''| = (10 / sqrt(3)) |w| / T^2,   max |d'''| = 60 |w| / T^3,

so T = max(sqrt(10 |w| / (sqrt(3) a_max)), (60 |w| / j_max)^(1/3)), and for a car at speed v no shorter than
1.875 |w| / (v tan(heading_max)), the angle it moves across at (tests/test_control.py checks sampled profiles
against the bounds by finite differences). The lateral controller tracks the path shifted by d(t).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

PEAK_RATE = 1.875  # max |d'| of the quintic step per unit width and 1/T
PEAK_ACCEL = 10.0 / math.sqrt(3.0)  # max |d''| per unit width and 1/T^2
PEAK_JERK = 60.0  # max |d'''| per unit width and 1/T^3
SLOW_SPEED = 5.0  # [m/s] a car slower than this (starting from rest) paces its lane change as at this speed


@dataclass(frozen=True)
class LaneOffset:
    """One manoeuvre: from offset `start` [m] to `start + width` [m] (left > 0) over `duration` [s] from `t0` [s]."""

    start: float
    width: float
    duration: float
    t0: float = 0.0

    @classmethod
    def within(cls, start: float, width: float, accel_max: float, jerk_max: float, t0: float = 0.0,
               speed: float = math.inf, heading_max: float = 1.5) -> LaneOffset:
        """The shortest manoeuvre by `width` [m] whose lateral acceleration stays within `accel_max` [m/s^2],
        jerk within `jerk_max` [m/s^3] and, for a car going `speed` [m/s], the angle it moves across at within
        `heading_max` [rad] (slow cars take longer, as if at SLOW_SPEED at least: a car starting from rest
        speeds up while it moves across)."""
        if accel_max <= 0 or jerk_max <= 0 or not 0 < heading_max <= 1.5:
            raise ValueError(f"bounds must be > 0 (heading_max <= 1.5 rad), got {accel_max}, {jerk_max}, "
                             f"{heading_max}")
        w = abs(width)
        slowest = PEAK_RATE * w / (max(speed, SLOW_SPEED) * math.tan(heading_max))
        duration = max(math.sqrt(PEAK_ACCEL * w / accel_max), (PEAK_JERK * w / jerk_max) ** (1.0 / 3.0), slowest,
                       1e-3)
        return cls(start, width, duration, t0)

    @property
    def end(self) -> float:
        """The final offset [m]."""
        return self.start + self.width

    def done(self, t: float) -> bool:
        return t >= self.t0 + self.duration

    def __call__(self, t: float) -> tuple[float, float, float]:
        """(offset [m], its rate [m/s], its acceleration [m/s^2]) at time t [s]."""
        u = min(max((t - self.t0) / self.duration, 0.0), 1.0)
        w, T = self.width, self.duration
        d = self.start + w * u**3 * (10.0 - 15.0 * u + 6.0 * u * u)
        rate = w / T * 30.0 * u * u * (1.0 - u) ** 2
        accel = w / (T * T) * 60.0 * u * (1.0 - u) * (1.0 - 2.0 * u)
        return d, rate, accel
