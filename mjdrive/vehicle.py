"""Cars: parameters, attachment to an MjSpec, (throttle, steer, brake) -> actuators, and read-outs.

The MJCF of each car lives in xml/vehicles/<name>.xml (its header documents the actuator, suspension, tire
and collision-bit choices); the numbers in `VEHICLES` mirror it and the tests check that the compiled model
matches. Conventions: x forward, y left, z up; yaw counter-clockwise from world x; positive steer turns
left. The chassis origin is on the ground at the centre of the car's footprint (the midpoint of the axles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from mjdrive.assets import XML_DIR
from mjdrive.compiled import inline

WHEELS = ("fl", "fr", "rl", "rr")  # order of every per-wheel array
BRAKE_HOLD_SPEED = 0.25  # [m/s] below this speed the brakes act as a stiff damper that holds the car


@dataclass(frozen=True)
class VehicleParams:
    """Physical description of one car model (all numbers as in its MJCF)."""

    name: str
    mass: float  # [kg] total, wheels included
    wheelbase: float  # [m]
    track: float  # [m] same front and rear
    wheel_radius: float  # [m]
    max_steer: float  # [rad] bicycle-equivalent steering angle at steer = 1
    length: float  # [m] footprint, centred on the chassis origin
    width: float  # [m]
    height: float  # [m]
    tire_mu: float  # [-] tire-road friction (tire geoms have contact priority: this mu holds on any surface)
    max_drive_torque: float  # [N m] summed over the driven wheels, full throttle at standstill
    top_speed: float  # [m/s] full throttle, flat road (drive torque falls linearly with wheel speed)
    engine_brake: float  # [N m s/rad] drag torque per driven wheel per rad/s of wheel spin, any throttle
    brake_torque: tuple[float, float]  # [N m] per wheel at brake = 1, (front, rear)
    driven_wheels: tuple[str, ...]  # subset of WHEELS, in WHEELS order
    rest_sink: float  # [m] tire penetration at rest; reset() puts the chassis origin at z = -rest_sink

    @property
    def xml_path(self) -> Path:
        return XML_DIR / "vehicles" / f"{self.name}.xml"

    @property
    def n_ctrl(self) -> int:
        """Actuators per car: 2 steering servos, one drive per driven wheel, 4 brakes."""
        return 2 + len(self.driven_wheels) + 4


VEHICLES: dict[str, VehicleParams] = {
    "sedan": VehicleParams(
        name="sedan", mass=1500.0, wheelbase=2.75, track=1.58, wheel_radius=0.32, max_steer=0.50,
        length=4.80, width=1.83, height=1.45, tire_mu=1.0, max_drive_torque=1600.0, top_speed=55.652,
        engine_brake=1.20, brake_torque=(1730.0, 620.0), driven_wheels=("rl", "rr"), rest_sink=0.0012,
    ),
    "suv": VehicleParams(
        name="suv", mass=2300.0, wheelbase=2.90, track=1.66, wheel_radius=0.37, max_steer=0.48,
        length=4.90, width=1.95, height=1.75, tire_mu=1.0, max_drive_torque=2400.0, top_speed=50.0,
        engine_brake=1.20, brake_torque=(3120.0, 1050.0), driven_wheels=WHEELS, rest_sink=0.0015,
    ),
}  # fmt: skip


def get_params(model_name: str) -> VehicleParams:
    """The VehicleParams of `model_name`; ValueError listing the valid names otherwise."""
    try:
        return VEHICLES[model_name]
    except KeyError:
        raise ValueError(f"unknown vehicle model {model_name!r}; valid names: {sorted(VEHICLES)}") from None


def add_vehicle(
    spec: mujoco.MjSpec,
    model_name: str = "sedan",
    prefix: str = "ego/",
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0),
    yaw: float = 0.0,
) -> None:
    """Attach car `model_name` to `spec` at `pos` [m] (z = 0: wheels on the ground) heading `yaw` [rad].
    Every name of the car (bodies, joints, actuators, sensors, cameras, sites) gets `prefix`."""
    params = get_params(model_name)
    child = mujoco.MjSpec.from_file(str(params.xml_path))
    quat = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
    frame = spec.worldbody.add_frame(pos=[float(p) for p in pos], quat=quat)
    spec.attach(child, prefix=prefix, frame=frame)


def ackermann(delta: np.ndarray | float, wheelbase: float, track: float) -> tuple[np.ndarray, np.ndarray]:
    """(left, right) road-wheel angles [rad] whose axes meet the rear-axle line at the turn centre of the
    bicycle angle `delta` [rad] (radius wheelbase / tan(delta) from the rear-axle centre), both signs.
    A Python float gives two floats: the same numbers (numpy's tangent and arctangent) in fewer numpy calls."""
    if type(delta) is float:  # the per-step path
        t = float(np.tan(delta))
        pair = (wheelbase * t / (wheelbase - 0.5 * track * t), wheelbase * t / (wheelbase + 0.5 * track * t))
        left, right = np.arctan(np.array(pair)).tolist()
        return left, right
    t = np.tan(delta)
    return (np.arctan(wheelbase * t / (wheelbase - 0.5 * track * t)),
            np.arctan(wheelbase * t / (wheelbase + 0.5 * track * t)))  # fmt: skip


def commands_to_ctrl(commands: np.ndarray, params: VehicleParams, speed: np.ndarray | float) -> np.ndarray:
    """Map (..., 3) commands (throttle, steer, brake) of cars moving at longitudinal `speed` (...) [m/s]
    to (..., params.n_ctrl) controls: steer_fl, steer_fr [rad], one drive per driven wheel, brake fl fr rl rr.

    throttle and brake are clipped to [0, 1], steer to [-1, 1] (steer * max_steer is the bicycle angle).
    The brake actuators are dampers (torque = -k * ctrl * omega, k = T_max * r / BRAKE_HOLD_SPEED) and the
    brake ctrl is brake * min(1, BRAKE_HOLD_SPEED / |speed|): while moving the torque is brake * T_max,
    falling with wheel slip (so the wheels never lock), and at rest a stiff damper holds the car.
    Raises ValueError on NaN/inf commands or a last axis that is not 3.
    """
    c = np.asarray(commands, dtype=np.float64)
    if c.shape[-1:] != (3,):
        raise ValueError(f"commands must have shape (..., 3) = (throttle, steer, brake), got {c.shape}")
    if not np.isfinite(c).all():
        raise ValueError(f"vehicle commands (throttle, steer, brake) must be finite, got {c.tolist()}")
    speed = np.asarray(speed, dtype=np.float64)
    if speed.shape != c.shape[:-1]:  # batch shape: commands and speeds broadcast together
        c = np.broadcast_to(c, np.broadcast_shapes(c.shape[:-1], speed.shape) + (3,))
    n_drive = len(params.driven_wheels)
    out = np.empty(c.shape[:-1] + (params.n_ctrl,))
    delta = np.clip(c[..., 1], -1.0, 1.0) * params.max_steer
    out[..., 0], out[..., 1] = ackermann(delta, params.wheelbase, params.track)
    out[..., 2 : 2 + n_drive] = np.clip(c[..., 0:1], 0.0, 1.0)
    hold = BRAKE_HOLD_SPEED / np.maximum(np.abs(speed), BRAKE_HOLD_SPEED)
    out[..., 2 + n_drive :] = (np.clip(c[..., 2], 0.0, 1.0) * hold)[..., None]
    return out


@inline
def chassis_state(px: float, py: float, w: float, x: float, y: float, z: float, vx: float, vy: float, vz: float,
                  wx: float, wy: float, wz: float) -> tuple[float, float, float, float, float, float]:
    """`Vehicle.planar_state` from the free joint's position (px, py) [m], orientation (w, x, y, z), world velocity
    (vx, vy, vz) [m/s] and body angular velocity (wx, wy, wz) [rad/s] (inlined into the tasks' kernels)."""
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    forward = (1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y + w * z) * vy + 2.0 * (x * z - w * y) * vz
    left = 2.0 * (x * y - w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy + 2.0 * (y * z + w * x) * vz
    yaw_rate = 2.0 * (x * z - w * y) * wx + 2.0 * (y * z + w * x) * wy + (1.0 - 2.0 * (x * x + y * y)) * wz
    return px, py, yaw, forward, left, yaw_rate


_chassis_state = getattr(chassis_state, "py_func", chassis_state)  # plain Python on the Python path (no dispatch)


class Vehicle:
    """One car in a compiled model, found by its name prefix; `model_name` None infers it from the mass.
    Ids are looked up once here; the per-step methods only index `data` (no name look-ups)."""

    def __init__(self, model: mujoco.MjModel, prefix: str = "ego/", model_name: str | None = None):
        def oid(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(model, kind, prefix + name)
            if i < 0:
                raise ValueError(f"no {kind.name[6:].lower()} named {prefix + name!r} in the model")
            return i

        def joints(names: list[str]) -> tuple[np.ndarray, np.ndarray]:
            ids = [oid(mujoco.mjtObj.mjOBJ_JOINT, n) for n in names]
            return model.jnt_qposadr[ids], model.jnt_dofadr[ids]

        self.prefix = prefix
        self.body_id = oid(mujoco.mjtObj.mjOBJ_BODY, "chassis")
        mass = float(model.body_subtreemass[self.body_id])
        if model_name is None:
            model_name = min(VEHICLES, key=lambda n: abs(VEHICLES[n].mass - mass))
        self.params = p = get_params(model_name)
        if abs(mass - p.mass) > 0.01 * p.mass:
            raise ValueError(f"car {prefix!r} weighs {mass:.0f} kg, not a {model_name} ({p.mass:.0f} kg)")
        q, v = joints(["root"])
        self._q, self._v = int(q[0]), int(v[0])  # free joint: qpos x y z qw qx qy qz; qvel v(world) w(body)
        self._steer_q, steer_v = joints(["steer_fl", "steer_fr"])
        self._spin_q, self._spin_v = joints([f"spin_{w}" for w in WHEELS])
        self._susp_q, susp_v = joints([f"susp_{w}" for w in WHEELS])
        names = ["steer_fl", "steer_fr", *(f"drive_{w}" for w in p.driven_wheels)]
        names += [f"brake_{w}" for w in WHEELS]
        self.actuator_ids = np.array([oid(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in names])  # ctrl order
        self._acc = int(model.sensor_adr[oid(mujoco.mjtObj.mjOBJ_SENSOR, "imu_acc")])
        self._gz = float(model.opt.gravity[2])  # [m/s^2]
        self._dofs = np.concatenate([np.arange(self._v, self._v + 6), steer_v, self._spin_v, susp_v])
        self._n_brake = 2 + len(p.driven_wheels)  # index of the first brake in ctrl order
        ids = self.actuator_ids  # the car's rows of ctrl: a slice when they follow each other in ctrl order
        contiguous = bool(len(ids)) and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids)))
        self._ctrl_rows = slice(int(ids[0]), int(ids[0]) + len(ids)) if contiguous else ids
        self._model = model

    @property
    def state_addresses(self) -> tuple[int, int]:
        """(qpos, qvel) addresses of the chassis' free joint: x y z qw qx qy qz and v (world) w (body)."""
        return self._q, self._v

    # --- commands ---------------------------------------------------------------------------------------
    def commands_to_ctrl(self, commands: np.ndarray, speed: np.ndarray | float) -> np.ndarray:
        """`commands_to_ctrl` for this car; the result goes to ctrl[..., self.actuator_ids]."""
        return commands_to_ctrl(commands, self.params, speed)

    def apply(self, data: mujoco.MjData, throttle: float, steer: float, brake: float) -> None:
        """Write the controls for throttle in [0, 1], steer in [-1, 1] (+ = left), brake in [0, 1] at the
        car's current speed. Out-of-range values are clipped; NaN or inf raise ValueError.

        `commands_to_ctrl` for one car, in scalars (the per-step path): the same operations, bit for bit (min/max
        keep a clipped -0.0 as np.clip does; the steering angles use numpy's tan and arctan)."""
        t, st, b = float(throttle), float(steer), float(brake)
        if not (math.isfinite(t) and math.isfinite(st) and math.isfinite(b)):
            raise ValueError(f"vehicle commands (throttle, steer, brake) must be finite, got {[t, st, b]}")
        p = self.params
        left, right = ackermann(min(max(st, -1.0), 1.0) * p.max_steer, p.wheelbase, p.track)
        hold = BRAKE_HOLD_SPEED / max(abs(self.speed(data)), BRAKE_HOLD_SPEED)
        drive, brake_ctrl = min(max(t, 0.0), 1.0), min(max(b, 0.0), 1.0) * hold
        n_brake = self._n_brake
        data.ctrl[self._ctrl_rows] = [left, right] + [drive] * (n_brake - 2) + [brake_ctrl] * (p.n_ctrl - n_brake)

    # --- read-outs --------------------------------------------------------------------------------------
    def _quat(self, data: mujoco.MjData) -> tuple[float, float, float, float]:
        a = self._q + 3
        w, x, y, z = data.qpos[a : a + 4].tolist()  # Python floats, read at once
        return w, x, y, z

    def pose(self, data: mujoco.MjData) -> tuple[float, float, float]:
        """(x [m], y [m], yaw [rad]) of the chassis origin (footprint centre) in the world."""
        w, x, y, z = self._quat(data)
        yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return float(data.qpos[self._q]), float(data.qpos[self._q + 1]), yaw

    def velocity_body(self, data: mujoco.MjData) -> tuple[float, float]:
        """(forward, leftward) velocity [m/s] of the chassis origin in the chassis frame."""
        w, x, y, z = self._quat(data)
        vx, vy, vz = data.qvel[self._v : self._v + 3].tolist()
        forward = (1.0 - 2.0 * (y * y + z * z)) * vx + 2.0 * (x * y + w * z) * vy + 2.0 * (x * z - w * y) * vz
        left = 2.0 * (x * y - w * z) * vx + (1.0 - 2.0 * (x * x + z * z)) * vy + 2.0 * (y * z + w * x) * vz
        return forward, left

    def planar_state(self, data: mujoco.MjData) -> tuple[float, float, float, float, float, float]:
        """(x [m], y [m], yaw [rad], forward [m/s], leftward [m/s], yaw rate [rad/s]): `pose`, `velocity_body`
        and `yaw_rate` from one read of the chassis state (the same arithmetic, for the per-step path)."""
        a, b = self._q, self._v
        px, py, _, w, x, y, z = data.qpos[a : a + 7].tolist()  # Python floats, read at once
        vx, vy, vz, wx, wy, wz = data.qvel[b : b + 6].tolist()
        return _chassis_state(px, py, w, x, y, z, vx, vy, vz, wx, wy, wz)

    def speed(self, data: mujoco.MjData) -> float:
        """Signed longitudinal speed [m/s] (negative when rolling backwards)."""
        return self.velocity_body(data)[0]

    def yaw_rate(self, data: mujoco.MjData) -> float:
        """Angular velocity about the world z axis [rad/s], + = turning left."""
        w, x, y, z = self._quat(data)
        v, a = data.qvel, self._v + 3  # free-joint angular velocity is in the body frame
        return (2.0 * (x * z - w * y) * float(v[a]) + 2.0 * (y * z + w * x) * float(v[a + 1])
                + (1.0 - 2.0 * (x * x + y * y)) * float(v[a + 2]))  # fmt: skip

    def acceleration(self, data: mujoco.MjData) -> tuple[float, float]:
        """(longitudinal, lateral) acceleration [m/s^2] at the imu site in the chassis frame, gravity
        removed (the accelerometer reads a - g). Valid after mj_step / mj_forward."""
        w, x, y, z = self._quat(data)
        s, gz = data.sensordata, self._gz  # world gravity (0, 0, gz) in the chassis frame: gz * row 3 of R
        a = self._acc
        return float(s[a]) + gz * 2.0 * (x * z - w * y), float(s[a + 1]) + gz * 2.0 * (y * z + w * x)

    def steering_angle(self, data: mujoco.MjData) -> float:
        """Bicycle-equivalent steering angle [rad]: the mean of the bicycle angles the two front wheels
        imply under Ackermann geometry (exact when they are on the Ackermann curve)."""
        L, h = self.params.wheelbase, 0.5 * self.params.track
        tl, tr = math.tan(float(data.qpos[self._steer_q[0]])), math.tan(float(data.qpos[self._steer_q[1]]))
        return 0.5 * (math.atan(L * tl / (L + h * tl)) + math.atan(L * tr / (L - h * tr)))

    def wheel_speeds(self, data: mujoco.MjData) -> np.ndarray:
        """Wheel spin rates (4,) [rad/s] in WHEELS order; rolling forward is positive."""
        return data.qvel[self._spin_v]

    # --- reset ------------------------------------------------------------------------------------------
    def reset(self, data: mujoco.MjData, x: float, y: float, yaw: float, speed: float = 0.0) -> None:
        """Put the car on the ground at (x, y) [m] heading `yaw` [rad], suspension at its static height,
        moving forward at `speed` [m/s] on rolling wheels, steering straight, commands zeroed; mj_forward."""
        q, v = data.qpos, data.qvel
        z = -self.params.rest_sink
        q[self._q : self._q + 7] = (x, y, z, math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
        q[self._steer_q] = 0.0
        q[self._spin_q] = 0.0
        q[self._susp_q] = 0.0  # the spring preload balances the static load at 0
        v[self._dofs] = 0.0
        v[self._v], v[self._v + 1] = speed * math.cos(yaw), speed * math.sin(yaw)
        v[self._spin_v] = speed / self.params.wheel_radius
        data.qacc_warmstart[self._dofs] = 0.0
        data.ctrl[self.actuator_ids] = commands_to_ctrl(np.zeros(3), self.params, speed)
        mujoco.mj_forward(self._model, data)
