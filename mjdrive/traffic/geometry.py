"""Pure geometry of road users: smooth lane-change profile, overlap of oriented boxes."""

from __future__ import annotations

import numpy as np


def smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3x^2 - 2x^3 on [0, 1] and its derivative."""
    x = np.minimum(np.maximum(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)


def overlapping_pairs(poses: np.ndarray, half_sizes: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Pairs (K,2) of oriented rectangles (x, y, yaw) (N,3) [m, m, rad] with half sizes (N,>=2) [m] that
    overlap (separating-axis test; each rectangle grown by `margin` [m])."""
    n = len(poses)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = np.triu_indices(n, 1)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    axes = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], 1)  # (N, 2 axes, 2)
    half = half_sizes[:, :2] + margin
    d = poses[j, :2] - poses[i, :2]
    separated = np.zeros(len(i), dtype=bool)
    for owner in (i, j):
        for k in range(2):
            axis = axes[owner, k]
            ri = np.abs(np.einsum("pa,pba->pb", axis, axes[i])) * half[i]
            rj = np.abs(np.einsum("pa,pba->pb", axis, axes[j])) * half[j]
            separated |= np.abs(np.einsum("pa,pa->p", d, axis)) > ri.sum(1) + rj.sum(1)
    return np.stack([i[~separated], j[~separated]], 1)
