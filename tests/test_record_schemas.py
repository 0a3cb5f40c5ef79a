"""Every JSON channel of an episode log declares what it sends: each message of a recorded episode of every task
validates against the JSON schema stored with its channel (jsonschema, the schema's own draft). Generic over the
channels: whatever JSON channel a log holds is checked, so a new one is covered the day it is logged."""

from __future__ import annotations

import json

import gymnasium as gym
import jsonschema
import pytest

import mjdrive  # noqa: F401  (registers the ids)
from mjdrive import suite
from mjdrive.envs import make_env
from mjdrive.policies import make_policy
from mjdrive.record import RecordEpisodes
from mjdrive.record.reader import read_episode

KNOWN_JSON_CHANNELS = {"/ego/state", "/action", "/reward", "/episode"}


def _strict_json(data: bytes):
    """JSON as the standard defines it: NaN and Infinity are not JSON (Foxglove's parser refuses them)."""
    def refuse(constant: str):
        raise ValueError(f"{constant} is not JSON")

    return json.loads(data, parse_constant=refuse)


def schema_errors(path) -> tuple[dict[str, int], list[str]]:
    """(messages validated per JSON channel, one line per message that breaks its channel's schema) of a log;
    the "summary" metadata record is checked against /episode's schema too."""
    episode = read_episode(path)
    counts, errors = {}, []
    for topic, encoding in episode.message_encodings.items():
        if encoding != "json":
            continue
        name, schema_encoding, data = episode.schemas[topic]
        assert schema_encoding == "jsonschema", (topic, schema_encoding)
        schema = json.loads(data)
        validator_class = jsonschema.validators.validator_for(schema)
        validator_class.check_schema(schema)
        validator = validator_class(schema)
        messages = episode.messages.get(topic, [])
        counts[topic] = len(messages)
        for index, (_, payload) in enumerate(messages):
            try:
                message = _strict_json(payload)
            except ValueError as error:
                errors.append(f"{path.name} {topic}[{index}]: {error}")
                continue
            errors += [f"{path.name} {topic}[{index}] ({name}): {e.json_path}: {e.message}"
                       for e in validator.iter_errors(message)]
        if topic == "/episode":
            summary = {key: _strict_json(json.dumps(value)) for key, value in episode.summary.items()}
            errors += [f"{path.name} metadata summary: {e.json_path}: {e.message}"
                       for e in validator.iter_errors(summary)]
    return counts, errors


@pytest.mark.parametrize("domain, task", suite.ALL_TASKS, ids=lambda value: str(value))
def test_every_json_message_of_every_task_matches_its_channel_schema(domain, task, tmp_path):
    env = RecordEpisodes(make_env(domain, task, time_limit=3.0), tmp_path)
    policy = make_policy("autopilot" if domain != "waypoints" else "pure_pursuit", env, 0)
    observation, _ = env.reset(seed=0)
    while True:
        observation, _, terminated, truncated, _ = env.step(policy(observation))
        if terminated or truncated:
            break
    env.reset(seed=1)  # a second episode, interrupted after two steps: comfort metrics null, info of a live step
    env.step(policy(observation))
    env.step(policy(observation))
    env.close()
    logs = sorted(tmp_path.glob("*.mcap"))
    assert len(logs) == 2
    for path in logs:
        counts, errors = schema_errors(path)
        assert KNOWN_JSON_CHANNELS <= set(counts), counts
        assert all(counts[topic] > 0 for topic in KNOWN_JSON_CHANNELS), counts
        assert not errors, "\n".join(errors[:20])


@pytest.mark.parametrize("task", ["crossroad", "concatenated"])
def test_the_operative_channels_of_a_decision_episode_match_their_schemas(task, tmp_path, drive_episode):
    """The decision action set adds /operative and /operative/plan and logs the decision in /action."""
    env = RecordEpisodes(make_env("urban", task, time_limit=4.0, decisions=True), tmp_path)
    drive_episode(env, make_policy("rules", env, 0), seed=0)
    ticks = env.unwrapped.task.control_ticks  # control periods per decision
    env.close()
    (path,) = sorted(tmp_path.glob("*.mcap"))
    counts, errors = schema_errors(path)
    assert {"/operative", "/operative/plan"} | KNOWN_JSON_CHANNELS <= set(counts), counts
    assert ticks > 1 and counts["/operative"] == ticks * counts["/action"], counts
    assert counts["/operative/plan"] == counts["/action"], counts
    assert not errors, "\n".join(errors[:20])
    action = json.loads(read_episode(path).messages["/action"][-1][1])
    assert isinstance(action["decision"], int) and isinstance(action["name"], str)


@pytest.mark.parametrize("control", ["lights", "stop"])
def test_the_junction_channels_match_their_schemas(control, tmp_path, drive_episode):
    """Junction control adds /junction (what each entry shows) and its lamps (/scene/signals), every step."""
    env = RecordEpisodes(make_env("urban", "crossroad", time_limit=20.0, junction_control=control), tmp_path)
    drive_episode(env, make_policy("autopilot", env, 0), seed=0)
    env.close()
    (path,) = sorted(tmp_path.glob("*.mcap"))
    counts, errors = schema_errors(path)
    assert not errors, "\n".join(errors[:20])
    episode = read_episode(path)
    assert counts["/junction"] == counts["/ego/state"] and "/scene/signals" in episode.messages
    states = {entry["state"] for _, payload in episode.messages["/junction"]
              for entry in json.loads(payload)["entries"]}
    if control == "stop":
        assert states == {"stop", "green"}  # the minor road's signs, the main road free
    else:
        assert {"green", "red"} <= states <= {"green", "amber", "red"}  # one road is always red


def test_the_schemas_are_strict_a_key_not_declared_or_a_wrong_type_fails(tmp_path):
    """The check above can fail: an undeclared key, a missing one, a null where none is allowed are errors."""
    env = RecordEpisodes(gym.make("mjdrive/Waypoints-Straight-v0", time_limit=0.5), tmp_path)
    env.reset(seed=0)
    for _ in range(5):
        env.step([0.5, 0.0, 0.0])
    env.close()
    episode = read_episode(next(tmp_path.glob("*.mcap")))
    schemas = {topic: json.loads(episode.schemas[topic][2]) for topic in KNOWN_JSON_CHANNELS}
    state = json.loads(episode.messages["/ego/state"][-1][1])
    assert state["scenario"] is None  # a waypoints task: null, which the schema allows
    jsonschema.validate(state, schemas["/ego/state"])
    for bad in ({**state, "extra": 1.0}, {k: v for k, v in state.items() if k != "speed"}, {**state, "speed": None},
                {**state, "scenario": 3}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schemas["/ego/state"])
    summary = json.loads(episode.messages["/episode"][-1][1])
    assert summary["jerk_p95_m_s3"] is not None or summary["steps"] < 5
    jsonschema.validate(summary, schemas["/episode"])
    for bad in ({**summary, "steps": 2.5}, {**summary, "seed": "0"}, {**summary, "surprise": True}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schemas["/episode"])
