"""Depth, segmentation and range ring (`make_env(..., sensors=...)`): checked against the geometry of a car
placed in front of the ego, bounded by their spaces, recorded in the MCAP, and without effect on physics."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mjdrive.envs import make_env
from mjdrive.record import RecordEpisodes
from mjdrive.record.reader import read_episode
from mjdrive.record.replay import replay
from mjdrive.sensors import SEGMENT_CLASSES

AHEAD = 12.0  # [m] from the ego's chassis origin to the centre of the car placed in front of it


@pytest.fixture()
def car_ahead():
    """An env whose only road user (a car, half length 2.25 m) stands AHEAD m in front of the ego, aligned."""
    env = make_env("roundabout", "d120", road_users={"car": 1}, sensors="depth,segmentation,range", sensor_size=65)
    env.reset(seed=0)
    physics = env.unwrapped.dm_env.physics
    model, data = physics.model.ptr, physics.data.ptr
    body = model.body("ego/chassis").id
    yaw = np.arctan2(data.xmat[body][3], data.xmat[body][0])
    data.mocap_pos[0] = data.xpos[body] + AHEAD * np.array([np.cos(yaw), np.sin(yaw), 0.0])
    data.mocap_pos[0, 2] = 0.0
    data.mocap_quat[0] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
    mujoco.mj_forward(model, data)
    yield env, model, data
    env.close()


def test_range_ring_measures_the_gap_to_the_car_ahead(car_ahead):
    env, model, data = car_ahead
    ranges = env.unwrapped.sensors(env.unwrapped.dm_env.physics)["range"]
    half_length = model.geom_size[model.geom("traffic_0_car").id][0]
    assert ranges[0] == pytest.approx(AHEAD - half_length, abs=0.02)  # first ray straight ahead
    assert ranges[18] == pytest.approx(50.0)  # nothing behind within 50 m on an empty arm


def test_depth_and_segmentation_see_the_car_ahead(car_ahead):
    env, model, data = car_ahead
    readings = env.unwrapped.sensors(env.unwrapped.dm_env.physics)
    camera = model.camera("ego/front").id
    axis = -data.cam_xmat[camera].reshape(3, 3)[:, 2]  # MuJoCo cameras look along their -z axis
    geom = np.zeros(1, np.int32)
    expected = mujoco.mj_ray(model, data, data.cam_xpos[camera], axis, None, 1, model.body("ego/chassis").id, geom)
    assert model.geom(int(geom[0])).name == "traffic_0_car"
    centre = readings["depth"].shape[0] // 2
    assert readings["depth"][centre, centre] == pytest.approx(expected, rel=0.02)
    labels = readings["segmentation"]
    assert SEGMENT_CLASSES[labels[centre, centre]] == "car"
    assert SEGMENT_CLASSES[labels[0, centre]] == "background"  # sky above
    assert {"road", "marking"} & {SEGMENT_CLASSES[i] for i in np.unique(labels[-5:])}  # the road below


def test_sensors_are_bounded_recorded_and_leave_the_physics_alone(tmp_path):
    with_sensors = RecordEpisodes(make_env("roundabout", "d120", sensors=["depth", "segmentation", "range"]), tmp_path)
    plain = make_env("roundabout", "d120")
    obs, _ = with_sensors.reset(seed=4)
    reference, _ = plain.reset(seed=4)
    for _ in range(8):
        assert all(with_sensors.observation_space[key].contains(value) for key, value in obs.items())
        obs, *_ = with_sensors.step(np.array([0.4, 0.1, 0.0]))
        reference, *_ = plain.step(np.array([0.4, 0.1, 0.0]))
    assert all(np.array_equal(obs[key], reference[key]) for key in reference)
    with_sensors.close()
    plain.close()
    path = with_sensors.recorder.paths[-1]
    episode = read_episode(path)
    assert {len(episode.messages[t]) for t in ("/sensors/depth", "/sensors/segmentation", "/sensors/range")} == {8}
    assert replay(path).checked == 8 and replay(path).mismatch_step is None


def test_unknown_sensor_is_refused():
    with pytest.raises(ValueError, match="unknown sensor 'lidar'; sensors: depth, segmentation, range"):
        make_env("waypoints", "straight", sensors=["lidar"])
