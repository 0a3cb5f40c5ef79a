"""TRPO (Schulman et al. 2015) for study 002's tactical level: MLP 2x128 tanh policy and value networks,
GAE, natural-gradient step by conjugate gradient with a KL trust region and a backtracking line search.
Categorical policy for discrete action tables, tanh-free Gaussian (clipped to the bounds) for continuous; the
networks, rollout and loop are `on_policy`'s.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn

from mjdrive.agents import on_policy
from mjdrive.agents.observations import ObsBatch
from mjdrive.agents.on_policy import COMMON_DEFAULTS, ActorCritic
from mjdrive.agents.run_log import Run

DEFAULTS = {
    **COMMON_DEFAULTS,
    "max_kl": 0.01,
    "cg_iters": 10,
    "cg_damping": 0.1,
    "line_search_steps": 10,
    "value_lr": 1e-3,
    "value_epochs": 5,
    "value_minibatches": 8,
}


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


class TRPOAgent(ActorCritic):
    algo = "trpo"
    DEFAULTS = DEFAULTS

    def update(self, obs: ObsBatch, actions: torch.Tensor, advantages: torch.Tensor,
               returns: torch.Tensor) -> dict[str, float]:
        hp, policy = self.hp, self.policy
        advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
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

        value_loss = self.fit_value(obs, returns)
        return {"surrogate": loss.item(), "kl": new_kl, "accepted": float(accepted),
                "value_loss": value_loss}

    @staticmethod
    def _set_flat(params: list[nn.Parameter], flat: torch.Tensor) -> None:
        i = 0
        for p in params:
            p.data.copy_(flat[i : i + p.numel()].view_as(p))
            i += p.numel()


def train(config: dict, run: Run, resume_state: dict | None = None) -> None:
    """Train TRPO on the config's env (`on_policy.train`)."""
    on_policy.train(TRPOAgent, config, run, resume_state)
