"""PPO (Schulman et al. 2017) with a categorical policy, for decision action tables such as study 002's: the
actor-critic, rollout and loop of `on_policy` (as TRPO's), the clipped surrogate with an entropy bonus in
minibatches, CleanRL's `ppo.py` read top to bottom. rsl-rl's PPO (`algo: ppo`) stays the learner for
continuous actions; it has no categorical distribution.
"""

from __future__ import annotations

import torch

from mjdrive.agents import on_policy
from mjdrive.agents.observations import ObsBatch
from mjdrive.agents.on_policy import COMMON_DEFAULTS, ActorCritic
from mjdrive.agents.run_log import Run

DEFAULTS = {
    **COMMON_DEFAULTS,
    "lr": 3e-4,  # the policy's Adam
    "clip": 0.2,
    "epochs": 4,
    "minibatches": 8,
    "entropy_coef": 0.01,
    "max_grad_norm": 0.5,
    "value_lr": 1e-3,
    "value_epochs": 4,
    "value_minibatches": 8,
}


class PPODiscreteAgent(ActorCritic):
    algo = "ppo_discrete"
    DEFAULTS = DEFAULTS

    def __init__(self, config: dict, observation_space, action_space):
        super().__init__(config, observation_space, action_space)
        if not self.policy.discrete:
            raise ValueError("ppo_discrete needs a discrete action set (e.g. the urban tasks' decisions); use ppo "
                             "(rsl-rl) for continuous actions")
        self.policy_optimizer = torch.optim.Adam(self.policy.parameters(), lr=self.hp["lr"])

    def update(self, obs: ObsBatch, actions: torch.Tensor, advantages: torch.Tensor,
               returns: torch.Tensor) -> dict[str, float]:
        hp, policy = self.hp, self.policy
        with torch.no_grad():
            old_log_prob = policy.log_prob(policy(obs), actions)
        clipped, entropies, kls = [], [], []
        for _ in range(hp["epochs"]):
            for idx in torch.randperm(len(actions)).chunk(hp["minibatches"]):
                dist = policy(ObsBatch(obs.features[idx], None if obs.image is None else obs.image[idx]))
                log_ratio = policy.log_prob(dist, actions[idx]) - old_log_prob[idx]
                ratio = log_ratio.exp()
                adv = advantages[idx]
                adv = (adv - adv.mean()) / (adv.std() + 1e-8)
                surrogate = torch.min(ratio * adv, ratio.clamp(1 - hp["clip"], 1 + hp["clip"]) * adv).mean()
                entropy = dist.entropy().mean()
                loss = -surrogate - hp["entropy_coef"] * entropy
                self.policy_optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(policy.parameters(), hp["max_grad_norm"])
                self.policy_optimizer.step()
                with torch.no_grad():
                    clipped.append(((ratio - 1).abs() > hp["clip"]).float().mean().item())
                    kls.append(((ratio - 1) - log_ratio).mean().item())  # the low-variance KL estimate
                    entropies.append(entropy.item())
        value_loss = self.fit_value(obs, returns)
        n = len(kls)
        return {"clip_fraction": sum(clipped) / n, "approx_kl": sum(kls) / n, "entropy": sum(entropies) / n,
                "value_loss": value_loss}

    def state_dict(self) -> dict:
        return {**super().state_dict(), "policy_optimizer": self.policy_optimizer.state_dict()}

    def load_state_dict(self, state: dict, inference_only: bool = False) -> None:
        super().load_state_dict(state, inference_only)
        if not inference_only:
            self.policy_optimizer.load_state_dict(state["policy_optimizer"])


def train(config: dict, run: Run, resume_state: dict | None = None) -> None:
    """Train PPO (categorical) on the config's env (`on_policy.train`)."""
    on_policy.train(PPODiscreteAgent, config, run, resume_state)
