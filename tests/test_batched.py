"""BatchedEnv: same episodes as the single env, auto-reset with the final observation kept, backends."""

import numpy as np
import pytest

from mjdrive.envs import make_env
from mjdrive.envs.batched import BatchedEnv, ObservationLayout


def _actions(steps: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([0.3, -0.4, 0.0], [1.0, 0.4, 0.1], size=(steps, 3)).astype(np.float32)


@pytest.mark.parametrize("backend", ["serial", "threads"])
def test_matches_single_env_bit_for_bit_with_auto_reset(backend):
    actions = _actions(120)
    env = make_env("waypoints", "straight", time_limit=3.0)
    obs, _ = env.reset(seed=3)
    reference = []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        reference.append((reward, terminated, truncated, obs))
        if terminated or truncated:
            obs, _ = env.reset()
    batched = BatchedEnv("waypoints", "straight", num_envs=2, nthread=2, backend=backend, time_limit=3.0)
    batched.reset(seed=3)
    ends = 0
    for action, (reward, terminated, truncated, final) in zip(actions, reference, strict=True):
        obs, rewards, terms, truncs, info = batched.step(np.stack([action, action]))
        assert rewards[0] == np.float32(reward) and terms[0] == terminated and truncs[0] == truncated
        for key, value in final.items():  # the ended episode's last observation is kept in info
            np.testing.assert_array_equal(info["final_observation"][key][0], value)
        if terminated or truncated:
            ends += 1
            assert info["_final_observation"][0] and info["final_info"][0]["time_limit"] == truncated
            assert batched.episode_lengths[0] == 0  # auto-reset happened
            assert obs["speed"][0, 0] < 1.0  # the new episode's first observation (standing car)
        # copy 1 was seeded with seed+1 but drives the same fixed route with the same actions
    assert ends >= 2
    batched.close()


def test_discrete_actions_torch_output_and_time_limit_truncation():
    torch = pytest.importorskip("torch")
    env = BatchedEnv("waypoints", "straight", num_envs=3, actions="table2", device="cpu", time_limit=1.0)
    obs, _ = env.reset(seed=0)
    assert isinstance(obs["speed"], torch.Tensor) and obs["speed"].shape == (3, 1)
    assert env.max_episode_steps == 10
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(torch.tensor([4, 13, 22]))  # straight ahead
    assert truncated.all() and not terminated.any()
    assert all(final["time_limit"] for final in info["final_info"])
    with pytest.raises(ValueError, match="expected 3 actions"):
        env.step(torch.tensor([1, 2]))
    env.close()


def test_rollout_backend_is_close_to_the_reference():
    actions = _actions(30)
    runs = {}
    for backend in ("serial", "rollout"):
        env = BatchedEnv("waypoints", "straight", num_envs=2, nthread=2, backend=backend)
        env.reset(seed=0)
        runs[backend] = [env.step(np.stack([a, a]))[0]["speed"].copy() for a in actions]
        env.close()
    np.testing.assert_allclose(np.array(runs["rollout"]), np.array(runs["serial"]), rtol=1e-3, atol=1e-3)


def test_observation_layout_scales_features_and_transposes_images():
    env = BatchedEnv("waypoints", "straight", num_envs=2, observation="camera", image_size=32)
    layout = ObservationLayout(env.single_observation_space)
    obs, _ = env.reset(seed=0)
    assert layout.image_key == "image" and layout.image_shape == (3, 32, 32)
    assert layout.feature_keys == ["heading_error", "speed", "waypoint_distance"]
    image = layout.image(obs)
    assert image.shape == (2, 3, 32, 32) and image.dtype == np.uint8
    np.testing.assert_array_equal(image[0, 1], obs["image"][0, :, :, 1])
    features = layout.features(obs)
    assert features.shape == (2, 3) and features.dtype == np.float32
    np.testing.assert_allclose(features[:, 2], obs["waypoint_distance"][:, 0] / 10.0)
    env.close()


@pytest.mark.parametrize("backend", ["threads", "rollout"])
def test_roundabout_traffic_moves_between_substeps_as_in_the_single_env(backend):
    """The roundabout moves its traffic between physics chunks: the batched physics must too."""
    actions = _actions(25, seed=1)
    env = make_env("roundabout", "d120", observation="features", off_route=None)  # random actions leave the route
    env.reset(seed=4)
    users = env.unwrapped.task.road_users()
    reference = []
    for action in actions:
        obs, reward, terminated, truncated, _ = env.step(action)
        reference.append((obs["road_users"].copy(), env.unwrapped.task.road_users().poses.copy(), reward))
        if terminated or truncated:
            break
    first, last = users.poses, env.unwrapped.task.road_users().poses
    assert len(reference) == len(actions)  # no episode end inside the compared steps
    assert first.shape != last.shape or np.abs(first - last).max() > 1.0  # [m] the traffic moved
    batched = BatchedEnv("roundabout", "d120", num_envs=2, nthread=2, backend=backend, observation="features",
                         off_route=None)
    batched.reset(seed=4)
    for action, (road_users, poses, reward) in zip(actions, reference, strict=False):
        obs, rewards, *_ = batched.step(np.stack([action, action]))
        if backend == "threads":  # bit for bit
            np.testing.assert_array_equal(obs["road_users"][0], road_users)
            np.testing.assert_array_equal(batched.bases[0].task.road_users().poses, poses)
            assert rewards[0] == np.float32(reward)
        else:  # the rollout backend does not carry the solver warm start: close, not identical
            assert batched.bases[0].task.road_users().poses.shape == poses.shape
    batched.close()


def test_copies_can_run_different_tasks_of_one_domain_each_as_its_single_env():
    """A batch over the roundabout's densities: copy i runs task[i % 2], bit for bit as its own single env."""
    from mjdrive.agents.env_factory import make_batched_env

    actions = _actions(15, seed=2)
    env = make_env("roundabout", "d160", observation="features", off_route=None)
    env.reset(seed=6)  # copy 1 is reset with seed + 1
    reference = [env.step(action)[0]["road_users"].copy() for action in actions]
    batched = make_batched_env({"task": "roundabout/d120", "mix_tasks": ["roundabout/d160"], "num_envs": 4,
                                "task_kwargs": {"observation": "features", "off_route": None}})
    assert batched.task_names == ["d120", "d160", "d120", "d160"]
    batched.reset(seed=5)
    sizes = [len(base.task.traffic.kind_id) for base in batched.bases]
    assert sizes[0] == sizes[2] < sizes[1] == sizes[3]  # denser traffic in the d160 copies
    for action, road_users in zip(actions, reference, strict=True):
        obs, *_ = batched.step(np.stack([action] * 4))
        np.testing.assert_array_equal(obs["road_users"][1], road_users)
    batched.close()
    short = BatchedEnv("roundabout", ["d120", "d160"], num_envs=2, observation="features", time_limit=0.4)
    short.reset(seed=0)
    for _ in range(2):  # 2 control steps of 0.2 s: both copies time out
        info = short.step(np.stack([actions[0]] * 2))[-1]
    assert [final["task"] for final in info["final_info"]] == ["roundabout/d120", "roundabout/d160"]
    short.close()
    with pytest.raises(ValueError, match="rollout backend steps copies of one model"):
        BatchedEnv("roundabout", ["d120", "d160"], num_envs=2, backend="rollout", observation="features")
    with pytest.raises(ValueError, match="mix_tasks must be tasks of roundabout"):
        make_batched_env({"task": "roundabout/d120", "mix_tasks": ["waypoints/straight"]})


def _single_env_trajectories(domain: str, task: str, actions: np.ndarray, seed: int, **kwargs) -> list[list]:
    """Per copy i: (obs, reward, terminated, truncated, info) of each step of an independent single env reset
    with `seed + i` and driven by `actions[:, i]`, reset without a seed after an episode end (as auto-reset)."""
    runs = []
    for i in range(actions.shape[1]):
        env = make_env(domain, task, **kwargs)
        env.reset(seed=seed + i)
        steps = []
        for action in actions[:, i]:
            obs, reward, terminated, truncated, info = env.step(action)
            steps.append((obs, reward, terminated, truncated, info))
            if terminated or truncated:
                steps[-1] = (*steps[-1][:4], {**info, "next_observation": env.reset()[0]})
        env.close()
        runs.append(steps)
    return runs


@pytest.mark.parametrize("backend", ["serial", "threads"])
@pytest.mark.parametrize(("domain", "task", "kwargs"), [
    ("roundabout", "d120", {"observation": "features", "time_limit": 3.0}),  # traffic; collisions end episodes
    ("waypoints", "random_routes", {"time_limit": 2.0}),  # hard steering ends episodes by lane invasion
])
def test_trajectories_equal_independent_single_envs_bit_for_bit(domain, task, kwargs, backend):
    """Three copies with their own actions: every observation, reward, termination, truncation and the
    metrics of every step equal those of three single envs seeded seed + i, across auto-resets (both a
    task end and a time limit happen inside the run)."""
    steps, seed = 40, 4
    mild = np.random.default_rng(0).uniform([0.3, -0.3, 0.0], [1.0, 0.3, 0.1], size=(steps, 2, 3))
    hard = np.random.default_rng(1).uniform([0.8, 0.8, 0.0], [1.0, 1.0, 0.0], size=(steps, 1, 3))
    actions = np.concatenate([mild[:, :1], hard, mild[:, 1:]], axis=1).astype(np.float32)
    reference = _single_env_trajectories(domain, task, actions, seed, **kwargs)
    env = BatchedEnv(domain, task, num_envs=3, nthread=2, backend=backend, **kwargs)
    obs, _ = env.reset(seed=seed)
    returns = np.zeros(3)
    lengths = np.zeros(3, int)
    ends = {"terminated": 0, "truncated": 0}
    for t in range(steps):
        obs, rewards, terms, truncs, info = env.step(actions[t])
        for i in range(3):
            single_obs, reward, terminated, truncated, single_info = reference[i][t]
            assert (rewards[i], terms[i], truncs[i]) == (np.float32(reward), terminated, truncated), (t, i)
            for key, value in single_obs.items():
                np.testing.assert_array_equal(info["final_observation"][key][i], value, err_msg=f"{t} {i} {key}")
            returns[i] += reward
            lengths[i] += 1
            if not (terminated or truncated):
                assert info["final_info"][i] is None and not info["_final_observation"][i]
                metrics = {**env.bases[i].task.info, "time_limit": False}
                np.testing.assert_equal(metrics, single_info, err_msg=f"{t} {i}")
                for key, value in single_obs.items():
                    np.testing.assert_array_equal(obs[key][i], value)
                continue
            ends["terminated" if terminated else "truncated"] += 1
            final = info["final_info"][i]
            assert info["_final_observation"][i] and final["task"] == f"{domain}/{task}"
            assert final["episode_length"] == lengths[i] and final["episode_return"] == returns[i]
            next_observation = single_info.pop("next_observation")
            np.testing.assert_equal({key: final[key] for key in single_info}, single_info, err_msg=f"{t} {i}")
            for key, value in next_observation.items():  # the auto-reset episode's first observation
                np.testing.assert_array_equal(obs[key][i], value, err_msg=f"{t} {i} {key} after reset")
            returns[i], lengths[i] = 0.0, 0
    assert ends["terminated"] >= 2 and ends["truncated"] >= 2, ends
    env.close()


def test_substep_callbacks_get_each_chunks_duration():
    """`Physics.set_substeps` calls back after every chunk of physics steps (the period's nearest whole number)
    with the chunk's duration, a shorter last chunk included (a callback without the ego's sensor or traffic: every
    chunk goes to it)."""
    from mjdrive import suite

    env = suite.load("waypoints", "straight", {"random": 0})
    env.reset()
    physics = env.physics
    dt = physics.timestep()  # [s]
    calls = []
    start = physics.data.time
    physics.set_substeps(lambda p, duration: calls.append((duration, p.data.time)), 4.2 * dt)
    assert physics.substeps.chunk == 4
    physics.advance(4 * 5 + 3)
    assert [duration for duration, _ in calls] == [4 * dt] * 5 + [3 * dt]
    np.testing.assert_allclose([t - start for _, t in calls], dt * np.array([4, 8, 12, 16, 20, 23]))
