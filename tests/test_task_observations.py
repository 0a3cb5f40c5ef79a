"""The tasks' observation tables and ego updates against their specification: road users at equal distances in
slot order, distances and speeds capped at their scales, an empty world's zero rows; an ego off its route and
turned round: the offset and the heading error (wrapped), the footprint's corners."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mjdrive.envs import make_env
from mjdrive.roads.geometry import footprint
from mjdrive.traffic.lanes import polyline_distance


def _rows(observation: dict[str, np.ndarray]) -> np.ndarray:
    return observation["adversaries"] if "adversaries" in observation else observation["road_users"]


@pytest.mark.parametrize("task_id", ["urban/crossroad", "roundabout/d210"])
def test_nearest_road_users_in_slot_order_on_ties_and_none_in_an_empty_world(task_id):
    env = make_env(*task_id.split("/"), random=2)
    dm_env = env.unwrapped.dm_env
    env.reset(seed=2)
    for _ in range(20):
        env.step(np.array([0.0, 0.0, 1.0]))
    task, traffic = dm_env.task, dm_env.task.traffic
    present = np.flatnonzero(traffic.present)
    assert len(present) >= 5
    point = task.relevant_point() if hasattr(task, "relevant_point") else task.xy
    pos, speed = traffic.now.pos, traffic.now.speed  # the slots' poses now (edited in place)
    for j, slot in enumerate(present):  # beyond the urban distance scale (60 m: capped at 1)
        pos[slot, :2] = point + (61.0 + j) * np.array([0.6, 0.8])
    speed[present[0]] = 20.0  # [m/s] beyond the urban speed scale (15 m/s)
    tied = present[-4:]  # four users on a circle round the point: equal distances, their slots in order
    for j, (slot, angle) in enumerate(zip(tied, (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi), strict=True)):
        pos[slot, :2] = point + 7.0 * np.array([np.cos(angle), np.sin(angle)])
        speed[slot] = 1.0 + j  # [m/s] tells them apart
    rows = _rows(task.get_observation(dm_env.physics))
    if task_id.startswith("urban"):  # present, distance / 60 m, speed / 15 m/s, ...
        np.testing.assert_allclose(rows[:4, 1], 7.0 / 60.0, rtol=1e-6)
        np.testing.assert_allclose(rows[:4, 2], (1.0 + np.arange(4)) / 15.0, rtol=1e-6)
        assert rows[4, 1] == 1.0 and rows[4, 2] == 1.0  # both caps taken
    else:  # present, dx, dy in the ego frame, the velocity relative to the ego's, ...
        np.testing.assert_allclose(np.hypot(rows[:4, 1], rows[:4, 2]), 7.0, rtol=1e-5)
        relative = np.hypot(rows[:4, 3] + task.speed * rows[:4, 5], rows[:4, 4] + task.speed * rows[:4, 6])
        assert np.all(np.diff(np.round(relative, 3)) != 0)  # four different users (1..4 m/s, in some frame)
    assert rows[:, 0].sum() >= 5
    traffic.vehicles.active[:] = False  # no vehicle in the world (pedestrians stay present by definition)
    rows = _rows(task.get_observation(dm_env.physics))
    assert rows[:, 0].sum() == np.count_nonzero(traffic.present) and np.all(rows[rows[:, 0] == 0] == 0)
    env.close()


@pytest.mark.parametrize("task_id", ["urban/lane_change", "roundabout/d160"])
def test_ego_update_off_the_route_and_turned_round(task_id):
    """3.5 m to the left of the route and turned by 3.2 rad: the lateral offset is the distance to the route's
    polyline (left: positive), the heading error wrapped into [-pi, pi) is large; the roundabout's footprint corners
    are the car's box and their offsets their distances to the route (to within the segments' resolution)."""
    env = make_env(*task_id.split("/"), random=3)
    dm_env = env.unwrapped.dm_env
    task, physics = dm_env.task, dm_env.physics
    env.reset(seed=3)
    env.step(np.array([0.3, 0.0, 0.0]))
    data = physics.raw_data
    qa, _ = task.vehicle.state_addresses
    yaw = task.yaw
    data.qpos[qa:qa + 2] += 3.5 * np.array([-np.sin(yaw), np.cos(yaw)])
    data.qpos[qa + 3:qa + 7] = (np.cos(0.5 * (yaw + 3.2)), 0.0, 0.0, np.sin(0.5 * (yaw + 3.2)))
    task._update_ego(physics)
    x, y, yaw = task.vehicle.pose(data)
    assert task.lane_offset > 2.5
    assert task.lane_offset == pytest.approx(polyline_distance(np.array([[x, y]]), task.route_lane.centre)[0], abs=1e-9)
    assert -math.pi <= task.heading_error < math.pi and abs(task.heading_error) > 2.5
    if task_id.startswith("roundabout"):
        np.testing.assert_allclose(task.corners, footprint(x, y, yaw, task.params.length, task.params.width),
                                   atol=1e-12)
        distance = polyline_distance(task.corners, task.route_lane.centre)
        np.testing.assert_allclose(np.abs(task.corner_offsets), distance, atol=0.05)  # (segments ~0.5 m: a corner's
        # nearest one in the search window may be a neighbour of the polyline's nearest)
    env.close()
