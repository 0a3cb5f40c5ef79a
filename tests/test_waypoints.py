"""Study 004's task: the scripted driver completes every crafted route; sensors flag what they should."""

import numpy as np
import pytest

from mjdrive import roads, suite
from mjdrive.envs import make_env
from mjdrive.policies import pure_pursuit_policy
from mjdrive.roads.geometry import footprint
from mjdrive.sensors import LaneInvasionSensor, RouteTracker


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


def test_buildings_line_the_roads_without_touching_them():
    env = suite.load("waypoints", "random_routes", {"random": 0, "buildings": True})
    model = env.physics.model.ptr
    buildings = [i for i in range(model.ngeom) if model.geom(i).name.startswith("building_")]
    assert len(buildings) > 20
    assert not env.task.road_map.on_road(model.geom_pos[buildings, :2]).any()
    assert (model.geom_contype[buildings] & 2).all()  # solid for the car body


def test_driving_into_an_obstacle_is_a_collision_from_a_real_contact():
    import mujoco
    from dm_control.mujoco import wrapper

    from mjdrive import world
    from mjdrive.tasks.base import DrivingEnvironment, Physics
    from mjdrive.tasks.waypoints import WaypointsConfig, WaypointTask

    road_map, routes = roads.crafted_routes()
    lane = road_map.lanes[routes["straight"][0]]
    spec = world.build_spec(road_map)
    block = lane.position(40.0)
    spec.worldbody.add_geom(name="block", type=mujoco.mjtGeom.mjGEOM_BOX, size=[1, 1, 1],
                            pos=[block[0], block[1], 1.0], contype=2, conaffinity=2)
    model = spec.compile()
    task = WaypointTask(model, road_map, [routes["straight"]], WaypointsConfig(start_noise=(0.0, 0.0), random=0))
    env = DrivingEnvironment(Physics.from_model(wrapper.MjModel(model)), task, control_timestep=0.1)
    env.reset()
    for _ in range(100):
        timestep = env.step(np.array([0.6, 0.0, 0.0]))
        if timestep.last():
            break
    assert task.info["collision"] and not task.info["lane_invasion"] and timestep.discount == 0.0
    assert model.geom(task.collision_sensor.last_other_geom).name == "block"


def test_off_road_ends_the_episode():
    env = suite.load("waypoints", "straight", {"random": 0})
    env.reset()
    task, data = env.task, env.physics.data.ptr
    x, y, yaw = task.vehicle.pose(data)
    task.vehicle.reset(data, x, y + 30.0, yaw)  # 30 m beside the road, on the grass
    timestep = env.step(np.zeros(3))
    assert task.info["off_road"] and timestep.last() and timestep.discount == 0.0


def test_camera_image_depends_on_the_state_alone():
    """Same state, same pixels: also right after the camera jumped to another route (a reset)."""
    env = make_env("waypoints", "four_routes", observation="camera")
    images = []
    for _ in range(3):
        observation, _ = env.reset(seed=123)
        images.append(observation["image"].copy())
        env.reset()  # another route, hundreds of metres away
    assert all(np.array_equal(images[0], image) for image in images[1:])


@pytest.mark.parametrize("capped", [False, True])
def test_features_reward_pays_for_speed_above_the_limit_only_without_the_cap(capped):
    env = make_env("waypoints", "straight", speed_limit_reward=capped, start_noise=(0.0, 0.0))
    task = env.unwrapped.task
    policy = pure_pursuit_policy(env, cruise=12.0)  # [m/s] above the 30 km/h limit
    observation, _ = env.reset(seed=0)
    limit = task.road_map.lanes[task.route[0]].speed_limit * 3.6  # [km/h]
    seen = {"below": 0, "above": 0}
    for _ in range(120):
        observation, reward, terminated, truncated, info = env.step(policy(observation))
        v, theta = task.speed * 3.6, task.heading_error
        speed_term = task.reward_terms["speed"]
        if v < limit:
            seen["below"] += 1
            assert speed_term == pytest.approx(abs(v * np.cos(theta)) - abs(v * np.sin(theta)))
        else:
            seen["above"] += 1
            assert speed_term == pytest.approx(-v if capped else abs(v * np.cos(theta)) - abs(v * np.sin(theta)))
        if terminated or truncated:
            break
    assert seen["below"] > 0 and seen["above"] > 0, seen
