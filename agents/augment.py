"""Image augmentation of observation batches."""

from __future__ import annotations

import torch


def random_shift(image: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """DrQ's augmentation (Kostrikov et al. 2021): shift each (C, H, W) frame stack of a batch by its own random
    offset in [-pad, pad] px on both axes, repeating the edge pixels (= pad with the edge, then crop)."""
    if pad <= 0:
        return image
    b, c, h, w = image.shape
    shift = torch.randint(-pad, pad + 1, (b, 2), generator=generator, device=image.device)
    rows = (shift[:, 0:1] + torch.arange(h, device=image.device)).clamp_(0, h - 1)  # (B, H) source rows
    cols = (shift[:, 1:2] + torch.arange(w, device=image.device)).clamp_(0, w - 1)  # (B, W) source columns
    image = image.gather(2, rows[:, None, :, None].expand(b, c, h, w))
    return image.gather(3, cols[:, None, None, :].expand(b, c, h, w))
