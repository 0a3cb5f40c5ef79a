"""`mjdrive eval`: run a checkpoint's greedy policy for N episodes and tabulate the study's metrics.

waypoints (study 004 §4.1): route completion, mean and per episode (the study: straight route, 50 episodes,
20 s, greedy). roundabout (study 000 Table 3): avg reward, avg time [s], avg speed [m/s], avg distance [m],
avg steps, success %, collision %. urban (study 002): success %, collision %, reward, time, speed, distance
(no route completion: the urban tasks have none).

Before any episode runs or any file is written, `plan_evaluation` checks that the checkpoint can run on the
task: the task keywords it was trained with must be ones the task takes, and the task's observation must hold
every entry the policy reads, with the same shape and dtype.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from mjdrive import suite
from mjdrive.agents.algorithms import agent_from_payload
from mjdrive.agents.checkpoints import load_checkpoint
from mjdrive.agents.ensemble import describe, ensemble_agent
from mjdrive.agents.observations import observation_mismatch
from mjdrive.envs import make_env
from mjdrive.record.summary import (
    COMFORT_COLUMNS,
    SCHEMA,
    comfort_cells,
    comfort_line,
    episode_row,
    roundabout_arms,
    summarize,
)
from mjdrive.suite import split_task


def load_agent(path: str | Path) -> tuple[Any, dict]:
    """(agent ready to act, checkpoint payload) from a full checkpoint, a policy.pt, an ensemble or a hybrid."""
    payload = load_checkpoint(path)
    if payload["algo"] == "ensemble":
        return ensemble_agent(payload, path), payload
    if payload["algo"] == "hybrid":
        from mjdrive.agents.hybrid import hybrid_agent

        return hybrid_agent(payload, path), payload
    return agent_from_payload(payload, str(path)), payload


@dataclass(frozen=True)
class EvalPlan:
    """A checkpoint's policy, loaded and checked against the task it is to run on (`plan_evaluation`)."""

    checkpoint: str
    agent: Any
    payload: dict
    task: str  # DOMAIN/TASK
    task_kwargs: dict[str, Any]  # the checkpoint's task keywords, then the user's
    actions: str  # the checkpoint's action set


def plan_evaluation(checkpoint: str | Path, task: str | None = None,
                    task_kwargs: dict[str, Any] | None = None) -> EvalPlan:
    """Load `checkpoint` and check, before anything runs or is written, that it can run on `task` (default:
    the one it was trained on) with its own task keywords and then `task_kwargs`: ValueError in one line
    naming the mismatch (a keyword the task does not take, an observation the policy cannot read, `actions`
    given as a task keyword)."""
    agent, payload = load_agent(checkpoint)
    config = payload["config"]
    trained_task, actions = config["task"], config.get("actions", "continuous")
    task = task or trained_task
    user = dict(task_kwargs or {})
    if "actions" in user:
        raise ValueError(f"'actions' is not a task keyword: the action set is the checkpoint's own "
                         f"({checkpoint} acts with {actions!r}); drop --task-kwarg actions=...")
    carried = dict(config.get("task_kwargs") or {})
    domain, name = suite.split_task(task)
    config_class, defaults = suite.task_config(domain, name)
    accepted = {f.name for f in fields(config_class)}
    foreign = {key: value for key, value in carried.items() if key not in accepted}
    if foreign:
        shown = ", ".join(f"{key}={value!r}" for key, value in foreign.items())
        raise ValueError(f"checkpoint {checkpoint} was trained on {trained_task} with the task keyword"
                         f"{'s' if len(foreign) > 1 else ''} {shown}, which {task} does not take: it cannot be "
                         f"evaluated there (its keywords: `mjdrive list --kwargs {task}`)")
    kwargs = {**carried, **user}
    config_class.from_dict(kwargs, defaults, where=task)  # a bad keyword of the user's: its one-line error
    if task != trained_task or user:  # another env than the one the policy was built for: can it read it?
        trained_env = make_env(*suite.split_task(trained_task), actions=actions, **carried)
        try:
            env = make_env(domain, name, actions=actions, **kwargs)
            problems = observation_mismatch(trained_env.observation_space, env.observation_space)
            if env.action_space != trained_env.action_space:
                problems.append(f"its action space is {env.action_space}, not {trained_env.action_space}")
            env.close()
        finally:
            trained_env.close()
        if problems:
            given = f"{task} with {', '.join(f'{k}={v!r}' for k, v in user.items())}" if user else task
            raise ValueError(f"checkpoint {checkpoint} reads the observation of {trained_task} and cannot read "
                             f"that of {given}: {'; '.join(problems[:4])}{'; ...' if len(problems) > 4 else ''}")
    return EvalPlan(str(checkpoint), agent, payload, task, kwargs, actions)


@dataclass(frozen=True)
class EvalSpec:
    """Everything a worker needs to run any episode of an evaluation (picklable); episode i runs with seed
    `seed + i`, so its result depends on its index alone."""

    checkpoint: str
    task: str
    task_kwargs: dict[str, Any]
    actions: str
    seed: int
    deterministic: bool = True
    record_dir: str | None = None
    torch_threads: int = 1
    live_port: int | None = None  # stream the logs' channels to Foxglove (one server; episodes in this process)
    live_host: str = "127.0.0.1"
    # [s] time.time() when the evaluation began; not in the repr, which keys the workers' cached runners
    started: float | None = field(default=None, repr=False, compare=False)


class EpisodeRunner:
    """A loaded policy and its env (built once), running episodes of an `EvalSpec` by index."""

    def __init__(self, spec: EvalSpec, agent: Any = None):
        import torch

        # one thread, as in training (OpenMP threads spin-waiting beside other busy processes stalled episodes
        # for 45 s on the 2-core machine); a worker process is pinned to one anyway
        torch.set_num_threads(spec.torch_threads)
        self.spec = spec
        self.agent = agent if agent is not None else load_agent(spec.checkpoint)[0]
        domain, self.name = split_task(spec.task)
        self.env = make_env(domain, self.name, actions=spec.actions, **spec.task_kwargs)
        self.arms = roundabout_arms(domain, self.name, spec.task_kwargs)  # to count the exits from the entry
        self.live = None  # with spec.live_port: one recorder (one live server) for every episode, run in order
        if spec.live_port is not None:
            from mjdrive.record import RecordEpisodes, RecordOptions

            options = RecordOptions(live_port=spec.live_port, live_host=spec.live_host)
            self.live = RecordEpisodes(self.env, spec.record_dir, options)
            from mjdrive.record.live import announce_live

            announce_live(self.live)

    def run(self, index: int) -> dict[str, Any]:
        """Episode `index` (seed `spec.seed + index`) as a row; with `spec.record_dir` also its MCAP log, named
        after the index whichever process runs it."""
        import torch

        spec, seed = self.spec, self.spec.seed + index
        env = self.env
        if self.live is not None:
            env = self.live
        elif spec.record_dir is not None:
            from mjdrive.record import RecordEpisodes, episode_filename

            env = RecordEpisodes(self.env, spec.record_dir, first_episode=index)
            # A worker that died running this episode left its unfinished file, or died after finishing the log
            # but before reporting the row: the rerun writes the same name (the same episode, bit for bit). Logs
            # older than this evaluation are kept (the rerun's name then takes a suffix).
            final = Path(spec.record_dir) / episode_filename(env.recorder.spec, seed, index)
            final.with_name(final.name + ".part").unlink(missing_ok=True)
            if spec.started is not None and final.exists() and final.stat().st_mtime >= spec.started:
                final.unlink()
        obs, info = env.reset(seed=seed)
        if not spec.deterministic:
            torch.manual_seed(seed)  # sampled actions are reproducible per episode too
        total, steps = 0.0, 0
        try:
            while True:
                action = self.agent.act({key: value[None] for key, value in obs.items()}, spec.deterministic)[0]
                if hasattr(env, "recorder") and getattr(self.agent, "last", None):  # who decided (the hybrid)
                    env.recorder.decided(*self.agent.last[0], obs)
                obs, reward, terminated, truncated, info = env.step(action)
                total += reward
                steps += 1
                if terminated or truncated:
                    break
        except BaseException:  # an error or Ctrl-C mid-episode: its log stays unfinished, never blocking a rerun
            if hasattr(env, "recorder"):
                env.recorder.abandon()
            raise
        if spec.record_dir is not None and self.live is None:
            env.recorder.close()
        log = Path(info["record_path"]).name if "record_path" in info else None
        return episode_row(info, episode=index, seed=seed, reward=total, steps=steps, terminated=terminated,
                           truncated=truncated, log=log, arms=self.arms,
                           control_dt=self.env.unwrapped.dm_env.control_timestep())

    def close(self) -> None:
        if self.live is not None:
            self.live.recorder.close()
        self.env.close()


_RUNNERS: dict[str, EpisodeRunner] = {}  # this process's runner of the last spec (a worker keeps it between jobs)


def run_episode(spec: EvalSpec, index: int) -> dict[str, Any]:
    """Episode `index` of `spec` as a row (the job `fan_out` sends to workers)."""
    key = repr(spec)
    if key not in _RUNNERS:
        for runner in _RUNNERS.values():
            runner.close()
        _RUNNERS.clear()
        _RUNNERS[key] = EpisodeRunner(spec)
    runner = _RUNNERS[key]
    runner.spec = spec  # the same episodes; this evaluation's start time
    return runner.run(index)


def evaluate(checkpoint: str | Path, episodes: int = 50, task: str | None = None, seed: int = 10_000,
             task_kwargs: dict | None = None, deterministic: bool = True,
             record_dir: str | Path | None = None, progress: str | None = None, workers: int = 0,
             ray: str | None = None, on_episode: Callable[[dict], None] | None = None,
             live: tuple[str, int] | None = None, plan: EvalPlan | None = None) -> dict[str, Any]:
    """Roll out the policy for `episodes` episodes (seeds seed, seed+1, ...); returns rows and a summary.
    With `record_dir`, every episode is also written there as an MCAP log (`mjdrive replay`/`logs`).
    `progress`: the label of a tqdm bar over the episodes (on stderr); None: no bar.
    `workers=N` runs the episodes in N worker processes, `ray` (an address, "local") as Ray tasks
    (`mjdrive.envs.fanout`); rows, summary and logs are the same for any N and either backend (episodes of a
    worker that died run again elsewhere). `on_episode(row)` is called as each episode ends. `live=(host,
    port)` streams the logs' channels to Foxglove while the episodes run (in this process only). `plan`:
    `plan_evaluation(checkpoint, task, task_kwargs)` if the caller made it already (else it is made here)."""
    from mjdrive.envs.fanout import fan_out
    from mjdrive.progress import Progress

    plan = plan or plan_evaluation(checkpoint, task, task_kwargs)
    agent, payload, task, kwargs = plan.agent, plan.payload, plan.task, plan.task_kwargs
    config = payload["config"]
    local = not workers and ray is None
    if live is not None and (not local or record_dir is None):
        raise ValueError("--live streams the episode logs of this process: drop --no-record, --workers and --ray")
    spec = EvalSpec(str(checkpoint), task, kwargs, plan.actions, seed, deterministic,
                    None if record_dir is None else str(record_dir), int(config.get("torch_threads", 1)),
                    *((live[1], live[0]) if live is not None else ()), started=time.time())
    start = time.perf_counter()
    if local:  # this process runs them: reuse the policy loaded above
        _RUNNERS.clear()
        _RUNNERS[repr(spec)] = EpisodeRunner(spec, agent)
    bar = Progress(total=episodes, desc=progress, unit="episode", disable=progress is None)

    def arrived(index: int, row: dict) -> None:
        bar.update(1)
        if on_episode is not None:
            on_episode(row)

    try:
        results = fan_out(run_episode, spec, range(episodes), workers=workers, ray=ray, on_result=arrived)
    finally:
        bar.close()
        if local:
            for runner in _RUNNERS.values():
                runner.close()
            _RUNNERS.clear()
    rows = [results[index] for index in range(episodes)]  # by episode, whatever the order they ended in
    trained_on = " + ".join([config["task"], *(config.get("mix_tasks") or [])])  # a mix: every task in turn
    return {"schema": SCHEMA, "command": "eval", "policy": f"{payload['algo']} {checkpoint}",
            "checkpoint": str(checkpoint), "algo": payload["algo"], "trained_on": trained_on,
            "train_steps": payload["step"], "task": task, "task_kwargs": kwargs, "episodes": episodes,
            "deterministic": deterministic, "seed": seed, "wall_s": round(time.perf_counter() - start, 1),
            "workers": workers, "ray": ray,
            **({"ensemble": config["ensemble"]} if "ensemble" in config else {}),
            **({"hybrid": config["hybrid"]} if "hybrid" in config else {}),
            "summary": summarize(rows), "rows": rows}


def to_markdown(result: dict) -> str:
    """The study's table for the task's domain, then one row per episode."""
    s = result["summary"]
    lines = [
        f"# {result['algo'].upper()} on {result['task']} ({result['episodes']} episodes, "
        f"{'greedy' if result['deterministic'] else 'stochastic'} policy)",
        "",
        f"Checkpoint `{result['checkpoint']}`, trained on {result['trained_on']} for {result['train_steps']:,} "
        f"env steps; task kwargs {result['task_kwargs']}; seeds {result['seed']}..."
        f"{result['seed'] + result['episodes'] - 1}.",
        "",
    ]
    if result.get("ensemble"):
        lines += [f"This is {describe(result['ensemble'])}; the steps above are its longest-trained member's.", ""]
    if result.get("hybrid"):
        from mjdrive.agents.hybrid import describe as describe_hybrid

        lines += [f"This is {describe_hybrid(result['hybrid'])}; the steps above are its longest-trained "
                  "member's.", ""]
    if result["task"].startswith("roundabout"):
        lines += [
            "| agent | avg reward | avg time (s) | avg speed (m/s) | avg distance (m) | avg steps | success % "
            "| collision % |",
            "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
            f"| {result['algo'].upper()} | {s['avg_reward']:.2f} | {s['avg_time_s']:.2f} | "
            f"{s['avg_speed_m_s']:.2f} | {s['avg_distance_m']:.2f} | {s['avg_steps']:.1f} | "
            f"{s['success_pct']:.0f} | {s['collision_pct']:.0f} |",
        ]
    elif "route_completion_mean" in s:  # a task with route completion (waypoints)
        lines += [
            "| route completion mean | min | max | success % | collision % | avg reward | avg time (s) "
            "| avg speed (m/s) |",
            "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
            f"| {100 * s['route_completion_mean']:.1f}% | {100 * s['route_completion_min']:.1f}% | "
            f"{100 * s['route_completion_max']:.1f}% | {s['success_pct']:.0f} | {s['collision_pct']:.0f} | "
            f"{s['avg_reward']:.1f} | {s['avg_time_s']:.2f} | {s['avg_speed_m_s']:.2f} |",
        ]
    else:  # none (urban): the outcome, time and speed
        lines += [
            "| success % | collision % | avg reward | avg time (s) | avg speed (m/s) | avg distance (m) | avg steps |",
            "| ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
            f"| {s['success_pct']:.0f} | {s['collision_pct']:.0f} | {s['avg_reward']:.2f} | {s['avg_time_s']:.2f} | "
            f"{s['avg_speed_m_s']:.2f} | {s['avg_distance_m']:.2f} | {s['avg_steps']:.1f} |",
        ]
    lines += ["", comfort_line(s)] if comfort_line(s) else []
    completion = any(row["route_completion"] is not None for row in result["rows"])
    head = "| episode | seed | " + ("route completion | " if completion else "")
    lines += [
        "",
        f"{head}reward | steps | time (s) | distance (m) {COMFORT_COLUMNS}| end |",
        "| ---: " * (head.count("|") - 1 + 7) + "| --- |",
    ]
    for row in result["rows"]:
        cells = f"| {row['episode']} | {row['seed']} | "
        if completion:
            cells += ("-" if row["route_completion"] is None else f"{100 * row['route_completion']:.1f}%") + " | "
        lines.append(f"{cells}{row['reward']:.1f} | {row['steps']} | {row['time_s']:.1f} | "
                     f"{_fmt(row['distance_m'])} {comfort_cells(row)}| {row['end']} |")
    return "\n".join(lines)


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def eval_command(args) -> int:
    """`mjdrive eval` (argument parsing lives in mjdrive/cli.py): prints markdown, writes OUT.md/OUT.json."""
    import json

    from mjdrive.config import parse_task_kwargs
    from mjdrive.run_folder import fresh_folder

    task_kwargs = parse_task_kwargs(args.task_kwarg)
    plan = plan_evaluation(args.checkpoint, args.task, task_kwargs)  # a mismatch: one line, nothing written yet
    record_dir = None
    if args.record:  # beside OUT.md/OUT.json as OUT/, else runs/eval/CHECKPOINT/; one evaluation per folder
        default = Path(args.out).with_suffix("") if args.out else Path("runs") / "eval" / Path(args.checkpoint).stem
        record_dir = str(fresh_folder(args.record_dir or default, getattr(args, "overwrite", False),
                                      ("*.mcap", "*.mcap.part"), "--record-dir" if args.record_dir else "logs folder"))
    result = evaluate(args.checkpoint, episodes=args.episodes, task=args.task, seed=args.seed,
                      task_kwargs=task_kwargs, deterministic=not args.stochastic, record_dir=record_dir,
                      progress="eval", workers=getattr(args, "workers", 0),
                      ray=getattr(args, "ray", None), live=(args.live_host, args.live_port) if args.live else None,
                      plan=plan)
    if record_dir is not None:
        result["logs"] = record_dir
    markdown = to_markdown(result)
    print(markdown)
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".md").write_text(markdown + "\n")
        out.with_suffix(".json").write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {out.with_suffix('.md')} and {out.with_suffix('.json')}")
    else:
        print(json.dumps(result["summary"]))
    if record_dir is not None:
        print(f"episode logs (MCAP) in {record_dir}/")
    return 0
