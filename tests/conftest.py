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


@pytest.fixture
def traffic_alone():
    """A function: (traffic, seconds) -> (vehicles that drove through each junction entry (E,), substeps with an
    overlap, whether each entry showed red at some substep (E,)) after running the traffic alone for `seconds`."""

    def run(traffic, seconds: float):
        import numpy as np

        from mjdrive.traffic import junction_control as jc
        from mjdrive.traffic import overlapping_pairs

        entries = traffic.junctions.lane
        passed, red, overlaps = np.zeros(len(entries), dtype=int), np.zeros(len(entries), dtype=bool), 0
        before = traffic.vehicles.path[:, 0].copy()
        for _ in range(int(round(seconds / traffic.config.substep))):
            traffic.advance(traffic.config.substep)
            red |= traffic.entry_state == jc.RED
            present = traffic.present
            overlaps += len(overlapping_pairs(traffic.poses()[present], traffic.half_size[present])) > 0
            now = np.where(traffic.vehicles.active, traffic.vehicles.path[:, 0], -1)
            passed += ((before[:, None] == entries[None, :]) & (now[:, None] != entries[None, :])
                       & (now[:, None] >= 0)).sum(axis=0)
            before = now
        return passed, overlaps, red

    return run
