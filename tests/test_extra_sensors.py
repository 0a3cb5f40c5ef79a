"""Depth, segmentation and range ring (the task keyword `sensors`, on every task): through `suite.load` and
gymnasium, checked against the geometry of a straight road and of a car placed in front of the ego, bounded
by their specs, recorded in the MCAP, refused with clear errors, and without effect on anything else."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mjdrive import ConfigError, suite
from mjdrive.envs import make_env
from mjdrive.envs.replay import replay, replay_task_kwargs
from mjdrive.record import EnvSpec, RecordedEnvironment, RecordEpisodes
from mjdrive.record.reader import read_episode
from mjdrive.record.recorder import SEGMENT_SCALE, decode_rng_state
from mjdrive.sensors import SEGMENT_CLASSES, DepthSegmentationCamera, geom_classes

AHEAD = 12.0  # [m] from the ego's chassis origin to the centre of the car placed in front of it
ALL = ["depth", "segmentation", "range"]


def _place_car_ahead(model: mujoco.MjModel, data: mujoco.MjData, distance: float = AHEAD) -> None:
    """Move the first road user (a car) `distance` [m] in front of the ego, aligned with it."""
    body = model.body("ego/chassis").id
    yaw = np.arctan2(data.xmat[body][3], data.xmat[body][0])
    data.mocap_pos[0] = data.xpos[body] + distance * np.array([np.cos(yaw), np.sin(yaw), 0.0])
    data.mocap_pos[0, 2] = 0.0
    data.mocap_quat[0] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
    mujoco.mj_forward(model, data)


@pytest.fixture()
def car_ahead():
    """A roundabout env whose only road user (a car, half length 2.25 m) stands AHEAD m in front of the ego."""
    env = suite.load("roundabout", "d120", {"random": 0, "road_users": {"car": 1}, "sensors": ALL,
                                            "sensor_size": 65})
    env.reset()
    model, data = env.physics.model.ptr, env.physics.data.ptr
    empty = env.task.sensor_observation(env.physics)
    _place_car_ahead(model, data)
    yield env, model, data, empty
    env.close()


@pytest.mark.parametrize("domain, task", [("waypoints", "straight"), ("roundabout", "d120")])
def test_suite_load_adds_the_sensors_with_their_specs(domain, task):
    plain = suite.load(domain, task, {"random": 0})
    env = suite.load(domain, task, {"random": 0, "sensors": "depth,segmentation,range", "sensor_size": 32,
                                    "range_rays": 24, "range_max": 40.0})
    spec = env.observation_spec()
    assert list(spec) == list(plain.observation_spec()) + ALL  # the task's own keys first, unchanged
    far = env.physics.model.vis.map.zfar * env.physics.model.stat.extent  # [m]
    assert (spec["depth"].shape, spec["depth"].dtype, spec["depth"].maximum) == ((32, 32), np.float32, far)
    assert (spec["segmentation"].shape, spec["segmentation"].dtype) == ((32, 32), np.uint8)
    assert spec["segmentation"].maximum == len(SEGMENT_CLASSES) - 1
    assert (spec["range"].shape, spec["range"].dtype, spec["range"].maximum) == ((24,), np.float32, 40.0)
    timestep = env.reset()
    for _ in range(3):
        for name in ALL:
            spec[name].validate(timestep.observation[name])  # shape, dtype and bounds
        depth = timestep.observation["depth"]
        assert depth.min() > 0.5 and depth.max() == pytest.approx(far)  # the sky reads `far`
        assert timestep.observation["range"].min() > 0.0
        timestep = env.step(np.array([0.5, 0.0, 0.0]))
    env.close()
    plain.close()


def test_depth_grows_with_the_distance_along_a_straight_road():
    env = suite.load("waypoints", "straight", {"random": 0, "start_noise": [0.0, 0.0], "sensors": ["depth",
                                                                                                    "segmentation"]})
    observation = env.reset().observation
    depth, labels = observation["depth"], observation["segmentation"]
    column = depth.shape[1] // 2
    flat = np.isin(labels[:, column], [SEGMENT_CLASSES.index(n) for n in ("ground", "road", "marking")])
    rows = np.flatnonzero(flat)[::-1]  # bottom of the image (near) to the horizon (far)
    assert len(rows) > depth.shape[0] // 4
    assert np.all(np.diff(depth[rows, column]) > 0.0)  # strictly farther up the image
    assert depth[rows[0], column] < 10.0 and depth[rows[-1], column] > 30.0
    assert SEGMENT_CLASSES[labels[-1, column]] == "road"  # the lane under the camera
    assert SEGMENT_CLASSES[labels[0, column]] == "background" and depth[0, column] == pytest.approx(
        env.physics.model.vis.map.zfar * env.physics.model.stat.extent)
    env.close()


def test_range_ring_readings_shrink_when_a_car_is_ahead(car_ahead):
    env, model, data, empty = car_ahead
    ranges = env.task.sensor_observation(env.physics)["range"]
    half_length = model.geom_size[model.geom("traffic_0_car").id][0]
    assert ranges[0] == pytest.approx(AHEAD - half_length, abs=0.02)  # first ray straight ahead
    assert ranges[0] < empty["range"][0]
    assert ranges[18] == pytest.approx(50.0)  # nothing behind within 50 m on an empty arm
    _place_car_ahead(model, data, AHEAD - 4.0)
    assert env.task.sensor_observation(env.physics)["range"][0] == pytest.approx(AHEAD - 4.0 - half_length, abs=0.02)


def test_depth_and_segmentation_see_the_car_ahead(car_ahead):
    env, model, data, empty = car_ahead
    readings = env.task.sensor_observation(env.physics)
    camera = model.camera("ego/front").id
    axis = -data.cam_xmat[camera].reshape(3, 3)[:, 2]  # MuJoCo cameras look along their -z axis
    geom = np.zeros(1, np.int32)
    expected = mujoco.mj_ray(model, data, data.cam_xpos[camera], axis, None, 1, model.body("ego/chassis").id, geom)
    assert model.geom(int(geom[0])).name == "traffic_0_car"
    centre = readings["depth"].shape[0] // 2
    assert readings["depth"][centre, centre] == pytest.approx(expected, rel=0.02)
    assert readings["depth"][centre, centre] < empty["depth"][centre, centre]
    labels = readings["segmentation"]
    assert SEGMENT_CLASSES[labels[centre, centre]] == "car"
    assert SEGMENT_CLASSES[labels[0, centre]] == "background"  # sky above
    assert {"road", "marking"} & {SEGMENT_CLASSES[i] for i in np.unique(labels[-5:])}  # the road below


def test_segmentation_labels_the_ego_the_road_and_the_traffic_apart(car_ahead):
    env, model, data, _ = car_ahead
    camera = DepthSegmentationCamera(model, "ego/chase", 96, 96)  # behind the ego: it, the road and the car
    try:
        camera.render_sensors(data)
        seen = {SEGMENT_CLASSES[i] for i in np.unique(camera.segmentation_image)}
    finally:
        camera.close()
    assert {"ego", "road", "car", "background"} <= seen
    classes = geom_classes(model)
    assert SEGMENT_CLASSES[classes[model.geom("ego/v_core").id]] == "ego"
    assert SEGMENT_CLASSES[classes[model.geom("road_surface").id]] == "road"
    assert SEGMENT_CLASSES[classes[model.geom("traffic_0_car").id]] == "car"


@pytest.mark.parametrize("kwargs, message", [
    ({"sensors": ["lidar"]}, "sensors=\\['lidar'\\]: element 'lidar' is not one of 'depth', 'segmentation', 'range'"),
    ({"sensors": "depth,lidar"}, "element 'lidar' is not one of 'depth', 'segmentation', 'range'"),
    ({"sensors": ["depth", "depth"]}, "must not repeat an element"),
    ({"sensors": 3}, "sensors=3: must be a list"),
    ({"sensor_size": 4}, "sensor_size=4: must be >= 8 and <= 512 \\[px\\]"),
    ({"range_rays": 0}, "range_rays=0: must be >= 1"),
    ({"range_max": -1.0}, "range_max=-1.0: must be > 0 and <= 500 \\[m\\]"),
    ({"sensor": ["depth"]}, "unknown keyword 'sensor' .*did you mean 'sensors'"),
])
def test_bad_sensor_keywords_are_refused(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        suite.load("waypoints", "straight", kwargs)
    with pytest.raises(ConfigError, match=message):
        make_env("roundabout", "d120", **kwargs)  # the gymnasium path validates the same keywords


def test_no_sensors_is_the_default():
    for value in (None, [], ""):
        env = suite.load("waypoints", "straight", {"random": 0, "sensors": value})
        assert env.task.sensors is None and "depth" not in env.observation_spec()
        env.close()


def test_sensors_are_bounded_recorded_and_leave_the_physics_alone(tmp_path):
    with_sensors = RecordEpisodes(make_env("roundabout", "d120", sensors=ALL), tmp_path)
    plain = make_env("roundabout", "d120")
    obs, _ = with_sensors.reset(seed=4)
    reference, _ = plain.reset(seed=4)
    assert set(with_sensors.observation_space) == set(plain.observation_space) | set(ALL)
    for _ in range(8):
        assert all(with_sensors.observation_space[key].contains(value) for key, value in obs.items())
        obs, *_ = with_sensors.step(np.array([0.4, 0.1, 0.0]))
        reference, *_ = plain.step(np.array([0.4, 0.1, 0.0]))
    assert all(np.array_equal(obs[key], reference[key]) for key in reference)
    with_sensors.close()
    plain.close()
    path = with_sensors.recorder.paths[-1]
    episode = read_episode(path)
    assert episode.metadata["task_kwargs"]["sensors"] == ALL  # a replay rebuilds the same sensors
    assert {len(episode.messages[t]) for t in ("/sensors/depth", "/sensors/segmentation", "/sensors/range")} == {8}
    assert replay(path).checked == 8 and replay(path).mismatch_step is None


def test_same_seed_same_sensor_readings():
    def run() -> list[dict[str, np.ndarray]]:
        env = suite.load("roundabout", "d120", {"random": 3, "sensors": ALL})
        readings = [dict(env.reset().observation)]
        for _ in range(4):
            readings.append(dict(env.step(np.array([0.6, -0.1, 0.0])).observation))
        env.close()
        return readings

    first, second = run(), run()
    assert all(np.array_equal(a[key], b[key]) for a, b in zip(first, second, strict=True) for key in a)


def _logged_sensors(path) -> list[dict[str, np.ndarray]]:
    """The sensor readings of every step of a log, as the observations held them."""
    episode = read_episode(path)
    depth, labels, ranges = (episode.decoded(f"/sensors/{name}") for name in ALL)
    return [{"depth": np.frombuffer(d.data, np.float32).reshape(d.height, d.width),
             "segmentation": np.frombuffer(s.data, np.uint8).reshape(s.height, s.width) // SEGMENT_SCALE,
             "range": np.array(r.ranges, np.float32)}
            for d, s, r in zip(depth, labels, ranges, strict=True)]


def test_dm_control_recorder_logs_the_sensors_and_they_replay_bit_for_bit(tmp_path):
    kwargs = {"random": 5, "road_users": {"car": 2}, "sensors": ALL, "sensor_size": 24, "range_rays": 12}
    env = RecordedEnvironment(suite.load("roundabout", "d120", kwargs), EnvSpec("roundabout", "d120", kwargs),
                              tmp_path)
    env.reset()
    actions = [np.array([0.6, 0.05 * k - 0.1, 0.0]) for k in range(6)]
    observed = [{name: value.copy() for name, value in env.step(action).observation.items()} for action in actions]
    env.close()
    path = env.recorder.paths[-1]
    assert path.name == "roundabout-d120_5_00000.mcap"  # the dm_control seed names the file
    logged = _logged_sensors(path)
    assert len(logged) == len(actions)  # one reading per step, as the gymnasium recorder writes
    for seen, log in zip(observed, logged, strict=True):
        assert all(np.array_equal(seen[name], log[name]) for name in ALL)
        assert seen["depth"].min() < 10.0  # a real reading: the road under the camera
    assert not np.array_equal(observed[0]["depth"], observed[-1]["depth"])  # one per step, as the ego moves
    result = replay(path)
    assert result.match, result.report()

    # re-simulated from the log's metadata and actions, the sensors read the same bytes
    metadata = read_episode(path).metadata
    again = suite.load(metadata["domain"], metadata["task_name"], replay_task_kwargs(metadata))
    again.task.random.set_state(decode_rng_state(metadata["rng_state"]))
    again.reset()
    for log, action in zip(logged, read_episode(path).actions(), strict=True):
        observation = again.step(action).observation
        assert all(observation[name].tobytes() == log[name].tobytes() for name in ALL)
    again.close()


def test_the_gymnasium_and_dm_control_recorders_log_the_same_sensor_topics(tmp_path):
    kwargs = {"sensors": ALL, "sensor_size": 16}
    gym_env = RecordEpisodes(make_env("waypoints", "straight", **kwargs), tmp_path / "gym")
    gym_env.reset(seed=2)
    dm_env = RecordedEnvironment(suite.load("waypoints", "straight", {"random": 2, **kwargs}),
                                 EnvSpec("waypoints", "straight", {"random": 2, **kwargs}), tmp_path / "dm")
    dm_env.reset()
    for _ in range(3):
        gym_env.step(np.array([0.5, 0.0, 0.0]))
        dm_env.step(np.array([0.5, 0.0, 0.0]))
    gym_env.close()
    dm_env.close()
    episodes = [read_episode(env.recorder.paths[-1]) for env in (gym_env, dm_env)]
    topics = [{t for t in e.topics if t.startswith("/sensors/")} for e in episodes]
    assert topics[0] == topics[1] == {f"/sensors/{name}" for name in ALL}
    assert [{t: e.schemas[t][0] for t in topics[0]} for e in episodes][0] == {
        t: episodes[1].schemas[t][0] for t in topics[0]}
    assert all(len(e.messages[t]) == 3 for e in episodes for t in topics[0])


def test_the_batched_env_records_the_sensors_of_each_copy(tmp_path):
    from mjdrive.envs.batched import BatchedEnv

    env = BatchedEnv("waypoints", "straight", num_envs=2, record_dir=tmp_path, time_limit=0.5,
                     sensors=["depth", "range"], sensor_size=16)
    env.reset(seed=1)
    for _ in range(5):  # 0.5 s episodes at 10 Hz: each copy's first episode ends
        env.step(np.tile([0.5, 0.0, 0.0], (2, 1)))
    env.close()
    for copy in ("env_00", "env_01"):
        episode = read_episode(min((tmp_path / copy).glob("*_00000.mcap")))
        assert {t for t in episode.topics if t.startswith("/sensors/")} == {"/sensors/depth", "/sensors/range"}
        assert len(episode.messages["/sensors/depth"]) == len(episode.messages["/action"]) == 5
