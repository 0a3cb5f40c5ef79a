"""DQN: a Q-network over the observation encoder (CNN for images, MLP for features), a target network,
uniform replay, a linear epsilon schedule and, with images, DrQ's random-shift augmentation. Defaults:
study 000 Table 2 (lr 1e-3, batch 128, buffer 1e5) and study 004 §4.2 (epsilon 0.9 -> 0.1); the loss is
the studies' MSE unless `loss: huber`.
"""

from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from mjdrive.agents.checkpoints import load_module_state, load_optimizer_state
from mjdrive.agents.networks import Encoder, mlp
from mjdrive.agents.observations import ObsBatch
from mjdrive.envs.batched import ObservationLayout

DEFAULTS = {
    "lr": 1e-3,  # Table 2 (000)
    "batch_size": 128,  # Table 2 (000)
    "buffer_size": 100_000,  # Table 2 (000)
    "gamma": 0.99,
    "epsilon_start": 0.9,  # study 004 §4.2
    "epsilon_end": 0.1,  # study 004 §4.2
    "epsilon_decay_steps": 50_000,  # [env steps] linear decay
    "target_every": 1000,  # [updates] between hard target copies
    "learning_starts": 1000,  # [env steps]
    "updates_per_step": 0.25,  # gradient steps per env transition
    "resume_refill": 10_000,  # [transitions] a run resumed without its saved buffer collects before updating
    "double": True,  # Double DQN target (van Hasselt 2016); False: the studies' max over the target net
    "loss": "mse",  # "mse" (the studies) or "huber"
    "random_shift": 4,  # [px] DrQ image augmentation in updates (as in agents/sac.py); 0: none
    "max_grad_norm": 10.0,
    "hidden": [256, 256],
    "cnn": {"channels": [16, 16, 64], "kernel": 5, "stride": 2, "pool": "avg"},
}


class QNetwork(nn.Module):
    def __init__(self, layout: ObservationLayout, n_actions: int, hp: dict):
        super().__init__()
        self.encoder = Encoder(layout, hp["cnn"])
        self.head = mlp(self.encoder.out_dim, hp["hidden"], n_actions)

    def forward(self, obs: ObsBatch) -> torch.Tensor:
        return self.head(self.encoder(obs.features, obs.image))


class DQNAgent:
    algo = "dqn"

    def __init__(self, config: dict, observation_space: gym.spaces.Dict, action_space: gym.Space):
        if not isinstance(action_space, gym.spaces.Discrete):
            raise ValueError("DQN needs a discrete action table (actions: table1 | table2 | roundabout7)")
        self.hp = hp = {**DEFAULTS, **config.get("algorithm", {})}
        self.layout = ObservationLayout(observation_space)
        self.n_actions = int(action_space.n)
        self.q = QNetwork(self.layout, self.n_actions, hp)
        self.q_target = copy.deepcopy(self.q).requires_grad_(False)
        self.optimizer = torch.optim.Adam(self.q.parameters(), lr=hp["lr"])
        self.updates = 0
        self.rng = np.random.default_rng(config.get("seed", 0))

    def epsilon(self, step: int) -> float:
        hp = self.hp
        fraction = min(1.0, step / max(1, hp["epsilon_decay_steps"]))
        return hp["epsilon_start"] + fraction * (hp["epsilon_end"] - hp["epsilon_start"])

    @torch.no_grad()
    def act(self, obs: dict[str, np.ndarray], deterministic: bool = True) -> np.ndarray:
        """Greedy action indices (N,) for batched observations."""
        return self.q(ObsBatch.from_numpy(self.layout, obs)).argmax(-1).numpy()

    @torch.no_grad()
    def explore(self, obs: dict[str, np.ndarray], step: int) -> tuple[np.ndarray, np.ndarray]:
        greedy = self.act(obs)
        random = self.rng.integers(self.n_actions, size=len(greedy))
        explore = self.rng.random(len(greedy)) < self.epsilon(step)
        actions = np.where(explore, random, greedy)
        return actions, actions

    def update(self, batch: dict) -> dict[str, float]:
        hp = self.hp
        obs, next_obs = batch["obs"].shifted(hp["random_shift"]), batch["next_obs"].shifted(hp["random_shift"])
        with torch.no_grad():
            q_next = self.q_target(next_obs)
            if hp["double"]:
                best = self.q(next_obs).argmax(-1, keepdim=True)
                v_next = q_next.gather(-1, best).squeeze(-1)
            else:
                v_next = q_next.max(-1).values
            target = batch["rewards"] + hp["gamma"] * (1.0 - batch["terminated"]) * v_next
        q = self.q(obs).gather(-1, batch["actions"].long().unsqueeze(-1)).squeeze(-1)
        loss = F.mse_loss(q, target) if hp["loss"] == "mse" else F.smooth_l1_loss(q, target)
        self.optimizer.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(self.q.parameters(), hp["max_grad_norm"])
        self.optimizer.step()
        self.updates += 1
        if self.updates % hp["target_every"] == 0:
            self.q_target.load_state_dict(self.q.state_dict())
        return {"q_loss": loss.item(), "q": q.mean().item()}

    def state_dict(self) -> dict:
        return {"q": self.q.state_dict(), "q_target": self.q_target.state_dict(),
                "optimizer": self.optimizer.state_dict(), "updates": self.updates}

    def load_state_dict(self, state: dict, inference_only: bool = False) -> None:
        load_module_state(self.q, state["q"], "DQN Q-network")
        if inference_only:
            return
        load_module_state(self.q_target, state["q_target"], "DQN target network")
        load_optimizer_state(self.optimizer, state["optimizer"], self.hp["lr"])
        self.updates = state["updates"]

    def inference_state(self) -> dict:
        return {"q": self.q.state_dict()}
