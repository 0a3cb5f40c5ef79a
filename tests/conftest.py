import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture
def drive_episode():
    """A function: (env, act, seed) -> the last step's info after driving one episode of `env` from a reset with
    `seed`, `act(observation)` choosing each action, to its end (terminated or truncated)."""

    def drive(env, act, seed: int) -> dict:
        observation, info = env.reset(seed=seed)
        while True:
            observation, _, terminated, truncated, info = env.step(act(observation))
            if terminated or truncated:
                return info

    return drive


@pytest.fixture
def decision_agent_file():
    """A factory: (folder, scenario, seed, **task kwargs) -> the path of an untrained TRPO decision agent of
    urban/<scenario> (random weights, decisive) saved as a policy file."""

    def make(folder, scenario: str, seed: int, **task_kwargs) -> str:
        import torch

        from mjdrive.agents.checkpoints import save_checkpoint
        from mjdrive.agents.config import apply_overrides, load_config
        from mjdrive.agents.trpo import TRPOAgent
        from mjdrive.envs import make_env

        config = apply_overrides(load_config("trpo_crossroad"), [f"task=urban/{scenario}"])
        config["task_kwargs"] = {"decisions": True, **task_kwargs}
        env = make_env("urban", scenario, **config["task_kwargs"])
        torch.manual_seed(seed)
        agent = TRPOAgent(config, env.observation_space, env.action_space)
        env.close()
        for p in agent.policy.parameters():
            torch.nn.init.normal_(p, std=1.0)  # decisive random policies
        path = folder / f"{scenario}_{seed}.pt"
        save_checkpoint(path, "trpo", config, {"policy": agent.policy.state_dict()}, step=1000 + seed,
                        extra={"inference_only": True})
        return str(path)

    return make
