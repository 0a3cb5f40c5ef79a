"""What every driving task shares: the ego car, the action spec, safety sensors, episode info with the comfort
metrics at the episode's end, and an Environment that turns physics blow-ups into an ended episode instead of
an exception."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import dm_env
import mujoco
import numpy as np
from dm_control import mujoco as dm_mujoco
from dm_control.rl import control
from dm_env import specs

from mjdrive.comfort import ComfortMeter, ComfortMetrics
from mjdrive.config import Config, ConfigError, param
from mjdrive.roads import RoadMap
from mjdrive.roads.geometry import footprint
from mjdrive.sensors import SENSORS, CameraRenderer, CollisionSensor, ExtraSensors, LaneInvasionSensor
from mjdrive.tasks.stepping import Substeps
from mjdrive.traffic import Traffic
from mjdrive.vehicle import VEHICLES, Vehicle
from mjdrive.world import PHYSICS_TIMESTEP

ACTION_NAMES = ("throttle", "steer", "brake")
ACTION_SPEC = specs.BoundedArray(
    (3,), np.float64, minimum=[0.0, -1.0, 0.0], maximum=[1.0, 1.0, 1.0], name="throttle,steer,brake"
)


OBSERVATIONS = ("features", "camera")
MAX_SEED = 2**32 - 1  # numpy RandomState seeds are 32-bit
CONTACT_SAMPLE_PERIOD = 0.02  # [s] the ego's contacts are sampled this often, whatever the physics step


@dataclass(frozen=True)
class DrivingConfig(Config):
    """Keywords every driving task takes; each domain's config adds its own (see `mjdrive list --kwargs`)."""

    random: int | np.random.RandomState | None = param(
        None, "seed of the task's random stream (episodes, traffic); None: fresh entropy", ge=0, le=MAX_SEED)
    observation: str = param("features", "observation set (see the domain's docs)", choices=OBSERVATIONS)
    vehicle: str = param("sedan", "the ego car", choices=tuple(VEHICLES))
    time_limit: float = param(60.0, "episode length, then truncation", "s", gt=0.0, le=3600.0)
    physics_dt: float = param(PHYSICS_TIMESTEP, "MuJoCo time step (the control period must be a multiple)", "s",
                              ge=0.0005, le=0.01)
    sensors: tuple[str, ...] | None = param(
        None, "extra observations: front-camera depth [m] and segmentation images, a range ring [m] (a list or "
        "comma-separated names); None: none", choices=SENSORS)
    sensor_size: int = param(64, "side of the square depth and segmentation images", "px", ge=8, le=512)
    range_rays: int = param(36, "rays of the range ring, evenly spaced, the first straight ahead", ge=1, le=1024)
    range_max: float = param(50.0, "reach of the range ring (its reading where no ray hits)", "m", gt=0.0, le=500.0)

    def __post_init__(self) -> None:
        if isinstance(self.sensors, str):  # "depth,range" as typed on a command line
            object.__setattr__(self, "sensors", tuple(n.strip() for n in self.sensors.split(",") if n.strip()))
        if isinstance(self.sensors, (list, tuple)) and not len(self.sensors):  # no sensor: the same as None
            object.__setattr__(self, "sensors", None)
        super().__post_init__()

    def extra_sensors(self) -> ExtraSensors | None:
        """The sensors of `sensors` (None without any), for DrivingTask."""
        if self.sensors is None:
            return None
        return ExtraSensors(self.sensors, self.sensor_size, self.range_rays, self.range_max)


@dataclass(frozen=True)
class EnvironmentConfig(Config):
    """Keywords of the dm_control Environment (`suite.load(..., environment_kwargs=...)`)."""

    control_timestep: float | None = param(None, "period of one env step; None: the task's control rate", "s",
                                           gt=0.0, le=10.0)
    flat_observation: bool = param(False, "concatenate the observation dict into one array")


def environment_config(environment_kwargs: Mapping[str, Any] | None, physics_dt: float,
                       default_control_timestep: float, where: str) -> dict[str, Any]:
    """Validated dm_control Environment keywords with the control period resolved: it must be a whole
    multiple of the physics step."""
    config = EnvironmentConfig.from_dict(environment_kwargs, where=f"{where} environment_kwargs")
    control_timestep = config.control_timestep or default_control_timestep
    ratio = control_timestep / physics_dt
    if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6 * ratio:
        raise ConfigError(f"{where}: control_timestep={control_timestep:g} s must be a whole multiple of "
                          f"physics_dt={physics_dt:g} s")
    return {"control_timestep": control_timestep, "flat_observation": config.flat_observation}


def configured_task(config_class: type[DrivingConfig], **defaults: Any) -> Callable:
    """Decorator of a registered task function `build(config, environment_kwargs) -> env`: the function the
    suite calls takes keyword arguments, validates them into `config_class` (with this task's `defaults`)
    before anything is built, and carries `config_class` and `config_defaults` for `mjdrive list --kwargs`."""

    def decorate(build: Callable[[DrivingConfig, Mapping[str, Any] | None], DrivingEnvironment]) -> Callable:
        where = f"{build.__module__.rsplit('.', 1)[-1]}/{build.__name__}"

        def task_fn(environment_kwargs: Mapping[str, Any] | None = None, **kwargs: Any) -> DrivingEnvironment:
            config = config_class.from_dict(kwargs, defaults, where=where)
            return build(config, environment_kwargs)

        task_fn.__name__, task_fn.__qualname__, task_fn.__doc__ = build.__name__, build.__name__, build.__doc__
        task_fn.__module__ = build.__module__
        task_fn.config_class, task_fn.config_defaults = config_class, dict(defaults)
        return task_fn

    return decorate


@dataclass(frozen=True)
class RoadUsers:
    """Snapshot of the other road users: kind names, poses (N,3) [m, m, rad], half sizes (N,3) [m], and
    where the traffic has them (urban), their intentions (N, 4) by scenario (`mjdrive.traffic.intentions`
    SCENARIOS columns, -1 for pedestrians)."""

    kinds: tuple[str, ...]
    poses: np.ndarray
    half_sizes: np.ndarray
    intentions: np.ndarray | None = None


NO_ROAD_USERS = RoadUsers((), np.zeros((0, 3)), np.zeros((0, 3)))


class Physics(dm_mujoco.Physics):
    """dm_control Physics; `raw_model`/`raw_data` are the mujoco structs used on the hot path (attributes, set
    whenever dm_control (re)loads the data).

    A task may register `callback(physics, dt)` with `set_substeps`: `step(n)` then runs the physics in chunks and
    calls it after each chunk that needs it, with the chunk's duration dt [s] (`tasks.stepping`, the substep loop:
    e.g. to move kinematic traffic and write its mocap poses at a finer period than the control period).
    """

    substeps: Substeps | None = None
    every_chunk: bool = False  # True: every chunk's work in the callback (tests that watch each sample)
    raw_model: mujoco.MjModel
    raw_data: mujoco.MjData

    def set_substeps(self, callback: Callable[[Physics, float], None] | None, period: float,
                     sensor: CollisionSensor | None = None, traffic: Traffic | None = None) -> None:
        """Run `callback(physics, dt)` between chunks of `period` [s] of physics (the nearest whole number of physics
        steps, at least one) from now on; None: no callback. With the ego's collision `sensor` and the `traffic` the
        callback advances, the substep loop does their plain work itself and calls back only where more is due."""
        self.substeps = None if callback is None else Substeps(self.raw_model.opt.timestep, period, callback, sensor,
                                                               traffic)

    def _reload_from_data(self, data) -> None:
        self.raw_model, self.raw_data = data.model.ptr, data.ptr  # before dm_control's own set-up uses them
        super()._reload_from_data(data)

    def step(self, nstep: int = 1) -> None:
        with self.check_invalid_state():
            self.advance(nstep)

    def advance(self, nstep: int = 1) -> None:
        """`nstep` physics steps (with the substep work), without dm_control's invalid-state check:
        DrivingEnvironment.after_physics checks the warnings itself."""
        if self.substeps is None:
            mujoco.mj_step(self.raw_model, self.raw_data, nstep)
        else:
            self.substeps.advance(self, nstep)


class DrivingTask(control.Task):
    """Base task: ego vehicle bound to the model, throttle/steer/brake actions, collision and
    lane-invasion sensors, and `info` (a dict of episode metrics refreshed every step).

    Comfort: `comfort` (a `mjdrive.comfort.ComfortMeter`) gets the chassis' planar velocity and yaw
    (`comfort_sample`) after every reset and control step; the DrivingEnvironment drives it and puts the
    metrics (`ComfortMetrics.as_dict()` keys, e.g. `jerk_p95_mps3`) into `info` at the episode's last step,
    sampled every control period `control_dt` [s] (set by the DrivingEnvironment).

    Extra sensors (`sensors`, from the config's `sensors` keyword): a task adds `sensor_spec` to its
    observation_spec and `sensor_observation` to its observation.

    Control underneath an env step (the urban tasks' decisions): a task with `control_ticks` > 1 splits each
    env step's physics into that many control periods; the DrivingEnvironment calls `control_tick(physics, k)`
    before the k-th and samples the comfort meter after each, so the comfort metrics keep the control rate.
    """

    control_ticks: int = 1  # control periods per env step

    def __init__(self, model: mujoco.MjModel, road_map: RoadMap, vehicle: str, random=None,
                 sensors: ExtraSensors | None = None):
        super().__init__()
        self._random = random if isinstance(random, np.random.RandomState) else np.random.RandomState(random)
        self.road_map = road_map
        self.params = VEHICLES[vehicle]
        self.vehicle = Vehicle(model, prefix="ego/", model_name=vehicle)
        self.collision_sensor = CollisionSensor(model)
        self.lane_invasion_sensor = LaneInvasionSensor(road_map)
        self.cameras: dict[tuple[str, int, int, bool], CameraRenderer] = {}
        self.sensors = sensors  # depth, segmentation, range ring on request
        self.info: dict[str, Any] = {}  # episode metrics, refreshed every step
        self.reward_terms: dict[str, float] = {}  # this step's reward, term by term (for logs)
        self.comfort = ComfortMeter()  # this episode's chassis samples, one per control step
        self._chassis: tuple[float, float, float] | None = None  # (yaw, forward, left) read since the physics moved
        self.control_dt: float | None = None  # [s] control period, set by the DrivingEnvironment

    @property
    def random(self) -> np.random.RandomState:
        return self._random

    def seed(self, seed: int | None) -> None:
        """Reseed the task's random stream (episode sampling)."""
        self._random = np.random.RandomState(seed)

    # --- actions ------------------------------------------------------------------------------------
    def action_spec(self, physics: Physics) -> specs.BoundedArray:
        return ACTION_SPEC

    def control_tick(self, physics: Physics, k: int) -> None:
        """Before the k-th control period of an env step's physics (k = 0 .. control_ticks - 1): a task that
        controls the car underneath its env step sets the commands here."""

    def before_step(self, action, physics: Physics) -> None:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (3,):
            raise ValueError(f"action must have shape (3,) = (throttle, steer, brake), got {action.shape}")
        throttle, steer, brake = action.tolist()
        self.vehicle.apply(physics.raw_data, throttle, steer, brake)
        self.last_action = action
        self._chassis = None  # the physics moves next

    # --- ego state ----------------------------------------------------------------------------------
    def ego_corners(self, physics: Physics) -> np.ndarray:
        x, y, yaw = self.vehicle.pose(physics.raw_data)
        return footprint(x, y, yaw, self.params.length, self.params.width)

    def comfort_sample(self, data: mujoco.MjData) -> tuple[np.ndarray, float]:
        """(planar chassis velocity (2,) [m/s] in the world frame, yaw [rad]): a `ComfortMeter` sample."""
        vx, vy, yaw = self._planar_velocity(data)
        return np.array([vx, vy]), yaw

    def read_chassis(self, data: mujoco.MjData) -> tuple[float, float, float, float, float, float]:
        """`Vehicle.planar_state` of the ego, kept for this control step's comfort sample (tasks that read it
        after a step or reset let the sample reuse it)."""
        state = self.vehicle.planar_state(data)
        self._chassis = state[2], state[3], state[4]
        return state

    def _planar_velocity(self, data: mujoco.MjData, reuse: bool = False) -> tuple[float, float, float]:
        """(vx, vy) [m/s] of the chassis in the world frame and its yaw [rad] (`reuse`: the chassis state
        `read_chassis` kept since the physics last moved, if any)."""
        if reuse and self._chassis is not None:
            yaw, forward, left = self._chassis
        else:
            _, _, yaw, forward, left, _ = self.vehicle.planar_state(data)
        c, s = math.cos(yaw), math.sin(yaw)
        return c * forward - s * left, s * forward + c * left, yaw

    def reset_comfort(self, physics: Physics) -> None:
        """Start the episode's comfort samples with the state after reset."""
        self.comfort.reset()
        self.sample_comfort(physics.raw_data)

    def sample_comfort(self, data: mujoco.MjData, meter: ComfortMeter | None = None) -> None:
        """Add the state of `data` after a control step to `meter` (default: the task's `comfort`; the
        recorder keeps its own); a non-finite state is left out."""
        vx, vy, yaw = self._planar_velocity(data, reuse=meter is None)
        if math.isfinite(yaw) and math.isfinite(vx) and math.isfinite(vy):
            (self.comfort if meter is None else meter).append(vx, vy, yaw)

    def comfort_metrics(self) -> dict[str, float]:
        """The episode's comfort metrics so far (`ComfortMetrics.as_dict()`; NaN when too short to filter,
        or without a control period)."""
        if self.control_dt is None:
            return ComfortMetrics.nan().as_dict()
        return self.comfort.metrics(self.control_dt).as_dict()

    def reset_safety_sensors(self, physics: Physics) -> None:
        """Reset the sensors and sample contacts between physics chunks (`substep`, every `substep_period()`
        seconds of physics: the chunk is the nearest whole number of physics steps) from now on."""
        self.lane_invasion_sensor.reset(self.ego_corners(physics))
        self.collision_sensor.reset()
        physics.set_substeps(self.substep, self.substep_period(), self.collision_sensor, self.substep_traffic())

    def substep_period(self) -> float:
        """[s] of physics between `substep` calls: CONTACT_SAMPLE_PERIOD (tasks that move things between
        chunks may set their own)."""
        return CONTACT_SAMPLE_PERIOD

    def substep_traffic(self) -> Traffic | None:
        """The traffic `substep` advances after sampling the contacts (None: it only samples them), for the
        substep loop (`tasks.stepping`), which does both where it can."""
        return None

    def substep(self, physics: Physics, dt: float) -> None:
        """The substep callback (after a chunk of physics steps that needs it): sample the ego's contacts. Tasks that
        move things between chunks (traffic) extend it."""
        self.collision_sensor.sample(physics.raw_data)

    def road_users(self) -> RoadUsers:
        """Every other road user now (for logs and viewers): those of `self.traffic` where the task has
        traffic, none otherwise."""
        traffic = getattr(self, "traffic", None)
        if traffic is None:
            return NO_ROAD_USERS
        present = traffic.present
        kinds = tuple(k for k, p in zip(traffic.kinds, present, strict=True) if p)
        return RoadUsers(kinds, traffic.poses()[present], traffic.half_size[present])

    def render_camera(self, physics: Physics, camera: str, height: int, width: int,
                      markers: np.ndarray | None = None, antialias: bool = False) -> np.ndarray:
        """Off-screen render of `camera` (renderer created once per (camera, size, antialias))."""
        key = (camera, height, width, antialias)
        if key not in self.cameras:
            self.cameras[key] = CameraRenderer(physics.raw_model, camera, height, width, antialias)
        return self.cameras[key].render(physics.raw_data, markers)

    def sensor_spec(self, physics: Physics) -> dict[str, specs.BoundedArray]:
        """Specs of the extra sensors' observations, by name ({} without sensors)."""
        return {} if self.sensors is None else self.sensors.specs(physics.raw_model)

    def sensor_observation(self, physics: Physics) -> dict[str, np.ndarray]:
        """The extra sensors' observations of the current state ({} without sensors)."""
        return {} if self.sensors is None else self.sensors(physics.raw_model, physics.raw_data)

    def close_cameras(self) -> None:
        """Free the camera renderers and the sensors' camera (each in its own GL context); a later render
        makes new ones."""
        for renderer in self.cameras.values():
            renderer.close()
        self.cameras.clear()
        if self.sensors is not None:
            self.sensors.close()


class DrivingEnvironment(control.Environment):
    """dm_control Environment whose episode ends (discount 0, `info["physics_error"]`) when the
    simulation becomes unstable, instead of raising and killing a training run. It samples the task's
    comfort meter after every reset and step, and puts the comfort metrics into `info` at the episode's
    last step (whatever ends it: the task, the time limit or a physics error).

    A control step is `before_physics(action)`, then for each of the task's `control_ticks` control periods
    `before_tick(k)` and `physics.advance(tick_steps)`, then `after_physics()`: `step` runs them, the batched env
    (`mjdrive.envs.batched`) runs the halves around one physics call per control period for all its copies, so
    both step a task the same way."""

    def __init__(self, physics: Physics, task: DrivingTask, **kwargs):
        kwargs.setdefault("legacy_step", False)
        if kwargs["legacy_step"]:
            raise ValueError("DrivingEnvironment steps with mj_step only (legacy_step=False)")
        super().__init__(physics, task, **kwargs)
        self._last_observation = None
        self._warnings: tuple[mujoco.MjData, np.ndarray] | None = None  # (data, its warning counts: a view)
        self._warnings_before = self.warning_counts().tobytes()  # the counts before this step's physics
        ticks = task.control_ticks
        if ticks < 1 or self._n_sub_steps % ticks:
            raise ValueError(f"{self._n_sub_steps} physics steps per env step do not split into {ticks} control "
                             "periods")
        self.tick_steps = self._n_sub_steps // ticks  # physics steps per control period
        task.control_dt = self.control_timestep() / ticks  # [s] the comfort samples' period

    @property
    def info(self) -> dict[str, Any]:
        return self.task.info

    def warning_counts(self) -> np.ndarray:
        """MuJoCo's warning counts of the physics' data now (a view into it, kept while the data is the same)."""
        data = self._physics.raw_data
        if self._warnings is None or self._warnings[0] is not data:
            self._warnings = (data, data.warning.number)
        return self._warnings[1]

    @property
    def n_sub_steps(self) -> int:
        """Physics steps per control step."""
        return self._n_sub_steps

    @property
    def max_episode_steps(self) -> int | None:
        """Control steps until the time limit ends an episode (None without a limit)."""
        return math.ceil(self._step_limit) if math.isfinite(self._step_limit) else None

    @property
    def episode_over(self) -> bool:
        """The last step ended the episode (or none has begun): the next `step` resets."""
        return self._reset_next_step

    def close(self) -> None:
        """Free the task's camera renderers (dm_env's close frees nothing)."""
        self.task.close_cameras()
        super().close()

    def reset(self) -> dm_env.TimeStep:
        timestep = super().reset()
        self._last_observation = timestep.observation
        self.task.reset_comfort(self.physics)
        return timestep

    def step(self, action) -> dm_env.TimeStep:
        if self._reset_next_step:
            return self.reset()
        self.before_physics(action)
        for k in range(self._task.control_ticks):
            self.before_tick(k)
            self._physics.advance(self.tick_steps)
        return self.after_physics()

    def before_tick(self, k: int) -> None:
        """Before the k-th control period of a step's physics: the comfort sample of the period before (the last
        one's is taken after the step), then the task's `control_tick`."""
        if k:
            self._task.sample_comfort(self._physics.raw_data)
        self._task.control_tick(self._physics, k)

    def before_physics(self, action) -> None:
        """First half of a control step: the task applies `action`; the physics' warning counts are kept to
        tell a blow-up in `after_physics`."""
        self._task.before_step(action, self._physics)
        self._warnings_before = self.warning_counts().tobytes()

    def after_physics(self) -> dm_env.TimeStep:
        """Second half of a control step, once the physics advanced `n_sub_steps`: the task's `after_step`,
        reward, observation and termination (as dm_control's `Environment.step`), the comfort sample; a new
        MuJoCo warning or a non-finite qpos ends the episode instead (`info["physics_error"]`, discount 0,
        the last observation again)."""
        data = self._physics.raw_data
        warnings = self.warning_counts()  # a count that changed is a new warning (MuJoCo's auto-reset restarts them)
        qpos = data.qpos  # q.q is finite iff every q is (MuJoCo resets a state past 1e10 long before it overflows)
        if warnings.tobytes() != self._warnings_before or not math.isfinite(qpos.dot(qpos)):
            new = warnings != np.frombuffer(self._warnings_before, dtype=warnings.dtype)
            names = [name for name, flag in zip(mujoco.mjtWarning.__members__, new, strict=False) if flag]
            self._reset_next_step = True
            self.task.info["physics_error"] = f"physics state is invalid ({', '.join(names) or 'non-finite qpos'})"
            self.task.info.update(self.task.comfort_metrics())
            return dm_env.TimeStep(dm_env.StepType.LAST, 0.0, 0.0, self._last_observation)
        self._task.after_step(self._physics)
        reward = self._task.get_reward(self._physics)
        observation = self._task.get_observation(self._physics)
        if self._flat_observation:
            observation = control.flatten_observation(observation)
        self._step_count += 1
        if self._step_count >= self._step_limit:
            discount = 1.0
        else:
            discount = self._task.get_termination(self._physics)
        self._last_observation = observation
        last = discount is not None
        self.end_step_comfort(last)
        if last:
            self._reset_next_step = True
            return dm_env.TimeStep(dm_env.StepType.LAST, reward, discount, observation)
        return dm_env.TimeStep(dm_env.StepType.MID, reward, 1.0, observation)

    def end_step_comfort(self, last: bool) -> None:
        """After a control step: sample the task's comfort meter; at the episode's last step put the comfort
        metrics into `info`."""
        self.task.sample_comfort(self.physics.raw_data)
        if last:
            self.task.info.update(self.task.comfort_metrics())
