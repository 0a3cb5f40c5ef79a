"""Soft Actor-Critic as in study 000's Algorithm 1: a tanh-Gaussian actor and twin Q critics over the
observation encoder (the §4.2 CNN for 4x84x84 frames + destination vector, or an MLP over features),
target critics, automatic entropy tuning. Table 2 hyper-parameters are the defaults.

One encoder serves both (as in SAC-AE / DrQ, Yarats et al. 2021, Kostrikov et al. 2021): the critic's loss
trains it, the actor reads its output detached, and the target critics keep a Polyak copy. With images,
each update sees its frames randomly shifted by up to `random_shift` px (DrQ's augmentation, which those
papers found makes pixel SAC far more sample-efficient). One CNN pass with gradients instead of three made
an update 1.8x cheaper here (batch 64, 4x84x84, 1 thread: 112 -> 61 ms).
"""

from __future__ import annotations

import copy
import math

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from mjdrive.agents.checkpoints import load_module_state, load_optimizer_state
from mjdrive.agents.networks import Encoder, bounded_action_map, mlp
from mjdrive.agents.observations import ObsBatch
from mjdrive.envs.batched import ObservationLayout

DEFAULTS = {
    "actor_lr": 3e-4,  # Table 2
    "critic_lr": 3e-4,  # Table 2
    "batch_size": 64,  # Table 2
    "buffer_size": 200_000,  # Table 2
    "gamma": 0.99,
    "tau": 0.005,  # Polyak factor of the target critics (1.0 with target_every > 1 = Algorithm 1's copy)
    "target_every": 1,  # [updates] between target updates
    "policy_every": 2,  # [updates] between actor (and alpha) updates, several actor steps each time
    "alpha": 0.2,  # initial entropy coefficient
    "autotune": True,  # automatic entropy tuning (Algorithm 1, line 23)
    "target_entropy": None,  # None: -dim(A)
    "learning_starts": 1000,  # [env steps] uniform random actions before learning
    "updates_per_step": 1.0,  # gradient steps per env transition
    "resume_refill": 10_000,  # [transitions] a run resumed without its saved buffer collects before updating
    "critic_warmup": 0,  # [updates] the first ones train only the critic heads and alpha (start from a policy.pt)
    "freeze_encoder": False,  # keep the encoder's weights: only the actor and critic heads learn (fine-tuning)
    "bc_alpha": 0.0,  # > 0: TD3+BC's alpha, the actor also imitates the demonstrations (if none: the replayed actions)
    "random_shift": 4,  # [px] DrQ image augmentation in updates; 0: none
    "hidden": [256, 256],
    "cnn": {"channels": [16, 16, 64], "kernel": 5, "stride": 2, "pool": "avg"},  # §4.2
    "log_std_range": [-5.0, 2.0],
}


class Actor(nn.Module):
    """pi(a|s): tanh(N(mu(s), sigma(s))) scaled to the action bounds (eq 13), over the critic's encoder."""

    def __init__(self, encoder: Encoder, action_space: gym.spaces.Box, hp: dict):
        super().__init__()
        self.encoder = encoder  # shared with the critic, which trains it
        self.trunk = mlp(self.encoder.out_dim, hp["hidden"], None)
        n = int(np.prod(action_space.shape))
        self.mean, self.log_std = nn.Linear(hp["hidden"][-1], n), nn.Linear(hp["hidden"][-1], n)
        self.log_std_min, self.log_std_max = hp["log_std_range"]
        scale, bias = bounded_action_map(action_space)
        self.register_buffer("action_scale", scale)
        self.register_buffer("action_bias", bias)

    def head_parameters(self) -> list[nn.Parameter]:
        """The actor's own parameters (the encoder belongs to the critic's optimizer)."""
        return [p for name, p in self.named_parameters() if not name.startswith("encoder.")]

    def forward(self, latent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.trunk(latent)
        log_std = torch.tanh(self.log_std(h))  # soft clamp into [min, max]
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (log_std + 1)
        return self.mean(h), log_std

    def sample(self, latent: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(squashed action in [-1, 1], its log-probability, the squashed mean) with reparameterisation."""
        mean, log_std = self(latent)
        normal = torch.distributions.Normal(mean, log_std.exp())
        u = normal.rsample()
        a = torch.tanh(u)
        log_prob = (normal.log_prob(u) - torch.log(1 - a.pow(2) + 1e-6)).sum(-1)
        return a, log_prob, torch.tanh(mean)

    def greedy(self, latent: torch.Tensor) -> torch.Tensor:
        """The squashed mean in [-1, 1] (`sample`'s third output, without the log-std head, the draw and its
        log-probability)."""
        return torch.tanh(self.mean(self.trunk(latent)))

    def encode(self, obs: ObsBatch) -> torch.Tensor:
        return self.encoder(obs.features, obs.image)

    def to_env(self, a: torch.Tensor) -> torch.Tensor:
        return self.action_bias + self.action_scale * a


class Critic(nn.Module):
    """Twin Q(s, a) heads over one encoder; a is the squashed action in [-1, 1]."""

    def __init__(self, layout: ObservationLayout, action_dim: int, hp: dict):
        super().__init__()
        self.encoder = Encoder(layout, hp["cnn"])
        self.q1 = mlp(self.encoder.out_dim + action_dim, hp["hidden"], 1)
        self.q2 = mlp(self.encoder.out_dim + action_dim, hp["hidden"], 1)

    def heads(self, latent: torch.Tensor, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat([latent, a], dim=-1)
        return self.q1(x).squeeze(-1), self.q2(x).squeeze(-1)

    def forward(self, obs: ObsBatch, a: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.heads(self.encoder(obs.features, obs.image), a)


class SACAgent:
    algo = "sac"

    def __init__(self, config: dict, observation_space: gym.spaces.Dict, action_space: gym.Space):
        if not isinstance(action_space, gym.spaces.Box):
            raise ValueError("SAC needs continuous actions (actions: continuous)")
        self.hp = hp = {**DEFAULTS, **config.get("algorithm", {})}
        self.layout = ObservationLayout(observation_space)
        action_dim = int(np.prod(action_space.shape))
        self.critic = Critic(self.layout, action_dim, hp)
        self.actor = Actor(self.critic.encoder, action_space, hp)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = torch.optim.Adam(self.actor.head_parameters(), lr=hp["actor_lr"])
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=hp["critic_lr"])
        self.target_entropy = float(hp["target_entropy"] if hp["target_entropy"] is not None else -action_dim)
        self.log_alpha = torch.tensor(math.log(hp["alpha"]), requires_grad=True)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=hp["critic_lr"])
        self.updates = 0
        self.action_dim = action_dim

    # --- acting -----------------------------------------------------------------------------------------
    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray], deterministic: bool = True) -> np.ndarray:
        """Env actions (N, 3) for batched observations: the squashed mean, or a sample."""
        latent = self.actor.encode(ObsBatch.from_numpy(self.layout, obs))
        a = self.actor.greedy(latent) if deterministic else self.actor.sample(latent)[0]
        return self.actor.to_env(a).numpy()

    @torch.no_grad()
    def explore(self, obs: dict[str, np.ndarray], step: int) -> tuple[np.ndarray, np.ndarray]:
        n = len(next(iter(obs.values())))
        if step < self.hp["learning_starts"]:
            a = torch.rand(n, self.action_dim) * 2 - 1
        else:
            a, _, _ = self.actor.sample(self.actor.encode(ObsBatch.from_numpy(self.layout, obs)))
        return a.numpy(), self.actor.to_env(a).numpy()

    # --- learning ---------------------------------------------------------------------------------------
    def update(self, batch: dict) -> dict[str, float]:
        hp = self.hp
        obs, next_obs = batch["obs"].shifted(hp["random_shift"]), batch["next_obs"].shifted(hp["random_shift"])
        alpha = self.log_alpha.exp().item()
        with torch.no_grad():  # eq 6/8: soft Bellman target with the smaller target Q
            next_a, next_log_prob, _ = self.actor.sample(self.actor.encode(next_obs))
            q1_next, q2_next = self.critic_target(next_obs, next_a)
            v_next = torch.min(q1_next, q2_next) - alpha * next_log_prob
            target = batch["rewards"] + hp["gamma"] * (1.0 - batch["terminated"]) * v_next
        warmup = self.updates < hp["critic_warmup"]  # new critic heads learn on the loaded encoder's features
        with torch.set_grad_enabled(not (warmup or hp["freeze_encoder"])):
            latent = self.critic.encoder(obs.features, obs.image)
        q1, q2 = self.critic.heads(latent, batch["actions"])
        critic_loss = F.mse_loss(q1, target) + F.mse_loss(q2, target)
        self.critic_optimizer.zero_grad()
        critic_loss.backward()
        self.critic_optimizer.step()
        self.updates += 1
        info = {"critic_loss": critic_loss.item(), "q": q1.mean().item(), "alpha": alpha}

        if self.updates % hp["policy_every"] == 0:  # delayed actor updates (TD3 / CleanRL style)
            latent = latent.detach()  # the actor does not train the encoder
            for _ in range(hp["policy_every"]):
                with torch.set_grad_enabled(not warmup):
                    a, log_prob, mean_action = self.actor.sample(latent)
                if not warmup:
                    q1_pi, q2_pi = self.critic.heads(latent, a)
                    q_pi = torch.min(q1_pi, q2_pi)
                    actor_loss = (self.log_alpha.exp().detach() * log_prob - q_pi).mean()  # eq 9
                    if hp["bc_alpha"] > 0:  # Fujimoto & Gu 2021: lambda Q - (pi(s) - a)^2, lambda = alpha / mean|Q|
                        rows = batch.get("demonstration", slice(None))  # imitate the demonstrations if any
                        bc_loss = F.mse_loss(mean_action[rows], batch["actions"][rows], reduction="none").sum(-1).mean()
                        actor_loss = hp["bc_alpha"] / q_pi.abs().mean().detach() * actor_loss + bc_loss
                        info["bc_loss"] = bc_loss.item()
                    self.actor_optimizer.zero_grad()
                    actor_loss.backward()
                    self.actor_optimizer.step()
                    info["actor_loss"] = actor_loss.item()
                if hp["autotune"]:
                    alpha_loss = -(self.log_alpha.exp() * (log_prob.detach() + self.target_entropy)).mean()
                    self.alpha_optimizer.zero_grad()
                    alpha_loss.backward()
                    self.alpha_optimizer.step()
            info["entropy"] = -log_prob.mean().item()

        if self.updates % hp["target_every"] == 0:
            with torch.no_grad():
                for p, p_target in zip(self.critic.parameters(), self.critic_target.parameters(), strict=True):
                    p_target.lerp_(p, hp["tau"])
        return info

    # --- checkpoints ------------------------------------------------------------------------------------
    def state_dict(self) -> dict:
        return {"actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
                "critic_target": self.critic_target.state_dict(), "log_alpha": self.log_alpha.detach().clone(),
                "actor_optimizer": self.actor_optimizer.state_dict(),
                "critic_optimizer": self.critic_optimizer.state_dict(),
                "alpha_optimizer": self.alpha_optimizer.state_dict(), "updates": self.updates}

    def load_state_dict(self, state: dict, inference_only: bool = False) -> None:
        """Networks, optimizers and counters; `inference_only`: the actor and its encoder only (a policy.pt),
        the critic heads stay new and the target critic copies the loaded encoder."""
        load_module_state(self.actor, state["actor"], "SAC actor")
        if inference_only:
            self.critic_target.load_state_dict(self.critic.state_dict())
            return
        load_module_state(self.critic, state["critic"], "SAC critic")
        load_module_state(self.critic_target, state["critic_target"], "SAC target critic")
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        load_optimizer_state(self.actor_optimizer, state["actor_optimizer"], self.hp["actor_lr"])
        load_optimizer_state(self.critic_optimizer, state["critic_optimizer"], self.hp["critic_lr"])
        load_optimizer_state(self.alpha_optimizer, state["alpha_optimizer"], self.hp["critic_lr"])
        self.updates = state["updates"]

    def inference_state(self) -> dict:
        """The actor alone (small checkpoints for results/)."""
        return {"actor": self.actor.state_dict()}
