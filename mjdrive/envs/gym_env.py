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


class DrivingGymEnv(gym.Env):
    """A dm_control task as a gymnasium Env.

    `terminated` is True when the task ended the episode (collision, lane invasion, arrival, physics
    error); `truncated` when the time limit ran out. `info` carries the task's metrics
    (route_completion, success, collision, ...). `reset(seed=s)` reseeds the task: same seed, same episode.
    Extra sensors are task keywords (`task_kwargs={"sensors": ["depth", "range"]}`).
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
        spaces = {name: spec_to_space(spec, reach) for name, spec in self.dm_env.observation_spec().items()}
        self.observation_space = gym.spaces.Dict(spaces)
        action_spec = self.dm_env.action_spec()
        self.decisions = isinstance(action_spec, specs.DiscreteArray)  # the urban tasks' decision action set
        if self.decisions:
            self.action_space = gym.spaces.Discrete(action_spec.num_values)
        else:
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
        return dict(timestep.observation), dict(self.task.info)

    def step(self, action):
        return self._gym_step(self.dm_env.step(self.command(action)))

    # The batched env (mjdrive.envs.batched) steps its copies' physics together, between these halves of
    # `step` (after an episode's end it resets the copy instead of stepping it).
    def before_physics(self, action) -> None:
        """First half of `step`: the task applies the (throttle, steer, brake) `action` (or takes the decision)."""
        self.dm_env.before_physics(self.command(action))

    def after_physics(self):
        """Second half of `step` once the physics advanced one control period: (obs, reward, terminated,
        truncated, info) as `step` returns them."""
        return self._gym_step(self.dm_env.after_physics())

    def command(self, action) -> np.ndarray | int:
        """`action` as a float64 (throttle, steer, brake) array (NaN or inf raise); a decision as it is (the task
        checks it is an index of its action set)."""
        if self.decisions:
            return action
        action = np.asarray(action, dtype=np.float64)
        if not np.all(np.isfinite(action)):
            raise ValueError(f"action contains NaN or inf: {action}")
        return action

    def _gym_step(self, timestep: dm_env.TimeStep):
        info = dict(self.task.info)
        terminated = timestep.step_type == dm_env.StepType.LAST and timestep.discount == 0.0
        truncated = timestep.step_type == dm_env.StepType.LAST and not terminated
        info["time_limit"] = truncated
        return dict(timestep.observation), float(timestep.reward or 0.0), terminated, truncated, info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        height, width = self.render_size
        return self.task.render_camera(self.dm_env.physics, self.render_camera, height, width).copy()

    def close(self) -> None:
        self.task.close_cameras()


def make_env(domain: str, task: str, actions: str = "continuous", render_mode: str | None = None,
             environment_kwargs: dict[str, Any] | None = None, **task_kwargs) -> gym.Env:
    """Entry point of the gymnasium ids: a DrivingGymEnv with the chosen action set; every other keyword is
    the task's (`mjdrive list --kwargs`), e.g. the extra sensors `sensors=["depth", "segmentation", "range"]`,
    `sensor_size`, `range_rays`, `range_max`."""
    env = DrivingGymEnv(domain, task, task_kwargs, environment_kwargs, render_mode=render_mode)
    return wrap_actions(env, actions)
