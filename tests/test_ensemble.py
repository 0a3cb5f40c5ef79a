"""Ensembles of trained policies (agents/ensemble.py, `mjdrive ensemble`): the combining rules, the file that
names its members, and the checks on what may be combined."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from mjdrive.agents.algorithms import agent_class  # noqa: E402
from mjdrive.agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint  # noqa: E402
from mjdrive.agents.config import apply_overrides, load_config  # noqa: E402
from mjdrive.agents.ensemble import EnsembleAgent, save_ensemble  # noqa: E402
from mjdrive.agents.evaluate import evaluate, load_agent, to_markdown  # noqa: E402
from mjdrive.cli import main as cli_main  # noqa: E402
from mjdrive.envs.batched import BatchedEnv  # noqa: E402


def _policy(path, seed: int, overrides: list[str] | None = None, algo: str = "sac"):
    """A policy file of `algo` on waypoints/straight with random weights (seed), pedal actions for SAC."""
    config = apply_overrides(load_config(algo), ["algorithm.hidden=[32, 32]", "torch_threads=1",
                                                 *(["actions=pedal"] if algo == "sac" else []), *(overrides or [])])
    env = BatchedEnv("waypoints", "straight", num_envs=1, actions=config["actions"], **config.get("task_kwargs", {}))
    torch.manual_seed(seed)
    agent = agent_class(algo)(config, env.single_observation_space, env.single_action_space)
    env.close()
    network = agent.q if algo == "dqn" else agent.actor
    for p in network.parameters():
        torch.nn.init.normal_(p, std=0.5)  # members that disagree clearly
    return save_checkpoint(path, algo, config, agent.state_dict(), step=100 * (seed + 1))


def _observations(n: int = 6) -> dict:
    env = BatchedEnv("waypoints", "straight", num_envs=n, actions="pedal")
    obs, _ = env.reset(seed=3)
    for _ in range(4):
        obs = env.step(np.tile([[0.6, 0.1]], (n, 1)).astype(np.float32))[0]
    env.close()
    return obs


def test_rules_combine_the_members_actions(tmp_path):
    paths = [_policy(tmp_path / f"m{i}.pt", seed=i) for i in range(3)]
    members = [load_agent(p)[0] for p in paths]
    obs = _observations()
    actions = np.stack([m.act(obs) for m in members])  # (3, N, 2): (pedal, steer)
    assert np.ptp(actions[:, :, 0], axis=0).min() > 1e-3  # the members disagree on the pedal everywhere

    mean = EnsembleAgent(members, "mean").act(obs)
    np.testing.assert_allclose(mean, actions.mean(axis=0), rtol=1e-6)
    cautious = EnsembleAgent(members, "min_pedal").act(obs)
    np.testing.assert_allclose(cautious[:, 0], actions[:, :, 0].min(axis=0), rtol=1e-6)
    np.testing.assert_allclose(cautious[:, 1], actions[:, :, 1].mean(axis=0), rtol=1e-6)
    assert (cautious[:, 0] <= mean[:, 0]).all() and (cautious[:, 0] < mean[:, 0]).any()
    # copies of one member act as that member
    np.testing.assert_allclose(EnsembleAgent([members[0]] * 3, "min_pedal").act(obs), actions[0], rtol=1e-6)
    with pytest.raises(ValueError, match="unknown ensemble rule 'vote'; valid: mean, min_pedal"):
        EnsembleAgent(members, "vote")


def test_an_ensemble_file_names_its_members_and_evaluates_like_a_policy(tmp_path):
    members = [_policy(tmp_path / "a.pt", 0), _policy(tmp_path / "b.pt", 1, ["task_kwargs.time_limit=8"])]
    assert cli_main(["ensemble", *map(str, members), "--out", str(tmp_path / "ens" / "e.pt")]) == 0
    path = tmp_path / "ens" / "e.pt"
    payload = load_checkpoint(path, "ensemble")
    assert path.stat().st_size < 20_000  # the members' weights stay in their own files
    assert [m["path"] for m in payload["state"]["members"]] == ["../a.pt", "../b.pt"]
    assert payload["state"]["rule"] == "min_pedal"
    assert "time_limit" not in payload["config"]["task_kwargs"]  # the members differ on it; it leaves obs alone

    agent, _ = load_agent(path)
    obs = _observations(4)
    expected = EnsembleAgent([load_agent(m)[0] for m in members], "min_pedal").act(obs)
    np.testing.assert_array_equal(agent.act(obs), expected)
    result = evaluate(path, episodes=1, task_kwargs={"time_limit": 3})
    assert result["algo"] == "ensemble" and result["rows"][0]["steps"] == 30
    assert "This is an ensemble of 2, rule 'min_pedal', of `" in to_markdown(result)

    members[1].write_bytes(members[1].read_bytes() + b"\0")  # a member changed after the ensemble was made
    with pytest.raises(CheckpointError, match="has changed since the ensemble was made"):
        load_agent(path)
    members[1].unlink()
    with pytest.raises(CheckpointError, match=r"member \.\./b\.pt is missing"):
        load_agent(path)


def test_members_that_cannot_be_combined_are_refused(tmp_path):
    sac = _policy(tmp_path / "sac.pt", 0)
    with pytest.raises(ValueError, match="at least 2 members"):
        save_ensemble([sac], "mean", tmp_path / "e.pt")
    with pytest.raises(ValueError, match="unknown ensemble rule"):
        save_ensemble([sac, sac], "max", tmp_path / "e.pt")
    dqn = _policy(tmp_path / "dqn.pt", 1, algo="dqn")
    with pytest.raises(CheckpointError, match="discrete action set 'table2'"):
        save_ensemble([sac, dqn], "mean", tmp_path / "e.pt")
    continuous = _policy(tmp_path / "continuous.pt", 2, ["actions=continuous"])
    with pytest.raises(CheckpointError, match="'min_pedal' needs members with the 'pedal' action set"):
        save_ensemble([sac, continuous], "min_pedal", tmp_path / "e.pt")
    with pytest.raises(CheckpointError, match="does not match"):
        save_ensemble([sac, continuous], "mean", tmp_path / "e.pt")
    farther = _policy(tmp_path / "farther.pt", 3, ["task_kwargs.waypoint_spacing=3.0"])
    with pytest.raises(CheckpointError, match="sees another observation than"):
        save_ensemble([sac, farther], "mean", tmp_path / "e.pt")
    assert not (tmp_path / "e.pt").exists()
