"""Built-in policies for `mjdrive run`: privileged scripted drivers (pure pursuit, the autopilot), random and idle
policies, and on the urban tasks' decision action set (`decisions=True`) the rule-based decisions and the two
constant ones."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
import numpy as np

from mjdrive.control import PurePursuit
from mjdrive.tasks.decisions import SAME_LINE

Policy = Callable[[dict], np.ndarray]
POLICIES = ("pure_pursuit", "always_go", "autopilot", "random", "idle", "rules", "always_drive", "always_stop")
DECISION_POLICIES = ("rules", "always_drive", "always_stop")  # these need the decision action set


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


def decision_task(env: gym.Env, policy: str):
    """The urban task under `env` if it takes decisions; else ValueError saying how to get them."""
    task = env.unwrapped.task
    if getattr(task, "decisions", None) is None:
        raise ValueError(f"the {policy} policy issues decisions: use an urban task with the decision action set "
                         "(--task-kwarg decisions=true)")
    return task


COMMITTED = 0.3  # [m] a stop that cannot end within this past the give-way line is not made: the ego goes on


def rules_policy(env: gym.Env) -> Policy:
    """Rule-based decisions from ground truth (privileged): at the roundabout, the crossroad and the merge, stop
    while the urban right-of-way rules (the conflict zones every vehicle obeys, `Traffic.give_way`) make the ego
    wait, else drive; on the two-lane road, the privileged overtaking rule (`RouteTraffic.overtaking`)."""
    task = decision_task(env, "rules")
    physics = env.unwrapped.dm_env.physics
    names = task.decisions
    index = {name: i for i, name in enumerate(names)}

    def act(observation: dict) -> int:
        scenario = task.active_scenario()
        if scenario in ("roundabout", "crossroad", "merge"):
            line = task.traffic.give_way(task.ego_state(physics)).stop  # [m] to where the ego must wait (inf: go)
            ours = task.route_traffic.stop_line(task.route_s, scenario)  # [m] to the scenario's stop point
            # wait at the scenario's stop point when the rules say so there and the comfortable stop still ends
            # there: past it the ego has committed (a zone to keep clear later on is the MPC's: an obstacle)
            wait = (ours is not None and abs(line - ours) < SAME_LINE
                    and task.operative.shortest_stop(task.speed) <= line + COMMITTED)
            return index["stop" if wait else "drive"]
        if scenario != "lane_change":
            return 0  # follow the path: any action
        route = task.route_traffic
        route.observe(task.route_s, task.traffic, track=False)
        choice = route.overtaking(task.route_s, task.speed, task.operative.profile.speed(task.route_s),
                                  task.operative.lanes()[-1])
        return index.get(choice, index.get("keep", index.get("drive")))

    return act


def constant_decision_policy(env: gym.Env, name: str) -> Policy:
    """Always the same decision: "drive" (keep in the lane-change scenario) or "stop"."""
    task = decision_task(env, f"always_{name}")
    choice = name if name in task.decisions else "keep"
    if choice not in task.decisions:
        raise ValueError(f"urban task {task.scenario} has no {name!r} decision; its actions: {task.decisions}")
    action = task.decisions.index(choice)
    return lambda observation: action


def make_policy(name: str, env: gym.Env, seed: int = 0) -> Policy:
    """A policy by name; unknown names raise ValueError listing the valid ones."""
    if name == "rules":
        return rules_policy(env)
    if name in ("always_drive", "always_stop"):
        return constant_decision_policy(env, name.removeprefix("always_"))
    if getattr(env.unwrapped.task, "decisions", None) is not None and name not in ("random",):
        raise ValueError(f"the {name} policy drives with throttle, steer and brake; this env takes decisions "
                         f"(use {', '.join(DECISION_POLICIES)} or random)")
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
