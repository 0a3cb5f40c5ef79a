"""N copies of a task stepped together: one physics call per control step, auto-reset, numpy or torch out.

    from mjdrive.envs.batched import BatchedEnv
    env = BatchedEnv("waypoints", "straight", num_envs=8, nthread=2)
    obs, info = env.reset(seed=0)                     # obs: {"waypoint_angles": (8,15), ...}
    obs, reward, terminated, truncated, info = env.step(actions)   # actions (8,3) or (8,) indices

Each copy is a `DrivingGymEnv` (own MjModel/MjData, own task and random stream). `task` may be a list of
tasks of one domain (e.g. the roundabout's four densities): copy i runs `task[i % len(task)]`; their observation
and action spaces must match. A step maps the actions, runs every copy's `DrivingGymEnv.before_physics`, advances
all physics (`backend`), then runs every copy's `DrivingGymEnv.after_physics` -- the two halves of the single
env's `step` (`DrivingEnvironment.step`), so the "threads" and "serial" backends give bit-identical episodes to
the single env.

Backends for the physics:
  "serial":  each copy's control step of physics (`Physics.advance`: the substep loop, `mjdrive.tasks.stepping`,
             with the task's work between chunks, e.g. the traffic) in turn (reference).
  "threads": the same, the copies in a thread pool of `nthread` (the loop's compiled chunks release the GIL).
  "rollout": `mujoco.rollout` over all copies, chunk by chunk (state in/out as arrays, ctrl and mocap as controls),
             each copy's work between chunks by the substep loop. The state is written back with `mj_setState` +
             `mj_forward`, so contacts are those of the final state and the solver warm start is not carried over:
             close to, but not bit-identical with, the others.

An episode that ends is reset at once; the returned observation is the new episode's first one and the
last observation of the ended episode is in `info["final_observation"]` (rows of the envs that did not
end hold their current observation, so `info["final_observation"]` is always the right "next obs" for a
replay buffer). `terminated` (task ended: collision, lane invasion, arrival, physics error) and `truncated`
(time limit) are kept apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np

from mjdrive.envs.gym_env import DrivingGymEnv, make_env
from mjdrive.record.recorder import EnvSpec, EpisodeRecorder

BACKENDS = ("serial", "threads", "rollout")
_CONTROL_SPEC = (mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS
                 | mujoco.mjtState.mjSTATE_MOCAP_QUAT)
_STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS


class BatchedEnv:
    """`num_envs` copies of `domain/task` behind one `step`; see the module docstring.

    `device=None` returns numpy arrays; a torch device ("cpu") returns torch tensors instead (obs, reward,
    terminated, truncated; info stays numpy). Seeds: copy i is reset with `seed + i`; later episodes follow
    each copy's own random stream, so a run is reproducible from its seed.
    `first_copy`: the index of copy 0 in a larger vector env split over workers (`mjdrive.envs.vector`); it
    names the copies' log folders (env_{first_copy + i}), so a split env writes the same files as a whole one.
    """

    def __init__(
        self,
        domain: str,
        task: str | Sequence[str],
        num_envs: int = 1,
        actions: str = "continuous",
        nthread: int = 1,
        backend: str = "threads",
        device: str | None = None,
        environment_kwargs: dict[str, Any] | None = None,
        record_dir: str | Path | None = None,
        first_copy: int = 0,
        **task_kwargs,
    ):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        tasks = [task] if isinstance(task, str) else list(task)
        if not tasks:
            raise ValueError("task must name at least one task")
        if backend == "rollout" and len(set(tasks)) > 1:
            raise ValueError(f"the rollout backend steps copies of one model; got several tasks {tasks} "
                             "(use backend='threads' or 'serial')")
        self.task_names = [tasks[i % len(tasks)] for i in range(num_envs)]  # the task of each copy
        self.task_ids = [f"{domain}/{name}" for name in self.task_names]  # as in final_info["task"]
        self.domain, self.task_name, self.actions = domain, tasks[0], actions
        self.task_kwargs = dict(task_kwargs)
        self.num_envs, self.nthread, self.backend, self.device = num_envs, max(1, nthread), backend, device
        self.envs: list[gym.Env] = [
            make_env(domain, name, actions=actions, environment_kwargs=environment_kwargs, **task_kwargs)
            for name in self.task_names
        ]
        self.bases: list[DrivingGymEnv] = [env.unwrapped for env in self.envs]
        self.single_observation_space: gym.spaces.Dict = self.envs[0].observation_space
        self.single_action_space: gym.Space = self.envs[0].action_space
        for name, env in zip(self.task_names, self.envs, strict=True):
            if env.observation_space != self.single_observation_space or env.action_space != self.single_action_space:
                raise ValueError(f"{domain}/{name} has other observation or action spaces than "
                                 f"{domain}/{tasks[0]}; a batch can mix only tasks whose spaces match")
        self.discrete = isinstance(self.single_action_space, gym.spaces.Discrete)
        self.wrapped_actions = isinstance(self.envs[0], gym.ActionWrapper)  # a table or "pedal"
        dm = self.bases[0].dm_env
        self.control_timestep = float(dm.control_timestep())  # [s]
        self.n_sub_steps = dm.n_sub_steps
        self.tick_steps = dm.tick_steps  # physics steps per control period
        self.max_episode_steps = dm.max_episode_steps
        self._models = [b.dm_env.physics.model.ptr for b in self.bases]
        self._datas = [b.dm_env.physics.data.ptr for b in self.bases]
        self._pool = ThreadPoolExecutor(self.nthread) if backend == "threads" and self.nthread > 1 else None
        self._rollout = None
        if backend == "rollout":
            from mujoco import rollout

            self._rollout = rollout.Rollout(nthread=self.nthread)
            self._scratch = [mujoco.MjData(self._models[0]) for _ in range(self.nthread)]
            model = self._models[0]
            self._state = np.empty((num_envs, mujoco.mj_stateSize(model, _STATE_SPEC)))
            self._control_size = mujoco.mj_stateSize(model, _CONTROL_SPEC)
            self._warmstart = np.empty((num_envs, model.nv))
        # One MCAP file per episode per copy, copy i into record_dir/env_{i:02d}/ (streams never mix).
        self.recorders: list[EpisodeRecorder] | None = None
        if record_dir is not None:
            self.recorders = [EpisodeRecorder(Path(record_dir) / f"env_{first_copy + i:02d}",
                                              EnvSpec(domain, name, self.task_kwargs, environment_kwargs))
                              for i, name in enumerate(self.task_names)]
        self._obs: list[dict[str, np.ndarray]] = []
        self.episode_returns = np.zeros(num_envs)
        self.episode_lengths = np.zeros(num_envs, np.int64)

    # --- gym-like API ---------------------------------------------------------------------------------
    def reset(self, seed: int | None = None) -> tuple[dict, dict]:
        """Reset every copy (copy i with `seed + i` when a seed is given)."""
        self._obs, infos = [], []
        for i in range(self.num_envs):
            obs, info = self._reset_copy(i, None if seed is None else seed + i)
            self._obs.append(obs)
            infos.append(info)
        self.episode_returns[:] = 0.0
        self.episode_lengths[:] = 0
        return self._out_obs(self._stack(self._obs)), {"infos": infos}

    def step(self, actions) -> tuple[dict, Any, Any, Any, dict]:
        """Step every copy with `actions` (num_envs, 3) or (num_envs,) indices; auto-resets ended episodes."""
        actions = self._to_numpy(actions)
        if len(actions) != self.num_envs:
            raise ValueError(f"expected {self.num_envs} actions, got {len(actions)}")
        n = self.num_envs
        rewards = np.zeros(n, np.float32)
        terminated, truncated = np.zeros(n, bool), np.zeros(n, bool)
        for i, base in enumerate(self.bases):
            base.before_physics(self._command(i, actions[i]))
        self.step_physics()
        final_obs: list[dict[str, np.ndarray]] = []
        final_info: list[dict | None] = [None] * n
        for i, base in enumerate(self.bases):
            obs, reward, term, trunc, step_info = base.after_physics()
            rewards[i], terminated[i], truncated[i] = reward, term, trunc
            self.episode_returns[i] += reward
            self.episode_lengths[i] += 1
            final_obs.append(obs)
            if self.recorders is not None:
                self.recorders[i].step(base.task, base.dm_env.physics, base.task.last_action, float(reward),
                                       terminated=bool(term), truncated=bool(trunc), observation=obs)
            if term or trunc:
                final_info[i] = {**step_info, "task": self.task_ids[i],
                                 "episode_return": float(self.episode_returns[i]),
                                 "episode_length": int(self.episode_lengths[i])}
                obs, _ = self._reset_copy(i)
                self.episode_returns[i], self.episode_lengths[i] = 0.0, 0
            self._obs[i] = obs
        done = terminated | truncated
        info = {"final_observation": self._stack(final_obs), "_final_observation": done,
                "final_info": final_info}
        return (self._out_obs(self._stack(self._obs)), self._out(rewards), self._out(terminated),
                self._out(truncated), info)

    def observations(self) -> dict | None:
        """The current observation of every copy (after the last reset or step); None before the first reset."""
        return self._out_obs(self._stack(self._obs)) if self._obs else None

    def close(self) -> None:
        for recorder in self.recorders or ():
            recorder.close()
        for env in self.envs:
            env.close()
        if self._pool is not None:
            self._pool.shutdown()
        if self._rollout is not None:
            self._rollout.close()

    # --- internals ------------------------------------------------------------------------------------
    def _reset_copy(self, i: int, seed: int | None = None) -> tuple[dict, dict]:
        """Reset copy i; with recording on, open its next episode file (with the RNG state for replay)."""
        base = self.bases[i]
        if self.recorders is None:
            return self.envs[i].reset(seed=seed)
        if seed is not None:
            base.task.seed(seed)
        rng_state = base.task.random.get_state()
        obs, info = self.envs[i].reset(seed=seed)
        self.recorders[i].begin(base.task, base.dm_env.physics, seed=seed, rng_state=rng_state)
        return obs, info

    def _command(self, i: int, action):
        """The (throttle, steer, brake) command of copy i: through its action wrapper, if any."""
        return self.envs[i].action(action) if self.wrapped_actions else action

    def step_physics(self) -> None:
        """Advance every copy's physics one env step (between the copies' `before_physics` and `after_physics`):
        per control period, each copy's `before_tick` first, then the period's physics with each copy's work
        between chunks as in `Physics.advance`."""
        physics = [base.dm_env.physics for base in self.bases]
        n_sub = self.tick_steps
        for k in range(self.bases[0].task.control_ticks):
            for base in self.bases:
                base.dm_env.before_tick(k)
            if self.backend == "rollout":
                chunk = physics[0].substeps.chunk
                for start in range(0, n_sub, chunk):
                    n = min(chunk, n_sub - start)
                    self._rollout_all(n)
                    for p in physics:
                        p.substeps.between_chunks(p, n)
            elif self._pool is not None:
                list(self._pool.map(lambda p: p.advance(n_sub), physics))
            else:
                for p in physics:
                    p.advance(n_sub)

    def _rollout_all(self, n_sub: int) -> None:
        """`n_sub` physics steps of every copy in one `mujoco.rollout` call."""
        control = np.empty((self.num_envs, n_sub, self._control_size))
        states = np.empty((self.num_envs, n_sub, self._state.shape[1]))
        for i, (m, d) in enumerate(zip(self._models, self._datas, strict=True)):
            mujoco.mj_getState(m, d, self._state[i], _STATE_SPEC)
            mujoco.mj_getState(m, d, control[i, 0], _CONTROL_SPEC)
            control[i, 1:] = control[i, 0]  # ctrl and mocap held over the chunk
            self._warmstart[i] = d.qacc_warmstart
        self._rollout.rollout(self._models, self._scratch, self._state, control, control_spec=_CONTROL_SPEC,
                              nstep=n_sub, initial_warmstart=self._warmstart, state=states, skip_checks=True)
        for i, (m, d) in enumerate(zip(self._models, self._datas, strict=True)):
            mujoco.mj_setState(m, d, states[i, -1], _STATE_SPEC)
            mujoco.mj_forward(m, d)

    def _stack(self, observations: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        return {key: np.stack([obs[key] for obs in observations]) for key in self.single_observation_space}

    def _to_numpy(self, actions) -> np.ndarray:
        if hasattr(actions, "detach"):
            actions = actions.detach().cpu().numpy()
        return np.asarray(actions)

    def _out(self, array: np.ndarray):
        if self.device is None:
            return array
        import torch

        return torch.as_tensor(array, device=self.device)

    def _out_obs(self, obs: dict[str, np.ndarray]) -> dict:
        return obs if self.device is None else {key: self._out(value) for key, value in obs.items()}


# --- a flat, learner-facing view of the observation ----------------------------------------------------

# Fixed scales that bring the tasks' observations (in the studies' units) to O(1) for the networks.
FEATURE_SCALES: dict[str, float] = {
    "waypoint_angles": 1 / 90.0,  # [deg]
    "heading_error": 1 / 90.0,  # [deg]
    "speed": 1 / 30.0,  # [km/h]
    "lane_offset": 1 / 2.0,  # [m]
    "waypoint_distance": 1 / 10.0,  # [m]
    "destination": 1 / 30.0,  # [m]
}


def is_image_space(space: gym.Space) -> bool:
    return isinstance(space, gym.spaces.Box) and space.dtype == np.uint8 and len(space.shape) == 3


class ObservationLayout:
    """Splits a dict observation into one float feature vector (scaled, keys in the space's order) and at
    most one uint8 image in (C, H, W) order (an (H, W, C) image with C <= 4 is transposed)."""

    def __init__(self, space: gym.spaces.Dict, scales: dict[str, float] | None = None):
        self.scales = {**FEATURE_SCALES, **(scales or {})}
        images = [key for key, sub in space.spaces.items() if is_image_space(sub)]
        if len(images) > 1:
            raise ValueError(f"at most one image observation is supported, got {images}")
        self.image_key = images[0] if images else None
        self.feature_keys = [key for key in space.spaces if key != self.image_key]
        self.feature_sizes = [int(np.prod(space[key].shape)) for key in self.feature_keys]  # flat, in order
        self.feature_dim = sum(self.feature_sizes)
        self.image_shape: tuple[int, int, int] | None = None
        self._transpose = False
        if self.image_key is not None:
            shape = space[self.image_key].shape
            self._transpose = shape[-1] <= 4 < shape[0]
            self.image_shape = (shape[2], shape[0], shape[1]) if self._transpose else tuple(shape)

    def features(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """(N, feature_dim) float32 from batched observations."""
        if not self.feature_keys:
            n = len(next(iter(obs.values())))
            return np.zeros((n, 0), np.float32)
        parts = [np.asarray(obs[k], np.float32).reshape(len(obs[k]), -1) * self.scales.get(k, 1.0)
                 for k in self.feature_keys]
        return np.concatenate(parts, axis=1)

    def image(self, obs: dict[str, np.ndarray]) -> np.ndarray | None:
        """(N, C, H, W) uint8 from batched observations, or None without an image."""
        if self.image_key is None:
            return None
        image = np.asarray(obs[self.image_key])
        return np.ascontiguousarray(image.transpose(0, 3, 1, 2)) if self._transpose else image

    def describe(self) -> dict[str, Any]:
        return {"feature_keys": self.feature_keys, "feature_dim": self.feature_dim,
                "image_key": self.image_key, "image_shape": self.image_shape}
