"""Lateral path tracking by LQR (study 002 §4.3, URBAN.md "Operative level").

Model: the kinematic bicycle seen from its rear axle, in the path frame. With e_y the rear axle's lateral
error [m] (left > 0), e_psi the heading error [rad], v the speed [m/s], L the wheelbase [m], delta the bicycle
steering angle [rad] and kappa the path curvature [1/m]:

    de_y/dt = v sin(e_psi),    de_psi/dt = v tan(delta) / L - v kappa

Linearised around the path, with delta = delta_ff + u (the feed-forward delta_ff = atan(L kappa)), the error
(e_y, e_psi) obeys d/dt (e_y, e_psi) = [[0, v], [0, 0]] (e_y, e_psi) + [[0], [v / L]] u, discretised exactly
(zero-order hold) at the control period T. The state is augmented with the last correction u_prev and the input
is its change du = u - u_prev, so the cost weighs the steering rate (a car's lateral jerk is v^2 / L times it):

    x = (e_y, e_psi, u_prev),   x+ = A x + B du,
    A = [[1, v T, v^2 T^2 / (2 L)], [0, 1, v T / L], [0, 0, 1]],   B = [[v^2 T^2 / (2 L)], [v T / L], [1]]

The gain K(v) of du = -K x comes from the discrete algebraic Riccati equation (`scipy.linalg.solve_discrete_are`)
on a grid of speeds, once (`GainTable`); a step interpolates it. The rear axle is the reference point because
its velocity lies along the car's heading (no side slip in the kinematic model), so on a circle the steady
state has e_y = e_psi = 0 and delta = atan(L kappa).

Delay compensation: a steering command acts `delay` seconds late (the steering servo's lag, measured at
about 0.04 s for the sedan and the suv by `tools.identify_vehicle`, plus any latency of the car). `LateralLQR`
predicts the error state over that delay with the commands already sent (the nonlinear kinematic model above,
integrated in small steps), then applies the gain to the predicted state.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_discrete_are

STEER_LAG = 0.04  # [s] the steering servo's first-order time constant (tools.identify_vehicle, sedan and suv)
MIN_SPEED = 1.0  # [m/s] the gain table's lowest speed: below it the path error barely responds to steering
PREDICTION_STEP = 0.01  # [s] integration step of the delay prediction


def lateral_model(v: float, wheelbase: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Discrete (A, B) of the rear-axle kinematic error model augmented with the last steering correction, at
    speed v [m/s] and period dt [s] (zero-order hold); see the module docstring."""
    if wheelbase <= 0 or dt <= 0:
        raise ValueError(f"wheelbase and dt must be > 0, got {wheelbase}, {dt}")
    by, bpsi = v * v * dt * dt / (2.0 * wheelbase), v * dt / wheelbase
    a = np.array([[1.0, v * dt, by], [0.0, 1.0, bpsi], [0.0, 0.0, 1.0]])
    b = np.array([[by], [bpsi], [1.0]])
    return a, b


def lqr_gain(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The discrete LQR gain K (m, n) minimising sum x'Qx + u'Ru for x+ = Ax + Bu, u = -Kx."""
    p = solve_discrete_are(a, b, q, r)
    return np.linalg.solve(r + b.T @ p @ b, b.T @ p @ a)


@dataclass(frozen=True)
class LQRWeights:
    """The LQR's costs on the error state, the steering correction and its change per period."""

    lateral: float = 1.0  # [1/m^2] on e_y
    heading: float = 1.0  # [1/rad^2] on e_psi
    steering: float = 1.0  # [1/rad^2] on u = delta - delta_ff
    steering_rate: float = 20.0  # [1/rad^2] on du, its change in one control period

    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        if min(self.lateral, self.heading, self.steering) < 0 or self.steering_rate <= 0:
            raise ValueError(f"LQR weights must be >= 0 (state) and > 0 (steering rate), got {self}")
        return np.diag([self.lateral, self.heading, self.steering]), np.array([[self.steering_rate]])


class GainTable:
    """K(v) of the LQR on a grid of speeds, solved once; `gain(v)` interpolates linearly (clamped at the ends)."""

    def __init__(self, wheelbase: float, dt: float, weights: LQRWeights = LQRWeights(),
                 speeds: np.ndarray | None = None):
        self.speeds = np.arange(MIN_SPEED, 30.0 + 1e-9, 0.5) if speeds is None else np.asarray(speeds, float)
        q, r = weights.matrices()
        self.gains = np.array([lqr_gain(*lateral_model(float(v), wheelbase, dt), q, r)[0] for v in self.speeds])

    def gain(self, v: float) -> tuple[float, float, float]:
        """(k_y [rad/m], k_psi [rad/rad], k_u [-]) at speed v [m/s]."""
        speeds = self.speeds
        v = min(max(v, speeds[0]), speeds[-1])
        i = min(int(np.searchsorted(speeds, v, side="right")) - 1, len(speeds) - 2)
        t = (v - speeds[i]) / (speeds[i + 1] - speeds[i])
        g0, g1 = self.gains[i], self.gains[i + 1]
        return (float(g0[0] + t * (g1[0] - g0[0])), float(g0[1] + t * (g1[1] - g0[1])),
                float(g0[2] + t * (g1[2] - g0[2])))


@dataclass
class LateralLQR:
    """Steering angle [rad] from the path errors, with curvature feed-forward and delay compensation.

    `delay` [s]: how long after it is sent a steering angle acts (compensated when `compensate`); the
    commands sent in the last `delay` seconds are kept to predict the error state over it."""

    wheelbase: float  # [m]
    max_steer: float  # [rad] bicycle angle at steer command 1
    dt: float  # [s] control period
    delay: float = STEER_LAG  # [s]
    compensate: bool = True
    weights: LQRWeights = field(default_factory=LQRWeights)

    def __post_init__(self):
        if self.delay < 0:
            raise ValueError(f"delay must be >= 0, got {self.delay}")
        self.table = GainTable(self.wheelbase, self.dt, self.weights)
        self._sent: deque[float] = deque()  # steering angles [rad] sent, most recent last
        self._slots = int(math.ceil(self.delay / self.dt - 1e-9))  # commands still in flight
        self.reset()

    def reset(self) -> None:
        self._sent.clear()
        self.correction = 0.0  # [rad] u = delta - delta_ff of the last command

    def predict(self, e_y: float, e_psi: float, v: float, kappa: float) -> tuple[float, float]:
        """(e_y, e_psi) after `delay` seconds under the commands already sent (oldest first), on a path of
        curvature kappa [1/m], at constant speed v [m/s]."""
        left = self.delay
        sent = list(self._sent)[-self._slots:] if self._slots else []
        # the last `delay` seconds of commands: the oldest one still acts for the remainder of its period
        pieces = []
        for k, delta in enumerate(sent):
            span = self.dt if k else left - self.dt * (len(sent) - 1)
            pieces.append((delta, max(span, 0.0)))
        for delta, span in pieces:
            steps = max(1, int(math.ceil(span / PREDICTION_STEP - 1e-9)))
            h = span / steps
            for _ in range(steps):
                e_y += h * v * math.sin(e_psi)
                e_psi += h * (v * math.tan(delta) / self.wheelbase - v * kappa)
        return e_y, e_psi

    def __call__(self, e_y: float, e_psi: float, v: float, kappa: float) -> float:
        """The bicycle steering angle [rad] (within +-max_steer) for rear-axle lateral error e_y [m] (left > 0)
        and heading error e_psi [rad] (car minus path) at speed v [m/s], with the path's curvature kappa [1/m]
        where the command will act."""
        if self.compensate and self.delay > 0:
            e_y, e_psi = self.predict(e_y, e_psi, v, kappa)
        k_y, k_psi, k_u = self.table.gain(v)
        feed_forward = math.atan(self.wheelbase * kappa)
        u = self.correction - (k_y * e_y + k_psi * e_psi + k_u * self.correction)
        delta = min(max(feed_forward + u, -self.max_steer), self.max_steer)
        self.correction = delta - feed_forward  # as saturated
        self._sent.append(delta)
        while len(self._sent) > max(self._slots, 1):
            self._sent.popleft()
        return delta
