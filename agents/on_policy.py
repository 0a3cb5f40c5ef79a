"""What the on-policy learners of study 002's tactical level share (TRPO, PPO with a categorical policy): the
actor-critic pair (policy and value MLPs of 2x128 tanh over the observation encoder, separate networks as in
SB3's default), the rollout with GAE, and the training loop; each learner adds only its `update`."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
from torch.distributions import Categorical, Distribution, Normal

from mjdrive.agents.checkpoints import load_module_state
from mjdrive.agents.env_factory import make_training_env
from mjdrive.agents.networks import make_encoder, mlp
from mjdrive.agents.observations import ObsBatch
from mjdrive.agents.run_log import Run
from mjdrive.envs.batched import ObservationLayout

COMMON_DEFAULTS = {
    "rollout_steps": 256,  # [steps per env copy] per update
    "gamma": 0.99,
    "lam": 0.95,
    "hidden": [128, 128],  # study 002 §5: MLP 2x128 tanh
    "init_log_std": -0.5,
    "cnn": {"channels": [16, 16, 64], "kernel": 5, "stride": 2, "pool": "avg"},
    "extractor": None,  # e.g. {groups: {ego: [ego, scenario], adversaries: [adversaries]}, hidden: [128, 128]}
}


class Policy(nn.Module):
    """Categorical over a discrete action table, or a state-independent Gaussian (clipped to the bounds)."""

    def __init__(self, layout: ObservationLayout, action_space: gym.Space, hp: dict):
        super().__init__()
        self.encoder = make_encoder(layout, hp)
        self.discrete = isinstance(action_space, gym.spaces.Discrete)
        n_out = int(action_space.n) if self.discrete else int(np.prod(action_space.shape))
        self.net = mlp(self.encoder.out_dim, hp["hidden"], n_out, nn.Tanh)
        if not self.discrete:
            self.log_std = nn.Parameter(torch.full((n_out,), float(hp["init_log_std"])))

    def forward(self, obs: ObsBatch) -> Distribution:
        out = self.net(self.encoder(obs.features, obs.image))
        if self.discrete:
            return Categorical(logits=out)
        return Normal(out, self.log_std.exp().expand_as(out))

    def log_prob(self, dist: Distribution, actions: torch.Tensor) -> torch.Tensor:
        return dist.log_prob(actions) if self.discrete else dist.log_prob(actions).sum(-1)


class ActorCritic:
    """The policy, the value network and how they act; a learner subclasses it with `update`."""

    algo = ""
    DEFAULTS: dict = COMMON_DEFAULTS

    def __init__(self, config: dict, observation_space: gym.spaces.Dict, action_space: gym.Space):
        self.hp = hp = {**self.DEFAULTS, **config.get("algorithm", {})}
        self.layout = ObservationLayout(observation_space)
        self.action_space = action_space
        self.policy = Policy(self.layout, action_space, hp)
        self.value = nn.Sequential(make_encoder(self.layout, hp))
        self.value_head = mlp(self.value[0].out_dim, hp["hidden"], 1, nn.Tanh)
        self.value_optimizer = torch.optim.Adam(
            list(self.value.parameters()) + list(self.value_head.parameters()), lr=hp["value_lr"])
        if not self.policy.discrete:
            self.low = torch.as_tensor(action_space.low)
            self.high = torch.as_tensor(action_space.high)

    def v(self, obs: ObsBatch) -> torch.Tensor:
        return self.value_head(self.value[0](obs.features, obs.image)).squeeze(-1)

    def to_env(self, actions: torch.Tensor) -> np.ndarray:
        if self.policy.discrete:
            return actions.numpy()
        return torch.max(torch.min(actions, self.high), self.low).numpy()

    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray], deterministic: bool = True) -> np.ndarray:
        dist = self.policy(ObsBatch.from_numpy(self.layout, obs))
        if deterministic:
            a = dist.probs.argmax(-1) if self.policy.discrete else dist.mean
        else:
            a = dist.sample()
        return self.to_env(a)

    def update(self, obs: ObsBatch, actions: torch.Tensor, advantages: torch.Tensor,
               returns: torch.Tensor) -> dict[str, float]:
        raise NotImplementedError

    def fit_value(self, obs: ObsBatch, returns: torch.Tensor) -> float:
        """`value_epochs` passes of regression onto the returns in `value_minibatches`; the mean loss."""
        hp, n, losses = self.hp, len(returns), []
        for _ in range(hp["value_epochs"]):
            for idx in torch.randperm(n).chunk(hp["value_minibatches"]):
                sub = ObsBatch(obs.features[idx], None if obs.image is None else obs.image[idx])
                loss = (self.v(sub) - returns[idx]).pow(2).mean()
                self.value_optimizer.zero_grad()
                loss.backward()
                self.value_optimizer.step()
                losses.append(loss.item())
        return float(np.mean(losses))

    def state_dict(self) -> dict:
        return {"policy": self.policy.state_dict(), "value": self.value.state_dict(),
                "value_head": self.value_head.state_dict(), "value_optimizer": self.value_optimizer.state_dict()}

    def load_state_dict(self, state: dict, inference_only: bool = False) -> None:
        name = self.algo.upper()
        load_module_state(self.policy, state["policy"], f"{name} policy")
        if inference_only:
            return
        load_module_state(self.value, state["value"], f"{name} value encoder")
        load_module_state(self.value_head, state["value_head"], f"{name} value head")
        self.value_optimizer.load_state_dict(state["value_optimizer"])


def train(agent_class: type[ActorCritic], config: dict, run: Run, resume_state: dict | None = None) -> None:
    """Collect `rollout_steps` per env copy, compute GAE, one `update`; until `run.total_steps`."""
    env = make_training_env(config)
    try:
        agent = agent_class(config, env.single_observation_space, env.single_action_space)
        if resume_state is not None:
            agent.load_state_dict(resume_state)
        _learn(agent, config, env, run)
    finally:
        env.close()  # and its workers, also on Ctrl-C or an error


def _learn(agent: ActorCritic, config: dict, env, run: Run) -> None:
    hp, n = agent.hp, env.num_envs
    reward_scale = float(config.get("reward_scale", 1.0))
    obs, _ = env.reset(seed=int(config.get("seed", 0)) + run.step)
    T = int(hp["rollout_steps"])
    while not run.done:
        batches, actions, rewards, values, dones = [], [], [], [], []
        for _ in range(T):
            batch = ObsBatch.from_numpy(agent.layout, obs)
            with torch.no_grad():
                a = agent.policy(batch).sample()
                values.append(agent.v(batch))
            obs, reward, terminated, truncated, info = env.step(agent.to_env(a))
            with torch.no_grad():  # bootstrap a truncated episode from its true final observation
                final = agent.v(ObsBatch.from_numpy(agent.layout, info["final_observation"]))
            reward = torch.as_tensor(reward * reward_scale) + hp["gamma"] * final * torch.as_tensor(
                truncated & ~terminated)
            batches.append(batch)
            actions.append(a)
            rewards.append(reward)
            dones.append(torch.as_tensor(terminated | truncated, dtype=torch.float32))
            run.add_steps(n, info["final_info"])
        with torch.no_grad():
            next_values = agent.v(ObsBatch.from_numpy(agent.layout, obs))
        advantages = torch.zeros(T, n)
        gae = torch.zeros(n)
        for t in reversed(range(T)):
            v_next = next_values if t == T - 1 else values[t + 1]
            delta = rewards[t] + hp["gamma"] * v_next * (1 - dones[t]) - values[t]
            gae = delta + hp["gamma"] * hp["lam"] * (1 - dones[t]) * gae
            advantages[t] = gae
        returns = advantages + torch.stack(values)
        flat_obs = ObsBatch(torch.cat([b.features for b in batches]),
                            None if batches[0].image is None else torch.cat([b.image for b in batches]))
        stats = agent.update(flat_obs, torch.cat(actions), advantages.reshape(-1), returns.reshape(-1))
        run.scalars(stats)
        if run.checkpoint_due():
            run.save(agent.algo, agent.state_dict())
    run.save(agent.algo, agent.state_dict(), periodic=False)
