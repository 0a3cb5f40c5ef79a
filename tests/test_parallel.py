"""Scale-out: the vector env's backends (in process, worker processes, Ray actors) step the same episodes, an
evaluation gives the same rows and MCAP logs at 1, 2 and 4 workers and on Ray, a killed worker's episodes run
again elsewhere, Ctrl-C leaves no process behind, and training with workers learns from the same episodes."""

from __future__ import annotations

import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from mjdrive.agents.config import apply_overrides, load_config
from mjdrive.agents.evaluate import evaluate
from mjdrive.agents.train import train
from mjdrive.envs.vector import RayVecEnv, SubprocessVecEnv, WorkerDied, make_vec_env, worker_cpus
from mjdrive.record import proto
from mjdrive.record.reader import read_episode

ROOT = Path(__file__).resolve().parents[1]
CHECKPOINT = ROOT / "results" / "checkpoints" / "sac_features_roundabout.pt"  # features, traffic, pedal actions
SHORT = {"time_limit": 4.0}  # [s]: 20 control steps, so episodes end and auto-reset within a few dozen steps
VOLATILE_METADATA = ("start_time_ns", "pid", "host")  # wall clock and process of the writer


@pytest.fixture(scope="module")
def ray_session():
    """One local Ray of 2 CPUs for the module (the backends join it and leave it running)."""
    import ray  # `make test` installs the ray extra for this test

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
             runtime_env={"env_vars": {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}})
    yield "local"
    ray.shutdown()


def _descendants() -> set[int]:
    """Pids of every process below this one (workers of a forkserver are its children, not ours)."""
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        parents[int(stat.parent.name)] = int(fields[1])
    found, frontier = set(), {os.getpid()}
    while frontier:
        frontier = {pid for pid, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return "forkserver import main (exited)"


def _episode_contents(path: Path) -> dict:
    """An MCAP episode's metadata and messages with the wall-clock parts taken out (log times, protobuf
    timestamps, the writer's pid and host)."""
    episode = read_episode(path)
    assert episode.complete, path
    topics = {}
    for topic in sorted(episode.topics):
        name, encoding, data = episode.schemas[topic]
        if encoding == "protobuf":
            messages = []
            for _, payload in episode.messages[topic]:
                message = proto.decode(name, data, payload)
                _clear_timestamps(message)
                messages.append(message.SerializeToString(deterministic=True))
        else:
            messages = [payload for _, payload in episode.messages[topic]]
        topics[topic] = messages
    metadata = {k: v for k, v in episode.metadata.items() if k not in VOLATILE_METADATA}
    return {"metadata": metadata, "summary": episode.summary, "topics": topics}


def _clear_timestamps(message) -> None:
    for field, value in message.ListFields():
        if field.name == "timestamp":
            message.ClearField(field.name)
        elif field.message_type is not None:
            for item in ([value] if hasattr(value, "ListFields") else value):  # a message or a repeated one
                _clear_timestamps(item)


def _logs(folder: Path) -> dict[str, dict]:
    files = sorted(folder.rglob("*.mcap"))
    assert files and not list(folder.rglob("*.part")), folder
    return {str(path.relative_to(folder)): _episode_contents(path) for path in files}


def _assert_same(a, b, path: str = "") -> None:
    """Equal values, dtypes and keys, recursively (numpy arrays bit for bit)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and list(a) == list(b), path
        for key in a:
            _assert_same(a[key], b[key], f"{path}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray) and a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True), path
    else:
        assert type(a) is type(b) and (a == b or (a != a and b != b)), f"{path}: {a!r} != {b!r}"


def _rollout(env, steps: int = 45) -> list:
    """Reset with seed 3 and step with seeded random pedal actions; everything the learners read."""
    rng = np.random.default_rng(0)
    out = [env.reset(seed=3)[0]]
    space = env.single_action_space
    for _ in range(steps):
        actions = rng.uniform(space.low, space.high, (env.num_envs, *space.shape)).astype(space.dtype)
        obs, reward, terminated, truncated, info = env.step(actions)
        out.append([obs, reward, terminated, truncated, info["final_observation"], info["final_info"]])
    env.close()
    return out


def test_vector_backends_step_bit_identical_episodes(tmp_path, ray_session):
    """4 copies of two densities, in process, over 1 and 2 processes and 2 Ray actors: the same observations,
    rewards, flags, final observations and infos at every step, and the same training logs (copy i in env_i/)."""
    def env(name: str, **backend):
        return make_vec_env("roundabout", ["d120", "d160"], num_envs=4, actions="pedal", record_dir=tmp_path / name,
                            observation="features", **SHORT, **backend)

    reference = _rollout(env("inproc"))
    ended = sum(f is not None for step in reference[1:] for f in step[5])
    assert ended >= 8, "episodes must end (and auto-reset) during the rollout"
    tasks = {(i, f["task"]) for step in reference[1:] for i, f in enumerate(step[5]) if f}
    assert tasks == {(0, "roundabout/d120"), (1, "roundabout/d160"), (2, "roundabout/d120"), (3, "roundabout/d160")}
    reference_logs = _logs(tmp_path / "inproc")
    for name, backend in (("w1", {"workers": 1}), ("w2", {"workers": 2}), ("ray", {"workers": 2, "ray": ray_session})):
        _assert_same(reference, _rollout(env(name, **backend)), name)
        _assert_same(reference_logs, _logs(tmp_path / name), f"{name} logs")


def test_camera_images_rendered_in_workers_are_those_rendered_in_process():
    """Each worker renders with its own GL context (MUJOCO_GL), created in the worker: the same pixels."""
    def env(**backend):
        return make_vec_env("waypoints", "straight", num_envs=2, observation="camera", image_size=32, time_limit=1.0,
                            **backend)

    reference = _rollout(env(), steps=12)
    assert reference[1][0]["image"].std() > 0  # a real picture, not a blank buffer
    _assert_same(reference, _rollout(env(workers=2), steps=12), "2 workers")


def test_evaluation_rows_and_logs_are_the_same_at_1_2_4_workers_on_ray_and_after_a_worker_is_killed(
        tmp_path, ray_session, capfd):
    def run(name: str, **backend) -> tuple[list[dict], dict]:
        result = evaluate(CHECKPOINT, episodes=5, seed=500, task_kwargs=SHORT, record_dir=tmp_path / name, **backend)
        return result["rows"], result["summary"]

    rows, summary = run("inproc")
    assert [row["episode"] for row in rows] == list(range(5))
    logs = _logs(tmp_path / "inproc")
    assert sorted(logs) == sorted(f"roundabout-d210_{500 + i}_{i:05d}.mcap" for i in range(5))
    killed: list[int] = []

    def kill_a_worker(row: dict) -> None:  # kill -9 a busy worker as the first episode comes back
        if not killed:
            worker = multiprocessing.active_children()[0]
            os.kill(worker.pid, signal.SIGKILL)
            killed.append(worker.pid)

    for name, backend in (("w1", {"workers": 1}), ("w2", {"workers": 2}), ("w4", {"workers": 4}),
                          ("ray", {"workers": 2, "ray": ray_session}),
                          ("w2_killed", {"workers": 2, "on_episode": kill_a_worker})):
        before = _descendants()  # (Ray keeps its idle workers)
        got_rows, got_summary = run(name, **backend)
        assert got_rows == rows, name
        assert got_summary == summary, name
        _assert_same(logs, _logs(tmp_path / name), f"{name} logs")
    assert killed and "a worker process died" in capfd.readouterr().err
    assert not multiprocessing.active_children()  # every pool's workers joined
    left = [_cmdline(pid) for pid in _descendants() - before]
    # no worker left behind; multiprocessing's forkserver and resource tracker serve later pools
    assert all("forkserver import main" in line or "resource_tracker import main" in line for line in left), left


def test_a_killed_vector_env_worker_is_reported_and_the_others_stop():
    env = make_vec_env("waypoints", "straight", num_envs=2, workers=2, observation="features")
    assert isinstance(env, SubprocessVecEnv)
    env.reset(seed=0)
    os.kill(env.pids[0], signal.SIGKILL)
    with pytest.raises(WorkerDied, match="worker 0"):
        for _ in range(3):
            env.step(np.zeros((2, 3), np.float32))
    time.sleep(0.5)
    assert not any(process.is_alive() for process in env.vec.processes)


@pytest.mark.parametrize("stop", ["ctrl_c", "kill_9_parent"])
def test_stopping_a_parallel_evaluation_leaves_no_process_behind(stop):
    """Ctrl-C (SIGINT to the terminal's foreground group) exits with 130; SIGKILL of the parent alone (no
    cleanup can run) takes the workers and multiprocessing's helpers with it within seconds."""
    command = [sys.executable, "-m", "mjdrive.cli", "eval", "--checkpoint", str(CHECKPOINT), "--episodes", "200",
               "--workers", "2", "--no-record"]
    # its own process group, as a terminal's foreground job; SIGINT as a terminal leaves it (a test run started
    # in the background of a non-interactive shell inherits SIGINT ignored, and Python would keep ignoring it)
    proc = subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    def group() -> list[str]:
        """Command lines of the live processes of its group (zombies are gone already)."""
        lines = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == proc.pid and fields[0] != "Z":
                lines.append(_cmdline(int(stat.parent.name)))
        return lines

    deadline = time.monotonic() + 60
    while sum("forkserver import main" in line for line in group()) < 3 and time.monotonic() < deadline:
        time.sleep(0.2)  # the forkserver and its two workers
    assert sum("forkserver import main" in line for line in group()) >= 3, group()
    time.sleep(1.0)  # episodes under way
    if stop == "ctrl_c":
        os.killpg(proc.pid, signal.SIGINT)  # the terminal signals the whole foreground group
        assert proc.wait(timeout=30) == 130, proc.stderr.read().decode()[-2000:]
    else:
        proc.kill()
        assert proc.wait(timeout=30) == -signal.SIGKILL
    proc.stderr.close()
    deadline = time.monotonic() + 15
    while group() and time.monotonic() < deadline:
        time.sleep(0.2)
    assert group() == []


TRAINING = {  # algo -> (config, overrides): a few episodes of 30 steps on 2 copies
    "sac": ("sac", ["steps=192", "algorithm.learning_starts=64", "algorithm.batch_size=16",
                    "algorithm.updates_per_step=0.5"]),
    "ppo": ("ppo", ["steps=192", "rsl_rl.num_steps_per_env=32"]),
}


@pytest.mark.parametrize("algo", sorted(TRAINING))
def test_training_with_workers_learns_from_the_same_episodes(algo, tmp_path):
    """Over 2 worker processes a learner writes the same episode log and ends with the same networks as in
    process (SAC: the off-policy loop DQN shares; PPO: rsl-rl through RslRlVecEnv)."""
    import torch

    from mjdrive.agents.checkpoints import load_checkpoint

    name, overrides = TRAINING[algo]
    config = apply_overrides(load_config(name), [*overrides, "num_envs=2", "tensorboard=false", "checkpoint_every=1000",
                                                 "log_every=1000", "task_kwargs.time_limit=3.0"])
    policies = {run: train({**config, "workers": workers}, tmp_path / run, progress=False)
                for run, workers in (("inproc", 0), ("w2", 2))}

    def episodes(run: str) -> list[list[str]]:
        lines = [line.split(",") for line in (tmp_path / run / "episodes.csv").read_text().splitlines()]
        wall = lines[0].index("wall_s")
        return [row[:wall] + row[wall + 1:] for row in lines]

    assert len(episodes("inproc")) >= 5  # the header and at least 4 episodes
    assert episodes("w2") == episodes("inproc")
    a, b = (load_checkpoint(policies[run])["state"] for run in ("inproc", "w2"))
    for module in a:
        assert all(torch.equal(a[module][key], b[module][key]) for key in a[module]), module


def test_ray_backend_without_ray_installed_says_how_to_get_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(ImportError, match=r"pip install 'mjdrive\[ray\]'"):
        make_vec_env("waypoints", "straight", num_envs=2, workers=2, ray="local", observation="features")
    assert RayVecEnv is not None


def test_copies_that_do_not_split_evenly_over_the_workers_are_refused():
    with pytest.raises(ValueError, match="multiple of the workers"):
        make_vec_env("waypoints", "straight", num_envs=3, workers=2, observation="features")


def test_vector_env_workers_each_run_on_their_own_cpu_where_there_are_enough():
    """Worker w on the w-th CPU this process may use (results do not depend on it: the tests above run pinned);
    more workers than CPUs: none pinned."""
    cpus = sorted(os.sched_getaffinity(0))
    assert worker_cpus(len(cpus)) == cpus and worker_cpus(len(cpus) + 1) == [None] * (len(cpus) + 1)
    workers = min(2, len(cpus))
    env = make_vec_env("waypoints", "straight", num_envs=2, workers=workers, observation="features")
    try:
        assert [os.sched_getaffinity(pid) for pid in env.pids] == [{cpu} for cpu in cpus[:workers]]
    finally:
        env.close()


def test_a_rerun_episode_rewrites_the_log_a_dead_worker_finished_and_keeps_older_logs(tmp_path):
    """A worker killed after publishing an episode's log but before reporting its row: the rerun writes the same
    name (the same contents), not a second copy under another name. A log older than the evaluation is kept."""
    reference = tmp_path / "reference"
    rows = evaluate(CHECKPOINT, episodes=3, seed=700, task_kwargs=SHORT, record_dir=reference)["rows"]
    names = sorted(p.name for p in reference.glob("*.mcap"))
    folder = tmp_path / "rerun"
    folder.mkdir()
    older = folder / names[0]
    older.write_bytes(b"an earlier evaluation's log")  # before this evaluation began: kept
    stale = folder / names[2]

    def finished_by_a_dead_worker(row: dict) -> None:  # episode 2's log is there before episode 2 runs
        if row["episode"] == 0:
            stale.write_bytes(b"episode 2, published by a worker that died before reporting it")

    got = evaluate(CHECKPOINT, episodes=3, seed=700, task_kwargs=SHORT, record_dir=folder,
                   on_episode=finished_by_a_dead_worker)["rows"]
    assert older.read_bytes() == b"an earlier evaluation's log"
    assert got[2]["log"] == rows[2]["log"] == names[2]
    assert got[0]["log"] != rows[0]["log"]  # the earlier log's name was taken: a suffix
    logs = {p.name: p for p in folder.glob("*.mcap")}
    assert set(logs) == {*names, got[0]["log"]}
    assert _episode_contents(logs[names[2]]) == _episode_contents(reference / names[2])
