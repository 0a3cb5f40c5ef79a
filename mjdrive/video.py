"""Episode videos: the front camera (with waypoint markers) beside a top view that follows the ego, with an
overlay (step, time, speed, reward, return, the task and its scenario, the episode's outcome) and a legend
of the road-user colours.

The video renders a copy of the model in which road users wear `LEGEND_RGBA`'s colours (pedestrians pink,
apart from the ego's blue); the simulation and its camera observations keep theirs, which trained camera
policies have learnt.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import imageio.v2 as imageio
import mujoco
import numpy as np
from PIL import Image, ImageDraw, ImageFont

from mjdrive.sensors import CameraRenderer

if TYPE_CHECKING:
    from mjdrive.tasks.base import Physics

FRONT_SIZE = (352, 480)  # (height, width) [px], multiples of 16 for the encoder
TOP_SIZE = (352, 352)
OUTCOME_HOLD = 1.0  # [s] the last frame, with the outcome, stays this long
FONT_SIZE = 14  # [px]
ORDINALS = ("first, right turn", "second, straight on", "third, left turn")
EGO_RGB = (31, 77, 158)  # the sedan's body colour (xml/vehicles/sedan.xml), for the legend
LEGEND_RGBA: dict[str, tuple[float, float, float, float]] = {  # road users in videos, by kind
    "car": (0.75, 0.15, 0.12, 1.0), "motorcycle": (0.15, 0.15, 0.18, 1.0), "bicycle": (0.95, 0.75, 0.1, 1.0),
    "pedestrian": (0.95, 0.3, 0.6, 1.0),
}


@dataclass
class Overlay:
    """What one frame shows: the step it follows, its reward, the return so far [task units], the task's
    `info`, and the outcome on the last frame (e.g. `mjdrive.record.summary.end_reason`)."""

    step: int = 0
    reward: float | None = None
    episode_return: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)
    outcome: str | None = None


def video_model(model: mujoco.MjModel) -> mujoco.MjModel:
    """A copy of `model` whose road-user geoms (`traffic_{i}_{kind}`) wear `LEGEND_RGBA`."""
    out = copy.copy(model)
    for geom in range(model.ngeom):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom) or ""
        kind = name.rsplit("_", 1)[-1] if name.startswith("traffic_") else None
        if kind in LEGEND_RGBA:
            out.geom_rgba[geom] = LEGEND_RGBA[kind]
    return out


def _rgb(rgba: tuple[float, ...]) -> tuple[int, int, int]:
    return tuple(int(round(255 * c)) for c in rgba[:3])


class EpisodeVideo:
    """Collects frames of a gymnasium driving env and writes an mp4 at the control rate. It owns its two
    anti-aliased renderers (apart from the env's observation cameras) and frees them in `close`."""

    def __init__(self, env: gym.Env, path: str | Path):
        self.env = env.unwrapped
        self.path = Path(path)
        self.fps = round(1.0 / self.env.dm_env.control_timestep())
        self.writer = imageio.get_writer(self.path, fps=self.fps, codec="libx264", quality=7, macro_block_size=16)
        self.renderers: dict[str, CameraRenderer] = {}
        self._model = None  # the model the renderers were made for (a task may rebuild it on reset)
        self._video_model: mujoco.MjModel | None = None
        self.font = ImageFont.load_default(size=FONT_SIZE)

    def _render(self, physics: Physics, camera: str, size: tuple[int, int], markers: np.ndarray | None) -> np.ndarray:
        if self._model is not physics.raw_model:
            self.close_renderers()
            self._model = physics.raw_model
            self._video_model = video_model(physics.raw_model)
        if camera not in self.renderers:
            self.renderers[camera] = CameraRenderer(self._video_model, camera, *size, antialias=True)
        return self.renderers[camera].render(physics.raw_data, markers).copy()

    def frame(self, overlay: Overlay | None = None) -> np.ndarray:
        """The two views side by side, with `overlay` and the legend drawn on them (None: bare views)."""
        task, physics = self.env.task, self.env.dm_env.physics
        tracker = getattr(task, "tracker", None)
        markers = None
        if tracker is not None:
            markers = tracker.points[tracker.next_index : tracker.next_index + 5]
        front = self._render(physics, "ego/front", FRONT_SIZE, markers)
        top = self._render(physics, "ego/top", TOP_SIZE, markers)
        image = np.concatenate([front, top], axis=1)
        if overlay is None:
            return image
        return self.draw(image, overlay)

    def scenario(self, info: dict[str, Any]) -> str:
        """The task and its active scenario: the route or exit being driven, a scenario the task names."""
        text = f"{self.env.domain}/{self.env.task_name}"
        exit_number = info.get("exit_number")  # the roundabout's exit, counted from the entry
        if exit_number is not None:
            text += f", exit {exit_number}"
            if exit_number <= len(ORDINALS):
                text += f" ({ORDINALS[exit_number - 1]})"
        scenario = info.get("scenario") or getattr(self.env.task, "scenario", None)
        if isinstance(scenario, str) and scenario:
            text += f", {scenario}"
        return text

    def draw(self, image: np.ndarray, overlay: Overlay) -> np.ndarray:
        """`image` with the overlay (top left of the front view) and the legend (bottom left)."""
        speed = float(getattr(self.env.task, "speed", 0.0))  # [m/s]
        time_s = overlay.step / self.fps
        lines = [self.scenario(overlay.info),
                 f"step {overlay.step}   t {time_s:5.1f} s   speed {3.6 * speed:5.1f} km/h",
                 f"reward {overlay.reward if overlay.reward is not None else 0.0:+8.2f}   "
                 f"return {overlay.episode_return:+9.2f}"]
        if overlay.outcome:
            lines.append(f"outcome: {overlay.outcome.replace('_', ' ')}")
        canvas = Image.fromarray(image)
        draw = ImageDraw.Draw(canvas, "RGBA")
        height = FONT_SIZE + 4
        width = max(draw.textlength(line, font=self.font) for line in lines) + 12
        draw.rectangle([4, 4, 4 + width, 8 + height * len(lines)], fill=(0, 0, 0, 150))
        for i, line in enumerate(lines):
            colour = (255, 220, 80) if overlay.outcome and i == len(lines) - 1 else (255, 255, 255)
            draw.text((10, 7 + height * i), line, fill=colour, font=self.font)
        self._legend(draw, x=6, y=FRONT_SIZE[0] - height - 8)
        return np.asarray(canvas)

    def _legend(self, draw: ImageDraw.ImageDraw, x: int, y: int) -> None:
        entries = [("ego", EGO_RGB)] + [(kind, _rgb(rgba)) for kind, rgba in LEGEND_RGBA.items()]
        width = sum(draw.textlength(name, font=self.font) + 24 for name, _ in entries) + 6
        draw.rectangle([x - 2, y - 2, x + width, y + FONT_SIZE + 6], fill=(255, 255, 255, 190))
        for name, rgb in entries:
            draw.rectangle([x + 2, y + 3, x + 14, y + FONT_SIZE + 1], fill=rgb, outline=(0, 0, 0))
            draw.text((x + 18, y + 1), name, fill=(0, 0, 0), font=self.font)
            x += int(draw.textlength(name, font=self.font)) + 24

    def add_frame(self, overlay: Overlay | None = None) -> None:
        """Append a frame; one with an outcome (the last) is held for OUTCOME_HOLD s."""
        image = self.frame(overlay)
        repeats = max(1, round(OUTCOME_HOLD * self.fps)) if overlay is not None and overlay.outcome else 1
        for _ in range(repeats):
            self.writer.append_data(image)

    def close_renderers(self) -> None:
        for renderer in self.renderers.values():
            renderer.close()
        self.renderers.clear()

    def close(self) -> None:
        self.writer.close()
        self.close_renderers()
