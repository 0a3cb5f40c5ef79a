"""Re-simulate a recorded episode from its metadata (task, kwargs, RNG state or seed) and its actions in a
gymnasium env, and check every logged state (time, qpos, qvel, act, mocap) and reward bit for bit; optionally
render a video. (Above the logs it reads: `mjdrive.record` writes and reads them, this rebuilds the env.)"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mjdrive.envs.gym_env import DrivingGymEnv
from mjdrive.record.reader import EpisodeFileError, read_episode
from mjdrive.record.recorder import decode_rng_state, package_versions

STATE_FIELDS = ("time", "qpos", "qvel", "act", "mocap_pos", "mocap_quat")
LEGACY_PHYSICS_DT = 0.002  # [s] the physics step of every task before the step became a task keyword


def replay_task_kwargs(metadata: dict) -> dict:
    """The task kwargs that rebuild a log's env: its own, with the physics step it ran at (`physics_dt` [s]):
    the kwarg if logged, else the metadata's `physics_timestep`, else LEGACY_PHYSICS_DT (logs written before
    either was recorded all ran at 2 ms)."""
    kwargs = dict(metadata.get("task_kwargs") or {})
    kwargs.setdefault("physics_dt", float(metadata.get("physics_timestep", LEGACY_PHYSICS_DT)))
    return kwargs


@dataclass
class ReplayResult:
    """Outcome of `replay`: steps in the file, steps compared, and the first mismatch if any."""

    path: Path
    steps: int
    checked: int
    complete: bool  # the file holds the whole episode (an incomplete file is checked up to its damage)
    mismatch_step: int | None = None  # first step whose state or reward differs (0: the reset state)
    mismatch_fields: list[str] = field(default_factory=list)
    max_abs_diff: dict[str, float] = field(default_factory=dict)
    video: Path | None = None
    damage: str | None = None  # what is wrong with a file that is incomplete or fails a CRC check
    version_changes: list[str] = field(default_factory=list)  # packages whose version differs from the log's

    @property
    def match(self) -> bool:
        """Every logged step re-simulated identically, and the file was complete and passed its CRC checks."""
        return self.complete and self.damage is None and self.mismatch_step is None and self.checked == self.steps

    def report(self) -> str:
        if self.mismatch_step is not None:
            diffs = ", ".join(f"{k} {v:.3g}" for k, v in self.max_abs_diff.items() if v > 0)
            text = (f"MISMATCH at step {self.mismatch_step} of {self.steps} ({', '.join(self.mismatch_fields)}); "
                    f"max |difference| over the episode: {diffs or '-'}")
        else:
            text = f"match: {self.checked} steps, every state (time, qpos, qvel, act, mocap) and reward bit for bit"
        if not self.complete:
            text = f"{self.damage}\nchecked only those steps: {text}; the episode cannot be fully verified"
        elif self.damage is not None:
            text = f"{self.damage}\n{text}; the file itself is damaged"
        if self.version_changes:
            text += f" (versions differ from the recording: {', '.join(self.version_changes)})"
        return f"replay {self.path}: {text}" + (f"; video {self.video}" if self.video else "")


def _physics_state(data) -> dict[str, np.ndarray]:
    return {"time": np.array([data.time]), "qpos": data.qpos.copy(), "qvel": data.qvel.copy(),
            "act": data.act.copy(), "mocap_pos": data.mocap_pos.ravel().copy(),
            "mocap_quat": data.mocap_quat.ravel().copy()}


def replay(path: str | Path, video: str | Path | None = None, progress: bool = False) -> ReplayResult:
    """Rebuild the env of `path`, replay its actions and compare (`progress`: a bar over the steps on
    stderr). Raises EpisodeFileError when the file cannot be replayed (not an episode, no seed or RNG state,
    kwargs that were not JSON)."""
    from mjdrive.progress import Progress

    episode = read_episode(path, topics={"/action", "/physics", "/reward"})
    meta = episode.metadata
    if not meta.get("replayable", False):
        raise EpisodeFileError(f"{path} cannot be replayed: it records no seed or RNG state, or its kwargs "
                               "were not JSON-serialisable")
    if not episode.messages.get("/physics"):
        damage = episode.describe_damage() if not episode.complete else f"{path} holds no states"
        raise EpisodeFileError(f"{damage} No state survived: nothing to replay.")
    physics_log = episode.physics()
    actions = episode.actions()
    rewards = [r["reward"] for r in episode.json("/reward")]
    steps = min(len(actions), len(rewards), len(physics_log["time"]) - 1)

    if progress:
        from mjdrive.progress import note

        note(f"replay: rebuilding {meta['domain']}/{meta['task_name']} for {steps} steps ...")
    env = DrivingGymEnv(meta["domain"], meta["task_name"], replay_task_kwargs(meta), meta.get("environment_kwargs"))
    try:
        if meta.get("rng_state") is not None:
            env.task.random.set_state(decode_rng_state(meta["rng_state"]))
        else:
            env.task.seed(meta["seed"])
        env.dm_env.reset()
        data = env.dm_env.physics.data.ptr
        writer = None
        if video is not None:
            from mjdrive.video import EpisodeVideo, Overlay

            writer = EpisodeVideo(env, video)
        result = ReplayResult(Path(path), len(actions), 0, episode.complete, video=Path(video) if video else None,
                              damage=None if episode.intact else episode.describe_damage())
        result.max_abs_diff = {name: 0.0 for name in (*STATE_FIELDS, "reward")}
        logged_versions = meta.get("versions") or {}
        result.version_changes = [f"{name} {logged_versions[name]} -> {version}"
                                  for name, version in package_versions().items()
                                  if name in logged_versions and logged_versions[name] != version]

        def compare(k: int, reward: float | None) -> None:
            state = _physics_state(data)
            bad = []
            for name in STATE_FIELDS:
                logged = physics_log[name][k]
                if state[name].shape != logged.shape:
                    bad.append(name)
                    result.max_abs_diff[name] = float("inf")
                    continue
                if state[name].tobytes() != logged.tobytes():
                    bad.append(name)
                    result.max_abs_diff[name] = max(result.max_abs_diff[name],
                                                    float(np.max(np.abs(state[name] - logged))))
            if reward is not None and float(reward) != rewards[k - 1]:
                bad.append("reward")
                result.max_abs_diff["reward"] = max(result.max_abs_diff["reward"], abs(float(reward) - rewards[k - 1]))
            if bad and result.mismatch_step is None:
                result.mismatch_step, result.mismatch_fields = k, bad

        compare(0, None)
        label = f"replay{' + video' if writer else ''}"
        overlay = None if writer is None else Overlay(info=dict(env.task.info))
        timestep = None
        for k in Progress(range(steps), desc=label, unit="step", disable=not progress):
            if writer:
                writer.add_frame(overlay)
            timestep = env.dm_env.step(actions[k])
            compare(k + 1, timestep.reward or 0.0)
            result.checked = k + 1
            if writer:
                overlay = Overlay(k + 1, timestep.reward or 0.0, overlay.episode_return + (timestep.reward or 0.0),
                                  dict(env.task.info))
        if writer:
            from mjdrive.record.summary import end_reason

            last = timestep is not None and timestep.last()
            terminated = last and timestep.discount == 0.0
            overlay.outcome = end_reason(overlay.info, terminated, last and not terminated) if last else "cut short"
            writer.add_frame(overlay)
            writer.close()
        return result
    finally:
        env.close()
