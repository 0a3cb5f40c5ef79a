"""Privileged scripted drivers for tasks with traffic (e.g. the roundabout): pure pursuit along the task's
route, with the speed either from traffic's own rules applied to the ego (`careful`: IDM behind leaders,
stops for pedestrians, gap acceptance at the roundabout entry, all from ground truth) or ignoring traffic
altogether ("just drive")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mjdrive.control.pure_pursuit import PurePursuit


@dataclass
class Autopilot:
    """Drives `task` (a task with `route_lane`, `traffic`, `ego_state(physics)`, `vehicle`, `params`).

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

    def __post_init__(self):
        params = self.task.params
        self.driver = PurePursuit(wheelbase=params.wheelbase, max_steer=params.max_steer)

    def reset(self) -> None:
        self.driver.reset()

    def __call__(self, physics) -> np.ndarray:
        """(throttle, steer, brake) for the current state."""
        task = self.task
        pose = task.vehicle.pose(physics.raw_data)
        speed = float(task.vehicle.speed(physics.raw_data))
        route = task.route_lane
        command = self.driver(pose, speed, route, self.cruise, self.control_dt)
        if not self.careful:
            return command
        s, _ = route.local_coordinates(np.array(pose[:2]))
        desired = self.driver.target_speed(route, float(s), self.cruise)
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
