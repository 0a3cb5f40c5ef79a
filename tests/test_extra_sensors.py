"""Depth, segmentation and range ring (the task keyword `sensors`, on every task): through `suite.load` and
gymnasium, checked against the geometry of a straight road and of a car placed in front of the ego, bounded
by their specs, recorded in the MCAP, refused with clear errors, and without effect on anything else."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mjdrive import ConfigError, suite
from mjdrive.envs import make_env
from mjdrive.record import RecordEpisodes
from mjdrive.record.reader import read_episode
from mjdrive.record.replay import replay
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
