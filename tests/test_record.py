"""MCAP episode logs: round trip with the mcap reader and Foxglove schemas, replay bit for bit, damaged
files, a writer killed mid-episode, concurrent recorders (in one process and in two)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from mjdrive import cli
from mjdrive.envs import make_env
from mjdrive.envs.replay import LEGACY_PHYSICS_DT, replay, replay_task_kwargs
from mjdrive.policies import make_policy
from mjdrive.record import EnvSpec, EpisodeRecorder, RecordEpisodes, RecordOptions, load, proto
from mjdrive.record.reader import logs_table, read_episode
from mjdrive.record.recorder import episode_filename
from mjdrive.tasks.base import RoadUsers
from mjdrive.world import PHYSICS_TIMESTEP

ROOT = Path(__file__).resolve().parents[1]
# Logs written at 2 ms before the physics step was a task keyword (their task kwargs do not name it):
# waypoints/straight with pure pursuit and roundabout/d120 with the autopilot, 20 steps each, seed 7.
LEGACY_LOGS = sorted((ROOT / "tests" / "data").glob("*.mcap"))
TASK_KWARGS = {"time_limit": 5.0}  # [s] 50 steps: short episodes keep the tests fast
CAMERA_EVERY = 10
PER_STEP = {"/tf", "/ego/state", "/physics"}  # steps + 1 messages (reset state first)
PER_ACTION = {"/action", "/reward"}  # steps messages
ONCE = {"/scene/road", "/scene/route", "/scene/ego", "/episode"}


def _drive(env, seed: int, policy) -> int:
    observation, _ = env.reset(seed=seed)
    steps = 0
    while True:
        observation, _, terminated, truncated, _ = env.step(policy(observation))
        steps += 1
        if terminated or truncated:
            return steps


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """Two recorded episodes of waypoints/straight (pure pursuit, camera every 10 steps)."""
    out = tmp_path_factory.mktemp("logs")
    env = RecordEpisodes(make_env("waypoints", "straight", **TASK_KWARGS), out,
                         RecordOptions(camera_every=CAMERA_EVERY, camera_size=(60, 80), chunk_size=16 * 1024))
    policy = make_policy("pure_pursuit", env)
    steps = [_drive(env, seed, policy) for seed in (3, 4)]
    env.close()
    return out, env.recorder.paths, steps


def test_file_names_and_topics_round_trip(recorded):
    out, paths, steps = recorded
    assert [p.name for p in paths] == ["waypoints-straight_3_00000.mcap", "waypoints-straight_4_00001.mcap"]
    assert not list(out.glob("*.part"))
    with open(paths[0], "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
        by_topic: dict[str, list] = {}
        last_time = -1
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert message.log_time >= last_time  # written in time order
            last_time = message.log_time
            by_topic.setdefault(channel.topic, []).append((schema, message))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    n = steps[0]
    image_topics = {"/camera/front", "/camera/front/calibration"}
    assert set(by_topic) == PER_STEP | PER_ACTION | ONCE | image_topics
    for topic in PER_STEP:
        assert len(by_topic[topic]) == n + 1, topic
    for topic in PER_ACTION:
        assert len(by_topic[topic]) == n, topic
    for topic in ONCE:
        assert len(by_topic[topic]) == 1, topic
    assert len(by_topic["/camera/front"]) == len(range(0, n + 1, CAMERA_EVERY))
    for topic, messages in by_topic.items():
        times = [m.log_time for _, m in messages]
        assert all(b > a for a, b in zip(times, times[1:], strict=False)), f"{topic} timestamps not increasing"
    well_known = {"/tf": "foxglove.FrameTransforms", "/scene/road": "foxglove.SceneUpdate",
                  "/scene/route": "foxglove.SceneUpdate", "/scene/ego": "foxglove.SceneUpdate",
                  "/camera/front": "foxglove.CompressedImage",
                  "/camera/front/calibration": "foxglove.CameraCalibration"}
    for topic, name in well_known.items():
        assert schemas[topic].name == name and schemas[topic].encoding == "protobuf"
    decode = lambda topic, i=0: proto.decode(schemas[topic].name, schemas[topic].data,  # noqa: E731
                                             by_topic[topic][i][1].data)
    tf = decode("/tf", n)
    frames = [(t.parent_frame_id, t.child_frame_id) for t in tf.transforms]
    assert frames == [("world", "ego"), ("ego", "camera_front")]
    assert tf.transforms[0].translation.x > decode("/tf", 0).transforms[0].translation.x  # the car drove forward
    road = decode("/scene/road")
    surface = next(e for e in road.entities if e.id == "road/surface")
    assert len(surface.triangles[0].points) > 0 and len(surface.triangles[0].indices) % 3 == 0
    assert any(len(line.points) for e in road.entities for line in e.lines)  # markings
    route = decode("/scene/route")
    assert {e.id for e in route.entities} == {"route/line", "route/waypoints"}
    image = decode("/camera/front")
    assert image.format == "jpeg" and image.frame_id == "camera_front" and image.data[:2] == b"\xff\xd8"
    state = json.loads(by_topic["/ego/state"][n][1].data)
    assert {"speed", "accel_long", "accel_lat", "jerk", "steering_angle", "throttle", "brake", "lane_offset",
            "heading_error"} <= set(state)
    reward = json.loads(by_topic["/reward"][0][1].data)
    assert set(reward["terms"]) == {"waypoint", "collision", "lane_invasion", "speed", "lane_centre"}
    physics = decode("/physics", n)
    assert physics.time == pytest.approx(state["t"]) and len(physics.qpos) == json.loads(metadata["mjdrive"]["nq"])
    meta = {k: json.loads(v) for k, v in metadata["mjdrive"].items()}
    assert meta["task"] == "waypoints/straight" and meta["seed"] == 3
    assert meta["task_kwargs"] == {**TASK_KWARGS, "physics_dt": PHYSICS_TIMESTEP}  # the step is always named
    assert {"mjdrive", "mujoco", "dm-control", "numpy"} <= set(meta["versions"])
    assert json.loads(metadata["summary"]["steps"]) == n


def test_replay_matches_bit_for_bit(recorded, tmp_path, capsys):
    _, paths, _ = recorded
    result = replay(paths[1])
    assert result.match, result.report()
    assert cli.main(["replay", str(paths[0]), "--video", str(tmp_path / "replay.mp4")]) == 0
    assert "match" in capsys.readouterr().out and (tmp_path / "replay.mp4").stat().st_size > 0


def test_logs_written_at_2ms_before_the_step_was_a_keyword_replay_bit_for_bit():
    """Old logs name no `physics_dt`: replay rebuilds them at the step their metadata records (2 ms), not
    at today's default, and every state and reward matches."""
    assert [p.name for p in LEGACY_LOGS] == ["roundabout-d120_7_00000.mcap", "waypoints-straight_7_00000.mcap"]
    for path in LEGACY_LOGS:
        meta = read_episode(path, topics=set()).metadata
        assert "physics_dt" not in meta["task_kwargs"] and meta["physics_timestep"] == LEGACY_PHYSICS_DT
        result = replay(path)
        assert result.match and result.checked == 20, result.report()


def test_replay_step_comes_from_the_log():
    assert replay_task_kwargs({"task_kwargs": {"random": 1}}) == {"random": 1, "physics_dt": LEGACY_PHYSICS_DT}
    assert replay_task_kwargs({"task_kwargs": None, "physics_timestep": 0.004}) == {"physics_dt": 0.004}
    assert replay_task_kwargs({"task_kwargs": {"physics_dt": 0.005}, "physics_timestep": 0.002}) == {
        "physics_dt": 0.005}


def test_a_log_made_at_another_step_replays_at_that_step(tmp_path):
    """An episode run at 2 ms with today's code names its step and replays at it (the default differs)."""
    assert PHYSICS_TIMESTEP != 0.002
    env = RecordEpisodes(make_env("waypoints", "straight", physics_dt=0.002, **TASK_KWARGS), tmp_path)
    steps = _drive(env, 5, lambda observation: np.array([0.4, 0.0, 0.0], np.float32))
    env.close()
    path = env.recorder.paths[0]
    meta = read_episode(path, topics=set()).metadata
    assert meta["task_kwargs"]["physics_dt"] == 0.002 and meta["physics_timestep"] == 0.002
    result = replay(path)
    assert result.match and result.checked == steps, result.report()


def test_replay_detects_a_wrong_action(tmp_path):
    """The check is not vacuous: a log whose action differs from the one applied fails at that step."""
    env = make_env("waypoints", "straight", **TASK_KWARGS).unwrapped
    recorder = EpisodeRecorder(tmp_path, EnvSpec("waypoints", "straight", TASK_KWARGS))
    env.reset(seed=0)
    recorder.begin(env.task, env.dm_env.physics, seed=0)
    for k in range(5):
        action = np.array([0.5, 0.0, 0.0])
        _, reward, *_ = env.step(action)
        logged = action + (0.01 if k == 2 else 0.0)
        recorder.step(env.task, env.dm_env.physics, logged, reward)
    path = recorder.end()
    result = replay(path)
    assert not result.match and result.mismatch_step == 3 and "qvel" in result.mismatch_fields


def test_dm_control_wrapper_replays_without_reset_seeds(tmp_path):
    """suite.load-style env, no reset seeds: the RNG state taken before each reset makes it replayable; the
    logs name the task's seed (`random`) and the episode index."""
    env = load("waypoints", "four_routes", {"random": 7, **TASK_KWARGS}, out_dir=tmp_path)
    for _ in range(2):
        timestep = env.reset()
        while not timestep.last():
            timestep = env.step(np.array([0.4, 0.05, 0.0]))
    env.close()
    names = sorted(p.name for p in tmp_path.glob("*.mcap"))
    assert names == ["waypoints-four_routes_7_00000.mcap", "waypoints-four_routes_7_00001.mcap"]
    assert replay(tmp_path / names[1]).match


def test_road_users_from_task(tmp_path):
    """Road users come only from task.road_users(): boxes standing on the ground, coloured by kind."""
    env = make_env("waypoints", "straight", **TASK_KWARGS).unwrapped
    poses = np.array([[10.0, 2.0, 0.5], [20.0, -3.0, np.pi], [5.0, 0.0, 0.0]])
    half = np.array([[2.2, 0.9, 0.75], [2.2, 0.9, 0.75], [0.3, 0.3, 0.9]])
    env.task.road_users = lambda: RoadUsers(("car", "car", "pedestrian"), poses, half)
    recorder = EpisodeRecorder(tmp_path, EnvSpec("waypoints", "straight", TASK_KWARGS))
    env.reset(seed=1)
    recorder.begin(env.task, env.dm_env.physics, seed=1)
    for _ in range(3):
        _, reward, *_ = env.step(np.zeros(3))
        recorder.step(env.task, env.dm_env.physics, env.task.last_action, reward)
    episode = read_episode(recorder.end())
    assert episode.schemas["/scene/road_users"][0] == "foxglove.SceneUpdate"
    updates = episode.decoded("/scene/road_users")
    assert len(updates) == 4
    cubes = updates[-1].entities[0].cubes
    assert len(cubes) == 3 and updates[-1].entities[0].frame_id == "world"
    assert (cubes[1].pose.position.x, cubes[1].pose.position.y, cubes[1].pose.position.z) == (20.0, -3.0, 0.75)
    assert cubes[1].pose.orientation.z == pytest.approx(1.0) and cubes[1].size.x == pytest.approx(4.4)
    assert (cubes[0].color.r, cubes[0].color.b) == (cubes[1].color.r, cubes[1].color.b) != (
        cubes[2].color.r, cubes[2].color.b)


def test_truncated_file_is_reported(recorded, tmp_path, capsys):
    _, paths, _ = recorded
    data = paths[0].read_bytes()
    with open(paths[0], "rb") as f:
        chunk_ends = [i.chunk_start_offset + i.chunk_length for i in make_reader(f).get_summary().chunk_indexes]
    assert len(chunk_ends) > 3
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: chunk_ends[0] + 100])  # only the first chunk (the road scene) survives
    episode = read_episode(cut)
    assert not episode.complete and episode.summary is None and "incomplete" in episode.describe_damage()
    assert cli.main(["replay", str(cut)]) == 2
    assert "is incomplete" in capsys.readouterr().err
    cut.write_bytes(data[: chunk_ends[2] + 100])  # some steps survive: that prefix is checked
    assert cli.main(["replay", str(cut)]) == 1
    out = capsys.readouterr().out
    assert "is incomplete" in out and "cannot be fully verified" in out and "match" in out
    (tmp_path / "garbage.mcap").write_bytes(b"not an mcap file")
    assert cli.main(["replay", str(tmp_path / "garbage.mcap")]) == 2
    assert "not a readable MCAP file" in capsys.readouterr().err
    (tmp_path / paths[0].name).write_bytes(data)
    assert cli.main(["logs", str(tmp_path)]) == 0
    table = capsys.readouterr().out
    assert "| cut.mcap | waypoints/straight | 3 |" in table and "incomplete" in table
    assert "unreadable" in table and "**all 1 complete**" in table


def test_two_recorders_in_one_process(tmp_path):
    """Two envs stepped in lockstep, recording into the same folder: separate, self-consistent files."""
    envs = [RecordEpisodes(make_env("waypoints", name, **TASK_KWARGS), tmp_path)
            for name in ("straight", "four_routes")]
    observations = [env.reset(seed=5)[0] for env in envs]
    policies = [make_policy("pure_pursuit", env) for env in envs]
    done = [False, False]
    while not all(done):
        for i, env in enumerate(envs):
            if not done[i]:
                observations[i], _, terminated, truncated, _ = env.step(policies[i](observations[i]))
                done[i] = terminated or truncated
    for env in envs:
        env.close()
    paths = [env.recorder.paths[0] for env in envs]
    assert [p.name for p in paths] == ["waypoints-straight_5_00000.mcap", "waypoints-four_routes_5_00000.mcap"]
    for path, name in zip(paths, ("straight", "four_routes"), strict=True):
        episode = read_episode(path)
        assert episode.metadata["task"] == f"waypoints/{name}"
        assert len(episode.messages["/physics"]) == episode.summary["steps"] + 1
        assert replay(path).match


def _flip(data: bytes, start: int, length: int) -> bytes:
    """`data` with `length` bytes from `start` inverted."""
    out = bytearray(data)
    for i in range(start, start + length):
        out[i] ^= 0xFF
    return bytes(out)


def test_a_damaged_summary_section_chunk_or_record_is_flagged_and_the_rest_is_read(recorded, tmp_path, capsys):
    """Every CRC an MCAP file has is checked: 100 bytes flipped near the end (the summary section), inside a
    chunk, or a digit changed in the summary metadata record (outside the chunks) are each reported in one
    line by `read_episode`, `mjdrive logs` (its table too) and `mjdrive replay`; what is intact is still read."""
    _, paths, steps = recorded
    data = paths[0].read_bytes()
    intact = read_episode(paths[0])
    assert intact.intact and intact.describe_damage() == ""
    with open(paths[0], "rb") as f:
        summary = make_reader(f).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset)
    assert len(chunks) > 3
    middle = len(chunks) // 2
    record = next(index for index in summary.metadata_indexes if index.name == "summary")
    assert record.offset > chunks[-1].chunk_start_offset + chunks[-1].chunk_length  # outside the chunks
    key_at = data.index(b"sim_time", record.offset, record.offset + record.length)
    value_at = key_at + len(b"sim_time") + 4  # after the value's 4-byte length: its first digit
    digit = data[value_at:value_at + 1]
    assert digit.isdigit()
    cases = {
        "tail.mcap": (_flip(data, len(data) - 200, 100), "its summary section (bytes"),
        "chunk.mcap": (_flip(data, chunks[middle].chunk_start_offset + chunks[middle].chunk_length - 150, 100),
                       f"chunk {middle + 1} fails its check"),
        "record.mcap": (data[:value_at] + (b"7" if digit != b"7" else b"8") + data[value_at + 1:],
                        "its data section fails its CRC check"),
    }
    folder = tmp_path / "damaged"
    folder.mkdir()
    for name, (content, expected) in cases.items():
        (folder / name).write_bytes(content)
        episode = read_episode(folder / name)
        assert episode.complete and not episode.intact, name
        line = episode.describe_damage()
        assert expected in line and "\n" not in line and "is damaged" in line, line
        assert episode.summary is not None  # the summary record sits outside the chunks: still read
        actions, physics = episode.messages.get("/action", []), episode.messages.get("/physics", [])
        if name == "chunk.mcap":  # a prefix of the episode: the chunks before the damaged one
            assert 0 < len(actions) < steps[0] and physics == intact.messages["/physics"][: len(physics)]
            assert "data section passes" not in line
        else:
            assert actions == intact.messages["/action"] and physics == intact.messages["/physics"]
        if name == "tail.mcap":
            assert "the data section passes its CRC check" in line
        if name == "record.mcap":
            assert episode.summary["sim_time"] != intact.summary["sim_time"]  # read, but flagged as damaged
    assert cli.main(["logs", str(folder)]) == 0
    table = capsys.readouterr().out
    for name, (_, expected) in cases.items():
        assert f"| {name} (damaged) | waypoints/straight |" in table
        assert sum(line.startswith(f"- {folder / name} is damaged: ") and expected in line
                   for line in table.splitlines()) == 1, table
    assert "**all 3 complete (3 damaged)**" in table
    assert cli.main(["replay", str(folder / "tail.mcap")]) == 1
    out = capsys.readouterr().out
    assert "tail.mcap is damaged: its summary section" in out
    assert f"match: {steps[0]} steps" in out and "the file itself is damaged" in out
    assert cli.main(["replay", str(folder / "chunk.mcap")]) == 1
    out = capsys.readouterr().out
    assert f"chunk {middle + 1} fails its check" in out and "match:" in out and "MISMATCH" not in out
    assert cli.main(["replay", str(paths[0])]) == 0  # the intact file: a match, exit status 0
    assert "damaged" not in capsys.readouterr().out


_WORKER = """
import sys, time
import numpy as np
from mjdrive.envs import make_env
from mjdrive.record import RecordEpisodes, RecordOptions
env = RecordEpisodes(make_env("waypoints", "straight", time_limit=float(sys.argv[2])), sys.argv[1],
                     RecordOptions(chunk_size=4096))
for episode in range(2):
    env.reset(seed=11)
    step = 0
    while True:
        _, _, terminated, truncated, _ = env.step(np.array([0.3, 0.0, 0.0]))
        step += 1
        if episode == 1 and step == 20:
            print("MID", flush=True)
        if sys.argv[3] == "slow" and episode == 1:
            time.sleep(0.05)
        if terminated or truncated:
            break
env.close()
print("DONE", flush=True)
"""


def test_killed_writer_and_two_processes(tmp_path):
    """Two processes record the same task and seeds into one folder; one is SIGKILLed mid-episode. The
    survivor's files and the victim's finished episode are complete; the victim leaves one readable .part."""
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    start = lambda mode: subprocess.Popen(  # noqa: E731
        [sys.executable, "-c", _WORKER, str(tmp_path), "6.0", mode], stdout=subprocess.PIPE, text=True, env=env)
    victim, survivor = start("slow"), start("fast")
    try:
        assert victim.stdout.readline().strip() == "MID"
        victim.send_signal(signal.SIGKILL)
        victim.wait(timeout=30)
        assert survivor.communicate(timeout=120)[0].split() == ["MID", "DONE"]
    finally:
        for process in (victim, survivor):
            if process.poll() is None:
                process.kill()
                process.wait(timeout=30)
            process.stdout.close()  # the victim's pipe was never read to the end (a ResourceWarning otherwise)
    spec = EnvSpec("waypoints", "straight")
    complete = sorted(tmp_path.glob("*.mcap"))
    parts = sorted(tmp_path.glob("*.mcap.part"))
    assert len(complete) == 3 and len(parts) == 1
    names = {p.name for p in complete} | {p.name[: -len(".part")] for p in parts}
    assert names == {episode_filename(spec, 11, e, suffix) for e in (0, 1) for suffix in (0, 1)}
    pids = set()
    for path in complete:
        episode = read_episode(path)
        assert episode.complete, episode.error
        steps = episode.summary["steps"]
        assert len(episode.messages["/physics"]) == steps + 1 and len(episode.messages["/action"]) == steps
        times = [t for t, _ in episode.messages["/physics"]]
        assert all(b > a for a, b in zip(times, times[1:], strict=False))
        pids.add(episode.metadata["pid"])
    assert pids == {victim.pid, survivor.pid}
    partial = read_episode(parts[0])
    assert not partial.complete and partial.metadata["pid"] == victim.pid
    assert 0 < len(partial.messages["/action"]) <= 60
    assert "incomplete" in logs_table(tmp_path)  # the .part stays, listed as incomplete


def test_roundabout_traffic_is_logged_and_replays(tmp_path):
    """The real traffic of the densest roundabout, read through task.road_users(), replays bit for bit
    (mocap poses of every road user included). d210 is a registered task: a missing one fails here."""
    env = RecordEpisodes(make_env("roundabout", "d210", time_limit=4.0), tmp_path)
    _drive(env, 2, lambda observation: np.array([0.3, 0.0, 0.0], np.float32))
    env.close()
    path = env.recorder.paths[0]
    episode = read_episode(path)
    n_users = len(env.unwrapped.task.road_users().kinds)
    updates = episode.decoded("/scene/road_users")
    assert n_users > 0 and len(updates) == episode.summary["steps"] + 1
    assert len(updates[-1].entities[0].cubes) == n_users
    assert replay(path).match


def test_layout_file_refers_to_logged_topics():
    from mjdrive.record import LAYOUT

    layout = json.loads(LAYOUT.read_text())
    assert {"3D!mjdrive", "Image!mjdrive", "Plot!speed", "Plot!jerk", "Plot!reward"} <= set(layout["configById"])
    topics = PER_STEP | PER_ACTION | ONCE | {"/scene/road_users", "/camera/front", "/camera/front/calibration"}
    topics |= {"/operative", "/operative/plan", "/scene/plan"}  # an urban task's with decisions
    topics |= {"/junction", "/scene/signals"}  # an urban task's with stop signs or lights
    assert set(layout["configById"]["3D!mjdrive"]["topics"]) <= topics
    panels = [key for key in layout["configById"] if key.startswith(("Plot!", "StateTransitions!"))]
    assert {"Plot!operative", "StateTransitions!decision"} <= set(panels)
    for key in panels:
        for path in layout["configById"][key]["paths"]:
            assert path["value"].split(".")[0] in topics
    assert layout["configById"]["Image!mjdrive"]["imageMode"]["imageTopic"] == "/camera/front"


def test_batched_env_records_each_copy_apart_and_every_file_replays(tmp_path):
    from mjdrive.envs.batched import BatchedEnv
    from mjdrive.envs.replay import replay

    env = BatchedEnv("waypoints", "straight", num_envs=2, record_dir=tmp_path, time_limit=1.0)
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(25):  # 1 s episodes at 10 Hz: every copy auto-resets twice
        env.step(rng.uniform([0.2, -0.2, 0.0], [0.8, 0.2, 0.0], size=(2, 3)))
    env.close()
    for copy in ("env_00", "env_01"):
        files = sorted((tmp_path / copy).glob("*.mcap"))
        assert len(files) >= 2, files
        for path in files[:2]:
            result = replay(path)
            assert result.complete and result.mismatch_step is None and result.steps == 10, result


def test_a_part_is_locked_while_written_and_abandoned_or_killed_ones_are_removed_by_the_next_run(tmp_path, capsys):
    """The recorder holds a lock on each .part while it writes; `abandon()` (an error mid-episode) leaves the
    file readable and unlocked, and a fresh run folder there removes it (the killed writer's case is
    tests/test_eval_tasks.py's)."""
    from mjdrive.run_folder import fresh_folder, part_is_live

    env = RecordEpisodes(make_env("waypoints", "straight", **TASK_KWARGS), tmp_path)
    env.reset(seed=3)
    for _ in range(5):
        env.step(np.array([0.5, 0.0, 0.0]))
    part = env.recorder._part
    assert part.name.endswith(".mcap.part") and part_is_live(part)
    with pytest.raises(ValueError, match="is in use: a running process is writing"):
        fresh_folder(tmp_path, overwrite=True)
    assert env.recorder.abandon() == part and part.exists() and not part_is_live(part)
    assert not read_episode(part).complete
    env.close()  # nothing open any more: no file is written
    assert [p.name for p in tmp_path.iterdir()] == [part.name]
    fresh_folder(tmp_path, overwrite=False)
    assert list(tmp_path.iterdir()) == []
    assert "removed 1 unfinished log" in capsys.readouterr().err
