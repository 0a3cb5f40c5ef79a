"""The operative level's parts against their specifications, without MuJoCo: the LQR's Riccati solution and closed
loop, the MPC's solutions against their bounds (checked here, not by the solver), against the LQR when no
constraint binds, and bit for bit for the same inputs; the lane-change profile against its bounds; the speed
reference against its comfort bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mjdrive.config import ConfigError
from mjdrive.control import mpc as mpc_module
from mjdrive.control.lane_change import LaneOffset
from mjdrive.control.lqr import GainTable, LateralLQR, LQRWeights, lateral_model, lqr_gain
from mjdrive.control.mpc import Leader, LongitudinalMPC, MPCConfig
from mjdrive.control.speed_profile import route_speed_profile
from mjdrive.roads import Lane

WHEELBASE, DT = 2.75, 0.1  # [m], [s]


# --- LQR ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("v", [1.0, 5.0, 13.9, 25.0])
def test_lqr_gain_solves_the_riccati_equation_and_stabilises(v):
    a, b = lateral_model(v, WHEELBASE, DT)
    q, r = LQRWeights().matrices()
    k = lqr_gain(a, b, q, r)
    # the Riccati solution behind K: P = Q + A'P(A - BK); recover P by iterating the fixed point from it
    p = np.eye(3)
    for _ in range(5000):
        p = q + a.T @ p @ a - a.T @ p @ b @ np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)
    assert np.allclose(k, np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a), rtol=1e-6, atol=1e-9)
    assert np.abs(np.linalg.eigvals(a - b @ k)).max() < 1.0


def test_gain_table_interpolates_between_its_speeds_and_clamps_outside():
    table = GainTable(WHEELBASE, DT)
    v0, v1 = table.speeds[4], table.speeds[5]
    mid = np.array(table.gain(0.5 * (v0 + v1)))
    assert np.allclose(mid, 0.5 * (table.gains[4] + table.gains[5]))
    assert np.allclose(table.gain(0.0), table.gains[0]) and np.allclose(table.gain(1e3), table.gains[-1])


def _kinematic_bicycle(lqr: LateralLQR, e_y: float, e_psi: float, v: float, seconds: float, delay: float = 0.0):
    """The rear-axle kinematic bicycle on a straight path under `lqr`, the steering acting `delay` [s] late
    (integrated at 1 ms); returns the lateral errors at the control steps and the steering angles sent."""
    h, errors, sent = 1e-3, [], []
    queue = [0.0] * int(round(delay / DT))
    for _ in range(int(round(seconds / DT))):
        delta = lqr(e_y, e_psi, v, 0.0)
        sent.append(delta)
        queue.append(delta)
        acting = queue.pop(0)
        for _ in range(int(round(DT / h))):
            e_y += h * v * math.sin(e_psi)
            e_psi += h * v * math.tan(acting) / WHEELBASE
        errors.append(e_y)
    return np.array(errors), np.array(sent)


@pytest.mark.parametrize("v", [3.0, 8.0, 13.9])
def test_a_half_metre_offset_decays_and_the_steering_stays_within_its_limit(v):
    lqr = LateralLQR(WHEELBASE, 0.5, DT, delay=0.0)
    errors, sent = _kinematic_bicycle(lqr, 0.5, 0.0, v, 10.0)
    assert abs(errors[-1]) < 0.02 and np.abs(errors).max() <= 0.5 + 1e-9
    assert np.abs(sent).max() <= 0.5
    lqr = LateralLQR(WHEELBASE, 0.05, DT, delay=0.0)  # a tight limit saturates
    _, sent = _kinematic_bicycle(lqr, 3.0, 0.0, v, 2.0)
    assert np.abs(sent).max() == pytest.approx(0.05)


def test_delay_compensation_tracks_better_under_a_steering_delay():
    """A steering command acting 0.2 s late: the compensated LQR settles a 0.5 m offset with less overshoot and
    less oscillation than the same gains without the prediction."""
    runs = {}
    for compensate in (False, True):
        lqr = LateralLQR(WHEELBASE, 0.5, DT, delay=0.2, compensate=compensate)
        errors, _ = _kinematic_bicycle(lqr, 0.5, 0.0, 13.9, 15.0, delay=0.2)
        runs[compensate] = errors
    assert abs(runs[True][-1]) < 0.02
    assert -runs[True].min() < -runs[False].min()  # overshoot past the path
    assert np.abs(runs[True][30:]).sum() < np.abs(runs[False][30:]).sum()


# --- MPC ------------------------------------------------------------------------------------------------------
def _random_problem(rng: np.random.Generator) -> dict:
    speed = rng.uniform(0.0, 16.0)
    return {"speed": speed, "accel": rng.uniform(-4.0, 2.5), "v_ref": rng.uniform(0.0, 16.0, 20),
            "stop": None if rng.random() < 0.4 else rng.uniform(-1.0, 90.0),
            "leaders": tuple(Leader(rng.uniform(-2.0, 80.0), rng.uniform(0.0, 16.0), rng.uniform(-6.0, 2.0))
                             for _ in range(rng.integers(0, 3)))}


def test_mpc_solutions_meet_their_bounds_on_randomised_problems():
    """Every plan, checked here from its numbers: the jerks within the bound used (comfort, firm or emergency as the
    plan says), the accelerations likewise from step 1, the states following the dynamics from the initial
    state, and each soft constraint violated by no more than the plan's reported slack."""
    config = MPCConfig()
    mpc = LongitudinalMPC(config)
    rng = np.random.default_rng(0)
    h, n = config.step, config.horizon
    statuses = {}
    for _ in range(1200):
        problem = _random_problem(rng)
        if rng.random() < 0.3:
            mpc.reset()
        plan = mpc.solve(**problem)
        statuses[plan.status] = statuses.get(plan.status, 0) + 1
        a_min, j_max = {"solved": (config.accel_min, config.jerk_max),
                        "firm": (config.firm_accel_min, config.firm_jerk_max),
                        "emergency": (config.emergency_accel_min, config.emergency_jerk_max),
                        "fallback": (config.accel_min, config.jerk_max)}[plan.status]
        assert np.all(np.abs(plan.j) <= j_max + 1e-9)
        assert np.all(plan.a[1:] >= a_min - 1e-9) and np.all(plan.a[1:] <= config.accel_max + 1e-9)
        v0, a0 = max(problem["speed"], 0.0), mpc.initial_accel(problem["speed"], problem["accel"])
        assert (plan.s[0], plan.v[0], plan.a[0]) == (0.0, v0, a0)
        if plan.status == "fallback":  # braking to rest: never reversing, slowing once its acceleration is gone
            assert np.all(plan.v >= 0.0) and plan.v[-1] < v0 + 1e-9 or plan.v[-1] == 0.0
            continue
        s, v, a = 0.0, v0, a0  # the dynamics, integrated here from the initial state and the plan's jerks
        for k in range(n):
            j = plan.j[k]
            s, v, a = s + v * h + a * h * h / 2 + j * h**3 / 6, v + a * h + j * h * h / 2, a + j * h
            assert (plan.s[k + 1], plan.v[k + 1], plan.a[k + 1]) == pytest.approx((s, v, a), abs=1e-9)
        slack = plan.slack + 1e-9
        times = mpc.times[1:]
        if problem["stop"] is not None:
            assert np.all(plan.s[1:] <= problem["stop"] + slack)
        for leader in problem["leaders"]:
            bound = leader.positions(times) - config.standstill_gap
            assert np.all(plan.s[1:] + config.headway * plan.v[1:] <= bound + slack)
    assert statuses.get("solved", 0) > 700 and statuses.get("fallback", 0) == 0  # always feasible: the slacks


def test_a_plan_from_braking_hard_near_rest_stops_without_reversing():
    """Braking at the comfort bound at 2.3 m/s behind a standing car 1.4 m ahead (inside the standstill gap): the
    jerk bound could not take the braking back before the speed is gone, so the plan starts from the braking it
    can take back (`initial_accel`), and it stops without reversing (v >= 0 is hard) and short of the car."""
    config = MPCConfig()
    mpc = LongitudinalMPC(config)
    a0 = mpc.initial_accel(2.28, config.accel_min)
    assert a0 == pytest.approx(-np.sqrt(2 * config.jerk_max * 2.28)) and a0 > config.accel_min
    plan = mpc.solve(2.28, config.accel_min, 3.3, leaders=(Leader(1.4, 0.0),))
    assert plan.status in ("solved", "firm", "emergency") and plan.converged
    assert plan.v.min() > -0.05 and abs(plan.v[-1]) < 0.05 and plan.s[-1] < 1.4  # v >= 0 to OSQP's accuracy


def test_mpc_answers_a_standing_obstacle_by_the_mildest_bounds_that_keep_the_gap():
    """At 10 m/s towards a standing car: far enough, the comfort bounds keep it out of the emergency gap; nearer,
    the firm bounds (and their jerk, not the emergency's) do; nearer still only the emergency bounds. Each plan
    stays out of the emergency gap (its intrusion), and each tier is used only where the one before cannot."""
    config = MPCConfig()
    statuses = []
    for gap in (30.0, 20.0, 12.0):  # [m] to the standing car's rear
        mpc = LongitudinalMPC(config)
        plan = mpc.solve(10.0, 0.0, 10.0, leaders=(Leader(gap, 0.0),))
        a_min, j_max = {"solved": (config.accel_min, config.jerk_max),
                        "firm": (config.firm_accel_min, config.firm_jerk_max),
                        "emergency": (config.emergency_accel_min, config.emergency_jerk_max)}[plan.status]
        assert np.abs(plan.j).max() <= j_max + 1e-9 and plan.a.min() >= a_min - 1e-9
        assert plan.intrusion <= 0.0 and plan.s.max() < gap - config.emergency_gap
        statuses.append(plan.status)
    assert statuses == ["solved", "firm", "emergency"]


def test_mpc_falls_in_behind_a_road_user_alongside_within_the_firm_bounds():
    """A car moving in beside the ego (its rear level with the ego's front, a little faster): the same car straight
    ahead would take the emergency bounds; alongside, the ego falls in behind braking within the firm bounds, and
    its plan still ends behind the car's rear by the time the horizon ends. A slower one alongside, and a stop
    point that moves (a road user crossing), get the emergency bounds at once."""
    config = MPCConfig()
    ahead = LongitudinalMPC(config).solve(6.0, 0.0, 8.0, leaders=(Leader(0.0, 6.3, 1.0),))
    beside = Leader(0.0, 6.3, 1.0, alongside=True)
    plan = LongitudinalMPC(config).solve(6.0, 0.0, 8.0, leaders=(beside,))
    assert ahead.status == "emergency" and plan.status == "firm"
    assert np.abs(plan.j).max() <= config.firm_jerk_max + 1e-9 and plan.a.min() >= config.firm_accel_min - 1e-9
    assert plan.s[-1] < beside.positions(LongitudinalMPC(config).times[-1:])[0] - config.emergency_gap
    # one the car closes on (slower than it) may take the emergency bounds, as may a stop point that moves
    slower = LongitudinalMPC(config).solve(6.0, 0.0, 8.0, leaders=(Leader(0.0, 5.0, 0.0, alongside=True),))
    assert slower.status == "emergency"
    static = LongitudinalMPC(config).solve(10.0, 0.0, 10.0, stop=18.0)
    moving = LongitudinalMPC(config).solve(10.0, 0.0, 10.0, stop=18.0, stop_moves=True)
    assert static.status == "firm" and moving.status == "emergency"


def test_unconstrained_mpc_matches_the_finite_horizon_lqr():
    """With no constraint binding, the MPC is the LQR of its own cost: (v, a) deviations from a constant
    reference and the jerk, solved backwards by the Riccati recursion; their first jerks agree (to OSQP's
    tolerance)."""
    config = MPCConfig(accel_min=-9.0, accel_max=5.0, jerk_max=50.0, firm_jerk_max=50.0, firm_accel_min=-9.0,
                       emergency_jerk_max=50.0, emergency_accel_min=-9.0)
    mpc = LongitudinalMPC(config)
    h, n = config.step, config.horizon
    a_mat = np.array([[1.0, h], [0.0, 1.0]])  # (v, a)
    b_mat = np.array([[h * h / 2], [h]])
    q = np.diag([config.speed_weight, config.accel_weight])
    r = np.array([[config.jerk_weight]])
    p, gains = q.copy(), []
    for _ in range(n):  # backward: cost on x_1..x_N and j_0..j_{N-1}
        k = np.linalg.solve(r + b_mat.T @ p @ b_mat, b_mat.T @ p @ a_mat)
        gains.append(k)
        p = q + a_mat.T @ p @ (a_mat - b_mat @ k)
    k0 = gains[-1]
    for speed, accel, ref in [(10.0, 0.0, 10.8), (6.0, 0.5, 9.0), (12.0, -0.3, 12.4)]:  # the speed bound v <= ref idle
        plan = mpc.solve(speed, accel, ref)
        expected = float(-(k0 @ np.array([speed - ref, accel]))[0])
        assert plan.status == "solved" and plan.mode == "cruise"
        assert plan.j[0] == pytest.approx(expected, abs=0.02)


def test_same_inputs_give_the_same_bits():
    rng = np.random.default_rng(5)
    problems = [_random_problem(rng) for _ in range(60)]
    runs = []
    for _ in range(2):
        mpc = LongitudinalMPC()
        runs.append([mpc.solve(**problem) for problem in problems])
    for first, second in zip(*runs, strict=True):
        for name in ("s", "v", "a", "j"):
            assert getattr(first, name).tobytes() == getattr(second, name).tobytes()


def test_a_reset_solver_gives_the_bits_of_a_fresh_one_whatever_it_solved_before():
    """Episodes do not depend on the episodes before: OSQP's set-up reads the vectors (its cost scaling reads q),
    so a reset restores them first."""
    rng = np.random.default_rng(11)
    before = [_random_problem(rng) for _ in range(40)]
    problems = [_random_problem(rng) for _ in range(40)]
    used = LongitudinalMPC()
    for problem in before:
        used.solve(**problem)
    used.reset()
    fresh = LongitudinalMPC()
    for problem in problems:
        a, b = used.solve(**problem), fresh.solve(**problem)
        assert a.j.tobytes() == b.j.tobytes() and a.status == b.status


def test_a_solver_failure_falls_back_to_braking_within_the_comfort_bounds(monkeypatch):
    monkeypatch.setattr(mpc_module.OSQPSolver, "solve", lambda self, q, l, u, budget=None: (None, 0, False))
    config = MPCConfig()
    plan = LongitudinalMPC(config).solve(12.0, 0.5, 12.0, stop=40.0)
    assert plan.status == "fallback" and plan.mode == "stop"
    assert np.all(np.abs(plan.j) <= config.jerk_max + 1e-12) and np.all(plan.a >= config.accel_min - 1e-12)
    peak = int(np.argmax(plan.v))  # the acceleration it had first runs down at the jerk bound, then it brakes
    assert peak <= 2 and np.all(np.diff(plan.v[peak:]) <= 1e-12) and plan.v[-1] == 0.0 and np.all(plan.v >= 0)


def test_mpc_config_refuses_emergency_bounds_inside_the_comfort_ones():
    with pytest.raises(ConfigError, match="emergency"):
        MPCConfig.from_dict({"emergency_accel_min": -2.0})


# --- lane change ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("width, accel, jerk", [(3.5, 1.5, 2.0), (-3.5, 2.0, 1.0), (3.0, 0.5, 5.0)])
def test_lane_offset_meets_its_bounds_by_finite_differences(width, accel, jerk):
    manoeuvre = LaneOffset.within(1.0, width, accel, jerk, t0=2.0)
    t = 2.0 + np.linspace(0.0, manoeuvre.duration, 4001)
    d = np.array([manoeuvre(x)[0] for x in t])
    step = t[1] - t[0]
    second = np.diff(d, 2) / step**2
    third = np.diff(d, 3) / step**3
    assert np.abs(second).max() <= accel * 1.001 and np.abs(third).max() <= jerk * 1.001
    # the shortest such manoeuvre: one bound is reached
    assert max(np.abs(second).max() / accel, np.abs(third).max() / jerk) > 0.99
    assert d[0] == pytest.approx(1.0) and d[-1] == pytest.approx(1.0 + width)
    assert manoeuvre(t[-1])[1:] == pytest.approx((0.0, 0.0), abs=1e-12) and manoeuvre(t[0])[1] == 0.0


# --- speed reference ------------------------------------------------------------------------------------------
def test_speed_profile_keeps_its_comfort_bounds_on_a_curve():
    arc = [(20.0 * math.sin(a), 20.0 - 20.0 * math.cos(a)) for a in np.linspace(0.0, math.pi / 2, 60)]
    straight_in = [(-100.0 + x, 0.0) for x in np.arange(0.0, 100.0, 1.0)]
    straight_out = [(20.0, 20.0 + y) for y in np.arange(1.0, 100.0, 1.0)]
    path = Lane(np.array(straight_in + arc + straight_out))
    profile = route_speed_profile(path, np.array([0.0, 150.0]), np.array([13.89, 8.33]), lateral_accel=2.0,
                                  lateral_jerk=2.5, decel=1.5)
    assert np.all(profile.v <= 13.89 + 1e-9)
    assert np.all(profile.v[profile.s >= 150.0 + 1.0] <= 8.33 + 1e-9)
    assert np.all(profile.v**2 * np.abs(profile.curvature) <= 2.0 + 1e-9)
    dv2 = np.diff(profile.v**2) / np.diff(profile.s)
    assert dv2.min() >= -2 * 1.5 - 1e-9  # every slower stretch reached braking at most 1.5 m/s^2
    assert profile.speed(50.0) < 13.89  # slowing for the arc ahead
    assert np.abs(profile.offset).max() < 0.35 and abs(profile.offset[-1]) < 1e-6  # the smoothed path returns
