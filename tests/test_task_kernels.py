"""The tasks' compiled observation parts (`mjdrive.tasks.kernels`) against the numpy code they repeat, bit for
bit, at every step of episodes driven by the privileged autopilot, with sparse traffic and with ties in
distance. Without numba both paths still run (the kernels as plain Python)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from mjdrive.envs import make_env
from mjdrive.policies import make_policy


def _both_ways(monkeypatch, task, physics) -> dict[str, np.ndarray]:
    """The task's observation with the numpy code and with the kernels; asserts the same bits, returns it."""
    module = sys.modules[type(task).__module__]
    monkeypatch.setattr(module, "KERNELS", False)
    expected = task.get_observation(physics)
    monkeypatch.setattr(module, "KERNELS", True)
    got = task.get_observation(physics)
    assert list(got) == list(expected)
    for key, value in expected.items():
        assert got[key].dtype == value.dtype and got[key].shape == value.shape, key
        assert got[key].tobytes() == value.tobytes(), (key, got[key], value)  # -0.0 and NaN bits included
    return got


def _rows(observation: dict[str, np.ndarray]) -> np.ndarray:
    return observation["adversaries"] if "adversaries" in observation else observation["road_users"]


@pytest.mark.parametrize("task_id, kwargs, steps", [
    ("urban/concatenated", {}, 900),
    ("urban/crossroad", {}, 300),
    ("urban/merge", {"road_users": {"car": 2}}, 300),  # fewer users than rows
    ("roundabout/d210", {}, 300),
    ("roundabout/d120", {"neighbours": 40}, 200),  # more rows than users
])
def test_observation_kernels_match_numpy(monkeypatch, task_id, kwargs, steps):
    env = make_env(*task_id.split("/"), random=5, **kwargs)
    dm_env = env.unwrapped.dm_env
    act = make_policy("autopilot", env, 5)
    observation, _ = env.reset(seed=5)
    scenarios, filled = set(), []
    for _ in range(steps):
        observation, _, terminated, truncated, info = env.step(act(observation))
        got = _both_ways(monkeypatch, dm_env.task, dm_env.physics)
        scenarios.add(info.get("scenario"))
        filled.append(int(_rows(got)[:, 0].sum()))
        if terminated or truncated:
            observation, _ = env.reset()
    if task_id == "urban/concatenated":  # the matrix in more than one scenario (intention columns)
        assert len(scenarios) >= 3, scenarios
    assert max(filled) > 0


@pytest.mark.parametrize("task_id", ["urban/crossroad", "roundabout/d210"])
def test_observation_kernels_keep_numpy_order_on_ties(monkeypatch, task_id):
    """Road users at the same distance keep numpy's stable order (their slot order), and an empty world gives
    zero rows."""
    env = make_env(*task_id.split("/"), random=2)
    dm_env = env.unwrapped.dm_env
    env.reset(seed=2)
    for _ in range(20):
        env.step(np.array([0.0, 0.0, 1.0]))
    task, traffic = dm_env.task, dm_env.task.traffic
    present = np.flatnonzero(traffic.present)
    assert len(present) >= 4
    # four users on a circle round the point distances are measured from: equal distances, different slots
    point = task.relevant_point() if hasattr(task, "relevant_point") else task.xy
    # the others beyond the urban distance scale (60 m: capped at 1), one of them faster than its speed scale
    for j, slot in enumerate(present):
        traffic._current_pos[slot, :2] = point + (61.0 + j) * np.array([0.6, 0.8])
    traffic._current_speed[present[0]] = 20.0  # [m/s]
    for j, angle in enumerate((0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi)):
        traffic._current_pos[present[-1 - j], :2] = point + 7.0 * np.array([np.cos(angle), np.sin(angle)])
    rows = _rows(_both_ways(monkeypatch, task, dm_env.physics))
    assert rows[:, 0].sum() >= 5
    if task_id.startswith("urban"):  # both caps taken
        assert rows[4, 1] == 1.0 and rows[4, 2] == 1.0, rows
    traffic.active[:] = False  # no vehicle in the world (pedestrians stay present by definition)
    _both_ways(monkeypatch, task, dm_env.physics)


_EGO_FIELDS = ("speed", "yaw_rate", "yaw", "route_s", "lane_offset", "heading_error", "_chassis")
_TASK_EGO_FIELDS = {"urban": ("scenario",), "roundabout": ("_left", "_yaw_cos_sin", "_frame_time")}


def _hex(value):
    """Floats (alone, in tuples, lists or arrays) as their hex: compared bit for bit."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (tuple, list)):
        return [_hex(v) for v in value]
    return float.hex(value) if isinstance(value, float) else value


def _ego_update_both_ways(monkeypatch, task, physics) -> dict:
    """The urban or roundabout task's ego update with the numpy code and with the kernel, from the same route-frame
    window; asserts the same state, bit for bit (floats compared as their hex), returns it."""
    module = sys.modules[type(task).__module__]
    fields = _EGO_FIELDS + _TASK_EGO_FIELDS[module.__name__.rsplit(".", 1)[-1]]
    if module.__name__.endswith("roundabout"):
        fields += ("corners", "corner_offsets")
    frame, states = task.route_frame, []
    segment = frame.segment
    for kernels_on in (False, True):
        monkeypatch.setattr(module, "KERNELS", kernels_on)
        frame.segment = segment
        task._update_ego(physics)
        state = {name: _hex(getattr(task, name)) for name in fields}
        state["xy"], state["segment"] = _hex(task.xy), frame.segment
        states.append(state)
    assert states[1] == states[0]
    return states[1]


@pytest.mark.parametrize("task_id, steps", [("urban/concatenated", 900), ("urban/lane_change", 200)])
def test_urban_ego_kernel_matches_numpy(monkeypatch, task_id, steps):
    """`UrbanTask._update_ego` in one kernel (chassis state, route coordinates, scenario, heading error) gives the
    numpy code's state at every step of autopilot episodes, in every scenario, and off the route."""
    env = make_env(*task_id.split("/"), random=3)
    dm_env = env.unwrapped.dm_env
    task, physics = dm_env.task, dm_env.physics
    act = make_policy("autopilot", env, 3)
    observation, _ = env.reset(seed=3)
    scenarios = set()
    for _ in range(steps):
        observation, _, terminated, truncated, info = env.step(act(observation))
        scenarios.add(_ego_update_both_ways(monkeypatch, task, physics)["scenario"])
        if terminated or truncated:
            observation, _ = env.reset()
    if task_id == "urban/concatenated":
        assert scenarios >= {"follow", "roundabout", "lane_change"}, scenarios
    # off the route and turned round: a large heading error (wrapped) and a lateral offset
    data = physics.raw_data
    qa, _ = task.vehicle.state_addresses
    data.qpos[qa:qa + 2] += (0.0, 3.5)
    data.qpos[qa + 3:qa + 7] = (np.cos(1.6), 0.0, 0.0, np.sin(1.6))  # yaw 3.2 rad
    state = _ego_update_both_ways(monkeypatch, task, physics)
    assert abs(float.fromhex(state["heading_error"])) > 2.5 and abs(float.fromhex(state["lane_offset"])) > 2.0


def test_roundabout_ego_kernel_matches_numpy(monkeypatch):
    """`RoundaboutTask._update_ego` in one kernel (chassis state, footprint corners, route coordinates of the centre
    and corners, heading error) gives the numpy code's state at every step of autopilot episodes, and off the
    route turned round, with corners off the lanes."""
    env = make_env("roundabout", "d160", random=5)
    dm_env = env.unwrapped.dm_env
    task, physics = dm_env.task, dm_env.physics
    act = make_policy("autopilot", env, 5)
    observation, _ = env.reset(seed=5)
    route_s = []
    for _ in range(300):
        observation, _, terminated, truncated, info = env.step(act(observation))
        state = _ego_update_both_ways(monkeypatch, task, physics)
        route_s.append(float.fromhex(state["route_s"]))
        if terminated or truncated:
            observation, _ = env.reset()
    assert max(route_s) - min(route_s) > 30.0  # the ego drove along its route
    data = physics.raw_data
    qa, _ = task.vehicle.state_addresses
    data.qpos[qa:qa + 2] += (0.0, 4.0)
    data.qpos[qa + 3:qa + 7] = (np.cos(1.6), 0.0, 0.0, np.sin(1.6))  # yaw 3.2 rad
    state = _ego_update_both_ways(monkeypatch, task, physics)
    assert abs(float.fromhex(state["heading_error"])) > 2.5
    assert max(abs(float.fromhex(d)) for d in state["corner_offsets"]) > task._route_width / 2
