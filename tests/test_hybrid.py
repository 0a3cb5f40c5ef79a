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
