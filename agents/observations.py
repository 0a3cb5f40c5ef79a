"""Batched observations as torch tensors."""

from __future__ import annotations

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
