"""gymnasium ids: check_env, action tables, terminated vs truncated, determinism."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import mjdrive  # noqa: F401  (registers the ids)
from mjdrive.envs import GYM_IDS
from mjdrive.envs.actions import TABLE1, TABLE2


@pytest.mark.parametrize("env_id", sorted(GYM_IDS))
def test_check_env(env_id):
    env = gym.make(env_id)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_action_tables_match_the_study():
    assert TABLE1.shape == (4, 3) and TABLE2.shape == (27, 3)
    assert set(np.round(TABLE2[:, 1], 2)) == {-1, -0.75, -0.5, -0.25, 0, 0.25, 0.5, 0.75, 1}
    assert set(TABLE2[:, 0]) == {0.0, 0.5, 1.0}
    env = gym.make("mjdrive/Waypoints-Straight-v0", actions="table1")
    assert env.action_space == gym.spaces.Discrete(4)
    env.reset(seed=0)
    wrapper = env.unwrapped
    env.step(2)  # throttle 0.5, steer +0.1
    env.step(3)  # coast, keeping steer +0.1
    np.testing.assert_allclose(wrapper.task.last_action, [0.0, 0.1, 0.0])
    with pytest.raises(ValueError, match="action index"):
        env.step(7)
    with pytest.raises(ValueError, match="unknown action set"):
        gym.make("mjdrive/Waypoints-Straight-v0", actions="table9")


def test_nan_action_raises():
    env = gym.make("mjdrive/Waypoints-Straight-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan, 0, 0], np.float32))


def test_time_limit_truncates_and_crash_terminates():
    env = gym.make("mjdrive/Waypoints-Straight-v0", time_limit=1.0)
    env.reset(seed=0)
    for _ in range(100):
        _, _, terminated, truncated, info = env.step(np.zeros(3, np.float32))
        if terminated or truncated:
            break
    assert truncated and not terminated and info["time_limit"]
    env = gym.make("mjdrive/Waypoints-Straight-v0")
    env.reset(seed=0)
    for _ in range(200):  # full throttle, full left: leaves the lane across a solid line
        _, reward, terminated, truncated, info = env.step(np.array([1.0, 1.0, 0.0], np.float32))
        if terminated or truncated:
            break
    assert terminated and not truncated and info["lane_invasion"]
    assert reward < -50  # the study's L penalty (-200) was applied


def _rollout(env_id, seed, steps=60):
    env = gym.make(env_id)
    observation, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    states, observations = [], [observation]
    for _ in range(steps):
        observation, _, terminated, truncated, _ = env.step(rng.uniform([0, -0.3, 0], [1, 0.3, 0.2]).astype(np.float32))
        observations.append(observation)
        states.append(env.unwrapped.dm_env.physics.data.qpos.copy())
        if terminated or truncated:
            observation, _ = env.reset()
    return np.array(states), observations


@pytest.mark.parametrize("env_id", ["mjdrive/Waypoints-RandomRoutes-v0", "mjdrive/Waypoints-Straight-Camera-v0"])
def test_same_seed_same_trajectory_bit_for_bit(env_id):
    a, obs_a = _rollout(env_id, 3)
    b, obs_b = _rollout(env_id, 3)
    c, _ = _rollout(env_id, 4) if "Random" in env_id else (None, None)
    assert np.array_equal(a, b)
    for x, y in zip(obs_a, obs_b, strict=True):
        for key in x:
            assert np.array_equal(x[key], y[key]), key
    if c is not None:
        assert not np.array_equal(a[:5], c[:5])  # another seed, another route


def test_pedal_actions_drive_or_brake_never_both():
    from mjdrive.envs.batched import BatchedEnv

    env = gym.make("mjdrive/Waypoints-Straight-v0", actions="pedal")
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    env.reset(seed=0)
    for action, command in (([0.6, -0.2], [0.6, -0.2, 0.0]), ([-0.4, 0.3], [0.0, 0.3, 0.4]), ([0, 0], [0, 0, 0])):
        env.step(np.array(action, np.float32))
        np.testing.assert_allclose(env.unwrapped.task.last_action, command, atol=1e-6)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0], np.float32))
    batched = BatchedEnv("waypoints", "straight", num_envs=2, actions="pedal")
    batched.reset(seed=0)
    for _ in range(10):
        batched.step(np.array([[1.0, 0.0], [-1.0, 0.0]], np.float32))
    speeds = [base.task.vehicle.speed(base.dm_env.physics.raw_data) for base in batched.bases]
    assert speeds[0] > 2.0 and abs(speeds[1]) < 0.05  # full pedal drives off; full brake stays put
    batched.close()


ODD_ACTIONS = [2, True, False, np.int8(2), np.int64(2), np.uint8(2), np.uint32(2), np.uint64(2), np.array(2),
               np.array(2, np.int16), np.array([2]), np.array([[2]]), 2.0, 2.5, 6.9, np.float32(2.0), np.float64(2.5),
               np.array(2.0), "3", b"3", None, [2], (2,), np.bool_(True), np.array(True), complex(2, 0), -1, 4,
               2**70, np.int64(-1), np.int64(4)]


@pytest.mark.parametrize("action", ODD_ACTIONS, ids=repr)
def test_action_index_accepts_exactly_what_a_discrete_space_contains(action):
    from mjdrive.envs.actions import action_index

    space = gym.spaces.Discrete(4)
    if space.contains(action):
        assert action_index(action, 4, "table1") == int(action)
        assert type(action_index(action, 4, "table1")) is int
    else:
        with pytest.raises(ValueError, match="action set 'table1'"):
            action_index(action, 4, "table1")


@pytest.mark.parametrize("actions, env_id", [("table1", "mjdrive/Waypoints-Straight-v0"),
                                             ("table2", "mjdrive/Waypoints-Straight-v0"),
                                             ("roundabout7", "mjdrive/Roundabout-D120-v0")])
def test_a_float_or_string_action_is_refused_by_name_and_never_truncated(actions, env_id):
    from mjdrive.envs.actions import ACTION_TABLES

    env = gym.make(env_id, actions=actions, time_limit=5.0)
    env.reset(seed=0)
    physics = env.unwrapped.dm_env.physics
    for bad in (2.5, 6.9, "3", np.float32(3.0), np.array([3])):
        with pytest.raises(ValueError, match=f"action set '{actions}': an action is an integer index"):
            env.step(bad)
    assert physics.data.time == 0.0  # nothing was applied
    env.step(np.int64(2))  # a policy's argmax
    np.testing.assert_allclose(env.unwrapped.task.last_action, ACTION_TABLES[actions][2], atol=1e-6)
    assert physics.data.time > 0.0
    env.close()
