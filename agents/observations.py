"""Batched observations as torch tensors; whether a policy can read another env's observations."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch

from mjdrive.agents.augment import random_shift
from mjdrive.envs.batched import ObservationLayout


class ObsBatch:
    """Batched observations as torch tensors: `features` (B, F) float32 and `image` (B, C, H, W) uint8|None."""

    def __init__(self, features: torch.Tensor, image: torch.Tensor | None):
        self.features, self.image = features, image

    def shifted(self, pad: int) -> ObsBatch:
        """The same batch with `random_shift`ed images (features unchanged)."""
        return self if self.image is None or pad <= 0 else ObsBatch(self.features, random_shift(self.image, pad))

    @classmethod
    def from_numpy(cls, layout: ObservationLayout, obs: dict[str, np.ndarray], device: str = "cpu") -> ObsBatch:
        image = layout.image(obs)
        return cls(torch.as_tensor(layout.features(obs), device=device),
                   None if image is None else torch.as_tensor(image, device=device))


def observation_mismatch(trained: gym.spaces.Dict, given: gym.spaces.Dict) -> list[str]:
    """What keeps a policy that reads `trained` observations from reading `given` ones: each entry it reads
    that is missing, or of another shape or dtype ([] when it can read them; extra entries are ignored)."""
    problems = [f"no {key!r}" for key in trained.spaces if key not in given.spaces]
    for key, space in trained.spaces.items():
        other = given.spaces.get(key)
        if other is not None and (other.shape, other.dtype) != (space.shape, space.dtype):
            problems.append(f"{key!r} is {other.shape} {other.dtype}, not {space.shape} {space.dtype}")
    return problems
