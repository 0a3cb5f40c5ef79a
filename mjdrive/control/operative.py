"""Study 002's operative level (§4.3, Fig. 5): the tactical level's decision and the ground truth of one control
step in, (throttle, steer, brake) out.

- Trajectory tracking: `LateralLQR` steers the rear axle onto the route (shifted by the lane offset), with the
  smoothed route curvature as feed-forward and the steering delay compensated; the speed reference is the
  route's `SpeedProfile`.
- Manoeuvres: `LongitudinalMPC` plans the speed (cruise to the reference, follow the leaders, stop at the
  point of a "stop" decision); a "left" / "right" decision starts a `LaneOffset` by one lane width.
- `PedalController` turns the planned acceleration into pedals.

Decisions (`DECISIONS`): "drive" (also the lane-change scenario's "keep": hold the lane), "stop", "left",
"right". Outside every scenario (`Situation.active` False) the level follows the path whatever the decision:
no stop, and back to the route's own lane. A "stop" with no stop point ahead (the give-way line passed) stops
where a comfortable braking ends, a point kept until the decision changes.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from mjdrive.config import Config, param
from mjdrive.control.lane_change import LaneOffset
from mjdrive.control.lqr import STEER_LAG, LateralLQR, LQRWeights
from mjdrive.control.mpc import Leader, LongitudinalMPC, MPCConfig, MPCPlan
from mjdrive.control.pedals import MODELS, PedalController
from mjdrive.control.speed_profile import SpeedProfile
from mjdrive.vehicle import VehicleParams

DECISIONS = ("drive", "stop", "left", "right")
DRIVE, STOP, LEFT, RIGHT = DECISIONS
STOP_MARGIN = 0.15  # [m] the front bumper comes to rest this far before a stop point (never past it)
TRACKING_MARGIN = 0.9  # a lane change is planned at this share of its bounds: the car tracks it a little late
CROSSING_CLEARANCE = 1.0  # [m] kept to a road user crossing the car's lane ahead


@dataclass(frozen=True)
class OperativeConfig(Config):
    """The operative level's parameters (the urban tasks' `operative` keyword)."""

    lateral_accel: float = param(2.0, "comfort bound on lateral acceleration in curves (the speed reference)",
                                 "m/s^2", gt=0.1, le=8.0)
    lateral_jerk: float = param(2.5, "comfort bound on lateral jerk where curves begin and end (the speed "
                                "reference)", "m/s^3", gt=0.1, le=20.0)
    curve_decel: float = param(1.5, "braking the speed reference plans before curves and slower stretches",
                               "m/s^2", gt=0.1, le=5.0)
    path_deviation: float = param(0.2, "the smoothed path the LQR tracks stays about this close to the route",
                                  "m", gt=0.0, le=2.0)
    smoothing: tuple[float, float] = param((6.0, 20.0), "shortest and longest window of the curvature smoothing",
                                           "m", gt=0.5, le=100.0, length=2)
    curve_footprint: float = param(6.0, "the curve bounds hold this far around the car's centre", "m", gt=0.0,
                                   le=50.0)
    approach_speed: float = param(3.0, "the speed at a give-way line of the active scenario while the rules "
                                  "of the road say wait there, whatever the decision (a later stop stays "
                                  "comfortable)", "m/s", gt=0.0, le=20.0)
    lane_change_accel: float = param(1.5, "lateral acceleration bound of a lane change", "m/s^2", gt=0.1, le=5.0)
    lane_change_jerk: float = param(2.0, "lateral jerk bound of a lane change", "m/s^3", gt=0.1, le=20.0)
    lane_change_heading: float = param(0.2, "a lane change moves across at most at this angle (slow cars take "
                                       "longer)", "rad", gt=0.01, le=1.0)
    delay_compensation: bool = param(True, "predict the path errors over the steering delay (the servo's lag and "
                                     "the car's steering latency)")
    lqr_lateral: float = param(1.0, "LQR weight on the lateral error", "1/m^2", ge=0.0)
    lqr_heading: float = param(1.0, "LQR weight on the heading error", "1/rad^2", ge=0.0)
    lqr_steering: float = param(1.0, "LQR weight on the steering correction", "1/rad^2", ge=0.0)
    lqr_steering_rate: float = param(20.0, "LQR weight on the steering correction's change per period",
                                     "1/rad^2", gt=0.0)
    mpc: MPCConfig = param(MPCConfig(), "the longitudinal MPC (a dict of its keywords)")


@dataclass(frozen=True)
class Situation:
    """The ground truth of one control step, as the task reads it."""

    s: float  # [m] the car's centre along the route
    rear_s: float  # [m] its rear axle's centre along the route
    rear_lateral: float  # [m] the rear axle's offset from the route's centre line (left > 0)
    heading_error: float  # [rad] car heading minus the route's at the rear axle
    speed: float  # [m/s] forward
    decision: str = DRIVE  # one of DECISIONS
    active: bool = True  # inside a scenario of the tactical trajectory (else: follow the path)
    stop: float | None = None  # [m] front bumper to the active scenario's stop point (None: none ahead)
    leaders: Sequence[Leader] = ()  # in the lane the car is in and the one it moves to
    lane_width: float = 3.5  # [m] of the lane a lane change moves by
    left_lane: bool = False  # a "left" decision may start a lane change now (the lane is there and takes the car)
    right_lane: bool = False  # ... to the right (back towards the route's lane, or a right neighbour)
    lane_end: float | None = None  # [m] front bumper to the end of the lane the car is in (off the route's lane)
    crossing: float | None = None  # [m] front bumper to a road user crossing its lane ahead (None: none)
    back_free: bool = True  # the route's own lane has room for the car to come back to it now
    yielding: bool = False  # the right-of-way rules would have the car wait at the stop point now


@dataclass
class OperativeStatus:
    """What the level did in its last step (for `info` and the logs)."""

    decision: str = DRIVE  # as applied (after "follow the path" and the lanes available)
    mode: str = "cruise"  # the MPC's: cruise, follow, stop
    solver: str = "solved"  # the MPC plan's status: solved, firm, emergency, fallback
    v_ref: float = 0.0  # [m/s]
    stop: float | None = None  # [m] ahead of the front bumper, the MPC's stop point
    offset: float = 0.0  # [m] the lateral offset tracked now
    target_offset: float = 0.0  # [m] where the lane offset goes
    lateral_error: float = 0.0  # [m] rear axle, from the offset path
    heading_error: float = 0.0  # [rad] from the offset path
    steering_angle: float = 0.0  # [rad] bicycle angle commanded
    accel: float = 0.0  # [m/s^2] commanded
    throttle: float = 0.0
    brake: float = 0.0
    solve_ms: float = 0.0  # [ms] the MPC's solve
    step_ms: float = 0.0  # [ms] the whole step: MPC, LQR, pedals
    plan: MPCPlan | None = field(default=None, repr=False)


class OperativeLevel:
    """Drives a route given decisions; `reset` at every episode, call once per control period `dt` [s].
    `extra_delay` [s]: how much later than sent the car applies a steering command (beyond the servo's lag)."""

    def __init__(self, profile: SpeedProfile, params: VehicleParams, dt: float,
                 config: OperativeConfig = OperativeConfig(), extra_delay: float = 0.0):
        self.config, self.profile, self.params, self.dt = config, profile, params, dt
        weights = LQRWeights(config.lqr_lateral, config.lqr_heading, config.lqr_steering, config.lqr_steering_rate)
        self.lqr = LateralLQR(params.wheelbase, params.max_steer, dt, STEER_LAG + extra_delay,
                              config.delay_compensation, weights)
        self.mpc = LongitudinalMPC(config.mpc)
        self.pedals = PedalController(MODELS[params.name], dt)
        self.status = OperativeStatus()
        self.reset()

    def reset(self) -> None:
        self.lqr.reset()
        self.mpc.reset()
        self.pedals.reset()
        self.time = 0.0  # [s] since reset
        self.accel = 0.0  # [m/s^2] the last commanded acceleration
        self.offset_target = 0.0  # [m] the lane offset a manoeuvre ends at
        self.manoeuvre: LaneOffset | None = None
        self.stop_hold: float | None = None  # [m] route position of a "stop" with no stop point ahead
        self.status = OperativeStatus()

    def lanes(self) -> tuple[float, ...]:
        """Centre offsets [m] from the route of the lane the car is in and, during a lane change, the one it moves
        to (the last: where it goes)."""
        if self.manoeuvre is None:
            return (self.offset_target,)
        return (self.manoeuvre.start, self.manoeuvre.end)

    # --- the manoeuvres ----------------------------------------------------------------------------------
    def _offset(self, situation: Situation) -> tuple[str, float, float, float]:
        """(the decision as applied, offset [m], its rate [m/s] and acceleration [m/s^2] now)."""
        decision = situation.decision if situation.active else DRIVE
        if self.manoeuvre is not None and self.manoeuvre.done(self.time):
            self.manoeuvre = None
        if self.manoeuvre is None:
            target = self.offset_target
            ending = situation.lane_end is not None and situation.lane_end < self._lane_change_room(situation)
            if target != 0.0 and (not situation.active or ending):  # back to the route's own lane, when it has room
                target = 0.0 if situation.back_free else target
            elif decision == LEFT and situation.left_lane:
                target += situation.lane_width
            elif decision == RIGHT and situation.right_lane:
                target -= situation.lane_width
            elif decision in (LEFT, RIGHT):
                decision = DRIVE  # no lane there: keep
            if target != self.offset_target:
                c = self.config
                self.manoeuvre = LaneOffset.within(self.offset_target, target - self.offset_target,
                                                   TRACKING_MARGIN * c.lane_change_accel,
                                                   TRACKING_MARGIN * c.lane_change_jerk, self.time,
                                                   situation.speed, c.lane_change_heading)
                self.offset_target = target
        if self.manoeuvre is None:
            return decision, self.offset_target, 0.0, 0.0
        d, rate, accel = self.manoeuvre(self.time)
        return decision, d, rate, accel

    def _lane_change_room(self, situation: Situation) -> float:
        """[m] a lane change back takes at the current speed, with a margin."""
        c = self.config
        duration = LaneOffset.within(0.0, situation.lane_width, TRACKING_MARGIN * c.lane_change_accel,
                                     TRACKING_MARGIN * c.lane_change_jerk, 0.0, situation.speed,
                                     c.lane_change_heading).duration
        return max(situation.speed, 1.0) * duration + 10.0

    def _stop_point(self, situation: Situation, decision: str) -> tuple[float | None, bool]:
        """([m] ahead of the front bumper: where the MPC must stop (None: nowhere), whether that point is a road user
        crossing ahead (it moves))."""
        front = situation.s + 0.5 * self.params.length
        points = []  # (distance [m], whether the point moves)
        if situation.lane_end is not None:  # the end of a lane off the route's: never past it
            points.append((situation.lane_end, False))
        if situation.crossing is not None:  # a road user crossing ahead: stop short of it until it has gone
            points.append((situation.crossing - CROSSING_CLEARANCE, True))
        if decision == STOP:
            if situation.stop is not None:
                points.append((situation.stop, False))
                self.stop_hold = None
            else:
                if self.stop_hold is None:  # where a comfortable braking from here ends, kept
                    self.stop_hold = front + self.braking_distance(situation.speed) + 0.5
                points.append((self.stop_hold - front, False))
        else:
            self.stop_hold = None
        if not points:
            return None, False
        nearest, moving = min(points)
        return nearest - STOP_MARGIN, moving

    def shortest_stop(self, speed: float) -> float:
        """[m] the shortest stop from `speed` [m/s] within the comfort envelope (its strongest braking at once):
        a stop point nearer than this cannot be kept without the emergency bounds."""
        v = max(speed, 0.0)
        return v * v / (2.0 * -self.config.mpc.accel_min)

    def braking_distance(self, speed: float) -> float:
        """[m] the comfortable stop from `speed` [m/s] takes: the stopping profile's deceleration, reached at the jerk
        bound."""
        c = self.config.mpc
        v = max(speed, 0.0)
        return v * v / (2.0 * c.stop_decel) + v * c.stop_decel / c.jerk_max

    # --- one control step --------------------------------------------------------------------------------
    def __call__(self, situation: Situation) -> tuple[float, float, float]:
        """(throttle, steer, brake) for this control step."""
        step_start = time.perf_counter()
        p, status = self.params, self.status
        decision, offset, rate, offset_accel = self._offset(situation)
        v = max(situation.speed, 0.0)
        # longitudinal: the MPC from the current speed and the last commanded acceleration
        stop, stop_moves = self._stop_point(situation, decision)
        plan_ahead = status.plan.s[1:] if status.plan is not None else v * self.mpc.times[1:]
        v_ref = self.profile.speed(situation.s + plan_ahead)
        # approach a give-way line where the rules have the car wait, and the end of a lane off the route's, slowly
        # enough to stop there
        for end in (situation.stop if situation.yielding else None, situation.lane_end):
            if end is not None:
                c = self.config
                room = np.maximum(end - plan_ahead, 0.0)
                v_ref = np.minimum(v_ref, np.sqrt(c.approach_speed**2 + 2.0 * c.curve_decel * room))
        start = time.perf_counter()
        plan = self.mpc.solve(v, self.accel, v_ref, stop, situation.leaders, stop_moves=stop_moves)
        solve_ms = 1e3 * (time.perf_counter() - start)
        self.accel = plan.accel_at(self.dt, self.mpc.config.step)
        throttle, brake = self.pedals(self.accel, situation.speed)
        # lateral: the rear axle onto the offset path
        rear = situation.rear_s
        path_offset, path_heading = self.profile.path_offset(rear)
        e_psi = situation.heading_error - path_heading - math.atan2(rate, max(v, 1.0))
        e_y = situation.rear_lateral - offset - path_offset
        ahead = v * (self.lqr.delay + 0.5 * self.dt)  # where the command acts
        kappa = self.profile.kappa(rear + ahead) + offset_accel / max(v, 1.0) ** 2
        delta = self.lqr(e_y, e_psi, v, kappa)
        steer = delta / p.max_steer
        self.time += self.dt
        status.decision, status.mode, status.solver, status.plan = decision, plan.mode, plan.status, plan
        status.v_ref, status.stop, status.offset, status.target_offset = float(v_ref[0]), stop, offset, \
            self.offset_target
        status.lateral_error, status.heading_error, status.steering_angle = e_y, e_psi, delta
        status.accel, status.throttle, status.brake, status.solve_ms = self.accel, throttle, brake, solve_ms
        status.step_ms = 1e3 * (time.perf_counter() - step_start)
        return throttle, steer, brake
