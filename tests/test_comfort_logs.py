"""Comfort metrics on every task (`mjdrive.comfort`, sampled by the DrivingEnvironment) in `info` at the
episode's end, in the MCAP `/episode` summary, `mjdrive logs` and eval; the urban MCAP's scenario segments,
intention labels and active scenario."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from mjdrive.comfort import ComfortMeter, ComfortMetrics
from mjdrive.envs import make_env
from mjdrive.envs.replay import replay
from mjdrive.policies import make_policy
from mjdrive.record import LAYOUT, RecordEpisodes, proto
from mjdrive.record.reader import logs_document, logs_rows, logs_table, read_episode
from mjdrive.record.summary import COMFORT_FIELDS, ROW_FIELDS, episode_row
from mjdrive.traffic import intentions

KEYS = tuple(ComfortMetrics.nan().as_dict())  # info keys, e.g. jerk_p95_mps3
INFO_KEY = dict(zip(COMFORT_FIELDS, KEYS, strict=True))  # ComfortMetrics field -> its info key


def _world_velocity(task, data) -> tuple[np.ndarray, float]:
    """A ComfortMeter sample as its docstring builds one from a Vehicle."""
    fwd, left = task.vehicle.velocity_body(data)
    yaw = task.vehicle.pose(data)[2]
    return np.array([fwd * math.cos(yaw) - left * math.sin(yaw), fwd * math.sin(yaw) + left * math.cos(yaw)]), yaw


def _episode(env, act, before_first_step=None) -> tuple[list[dict], ComfortMeter]:
    """Infos of every step, and a ComfortMeter fed here with the same states (reset state first)."""
    env.reset(seed=3)
    task, data = env.unwrapped.task, env.unwrapped.dm_env.physics.data.ptr
    if before_first_step is not None:
        before_first_step(env)
    meter = ComfortMeter()
    meter.add(*_world_velocity(task, data))
    infos = []
    while True:
        _, _, terminated, truncated, info = env.step(act())
        meter.add(*_world_velocity(task, data))
        infos.append(info)
        if terminated or truncated:
            return infos, meter


def _coast_straight_at_8_m_s(env) -> None:
    """Put the car at 8 m/s along the straight road (after the env's reset) and restart the comfort samples."""
    task, physics = env.unwrapped.task, env.unwrapped.dm_env.physics
    x, y, yaw = task.vehicle.pose(physics.raw_data)
    task.vehicle.reset(physics.raw_data, x, y, yaw, speed=8.0)
    task.reset_comfort(physics)


def test_waypoints_coasting_straight_has_small_jerk_and_matches_a_meter_fed_the_same_samples():
    env = make_env("waypoints", "straight", time_limit=2.0, start_noise=(0.0, 0.0))
    infos, meter = _episode(env, lambda: np.zeros(3), _coast_straight_at_8_m_s)
    env.close()
    assert all(key not in info for info in infos[:-1] for key in KEYS)  # only at the last step
    last = infos[-1]
    assert last["time_limit"] and len(infos) == 20
    expected = meter.metrics(0.1).as_dict()
    for key in KEYS:
        assert last[key] == pytest.approx(expected[key], rel=1e-9, abs=1e-9), key
    assert last["jerk_max_mps3"] < 0.2 and last["accel_p95_mps2"] < 0.3  # [m/s^3], [m/s^2]: coasting, no steering
    assert last["jerk_lat_max_mps3"] < 0.05 and last["accel_lat_p95_mps2"] < 0.05


def test_roundabout_episode_ends_with_comfort_metrics_at_its_5_hz_control_rate():
    env = make_env("roundabout", "d120", time_limit=3.0)
    infos, meter = _episode(env, lambda: np.array([0.4, 0.2, 0.0]))
    env.close()
    last = infos[-1]
    expected = meter.metrics(0.2).as_dict()  # [s] the roundabout's control period
    for key in KEYS:
        assert np.isfinite(last[key]) and last[key] >= 0.0, key
        assert last[key] == pytest.approx(expected[key], rel=1e-9, abs=1e-9), key
    assert last["jerk_p95_mps3"] <= last["jerk_max_mps3"] and last["accel_lat_p95_mps2"] > 0.1  # it turned


def test_logs_and_the_episode_summary_carry_the_task_s_comfort_metrics(tmp_path):
    env = RecordEpisodes(make_env("waypoints", "straight", time_limit=1.5), tmp_path)
    policy = make_policy("pure_pursuit", env)
    finals = []
    for seed in (1, 2):
        observation, _ = env.reset(seed=seed)
        while True:
            observation, reward, terminated, truncated, info = env.step(policy(observation))
            if terminated or truncated:
                finals.append(info)
                break
    observation, _ = env.reset(seed=3)
    for _ in range(8):
        env.step(policy(observation))
    env.close()  # the third episode is interrupted: the recorder's own samples still give its metrics
    paths = env.recorder.paths
    for path, info in zip(paths, finals, strict=False):
        summary = read_episode(path).summary
        for name, key in COMFORT_FIELDS.items():
            assert summary[key] == info[INFO_KEY[name]], key  # the same samples, period and filter
        assert "max_abs_jerk_m_s3" not in summary
    interrupted = read_episode(paths[2]).summary
    assert interrupted["interrupted"] and all(interrupted[key] >= 0.0 for key in COMFORT_FIELDS.values())

    read = logs_rows(tmp_path)
    rows = read[0]
    assert [list(row) for row in rows] == [list(ROW_FIELDS)] * 3
    for row, info in zip(rows, finals, strict=False):  # the rows of run and eval (from info) are those of logs
        assert row == episode_row(info, episode=row["episode"], seed=row["seed"], reward=row["reward"],
                                  steps=row["steps"], terminated=False, truncated=True, control_dt=0.1,
                                  log=row["log"])
        assert 0.0 <= row["jerk_p95_m_s3"] <= row["jerk_max_m_s3"] and row["accel_p95_m_s2"] > 0.0
    table = logs_table(tmp_path, read)
    assert "p95 jerk [m/s^3]" in table and f"{rows[0]['jerk_p95_m_s3']:.2f}" in table
    summary = logs_document(tmp_path, read)["summary"]
    assert summary["avg_jerk_p95_m_s3"] == pytest.approx(np.mean([row["jerk_p95_m_s3"] for row in rows]), abs=1e-3)


def test_json_of_an_episode_too_short_to_filter_has_null_comfort(tmp_path):
    env = RecordEpisodes(make_env("waypoints", "straight", time_limit=0.3), tmp_path)  # 3 steps, 4 samples
    env.reset(seed=0)
    while True:
        *_, terminated, truncated, info = env.step(np.array([0.5, 0.0, 0.0]))
        if terminated or truncated:
            break
    env.close()
    assert all(math.isnan(info[key]) for key in KEYS)
    raw = read_episode(env.recorder.paths[0]).messages["/episode"][0][1]
    summary = json.loads(raw)  # strict JSON: no NaN
    assert b"NaN" not in raw and all(summary[key] is None for key in COMFORT_FIELDS.values())
    assert all(summary["info"][key] is None for key in KEYS)
    assert all(logs_rows(tmp_path)[0][0][key] is None for key in COMFORT_FIELDS.values())


def test_urban_log_shows_scenarios_intentions_and_the_active_scenario_and_replays(tmp_path):
    env = RecordEpisodes(make_env("urban", "merge", time_limit=4.0), tmp_path)
    policy = make_policy("pure_pursuit", env)
    observation, _ = env.reset(seed=1)
    while True:
        observation, _, terminated, truncated, info = env.step(policy(observation))
        if terminated or truncated:
            break
    task = env.unwrapped.task
    users = task.road_users()
    env.close()
    path = env.recorder.paths[0]
    episode = read_episode(path)
    # the route's scenario segments, coloured and labelled by scenario
    route = {entity.id: entity for entity in episode.decoded("/scene/route")[0].entities}
    segments = route["route/scenarios"]
    assert [text.text for text in segments.texts] == list(task.urban.tactical.names) == ["merge"]
    assert len(segments.lines) == 1 and len(segments.lines[0].points) > 10
    # the active scenario of every state
    states = episode.json("/ego/state")
    assert len(states) == episode.summary["steps"] + 1
    assert states[0]["scenario"] == "follow" and states[-1]["scenario"] == task.active_scenario() == info["scenario"]
    assert {state["scenario"] for state in states} <= {"follow", "merge"}
    # every vehicle's intentions on its box's label, coloured by the one in the active scenario
    entity = episode.decoded("/scene/road_users")[-1].entities[0]
    vehicles = np.flatnonzero((users.intentions >= 0).all(axis=1))
    assert len(entity.cubes) == len(users.kinds) and len(entity.texts) == len(vehicles) > 0
    for text, i in zip(entity.texts, vehicles, strict=True):
        assert (text.pose.position.x, text.pose.position.y) == tuple(users.poses[i, :2])
        merge = users.intentions[i, intentions.SCENARIOS.index("merge")]
        assert text.text.split(" | ")[2] == f"M {('yield', 'take way')[merge]}"
    # the comfort metrics are the task's, and the episode replays bit for bit
    for name, key in COMFORT_FIELDS.items():
        assert episode.summary[key] == info[INFO_KEY[name]], key
    assert replay(path).match


def test_text_labels_decode_as_foxglove_texts():
    from foxglove import messages as fm

    body = proto.text_fields(np.array([[1.0, 2.0, 3.0]]), [b"LC keep"], np.array([[0.1, 0.2, 0.3, 1.0]]))
    schema = fm.SceneUpdate.get_schema()
    update = proto.decode(schema.name, schema.data, proto.scene_update_bytes(proto.entity_head(0, "world", "x"), body))
    text = update.entities[0].texts[0]
    assert (text.text, text.billboard, text.scale_invariant, text.pose.position.z, text.color.g) == (
        "LC keep", True, True, 3.0, 0.2)


def test_layout_plots_acceleration_jerk_and_the_scenario_from_ego_state():
    layout = json.loads(LAYOUT.read_text())["configById"]
    fields = {"accel_long", "accel_lat", "jerk_long", "jerk_lat", "jerk", "scenario"}
    shown = {path["value"] for key in ("Plot!accel", "Plot!jerk", "StateTransitions!scenario")
             for path in layout[key]["paths"]}
    assert shown == {f"/ego/state.{name}" for name in fields}


def test_eval_rows_summary_and_markdown_show_comfort(tmp_path):
    from mjdrive.agents.evaluate import evaluate, to_markdown

    checkpoint = LAYOUT.parents[2] / "results" / "checkpoints" / "ppo_features_straight.pt"
    result = evaluate(checkpoint, episodes=2, task_kwargs={"time_limit": 1.0}, record_dir=tmp_path)
    rows, summary = result["rows"], result["summary"]
    assert all(row["jerk_p95_m_s3"] is not None and row["accel_p95_m_s2"] > 0.0 for row in rows)
    assert summary["avg_jerk_max_m_s3"] == pytest.approx(np.mean([row["jerk_max_m_s3"] for row in rows]), abs=1e-3)
    assert logs_rows(tmp_path)[0] == rows  # eval's rows are those read back from its logs
    markdown = to_markdown(result)
    assert f"p95 jerk {summary['avg_jerk_p95_m_s3']:.2f} m/s^3" in markdown and "| p95 jerk (m/s^3) |" in markdown
    assert f"| {rows[1]['jerk_max_m_s3']:.2f} |" in markdown
