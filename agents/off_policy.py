"""The loop SAC and DQN share: act in a BatchedEnv, store transitions, update from replay, log, checkpoint.

An off-policy agent provides:
    explore(obs, step) -> (stored_action, env_action)   batched; random before `learning_starts`
    update(batch) -> dict[str, float]                   one gradient step on a replay batch
    state_dict() / load_state_dict(state)               networks, optimizers, counters
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from agents.common import ReplayBuffer, Run
from mjdrive.envs.batched import BatchedEnv


def run_off_policy(agent: Any, env: BatchedEnv, run: Run, buffer: ReplayBuffer, hp: dict, seed: int) -> None:
    """Train `agent` until `run.total_steps` env steps; `hp`: learning_starts, batch_size, updates_per_step,
    reward_scale, log_every, resume_refill.

    A resumed run starts with an empty replay buffer (checkpoints do not keep it): it collects
    `resume_refill` transitions with the resumed policy before updating again, since gradient steps on a
    few hundred fresh transitions overfit the critics and undo the learned policy."""
    obs, _ = env.reset(seed=seed + run.step)  # a resumed run does not replay its first episodes
    learning_starts = int(hp.get("learning_starts", 1000))
    updates_per_step = float(hp.get("updates_per_step", 1.0))  # gradient steps per env transition
    reward_scale = float(hp.get("reward_scale", 1.0))
    log_every = int(hp.get("log_every", 1000))
    min_buffer = int(hp["batch_size"])  # transitions in the buffer before updates
    if run.step > 0:
        min_buffer = max(min_buffer, min(int(hp.get("resume_refill", 10_000)), buffer.capacity))
    start_step, start_time, debt, next_log = run.step, time.perf_counter(), 0.0, run.step + log_every
    losses: dict[str, list[float]] = {}
    while not run.done:
        stored, command = agent.explore(obs, run.step)
        next_obs, reward, terminated, _, info = env.step(command)
        # the true next observation of an ended episode is its final one, not the auto-reset one
        buffer.add(obs, stored, reward * reward_scale, info["final_observation"], terminated)
        obs = next_obs
        run.add_steps(env.num_envs, info["final_info"])
        if run.step >= learning_starts and buffer.size >= min_buffer:
            debt += updates_per_step * env.num_envs
            while debt >= 1.0:
                for name, value in agent.update(buffer.sample(hp["batch_size"])).items():
                    losses.setdefault(name, []).append(value)
                debt -= 1.0
        if run.step >= next_log:
            run.scalars({name: float(np.mean(values)) for name, values in losses.items()})
            run.scalar("perf/steps_per_s", (run.step - start_step) / (time.perf_counter() - start_time))
            losses.clear()
            next_log += log_every
        if run.checkpoint_due():
            run.save(agent.algo, agent.state_dict())
    if losses:
        run.scalars({name: float(np.mean(values)) for name, values in losses.items()})
    run.save(agent.algo, agent.state_dict(), periodic=False)
