"""Episode videos: the front camera (with waypoint markers) beside a top view that follows the ego."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np

FRONT_SIZE = (352, 480)  # (height, width) [px], multiples of 16 for the encoder
TOP_SIZE = (352, 352)


class EpisodeVideo:
    """Collects frames of a gymnasium driving env and writes an mp4 at the control rate."""

    def __init__(self, env: gym.Env, path: str | Path):
        self.env = env.unwrapped
        self.path = Path(path)
        fps = round(1.0 / self.env.dm_env.control_timestep())
        self.writer = imageio.get_writer(self.path, fps=fps, codec="libx264", quality=7, macro_block_size=16)

    def frame(self) -> np.ndarray:
        task, physics = self.env.task, self.env.dm_env.physics
        tracker = getattr(task, "tracker", None)
        markers = None
        if tracker is not None:
            markers = tracker.points[tracker.next_index : tracker.next_index + 5]
        front = task.render_camera(physics, "ego/front", *FRONT_SIZE, markers=markers, antialias=True).copy()
        top = task.render_camera(physics, "ego/top", *TOP_SIZE, markers=markers, antialias=True).copy()
        return np.concatenate([front, top], axis=1)

    def add_frame(self) -> None:
        self.writer.append_data(self.frame())

    def close(self) -> None:
        self.writer.close()
