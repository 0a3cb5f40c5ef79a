"""Study 002's hybrid agent: the scenario selector hands each decision to the member of the active scenario (by
action name onto the route's action set), "drive" elsewhere; one checkpoint whose members' weights are checked."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from mjdrive.agents.checkpoints import CheckpointError, load_checkpoint, save_checkpoint  # noqa: E402
from mjdrive.agents.evaluate import evaluate, load_agent  # noqa: E402
from mjdrive.agents.hybrid import HybridAgent, save_hybrid  # noqa: E402
from mjdrive.tasks.urban import SCENARIOS  # noqa: E402


def _observations(scenario_codes: list[int], n_adversaries: int = 6) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    n = len(scenario_codes)
    return {"ego": rng.random((n, 4), dtype=np.float32),
            "scenario": np.eye(len(SCENARIOS), dtype=np.float32)[scenario_codes],
            "adversaries": rng.random((n, n_adversaries, 4), dtype=np.float32)}


def test_the_selector_hands_each_row_to_its_scenarios_member_by_action_name(tmp_path, decision_agent_file):
    _member = decision_agent_file
    members = {"crossroad": _member(tmp_path, "crossroad", 1), "lane_change": _member(tmp_path, "lane_change", 2)}
    path = save_hybrid(members, tmp_path / "hybrid.pt")
    hybrid, payload = load_agent(path)
    assert isinstance(hybrid, HybridAgent) and payload["algo"] == "hybrid"
    assert payload["config"]["hybrid"]["members"]["crossroad"]["step"] == 1001
    actions = hybrid.actions
    assert actions == ("drive", "stop", "left", "right")
    codes = [SCENARIOS.index(s) for s in ("follow", "crossroad", "lane_change", "roundabout", "crossroad",
                                          "lane_change")] * 20
    obs = _observations(codes)
    chosen = hybrid.act(obs)
    crossroad, _ = load_agent(members["crossroad"])
    lane_change, _ = load_agent(members["lane_change"])
    rows = {s: np.flatnonzero(np.array(codes) == SCENARIOS.index(s)) for s in ("follow", "crossroad",
                                                                               "lane_change", "roundabout")}
    sub = lambda rows: {k: v[rows] for k, v in obs.items()}  # noqa: E731
    # crossroad: drive/stop are the route's indices 0/1; lane change: keep/left/right are drive/left/right
    np.testing.assert_array_equal(chosen[rows["crossroad"]], crossroad.act(sub(rows["crossroad"])))
    np.testing.assert_array_equal(chosen[rows["lane_change"]], np.array([0, 2, 3])[lane_change.act(
        sub(rows["lane_change"]))])
    assert len(set(chosen[rows["crossroad"]])) == 2 and len(set(chosen[rows["lane_change"]])) >= 2  # not constant
    assert (chosen[rows["follow"]] == 0).all() and (chosen[rows["roundabout"]] == 0).all()  # no member: drive
    assert hybrid.last[1][:2] == ("crossroad", "crossroad") and hybrid.last[0][1:] == ("follow path", "drive")
    # on a scenario task the route's own actions: a lane-change member's left and right (no such action there) drive
    single, _ = load_agent(save_hybrid(members, tmp_path / "crossroad_hybrid.pt", task="urban/crossroad"))
    assert single.actions == ("drive", "stop")
    chosen = single.act(obs)
    assert (chosen[rows["lane_change"]] == 0).all()
    np.testing.assert_array_equal(chosen[rows["crossroad"]], crossroad.act(sub(rows["crossroad"])))


def test_a_changed_member_weight_or_a_wrong_member_is_refused(tmp_path, decision_agent_file):
    _member = decision_agent_file
    path = save_hybrid({"crossroad": _member(tmp_path, "crossroad", 1)}, tmp_path / "hybrid.pt")
    payload = load_checkpoint(path)
    weights = payload["state"]["members"]["crossroad"]["state"]["policy"]
    key = next(iter(weights))
    weights[key] = weights[key] + 1e-3
    save_checkpoint(tmp_path / "tampered.pt", "hybrid", payload["config"], payload["state"], payload["step"])
    with pytest.raises(CheckpointError, match="SHA-256"):
        load_agent(tmp_path / "tampered.pt")
    with pytest.raises(CheckpointError, match="must be trained on urban/merge"):
        save_hybrid({"merge": _member(tmp_path, "crossroad", 1)}, tmp_path / "wrong.pt")
    with pytest.raises(ValueError, match="no scenario 'follow'"):
        save_hybrid({"follow": _member(tmp_path, "crossroad", 1)}, tmp_path / "wrong.pt")
    with pytest.raises(CheckpointError, match="another observation"):
        save_hybrid({"crossroad": _member(tmp_path, "crossroad", 1),
                     "merge": _member(tmp_path, "merge", 2, adversaries=4)}, tmp_path / "wrong.pt")


def test_mjdrive_eval_drives_a_hybrid_episode(tmp_path, decision_agent_file):
    _member = decision_agent_file
    path = save_hybrid({"crossroad": _member(tmp_path, "crossroad", 1)}, tmp_path / "hybrid.pt",
                       task="urban/crossroad")
    result = evaluate(path, episodes=1, seed=5)
    assert result["algo"] == "hybrid" and result["task"] == "urban/crossroad"
    assert result["rows"][0]["steps"] > 5 and "hybrid" in result


def test_the_log_says_which_agent_decided_each_step_and_on_what(tmp_path, decision_agent_file):
    """/decision: one message per step of a hybrid's evaluated episode, valid against its schema, naming the
    member that decided in its scenario ("follow path" elsewhere) and the observation it saw."""
    import json

    import jsonschema

    from mjdrive.record.reader import read_episode

    path = save_hybrid({"crossroad": decision_agent_file(tmp_path, "crossroad", 1)}, tmp_path / "hybrid.pt",
                       task="urban/crossroad")
    result = evaluate(path, episodes=1, seed=5, record_dir=tmp_path / "logs")
    (log,) = sorted((tmp_path / "logs").glob("*.mcap"))
    episode = read_episode(log)
    _, _, schema = episode.schemas["/decision"]
    messages = [json.loads(payload) for _, payload in episode.messages["/decision"]]
    actions = [json.loads(payload) for _, payload in episode.messages["/action"]]
    assert len(messages) == len(actions) == result["rows"][0]["steps"]
    for message in messages:
        jsonschema.validate(message, json.loads(schema))
    assert {m["agent"] for m in messages} == {"follow path", "crossroad"}
    assert all(m["agent"] == ("crossroad" if m["scenario"] == "crossroad" else "follow path") for m in messages)
    assert [m["action"] for m in messages] == [a["name"] for a in actions]  # the decision the env applied
    assert all(np.asarray(m["observation"]["adversaries"]).shape == (6, 4) for m in messages)
    from mjdrive.envs.replay import replay

    replayed = replay(log)  # the decisions replay bit for bit like any other action
    assert replayed.checked == replayed.steps > 5 and replayed.mismatch_step is None


def _drive_probability(agent, obs: dict) -> float:
    """The policy's mean probability of "drive" (action 0) over a batch of observations."""
    from mjdrive.agents.observations import ObsBatch

    with torch.no_grad():
        return float(agent.policy(ObsBatch.from_numpy(agent.layout, obs)).probs[:, 0].mean())


def test_a_tiny_decision_agent_learns_to_drive_and_beats_always_stop(tmp_path, drive_episode):
    """A learning test that can fail: TRPO (Fig. 6's network) on the crossroad's decisions for 2,048 decisions.
    Its probability of "drive" on the states of a crossroad approach must rise by a margin over the untrained
    policy's (same seed), and its greedy policy must arrive where always stop never does."""
    from mjdrive.agents.algorithms import agent_class
    from mjdrive.agents.config import apply_overrides, load_config
    from mjdrive.agents.seeding import set_seed
    from mjdrive.agents.train import train
    from mjdrive.envs import make_env

    config = apply_overrides(load_config("trpo_crossroad"), [
        "steps=2048", "num_envs=8", "algorithm.rollout_steps=64", "algorithm.max_kl=0.05", "checkpoint_every=0",
        "tensorboard=false", "torch_threads=1", "seed=0", "algorithm.hidden=[32, 32]",
        "algorithm.extractor={groups: {ego: [ego, scenario], adversaries: [adversaries]}, hidden: [32, 32]}"])
    env = make_env("urban", "crossroad", decisions=True)
    rows, (obs, _) = [], env.reset(seed=77)
    for _ in range(40):  # states of an approach to the crossroad and its crossing
        rows.append(obs)
        obs, _, terminated, truncated, _ = env.step(0)
        if terminated or truncated:
            break
    states = {key: np.stack([row[key] for row in rows]) for key in rows[0]}
    set_seed(0)
    untrained = agent_class("trpo")(config, env.observation_space, env.action_space)
    policy_path = train(config, tmp_path, progress=False)
    trained, _ = load_agent(policy_path)
    before, after = _drive_probability(untrained, states), _drive_probability(trained, states)
    assert after > before + 0.1, (before, after)
    def act(obs: dict) -> int:
        return trained.act({k: v[None] for k, v in obs.items()})[0]

    arrived = sum(int(drive_episode(env, act, seed)["success"]) for seed in (10_000, 10_001))
    env.close()
    assert arrived >= 1  # always stop arrives in none (it waits at the line until the time limit)


def test_the_committed_hybrid_hands_control_between_agents_at_the_scenario_borders():
    """The committed TRPO hybrid on the concatenated route's first 45 s: the roundabout's agent decides inside the
    roundabout and "follow path" outside, switching at the steps where the active scenario changes."""
    from pathlib import Path

    from mjdrive.envs import make_env

    hybrid, payload = load_agent(Path(__file__).parents[1] / "results/checkpoints/hybrid_trpo.pt")
    assert set(payload["config"]["hybrid"]["members"]) == {"roundabout", "lane_change", "crossroad", "merge"}
    env = make_env("urban", "concatenated", decisions=True, time_limit=45.0)
    obs, info = env.reset(seed=20000)
    seen = []
    while True:
        scenario = info["scenario"]
        action = hybrid.act({k: v[None] for k, v in obs.items()})[0]
        seen.append((scenario, hybrid.last[0][1]))
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
    agents = [agent for _, agent in seen]
    assert "roundabout" in agents and "follow path" in agents
    assert all(agent == (scenario if scenario != "follow" else "follow path") for scenario, agent in seen)
    switches = [i for i in range(1, len(agents)) if agents[i] != agents[i - 1]]
    assert switches and all(seen[i][0] != seen[i - 1][0] for i in switches)
