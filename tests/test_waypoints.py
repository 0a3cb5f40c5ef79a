"""Study 004's task: the scripted driver completes every crafted route; sensors flag what they should."""

import numpy as np
import pytest

from mjdrive import roads, suite
from mjdrive.envs import make_env
from mjdrive.policies import pure_pursuit_policy
from mjdrive.sensors import LaneInvasionSensor, RouteTracker, footprint


def _drive(env, seed):
    policy = pure_pursuit_policy(env)
    observation, info = env.reset(seed=seed)
    while True:
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        if terminated or truncated:
            return info


@pytest.mark.parametrize("route", ["left_turn", "straight", "soft_right", "soft_left"])
def test_scripted_driver_completes_each_crafted_route(route):
    env = make_env("waypoints", "four_routes", time_limit=40.0)
    task = env.unwrapped.task
    names = ["left_turn", "straight", "soft_right", "soft_left"]
    task.routes = [task.routes[names.index(route)]]
    info = _drive(env, seed=1)
    assert info["route_completion"] >= 0.99, info
    assert info["success"] and not info["lane_invasion"] and not info["collision"] and not info["off_road"]


def test_scripted_driver_completes_straight_route_within_the_20s_limit():
    env = make_env("waypoints", "straight")
    info = _drive(env, seed=0)
    assert info["route_completion"] >= 0.99 and info["success"], info
    assert info["elapsed_time"] < 20.0


def test_scripted_driver_on_random_town_routes():
    env = make_env("waypoints", "random_routes", time_limit=120.0)
    completions = [_drive(env, seed)["route_completion"] for seed in range(3)]
    assert min(completions) >= 0.99, completions


def test_lane_invasion_flags_a_car_steered_across_a_solid_line_only():
    road_map, routes = roads.crafted_routes()
    lane = road_map.lanes[routes["straight"][0]]
    sensor = LaneInvasionSensor(road_map)
    length, width = 4.6, 1.9
    # Driving along the lane centre: no invasion.
    sensor.reset(footprint(*lane.position(10.0), lane.heading(10.0), length, width))
    for s in np.arange(10.5, 60.0, 0.5):
        assert not sensor(footprint(*lane.position(s), lane.heading(s), length, width))
    # Drifting steadily left across the marking: flagged while the corners cross it.
    sensor.reset(footprint(*lane.position(10.0), lane.heading(10.0), length, width))
    flagged = [sensor(footprint(*lane.position(10.0 + k, 0.25 * k), lane.heading(10.0), length, width))
               for k in range(1, 30)]
    assert any(flagged)


def test_camera_shows_waypoint_markers_and_only_the_next_few():
    env = suite.load("waypoints", "straight", {"random": 0, "observation": "camera"})
    timestep = env.reset()
    image = timestep.observation["image"]
    assert image.shape == (128, 128, 3) and image.dtype == np.uint8
    green = (image[..., 1] > 180) & (image[..., 0] < 100) & (image[..., 2] < 120)
    assert green.sum() > 10  # the markers are visible
    task = env.task
    plain = task.render_camera(env.physics, "ego/front", 128, 128, markers=None)
    green_plain = (plain[..., 1] > 180) & (plain[..., 0] < 100) & (plain[..., 2] < 120)
    assert green_plain.sum() == 0  # and they come from the markers alone
    assert task.visible_waypoints == 3


def test_route_tracker_counts_reached_and_skipped_waypoints():
    points = np.array([[float(k), 0.0] for k in range(0, 50, 5)])
    tracker = RouteTracker(points, np.zeros(len(points)), reach_radius=3.0)
    assert tracker.update(np.array([0.5, 0.0])) and tracker.reached == 1
    tracker.update(np.array([11.0, 6.0]))  # passes 5 and 10 too far to the side: skipped
    assert tracker.reached == 1 and tracker.next_index == 3
    for x in np.arange(12.0, 50.0, 1.0):
        tracker.update(np.array([x, 0.0]))
    assert tracker.done and tracker.reached == 8 and tracker.completion == pytest.approx(0.8)
