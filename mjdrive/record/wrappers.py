"""Recording wrappers: `RecordEpisodes` for gymnasium envs (DrivingGymEnv and any wrapper stack over it),
`RecordedEnvironment` for dm_control envs from `suite.load`, and `load(...)` = suite.load + recording.

Both take the task's RNG state just before each reset, so `mjdrive replay` can rebuild the episode whether
or not a seed was passed to reset, and both hand each step's observation to the recorder, which logs the
extra sensors in it (task keyword `sensors`: /sensors/depth, /sensors/segmentation, /sensors/range).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import dm_env
import gymnasium as gym

from mjdrive.record.recorder import EnvSpec, EpisodeRecorder, RecordOptions


class RecordEpisodes(gym.Wrapper):
    """Writes one MCAP file per episode of a gymnasium driving env into `out_dir`.

    Put it anywhere over a DrivingGymEnv: it logs the continuous (throttle, steer, brake) the task applied
    (`task.last_action`), so discrete-action wrappers below or above it make no difference.
    `recorder.paths` lists the finished files; `close()` finishes an open episode (marked interrupted).
    """

    def __init__(self, env: gym.Env, out_dir: str | Path, options: RecordOptions | None = None,
                 first_episode: int = 0):
        super().__init__(env)
        base = env.unwrapped
        if not hasattr(base, "task") or not hasattr(base, "dm_env"):
            raise TypeError(f"RecordEpisodes needs a DrivingGymEnv underneath, got {type(base).__name__}")
        spec = EnvSpec(base.domain, base.task_name, dict(base.task_kwargs),
                       getattr(base, "environment_kwargs", None))
        self.recorder = EpisodeRecorder(out_dir, spec, options, first_episode)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        base = self.env.unwrapped
        if seed is not None:
            base.task.seed(seed)  # the env reseeds the same way: the state below is the episode's
        rng_state = base.task.random.get_state()
        observation, info = self.env.reset(seed=seed, options=options)
        self.recorder.begin(base.task, base.dm_env.physics, seed=seed, rng_state=rng_state)
        return observation, info

    def step(self, action):
        observation, reward, terminated, truncated, info = self.env.step(action)
        base = self.env.unwrapped
        if self.recorder.recording:
            path = self.recorder.step(base.task, base.dm_env.physics, base.task.last_action, reward,
                                      terminated=terminated, truncated=truncated, observation=observation)
            if path is not None:
                info = {**info, "record_path": str(path)}
        return observation, reward, terminated, truncated, info

    def close(self) -> None:
        self.recorder.close()
        super().close()


class RecordedEnvironment(dm_env.Environment):
    """A dm_control driving env that writes one MCAP file per episode; everything else passes through."""

    def __init__(self, env, spec: EnvSpec, out_dir: str | Path, options: RecordOptions | None = None,
                 first_episode: int = 0):
        self._env = env
        self.recorder = EpisodeRecorder(out_dir, spec, options, first_episode)
        # dm_control seeds a task once (task kwarg `random`); its episodes k = 0, 1, ... continue that RNG, so
        # a log names that seed and its episode index (replay restores the RNG state taken at each reset)
        random = spec.task_kwargs.get("random")
        self._seed = random if isinstance(random, int) and not isinstance(random, bool) else None

    def __getattr__(self, name: str) -> Any:  # physics, task, control_timestep, ...
        return getattr(self._env, name)

    def reset(self) -> dm_env.TimeStep:
        rng_state = self._env.task.random.get_state()
        timestep = self._env.reset()
        self.recorder.begin(self._env.task, self._env.physics, seed=self._seed, rng_state=rng_state)
        return timestep

    def step(self, action) -> dm_env.TimeStep:
        if getattr(self._env, "episode_over", False):
            return self.reset()
        timestep = self._env.step(action)
        if self.recorder.recording:
            last = timestep.last()
            terminated = last and timestep.discount == 0.0
            self.recorder.step(self._env.task, self._env.physics, self._env.task.last_action,
                               timestep.reward or 0.0, terminated=terminated, truncated=last and not terminated,
                               observation=timestep.observation)
        return timestep

    def action_spec(self):
        return self._env.action_spec()

    def observation_spec(self):
        return self._env.observation_spec()

    def close(self) -> None:
        self.recorder.close()
        self._env.close()


def load(domain: str, task: str, task_kwargs: dict[str, Any] | None = None,
         environment_kwargs: dict[str, Any] | None = None, *, out_dir: str | Path,
         options: RecordOptions | None = None) -> RecordedEnvironment:
    """`suite.load(...)` whose episodes are recorded into `out_dir`."""
    from mjdrive import suite

    env = suite.load(domain, task, task_kwargs, environment_kwargs)
    spec = EnvSpec(domain, task, dict(task_kwargs or {}), environment_kwargs)
    return RecordedEnvironment(env, spec, out_dir, options)
