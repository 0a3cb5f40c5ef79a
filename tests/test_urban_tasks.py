"""Urban tasks (study 002): specs and bounds, determinism, the §5.1.4 reward, the active scenario, the
adversary matrix, comfort metrics at the episode's end, and that traffic makes a blind driver crash."""

from __future__ import annotations

import numpy as np
import pytest

from mjdrive import suite
from mjdrive.envs import make_env
from mjdrive.policies import make_policy
from mjdrive.tasks import urban

TASKS = ("roundabout", "lane_change", "crossroad", "merge", "concatenated")


def within_spec(env, observation) -> None:
    for name, spec in env.observation_spec().items():
        value = observation[name]
        assert value.shape == spec.shape and value.dtype == spec.dtype, name
        assert np.all(value >= spec.minimum) and np.all(value <= spec.maximum), name


@pytest.mark.parametrize("task", TASKS)
def test_observations_stay_in_their_bounds_and_repeat_with_the_seed(task):
    runs = []
    for _ in range(2):
        env = suite.load("urban", task, {"random": 4})
        timestep = env.reset()
        observations = [timestep.observation]
        for i in range(40):
            timestep = env.step(np.array([0.6, 0.1 * np.sin(i / 5), 0.0]))
            within_spec(env, timestep.observation)
            observations.append(timestep.observation)
            if timestep.last():
                break
        runs.append(observations)
    assert len(runs[0]) == len(runs[1])
    for a, b in zip(*runs, strict=True):
        for name in a:
            np.testing.assert_array_equal(a[name], b[name])


def drive(task: str, seed: int, policy: str = "pure_pursuit", **kwargs):
    env = make_env("urban", task, random=seed, **kwargs)
    act = make_policy(policy, env, seed)
    observation, info = env.reset(seed=seed)
    rewards, scenarios = [], []
    while True:
        observation, reward, terminated, truncated, info = env.step(act(observation))
        rewards.append(reward)
        scenarios.append(info["scenario"])
        terms = dict(env.unwrapped.task.reward_terms)
        if terminated or truncated:
            return env, info, rewards, scenarios, terms, terminated


def test_reward_is_speed_plus_arrival_and_the_scenario_follows_the_route():
    env, info, rewards, scenarios, terms, terminated = drive("merge", 0)
    task = env.unwrapped.task
    assert terminated and info["success"] and not info["collision"]
    assert terms["arrival"] == 1.0 and terms["collision"] == 0.0
    assert rewards[-1] == pytest.approx(1.0 + 1e-3 * task.speed)
    assert all(0.0 < r < 0.02 for r in rewards[:-1])  # k_v * speed only, speeds below 20 m/s
    assert scenarios[0] == "follow" and "merge" in scenarios  # starts before the scenario, then in it
    assert info["elapsed_time"] == pytest.approx(len(rewards) * urban.CONTROL_TIMESTEP)
    assert info["average_speed"] == pytest.approx(info["distance"] / info["elapsed_time"])
    for key in ("jerk_p95_mps3", "jerk_max_mps3", "accel_p95_mps2", "accel_lon_p95_mps2", "accel_lat_p95_mps2"):
        assert np.isfinite(info[key]) and info[key] >= 0.0, key


def test_a_driver_blind_to_traffic_collides_at_the_crossroad():
    """The "always go" driver (the route at the speed limit, ignoring traffic) collides in some episodes
    (the -2 reward ends them); results/urban/always_go.md has the rates over 100 episodes per scenario."""
    outcomes = [drive("crossroad", seed, "always_go")[1:] for seed in range(4)]
    collisions = [(info, terms) for info, _, _, terms, terminated in outcomes if info["collision"]]
    assert collisions and len(collisions) < len(outcomes)
    for info, terms in collisions:
        assert terms["collision"] == -2.0 and not info["success"]
    seed = next(seed for seed, (info, *_) in enumerate(outcomes) if info["collision"])
    _, info, rewards, _, terms, _ = drive("crossroad", seed, "always_go", collision_reward=-7.5)
    assert info["collision"] and terms["collision"] == -7.5  # the keyword sets the penalty, nothing else changes
    default_rewards = outcomes[seed][1]
    assert rewards[:-1] == default_rewards[:-1]
    assert rewards[-1] - default_rewards[-1] == pytest.approx(-7.5 + 2.0)


def test_the_always_go_driver_keeps_the_speed_limit_on_an_empty_road():
    env = make_env("urban", "merge", random=0, road_users={"car": 0})
    act = make_policy("always_go", env, 0)
    task = env.unwrapped.task
    observation, info = env.reset(seed=0)
    speeds, limits = [], []
    while True:
        observation, _, terminated, truncated, info = env.step(act(observation))
        k = int(np.searchsorted(task.route_starts, task.route_s, side="right") - 1)
        speeds.append(task.speed)
        limits.append(task.road_map.lanes[task.route[k]].speed_limit)
        if terminated or truncated:
            break
    assert info["success"] and not info["collision"]
    speeds, limits = np.array(speeds), np.array(limits)
    assert speeds.max() < 1.05 * limits.max()  # the speed controller overshoots by under 5%
    assert np.all(np.abs(speeds[-20:] - limits[-20:]) < 0.5)  # at the main road's 50 km/h by the end


def test_adversaries_are_the_nearest_road_users_to_the_relevant_point():
    env = suite.load("urban", "crossroad", {"random": 1})
    env.reset()
    task = env.task
    for _ in range(30):
        timestep = env.step(np.array([0.3, 0.0, 0.0]))
    point = task.relevant_point()
    traffic = task.traffic
    present = np.flatnonzero(traffic.present)
    distance = np.sort(np.hypot(*(traffic.positions()[present] - point).T))
    matrix = timestep.observation["adversaries"]
    k = min(len(present), task.config.adversaries)
    np.testing.assert_allclose(matrix[:k, 1], np.minimum(distance[:k] / urban.DISTANCE_SCALE, 1.0), atol=1e-6)
    assert np.all(matrix[:k, 0] == 1.0) and np.all(matrix[k:] == 0.0)
    assert set(np.round(matrix[:k, 3] * 2).astype(int)) <= {0, 1, 2}
    if task.active_scenario() == "crossroad":  # the point is the next conflict point on the route
        assert np.min(np.hypot(*(task._points - point).T)) == 0.0


def test_bad_keywords_are_refused():
    with pytest.raises(ValueError, match="adversaries=0: must be >= 1"):
        suite.load("urban", "merge", {"adversaries": 0})
    with pytest.raises(ValueError, match="road_users=.*unknown key 'pedestrian'"):
        suite.load("urban", "merge", {"road_users": {"pedestrian": 2}})


def test_no_zipper_deadlock_where_the_left_lane_tapers_off(drive_episode):
    """Seed 20064 of Table 2: a motorcycle waited at the taper's give-way line for a car standing just
    behind it on the continuing lane, which stood for the motorcycle (ahead in its corridor); the queue behind
    held the autopilot until the time limit. A standing car behind no longer makes a merging vehicle wait."""
    env = make_env("urban", "concatenated", random=20064, time_limit=200.0)
    info = drive_episode(env, make_policy("autopilot", env, 20064), seed=20064)
    assert info["success"] and not info["collision"], (info["scenario"], info["elapsed_time"])
