"""TRPO (Schulman et al. 2015) for study 002's tactical level: MLP 2x128 tanh policy and value networks,
GAE, natural-gradient step by conjugate gradient with a KL trust region and a backtracking line search.
Categorical policy for discrete action tables, tanh-free Gaussian (clipped to the bounds) for continuous.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
from torch.distributions import Categorical, Distribution, Normal

from mjdrive.agents.checkpoints import load_module_state
from mjdrive.agents.env_factory import make_training_env
from mjdrive.agents.networks import Encoder, mlp
from mjdrive.agents.observations import ObsBatch
from mjdrive.agents.run_log import Run
from mjdrive.envs.batched import ObservationLayout

DEFAULTS = {
    "rollout_steps": 256,  # [steps per env copy] per update
    "gamma": 0.99,
    "lam": 0.95,
    "max_kl": 0.01,
    "cg_iters": 10,
    "cg_damping": 0.1,
    "line_search_steps": 10,
    "value_lr": 1e-3,
    "value_epochs": 5,
    "value_minibatches": 8,
    "hidden": [128, 128],  # study 002 §5: MLP 2x128 tanh
    "init_log_std": -0.5,
    "cnn": {"channels": [16, 16, 64], "kernel": 5, "stride": 2, "pool": "avg"},
}


class Policy(nn.Module):
    def __init__(self, layout: ObservationLayout, action_space: gym.Space, hp: dict):
        super().__init__()
        self.encoder = Encoder(layout, hp["cnn"])
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


def flat_grad(y: torch.Tensor, params: list[nn.Parameter], **kwargs) -> torch.Tensor:
    return torch.cat([g.reshape(-1) for g in torch.autograd.grad(y, params, **kwargs)])


def conjugate_gradient(Avp, b: torch.Tensor, iters: int) -> torch.Tensor:
    """Solve A x = b for x with A given as a matrix-vector product."""
    x, r, p = torch.zeros_like(b), b.clone(), b.clone()
    rr = r @ r
    for _ in range(iters):
        Ap = Avp(p)
        alpha = rr / (p @ Ap + 1e-10)
        x += alpha * p
        r -= alpha * Ap
        rr_new = r @ r
        if rr_new < 1e-10:
            break
        p = r + (rr_new / rr) * p
        rr = rr_new
    return x


class TRPOAgent:
    algo = "trpo"

    def __init__(self, config: dict, observation_space: gym.spaces.Dict, action_space: gym.Space):
        self.hp = hp = {**DEFAULTS, **config.get("algorithm", {})}
        self.layout = ObservationLayout(observation_space)
        self.action_space = action_space
        self.policy = Policy(self.layout, action_space, hp)
        self.value = nn.Sequential(Encoder(self.layout, hp["cnn"]))
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
        hp, policy = self.hp, self.policy
        params = [p for p in policy.parameters() if p.requires_grad]
        with torch.no_grad():
            old_dist = policy(obs)
            old_log_prob = policy.log_prob(old_dist, actions)

        def surrogate() -> torch.Tensor:
            return (torch.exp(policy.log_prob(policy(obs), actions) - old_log_prob) * advantages).mean()

        def kl() -> torch.Tensor:
            divergence = torch.distributions.kl_divergence(old_dist, policy(obs))
            return (divergence if policy.discrete else divergence.sum(-1)).mean()

        loss = surrogate()
        g = flat_grad(loss, params)
        grad_kl = flat_grad(kl(), params, create_graph=True)

        def fisher_vector_product(v: torch.Tensor) -> torch.Tensor:
            return flat_grad(grad_kl @ v, params, retain_graph=True) + hp["cg_damping"] * v

        step = conjugate_gradient(fisher_vector_product, g, hp["cg_iters"])
        shs = 0.5 * step @ fisher_vector_product(step)
        full_step = step * torch.sqrt(2 * hp["max_kl"] / (shs + 1e-10))  # KL(step) = max_kl
        expected = g @ full_step
        old = torch.cat([p.data.reshape(-1) for p in params])
        accepted, new_kl = False, 0.0
        with torch.no_grad():
            for fraction in 0.5 ** np.arange(hp["line_search_steps"]):
                self._set_flat(params, old + fraction * full_step)
                improvement = surrogate() - loss
                new_kl = kl().item()
                if new_kl <= 1.5 * hp["max_kl"] and improvement > 0 and improvement > 0.1 * fraction * expected:
                    accepted = True
                    break
            if not accepted:
                self._set_flat(params, old)

        n = len(returns)
        value_losses = []
        for _ in range(hp["value_epochs"]):
            for idx in torch.randperm(n).chunk(hp["value_minibatches"]):
                sub = ObsBatch(obs.features[idx], None if obs.image is None else obs.image[idx])
                value_loss = (self.v(sub) - returns[idx]).pow(2).mean()
                self.value_optimizer.zero_grad()
                value_loss.backward()
                self.value_optimizer.step()
                value_losses.append(value_loss.item())
        return {"surrogate": loss.item(), "kl": new_kl, "accepted": float(accepted),
                "value_loss": float(np.mean(value_losses))}

    @staticmethod
    def _set_flat(params: list[nn.Parameter], flat: torch.Tensor) -> None:
        i = 0
        for p in params:
            p.data.copy_(flat[i : i + p.numel()].view_as(p))
            i += p.numel()

    def state_dict(self) -> dict:
        return {"policy": self.policy.state_dict(), "value": self.value.state_dict(),
                "value_head": self.value_head.state_dict(), "value_optimizer": self.value_optimizer.state_dict()}

    def load_state_dict(self, state: dict, inference_only: bool = False) -> None:
        load_module_state(self.policy, state["policy"], "TRPO policy")
        if inference_only:
            return
        load_module_state(self.value, state["value"], "TRPO value encoder")
        load_module_state(self.value_head, state["value_head"], "TRPO value head")
        self.value_optimizer.load_state_dict(state["value_optimizer"])


def train(config: dict, run: Run, resume_state: dict | None = None) -> None:
    """Collect `rollout_steps` per env copy, compute GAE, one TRPO step; until `run.total_steps`."""
    env = make_training_env(config)
    try:
        _learn(config, env, run, resume_state)
    finally:
        env.close()  # and its workers, also on Ctrl-C or an error


def _learn(config: dict, env, run: Run, resume_state: dict | None) -> None:
    agent = TRPOAgent(config, env.single_observation_space, env.single_action_space)
    if resume_state is not None:
        agent.load_state_dict(resume_state)
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
        adv = advantages.reshape(-1)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        stats = agent.update(flat_obs, torch.cat(actions), adv, returns.reshape(-1))
        run.scalars(stats)
        if run.checkpoint_due():
            run.save("trpo", agent.state_dict())
    run.save("trpo", agent.state_dict(), periodic=False)

