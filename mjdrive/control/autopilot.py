"""Privileged scripted drivers for tasks with traffic (e.g. the roundabout): pure pursuit along the task's
route, with the speed either from traffic's own rules applied to the ego (`careful`: IDM behind leaders,
stops for pedestrians, gap acceptance at the roundabout entry, all from ground truth) or ignoring traffic
altogether ("just drive"). On a two-lane road of the urban tasks the careful autopilot overtakes slow road users
by the privileged overtaking rule (`RouteTraffic.overtaking`), moving across by a quintic lane offset
(`LaneOffset`) that pure pursuit follows."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mjdrive.control.lane_change import LaneOffset
from mjdrive.control.pure_pursuit import PurePursuit

LANE_END_STOP = 6.0  # [m] in the left lane, the car can stop this far before the lane ends ...
LANE_END_DECEL = 1.5  # [m/s^2] ... braking at this


@dataclass
class Autopilot:
    """Drives `task` (a task with `route_lane`, `traffic`, `ego_state(physics)`, `vehicle`, `params`; overtakes on
    tasks with a `route_traffic` and an `active_scenario()`).

    careful: take the speed from `task.traffic.advise` (the traffic model's rules with a larger accepted
    gap and headway than traffic's own, as the ego brakes through real tyres); otherwise cruise.
    """

    task: object
    control_dt: float  # [s]
    careful: bool = True
    cruise: float = 6.0  # [m/s] desired speed (lowered in curves by pure pursuit's comfort limit)
    accept_gap: float = 4.5  # [s] at merges
    headway: float = 1.5  # [s] IDM time headway
    horizon: float = 0.6  # [s] the speed target is the speed `advise`'s acceleration reaches in this time
    overtake_margin: float = 1.5  # [m/s] a road user this much slower than `cruise` is overtaken (two-lane roads)
    lateral_accel: float = 1.0  # [m/s^2] bound of its lane changes' lateral acceleration ...
    lateral_jerk: float = 1.0  # [m/s^3] ... and jerk
    decision_period: float = 0.5  # [s] how often it reconsiders overtaking

    def __post_init__(self):
        params = self.task.params
        self.driver = PurePursuit(wheelbase=params.wheelbase, max_steer=params.max_steer)
        self.reset()

    def reset(self) -> None:
        self.driver.reset()
        self.time = 0.0  # [s] since the episode began
        self.target = 0.0  # [m] the lateral offset from the route it drives at, or moves to
        self.manoeuvre: LaneOffset | None = None  # the lane change under way
        self.next_decision = 0.0  # [s]

    def __call__(self, physics) -> np.ndarray:
        """(throttle, steer, brake) for the current state."""
        task = self.task
        self.time += self.control_dt
        pose = task.vehicle.pose(physics.raw_data)
        speed = float(task.vehicle.speed(physics.raw_data))
        route = task.route_lane
        s, _ = route.local_coordinates(np.array(pose[:2]))
        desired = self.driver.target_speed(route, float(s), self.cruise)
        offset = 0.0  # [m] from the route, to its left
        if self.careful:
            desired, offset = self._overtake(speed, desired)
        command = self.driver(pose, speed, route, self.cruise, self.control_dt, offset=offset)
        if not self.careful:
            return command
        ego = task.ego_state(physics)
        if ego.path is None:  # off the route: stop
            return np.array([0.0, command[1], 1.0])
        accel = task.traffic.advise(ego, accel=2.0, decel=3.0, headway=self.headway, desired_speed=desired,
                                    accept_gap=self.accept_gap)
        target = max(speed + accel * self.horizon, 0.0)
        if accel < -1.0 or target < 0.3:
            return np.array([0.0, command[1], float(np.clip(-accel / 6.0, 0.3, 1.0))])
        throttle, brake = self.driver.speed(speed, target, self.control_dt)
        return np.array([throttle, command[1], brake])

    def _overtake(self, speed: float, desired: float) -> tuple[float, float]:
        """On a two-lane road: start a lane change when the overtaking rule says so (every `decision_period`, none
        while one is under way); out of the route's lane, slow down to stop before the lane it is in ends. Returns
        the desired speed [m/s] and the lateral offset [m] to steer for."""
        task = self.task
        route = getattr(task, "route_traffic", None)
        if route is None:
            return desired, 0.0
        if self.manoeuvre is not None and self.manoeuvre.done(self.time):
            self.manoeuvre = None
        s = task.route_s
        if self.manoeuvre is None and self.time >= self.next_decision and (
                self.target != 0.0 or task.active_scenario() == "lane_change"):
            self.next_decision = self.time + self.decision_period
            route.observe(s, task.traffic, track=False)
            choice = route.overtaking(s, speed, self.cruise, self.target, margin=self.overtake_margin)
            width = float(route.lane_width[route.route_index(s)])
            step = width if choice == "left" and self.target == 0.0 else (
                -self.target if choice == "right" and self.target != 0.0 else 0.0)
            if step:
                self.manoeuvre = LaneOffset.within(self.target, step, self.lateral_accel, self.lateral_jerk,
                                                   t0=self.time, speed=speed)
                self.target += step
        offset = self.target if self.manoeuvre is None else self.manoeuvre(self.time)[0]  # [m]
        if abs(offset) > 0.5 * float(route.lane_width[route.route_index(s)]):  # able to stop before the lane ends
            room = max(route.lane_length_left(s) - LANE_END_STOP, 0.0)  # [m]
            desired = min(desired, math.sqrt(2.0 * LANE_END_DECEL * room))
        return desired, offset
