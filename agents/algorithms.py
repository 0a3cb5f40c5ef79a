"""The learners by name, and an acting agent from a checkpoint's payload."""

from __future__ import annotations

from typing import Any

from mjdrive.agents.checkpoints import CheckpointError
from mjdrive.envs import make_env
from mjdrive.suite import split_task

ALGOS = ("ppo", "sac", "dqn", "trpo", "ppo_discrete")


def agent_class(algo: str):
    """The acting/learning class of `algo` (imported lazily: PPO pulls rsl-rl in)."""
    if algo == "sac":
        from mjdrive.agents.sac import SACAgent

        return SACAgent
    if algo == "dqn":
        from mjdrive.agents.dqn import DQNAgent

        return DQNAgent
    if algo == "ppo":
        from mjdrive.agents.ppo import PPOAgent

        return PPOAgent
    if algo == "trpo":
        from mjdrive.agents.trpo import TRPOAgent

        return TRPOAgent
    if algo == "ppo_discrete":
        from mjdrive.agents.ppo_discrete import PPODiscreteAgent

        return PPODiscreteAgent
    raise ValueError(f"unknown algo {algo!r}; valid: {', '.join(ALGOS)}")


def agent_from_payload(payload: dict, name: str) -> Any:
    """The acting agent of a loaded checkpoint payload (`name` for errors)."""
    config = payload["config"]
    domain, task = split_task(config["task"])
    task_kwargs = config.get("task_kwargs", {})
    if not isinstance(task_kwargs, dict):
        raise CheckpointError(f"{name}: its config's task_kwargs is a {type(task_kwargs).__name__}, not a dict")
    try:
        env = make_env(domain, task, actions=config.get("actions", "continuous"), **task_kwargs)
    except (KeyError, TypeError) as error:
        raise CheckpointError(f"{name}: its config cannot build the env {config['task']} ({error})") from error
    try:
        agent = agent_class(payload["algo"])(config, env.observation_space, env.action_space)
    except (KeyError, TypeError) as error:
        raise CheckpointError(f"{name}: its config cannot build a {payload['algo']} agent ({error})") from error
    finally:
        env.close()
    try:
        agent.load_state_dict(payload["state"], inference_only=True)
    except (KeyError, TypeError, AttributeError) as error:  # a state without the networks this algo needs
        raise CheckpointError(f"{name}: its state cannot load into a {payload['algo']} agent "
                              f"({type(error).__name__}: {error})") from error
    return agent
