"""The off-policy learners' replay buffer."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch

from mjdrive.agents.observations import ObsBatch
from mjdrive.envs.batched import ObservationLayout


class ReplayBuffer:
    """Uniform replay of (obs, action, reward, next_obs, terminated); images kept as uint8.

    Only `terminated` stops bootstrapping: a time-limit truncation keeps its true final observation
    (BatchedEnv's `info["final_observation"]`) as next_obs and is bootstrapped like any other step.
    Memory: 2 x capacity x image bytes (84x84x4: 56 kB per transition; 128x128x3: 98 kB).
    """

    def __init__(self, capacity: int, layout: ObservationLayout, action_shape: tuple[int, ...],
                 action_dtype=np.float32, device: str = "cpu"):
        self.capacity, self.layout, self.device = int(capacity), layout, device
        self.features = np.zeros((self.capacity, layout.feature_dim), np.float32)
        self.next_features = np.zeros_like(self.features)
        shape = layout.image_shape
        self.images = np.zeros((self.capacity, *shape), np.uint8) if shape else None
        self.next_images = np.zeros_like(self.images) if shape else None
        self.actions = np.zeros((self.capacity, *action_shape), action_dtype)
        self.rewards = np.zeros(self.capacity, np.float32)
        self.terminated = np.zeros(self.capacity, np.float32)
        self.position, self.size = 0, 0

    def add(self, obs: dict, actions: np.ndarray, rewards: np.ndarray, next_obs: dict,
            terminated: np.ndarray) -> None:
        """Add a batch of transitions (one per env copy)."""
        features, next_features = self.layout.features(obs), self.layout.features(next_obs)
        images, next_images = self.layout.image(obs), self.layout.image(next_obs)
        for i in range(len(rewards)):
            k = self.position
            self.features[k], self.next_features[k] = features[i], next_features[i]
            if self.images is not None:
                self.images[k], self.next_images[k] = images[i], next_images[i]
            self.actions[k], self.rewards[k], self.terminated[k] = actions[i], rewards[i], terminated[i]
            self.position = (k + 1) % self.capacity
            self.size = min(self.size + 1, self.capacity)

    def sample(self, batch_size: int) -> dict[str, Any]:
        idx = np.random.randint(0, self.size, size=batch_size)

        def t(array):
            return None if array is None else torch.as_tensor(array[idx], device=self.device)

        return {"obs": ObsBatch(t(self.features), t(self.images)),
                "next_obs": ObsBatch(t(self.next_features), t(self.next_images)),
                "actions": t(self.actions), "rewards": t(self.rewards), "terminated": t(self.terminated)}

    ARRAYS = ("features", "next_features", "images", "next_images", "actions", "rewards", "terminated")

    def save(self, directory: str | Path, step: int) -> Path:
        """Write the filled part to `directory` (one .npy per array + meta.json; uncompressed, so 100k camera
        transitions take ~5.6 GB and a few seconds) as of env step `step`; replaces an earlier save only once
        the new one is complete."""
        directory = Path(directory)
        tmp = directory.with_name(directory.name + ".tmp")
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir(parents=True)
        for name in self.ARRAYS:
            array = getattr(self, name)
            if array is not None:
                np.save(tmp / f"{name}.npy", array[:self.size])
        meta = {"step": int(step), "size": self.size, "position": self.position, "capacity": self.capacity}
        (tmp / "meta.json").write_text(json.dumps(meta) + "\n")
        if directory.exists():
            shutil.rmtree(directory)
        tmp.rename(directory)
        return directory

    def load(self, directory: str | Path, step: int) -> None:
        """Fill this (empty) buffer from `save`'s `directory`, keeping the newest transitions if it holds fewer
        than were saved; ValueError if it was saved at another env step than `step` or for other observation
        or action shapes."""
        directory = Path(directory)
        meta = json.loads((directory / "meta.json").read_text())
        if meta["step"] != step:
            raise ValueError(f"replay buffer {directory} was saved at env step {meta['step']:,}, "
                             f"the checkpoint is at {step:,}")
        size, position = int(meta["size"]), int(meta["position"])
        arrays = {}
        for name in self.ARRAYS:
            own = getattr(self, name)
            if own is None:
                continue
            saved = np.load(directory / f"{name}.npy", mmap_mode="r", allow_pickle=False)
            if saved.shape != (size, *own.shape[1:]) or saved.dtype != own.dtype:
                raise ValueError(f"replay buffer {directory}: {name} is {saved.dtype}{list(saved.shape)}, this "
                                 f"run stores {own.dtype}{[size, *own.shape[1:]]}")
            arrays[name] = saved
        # the saved rows oldest first (a wrapped buffer's oldest row is at `position`), then the newest n of them
        segments = [(position, size), (0, position)] if size == meta["capacity"] else [(0, size)]
        n = min(size, self.capacity)
        skip, row = size - n, 0
        for first, last in segments:
            dropped = min(skip, last - first)  # older than the newest n
            first, skip = first + dropped, skip - dropped
            for name, saved in arrays.items():
                getattr(self, name)[row:row + last - first] = saved[first:last]
            row += last - first
        self.size, self.position = n, n % self.capacity
