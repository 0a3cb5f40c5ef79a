"""Episode videos: the front camera (with waypoint markers) beside a top view that follows the ego."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np

from mjdrive.sensors import CameraRenderer

if TYPE_CHECKING:
    from mjdrive.tasks.base import Physics

FRONT_SIZE = (352, 480)  # (height, width) [px], multiples of 16 for the encoder
TOP_SIZE = (352, 352)


class EpisodeVideo:
    """Collects frames of a gymnasium driving env and writes an mp4 at the control rate. It owns its two
    anti-aliased renderers (apart from the env's observation cameras) and frees them in `close`."""

    def __init__(self, env: gym.Env, path: str | Path):
        self.env = env.unwrapped
        self.path = Path(path)
        fps = round(1.0 / self.env.dm_env.control_timestep())
        self.writer = imageio.get_writer(self.path, fps=fps, codec="libx264", quality=7, macro_block_size=16)
        self.renderers: dict[str, CameraRenderer] = {}
        self._model = None  # the model the renderers were made for (a task may rebuild it on reset)

    def _render(self, physics: Physics, camera: str, size: tuple[int, int], markers: np.ndarray | None) -> np.ndarray:
        if self._model is not physics.raw_model:
            self.close_renderers()
            self._model = physics.raw_model
        if camera not in self.renderers:
            self.renderers[camera] = CameraRenderer(physics.raw_model, camera, *size, antialias=True)
        return self.renderers[camera].render(physics.raw_data, markers).copy()

    def frame(self) -> np.ndarray:
        task, physics = self.env.task, self.env.dm_env.physics
        tracker = getattr(task, "tracker", None)
        markers = None
        if tracker is not None:
            markers = tracker.points[tracker.next_index : tracker.next_index + 5]
        front = self._render(physics, "ego/front", FRONT_SIZE, markers)
        top = self._render(physics, "ego/top", TOP_SIZE, markers)
        return np.concatenate([front, top], axis=1)

    def add_frame(self) -> None:
        self.writer.append_data(self.frame())

    def close_renderers(self) -> None:
        for renderer in self.renderers.values():
            renderer.close()
        self.renderers.clear()

    def close(self) -> None:
        self.writer.close()
        self.close_renderers()
