"""One vector-env boundary, three backends: the copies in this process, in worker processes, or in Ray actors.

    from mjdrive.envs.vector import make_vec_env
    env = make_vec_env("waypoints", "straight", num_envs=8)                  # in process (BatchedEnv)
    env = make_vec_env("waypoints", "straight", num_envs=8, workers=2)       # 2 processes x 4 copies
    env = make_vec_env("waypoints", "straight", num_envs=8, workers=4, ray="local")  # 4 Ray actors x 2 copies
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(actions)   # (8, ...) numpy batches, auto-reset

Every backend has the `VecEnv` interface of `BatchedEnv` (reset, step, observations, close, num_envs,
single_observation_space, single_action_space, ...) and gives the same episodes: worker w holds copies
[w K, (w + 1) K) as a `BatchedEnv` of K = num_envs / workers copies (serial physics), copy i is reset with
`seed + i` and runs task i of the task list whatever the worker count, and `info["final_info"]` holds plain
scalars. Learners read only the observation arrays, rewards, flags and `final_observation`/`final_info`.

- `SubprocessVecEnv`: gymnasium's `AsyncVectorEnv` over worker processes (forkserver context on Linux, spawn
  elsewhere), observations in shared memory. Each worker builds its copies, and so its GL contexts (EGL or
  OSMesa, `MUJOCO_GL`), inside itself, with torch, OpenMP and llvmpipe pinned to one thread (`pin_threads`).
  With no more workers than CPUs this process may run on, worker w runs on the w-th of them only
  (`worker_cpus`): the step of a batch waits for its slowest worker, and two workers the scheduler put on one
  core would take turns there.
  A sub-env of the `AsyncVectorEnv` is a `ChunkEnv`: K copies whose step returns (K,) rewards and flags and
  resets its own ended copies (autoreset "disabled" at the `AsyncVectorEnv` level).
- `RayVecEnv` (`pip install mjdrive[ray]`): one Ray actor per worker, each holding K copies and stepping them
  on numpy batches; the actors may live on any node of a cluster.

A worker that dies (killed, out of memory) raises `WorkerDied` at the next step, after the other workers have
been stopped; a training run cannot go on without it (its copies' state is lost), so there is no restart here.
Evaluation, whose episodes are independent, reruns them elsewhere (`mjdrive.envs.fanout`).
"""

from __future__ import annotations

import importlib.util
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import gymnasium as gym
import numpy as np

# one thread per worker: OpenMP and MKL (torch, numpy), OpenBLAS, llvmpipe (Mesa's software GL under EGL and OSMesa)
WORKER_THREAD_VARS = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
                      "LP_NUM_THREADS": "1"}
REWARD_DTYPE = np.float32  # as BatchedEnv's (AsyncVectorEnv hands float64 on; float32 values survive exactly)
DEATH_REPORT_WAIT = 2.0  # [s] to learn which worker died, for the error message
RAY_MISSING = "the Ray backend needs Ray: pip install 'mjdrive[ray]'"


class WorkerDied(RuntimeError):
    """A worker process or actor of a vector env died; the env is closed."""


class VecEnv(Protocol):
    """The boundary every learner steps: N copies, numpy batches, auto-reset, final observations and infos."""

    num_envs: int
    single_observation_space: gym.spaces.Dict
    single_action_space: gym.Space
    discrete: bool
    domain: str
    task_name: str
    task_kwargs: dict[str, Any]
    max_episode_steps: int | None
    control_timestep: float  # [s]

    def reset(self, seed: int | None = None) -> tuple[dict, dict]: ...

    def step(self, actions) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]: ...

    def observations(self) -> dict | None: ...

    def close(self) -> None: ...


def worker_cpus(workers: int) -> list[int | None]:
    """The CPU each of `workers` vector-env workers is pinned to: the w-th of the CPUs this process may run on,
    or None for all when there are more workers than those CPUs (or no affinity to read: not Linux).

    Unpinned, the scheduler often wakes both workers of a 2-core machine on the same core and moves one only
    after a while: on the 2-core machine a 2-worker batch of PPO's 16 waypoint copies took 7.0-7.4 ms unpinned
    (the second worker started 1-1.3 ms late on average), 5.6-5.7 ms pinned. This process stays unpinned: it
    acts while the workers wait."""
    if not hasattr(os, "sched_getaffinity"):
        return [None] * workers
    cpus = sorted(os.sched_getaffinity(0))
    return list(cpus[:workers]) if workers <= len(cpus) else [None] * workers


def pin_cpu(cpu: int | None) -> None:
    """Run this process on `cpu` only (None, or a CPU this process may not use: leave it as it is)."""
    if cpu is None:
        return
    try:
        os.sched_setaffinity(0, {cpu})
    except OSError:  # not in this process's cpuset (a forkserver started under another affinity)
        pass


def pin_threads() -> None:
    """One compute thread in this process (call in a worker before it renders or runs torch)."""
    os.environ.update(WORKER_THREAD_VARS)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


# imported once by the forkserver, so that each worker forks with them loaded (torch and its compiler stack, which
# torch.optim pulls in, take seconds to import; `mjdrive.envs.preload`: what a worker would otherwise load at its
# first episode, stalling every step of the batch there); nothing that opens a GL display (dm_control's EGL
# backend does at import): every worker initialises its own
FORKSERVER_PRELOAD = ("numpy", "gymnasium", "torch", "torch._dynamo", "mjdrive.envs.preload")


def exit_with_parent(pid: int, period: float = 1.0) -> None:
    """In a worker: exit as soon as process `pid` (the parent that started the workers) is gone, even if it was
    killed with SIGKILL. A forkserver's worker is not the parent's child and may block on a queue whose writer
    it holds itself, so it would not notice otherwise. `period` [s] between checks."""
    def watch() -> None:
        while True:
            time.sleep(period)
            try:
                os.kill(pid, 0)
                with open(f"/proc/{pid}/stat") as stat:  # a zombie is gone too
                    if stat.read().rsplit(")", 1)[1].split()[0] == "Z":
                        os._exit(1)
            except (ProcessLookupError, FileNotFoundError):
                os._exit(1)
            except (PermissionError, OSError):
                continue

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def default_context() -> str:
    """forkserver on Linux (workers fork from a clean server: no GL or torch state of the parent), else spawn."""
    return "forkserver" if sys.platform.startswith("linux") else "spawn"


def worker_context(name: str | None = None):
    """The multiprocessing context of the workers (`default_context()` unless named); a forkserver preloads
    `FORKSERVER_PRELOAD` (when installed; it takes effect where the server has not started yet)."""
    ctx = multiprocessing.get_context(name or default_context())
    if ctx.get_start_method() == "forkserver":
        ctx.set_forkserver_preload(["__main__", *(m for m in FORKSERVER_PRELOAD if importlib.util.find_spec(m))])
    return ctx


@dataclass(frozen=True)
class CopySpec:
    """What a worker needs to build its copies (picklable): the domain, the task of every copy and their settings."""

    domain: str
    tasks: tuple[str, ...]  # the task of each copy
    actions: str = "continuous"
    task_kwargs: dict[str, Any] = field(default_factory=dict)
    environment_kwargs: dict[str, Any] | None = None
    backend: str = "threads"
    record_dir: str | None = None

    @property
    def num_envs(self) -> int:
        return len(self.tasks)

    def build(self, start: int = 0, count: int | None = None, nthread: int = 1, device: str | None = None):
        """A `BatchedEnv` of copies start .. start + count - 1."""
        from mjdrive.envs.batched import BatchedEnv

        count = self.num_envs - start if count is None else count
        return BatchedEnv(self.domain, list(self.tasks[start:start + count]), num_envs=count, actions=self.actions,
                          nthread=nthread, backend=self.backend, device=device,
                          environment_kwargs=self.environment_kwargs, record_dir=self.record_dir,
                          first_copy=start, **self.task_kwargs)


def chunk_spaces(observation_space: gym.spaces.Dict, action_space: gym.Space,
                 k: int) -> tuple[gym.spaces.Dict, gym.Space]:
    """The spaces of K copies as one env: every observation (K, ...), actions (K, ...) or K indices."""
    observations = gym.spaces.Dict({
        key: gym.spaces.Box(np.broadcast_to(sub.low, (k, *sub.shape)), np.broadcast_to(sub.high, (k, *sub.shape)),
                            (k, *sub.shape), sub.dtype)
        for key, sub in observation_space.spaces.items()})
    if isinstance(action_space, gym.spaces.Discrete):
        return observations, gym.spaces.MultiDiscrete(np.full(k, action_space.n))
    return observations, gym.spaces.Box(np.broadcast_to(action_space.low, (k, *action_space.shape)),
                                        np.broadcast_to(action_space.high, (k, *action_space.shape)),
                                        (k, *action_space.shape), action_space.dtype)


def split_step(info: dict, done: np.ndarray, obs: dict[str, np.ndarray]) -> tuple[dict[int, dict], list]:
    """A chunk's step info as (final observation of each ended copy by row, final_info list)."""
    final = info["final_observation"]
    rows = {int(i): {key: np.asarray(final[key][i]) for key in obs} for i in np.flatnonzero(done)}
    return rows, list(info["final_info"])


class ChunkEnv(gym.Env):
    """K copies (a `BatchedEnv`) as one gymnasium env, for `AsyncVectorEnv`: observations (K, ...) in shared
    memory, step -> (obs, (K,) rewards, (K,) terminated, (K,) truncated, {"chunk": (final rows, final_info)}).
    It resets its ended copies itself."""

    def __init__(self, spec: CopySpec, start: int, count: int, parent_pid: int | None = None,
                 cpu: int | None = None):
        pin_threads()  # before any GL context (created at the first render) or torch op in this process
        pin_cpu(cpu)  # before the GL context too: llvmpipe's threads inherit the affinity
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's: it closes the workers in order
        if parent_pid is not None:
            exit_with_parent(parent_pid)
        self.env = spec.build(start, count)
        self.observation_space, self.action_space = chunk_spaces(
            self.env.single_observation_space, self.env.single_action_space, count)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, _ = self.env.reset(seed=seed)
        return obs, {}

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        return obs, reward, terminated, truncated, {"chunk": split_step(info, terminated | truncated, obs)}

    def close(self) -> None:
        self.env.close()


class _SpacesOnly(gym.Env):
    """What `AsyncVectorEnv` builds in the parent only to read the spaces: the spaces, no task."""

    def __init__(self, observation_space: gym.spaces.Dict, action_space: gym.Space):
        self.observation_space, self.action_space = observation_space, action_space


class ChunkFactory:
    """Builds worker w's `ChunkEnv` in the worker; called in the process that made it, it returns the spaces
    only (gymnasium's `AsyncVectorEnv` calls its first factory in the parent to read them)."""

    def __init__(self, spec: CopySpec, start: int, count: int, spaces: tuple[gym.spaces.Dict, gym.Space],
                 cpu: int | None = None):
        self.spec, self.start, self.count, self.spaces, self.cpu = spec, start, count, spaces, cpu
        self.parent_pid = os.getpid()

    def __call__(self) -> gym.Env:
        if os.getpid() == self.parent_pid:
            return _SpacesOnly(*self.spaces)
        return ChunkEnv(self.spec, self.start, self.count, self.parent_pid, self.cpu)


class _ChunkedVecEnv:
    """The part of the worker backends that is not transport: spaces, seeds, merging the chunks' results."""

    def __init__(self, spec: CopySpec, workers: int):
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if spec.num_envs % workers:
            raise ValueError(f"{spec.num_envs} env copies do not split evenly over {workers} workers; make the "
                             f"number of copies (num_envs, --num-envs) a multiple of the workers")
        self.spec, self.workers = spec, workers
        self.num_envs, self.k = spec.num_envs, spec.num_envs // workers
        self.domain, self.task_name, self.actions = spec.domain, spec.tasks[0], spec.actions
        self.task_names = list(spec.tasks)
        self.task_ids = [f"{spec.domain}/{name}" for name in spec.tasks]
        self.task_kwargs = dict(spec.task_kwargs)
        probe = spec.build(0, 1)  # one copy here: the spaces and the episode limits, no worker needed
        try:
            self.single_observation_space: gym.spaces.Dict = probe.single_observation_space
            self.single_action_space: gym.Space = probe.single_action_space
            self.discrete, self.control_timestep = probe.discrete, probe.control_timestep
            self.max_episode_steps = probe.max_episode_steps
        finally:
            probe.close()
        self._obs: dict[str, np.ndarray] | None = None

    def observations(self) -> dict | None:
        """The current observation of every copy (after the last reset or step); None before the first reset."""
        return None if self._obs is None else {key: value.copy() for key, value in self._obs.items()}

    def _chunk_actions(self, actions) -> np.ndarray:
        if hasattr(actions, "detach"):
            actions = actions.detach().cpu().numpy()
        actions = np.asarray(actions)
        return actions.reshape(self.workers, self.k, *actions.shape[1:])

    def _flat(self, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {key: np.asarray(value).reshape(self.num_envs, *np.shape(value)[2:]) for key, value in obs.items()}

    def _merge(self, obs: dict[str, np.ndarray], reward, terminated, truncated,
               chunks: Sequence[tuple[dict[int, dict], list]]) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
        """(workers, K, ...) results -> the (num_envs, ...) step of a `BatchedEnv`."""
        self._obs = self._flat(obs)
        final_obs = {key: value.copy() for key, value in self._obs.items()}
        final_info: list[dict | None] = []
        for w, (rows, infos) in enumerate(chunks):
            for row, values in rows.items():
                for key, value in values.items():
                    final_obs[key][w * self.k + row] = value
            final_info.extend(infos)
        terminated = np.asarray(terminated, bool).reshape(self.num_envs)
        truncated = np.asarray(truncated, bool).reshape(self.num_envs)
        info = {"final_observation": final_obs, "_final_observation": terminated | truncated,
                "final_info": final_info}
        return (self.observations(), np.asarray(reward, REWARD_DTYPE).reshape(self.num_envs), terminated, truncated,
                info)

    def _seeds(self, seed: int | None) -> list[int | None]:
        return [None if seed is None else seed + w * self.k for w in range(self.workers)]


class SubprocessVecEnv(_ChunkedVecEnv):
    """`num_envs` copies over `workers` processes (gymnasium `AsyncVectorEnv`, shared-memory observations);
    `pin`: each worker on its own CPU where there are enough (`worker_cpus`)."""

    def __init__(self, spec: CopySpec, workers: int, context: str | None = None, timeout: float | None = None,
                 pin: bool = True):
        super().__init__(spec, workers)
        from gymnasium.vector import AsyncVectorEnv

        spaces = chunk_spaces(self.single_observation_space, self.single_action_space, self.k)
        self.timeout = timeout  # [s] for one step of every worker; None waits forever
        self.cpus = worker_cpus(workers) if pin else [None] * workers  # each worker's CPU (None: any)
        factories = [ChunkFactory(spec, w * self.k, self.k, spaces, cpu) for w, cpu in enumerate(self.cpus)]
        self.vec = AsyncVectorEnv(factories,
                                  shared_memory=True, copy=False, context=worker_context(context).get_start_method(),
                                  daemon=True, autoreset_mode="Disabled")

    @property
    def pids(self) -> list[int]:
        """The worker processes' ids."""
        return [process.pid for process in self.vec.processes]

    def reset(self, seed: int | None = None) -> tuple[dict, dict]:
        """Reset every copy (copy i with `seed + i` when a seed is given)."""
        try:
            obs, _ = self.vec.reset(seed=self._seeds(seed))
        except (EOFError, ConnectionError) as error:
            self._died(error)
        self._obs = self._flat(obs)
        return self.observations(), {}

    def step(self, actions) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
        """Step every copy with `actions` (num_envs, ...); auto-resets ended episodes (see `BatchedEnv.step`)."""
        try:
            self.vec.step_async(self._chunk_actions(actions))
            obs, reward, terminated, truncated, info = self.vec.step_wait(self.timeout)
        except (EOFError, ConnectionError) as error:
            self._died(error)
        return self._merge(obs, reward, terminated, truncated, list(info["chunk"]))

    def _died(self, error: Exception):
        deadline = time.monotonic() + DEATH_REPORT_WAIT
        while all(p.is_alive() for p in self.vec.processes) and time.monotonic() < deadline:
            time.sleep(0.05)  # the pipe broke a moment before the process is known to be gone
        dead = [f"worker {w} (pid {p.pid}, exit code {p.exitcode})" for w, p in enumerate(self.vec.processes)
                if not p.is_alive()]
        self.close(terminate=True)
        raise WorkerDied(f"{', '.join(dead) or 'a worker'} died ({type(error).__name__}); the vector env is "
                         "closed") from error

    def close(self, terminate: bool = False) -> None:
        """Close the workers (each closes its copies and finishes their open logs); `terminate`: stop them now."""
        if self.vec.closed:
            return
        if not terminate and all(p.is_alive() for p in self.vec.processes):
            self.vec.close()
            return
        # AsyncVectorEnv would first wait for a pending step's answers, and a dead worker's pipe raises EOFError
        # there: drop the pending call, then terminate
        from gymnasium.vector.async_vector_env import AsyncState

        self.vec._state = AsyncState.DEFAULT
        self.vec.close(terminate=True)


class _ChunkWorker:
    """A Ray actor's state: K copies as a `BatchedEnv`, stepped on numpy batches."""

    def __init__(self, spec: CopySpec, start: int, count: int):
        pin_threads()
        self.env = spec.build(start, count)

    def reset(self, seed: int | None) -> dict:
        return self.env.reset(seed=seed)[0]

    def step(self, actions: np.ndarray) -> tuple:
        obs, reward, terminated, truncated, info = self.env.step(actions)
        return obs, reward, terminated, truncated, split_step(info, terminated | truncated, obs)

    def pid(self) -> int:
        return os.getpid()

    def close(self) -> None:
        self.env.close()


def ray_module():
    """`ray`, or ImportError telling how to install it."""
    try:
        import ray
    except ImportError as error:
        raise ImportError(RAY_MISSING) from error
    return ray


def ray_connect(address: str | None, num_cpus: int | None = None) -> bool:
    """Connect to Ray: `address` "local" (or None) starts a private cluster of `num_cpus` CPUs in this process,
    "auto" joins the cluster started on this machine (`ray start --head`), HOST:PORT or ray://HOST:PORT a remote
    one. Returns whether this call started Ray (and its caller should shut it down)."""
    ray = ray_module()
    if ray.is_initialized():
        return False
    env_vars = {**WORKER_THREAD_VARS, **{k: os.environ[k] for k in ("MUJOCO_GL", "PYOPENGL_PLATFORM")
                                         if k in os.environ}}
    runtime_env = {"env_vars": env_vars}
    if address in (None, "local"):
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False, runtime_env=runtime_env)
    else:
        ray.init(address=address, log_to_driver=False, runtime_env=runtime_env)
    return True


class RayVecEnv(_ChunkedVecEnv):
    """`num_envs` copies over `workers` Ray actors of K copies each (see `ray_connect` for `address`)."""

    def __init__(self, spec: CopySpec, workers: int, address: str | None = "local"):
        super().__init__(spec, workers)
        ray = ray_module()
        self._ray = ray
        self._owns_ray = ray_connect(address, num_cpus=workers)
        actor = ray.remote(num_cpus=1, max_restarts=0)(_ChunkWorker)
        self.actors = [actor.remote(spec, w * self.k, self.k) for w in range(workers)]
        self._closed = False

    def _get(self, refs: list) -> list:
        try:
            return self._ray.get(refs)
        except self._ray.exceptions.RayActorError as error:
            self.close()
            raise WorkerDied(f"a Ray actor of the vector env died ({error}); the vector env is closed") from error

    @property
    def pids(self) -> list[int]:
        return self._get([a.pid.remote() for a in self.actors])

    def reset(self, seed: int | None = None) -> tuple[dict, dict]:
        chunks = self._get([a.reset.remote(s) for a, s in zip(self.actors, self._seeds(seed), strict=True)])
        self._obs = self._flat({key: np.stack([c[key] for c in chunks]) for key in chunks[0]})
        return self.observations(), {}

    def step(self, actions) -> tuple[dict, np.ndarray, np.ndarray, np.ndarray, dict]:
        chunks = self._get([a.step.remote(act) for a, act in zip(self.actors, self._chunk_actions(actions),
                                                                  strict=True)])
        obs = {key: np.stack([c[0][key] for c in chunks]) for key in chunks[0][0]}
        return self._merge(obs, *(np.stack([c[i] for c in chunks]) for i in (1, 2, 3)), [c[4] for c in chunks])

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        closing = [actor.close.remote() for actor in self.actors]  # finish the copies' open logs
        self._ray.wait(closing, num_returns=len(closing), timeout=30)
        for actor in self.actors:
            self._ray.kill(actor)
        if self._owns_ray:
            self._ray.shutdown()


def make_vec_env(domain: str, task: str | Sequence[str], num_envs: int = 1, actions: str = "continuous",
                 workers: int = 0, ray: str | None = None, nthread: int = 1, backend: str = "threads",
                 device: str | None = None, environment_kwargs: dict[str, Any] | None = None,
                 record_dir: str | None = None, context: str | None = None, **task_kwargs) -> VecEnv:
    """`num_envs` copies of `domain/task` (a list: copy i runs task[i % len]) behind the one boundary:
    `workers=0` in this process (a `BatchedEnv` with `nthread` physics threads), `workers=N` over N processes,
    and with `ray` (an address, or "local") over N Ray actors. `device` (torch tensors out) only in process."""
    tasks = [task] if isinstance(task, str) else list(task)
    if not tasks:
        raise ValueError("task must name at least one task")
    spec = CopySpec(domain, tuple(tasks[i % len(tasks)] for i in range(num_envs)), actions, dict(task_kwargs),
                    environment_kwargs, backend, None if record_dir is None else str(record_dir))
    if workers < 0:
        raise ValueError(f"workers must be >= 0, got {workers}")
    if device is not None and (workers or ray):
        raise ValueError("device (torch tensors out) is only for the in-process env; convert at the adapter")
    if ray is not None:
        return RayVecEnv(spec, workers or 1, ray)
    if workers:
        return SubprocessVecEnv(spec, workers, context)
    return spec.build(0, num_envs, nthread=nthread, device=device)

