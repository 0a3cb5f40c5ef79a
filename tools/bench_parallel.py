"""Scale-out throughput: evaluation and training collection in this process, over 1 and 2 worker processes.

    python -m tools.bench_parallel --out results/bench_parallel.md

Evaluation: `mjdrive.agents.evaluate.evaluate` of a committed roundabout SAC (features, camera) for the same episodes at
workers 0 (this process), 1 and 2; env steps per wall second, worker start-up included, and a check that the
rows are identical. Training: the collection loop of two training configs (PPO features on waypoints/straight,
16 copies; SAC camera on roundabout/d210, 4 copies): the learner's policy acts on the batch in this process and
the vector env steps it (`mjdrive.agents.env_factory.make_training_env`), no gradient updates; env steps per wall
second after a warm-up. Every figure of a table comes from one run of this script, ratios between figures of that run.
Projections for bigger nodes use the measured per-worker rate and the measured time this process spends acting.
"""

from __future__ import annotations

import argparse
import operator
import os
import platform
import shlex
import statistics
import sys
import time
from pathlib import Path

from mjdrive.agents.algorithms import agent_class
from mjdrive.agents.config import apply_overrides, load_config
from mjdrive.agents.env_factory import make_training_env
from mjdrive.agents.evaluate import evaluate
from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.comfort import load_filter
from mjdrive.envs.fanout import fan_out

ROOT = Path(__file__).resolve().parents[1]
EVAL_CASES = {  # observation -> committed checkpoint
    "features": ROOT / "results" / "checkpoints" / "sac_features_roundabout.pt",
    "camera": ROOT / "results" / "checkpoints" / "sac_camera_roundabout.pt",
}
TRAIN_CASES = {  # label -> (config, overrides)
    "PPO features (waypoints/straight, 16 copies)": ("ppo", []),
    "SAC camera (roundabout/d210, 4 copies)": ("sac_roundabout", []),
}
WORKERS = (0, 1, 2)
PROJECTED = (16, 64)
IDLE_BUSY = 0.25  # [cores]: the machine counts as idle below this over `IDLE_SAMPLE`
IDLE_SAMPLE = 1.0  # [s]
IDLE_WAIT = 60.0  # [s] at most before a measurement starts anyway
STARTS: list[float] = []  # busy cores of the machine when each measurement started


def load() -> str:
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


def cpu_busy(seconds: float = IDLE_SAMPLE) -> float:
    """Cores busy on the whole machine over `seconds` (/proc/stat: every process, this one's too)."""
    def sample() -> tuple[int, int]:
        with open("/proc/stat") as stat:
            ticks = [int(x) for x in stat.readline().split()[1:]]
        idle = ticks[3] + ticks[4]  # idle, iowait
        return sum(ticks[:8]) - idle, sum(ticks[:8])

    busy0, total0 = sample()
    time.sleep(seconds)
    busy1, total1 = sample()
    return (os.cpu_count() or 1) * (busy1 - busy0) / max(total1 - total0, 1)


def wait_idle() -> float:
    """Wait (at most `IDLE_WAIT`) until the machine is idle; the busy cores when the measurement starts."""
    deadline = time.monotonic() + IDLE_WAIT
    while (busy := cpu_busy()) >= IDLE_BUSY and time.monotonic() < deadline:
        pass
    STARTS.append(busy)
    return busy


def busy_processes() -> str:
    """Other processes using more than half a core now (CPU share since they started, nice value, command)."""
    import subprocess

    lines = subprocess.run(["ps", "-eo", "pid,pcpu,ni,args", "--sort=-pcpu"], capture_output=True,
                           text=True).stdout.splitlines()[1:]
    busy = []
    for line in lines:
        pid, cpu, nice, command = line.split(None, 3)
        if float(cpu) > 50 and int(pid) != os.getpid():
            busy.append(f"`{command[:90]}` ({cpu}% CPU, nice {nice})")
    return "; ".join(busy) or "none"


def bench_eval(checkpoint: Path, episodes: int, seed: int, rounds: int) -> dict:
    """{workers: {steps_per_s, wall_s, steps}} for the same episodes, the best of `rounds` rounds (0, 1, 2 workers
    in turn), and "rounds": each round's {workers: steps_per_s}; raises if the rows differ."""
    evaluate(checkpoint, episodes=2, seed=seed, workers=2)  # warm-up: files in the page cache, first imports
    best: dict = {"rounds": []}
    for _ in range(rounds):
        measured = _eval_round(checkpoint, episodes, seed)
        best["rounds"].append({workers: result["steps_per_s"] for workers, result in measured.items()})
        for workers, result in measured.items():
            if workers not in best or result["wall_s"] < best[workers]["wall_s"]:
                best[workers] = result
    return best


def _eval_round(checkpoint: Path, episodes: int, seed: int) -> dict[int, dict]:
    out, reference = {}, None
    for workers in WORKERS:
        arrivals: list[float] = []
        wait_idle()
        start = time.perf_counter()
        result = evaluate(checkpoint, episodes=episodes, seed=seed, workers=workers,
                          on_episode=lambda row, arrivals=arrivals: arrivals.append(time.perf_counter()))
        wall = time.perf_counter() - start
        steps = sum(row["steps"] for row in result["rows"])
        if reference is None:
            reference = result["rows"]
        elif result["rows"] != reference:
            raise RuntimeError(f"{checkpoint.name}: rows at {workers} workers differ from in process")
        out[workers] = {"steps_per_s": steps / wall, "wall_s": wall, "steps": steps,
                        "first_s": arrivals[0] - start}  # start-up (policy, env, workers) + one episode
        print(f"eval {checkpoint.name} workers={workers}: {steps} steps in {wall:.1f} s ({steps / wall:.1f}/s), "
              f"load {load()}", flush=True)
    return out


def policy(algo: str, agent):
    """obs batch -> env actions as the training loop acts (PPO sampled; SAC/DQN past `learning_starts`)."""
    if algo == "ppo":
        return lambda obs: agent.act(obs, deterministic=False)
    learned = int(agent.hp.get("learning_starts", 0))  # past it: the actor network acts
    return lambda obs: agent.explore(obs, learned)[1]


def bench_collection(name: str, overrides: list[str], seconds: float, rounds: int) -> dict:
    """{workers: {steps_per_s, act_s_per_step, ...}} (best of `rounds`), plus "threads": in process with the
    config's physics threads when it has more than one (workers use one each, and so does workers=0 here), and
    "rounds": each round's {workers: steps_per_s}."""
    config = apply_overrides(load_config(name), overrides)
    variants = [(w, {"workers": w, "nthread": 1}) for w in WORKERS]
    if int(config.get("nthread", 1)) > 1:
        variants.append(("threads", {"workers": 0}))
    best: dict = {"rounds": []}
    for _ in range(rounds):
        best["rounds"].append({})
        for key, settings in variants:
            wait_idle()
            result = _collect({**config, **settings}, seconds)
            best["rounds"][-1][key] = result["steps_per_s"]
            if key not in best or result["steps_per_s"] > best[key]["steps_per_s"]:
                best[key] = result
            print(f"collect {name} {key}: {result['steps_per_s']:.1f} env steps/s (acting "
                  f"{1000 * result['act_s_per_step']:.1f} ms per batch), load {load()}", flush=True)
    return best


def _collect(config: dict, seconds: float) -> dict:
    """One measurement: the learner acts on the batch here, the vector env of `config` steps it."""
    env = make_training_env(config)
    agent = agent_class(config["algo"])(config, env.single_observation_space, env.single_action_space)
    act = policy(config["algo"], agent)
    obs, _ = env.reset(seed=0)
    for _ in range(5):  # warm-up: first renders, torch's first calls
        obs = env.step(act(obs))[0]
    steps, acting, start = 0, 0.0, time.perf_counter()
    while (wall := time.perf_counter() - start) < seconds:
        t = time.perf_counter()
        actions = act(obs)
        acting += time.perf_counter() - t
        obs = env.step(actions)[0]
        steps += 1
    env.close()
    n = env.num_envs
    return {"steps_per_s": steps * n / wall, "act_s_per_step": acting / steps, "wall_s": wall,
            "batch_s": wall / steps, "num_envs": n, "nthread": config.get("nthread", 1)}


def idle_line() -> str:
    """How idle the machine was when the measurements started."""
    if not STARTS:
        return "No measurement"
    busy = sorted(STARTS)
    late = sum(b >= IDLE_BUSY for b in busy)
    return (f"Each measurement waited (at most {IDLE_WAIT:g} s) for an idle machine (under {IDLE_BUSY:g} of a core "
            f"busy over {IDLE_SAMPLE:g} s in /proc/stat, the whole machine): busy cores at the starts min / "
            f"median / max {busy[0]:.2f} / {busy[len(busy) // 2]:.2f} / {busy[-1]:.2f}; {late} of {len(busy)} "
            "started on a busy machine")


def ratio(a: float, b: float) -> str:
    return f"{a / b:.2f}"


def paired(rounds: list[dict], top: int, bottom: int) -> str:
    """The ratio of two rows measured back to back in each round: "median (lowest-highest)" over the rounds
    (a slow phase of the machine then weighs on both rows of a ratio alike)."""
    values = [r[top] / r[bottom] for r in rounds]
    median = statistics.median(values)
    return f"{median:.2f} ({min(values):.2f}-{max(values):.2f})" if len(values) > 1 else f"{median:.2f}"


def report(evals: dict, trains: dict, args: argparse.Namespace, load_before: str, load_after: str,
           wall: float, busy: str) -> str:
    command = "python -m tools.bench_parallel " + shlex.join(sys.argv[1:])
    lines = [
        f"# Scale-out throughput ({platform.machine()}, {os.cpu_count()} cores, python "
        f"{platform.python_version()}, MUJOCO_GL={os.environ.get('MUJOCO_GL', '-')})",
        "",
        f"Command: `{command}`",
        "",
        f"1-min / 5-min / 15-min load average: {load_before} at the start, {load_after} at the end "
        f"(the run took {wall / 60:.1f} min). Every figure below comes from this one run; ratios compare figures of "
        f"this run; each rate is the best of {args.rounds} measurements (a round measures the rows in turn, after a "
        "warm-up), and the bold ratios divide those bests. The per-round columns divide the two rows of each round "
        "instead (measured back to back, so a slow phase of the machine weighs on both): their median, and lowest "
        "to highest in brackets. Other busy processes at the start: " + busy + ". " + idle_line() + ".",
        "",
        "## Evaluation (`mjdrive eval --workers N`)",
        "",
        f"{args.episodes} greedy episodes of roundabout/d210 (seeds {args.seed}...) per row, the same episodes at "
        "every worker count (rows checked identical). env steps/s = steps of all episodes / wall time of the whole "
        "`evaluate` call, worker start-up included (the forkserver, which preloads torch, scipy.signal and numba, "
        "was started before the first row).",
        "",
        "| observation | checkpoint | steps | in process | 1 worker | 2 workers | 2 workers / 1 worker "
        "| 1 worker / in process | per round: 2 / 1 worker | per round: 1 worker / in process "
        "| first episode back [s]: in process, 1, 2 workers |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for obs, (checkpoint, result) in evals.items():
        r = {w: result[w]["steps_per_s"] for w in WORKERS}
        lines.append(f"| {obs} | `{checkpoint.name}` | {result[0]['steps']} | {r[0]:.1f} | {r[1]:.1f} | {r[2]:.1f} "
                     f"| **{ratio(r[2], r[1])}** | {ratio(r[1], r[0])} | {paired(result['rounds'], 2, 1)} | "
                     f"{paired(result['rounds'], 1, 0)} | "
                     + ", ".join(f"{result[w]['first_s']:.1f}" for w in WORKERS) + " |")
    lines += [
        "",
        "## Training collection (`mjdrive train --workers N`)",
        "",
        f"The training loop's collection for {args.seconds:g} s per row after 5 warm-up steps, one physics thread per "
        "process (the in-process column with the config's threads for comparison): the learner's policy "
        "acts on the batch here (PPO: rsl-rl's actor, sampled; SAC: the actor network past `learning_starts`), the "
        "vector env steps it; no gradient updates (they run in this process whatever the worker count). "
        "acting = this process's policy time per batched step.",
        "",
        "| config | in process | in process, config's physics threads | 1 worker | 2 workers | 2 workers / 1 worker "
        "| 1 worker / in process | per round: 2 / 1 worker | per round: 1 worker / in process | acting [ms/step] |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for label, result in trains.items():
        r = {w: result[w]["steps_per_s"] for w in WORKERS}
        threads = (f"{result['threads']['steps_per_s']:.1f} ({result['threads']['nthread']} threads)"
                   if "threads" in result else "-")
        lines.append(f"| {label} | {r[0]:.1f} | {threads} | {r[1]:.1f} | {r[2]:.1f} | **{ratio(r[2], r[1])}** | "
                     f"{ratio(r[1], r[0])} | {paired(result['rounds'], 2, 1)} | {paired(result['rounds'], 1, 0)} | "
                     f"{1000 * result[2]['act_s_per_step']:.1f} |")
    lines += [
        "",
        "## Projection for bigger nodes (not measured)",
        "",
        "Evaluation: episodes are independent and a worker holds its own policy and env, so N workers on N free "
        "cores give about N x the per-worker rate measured above with 2 workers (start-up and the parent's "
        "gathering are small against 200-800 episodes). Training collection: a batched step costs this "
        "process's acting time (measured above, for the measured batch; scaled linearly with the batch, which "
        "overstates a GPU's cost) plus one worker's step of its K copies (the 2-worker batch time minus acting, "
        "K fixed as measured), so N workers give N K / (acting(N K) + worker step) env steps/s.",
        "",
        "| workload | per-worker rate [env steps/s] | " + " | ".join(f"{n} workers" for n in PROJECTED) + " |",
        "| --- | ---: | " + " | ".join("---:" for _ in PROJECTED) + " |",
    ]
    for obs, (_, result) in evals.items():
        per_worker = result[2]["steps_per_s"] / 2
        lines.append(f"| eval, {obs} | {per_worker:.1f} | "
                     + " | ".join(f"{n * per_worker:,.0f}" for n in PROJECTED) + " |")
    for label, result in trains.items():
        two = result[2]
        k = two["num_envs"] / 2  # copies per worker
        act_per_copy = two["act_s_per_step"] / two["num_envs"]
        worker_step = max(two["batch_s"] - two["act_s_per_step"], 1e-9)
        per_worker = k / worker_step
        cells = [f"{n * k / (act_per_copy * n * k + worker_step):,.0f}" for n in PROJECTED]
        lines.append(f"| train collection, {label} | {per_worker:.1f} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Caveats: the 2-core machine is shared with other jobs (load above). A worker here competes with the "
        "parent and other processes for "
        "2 cores, so the 2-worker figures are a lower bound of what 2 free cores give. The projections assume "
        "one free core per worker, no memory-bandwidth limit and software rendering (llvmpipe) in every worker.",
        "",
        "## On a GPU node (plan, not code)",
        "",
        "- Rendering on the GPU: EGL on an NVIDIA driver gives each worker a hardware context (`MUJOCO_GL=egl`, "
        "`MUJOCO_EGL_DEVICE_ID` to spread workers over GPUs); the camera's 84x84 renders then cost the GPU "
        "little, and the workers' CPU time is the task Python and physics. No code change is needed for the "
        "worker-per-process layout; llvmpipe's thread pinning becomes moot.",
        "- The learner on the GPU: torch updates and batched acting move to CUDA in the parent; the adapters "
        "(`RslRlVecEnv`, the off-policy loop) already convert numpy batches at the boundary, so only the device "
        "changes. Then acting stops being the serial share that limits the projections above.",
        "- Batch physics with MuJoCo Warp (MJX's successor on NVIDIA Warp): step thousands of copies of one model "
        "on the GPU. The roundabout's traffic is numpy over all road users, which maps to array code over a copy "
        "axis; the dm_control task Python per copy (observations, rewards, sensors) would have to become batched "
        "array code first, which is the real cost of that move. A mixed layout (Warp physics per worker, task "
        "code batched over copies) would keep this vector-env boundary unchanged.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int_at_least(1), default=200,
                        help="evaluation episodes per row (200: the smallest table the study tools print)")
    parser.add_argument("--seed", type=int_at_least(0), default=20_000)
    parser.add_argument("--seconds", type=positive_float, default=10.0, help="collection time per training row [s]")
    parser.add_argument("--rounds", type=int_at_least(1), default=2,
                        help="rounds of measurements (rows in turn); the best rate of each row is kept")
    parser.add_argument("--out", default=None, help="write the markdown report here")
    args = parser.parse_args(argv)
    import torch

    torch.set_num_threads(1)  # as `mjdrive train` and `eval` (the configs' torch_threads)
    load_filter()  # scipy.signal, as the workers' forkserver preloads it: the in-process rows do not pay its import
    busy = busy_processes()  # before this script starts any
    fan_out(operator.add, 0, range(2), workers=1)  # start the forkserver (it preloads torch) before any timing
    load_before, start = load(), time.perf_counter()
    print(f"load {load_before}", flush=True)
    evals = {obs: (checkpoint, bench_eval(checkpoint, args.episodes, args.seed, args.rounds))
             for obs, checkpoint in EVAL_CASES.items()}
    trains = {label: bench_collection(name, overrides, args.seconds, args.rounds)
              for label, (name, overrides) in TRAIN_CASES.items()}
    text = report(evals, trains, args, load_before, load(), time.perf_counter() - start, busy)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
