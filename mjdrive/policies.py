"""Built-in policies for `mjdrive run`: a privileged pure-pursuit driver, random and idle policies."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from mjdrive.control import PurePursuit

Policy = Callable[[dict], np.ndarray]
POLICIES = ("pure_pursuit", "always_go", "autopilot", "random", "idle")


def pure_pursuit_policy(env: gym.Env, cruise: float | None = None) -> Policy:
    """Follows the task's route with pure pursuit at `cruise` [m/s] (default: 80% of the speed limit).

    Privileged: it reads the route from the task, like CARLA's autopilot reads the map.
    """
    task = env.unwrapped.task
    dt = env.unwrapped.dm_env.control_timestep()
    driver = PurePursuit(wheelbase=task.params.wheelbase, max_steer=task.params.max_steer)
    physics = env.unwrapped.dm_env.physics

    def act(observation: dict) -> np.ndarray:
        if task.info.get("elapsed_time", 0.0) == 0.0:
            driver.reset()
        limit = task.road_map.lanes[task.route[0]].speed_limit
        speed_target = cruise if cruise is not None else 0.8 * limit
        pose = task.vehicle.pose(physics.raw_data)
        return driver(pose, task.speed, task.route_lane, speed_target, dt).astype(np.float32)

    return act


def always_go_policy(env: gym.Env) -> Policy:
    """The scripted "always go" driver of study 002's difficulty check: pure pursuit along the route at the
    speed limit of the route's lane under the ego, ignoring traffic and give-way lines (privileged: it
    reads the route from the task)."""
    task = env.unwrapped.task
    dt = env.unwrapped.dm_env.control_timestep()
    driver = PurePursuit(wheelbase=task.params.wheelbase, max_steer=task.params.max_steer)
    physics = env.unwrapped.dm_env.physics
    starts = getattr(task, "route_starts", None)  # [m] where each route lane starts (urban tasks)
    limits = np.array([task.road_map.lanes[lane].speed_limit for lane in task.route])  # [m/s]

    def act(observation: dict) -> np.ndarray:
        if task.info.get("steps", 0) == 0:
            driver.reset()
        k = 0 if starts is None else int(np.clip(np.searchsorted(starts, task.route_s, side="right") - 1, 0,
                                                  len(limits) - 1))
        pose = task.vehicle.pose(physics.raw_data)
        return driver(pose, task.speed, task.route_lane, float(limits[k]), dt).astype(np.float32)

    return act


def autopilot_policy(env: gym.Env) -> Policy:
    """The careful privileged autopilot of tasks with traffic (`mjdrive.control.autopilot`): pure pursuit
    along the route, speed from the traffic model's own rules (yields, stops for pedestrians)."""
    from mjdrive.control.autopilot import Autopilot

    task, dm_env = env.unwrapped.task, env.unwrapped.dm_env
    if not hasattr(task, "traffic"):
        raise ValueError("the autopilot policy needs a task with traffic (e.g. roundabout/d120)")
    driver = Autopilot(task, dm_env.control_timestep())

    def act(observation: dict) -> np.ndarray:
        if task.info.get("steps", 0) == 0:
            driver.reset()
        return driver(dm_env.physics).astype(np.float32)

    return act


def make_policy(name: str, env: gym.Env, seed: int = 0) -> Policy:
    """A policy by name; unknown names raise ValueError listing the valid ones."""
    if name == "pure_pursuit":
        return pure_pursuit_policy(env)
    if name == "always_go":
        return always_go_policy(env)
    if name == "autopilot":
        return autopilot_policy(env)
    if name == "random":
        space = env.action_space
        space.seed(seed)
        return lambda observation: space.sample()
    if name == "idle":
        return lambda observation: np.zeros(3, np.float32)
    raise ValueError(f"unknown policy {name!r}; valid: {', '.join(POLICIES)}")
