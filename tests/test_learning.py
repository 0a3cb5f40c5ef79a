"""Every learner learns: PPO (rsl-rl), SAC, DQN and TRPO, each through `mjdrive.agents.train.train` (its real
training loop, checkpoint and policy.pt), must solve a tiny lane-keeping task within a bounded number of env
steps. The learned policy's mean return must beat a threshold that a uniformly random policy and the learner's
own untrained policy (same seed) both stay under; all three are measured here on the same evaluation episodes.

The task, `LaneVecEnv`, stands in for `make_training_env`'s vector env (same interface: dict observations,
(throttle, steer, brake) commands or action-table indices, auto-reset with `final_observation`/`final_info`):
the car starts at a lateral offset x0 ~ U(-1, 1) m, each 0.1 s step moves it by STEER_GAIN * steer, and pays
1 - |x|; leaving the road (|x| > ROAD_HALF_WIDTH) ends the episode, the time limit (HORIZON steps) truncates
it. Steering back to the centre and holding it earns about HORIZON - |x0|; a random or a constant policy drifts
off the road or stays off centre."""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rsl_rl")

from mjdrive.agents.algorithms import agent_class  # noqa: E402
from mjdrive.agents.checkpoints import load_checkpoint  # noqa: E402
from mjdrive.agents.config import apply_overrides, load_config  # noqa: E402
from mjdrive.agents.seeding import set_seed  # noqa: E402

HORIZON = 10  # [steps] per episode (time limit)
STEER_GAIN = 0.6  # [m] lateral move per step at full steer
ROAD_HALF_WIDTH = 1.5  # [m] beyond it the episode ends (off road)
STEER_TABLE = np.linspace(-1.0, 1.0, 9)  # the discrete action set (DQN): steer values
# mean return the learned policy must beat: steering back in proportion to the offset earns 9.9 (9.6 with the
# table), holding the wheel straight 5.6, half steer towards the centre 8.4, random steering about 3.4
THRESHOLD = 9.0
EVAL_EPISODES = 64
EVAL_SEED = 10_000  # evaluation episodes differ from the training ones (seeds 0 ...)


class LaneVecEnv:
    """`num_envs` copies of the lane-keeping task with the `mjdrive.envs.vector.VecEnv` interface."""

    domain, task_name = "test", "lane"
    control_timestep = 0.1  # [s]
    max_episode_steps = HORIZON

    def __init__(self, num_envs: int, discrete: bool = False):
        self.num_envs, self.discrete = num_envs, discrete
        self.task_kwargs: dict[str, Any] = {}
        self.single_observation_space = gym.spaces.Dict(
            {"offset": gym.spaces.Box(-2 * ROAD_HALF_WIDTH, 2 * ROAD_HALF_WIDTH, (1,), np.float32)})
        self.single_action_space: gym.Space = gym.spaces.Discrete(len(STEER_TABLE)) if discrete else \
            gym.spaces.Box(np.array([0.0, -1.0, 0.0], np.float32), np.array([1.0, 1.0, 1.0], np.float32))
        self.x = np.zeros(num_envs)
        self.steps = np.zeros(num_envs, np.int64)
        self.returns = np.zeros(num_envs)
        self.rngs: list[np.random.Generator] = []

    def _obs(self, x: np.ndarray) -> dict[str, np.ndarray]:
        return {"offset": x.astype(np.float32)[:, None]}

    def _start(self, i: int) -> None:
        self.x[i] = self.rngs[i].uniform(-1.0, 1.0)
        self.steps[i], self.returns[i] = 0, 0.0

    def reset(self, seed: int | None = None) -> tuple[dict, dict]:
        base = 0 if seed is None else seed
        self.rngs = [np.random.default_rng(base + i) for i in range(self.num_envs)]
        for i in range(self.num_envs):
            self._start(i)
        return self._obs(self.x), {"infos": [{} for _ in range(self.num_envs)]}

    def observations(self) -> dict | None:
        return self._obs(self.x) if self.rngs else None

    def step(self, actions) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
        actions = np.asarray(actions)
        steer = STEER_TABLE[actions.astype(np.int64)] if self.discrete else np.clip(actions[:, 1], -1.0, 1.0)
        self.x = self.x + STEER_GAIN * steer
        self.steps += 1
        off_road = np.abs(self.x) > ROAD_HALF_WIDTH
        rewards = np.where(off_road, 0.0, 1.0 - np.abs(self.x)).astype(np.float32)
        self.returns += rewards
        terminated = off_road
        truncated = ~off_road & (self.steps >= HORIZON)
        final_obs = self._obs(self.x)
        final_info: list[dict | None] = [None] * self.num_envs
        for i in np.flatnonzero(terminated | truncated):
            final_info[i] = {"episode_return": float(self.returns[i]), "episode_length": int(self.steps[i]),
                             "off_road": bool(off_road[i]), "time_limit": bool(truncated[i]), "task": "test/lane"}
            self._start(i)
        info = {"final_observation": final_obs, "_final_observation": terminated | truncated,
                "final_info": final_info}
        return self._obs(self.x), rewards, terminated, truncated, info

    def close(self) -> None:
        pass


def mean_return(act, discrete: bool) -> float:
    """Mean return of `act(batched_obs) -> actions` over the first episode of each of EVAL_EPISODES copies."""
    env = LaneVecEnv(EVAL_EPISODES, discrete)
    obs, _ = env.reset(seed=EVAL_SEED)
    returns: list[float | None] = [None] * EVAL_EPISODES
    while any(r is None for r in returns):
        obs, _, _, _, info = env.step(act(obs))
        for i, final in enumerate(info["final_info"]):
            if final is not None and returns[i] is None:
                returns[i] = final["episode_return"]
    return float(np.mean(returns))


def random_policy(discrete: bool):
    rng = np.random.default_rng(0)
    if discrete:
        return lambda obs: rng.integers(len(STEER_TABLE), size=len(obs["offset"]))
    return lambda obs: rng.uniform([0.0, -1.0, 0.0], [1.0, 1.0, 1.0], size=(len(obs["offset"]), 3))


# config name -> overrides: small networks and settings that learn this task within `steps` env steps
LEARNERS = {
    "ppo": ("ppo", ["steps=4096", "num_envs=16", "rsl_rl.num_steps_per_env=16", "rsl_rl.algorithm.gamma=0.9",
                    "rsl_rl.actor.hidden_dims=[32, 32]", "rsl_rl.critic.hidden_dims=[32, 32]",
                    "rsl_rl.algorithm.learning_rate=1.0e-3"]),
    "sac": ("sac", ["steps=1000", "num_envs=4", "algorithm.gamma=0.9", "algorithm.learning_starts=200",
                    "algorithm.batch_size=64", "algorithm.updates_per_step=0.5", "algorithm.hidden=[64, 64]",
                    "algorithm.actor_lr=1.0e-3", "algorithm.critic_lr=1.0e-3"]),
    "dqn": ("dqn", ["steps=2000", "num_envs=4", "algorithm.gamma=0.9", "algorithm.learning_starts=200",
                    "algorithm.batch_size=64", "algorithm.epsilon_decay_steps=1000", "algorithm.target_every=50",
                    "algorithm.updates_per_step=0.5", "algorithm.hidden=[64, 64]"]),
    "trpo": ("trpo", ["steps=2048", "num_envs=16", "algorithm.gamma=0.9", "algorithm.rollout_steps=16",
                      "algorithm.hidden=[32, 32]", "algorithm.max_kl=0.05"]),
    "ppo_discrete": ("ppo_discrete", ["steps=4096", "num_envs=16", "algorithm.gamma=0.9",
                                      "algorithm.rollout_steps=16", "algorithm.hidden=[32, 32]",
                                      "algorithm.lr=1.0e-3", "algorithm.extractor=null"]),
}
COMMON = ["task=test/lane", "task_kwargs={}", "reward_scale=1.0", "seed=0", "checkpoint_every=0",
          "tensorboard=false", "torch_threads=1", "log_every=500"]


@pytest.mark.parametrize("algo", sorted(LEARNERS))
def test_learner_solves_the_lane_task_within_its_step_budget(algo, tmp_path, monkeypatch):
    from mjdrive.agents import on_policy, ppo, train

    name, overrides = LEARNERS[algo]
    config = apply_overrides(load_config(name), COMMON + overrides)
    discrete = algo in ("dqn", "ppo_discrete")
    envs: list[LaneVecEnv] = []

    def make_lane_env(config: dict, num_envs: int | None = None, **overrides) -> LaneVecEnv:
        envs.append(LaneVecEnv(num_envs or config["num_envs"], discrete))
        return envs[-1]

    for module in (train, ppo, on_policy):  # the learners build their env through make_training_env
        monkeypatch.setattr(module, "make_training_env", make_lane_env)
    probe = LaneVecEnv(1, discrete)
    set_seed(int(config["seed"]))  # the untrained networks train() starts from
    untrained = agent_class(algo)(config, probe.single_observation_space, probe.single_action_space)
    start = time.perf_counter()
    policy_path = train.train(config, tmp_path, progress=False)
    seconds = time.perf_counter() - start
    assert len(envs) == 1 and (tmp_path / "episodes.csv").exists()
    payload = load_checkpoint(policy_path, algo)
    assert payload["step"] <= int(config["steps"]) + config["num_envs"]  # the step budget was kept
    trained = agent_class(algo)(payload["config"], probe.single_observation_space, probe.single_action_space)
    trained.load_state_dict(payload["state"], inference_only=True)
    learned = mean_return(trained.act, discrete)
    baselines = {"random": mean_return(random_policy(discrete), discrete),
                 "untrained": mean_return(untrained.act, discrete)}
    assert all(value < THRESHOLD - 1.0 for value in baselines.values()), baselines
    assert learned > THRESHOLD, (learned, baselines, f"{seconds:.1f} s")
