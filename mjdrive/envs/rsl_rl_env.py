"""rsl-rl 5.x `VecEnv` over any mjdrive vector env (`mjdrive.envs.vector`: a `BatchedEnv` in process, worker
processes or Ray actors; needs the `learn` extra: torch, tensordict, rsl-rl-lib). It converts only dtypes and
the device; everything else is the vector env's.

Observation groups (TensorDict, batch size [num_envs]):
  "policy": (N, F) float32, the non-image observations flattened and scaled (`ObservationLayout`);
  "image":  (N, C, H, W) float32 in [0, 1], when the task has an image observation.
Use them in the runner config, e.g. `obs_groups: {actor: [policy, image], critic: [policy, image]}`.

Actions: rsl-rl's Gaussian policies are unbounded; each channel is clipped to [-1, 1] and mapped linearly
onto the env's bounds (throttle [0, 1], steer [-1, 1], brake [0, 1]). Discrete action tables are not
supported here (rsl-rl has no categorical distribution): use DQN for those.
`extras["time_outs"]` flags time-limit truncations (rsl-rl bootstraps on them); `extras["log"]` carries the
means of the task metrics (route completion, success, ...) over the episodes that ended this step.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from mjdrive.envs.batched import ObservationLayout
from mjdrive.envs.vector import VecEnv as MjVecEnv

LOGGED_METRICS = ("route_completion", "success", "collision", "lane_invasion", "off_road")


def to_tensordict(layout: ObservationLayout, obs: dict[str, np.ndarray], device: str = "cpu") -> TensorDict:
    """Batched numpy observations -> the observation groups ("policy", and "image" when there is one)."""
    groups = {"policy": torch.as_tensor(layout.features(obs), device=device)}
    image = layout.image(obs)
    if image is not None:
        groups["image"] = torch.as_tensor(image, device=device).float().div_(255.0)
    return TensorDict(groups, batch_size=[len(groups["policy"])], device=device)


def action_scaler(space: gym.spaces.Box) -> tuple[np.ndarray, np.ndarray]:
    """(scale, offset) such that env_action = offset + scale * clip(a, -1, 1)."""
    low, high = space.low.astype(np.float32), space.high.astype(np.float32)
    return (high - low) / 2.0, (high + low) / 2.0


class RslRlVecEnv(VecEnv):
    """An mjdrive vector env as an rsl-rl `VecEnv`; `reward_scale` multiplies the rewards the learner sees."""

    def __init__(self, env: MjVecEnv, device: str = "cpu", reward_scale: float = 1.0):
        if env.discrete:
            raise ValueError("RslRlVecEnv needs continuous actions (actions='continuous'); use DQN for tables")
        self.env = env
        self.device = device
        self.num_envs = env.num_envs
        self.num_actions = int(np.prod(env.single_action_space.shape))
        self.max_episode_length = env.max_episode_steps or 10**9
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long, device=device)
        self.reward_scale = reward_scale
        self.layout = ObservationLayout(env.single_observation_space)
        self.cfg = {"domain": env.domain, "task": env.task_name, "num_envs": env.num_envs,
                    "task_kwargs": env.task_kwargs, "reward_scale": reward_scale}
        self._scale, self._offset = action_scaler(env.single_action_space)
        self.completed: list[dict] = []  # final infos of the episodes ended since the caller last cleared it
        obs = env.observations()
        self._obs = self.to_tensordict(env.reset(seed=0)[0] if obs is None else obs)

    def seed(self, seed: int) -> None:
        """Reset every copy with `seed` (copy i gets seed + i)."""
        self._obs = self.to_tensordict(self.env.reset(seed=seed)[0])
        self.episode_length_buf.zero_()

    def to_tensordict(self, obs: dict[str, np.ndarray]) -> TensorDict:
        return to_tensordict(self.layout, obs, self.device)

    def env_actions(self, actions: torch.Tensor) -> np.ndarray:
        """Policy outputs (N, A) -> env commands within the action bounds."""
        a = np.clip(actions.detach().cpu().numpy(), -1.0, 1.0)
        return self._offset + self._scale * a

    def get_observations(self) -> TensorDict:
        return self._obs

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        obs, reward, terminated, truncated, info = self.env.step(self.env_actions(actions))
        self._obs = self.to_tensordict(obs)
        done = terminated | truncated
        self.episode_length_buf += 1
        self.episode_length_buf[torch.as_tensor(done, device=self.device)] = 0
        extras: dict = {"time_outs": torch.as_tensor(truncated & ~terminated, device=self.device)}
        finals = [f for f in info["final_info"] if f is not None]
        self.completed.extend(finals)
        if finals:
            extras["log"] = {f"/episode/{key}": torch.tensor([float(f.get(key, 0.0)) for f in finals])
                             for key in LOGGED_METRICS if key in finals[0]}
            extras["log"]["/episode/return"] = torch.tensor([f["episode_return"] for f in finals])
        self.last_info = info
        rewards = torch.as_tensor(reward * self.reward_scale, dtype=torch.float32, device=self.device)
        return self._obs, rewards, torch.as_tensor(done, device=self.device).long(), extras

    def close(self) -> None:
        self.env.close()
