"""Acceleration to pedals: the inverse of each car's identified longitudinal response, with a small integral
correction, so that the acceleration a plan asks for is the acceleration the car makes.

The response (flat road, straight, above the brakes' hold speed; measured by `python -m tools.identify_vehicle`,
checked against the physics by tests/test_control.py):

    throttle u in [0, 1]:  a = u (c0 - c1 v) - d v - e      (drive torque falls with wheel speed; engine braking)
    brake b in [0, 1]:     a = -k b - d v - e

Below the hold speed the brakes act as a stiff damper that keeps the car still (`mjdrive.vehicle`): a stopped
car asked not to move is held with `HOLD_BRAKE`.
"""

from __future__ import annotations

from dataclasses import dataclass

HOLD_BRAKE = 0.4  # brake that holds a stopped car
STOPPED = 0.05  # [m/s] below this a car asked for no positive acceleration is held
MEASURED = 0.3  # [m/s] below this speed the acceleration error is not integrated (the car may just have stopped)


@dataclass(frozen=True)
class LongitudinalModel:
    """a [m/s^2] = u (c0 - c1 v) - d v - e (throttle u) or -k b - d v - e (brake b) at speed v [m/s]."""

    c0: float  # [m/s^2] full-throttle acceleration at rest (before losses)
    c1: float  # [1/s] its fall with speed
    k: float  # [m/s^2] full-brake deceleration
    d: float  # [1/s] engine braking per m/s
    e: float  # [m/s^2] rolling loss

    def coast(self, v: float) -> float:
        """[m/s^2] with neither pedal."""
        return -self.d * v - self.e

    def acceleration(self, v: float, throttle: float, brake: float) -> float:
        """The model's acceleration [m/s^2] at speed v [m/s] (one pedal at a time, as `pedals` sets them)."""
        return throttle * (self.c0 - self.c1 * v) - self.k * brake + self.coast(v)

    def pedals(self, accel: float, v: float) -> tuple[float, float]:
        """(throttle, brake) in [0, 1]^2, at most one non-zero, that make `accel` [m/s^2] at speed v [m/s]."""
        coast = self.coast(v)
        if accel >= coast:
            return min((accel - coast) / max(self.c0 - self.c1 * v, 1e-3), 1.0), 0.0
        return 0.0, min((coast - accel) / self.k, 1.0)


MODELS: dict[str, LongitudinalModel] = {  # python -m tools.identify_vehicle
    "sedan": LongitudinalModel(c0=3.1086, c1=0.0412, k=9.2353, d=0.0148, e=-0.0034),
    "suv": LongitudinalModel(c0=2.6299, c1=0.0386, k=9.2329, d=0.0142, e=-0.0019),
}


@dataclass
class PedalController:
    """Pedals for a commanded acceleration: the model's inverse plus an integral of the acceleration error
    (the last period's commanded against the measured one), bounded to `max_correction`."""

    model: LongitudinalModel
    dt: float  # [s] control period
    gain: float = 0.5  # [1/s] of the integral
    max_correction: float = 0.5  # [m/s^2]

    def __post_init__(self):
        self.reset()

    def reset(self) -> None:
        self.correction = 0.0  # [m/s^2]
        self._last: tuple[float, float] | None = None  # (commanded accel, speed) of the last period

    def __call__(self, accel: float, v: float) -> tuple[float, float]:
        """(throttle, brake) for the commanded `accel` [m/s^2] at the measured speed v [m/s]."""
        if self._last is not None:
            commanded, v_before = self._last
            moving = v > MEASURED and v_before > MEASURED  # a stopping car's acceleration says nothing
            if moving:
                error = commanded - (v - v_before) / self.dt
                self.correction = min(max(self.correction + self.gain * self.dt * error, -self.max_correction),
                                      self.max_correction)
        self._last = (accel, v)
        if v < STOPPED and accel <= 0.0:
            return 0.0, HOLD_BRAKE
        return self.model.pedals(accel + self.correction, v)
