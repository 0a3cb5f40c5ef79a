"""`mjdrive train`: one entry point over every learner (config in, run folder out).

A run folder holds config.yaml, episodes.csv, tb/ (TensorBoard), checkpoint.pt (latest, full state),
checkpoints/step_N.pt (periodic) and policy.pt (the acting network only, for evaluation and results/).
"""

from __future__ import annotations

import contextlib
import copy
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np
import torch

from mjdrive import suite
from mjdrive.agents.algorithms import agent_class
from mjdrive.agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint
from mjdrive.agents.env_factory import make_training_env, training_tasks
from mjdrive.agents.replay import ReplayBuffer
from mjdrive.agents.run_log import Run
from mjdrive.agents.seeding import set_seed

# the entries of each learner's state that acting needs (policy.pt keeps only these)
INFERENCE_KEYS = {"sac": ("actor",), "dqn": ("q",), "ppo": ("actor_state_dict",), "trpo": ("policy",),
                  "ppo_discrete": ("policy",)}
# config keys that must match to resume a run
RESUME_KEYS = ("algo", "task", "mix_tasks", "task_kwargs", "actions", "num_envs", "algorithm", "rsl_rl")
# algorithm keys a resumed run may change (fine-tuning at a lower learning rate); the rest must match
RESUME_TUNABLE = {"sac": ("actor_lr", "critic_lr", "resume_refill", "freeze_encoder", "bc_alpha", "autotune"),
                  "dqn": ("lr", "resume_refill")}
SAC_NETWORK_KEYS = ("hidden", "cnn", "log_std_range")  # what a SAC policy.pt must share with a run it starts


def check_resumable(saved: dict, config: dict, keys: tuple[str, ...] = RESUME_KEYS, action: str = "resume") -> None:
    """Raise CheckpointError unless `config` may continue the run saved with config `saved` (`keys` must match,
    the algorithm's RESUME_TUNABLE keys aside)."""
    tunable = RESUME_TUNABLE.get(config.get("algo"), ())
    for key in keys:
        old, new = saved.get(key), config.get(key)
        if key == "algorithm" and isinstance(old, dict) and isinstance(new, dict):
            old = {k: v for k, v in old.items() if k not in tunable}
            new = {k: v for k, v in new.items() if k not in tunable}
        if old != new:
            hint = f" (it may change only {', '.join(tunable)})" if key == "algorithm" and tunable else ""
            raise CheckpointError(f"cannot {action}: config '{key}' differs from the checkpoint's "
                                  f"({saved.get(key)!r} vs {config.get(key)!r}){hint}")


def load_initial_state(path: str | Path, config: dict) -> tuple[dict, int, bool]:
    """(learner state, its env steps of experience, whether it is the acting network only) of checkpoint `path`
    for a new run `config` to start from (`init_from`): the same learner, actions and algorithm settings
    (learning rates aside); the task and its observation may differ. A SAC policy.pt (acting network only) may
    start a run whose new critics learn first (`algorithm.critic_warmup` updates); then only the network
    settings must match."""
    algo = config.get("algo")
    if algo not in RESUME_TUNABLE:
        raise CheckpointError(f"init_from: only {', '.join(RESUME_TUNABLE)} runs can start from another run's "
                              f"networks, not {algo!r}")
    payload = load_checkpoint(path, algo)
    experience = int(payload["step"]) + int(payload["extra"].get("experience", 0))
    if not payload["extra"].get("inference_only"):
        check_resumable(payload["config"], config, ("algo", "actions", "algorithm"), f"start from {path}")
        return payload["state"], experience, False
    if algo != "sac" or int(config.get("algorithm", {}).get("critic_warmup", 0)) <= 0:
        raise CheckpointError(f"init_from: {path} holds only the acting network (a policy.pt); start from a full "
                              "checkpoint (a run's checkpoint.pt or checkpoints/step_N.pt)"
                              + (", or set algorithm.critic_warmup > 0 so that new critics learn before the actor"
                                 if algo == "sac" else ""))
    check_resumable(payload["config"], config, ("algo", "actions"), f"start from {path}")
    from mjdrive.agents.sac import DEFAULTS

    def network(settings: dict) -> dict:
        return {key: {**DEFAULTS, **settings.get("algorithm", {})}[key] for key in SAC_NETWORK_KEYS}

    check_resumable({"algorithm": network(payload["config"])}, {"algorithm": network(config)}, ("algorithm",),
                    f"start from {path}")
    return payload["state"], experience, True


def check_task_kwargs(config: dict) -> None:
    """The config's task keywords, checked against every task it trains on: ValueError in one line naming a bad
    one (`actions`, the action set, is the config's own key, not a task keyword)."""
    kwargs = dict(config.get("task_kwargs") or {})
    if "actions" in kwargs:
        raise ValueError(f"'actions' is not a task keyword: the action set is the config's `actions` (here "
                         f"{config.get('actions', 'continuous')!r}); set it with --set actions=NAME")
    domain, tasks = training_tasks(config)
    for task in tasks:
        config_class, defaults = suite.task_config(domain, task)
        config_class.from_dict(kwargs, defaults, where=f"{domain}/{task}")


def train(config: dict, out: str | Path, resume: bool = False, progress: bool = True) -> Path:
    """Train the learner `config["algo"]` for `config["steps"]` env steps; returns the policy.pt path.

    `resume=True` continues from out/checkpoint.pt (networks, optimizers, step and episode counters). An
    off-policy replay buffer comes back too if training was interrupted (Ctrl-C, SIGTERM: out/replay/ is saved
    at checkpoint.pt's step); after a crash or from a periodic checkpoint it refills from the resumed policy
    (`resume_refill`). SAC and DQN may resume
    with other learning rates (RESUME_TUNABLE), e.g. to fine-tune a checkpoint at a lower one.
    `config["init_from"]` (SAC/DQN, a new run): start from that checkpoint's networks and optimizer state
    on another task or observation (e.g. another camera); counters and the replay buffer start empty. A SAC
    policy.pt works too with `algorithm.critic_warmup` > 0: its actor and encoder, with new critics.
    """
    config = copy.deepcopy(config)
    algo = config.get("algo")
    agent_class(algo)  # validates the name early
    out = Path(out)
    torch.set_num_threads(int(config.get("torch_threads", 1)))
    seed = int(config.get("seed", 0))
    set_seed(seed)
    start_step, start_episode, state, experience, acting_only = 0, 0, None, 0, False
    if resume:
        payload = load_checkpoint(out / "checkpoint.pt", algo)
        check_resumable(payload["config"], config)
        start_step, state = payload["step"], payload["state"]
        start_episode = payload["extra"].get("episode", 0)
        experience = payload["extra"].get("experience", 0)  # of the networks a run started from (init_from)
        set_seed(seed + start_step)
    elif config.get("init_from"):
        state, experience, acting_only = load_initial_state(config["init_from"], config)
    run = Run(out, config, total_steps=int(config["steps"]), start_step=start_step,
              start_episode=start_episode, progress=progress, tensorboard=config.get("tensorboard", True))
    stack = contextlib.ExitStack()
    try:
        if algo == "ppo":
            from mjdrive.agents import ppo

            ppo.train(config, run, state)
        elif algo == "trpo":
            from mjdrive.agents import trpo

            trpo.train(config, run, state)
        elif algo == "ppo_discrete":
            from mjdrive.agents import ppo_discrete

            ppo_discrete.train(config, run, state)
        else:
            from mjdrive.agents.off_policy import (
                REPLAY_DIR,
                collect_demonstrations,
                demonstration_settings,
                run_off_policy,
            )

            env = make_training_env(config)
            stack.callback(env.close)
            agent = agent_class(algo)(config, env.single_observation_space, env.single_action_space)
            if state is not None:
                agent.load_state_dict(state, inference_only=acting_only)
            discrete = algo == "dqn"
            buffer = ReplayBuffer(min(agent.hp["buffer_size"], int(config["steps"])), agent.layout,
                                  () if discrete else env.single_action_space.shape,
                                  np.int64 if discrete else np.float32)
            if resume and (out / REPLAY_DIR).is_dir():
                restore_replay(buffer, out / REPLAY_DIR, start_step)
            hp = {**agent.hp, "reward_scale": config.get("reward_scale", 1.0),
                  "log_every": config.get("log_every", 1000)}
            demonstrations, fraction = None, 0.0
            if config.get("demonstrations"):
                settings = demonstration_settings(config)
                demonstrations = ReplayBuffer(int(settings["steps"]), agent.layout, buffer.actions.shape[1:],
                                              buffer.actions.dtype)
                counts = collect_demonstrations(config, demonstrations, settings, seed, progress)
                (out / "demonstrations.json").write_text(json.dumps({**settings, **counts}, indent=1))
                fraction = float(settings["fraction"])
            run_off_policy(agent, env, run, buffer, hp, seed, demonstrations, fraction, experience)
    finally:
        stack.close()  # the env (and its workers), also on Ctrl-C or an error
        run.close()
    return export_policy(out / "checkpoint.pt", out / "policy.pt")


def restore_replay(buffer: ReplayBuffer, directory: Path, step: int) -> None:
    """Load the replay buffer an interrupted run saved; one that does not fit (saved at another step, e.g. the
    run crashed after a later periodic checkpoint, or for other shapes; unreadable) is reported and left out."""
    try:
        buffer.load(directory, step)
    except (ValueError, OSError, KeyError) as error:
        print(f"not restoring the replay buffer: {error}; refilling it from the resumed policy", flush=True)
        return
    print(f"restored {buffer.size:,} replay transitions from {directory}", flush=True)


def export_policy(checkpoint: str | Path, out: str | Path) -> Path:
    """A small checkpoint with only the acting network (same format, `extra.inference_only`)."""
    payload = load_checkpoint(checkpoint)
    keys = INFERENCE_KEYS[payload["algo"]]
    state = {key: payload["state"][key] for key in keys}
    return save_checkpoint(out, payload["algo"], payload["config"], state, payload["step"],
                           {**payload["extra"], "inference_only": True})


def train_command(args) -> int:
    """`mjdrive train` (argument parsing lives in mjdrive/cli.py)."""
    from mjdrive.agents.config import apply_overrides, load_config

    config = load_config(args.config or args.algo)
    if args.config is None and config.get("algo") != args.algo:
        raise ValueError(f"config {args.algo!r} is for {config.get('algo')!r}")
    overrides = list(args.set)
    if args.task:
        overrides.append(f"task={args.task}")
    if args.steps is not None:
        overrides.append(f"steps={args.steps}")
    if args.seed is not None:
        overrides.append(f"seed={args.seed}")
    if args.num_envs is not None:
        overrides.append(f"num_envs={args.num_envs}")
    if getattr(args, "workers", None) is not None:
        overrides.append(f"workers={args.workers}")
    overrides += [f"task_kwargs.{pair}" for pair in args.task_kwarg]
    config = apply_overrides(config, overrides)
    if getattr(args, "ray", None) is not None:
        config["ray"] = args.ray  # "local", "auto" or HOST:PORT: the copies run in Ray actors
    if args.record_dir:
        config["record_dir"] = args.record_dir  # one MCAP log per training episode, per env copy
    out = args.out or f"runs/{config['algo']}_{config['task'].replace('/', '_')}_seed{config.get('seed', 0)}"
    check_task_kwargs(config)  # a bad task keyword: one line, before the run folder is written

    def stop(signum, frame):  # SIGTERM (kill, a cluster's time limit) stops like Ctrl-C: state saved, see train
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    start = time.perf_counter()
    try:
        policy = train(config, out, resume=args.resume, progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"training stopped; {out}/checkpoint.pt holds the latest saved state (resume with --resume)",
              file=sys.stderr)
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    steps = load_checkpoint(policy)["step"]  # PPO rounds up to whole rollouts (it said so when it began)
    asked = "" if steps == config["steps"] else f" (asked {config['steps']:,})"
    print(f"trained {config['algo']} on {config['task']} for {steps:,} env steps{asked} in "
          f"{time.perf_counter() - start:.0f} s; wrote {out}/ (policy: {policy})")
    return 0
