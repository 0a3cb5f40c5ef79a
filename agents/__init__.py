"""Learners for mjdrive tasks: PPO (rsl-rl), SAC, DQN and TRPO in torch, with shared pieces in `common`.

    from agents.common import load_config
    from agents.train import train
    train(load_config("ppo"), "runs/ppo")            # or: mjdrive train --algo ppo --out runs/ppo
    from agents.evaluate import evaluate, to_markdown # or: mjdrive eval --checkpoint runs/ppo/policy.pt
"""
