"""Identify each car's longitudinal response and steering lag by measurement, for `mjdrive.control.pedals` and
`mjdrive.control.lqr`:

    python -m tools.identify_vehicle            # prints the fitted constants of every car
    python -m tools.identify_vehicle --vehicle sedan

Longitudinal: the car drives straight on flat ground at a set speed; a pedal (throttle or brake) is held for
0.3 s and the acceleration measured over its last 0.2 s, on a grid of pedal positions and speeds. Least squares
then fit the model of `pedals.LongitudinalModel`: a = u (c0 - c1 v) - d v - e with the throttle u, and
a = -k b - d v - e with the brake b (above the brakes' hold speed). Steering: from straight driving at 8 m/s a
step of the steer command; the time [s] until the bicycle steering angle covers 63% of the step (the lag of a
first-order response).
"""

from __future__ import annotations

import mujoco
import numpy as np

from mjdrive import world
from mjdrive.cli import ArgumentParser, run_reporting_errors
from mjdrive.control.pedals import LongitudinalModel
from mjdrive.vehicle import VEHICLES, Vehicle

SPEEDS = (3.0, 5.0, 7.0, 9.0, 11.0, 13.0, 15.0)  # [m/s] above the brakes' hold speed
THROTTLES = (0.0, 0.1, 0.2, 0.35, 0.5, 0.7, 1.0)
BRAKES = (0.05, 0.1, 0.2, 0.35, 0.5)
SETTLE, MEASURE = 0.1, 0.2  # [s] pedal held before and during the measurement


class FlatGround:
    """One car on an empty world (no road), stepped at the default physics step."""

    def __init__(self, vehicle: str):
        self.model = world.build(None, vehicle=vehicle)
        self.data = mujoco.MjData(self.model)
        self.car = Vehicle(self.model, model_name=vehicle)

    def run(self, seconds: float, throttle: float, steer: float, brake: float) -> None:
        for _ in range(int(round(seconds / self.model.opt.timestep))):
            self.car.apply(self.data, throttle, steer, brake)
            mujoco.mj_step(self.model, self.data)

    def acceleration(self, speed: float, throttle: float, brake: float) -> float:
        """[m/s^2] measured with the pedal held at `speed` [m/s]."""
        self.car.reset(self.data, 0.0, 0.0, 0.0, speed=speed)
        self.run(SETTLE, throttle, 0.0, brake)
        v0 = self.car.speed(self.data)
        self.run(MEASURE, throttle, 0.0, brake)
        return (self.car.speed(self.data) - v0) / MEASURE


def identify_longitudinal(vehicle: str, speeds=SPEEDS, throttles=THROTTLES, brakes=BRAKES) -> LongitudinalModel:
    """The least-squares `LongitudinalModel` of `vehicle` from the measurement grid."""
    ground = FlatGround(vehicle)
    rows, targets = [], []
    for v in speeds:
        for u in throttles:  # a = u c0 - u v c1 - v d - e
            rows.append((u, -u * v, 0.0, -v, -1.0))
            targets.append(ground.acceleration(v, u, 0.0))
        for b in brakes:  # a = -b k - v d - e
            rows.append((0.0, 0.0, -b, -v, -1.0))
            targets.append(ground.acceleration(v, 0.0, b))
    c0, c1, k, d, e = np.linalg.lstsq(np.array(rows), np.array(targets), rcond=None)[0]
    return LongitudinalModel(*(round(float(x), 4) for x in (c0, c1, k, d, e)))


def steering_lag(vehicle: str, speed: float = 8.0, steer: float = 0.2) -> float:
    """[s] until the bicycle steering angle covers 63% of a steer step at `speed` [m/s]."""
    ground = FlatGround(vehicle)
    ground.car.reset(ground.data, 0.0, 0.0, 0.0, speed=speed)
    ground.run(0.5, 0.2, 0.0, 0.0)
    target = steer * ground.car.params.max_steer
    dt = ground.model.opt.timestep
    for k in range(1, 200):
        ground.run(dt, 0.2, steer, 0.0)
        if ground.car.steering_angle(ground.data) >= 0.632 * target:
            return k * dt
    return float("nan")


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--vehicle", choices=tuple(VEHICLES), default=None, help="one car (default: every car)")
    args = parser.parse_args(argv)
    for name in [args.vehicle] if args.vehicle else VEHICLES:
        model = identify_longitudinal(name)
        print(f'"{name}": {model!r},  # steering lag {steering_lag(name):.3f} s')
    return 0


if __name__ == "__main__":
    raise SystemExit(run_reporting_errors("tools.identify_vehicle", main))
