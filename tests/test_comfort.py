"""Comfort metrics against analytic motions, short episodes, bad inputs, and the sedan's physics at 10 Hz."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from mjdrive import world
from mjdrive.comfort import (
    ComfortMeter,
    ComfortMetrics,
    acceleration_profile,
    comfort_metrics,
    finite_difference_jerk,
    savgol_window,
)
from mjdrive.vehicle import Vehicle

RATES = [0.1, 0.05]  # [s] control timesteps: 10 Hz and 20 Hz
P95_ABS_SIN = math.sin(0.95 * math.pi / 2)  # 95th percentile of |sin| over uniform phases, 0.99692


def straight(speed: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """World-frame velocities (N, 2) [m/s] and yaws (N,) [rad] of a car driving straight at heading `yaw`."""
    return np.outer(speed, (math.cos(yaw), math.sin(yaw))), np.full(len(speed), yaw)


@pytest.mark.parametrize("dt", RATES)
def test_constant_acceleration_has_no_jerk(dt):
    a, v0 = 1.7, 3.0  # [m/s^2], [m/s]
    t = dt * np.arange(round(8.0 / dt))
    m = comfort_metrics(*straight(v0 + a * t, 0.7), dt)
    # Savitzky-Golay fits of order 2 are exact on a linear speed and a constant acceleration, edges included.
    assert m.accel_lon_p95 == pytest.approx(a, abs=1e-9)
    assert m.accel_p95 == pytest.approx(a, abs=1e-9)
    assert m.accel_lat_p95 < 1e-9
    assert m.jerk_max < 1e-6 and m.jerk_lon_max < 1e-6 and m.jerk_lat_max < 1e-6


@pytest.mark.parametrize("dt", RATES)
def test_sinusoidal_speed(dt):
    v0, amp, omega = 10.0, 2.0, 1.0  # [m/s], [m/s], [rad/s]
    t = dt * np.arange(round(30.0 / dt))
    vel, yaw = straight(v0 + amp * np.sin(omega * t), -2.0)
    m = comfort_metrics(vel, yaw, dt)
    # At omega = 1 rad/s the 0.5 s filters keep 98.5-99 % of the jerk amplitude (two derivative passes) and
    # ~99.4 % of the acceleration (one pass); the window at either edge is fitted one-sided, which is less
    # exact. Hence 3 % on the max jerk and 2 % on the p95 of |a_lon|.
    assert m.jerk_lon_max == pytest.approx(amp * omega**2, rel=0.03)
    assert m.accel_lon_p95 == pytest.approx(amp * omega * P95_ABS_SIN, rel=0.02)
    assert m.jerk_lat_max < 1e-9 and m.jerk_max == pytest.approx(m.jerk_lon_max)
    p = acceleration_profile(vel, yaw, dt)
    inner = slice(p.window, -p.window)  # away from the one-sided edge fits
    np.testing.assert_allclose(p.a_lon[inner], amp * omega * np.cos(omega * t[inner]), atol=0.01 * amp * omega)
    np.testing.assert_allclose(p.jerk_lon[inner], -amp * omega**2 * np.sin(omega * t[inner]),
                               atol=0.02 * amp * omega**2)  # fmt: skip
    np.testing.assert_allclose(p.speed, v0 + amp * np.sin(omega * t))


@pytest.mark.parametrize("turn", [1.0, -1.0])  # + = left (counter-clockwise)
def test_uniform_circular_motion(turn):
    dt, v, radius = 0.1, 10.0, 50.0  # [s], [m/s], [m]
    t = dt * np.arange(round(60.0 / dt))  # almost two laps: the yaw wraps around +-pi
    yaw = np.angle(np.exp(1j * (0.3 + turn * v / radius * t)))
    vel = v * np.c_[np.cos(yaw), np.sin(yaw)]
    p = acceleration_profile(vel, yaw, dt)
    np.testing.assert_allclose(p.a_lat, turn * v**2 / radius, rtol=2e-3)  # the filter's gain at v/R = 0.2 rad/s
    np.testing.assert_allclose(p.a_lon, 0.0, atol=1e-4)  # inside ~1e-14; the one-sided edge fits ~4e-5
    np.testing.assert_allclose(p.speed, v)
    m = p.metrics()
    assert m.accel_lat_p95 == pytest.approx(v**2 / radius, rel=2e-3)
    assert m.accel_p95 == pytest.approx(m.accel_lat_p95)
    # [m/s^3] The world-frame jerk vector would have |j| = v^3/R^2 = 0.4. Inside, the car-frame jerk is ~1e-13;
    # the one-sided fits of the first and last windows reach 0.012.
    assert m.jerk_p95 < 1e-9 and m.jerk_max < 0.02


def test_speed_step_gives_finite_jerk():
    dt, dv = 0.1, 1.0  # [s], [m/s]
    speed = np.where(np.arange(60) < 30, 10.0, 10.0 + dv)
    p = acceleration_profile(*straight(speed, 1.0), dt)
    m = p.metrics()
    assert np.isfinite([m.jerk_max, m.jerk_lon_p95, m.accel_lon_p95]).all()
    # The 5-sample derivative kernel is k / (10 dt), k = -2..2: a_lon across the step is (0.2, 0.3, 0.3, 0.2)
    # dv/dt and the jerk peaks at (1 * 0.3 + 2 * 0.3) / 10 dv/dt^2 (raw differences: dv/dt, dv/dt^2).
    assert p.window == 5
    assert p.a_lon.max() == pytest.approx(0.3 * dv / dt)
    assert m.jerk_lon_max == pytest.approx(0.09 * dv / dt**2)
    assert np.sum(p.a_lon) * dt == pytest.approx(dv, rel=1e-9)  # the filter keeps the speed change


def test_window_rule():
    assert savgol_window(1000, 0.1) == 5  # 0.5 s at 10 Hz
    assert savgol_window(1000, 0.05) == 11  # the smallest odd count covering 0.5 s at 20 Hz
    assert savgol_window(1000, 0.2) == 5  # 5 Hz: the minimum for order 2 (1.0 s)
    assert savgol_window(8, 0.05) == 7 and savgol_window(6, 0.05) == 5  # short: the largest odd that fits
    assert [savgol_window(n, 0.1) for n in range(5)] == [0] * 5
    assert savgol_window(1000, 0.1, polyorder=1) == 5 and savgol_window(3, 0.1, polyorder=1) == 3


@pytest.mark.parametrize("n", [0, 1, 2, 4])
def test_too_short_episode_is_nan(n):
    vel, yaw = straight(np.linspace(0.0, 1.0, n), 0.0)
    assert all(math.isnan(x) for x in comfort_metrics(vel, yaw, 0.1).as_dict().values())
    p = acceleration_profile(vel, yaw, 0.1)
    assert p.window == 0 and len(p.a_lon) == n and np.isnan(p.jerk_lat).all()
    np.testing.assert_allclose(p.time, 0.1 * np.arange(n))


def test_five_samples_use_the_whole_episode():
    dt, a = 0.05, 2.0  # [s], [m/s^2]
    p = acceleration_profile(*straight(4.0 + a * dt * np.arange(5), 0.0), dt)
    assert p.window == 5
    np.testing.assert_allclose(p.a_lon, a)
    assert p.metrics().jerk_max < 1e-9


def test_as_dict_keys():
    d = comfort_metrics(*straight(np.linspace(0.0, 5.0, 50), 0.0), 0.1).as_dict()
    assert list(d) == [
        "jerk_lon_p95_mps3", "jerk_lon_max_mps3", "jerk_lat_p95_mps3", "jerk_lat_max_mps3",
        "jerk_p95_mps3", "jerk_max_mps3", "accel_lon_p95_mps2", "accel_lat_p95_mps2", "accel_p95_mps2",
    ]  # fmt: skip
    assert all(type(v) is float for v in d.values())
    assert set(ComfortMetrics.nan().as_dict()) == set(d)


@pytest.mark.parametrize(
    "vel, yaw, dt, kwargs",
    [
        (np.zeros((5, 3)), np.zeros(5), 0.1, {}),
        (np.zeros(5), np.zeros(5), 0.1, {}),
        (np.zeros((5, 2)), np.zeros(4), 0.1, {}),
        (np.zeros((5, 2)), np.zeros((5, 1)), 0.1, {}),
        (np.full((5, 2), np.nan), np.zeros(5), 0.1, {}),
        (np.zeros((5, 2)), np.full(5, np.inf), 0.1, {}),
        (np.zeros((5, 2)), np.zeros(5), 0.0, {}),
        (np.zeros((5, 2)), np.zeros(5), -0.1, {}),
        (np.zeros((5, 2)), np.zeros(5), math.nan, {}),
        (np.zeros((5, 2)), np.zeros(5), 0.1, {"window_s": 0.0}),
        (np.zeros((5, 2)), np.zeros(5), 0.1, {"polyorder": 0}),
        (np.zeros((5, 2)), np.zeros(5), 0.1, {"polyorder": 1.5}),
    ],
)
def test_bad_inputs_raise(vel, yaw, dt, kwargs):
    with pytest.raises(ValueError):
        comfort_metrics(vel, yaw, dt, **kwargs)


def test_bad_window_settings_raise():
    with pytest.raises(ValueError):
        savgol_window(100, 0.0)
    with pytest.raises(ValueError):
        savgol_window(100, 0.1, window_s=math.inf)


def test_meter_matches_the_function():
    dt = 0.1  # [s]
    t = dt * np.arange(70)
    vel, yaw = straight(5.0 + np.sin(t), 0.2)
    meter = ComfortMeter(capacity=4)  # grows past its first buffers
    for v, psi in zip(vel, yaw, strict=True):
        meter.add(v, psi)
    assert len(meter) == 70
    assert meter.metrics(dt) == comfort_metrics(vel, yaw, dt)
    meter.reset()
    assert len(meter) == 0 and math.isnan(meter.metrics(dt).jerk_max)
    meter.add((1.0, 0.0), 0.0)
    assert math.isnan(meter.metrics(dt).accel_p95)  # one sample: NaN, no error
    with pytest.raises(ValueError):
        meter.add((math.nan, 0.0), 0.0)
    with pytest.raises(ValueError):
        meter.add((1.0, 0.0, 0.0), 0.0)


def test_sedan_full_throttle_at_10hz():
    """Physics against physics: from rest at full throttle, the p95 of a_lon agrees with the mean
    acceleration (speed gain / time) and, away from the edges, with the chassis IMU."""
    model = world.build(None)
    vehicle = Vehicle(model)
    data = mujoco.MjData(model)
    dt = 0.1  # [s] control rate 10 Hz
    n_sub = round(dt / model.opt.timestep)
    vehicle.reset(data, 2.0, -1.0, 0.4)
    meter, imu = ComfortMeter(), [math.nan]  # imu: [m/s^2] longitudinal, per sample

    def sample() -> None:
        forward, left = vehicle.velocity_body(data)
        yaw = vehicle.pose(data)[2]
        c, s = math.cos(yaw), math.sin(yaw)
        meter.add((forward * c - left * s, forward * s + left * c), yaw)

    sample()
    for _ in range(40):  # 4 s
        vehicle.apply(data, 1.0, 0.0, 0.0)
        mujoco.mj_step(model, data, n_sub)
        sample()
        imu.append(vehicle.acceleration(data)[0])
    p, m = meter.profile(dt), meter.metrics(dt)
    mean_accel = (p.speed[-1] - p.speed[0]) / p.time[-1]  # [m/s^2]
    assert mean_accel > 1.0
    assert m.accel_lon_p95 == pytest.approx(mean_accel, rel=0.2)
    inner = slice(p.window, -p.window)
    np.testing.assert_allclose(p.a_lon[inner], np.array(imu)[inner], atol=0.05)
    assert m.accel_lat_p95 < 0.05 and m.jerk_lat_max < 0.05


@pytest.mark.parametrize("domain, task", [("urban", "concatenated"), ("roundabout", "d120"), ("waypoints", "straight")])
def test_each_comfort_sample_is_the_chassis_after_its_step(domain, task):
    """The task's comfort meter gets, after reset and after every control step, the chassis' planar velocity and
    yaw read afresh from the physics at that moment (tasks that read the chassis in `after_step` hand it over
    instead of reading it twice: the same numbers)."""
    from mjdrive import suite

    env = suite.load(domain, task, {"random": 2})
    env.reset()
    meter, data = env.task.comfort, env.physics.raw_data
    rng = np.random.default_rng(0)
    k, checked, yaws = 0, 0, []  # k: the sample of this step in the episode's meter
    for _ in range(60):
        _, _, yaw, forward, left, _ = env.task.vehicle.planar_state(data)
        c, s = math.cos(yaw), math.sin(yaw)
        assert len(meter) == k + 1
        assert tuple(meter._velocity[k]) == (c * forward - s * left, s * forward + c * left)
        assert meter._yaw[k] == yaw
        checked, k = checked + 1, k + 1
        yaws.append(yaw)
        if env.step(np.array([rng.uniform(0.3, 1.0), rng.uniform(-0.3, 0.3), 0.0])).last():
            env.reset()  # a new episode: its first sample is the state after reset
            k = 0
    assert checked == 60 and np.ptp(yaws) > 0.0  # the car drove and turned: the samples changed


def _filter_gains(f: float, dt: float) -> tuple[float, float]:
    """Amplitude passed of a jerk oscillation of f [Hz] sampled every dt [s]: (the comfort metrics' two
    Savitzky-Golay derivatives, window 5 samples, order 2; two first differences), from their frequency
    responses: (2 sin x + 4 sin 2x) / (10 x) per derivative, sin(x/2) / (x/2) per difference, x = 2 pi f dt."""
    x = 2 * math.pi * f * dt
    return ((2 * math.sin(x) + 4 * math.sin(2 * x)) / (10 * x)) ** 2, (math.sin(x / 2) / (x / 2)) ** 2


@pytest.mark.parametrize("f, dt, savgol, differences", [(1.0, 0.1, 0.628, 0.968), (0.5, 0.1, 0.893, 0.992),
                                                          (0.5, 0.2, 0.628, 0.968), (2.0, 0.1, 0.115, 0.875)])
def test_the_filter_attenuates_a_jerk_oscillation_as_docs_summary_states(f, dt, savgol, differences):
    """docs/summary.md: at 10 Hz the filter passes 63% of a 1 Hz jerk oscillation's amplitude, the finite
    differences 97%. Measured on a sampled oscillation (the in-phase amplitude by least squares) and
    against the closed form."""
    omega, jerk_amp = 2 * math.pi * f, 1.0  # [rad/s], [m/s^3]
    t = dt * np.arange(round(120.0 / dt))
    speed = 10.0 - jerk_amp / omega**2 * np.sin(omega * t)  # [m/s] its jerk: jerk_amp sin(omega t)
    vel, yaw = straight(speed, 0.4)
    inner = slice(10, -10)
    p = acceleration_profile(vel, yaw, dt)
    basis = np.c_[np.sin(omega * t), np.cos(omega * t)][inner]
    gain = np.hypot(*np.linalg.lstsq(basis, p.jerk_lon[inner], rcond=None)[0]) / jerk_amp
    jerk_lon, jerk_lat = finite_difference_jerk(vel, yaw, dt)
    t_fd = t[1:-1]  # the second differences sit on the samples between the first and the last
    basis_fd = np.c_[np.sin(omega * t_fd), np.cos(omega * t_fd)][inner]
    gain_fd = np.hypot(*np.linalg.lstsq(basis_fd, jerk_lon[inner], rcond=None)[0]) / jerk_amp
    assert (gain, gain_fd) == pytest.approx(_filter_gains(f, dt), abs=2e-3)
    assert (gain, gain_fd) == pytest.approx((savgol, differences), abs=1e-3)
    assert np.abs(jerk_lat).max() < 1e-9
    docs = " ".join((Path(__file__).resolve().parents[1] / "docs" / "summary.md").read_text().split())
    assert "passes 63% of a 1 Hz jerk oscillation's amplitude" in docs and "97% of a 1 Hz oscillation" in docs


def test_unfiltered_jerk_of_constant_jerk_and_circles():
    dt, j = 0.1, 0.8  # [s], [m/s^3]
    t = dt * np.arange(100)
    vel, yaw = straight(2.0 + 0.5 * j * t**2, -1.1)  # a = j t: the differences are exact
    jerk_lon, jerk_lat = finite_difference_jerk(vel, yaw, dt)
    np.testing.assert_allclose(jerk_lon, j, rtol=1e-9)
    np.testing.assert_allclose(jerk_lat, 0.0, atol=1e-9)
    meter = ComfortMeter()
    for velocity, heading in zip(vel, yaw, strict=True):
        meter.add(velocity, heading)
    assert meter.unfiltered_jerk(dt) == pytest.approx((j, j), rel=1e-9)
    v, radius = 10.0, 50.0  # uniform circular motion: constant car-frame acceleration, no jerk
    yaw = np.angle(np.exp(1j * (0.3 + v / radius * t * 4)))  # wraps around +-pi
    vel = v * np.c_[np.cos(yaw), np.sin(yaw)]
    assert np.abs(np.hypot(*finite_difference_jerk(vel, yaw, dt))).max() < 1e-9
    short = ComfortMeter()
    short.add((1.0, 0.0), 0.0)
    short.add((1.0, 0.0), 0.0)
    assert all(math.isnan(value) for value in short.unfiltered_jerk(dt))
