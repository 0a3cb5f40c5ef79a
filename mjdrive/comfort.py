"""Ride-comfort metrics of one episode (URBAN.md §5.2): percentiles of the chassis acceleration and jerk.

Input: the chassis planar velocity v (N, 2) [m/s] in the world frame and its yaw psi (N,) [rad], sampled
every dt [s]. Signal chain:

1. a = dv/dt in the world frame, by a Savitzky-Golay derivative (`scipy.signal.savgol_filter`, deriv=1):
   the slope of a local least-squares polynomial of order POLYORDER over a window of about WINDOW_S, so
   the derivative comes out smoothed (nuPlan smooths its comfort signals the same way, order 2).
2. Car frame: a_lon = a . (cos psi, sin psi), a_lat = a . (-sin psi, cos psi), + = forward / leftward.
   This is the planar acceleration the chassis (and a passenger) undergoes, the planar part of what
   `Vehicle.acceleration` reads from the IMU. It includes the centripetal term and the sideslip rate,
   needs no yaw rate and no unwrapped yaw, and equals d(speed)/dt and speed * yaw_rate without sideslip.
3. jerk_lon, jerk_lat: the same Savitzky-Golay derivative of the smoothed a_lon, a_lat, i.e. the rates of
   change of the car-frame components (uniform circular motion: constant a_lat, zero jerk).
4. Magnitudes: |a| = hypot(a_lon, a_lat), |jerk| = hypot(jerk_lon, jerk_lat). (nuPlan's ego_jerk
   differentiates |a| instead, which is never larger than this.)

Window: the smallest odd number of samples spanning at least `window_s` (n * dt >= window_s), but at least
the smallest odd number >= polyorder + 2, so each fit is a least-squares smoothing, not an interpolation:
at 10 Hz 5 samples (0.5 s), at 20 Hz 11 (0.55 s), at 5 Hz 5 (1.0 s). Edges use savgol's "interp" mode
(the polynomial of the first / last full window): exact up to order 2, but one-sided, so less exact than
the centred fits on other signals, and a max |jerk| may come from the first or last window.

Short episodes: the window shrinks to the largest odd number of samples in the episode; below the minimum
(5 samples for order 2) the accelerations, jerks and every metric are NaN. Nothing raises for a short
episode, including an empty one; bad inputs (shapes, dt <= 0, NaN or inf) raise ValueError.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

WINDOW_S = 0.5  # [s] Savitzky-Golay window
POLYORDER = 2  # order of the local polynomial fits
PERCENTILE = 95.0  # [%] the reported percentile of |a| and |jerk|
_UNITS = {"accel": "mps2", "jerk": "mps3"}  # as_dict key suffix by field prefix


@dataclass(frozen=True)
class ComfortMetrics:
    """Per-episode comfort metrics; NaN for an episode too short to filter (see the module docstring)."""

    jerk_lon_p95: float  # [m/s^3] 95th percentile of |jerk_lon|
    jerk_lon_max: float  # [m/s^3] max |jerk_lon|
    jerk_lat_p95: float  # [m/s^3]
    jerk_lat_max: float  # [m/s^3]
    jerk_p95: float  # [m/s^3] of |jerk| = hypot(jerk_lon, jerk_lat)
    jerk_max: float  # [m/s^3]
    accel_lon_p95: float  # [m/s^2] 95th percentile of |a_lon|
    accel_lat_p95: float  # [m/s^2]
    accel_p95: float  # [m/s^2] of |a| = hypot(a_lon, a_lat)

    @classmethod
    def nan(cls) -> ComfortMetrics:
        """All metrics NaN: the result for an episode too short to filter."""
        return cls(*(math.nan for _ in fields(cls)))

    def as_dict(self) -> dict[str, float]:
        """Plain floats under unit-suffixed keys, e.g. `jerk_p95_mps3`, `accel_lon_p95_mps2`."""
        return {f"{f.name}_{_UNITS[f.name.split('_')[0]]}": float(getattr(self, f.name)) for f in fields(self)}


@dataclass(frozen=True, eq=False)
class AccelerationProfile:
    """Per-sample signals of one episode, all (N,); accelerations and jerks NaN when `window` is 0."""

    time: np.ndarray  # [s] from 0, step dt
    speed: np.ndarray  # [m/s] signed forward speed v . heading (raw samples, not smoothed)
    a_lon: np.ndarray  # [m/s^2] + = speeding up
    a_lat: np.ndarray  # [m/s^2] + = leftward (a left turn)
    jerk_lon: np.ndarray  # [m/s^3]
    jerk_lat: np.ndarray  # [m/s^3]
    window: int  # [samples] Savitzky-Golay window used; 0 when the episode is too short

    def metrics(self) -> ComfortMetrics:
        """Percentiles and maxima of the absolute values (NaN when `window` is 0)."""
        if self.window == 0:
            return ComfortMetrics.nan()
        jerk, accel = np.hypot(self.jerk_lon, self.jerk_lat), np.hypot(self.a_lon, self.a_lat)
        j_lon, j_lat = np.abs(self.jerk_lon), np.abs(self.jerk_lat)

        def p(x: np.ndarray) -> float:
            return float(np.percentile(x, PERCENTILE))

        return ComfortMetrics(
            jerk_lon_p95=p(j_lon), jerk_lon_max=float(j_lon.max()),
            jerk_lat_p95=p(j_lat), jerk_lat_max=float(j_lat.max()),
            jerk_p95=p(jerk), jerk_max=float(jerk.max()),
            accel_lon_p95=p(np.abs(self.a_lon)), accel_lat_p95=p(np.abs(self.a_lat)), accel_p95=p(accel),
        )  # fmt: skip


def savgol_window(n_samples: int, dt: float, window_s: float = WINDOW_S, polyorder: int = POLYORDER) -> int:
    """The odd Savitzky-Golay window [samples] for an episode of `n_samples` at step dt [s]: the smallest odd
    n with n * dt >= window_s, at least the smallest odd >= polyorder + 2, at most the largest odd <=
    n_samples; 0 when n_samples is below that minimum (the metrics are then NaN)."""
    _check_settings(dt, window_s, polyorder)
    minimum = polyorder + 2 + (polyorder + 1) % 2  # smallest odd >= polyorder + 2
    wanted = max(minimum, math.ceil(window_s / dt - 1e-9))
    wanted += 1 - wanted % 2  # odd
    largest = n_samples - 1 + n_samples % 2  # largest odd <= n_samples
    return 0 if largest < minimum else min(wanted, largest)


def _check_settings(dt: float, window_s: float, polyorder: int) -> None:
    """ValueError unless dt [s] and window_s [s] are finite and > 0 and polyorder is an integer >= 1."""
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite time step > 0 [s], got {dt}")
    if not (math.isfinite(window_s) and window_s > 0):
        raise ValueError(f"window_s must be finite and > 0 [s], got {window_s}")
    if isinstance(polyorder, bool) or not isinstance(polyorder, (int, np.integer)) or polyorder < 1:
        raise ValueError(f"polyorder must be an integer >= 1 (the filter differentiates), got {polyorder!r}")


def _validated(
    velocity_xy: np.ndarray, yaw: np.ndarray, dt: float, window_s: float, polyorder: int
) -> tuple[np.ndarray, np.ndarray]:
    """(velocity (N, 2), yaw (N,)) as float64 arrays; ValueError on bad shapes, values or settings."""
    _check_settings(dt, window_s, polyorder)
    v = np.asarray(velocity_xy, dtype=np.float64)
    psi = np.asarray(yaw, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 2:
        raise ValueError(f"velocity_xy must have shape (N, 2) [m/s], got {v.shape}")
    if psi.shape != (len(v),):
        raise ValueError(f"yaw must have shape (N,) = ({len(v)},) like velocity_xy, got {psi.shape}")
    if not (np.isfinite(v).all() and np.isfinite(psi).all()):
        raise ValueError("velocity_xy and yaw must be finite (no NaN or inf)")
    return v, psi


def acceleration_profile(
    velocity_xy: np.ndarray, yaw: np.ndarray, dt: float, window_s: float = WINDOW_S, polyorder: int = POLYORDER
) -> AccelerationProfile:
    """Per-sample speed, car-frame acceleration and jerk (module docstring) of chassis planar velocities
    `velocity_xy` (N, 2) [m/s, world frame] and yaws `yaw` (N,) [rad] sampled every dt [s]."""
    v, psi = _validated(velocity_xy, yaw, dt, window_s, polyorder)
    n = len(psi)
    heading = np.stack([np.cos(psi), np.sin(psi)], axis=1)  # unit forward
    left = np.stack([-heading[:, 1], heading[:, 0]], axis=1)  # unit leftward
    time, speed = dt * np.arange(n), np.einsum("ij,ij->i", v, heading)
    w = savgol_window(n, dt, window_s, polyorder)
    if w == 0:
        return AccelerationProfile(time, speed, *(np.full(n, np.nan) for _ in range(4)), window=0)
    savgol_filter = load_filter()
    a_xy = savgol_filter(v, w, polyorder, deriv=1, delta=dt, axis=0)  # [m/s^2] world frame
    a = np.stack([np.einsum("ij,ij->i", a_xy, heading), np.einsum("ij,ij->i", a_xy, left)])  # (2, N)
    jerk = savgol_filter(a, w, polyorder, deriv=1, delta=dt, axis=1)  # [m/s^3] (2, N)
    return AccelerationProfile(time, speed, a[0], a[1], jerk[0], jerk[1], window=w)


def finite_difference_jerk(velocity_xy: np.ndarray, yaw: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Unfiltered car-frame jerk (longitudinal, lateral), each (N - 2,) [m/s^3], of the same samples as
    `acceleration_profile`: the acceleration by first differences of the world-frame velocity, turned into the
    car frame at each interval's mean heading, then its components' first differences. No smoothing beyond
    the sampling (two differences pass 97% of a 1 Hz jerk at 10 Hz); empty arrays for fewer than 3 samples."""
    v, psi = _validated(velocity_xy, yaw, dt, WINDOW_S, POLYORDER)
    if len(psi) < 3:
        return np.empty(0), np.empty(0)
    a_xy = np.diff(v, axis=0) / dt  # [m/s^2] world frame, at the intervals' midpoints
    mid = psi[:-1] + 0.5 * np.angle(np.exp(1j * np.diff(psi)))  # [rad] mean heading of each interval
    a_lon = a_xy[:, 0] * np.cos(mid) + a_xy[:, 1] * np.sin(mid)
    a_lat = -a_xy[:, 0] * np.sin(mid) + a_xy[:, 1] * np.cos(mid)
    return np.diff(a_lon) / dt, np.diff(a_lat) / dt


def load_filter() -> Callable:
    """scipy.signal's `savgol_filter`, imported on first use, not with this module: importing scipy.signal takes
    ~0.5 s, which an env pays at its first episode end."""
    from scipy.signal import savgol_filter

    return savgol_filter


def comfort_metrics(
    velocity_xy: np.ndarray, yaw: np.ndarray, dt: float, window_s: float = WINDOW_S, polyorder: int = POLYORDER
) -> ComfortMetrics:
    """p95 and max of |jerk| and p95 of |a| (longitudinal, lateral, magnitude) of one episode, from chassis
    planar velocities (N, 2) [m/s, world frame] and yaws (N,) [rad] sampled every dt [s]."""
    return acceleration_profile(velocity_xy, yaw, dt, window_s, polyorder).metrics()


class ComfortMeter:
    """Collects one episode's chassis samples: `reset()` and `add()` of the initial state at the episode
    start, `add()` after each control step, `metrics(dt)` at the end, dt being the control timestep.

    Sample at the control rate (10-20 Hz; `control_timestep` of the task), not at the physics rate (500 Hz):
    the commands change only at the control rate, and that rate resolves the manoeuvres the metrics are
    about (the two 0.5 s derivative filters already halve the jerk of a ~1.1-1.2 Hz oscillation); at the
    physics rate the velocity also carries contact and suspension chatter, which two differentiations
    amplify into jerk; and a call per physics step costs 25-50 times the calls and memory.

    From a `mjdrive.vehicle.Vehicle`: `fwd, left = vehicle.velocity_body(data)`, `yaw = vehicle.pose(data)[2]`,
    then `add((fwd * cos(yaw) - left * sin(yaw), fwd * sin(yaw) + left * cos(yaw)), yaw)`.
    """

    def __init__(self, capacity: int = 512):
        """Buffers for `capacity` samples [control steps]; they double when full."""
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1 [samples], got {capacity}")
        self._velocity = np.empty((capacity, 2))  # [m/s] world frame
        self._yaw = np.empty(capacity)  # [rad]
        self._n = 0

    def __len__(self) -> int:
        return self._n

    def reset(self) -> None:
        """Forget the samples (the buffers are kept)."""
        self._n = 0

    def add(self, velocity_xy: tuple[float, float] | np.ndarray, yaw: float) -> None:
        """Append one sample: chassis planar velocity (2,) [m/s] in the world frame and yaw [rad]."""
        v = np.asarray(velocity_xy, dtype=np.float64)
        if v.shape != (2,):
            raise ValueError(f"velocity_xy must have shape (2,) [m/s], got {v.shape}")
        if not (np.isfinite(v).all() and math.isfinite(yaw)):
            raise ValueError(f"velocity_xy and yaw must be finite, got {v.tolist()}, {yaw}")
        self.append(float(v[0]), float(v[1]), float(yaw))

    def append(self, vx: float, vy: float, yaw: float) -> None:
        """`add` for callers that checked their finite scalars (the per-step path): velocity [m/s], yaw [rad]."""
        n = self._n
        if n == len(self._yaw):
            self._velocity = np.concatenate([self._velocity, np.empty_like(self._velocity)])
            self._yaw = np.concatenate([self._yaw, np.empty_like(self._yaw)])
        row = self._velocity[n]
        row[0], row[1] = vx, vy
        self._yaw[n] = yaw
        self._n = n + 1

    def profile(self, dt: float, window_s: float = WINDOW_S, polyorder: int = POLYORDER) -> AccelerationProfile:
        """`acceleration_profile` of the samples so far, taken every dt [s]."""
        return acceleration_profile(self._velocity[: self._n], self._yaw[: self._n], dt, window_s, polyorder)

    def metrics(self, dt: float, window_s: float = WINDOW_S, polyorder: int = POLYORDER) -> ComfortMetrics:
        """`comfort_metrics` of the samples so far, taken every dt [s] (NaN when too few)."""
        return self.profile(dt, window_s, polyorder).metrics()

    def unfiltered_jerk(self, dt: float) -> tuple[float, float]:
        """(p95, max) [m/s^3] of the magnitude of `finite_difference_jerk` of the samples so far, taken every
        dt [s]: the jerk without the Savitzky-Golay filter, to compare with figures filtered otherwise (NaN for
        fewer than 3 samples)."""
        jerk_lon, jerk_lat = finite_difference_jerk(self._velocity[: self._n], self._yaw[: self._n], dt)
        if len(jerk_lon) == 0:
            return math.nan, math.nan
        jerk = np.hypot(jerk_lon, jerk_lat)
        return float(np.percentile(jerk, PERCENTILE)), float(jerk.max())
