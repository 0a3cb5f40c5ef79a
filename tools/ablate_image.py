"""Does a camera agent use its image? Greedy episodes with the real image, a black one, and the first
frame frozen; the scalar observations (d, θ, v or the destination) are left as they are.

    python -m tools.ablate_image results/checkpoints/ppo_camera_straight.pt --episodes 1
    python -m tools.ablate_image results/checkpoints/dqn_camera_four_routes.pt --episodes 50 --summary

Prints a row per episode, or with --summary a row per image mode (mean and least route completion, arrivals).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

from mjdrive.agents.evaluate import load_agent
from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from mjdrive.envs import make_env
from mjdrive.envs.batched import ObservationLayout
from mjdrive.suite import split_task


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint")
    parser.add_argument("--task", default=None, help="DOMAIN/TASK (default: the checkpoint's)")
    parser.add_argument("--episodes", type=int_at_least(1), default=1)
    parser.add_argument("--seed", type=int_at_least(0), default=10_000)
    parser.add_argument("--summary", action="store_true", help="one row per image mode instead of per episode")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    agent, payload = load_agent(args.checkpoint)
    config = payload["config"]
    domain, task = split_task(args.task or config["task"])
    env = make_env(domain, task, actions=config.get("actions", "continuous"), **config.get("task_kwargs", {}))
    key = ObservationLayout(env.observation_space).image_key
    if key is None:
        raise SystemExit("this agent has no image observation")
    if args.summary:
        last = args.seed + args.episodes - 1
        print(f"{args.episodes} greedy episodes on {domain}/{task}, seeds {args.seed}-{last}\n")
        print("| image | mean route completion | min | success % |\n| --- | ---: | ---: | ---: |")
    else:
        print("| image | episode | steps | route completion | success |\n| --- | ---: | ---: | ---: | --- |")
    for mode in ("real", "black", "frozen first frame"):
        completions, successes = [], []
        for episode in range(args.episodes):
            obs, info = env.reset(seed=args.seed + episode)
            first, steps = obs[key].copy(), 0
            while True:
                seen = dict(obs)
                if mode == "black":
                    seen[key] = np.zeros_like(obs[key])
                elif mode == "frozen first frame":
                    seen[key] = first
                action = agent.act({k: v[None] for k, v in seen.items()})[0]
                obs, _, terminated, truncated, info = env.step(action)
                steps += 1
                if terminated or truncated:
                    break
            completions.append(100 * info.get("route_completion", np.nan))
            successes.append(bool(info.get("success")))
            if not args.summary:
                print(f"| {mode} | {episode} | {steps} | {completions[-1]:.1f}% | {successes[-1]} |")
        if args.summary:
            print(f"| {mode} | {np.mean(completions):.1f}% | {np.min(completions):.1f}% | "
                  f"{100 * np.mean(successes):.0f} |", flush=True)
    env.close()
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
