"""Learners for mjdrive tasks: PPO (rsl-rl), SAC, DQN and TRPO in torch, with shared pieces one module each
(config, seeding, env_factory, networks, augment, observations, replay, checkpoints, run_log, algorithms).

    from mjdrive.agents.config import load_config
    from mjdrive.agents.train import train
    train(load_config("ppo"), "runs/ppo")            # or: mjdrive train --algo ppo --out runs/ppo
    from mjdrive.agents.evaluate import evaluate, to_markdown # or: mjdrive eval --checkpoint runs/ppo/policy.pt
"""
