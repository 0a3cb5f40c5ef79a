"""Pure-pursuit steering and a PI speed controller: the built-in driver of `mjdrive run`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mjdrive.roads import Lane


@dataclass
class SpeedController:
    """PI on speed error -> throttle in [0,1] or brake in [0,1]."""

    kp: float = 0.5  # [1/(m/s)]
    ki: float = 0.1  # [1/m]
    brake_gain: float = 0.4  # [1/(m/s)]
    integral: float = 0.0  # [m]

    def reset(self) -> None:
        self.integral = 0.0

    def __call__(self, speed: float, target: float, dt: float) -> tuple[float, float]:
        """(throttle, brake) driving `speed` [m/s] towards `target` [m/s]."""
        error = target - speed
        if error < -0.5:  # too fast: brake, and forget the integral
            self.integral = 0.0
            return 0.0, float(min(max(-error * self.brake_gain, 0.0), 1.0))  # np.clip's numbers, without its call
        self.integral = float(min(max(self.integral + error * dt, -2.0), 10.0))
        return float(min(max(self.kp * error + self.ki * self.integral, 0.0), 1.0)), 0.0


@dataclass
class PurePursuit:
    """Steer towards the point of `path` one look-ahead distance ahead of the rear axle."""

    wheelbase: float  # [m]
    max_steer: float  # [rad] bicycle steer angle at steer command 1
    lookahead_min: float = 4.0  # [m]
    lookahead_gain: float = 0.6  # [s] look-ahead grows with speed
    max_lateral_accel: float = 2.0  # [m/s^2] comfort limit used to slow down for curves
    speed: SpeedController = None  # type: ignore[assignment]

    def __post_init__(self):
        if self.speed is None:
            self.speed = SpeedController()

    def reset(self) -> None:
        self.speed.reset()

    def target_speed(self, path: Lane, s: float, cruise: float) -> float:
        """Cruise speed [m/s], lowered so the lateral acceleration over the next 20 m stays comfortable."""
        curvature = path.max_abs_curvature(s, min(s + 20.0, path.length), 8) + 1e-6  # [1/m]
        return min(cruise, math.sqrt(self.max_lateral_accel / curvature))

    def __call__(self, pose: tuple[float, float, float], speed: float, path: Lane, cruise: float,
                 dt: float, offset: float = 0.0) -> np.ndarray:
        """(throttle, steer, brake) for the car at `pose` (x, y, yaw) [m, m, rad] going `speed` [m/s], steering for
        the path shifted `offset` [m] to its left."""
        x, y, yaw = pose
        rear_x, rear_y = x - 0.5 * self.wheelbase * np.cos(yaw), y - 0.5 * self.wheelbase * np.sin(yaw)  # [m]
        s, _ = path.local_coordinates(np.array([rear_x, rear_y]))
        lookahead = self.lookahead_min + self.lookahead_gain * max(speed, 0.0)
        s_target = min(float(s) + lookahead, path.length)
        target_x, target_y = path.point(s_target) if offset == 0.0 else path.position(s_target, offset).tolist()
        alpha = np.arctan2(target_y - rear_y, target_x - rear_x) - yaw
        distance = max(float(np.hypot(target_x - rear_x, target_y - rear_y)), 1e-3)
        delta = np.arctan2(2.0 * self.wheelbase * np.sin(alpha), distance)
        steer = float(min(max(delta / self.max_steer, -1.0), 1.0))
        remaining = path.length - float(s)
        target_speed = self.target_speed(path, float(s), cruise) if remaining > 3.0 else 0.0
        throttle, brake = self.speed(speed, target_speed, dt)
        return np.array([throttle, steer, brake])
