"""One training run's bookkeeping: config copy, episode log, TensorBoard scalars, periodic checkpoints,
progress bar."""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import numpy as np

from mjdrive.agents.checkpoints import save_checkpoint

EPISODE_FIELDS = ("episode", "env_step", "wall_s", "return", "length", "route_completion", "success",
                  "collision", "lane_invasion", "off_road", "off_route", "time_limit", "task")


class Run:
    """One training run's outputs in `out/`: config.yaml, episodes.csv (one row per ended episode, flushed as
    it ends; a resumed run keeps the rows up to its checkpoint),
    TensorBoard scalars (tb/), checkpoints (checkpoint.pt = latest, checkpoints/step_N.pt), a tqdm bar."""

    def __init__(self, out: str | Path, config: dict, total_steps: int, start_step: int = 0,
                 start_episode: int = 0, progress: bool = True, tensorboard: bool = True):
        import yaml

        from mjdrive.progress import Progress

        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        self.config, self.total_steps = config, int(total_steps)
        self.step, self.episode = int(start_step), int(start_episode)
        self.checkpoint_every = int(config.get("checkpoint_every", 0) or 0)
        self._next_checkpoint = (self.step // self.checkpoint_every + 1) * self.checkpoint_every \
            if self.checkpoint_every else None
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.out / "tb"))
        csv_path = self.out / "episodes.csv"
        new_file = not csv_path.exists() or start_step == 0
        if not new_file:  # a resumed run: drop the rows logged after the checkpoint it resumes from
            with open(csv_path, newline="") as f:
                kept = [row for row in csv.DictReader(f) if int(row["episode"]) <= start_episode]
        self._csv_file = open(csv_path, "w", newline="")  # noqa: SIM115
        self._csv = csv.DictWriter(self._csv_file, EPISODE_FIELDS, extrasaction="ignore")
        self._csv.writeheader()
        self.wall_offset = 0.0  # [s] of training before a resume: wall_s in episodes.csv is cumulative
        if not new_file:
            self._csv.writerows(kept)
            self.wall_offset = float(kept[-1]["wall_s"]) if kept else 0.0
        self._csv_file.flush()
        self.recent: list[float] = []
        self.latest: dict[str, float] = {}  # last value of every scalar (written to scalars.json at close)
        self.start_time = time.perf_counter()
        self.bar = Progress(total=self.total_steps, initial=self.step, unit="step", disable=not progress,
                            desc=f"{config.get('algo', 'train')} (env steps)")

    def add_steps(self, n: int, final_infos: list[dict | None] | None = None) -> None:
        """Count `n` env steps and log the episodes that ended (BatchedEnv's `info["final_info"]`)."""
        self.step += n
        self.bar.update(n)
        for final in final_infos or []:
            if final is None:
                continue
            self.episode += 1
            row = {"episode": self.episode, "env_step": self.step,
                   "wall_s": round(self.wall_offset + time.perf_counter() - self.start_time, 2),
                   "return": round(final["episode_return"], 3), "length": final["episode_length"],
                   **{k: final[k] for k in EPISODE_FIELDS[5:] if k in final}}
            self._csv.writerow(row)
            self.recent = (self.recent + [final["episode_return"]])[-20:]
            self.scalar("episode/return", final["episode_return"])
            self.scalar("episode/length", final["episode_length"])
            for key in ("route_completion", "success", "collision"):
                if key in final:
                    self.scalar(f"episode/{key}", float(final[key]))
        if any(final is not None for final in final_infos or []):
            self._csv_file.flush()  # a killed run keeps every ended episode
        if self.recent:
            self.bar.set_postfix(episodes=self.episode, mean_return_last_20=f"{np.mean(self.recent):.0f}",
                                 refresh=False)

    def scalar(self, name: str, value: float) -> None:
        self.latest[name] = float(value)
        if self.writer is not None:
            self.writer.add_scalar(name, float(value), self.step)

    def scalars(self, values: dict[str, float], prefix: str = "train/") -> None:
        for name, value in values.items():
            self.scalar(prefix + name, value)

    def checkpoint_due(self) -> bool:
        return self._next_checkpoint is not None and self.step >= self._next_checkpoint

    def save(self, algo: str, state: dict, extra: dict | None = None, periodic: bool = True) -> Path:
        """Write checkpoint.pt (and checkpoints/step_N.pt when periodic)."""
        extra = {"episode": self.episode, **(extra or {})}
        path = save_checkpoint(self.out / "checkpoint.pt", algo, self.config, state, self.step, extra)
        if periodic:
            save_checkpoint(self.out / "checkpoints" / f"step_{self.step}.pt", algo, self.config, state,
                            self.step, extra)
        if self.checkpoint_every:
            self._next_checkpoint = (self.step // self.checkpoint_every + 1) * self.checkpoint_every
        self._csv_file.flush()
        return path

    def close(self) -> None:
        summary = {"env_steps": self.step, "episodes": self.episode,
                   "wall_s": round(self.wall_offset + time.perf_counter() - self.start_time, 1),
                   "latest": self.latest}
        (self.out / "scalars.json").write_text(json.dumps(summary, indent=2) + "\n")
        self.bar.close()
        self._csv_file.close()
        if self.writer is not None:
            self.writer.close()

    @property
    def done(self) -> bool:
        return self.step >= self.total_steps
