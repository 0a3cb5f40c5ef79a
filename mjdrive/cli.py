"""`mjdrive list | run | drive | bench | replay | logs | train | eval | ensemble | hybrid`: the command line."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from mjdrive.config import parse_task_kwargs
from mjdrive.policies import POLICIES
from mjdrive.run_folder import fresh_folder

MAX_SEED = 2**32 - 1


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """--help with each option's default: `(default: X)` after its help, lists written as on the command line
    (none: `none`); left out where the help already says its default, for required options and for on/off
    flags (off unless given). An option whose default is None says in its help what that means."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        said = "default:" in text or "by default" in text
        if (said or action.required or default is None or default is argparse.SUPPRESS or not action.option_strings
                or isinstance(action, argparse._StoreConstAction)):
            return text
        if isinstance(default, bool):  # --x/--no-x
            shown = "on" if default else "off"
        elif isinstance(default, (list, tuple)):
            shown = " ".join(str(item) for item in default) or "none"
        else:
            shown = str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


class ArgumentParser(argparse.ArgumentParser):
    """argparse with one-line errors (exit status 2) and the defaults shown in --help."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def int_at_least(low: int, high: int | None = None):
    """argparse type: an integer in [low, high]."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < low or (high is not None and value > high):
            bound = f">= {low}" if high is None else f"in {low}..{high}"
            raise argparse.ArgumentTypeError(f"must be {bound}, got {value}")
        return value

    return parse


def float_at_least(low: float, strict: bool):
    """argparse type: a finite number > low (`strict`) or >= low."""
    sign = ">" if strict else ">="

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not ((value > low if strict else value >= low) and value < float("inf")):
            raise argparse.ArgumentTypeError(f"must be a finite number {sign} {low:g}, got {text}")
        return value

    return parse


positive_float = float_at_least(0.0, strict=True)
non_negative_float = float_at_least(0.0, strict=False)


def existing_path(kind: str):
    """argparse type: a path to an existing `kind` ("file" or "folder")."""
    other = "folder" if kind == "file" else "file"

    def parse(text: str) -> str:
        path = Path(text)
        if not path.exists():
            raise argparse.ArgumentTypeError(f"{text}: no such {kind}")
        if path.is_file() != (kind == "file"):
            raise argparse.ArgumentTypeError(f"{text} is a {other}, not a {kind}")
        return text

    return parse


existing_file = existing_path("file")
existing_folder = existing_path("folder")


def task_name(text: str) -> str:
    """argparse type: DOMAIN/TASK of a registered task."""
    from mjdrive import suite

    try:
        suite.task_config(*suite.split_task(text))
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return text


def _check_kwargs(domain: str, task: str, task_kwargs: dict) -> None:
    """Validate task keywords before anything is built or printed (a mistake gives its one-line error)."""
    from mjdrive import suite

    config_class, defaults = suite.task_config(domain, task)
    config_class.from_dict(task_kwargs, defaults, where=f"{domain}/{task}")


def sensor_names(text: str) -> tuple[str, ...]:
    """argparse type: comma-separated extra sensors (depth, segmentation, range)."""
    from mjdrive.sensors import SENSORS

    names = tuple(name for name in text.split(",") if name)
    unknown = [name for name in names if name not in SENSORS]
    if unknown:
        raise argparse.ArgumentTypeError(f"unknown sensor {unknown[0]!r}; sensors: {', '.join(SENSORS)}")
    return names


def add_live_arguments(parser: argparse.ArgumentParser) -> None:
    """--live, --live-port, --live-host: stream the log's channels to the Foxglove app while it runs."""
    parser.add_argument("--live", action="store_true",
                        help="also stream the MCAP log's channels to Foxglove (Open connection > Foxglove "
                             "WebSocket, ws://HOST:PORT) while the episodes run")
    parser.add_argument("--live-port", type=int_at_least(0, 65535), default=8765, help="port of the live stream "
                        "(0: any free port)")
    parser.add_argument("--live-host", default="127.0.0.1", help="address the live stream binds (0.0.0.0: "
                        "reachable from other machines)")


def record_options(args, **options):
    """RecordOptions of a command's arguments (its live stream included); announces the live URL."""
    from mjdrive.record import RecordOptions

    if args.live:
        options.update(live_port=args.live_port, live_host=args.live_host)
    return RecordOptions(**options)


def cmd_list(args) -> int:
    from mjdrive import suite
    from mjdrive.envs import GYM_IDS

    if args.kwargs == "all":
        print(suite.kwargs_reference(), end="")
        return 0
    if args.kwargs:
        domain, task = suite.split_task(args.kwargs)
        config_class, defaults = suite.task_config(domain, task)
        print(f"keywords of {domain}/{task} (suite.load(..., task_kwargs={{...}}), --task-kwarg KEY=VALUE):")
        print(config_class.markdown(defaults))
        return 0
    rows = []
    for domain, task in suite.ALL_TASKS:
        tags = [tag for tag in suite.TAGS if (domain, task) in suite.tasks_with_tag(tag)]
        doc = (suite.task_description(domain, task) or "").split("\n")[0]
        rows.append((f"{domain}/{task}", ", ".join(tags), doc))
    width = [max(len(row[i]) for row in rows) for i in range(2)]
    print("dm_control tasks (mjdrive.suite.load(domain, task); keywords: mjdrive list --kwargs DOMAIN/TASK):")
    print(f"  {'task':<{width[0]}}  {'tags':<{width[1]}}  description")
    for name, tags, doc in rows:
        print(f"  {name:<{width[0]}}  {tags:<{width[1]}}  {doc}")
    print("gymnasium ids (gymnasium.make(id)):")
    for env_id in GYM_IDS:
        print(f"  {env_id}")
    return 0


def _checked_task(args) -> tuple[str, str, dict]:
    """DOMAIN, TASK and validated task keywords of `run` / `drive` (a user's mistake before anything is built)."""
    from mjdrive import suite

    domain, task = suite.split_task(args.task)
    task_kwargs = parse_task_kwargs(args.task_kwarg)
    if args.live and not args.record:
        raise ValueError("--live streams the channels of the episode logs: drop --no-record")
    if args.sensors:  # the task keyword `sensors`: in the summary and the logs' task keywords like any other
        if "sensors" in task_kwargs:
            raise ValueError("give the sensors once: --sensors or --task-kwarg sensors=...")
        task_kwargs["sensors"] = list(args.sensors)
    _check_kwargs(domain, task, task_kwargs)
    return domain, task, task_kwargs


def cmd_run(args) -> int:
    from mjdrive.envs import make_env
    from mjdrive.policies import make_policy
    from mjdrive.progress import Progress, note
    from mjdrive.record.summary import document, end_reason, episode_row, roundabout_arms
    from mjdrive.video import EpisodeVideo, Overlay

    domain, task, task_kwargs = _checked_task(args)
    note(f"mjdrive run: building {args.task} ...")
    env = make_env(domain, task, **task_kwargs)  # bad keywords: reported before the folder
    out = fresh_folder(args.out, args.overwrite)
    policy = make_policy(args.policy, env, args.seed)
    if args.record:  # one MCAP file per episode in OUT (see mjdrive/record/recorder.py)
        from mjdrive.record import RecordEpisodes
        from mjdrive.record.live import announce_live

        env = RecordEpisodes(env, out, record_options(args, camera_every=args.record_camera_every,
                                                      image_format=args.record_image_format))
        announce_live(env)
    rows = []
    arms = roundabout_arms(domain, task, task_kwargs)  # to count the roundabout's exits from the entry
    run_start = time.perf_counter()
    for episode in range(args.episodes):
        seed = args.seed + episode
        observation, info = env.reset(seed=seed)
        video = EpisodeVideo(env, out / f"episode_{episode:03d}.mp4") if args.video else None
        total_reward, steps = 0.0, 0
        overlay = Overlay(info=info)
        control_dt = env.unwrapped.dm_env.control_timestep()  # [s]
        next_tick = time.perf_counter()
        with Progress(desc=f"episode {episode + 1}/{args.episodes} (seed {seed})", unit="step",
                      total=env.unwrapped.max_episode_steps, leave=False) as bar:
            while True:
                if video:
                    video.add_frame(overlay)
                observation, reward, terminated, truncated, info = env.step(policy(observation))
                total_reward += reward
                steps += 1
                overlay = Overlay(steps, reward, total_reward, info)
                bar.update()
                if args.realtime:  # paced, e.g. to watch it live in Foxglove
                    next_tick += control_dt / args.realtime
                    time.sleep(max(0.0, next_tick - time.perf_counter()))
                if terminated or truncated:
                    break
        if video:
            overlay.outcome = end_reason(info, terminated, truncated)
            video.add_frame(overlay)
            video.close()
        log = Path(info["record_path"]).name if "record_path" in info else None
        rows.append(episode_row(info, episode=episode, seed=seed, reward=total_reward, steps=steps,
                                terminated=terminated, truncated=truncated, arms=arms, log=log,
                                control_dt=env.unwrapped.dm_env.control_timestep()))
        print(json.dumps(rows[-1]))
    summary = document("run", args.task, task_kwargs, args.policy, rows,
                       wall_s=round(time.perf_counter() - run_start, 1))
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(json.dumps({"summary": summary["summary"]}))
    print(f"wrote {out}/ ({'MCAP logs, ' if args.record else ''}{'videos, ' if args.video else ''}summary.json)")
    env.close()
    return 0


def cmd_drive(args) -> int:
    from mjdrive.drive import has_display
    from mjdrive.envs import make_env
    from mjdrive.progress import note
    from mjdrive.record.summary import document

    domain, task, task_kwargs = _checked_task(args)
    if not has_display():
        raise ValueError("drive opens a window: set DISPLAY (or run it under `xvfb-run`)")
    note(f"mjdrive drive: building {args.task} ...")
    env = make_env(domain, task, **task_kwargs)
    out = fresh_folder(args.out, args.overwrite)
    if args.record:
        from mjdrive.record import RecordEpisodes
        from mjdrive.record.live import announce_live

        env = RecordEpisodes(env, out, record_options(args))
        announce_live(env)
    from mjdrive.drive import HELP, StopRequests, drive

    note(f"mjdrive drive: {HELP}")
    start = time.perf_counter()
    stop = StopRequests()
    with stop.installed():  # SIGINT, SIGTERM, a window closed from outside: the log and summary still get written
        try:
            rows = drive(env, episodes=args.episodes, seed=args.seed, task_name=args.task, realtime=args.realtime,
                         on_episode=lambda row: print(json.dumps(row), flush=True), stop=stop)
        finally:
            env.close()
        summary = document("drive", args.task, task_kwargs, "keyboard", rows,
                           wall_s=round(time.perf_counter() - start, 1))
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if stop.requested:
        note(f"mjdrive drive: stopped: {stop.reason}")
    print(f"wrote {out}/ ({'MCAP logs, ' if args.record else ''}summary.json)")
    return 0


def cmd_replay(args) -> int:
    from mjdrive.envs.replay import replay

    result = replay(args.file, video=args.video, progress=True)
    print(result.report())
    return 0 if result.match else 1


def cmd_logs(args) -> int:
    from mjdrive.record.reader import logs_document, logs_rows, logs_table

    if not any(Path(args.folder).glob("*.mcap*")):
        raise ValueError(f"no .mcap logs in {args.folder}")
    read = logs_rows(args.folder, progress=True)
    table = logs_table(args.folder, read)
    print(table)
    if args.out and Path(args.out).suffix == ".json":
        Path(args.out).write_text(json.dumps(logs_document(args.folder, read), indent=2) + "\n")
    elif args.out:
        Path(args.out).write_text(table + "\n")
    return 0


def cmd_bench(args) -> int:
    from mjdrive.bench import bench_parts, run_benchmarks, run_roundabout_benchmarks, run_urban_benchmarks
    from mjdrive.bench_operative import OPERATIVE_PARTS, run_operative_benchmark
    from mjdrive.bench_sensors import SENSOR_PARTS, run_sensor_benchmarks
    from mjdrive.progress import Progress

    parts = []
    total = (bench_parts(args.tasks, args.roundabout, args.highway, args.urban) + SENSOR_PARTS * len(args.sensors)
             + OPERATIVE_PARTS * args.operative)
    with Progress(total=total, desc="bench", unit="part") as bar:
        def tick(label: str) -> None:
            bar.set_postfix_str(label, refresh=False)
            bar.update()

        if args.tasks:
            parts.append(run_benchmarks(args.tasks, seconds=args.seconds, image_size=args.image_size, tick=tick))
        if args.roundabout:
            parts.append(run_roundabout_benchmarks(args.roundabout, seconds=args.seconds, highway=args.highway,
                                                   tick=tick))
        if args.urban:
            parts.append(run_urban_benchmarks(args.urban, seconds=args.seconds, tick=tick))
        if args.sensors:
            parts.append(run_sensor_benchmarks(args.sensors, seconds=args.seconds, tick=tick))
        if args.operative:
            parts.append(run_operative_benchmark(seconds=args.seconds, tick=tick))
    report = "\n\n".join(parts)
    print(report)
    if args.out:
        Path(args.out).write_text(report + "\n")
        print(f"wrote {args.out}")
    return 0


def cmd_train(args) -> int:
    from mjdrive.progress import Starting

    with Starting("mjdrive train: loading torch, the config and the envs", delay=0.3):
        from mjdrive.agents.train import train_command  # needs the `learn` extra (torch, rsl-rl)

        return train_command(args)


def _say_when_not_a_terminal(message: str) -> None:
    """A plain status line on stdout when stderr is not a terminal (a log file hears that a slow start has
    begun; stderr keeps a user's mistake to one line)."""
    from mjdrive.progress import is_terminal

    if not is_terminal(sys.stderr):
        print(message, flush=True)


def cmd_eval(args) -> int:
    from mjdrive.progress import Starting

    if args.live and (getattr(args, "workers", 0) or getattr(args, "ray", None) or not args.record):
        raise ValueError("--live streams the episode logs of this process: drop --no-record, --workers and --ray")

    _say_when_not_a_terminal("mjdrive eval: loading torch and checking the checkpoint ...")
    with Starting("mjdrive eval: loading torch and checking the checkpoint", stdout_in_logs=True):
        from mjdrive.agents.checkpoints import load_checkpoint

        load_checkpoint(args.checkpoint)  # a bad file is a one-line error, before any status line in a log
    with Starting("mjdrive eval: loading the policy and the env", delay=0.0, stdout_in_logs=True):  # may still fail
        from mjdrive.agents.evaluate import eval_command

        return eval_command(args)


def cmd_ensemble(args) -> int:
    from mjdrive.progress import Starting

    _say_when_not_a_terminal("mjdrive ensemble: loading torch and the members ...")
    with Starting("mjdrive ensemble: loading torch and the members", stdout_in_logs=True):
        from mjdrive.agents.ensemble import ensemble_command

        return ensemble_command(args)


def cmd_hybrid(args) -> int:
    from mjdrive.progress import Starting

    _say_when_not_a_terminal("mjdrive hybrid: loading torch and the members ...")
    with Starting("mjdrive hybrid: loading torch and the members", stdout_in_logs=True):
        from mjdrive.agents.hybrid import hybrid_command

        return hybrid_command(args)


def build_parser() -> argparse.ArgumentParser:
    parser = ArgumentParser(prog="mjdrive", description="MuJoCo driving-simulation suite for RL.")
    sub = parser.add_subparsers(dest="command", required=True)

    listing = sub.add_parser("list", help="list tasks, tags and gymnasium ids; or one task's keywords")
    listing.add_argument("--kwargs", default=None, type=lambda text: text if text == "all" else task_name(text),
                         metavar="DOMAIN/TASK", help="print the task's keywords (type, default, unit, allowed "
                         "values); 'all': every task's, as markdown (default: list the tasks)")
    listing.set_defaults(func=cmd_list)

    run = sub.add_parser("run", help="drive a task with a policy; write videos and a summary")
    run.add_argument("--task", default="waypoints/four_routes", type=task_name, help="DOMAIN/TASK (see `mjdrive list`)")
    run.add_argument("--task-kwarg", action="append", default=[], metavar="KEY=VALUE",
                     help="task keyword argument, e.g. observation=camera buildings=true (repeatable)")
    run.add_argument("--policy", default="pure_pursuit", choices=POLICIES, help="the driver")
    run.add_argument("--episodes", type=int_at_least(1), default=1, help="episodes to drive")
    run.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=0, help="seed of the first episode")
    run.add_argument("--out", default="runs/demo", help="output folder (one run: it must be new or empty)")
    run.add_argument("--overwrite", action="store_true",
                     help="replace the run already in OUT (its logs, videos and summary; nothing else)")
    run.add_argument("--video", action=argparse.BooleanOptionalAction, default=True,
                     help="write an mp4 per episode (front camera | top view)")
    run.add_argument("--record", action=argparse.BooleanOptionalAction, default=True,
                     help="write an MCAP log per episode into OUT (Foxglove; see `mjdrive logs`, `mjdrive replay`)")
    run.add_argument("--record-camera-every", type=int_at_least(0), default=1, metavar="K",
                     help="log the front camera every K-th step (0: no images)")
    run.add_argument("--record-image-format", default="jpeg", choices=("jpeg", "png"),
                     help="compression of the logged camera images")
    run.add_argument("--realtime", type=non_negative_float, default=0.0, metavar="X",
                     help="run at X simulated seconds per wall second (1: as it happens, to watch with --live; "
                          "0: as fast as it goes)")
    run.add_argument("--sensors", type=sensor_names, default=(), metavar="NAMES",
                     help="extra observations, recorded in the logs: depth,segmentation,range (comma-separated; "
                     "the task keyword `sensors`)")
    add_live_arguments(run)
    run.set_defaults(func=cmd_run)

    drive = sub.add_parser("drive", help="drive a task by keyboard in MuJoCo's viewer; log each episode as MCAP")
    drive.add_argument("--task", default="roundabout/d120", type=task_name, help="DOMAIN/TASK (see `mjdrive list`)")
    drive.add_argument("--task-kwarg", action="append", default=[], metavar="KEY=VALUE",
                       help="task keyword argument, e.g. vehicle=suv (repeatable)")
    drive.add_argument("--episodes", type=int_at_least(0), default=0, help="episodes to drive (0: until the "
                       "window is closed)")
    drive.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=0, help="seed of the first episode")
    drive.add_argument("--realtime", type=positive_float, default=1.0, help="simulated seconds per wall second")
    drive.add_argument("--out", default="runs/drive", help="output folder (one run: it must be new or empty)")
    drive.add_argument("--overwrite", action="store_true", help="replace the run already in OUT")
    drive.add_argument("--record", action=argparse.BooleanOptionalAction, default=True,
                       help="write an MCAP log per episode into OUT")
    drive.add_argument("--sensors", type=sensor_names, default=(), metavar="NAMES",
                       help="extra sensors recorded in the logs: depth,segmentation,range (comma-separated; "
                       "the task keyword `sensors`)")
    add_live_arguments(drive)
    drive.set_defaults(func=cmd_drive)

    replay = sub.add_parser("replay", help="re-simulate a logged episode and check it matches bit for bit")
    replay.add_argument("file", type=existing_file, help="an episode's .mcap file")
    replay.add_argument("--video", default=None, metavar="OUT.mp4",
                        help="also render the replay to a video (default: none)")
    replay.set_defaults(func=cmd_replay)

    logs = sub.add_parser("logs", help="summarise a folder of episode logs as a markdown table")
    logs.add_argument("folder", type=existing_folder, help="a folder of .mcap episode files")
    logs.add_argument("--out", default=None,
                      help="also write the table to this file (FILE.json: the episodes in the summary schema; "
                      "default: print it only)")
    logs.set_defaults(func=cmd_logs)

    bench = sub.add_parser("bench", help="throughput: raw mj_step vs env steps, with and without camera")
    bench.add_argument("--tasks", nargs="*", type=task_name, default=["waypoints/straight", "waypoints/random_routes"],
                       help="tasks for the env-vs-raw table (none: skip it)")
    bench.add_argument("--roundabout", nargs="*", default=["d120", "d140", "d160", "d210"], metavar="LEVEL",
                       choices=("d120", "d140", "d160", "d210"),
                       help="roundabout densities for the roundabout table (none: skip it)")
    bench.add_argument("--urban", nargs="*", default=["concatenated"], metavar="TASK",
                       choices=("roundabout", "lane_change", "crossroad", "merge", "concatenated"),
                       help="urban tasks (study 002) for the urban table (none: skip it)")
    bench.add_argument("--highway", action=argparse.BooleanOptionalAction, default=True,
                       help="also run highway-env's roundabout-v0 when it is installed")
    bench.add_argument("--sensors", nargs="*", type=task_name, default=["roundabout/d120"], metavar="TASK",
                       help="tasks for the extra sensors' cost table: depth, segmentation, range ring (none: skip)")
    bench.add_argument("--operative", action=argparse.BooleanOptionalAction, default=True,
                       help="study 002's operative level: its MPC and per-step cost, decision env against the "
                            "throttle/steer/brake env")
    bench.add_argument("--seconds", type=positive_float, default=3.0, help="wall time per measurement [s]")
    bench.add_argument("--image-size", type=int_at_least(16, 1024), default=128, help="camera side [px]")
    bench.add_argument("--out", default=None, help="also write the report to this file (default: print it only)")
    bench.set_defaults(func=cmd_bench)

    train = sub.add_parser("train", help="train a learner (ppo, sac, dqn, trpo, ppo_discrete) on a task")
    train.add_argument("--algo", default="ppo", choices=("ppo", "sac", "dqn", "trpo", "ppo_discrete"),
                       help="the learner (config: agents/configs/ALGO.yaml)")
    train.add_argument("--config", default=None, help="config file, or name in agents/configs/ (e.g. ppo_camera; "
                       "default: agents/configs/ALGO.yaml)")
    train.add_argument("--task", default=None, type=task_name, help="DOMAIN/TASK (default: the config's)")
    train.add_argument("--task-kwarg", action="append", default=[], metavar="KEY=VALUE",
                       help="task keyword argument, e.g. observation=camera (repeatable)")
    train.add_argument("--steps", type=int_at_least(1), default=None, help="env steps (default: the config's)")
    train.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=None, help="seed (default: the config's)")
    train.add_argument("--num-envs", type=int_at_least(1, 1024), default=None,
                       help="env copies stepped together (default: the config's)")
    train.add_argument("--workers", type=int_at_least(0, 1024), default=None, metavar="N",
                       help="step the copies in N worker processes (num_envs a multiple of N; 0: in this process; "
                            "default: the config's)")
    train.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                       help="step the copies in --workers Ray actors: a local Ray (no ADDRESS), 'auto' (the cluster "
                            "of `ray start` on this machine) or HOST:PORT (pip install 'mjdrive[ray]'; "
                            "default: no Ray)")
    train.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                       help="config override, dots for nesting, e.g. algorithm.batch_size=128 (repeatable)")
    train.add_argument("--out", default=None, help="run folder (default: runs/ALGO_TASK_seedS)")
    train.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    train.add_argument("--record-dir", default=None, metavar="DIR",
                       help="also log every training episode as MCAP, copy i in DIR/env_i/ (off by default)")
    train.add_argument("--no-progress", action="store_true", help="no progress bar")
    train.set_defaults(func=cmd_train)

    evaluate = sub.add_parser("eval", help="evaluate a checkpoint: the study's table as markdown and JSON")
    evaluate.add_argument("--checkpoint", required=True, type=existing_file, help="a run's policy.pt or checkpoint.pt")
    evaluate.add_argument("--episodes", type=int_at_least(1), default=50, help="episodes to evaluate")
    evaluate.add_argument("--task", default=None, type=task_name,
                          help="DOMAIN/TASK (default: the one it was trained on)")
    evaluate.add_argument("--task-kwarg", action="append", default=[], metavar="KEY=VALUE",
                          help="task keyword argument, e.g. time_limit=20 (repeatable)")
    evaluate.add_argument("--seed", type=int_at_least(0, MAX_SEED), default=10_000, help="seed of the first episode")
    evaluate.add_argument("--stochastic", action="store_true", help="sample actions instead of greedy ones")
    evaluate.add_argument("--workers", type=int_at_least(0, 1024), default=0, metavar="N",
                          help="run the episodes in N worker processes (0: in this process); same results at any N")
    evaluate.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                          help="run the episodes as Ray tasks: a local Ray of --workers CPUs (no ADDRESS), 'auto' or "
                               "HOST:PORT (pip install 'mjdrive[ray]'; default: no Ray)")
    evaluate.add_argument("--out", default=None, help="write OUT.md and OUT.json (default: print the table only)")
    evaluate.add_argument("--record", action=argparse.BooleanOptionalAction, default=True,
                          help="write one MCAP log per episode")
    evaluate.add_argument("--record-dir", default=None,
                          help="where the logs go (default: OUT/ beside OUT.md, or runs/eval/CHECKPOINT/ without "
                               "--out); it must be new or empty")
    evaluate.add_argument("--overwrite", action="store_true",
                          help="replace the logs of an earlier evaluation in the logs folder")
    add_live_arguments(evaluate)
    evaluate.set_defaults(func=cmd_eval)

    ensemble = sub.add_parser("ensemble", help="combine trained policies into one that `eval` reads like a policy.pt")
    ensemble.add_argument("members", nargs="+", type=existing_file,
                          help="policy.pt or checkpoint files of runs on the same observation")
    ensemble.add_argument("--rule", default="min_pedal",
                          help="'mean' (the mean action) or 'min_pedal' (the smallest pedal with the mean steer, "
                               "pedal actions)")
    ensemble.add_argument("--out", required=True, help="the ensemble checkpoint to write")
    ensemble.set_defaults(func=cmd_ensemble)

    hybrid = sub.add_parser("hybrid", help="compose study 002's hybrid agent (a scenario selector over one decision "
                            "agent per scenario) into one checkpoint that `eval` reads like a policy.pt")
    hybrid.add_argument("--member", action="append", required=True, metavar="SCENARIO=CHECKPOINT",
                        help="the agent trained on urban/SCENARIO with decisions (roundabout, lane_change, crossroad, "
                             "merge); repeat per scenario (one left out decides 'drive' there)")
    hybrid.add_argument("--task", default="urban/concatenated", type=task_name,
                        help="the urban task the hybrid drives (default: urban/concatenated)")
    hybrid.add_argument("--out", required=True, help="the hybrid checkpoint to write")
    hybrid.set_defaults(func=cmd_hybrid)
    return parser


# the optional packages and the extra of mjdrive that installs each (pyproject.toml)
OPTIONAL_MODULES = {"matplotlib": "plot", "highway_env": "bench", "ray": "ray", "torch": "learn", "rsl_rl": "learn",
                    "tensorboard": "learn", "numba": "fast"}


def run_reporting_errors(prog: str, func: Callable[[], int | None]) -> int:
    """`func()`'s exit status; a user's mistake (a bad name, number, keyword, path or file: ValueError, OSError)
    prints one line `PROG: error: ...` and gives status 2 (MJDRIVE_DEBUG=1: the traceback instead), Ctrl-C 130;
    so does a missing optional package (OPTIONAL_MODULES), naming the extra that installs it.
    The `mjdrive` subcommands and the study tools (`python -m tools.NAME`) run through it."""
    try:
        return func() or 0
    except (ValueError, OSError) as error:  # bad names, keywords, files: a clear message, no traceback
        if os.environ.get("MJDRIVE_DEBUG"):
            raise
        message = " ".join(str(error).split()) or type(error).__name__
        print(f"{prog}: error: {message}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as error:
        package = (error.name or "").split(".")[0]
        if package not in OPTIONAL_MODULES or os.environ.get("MJDRIVE_DEBUG"):
            raise
        print(f"{prog}: error: this needs {package}, which is not installed: pip install "
              f"'mjdrive[{OPTIONAL_MODULES[package]}]' (or pip install -e '.[{OPTIONAL_MODULES[package]}]' in a "
              "clone)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130


def main(argv: list[str] | None = None) -> int:
    """Run a subcommand. A user's mistake (a bad name, number, keyword, path or file) prints one line and
    exits with status 2; set MJDRIVE_DEBUG=1 to see the traceback instead."""
    args = build_parser().parse_args(argv)
    return run_reporting_errors(f"mjdrive {args.command}", lambda: args.func(args))


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    sys.exit(main())
