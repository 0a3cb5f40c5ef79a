"""The loop SAC and DQN share: act in a vector env (`mjdrive.envs.vector`: in process, worker processes or Ray),
store transitions, update from replay, log, checkpoint.

An off-policy agent provides:
    explore(obs, step) -> (stored_action, env_action)   batched; random before `learning_starts`
    update(batch) -> dict[str, float]                   one gradient step on a replay batch
    state_dict() / load_state_dict(state)               networks, optimizers, counters

Optionally a second buffer of demonstrations by a scripted driver (`collect_demonstrations`) supplies a fixed
fraction of every update batch, as in RLPD (Ball et al. 2023, "Efficient online reinforcement learning with
offline data": symmetric sampling of offline and online data, no pre-training).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from mjdrive.agents.env_factory import training_tasks
from mjdrive.agents.networks import bounded_action_map
from mjdrive.agents.observations import ObsBatch
from mjdrive.agents.replay import ReplayBuffer
from mjdrive.agents.run_log import Run
from mjdrive.envs.vector import VecEnv

DEMONSTRATION_DEFAULTS = {
    "policy": "autopilot",  # a scripted policy of mjdrive.policies (privileged: it reads the task's state)
    "steps": 20_000,  # [transitions] collected before training, kept for the whole run
    "fraction": 0.5,  # of every update batch drawn from the demonstrations (RLPD: 0.5)
}
DEMONSTRATORS = ("autopilot", "pure_pursuit")  # the scripted drivers of mjdrive.policies worth imitating
REPLAY_DIR = "replay"  # in a run folder: the buffer saved when training is interrupted (ReplayBuffer.save)


def run_off_policy(agent: Any, env: VecEnv, run: Run, buffer: ReplayBuffer, hp: dict, seed: int,
                   demonstrations: ReplayBuffer | None = None, demo_fraction: float = 0.0,
                   experience: int = 0) -> None:
    """Train `agent` until `run.total_steps` env steps; `hp`: learning_starts, batch_size, updates_per_step,
    reward_scale, log_every, resume_refill. With `demonstrations`, `demo_fraction` of each batch comes from them.
    `experience`: env steps the agent's networks were trained for in another run (`init_from`); exploration
    (random actions before `learning_starts`, DQN's epsilon) goes on from there.

    A resumed or initialized run whose buffer holds fewer than `resume_refill` transitions (periodic
    checkpoints do not keep it) collects them with the loaded policy before updating again, since gradient
    steps on a few hundred fresh transitions overfit the critics and undo the learned policy. Stopped by
    Ctrl-C or SIGTERM (KeyboardInterrupt), the loop saves checkpoint.pt and the buffer (`run.out/replay/`)
    at the current step before re-raising, so `--resume` goes on without the refill."""
    obs, _ = env.reset(seed=seed + run.step)  # a resumed run does not replay its first episodes
    learning_starts = int(hp.get("learning_starts", 1000))
    updates_per_step = float(hp.get("updates_per_step", 1.0))  # gradient steps per env transition
    reward_scale = float(hp.get("reward_scale", 1.0))
    log_every = int(hp.get("log_every", 1000))
    batch_size = int(hp["batch_size"])
    demo_batch = round(batch_size * demo_fraction) if demonstrations is not None and demonstrations.size else 0
    demo_rows = torch.arange(batch_size) >= batch_size - demo_batch  # which rows of a batch are demonstrations
    min_buffer = batch_size  # transitions in the buffer before updates
    if run.step > 0 or experience > 0:
        min_buffer = max(min_buffer, min(int(hp.get("resume_refill", 10_000)), buffer.capacity))
    start_step, start_time, debt, next_log = run.step, time.perf_counter(), 0.0, run.step + log_every
    losses: dict[str, list[float]] = {}
    try:
        while not run.done:
            stored, command = agent.explore(obs, run.step + experience)
            next_obs, reward, terminated, _, info = env.step(command)
            # the true next observation of an ended episode is its final one, not the auto-reset one
            buffer.add(obs, stored, reward * reward_scale, info["final_observation"], terminated)
            obs = next_obs
            run.add_steps(env.num_envs, info["final_info"])
            if run.step + experience >= learning_starts and buffer.size >= min_buffer:
                debt += updates_per_step * env.num_envs
                while debt >= 1.0:
                    batch = buffer.sample(batch_size - demo_batch)
                    if demo_batch:
                        batch = concat_batches(batch, demonstrations.sample(demo_batch))
                        batch["demonstration"] = demo_rows
                    for name, value in agent.update(batch).items():
                        losses.setdefault(name, []).append(value)
                    debt -= 1.0
            if run.step >= next_log:
                run.scalars({name: float(np.mean(values)) for name, values in losses.items()})
                run.scalar("perf/steps_per_s", (run.step - start_step) / (time.perf_counter() - start_time))
                losses.clear()
                next_log += log_every
            if run.checkpoint_due():
                run.save(agent.algo, agent.state_dict(), {"experience": experience})
    except KeyboardInterrupt:
        run.save(agent.algo, agent.state_dict(), {"experience": experience}, periodic=False)
        buffer.save(run.out / REPLAY_DIR, run.step)
        print(f"\ninterrupted at env step {run.step:,}: saved {run.out / 'checkpoint.pt'} and its "
              f"{buffer.size:,} replay transitions ({run.out / REPLAY_DIR}); continue with --resume", flush=True)
        raise
    if losses:
        run.scalars({name: float(np.mean(values)) for name, values in losses.items()})
    run.save(agent.algo, agent.state_dict(), {"experience": experience}, periodic=False)


def concat_batches(first: dict, second: dict) -> dict:
    """Two replay samples (ReplayBuffer.sample) as one."""
    out = {}
    for key, value in first.items():
        if isinstance(value, ObsBatch):
            image = None if value.image is None else torch.cat([value.image, second[key].image])
            out[key] = ObsBatch(torch.cat([value.features, second[key].features]), image)
        else:
            out[key] = torch.cat([value, second[key]])
    return out


def demonstration_settings(config: dict) -> dict:
    """The config's `demonstrations` merged over DEMONSTRATION_DEFAULTS; ValueError for unknown keys, a
    fraction outside [0, 1), a policy not in DEMONSTRATORS, or actions other than continuous/pedal."""
    settings = {**DEMONSTRATION_DEFAULTS, **config["demonstrations"]}
    unknown = set(settings) - set(DEMONSTRATION_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown demonstrations settings {sorted(unknown)}; valid: {sorted(DEMONSTRATION_DEFAULTS)}")
    if not 0.0 <= float(settings["fraction"]) < 1.0:
        raise ValueError(f"demonstrations.fraction must be in [0, 1), got {settings['fraction']}")
    if settings["policy"] not in DEMONSTRATORS:
        raise ValueError(f"unknown policy {settings['policy']!r} for demonstrations; valid: {', '.join(DEMONSTRATORS)}")
    actions = config.get("actions", "continuous")
    if actions not in ("continuous", "pedal"):
        raise ValueError(f"demonstrations need continuous or pedal actions, the config has {actions!r}")
    return settings


def collect_demonstrations(config: dict, buffer: ReplayBuffer, settings: dict, seed: int,
                           progress: bool = True) -> dict[str, int]:
    """Fill `buffer` with `settings["steps"]` transitions of the scripted `settings["policy"]` driving the
    config's task (settings checked by `demonstration_settings`; actions converted to the learner's action set,
    rewards scaled by `reward_scale` like the online ones); returns the counts of episodes, successes and
    collisions."""
    from tqdm import tqdm

    from mjdrive.envs import make_env
    from mjdrive.policies import make_policy

    actions = config.get("actions", "continuous")
    domain, names = training_tasks(config)  # episodes go through `task` and `mix_tasks` in turn
    envs = [make_env(domain, name, actions=actions, **config.get("task_kwargs", {})) for name in names]
    policies = [make_policy(settings["policy"], each, seed + k) for k, each in enumerate(envs)]
    env, policy = envs[0], policies[0]
    space = env.action_space
    scale, bias = (t.numpy() for t in bounded_action_map(space))
    reward_scale = float(config.get("reward_scale", 1.0))
    counts = {"episodes": 0, "success": 0, "collision": 0}
    obs, _ = env.reset(seed=seed + 10**9)
    bar = tqdm(total=int(settings["steps"]), unit="step", desc=f"demonstrations ({settings['policy']})",
               disable=not progress, dynamic_ncols=True)
    try:
        for _ in range(int(settings["steps"])):
            throttle, steer, brake = policy(obs)
            action = np.array([throttle - brake, steer], np.float32) if actions == "pedal" else \
                np.array([throttle, steer, brake], np.float32)
            action = np.clip(action, space.low, space.high)
            next_obs, reward, terminated, truncated, info = env.step(action)
            stored = (action - bias) / scale  # the learner's [-1, 1] box
            buffer.add({k: v[None] for k, v in obs.items()}, stored[None], np.array([reward * reward_scale]),
                       {k: v[None] for k, v in next_obs.items()}, np.array([terminated]))
            obs = next_obs
            bar.update(1)
            if terminated or truncated:
                counts["episodes"] += 1
                counts["success"] += bool(info.get("success"))
                counts["collision"] += bool(info.get("collision"))
                env, policy = envs[counts["episodes"] % len(envs)], policies[counts["episodes"] % len(envs)]
                obs, _ = env.reset(seed=seed + 10**9 + counts["episodes"])
    finally:
        bar.close()
        for each in envs:
            each.close()
    return counts
