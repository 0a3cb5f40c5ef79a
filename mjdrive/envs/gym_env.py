"""gymnasium Env over a dm_control driving task."""

from __future__ import annotations

import math
from typing import Any

import dm_env
import gymnasium as gym
import numpy as np
from dm_env import specs

from mjdrive import suite
from mjdrive.envs.actions import wrap_actions

MAX_SPEED = 100.0  # [m/s] above any road user's and the cars' top speeds (sedan 200 km/h = 56 m/s)
MAX_YAW_RATE = 8 * np.pi  # [rad/s] 4 turns a second: beyond it the physics blows up, which ends the episode
MAX_SIZE = 20.0  # [m] longest road-user box side


def observation_bounds(name: str, shape: tuple[int, ...], reach: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(low, high) of the unbounded-spec observations of the tasks, from what they measure: angles wrap,
    cos/sin and flags lie in [-1, 1] / [0, 1], speeds stay under MAX_SPEED, and a distance on the map is at
    most `reach` [m] (the map's diagonal plus the farthest the ego can drive in an episode). None: unknown."""
    deg, rad = 180.0, np.pi
    columns: dict[str, list[tuple[float, float]]] = {
        "waypoint_angles": [(-deg, deg)], "heading_error": [(-deg, deg)],  # [deg] wrapped
        "speed": [(-3.6 * MAX_SPEED, 3.6 * MAX_SPEED)],  # [km/h] signed (reverse)
        "lane_offset": [(-reach, reach)], "waypoint_distance": [(0.0, reach)],  # [m]
        "destination": [(-reach, reach)],  # [m]
        # roundabout ego: speed [m/s], yaw rate [rad/s], heading error [rad], lateral offset [m], cos/sin(yaw)
        "ego": [(-MAX_SPEED, MAX_SPEED), (-MAX_YAW_RATE, MAX_YAW_RATE), (-rad, rad), (-reach, reach),
                (-1.0, 1.0), (-1.0, 1.0)],
        # roundabout road users: present, dx, dy [m], dvx, dvy [m/s], cos/sin relative yaw, length, width [m],
        # one-hot kind
        "road_users": [(0.0, 1.0), (-reach, reach), (-reach, reach), (-2 * MAX_SPEED, 2 * MAX_SPEED),
                       (-2 * MAX_SPEED, 2 * MAX_SPEED), (-1.0, 1.0), (-1.0, 1.0), (0.0, MAX_SIZE), (0.0, MAX_SIZE)],
    }
    if name not in columns:
        return None
    bounds = columns[name]
    if len(bounds) == 1:  # the same for every element
        bounds = bounds * shape[-1]
    if name == "road_users":  # one-hot kind columns after the listed ones
        bounds = bounds + [(0.0, 1.0)] * (shape[-1] - len(bounds))
    if len(bounds) != shape[-1]:
        return None
    low, high = np.array(bounds, np.float64).T
    return np.broadcast_to(low, shape), np.broadcast_to(high, shape)


def spec_to_space(spec: specs.Array, reach: float = np.inf) -> gym.spaces.Box:
    """A gymnasium Box for a dm_env array spec: its own bounds, else `observation_bounds` of its name."""
    if isinstance(spec, specs.BoundedArray):
        low = np.broadcast_to(spec.minimum, spec.shape).astype(spec.dtype)
        high = np.broadcast_to(spec.maximum, spec.shape).astype(spec.dtype)
        return gym.spaces.Box(low, high, spec.shape, spec.dtype)
    bounds = observation_bounds(spec.name, spec.shape, reach) if np.isfinite(reach) else None
    if bounds is None:  # an observation this module does not know: no bound is claimed
        return gym.spaces.Box(-np.inf, np.inf, spec.shape, spec.dtype)
    return gym.spaces.Box(bounds[0].astype(spec.dtype), bounds[1].astype(spec.dtype), spec.shape, spec.dtype)


SENSORS = ("depth", "segmentation", "range")  # extra observations every task can add (`sensors=`)


class ExtraSensors:
    """Depth and segmentation images from the front camera and a range ring around the ego, for any task
    (`DrivingGymEnv(sensors=...)`): observation keys `depth` (size, size) float32 [m], `segmentation`
    (size, size) uint8 (`mjdrive.sensors.SEGMENT_CLASSES` indices), `range` (rays,) float32 [m]."""

    def __init__(self, names: tuple[str, ...], size: int = 64, rays: int = 36, max_range: float = 50.0):
        unknown = [name for name in names if name not in SENSORS]
        if unknown:
            raise ValueError(f"unknown sensor {unknown[0]!r}; sensors: {', '.join(SENSORS)}")
        if not 8 <= size <= 512 or rays < 1 or not max_range > 0:
            raise ValueError(f"sensor_size must be in 8..512, range_rays >= 1 and range_max > 0; got {size}, "
                             f"{rays}, {max_range}")
        self.names, self.size, self.rays, self.max_range = tuple(dict.fromkeys(names)), size, rays, max_range
        self._model = None
        self.camera = None
        self.ring = None

    def spaces(self, model) -> dict[str, gym.spaces.Box]:
        from mjdrive.sensors import SEGMENT_CLASSES

        far = float(model.vis.map.zfar * model.stat.extent)  # [m]
        shape = (self.size, self.size)
        out = {"depth": gym.spaces.Box(0.0, far, shape, np.float32),
               "segmentation": gym.spaces.Box(0, len(SEGMENT_CLASSES) - 1, shape, np.uint8),
               "range": gym.spaces.Box(0.0, self.max_range, (self.rays,), np.float32)}
        return {name: out[name] for name in self.names}

    def __call__(self, physics) -> dict[str, np.ndarray]:
        from mjdrive.sensors import DepthSegmentationCamera, RangeRing

        model, data = physics.model.ptr, physics.data.ptr
        if model is not self._model:  # a task may rebuild its model on reset
            self.close()
            self._model = model
            if "depth" in self.names or "segmentation" in self.names:
                self.camera = DepthSegmentationCamera(model, "ego/front", self.size, self.size)
            if "range" in self.names:
                self.ring = RangeRing(model, self.rays, self.max_range)
        out = {}
        if self.camera is not None:
            self.camera.render_sensors(data, "depth" in self.names, "segmentation" in self.names)
            if "depth" in self.names:
                out["depth"] = self.camera.depth_image.copy()
            if "segmentation" in self.names:
                out["segmentation"] = self.camera.segmentation_image.copy()
        if self.ring is not None:
            out["range"] = self.ring(data).copy()
        return out

    def close(self) -> None:
        if self.camera is not None:
            self.camera.close()
        self.camera = self.ring = self._model = None


class DrivingGymEnv(gym.Env):
    """A dm_control task as a gymnasium Env.

    `terminated` is True when the task ended the episode (collision, lane invasion, arrival, physics
    error); `truncated` when the time limit ran out. `info` carries the task's metrics
    (route_completion, success, collision, ...). `reset(seed=s)` reseeds the task: same seed, same episode.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        domain: str,
        task: str,
        task_kwargs: dict[str, Any] | None = None,
        environment_kwargs: dict[str, Any] | None = None,
        render_mode: str | None = None,
        render_camera: str = "ego/chase",
        render_size: tuple[int, int] = (360, 640),  # (height, width) [px]
        sensors: tuple[str, ...] | list[str] | str = (),
        sensor_size: int = 64,  # [px] side of the depth and segmentation images
        range_rays: int = 36,
        range_max: float = 50.0,  # [m]
    ):
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.domain, self.task_name = domain, task
        self.task_kwargs = dict(task_kwargs or {})
        self.environment_kwargs = dict(environment_kwargs) if environment_kwargs else None  # for logs/replay
        self.dm_env = suite.load(domain, task, self.task_kwargs, environment_kwargs)
        self.task = self.dm_env.task
        x0, y0, x1, y1 = self.task.road_map.bounds()
        reach = float(np.hypot(x1 - x0, y1 - y0) + MAX_SPEED * self.max_episode_steps
                      * self.dm_env.control_timestep())  # [m] no distance between the ego and the map exceeds it
        if isinstance(sensors, str):  # "depth,range"
            sensors = tuple(name for name in sensors.split(",") if name)
        self.sensors = ExtraSensors(tuple(sensors), sensor_size, range_rays, range_max) if sensors else None
        spaces = {name: spec_to_space(spec, reach) for name, spec in self.dm_env.observation_spec().items()}
        if self.sensors is not None:
            spaces.update(self.sensors.spaces(self.dm_env.physics.model.ptr))
        self.observation_space = gym.spaces.Dict(spaces)
        action_spec = self.dm_env.action_spec()
        self.action_space = gym.spaces.Box(
            action_spec.minimum.astype(np.float32), action_spec.maximum.astype(np.float32), dtype=np.float32
        )
        self.render_mode = render_mode
        self.render_camera, self.render_size = render_camera, render_size
        self.metadata = {**self.metadata, "render_fps": round(1.0 / self.dm_env.control_timestep())}

    @property
    def max_episode_steps(self) -> int:
        """Control steps until the time limit truncates an episode (a task may end it sooner)."""
        config_class, defaults = suite.task_config(self.domain, self.task_name)
        time_limit = config_class.from_dict(self.task_kwargs, defaults).time_limit  # [s]
        return math.ceil(round(time_limit / self.dm_env.control_timestep(), 6))

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.task.seed(seed)
        timestep = self.dm_env.reset()
        return self._observation(timestep), dict(self.task.info)

    def _observation(self, timestep) -> dict[str, np.ndarray]:
        observation = dict(timestep.observation)
        if self.sensors is not None:
            observation.update(self.sensors(self.dm_env.physics))
        return observation

    def step(self, action):
        action = np.asarray(action, dtype=np.float64)
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains NaN or inf: {action}")
        timestep = self.dm_env.step(action)
        info = dict(self.task.info)
        terminated = timestep.step_type == dm_env.StepType.LAST and timestep.discount == 0.0
        truncated = timestep.step_type == dm_env.StepType.LAST and not terminated
        info["time_limit"] = truncated
        return self._observation(timestep), float(timestep.reward or 0.0), terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        height, width = self.render_size
        return self.task.render_camera(self.dm_env.physics, self.render_camera, height, width).copy()

    def close(self) -> None:
        if self.sensors is not None:
            self.sensors.close()
        for camera in self.task.cameras.values():
            camera.close()
        self.task.cameras.clear()


def make_env(domain: str, task: str, actions: str = "continuous", render_mode: str | None = None,
             environment_kwargs: dict[str, Any] | None = None, sensors: tuple[str, ...] | list[str] | str = (),
             sensor_size: int = 64, range_rays: int = 36, range_max: float = 50.0, **task_kwargs) -> gym.Env:
    """Entry point of the gymnasium ids: a DrivingGymEnv with the chosen action set and extra `sensors`
    (`SENSORS`: depth and segmentation images of `sensor_size` px, a range ring of `range_rays` rays up to
    `range_max` m)."""
    env = DrivingGymEnv(domain, task, task_kwargs, environment_kwargs, render_mode=render_mode, sensors=sensors,
                        sensor_size=sensor_size, range_rays=range_rays, range_max=range_max)
    return wrap_actions(env, actions)
