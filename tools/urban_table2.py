"""Study 002's Table 2 on `urban/concatenated` (or another urban task) for one or more drivers, beside the
paper's rows.

    python -m tools.urban_table2 --policy autopilot rules --episodes 200 --out results/urban/table2.md
    python -m tools.urban_table2 --checkpoint "hybrid (TRPO)=results/checkpoints/hybrid_trpo.pt" --policy rules

Episode i of every driver runs with seed SEED + i. The drivers of the decision action set (`rules`,
`always_drive`, `always_stop`, and checkpoints trained with `decisions=true`, such as the hybrid agent) drive the
task with `decisions=True` (the operative level underneath); the others with throttle, steer and brake. A
checkpoint acts greedily. Metrics per episode from the task's `info` (comfort metrics of the chassis in the

car's heading frame, sampled at the control rate, 10 Hz, Savitzky-Golay smoothed over 0.5 s: `mjdrive.comfort`,
docs/summary.md); two more columns give the p95 and max jerk of the same samples unfiltered (finite differences,
`ComfortMeter.unfiltered_jerk`), to compare with figures filtered otherwise. The table shows means over episodes,
like the paper's; comfort and time over successful episodes only.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

from mjdrive import suite
from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from mjdrive.config import parse_task_kwargs
from mjdrive.envs import make_env
from mjdrive.envs.fanout import fan_out
from mjdrive.policies import DECISION_POLICIES, POLICIES, make_policy
from tools.report import publish

PAPER = {"Ours (paper, hybrid DRL)": (95.76, 4.37, 6.20, 3.33, 76.85, 7.60),
         "CARLA Autopilot (paper)": (100.0, 8.63, 11.94, 2.98, 140.23, 2.75)}
COLUMNS = ("success [%]", "p95 jerk [m/s^3]", "max jerk [m/s^3]", "p95 accel [m/s^2]", "time [s]", "speed [m/s]",
           "p95 jerk unfiltered [m/s^3]", "max jerk unfiltered [m/s^3]")


_ENVS: dict[tuple, gym.Env] = {}  # this process's env of the last task (a worker keeps it)


def task_env(task: str, decisions: bool = False, kwargs: str = "{}", actions: str = "continuous") -> gym.Env:
    """The urban `task`'s env (with the decision action set or the continuous `actions`, and the task keywords
    `kwargs` as JSON), built once per process (the concatenated route's takes ~0.4 s); an episode's reset with its
    seed sets all of its state, so a reused env drives the episode a new one would."""
    key = (task, decisions, kwargs, actions)
    if key not in _ENVS:
        for env in _ENVS.values():
            env.close()
        _ENVS.clear()
        _ENVS[key] = make_env("urban", task, actions=actions, decisions=decisions, **json.loads(kwargs))
    return _ENVS[key]


CHECKPOINT = "checkpoint="  # a driver `checkpoint=PATH`: the policy of a checkpoint file
_AGENTS: dict[str, object] = {}  # this process's loaded checkpoints


def checkpoint_policy(path: str) -> tuple[object, bool, str]:
    """(the greedy agent of checkpoint `path`, whether it takes decisions, its action set), loaded once per
    process."""
    from mjdrive.agents.evaluate import load_agent

    if path not in _AGENTS:
        agent, payload = load_agent(path)
        if not payload["config"]["task"].startswith("urban/"):
            raise ValueError(f"checkpoint {path} was trained on {payload['config']['task']}, not an urban task")
        config = payload["config"]
        _AGENTS[path] = (agent, bool(config.get("task_kwargs", {}).get("decisions")),
                         config.get("actions", "continuous"))
    return _AGENTS[path]


def episode(spec: tuple[str, str, int, str], index: int) -> dict:
    """Episode `index` of (task, policy, first seed, task keywords as JSON): its end and metrics (a fan-out job:
    depends only on its arguments)."""
    task, policy, seed, kwargs = spec
    if policy.startswith(CHECKPOINT):
        agent, decisions, actions = checkpoint_policy(policy.removeprefix(CHECKPOINT))
        env = task_env(task, decisions, kwargs, actions)

        def act(observation: dict):
            return agent.act({key: value[None] for key, value in observation.items()})[0]
    else:
        env = task_env(task, policy in DECISION_POLICIES, kwargs)
        act = make_policy(policy, env, seed + index)
    observation, info = env.reset(seed=seed + index)
    while True:
        observation, _, terminated, truncated, info = env.step(act(observation))
        if terminated or truncated:
            break
    end = ("success" if info["success"] else "collision" if info["collision"] else
           info["violation"] if info.get("violation") else "off_route" if info["off_route"] else "time_limit")
    task = env.unwrapped.task
    raw_p95, raw_max = task.comfort.unfiltered_jerk(task.control_dt)  # the same samples, finite differences
    return {"seed": seed + index, "end": end, "time": info["elapsed_time"], "speed": info["average_speed"],
            "jerk_p95": info["jerk_p95_mps3"], "jerk_max": info["jerk_max_mps3"],
            "accel_p95": info["accel_p95_mps2"], "jerk_p95_raw": raw_p95, "jerk_max_raw": raw_max,
            "scenario": info["scenario"]}


def run(task: str, policy: str, episodes: int, seed: int, workers: int = 0, ray: str | None = None,
        task_kwargs: dict | None = None) -> list[dict]:
    """Rows of episodes 0..episodes-1 in episode order, on `workers` processes (0: here) or Ray
    (`mjdrive.envs.fanout`): the same rows for any number of workers. `task_kwargs`: more task keywords (e.g.
    `road_users`)."""
    start, done = time.perf_counter(), [0]

    def report(index: int, row: dict) -> None:
        done[0] += 1
        print(f"[{done[0]}/{episodes}] seed {row['seed']}: {row['end']} after {row['time']:.1f} s "
              f"({time.perf_counter() - start:.0f} s)", file=sys.stderr, flush=True)

    kwargs = json.dumps(task_kwargs or {}, sort_keys=True)
    rows = fan_out(episode, (task, policy, seed, kwargs), range(episodes), workers=workers, ray=ray, on_result=report)
    for env in _ENVS.values():  # this process's (when the episodes ran here); workers' go with them
        env.close()
    _ENVS.clear()
    return [rows[i] for i in range(episodes)]


DRIVER_NAMES = {"rules": "rules + operative level"}  # else the policy's name
ENDS = ("success", "collision", "red_light", "stop_sign", "off_route", "time_limit")
SHOWN = 8  # failed episodes named per driver


def markdown(task: str, policies: str | list[str], rows: list[dict] | list[list[dict]], seed: int,
             checkpoints: dict[str, str] | None = None, task_kwargs: dict | None = None) -> str:
    """The table of one run: a row per driver (`checkpoints` by name, then `policies`, with their episodes'
    `rows` in that order), the paper's rows."""
    if isinstance(policies, str):
        policies, rows = [policies], [rows]
    checkpoints = checkpoints or {}
    n = len(rows[0])
    command = "".join(f' --checkpoint "{name}={path}"' for name, path in checkpoints.items())
    command += f" --policy {' '.join(policies)}" if policies else ""
    command += "".join(f" --task-kwarg '{key}={json.dumps(value)}'" for key, value in (task_kwargs or {}).items())
    names = [*checkpoints, *(DRIVER_NAMES.get(p, p) for p in policies)]
    lines = [f"# Table 2 on urban/{task}: {', '.join(names)}", "",
             f"`python -m tools.urban_table2 --task {task}{command} --episodes {n} "
             f"--seed {seed}`: {n} episodes per driver (seeds {seed}-{seed + n - 1}). Means over episodes (comfort, "
             "time and speed over the successful ones), beside the paper's rows (CARLA Town03, its own route and "
             "traffic: a comparison of magnitudes, not of the same world). Comfort: the chassis in the car's heading "
             "frame, sampled at the control rate, Savitzky-Golay smoothed over 0.5 s (docs/summary.md: it passes 63% "
             "of a 1 Hz jerk oscillation's amplitude); the last two columns are the same samples' jerk by finite "
             "differences, unfiltered (the paper does not say how it filtered).", "",
             "| driver | " + " | ".join(COLUMNS) + " |", "| --- |" + " ---: |" * len(COLUMNS)]
    notes = []
    for policy, episodes in zip([*checkpoints, *policies], rows, strict=True):
        ok = [r for r in episodes if r["end"] == "success"]
        mean = (lambda key, ok=ok: float(np.mean([r[key] for r in ok])) if ok else float("nan"))  # noqa: E731
        ours = (100.0 * len(ok) / len(episodes), mean("jerk_p95"), mean("jerk_max"), mean("accel_p95"),
                mean("time"), mean("speed"), mean("jerk_p95_raw"), mean("jerk_max_raw"))
        lines.append(f"| mjdrive {DRIVER_NAMES.get(policy, policy)} | " + " | ".join(f"{v:.2f}" for v in ours)
                     + " |")
        ends = {e: sum(r["end"] == e for r in episodes) for e in ENDS}
        failed = [r for r in episodes if r["end"] != "success"]
        note = f"{policy}: " + ", ".join(f"{k} {e}" for e, k in ends.items())
        if failed:
            note += "; did not arrive: " + ", ".join(
                f"seed {r['seed']} ({r['end']} in {r['scenario']} at {r['time']:.0f} s)" for r in failed[:SHOWN])
            note += f" and {len(failed) - SHOWN} more" if len(failed) > SHOWN else ""
        notes.append(note + ".")
    lines += [f"| {name} | " + " | ".join(f"{v:.2f}" for v in values) + " | - | - |" for name, values in PAPER.items()]
    return "\n".join(lines + ["", "Ends: " + " ".join(notes)]) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--task", default="concatenated", choices=("roundabout", "lane_change", "crossroad",
                                                                   "merge", "concatenated"))
    parser.add_argument("--policy", nargs="*", default=None, choices=POLICIES,
                        help="one or more built-in drivers, a row each (default: autopilot, unless checkpoints are "
                             "given)")
    parser.add_argument("--checkpoint", action="append", default=[], metavar="NAME=PATH",
                        help="a trained policy (e.g. a hybrid checkpoint) as the row NAME; repeatable, rows first")
    parser.add_argument("--episodes", type=int_at_least(1), default=200)
    parser.add_argument("--seed", type=int_at_least(0), default=20000, help="seed of the first episode")
    parser.add_argument("--workers", type=int_at_least(0), default=0, metavar="N",
                        help="worker processes (0: run the episodes here, in order); same rows for any N")
    parser.add_argument("--ray", default=None, metavar="ADDRESS",
                        help="run the episodes as Ray tasks ('local' for a private Ray of --workers CPUs)")
    parser.add_argument("--task-kwarg", action="append", default=[], metavar="KEY=VALUE",
                        help="a task keyword for every driver, e.g. road_users='{\"car\": 13}' (repeatable)")
    parser.add_argument("--out", default=None, help="write the markdown table here")
    args = parser.parse_args(argv)
    task_kwargs = parse_task_kwargs(args.task_kwarg)
    if "decisions" in task_kwargs:
        parser.error("--task-kwarg decisions=...: each driver sets it (the decision drivers and checkpoints use them)")
    config_class, defaults = suite.task_config("urban", args.task)
    config_class.from_dict(task_kwargs, defaults, where=f"urban/{args.task}")  # a bad keyword: its one-line error
    checkpoints = {}
    for item in args.checkpoint:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            parser.error(f"--checkpoint {item!r}: write NAME=PATH")
        if not Path(path).is_file():
            parser.error(f"--checkpoint {item!r}: no file {path}")
        checkpoint_policy(path)  # a bad checkpoint: its one-line error before any episode runs
        checkpoints[name] = path
    policies = args.policy if args.policy is not None else ([] if checkpoints else ["autopilot"])
    drivers = [CHECKPOINT + path for path in checkpoints.values()] + policies
    rows = [run(args.task, driver, args.episodes, args.seed, args.workers, args.ray, task_kwargs)
            for driver in drivers]
    text = markdown(args.task, policies, rows, args.seed, checkpoints, task_kwargs)
    publish(text, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
