"""Study 000's roundabout task: densities, observations, eq. 12 reward, contacts, limits, the scripted
drivers, determinism."""

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import mjdrive  # noqa: F401  (registers the gymnasium ids)
from mjdrive import suite
from mjdrive.control.autopilot import Autopilot
from mjdrive.tasks.roundabout import DENSITIES, MAX_STEPS

TERMS = {"collision", "progress", "speed", "off_road", "other_lane", "arrival", "off_route"}


@pytest.fixture(scope="module")
def env210():
    return suite.load("roundabout", "d210", {"random": 0})


def _drive(env, driver, max_steps=MAX_STEPS):
    timestep = env.reset()
    driver.reset()
    rewards = []
    while not timestep.last() and len(rewards) < max_steps:
        timestep = env.step(driver(env.physics))
        rewards.append(timestep.reward)
    return timestep, rewards


@pytest.mark.parametrize("level", sorted(DENSITIES))
def test_density_levels_have_their_road_users(level):
    env = suite.load("roundabout", level, {"random": 0})
    traffic = env.task.traffic
    counts = {kind: traffic.kinds.count(kind) for kind in set(traffic.kinds)}
    assert counts == {k: n for k, n in DENSITIES[level].items() if n}
    assert env.physics.model.nmocap == traffic.n
    env.reset()
    users = env.task.road_users()
    assert len(users.kinds) == len(users.poses) == len(users.half_sizes) == traffic.present.sum() > 10


def test_observations_camera_stack_and_destination_vector():
    env = suite.load("roundabout", "d120", {"random": 1, "observation": "camera"})
    timestep = env.reset()
    image = timestep.observation["image"]
    assert image.shape == (4, 84, 84) and image.dtype == np.uint8
    assert all(np.array_equal(image[0], image[k]) for k in range(4))  # the first frame, repeated
    for _ in range(3):
        timestep = env.step(np.array([0.6, 0.0, 0.0]))
    image = timestep.observation["image"]
    assert not np.array_equal(image[-1], image[0])  # the newest frame last, and the scene moved
    task = env.task
    np.testing.assert_allclose(timestep.observation["destination"], task.destination - task.xy, atol=1e-4)
    assert image.std() > 5  # not a blank frame
    assert set(timestep.observation) == {"image", "destination"}  # the study's camera input only


def test_camera_observation_can_carry_the_ego_state():
    features = suite.load("roundabout", "d120", {"random": 2})
    camera = suite.load("roundabout", "d120", {"random": 2, "observation": "camera", "camera_ego": True})
    assert set(camera.observation_spec()) == {"image", "destination", "ego"}
    a, b = features.reset(), camera.reset()
    for _ in range(6):
        a, b = features.step(np.array([0.5, 0.2, 0.0])), camera.step(np.array([0.5, 0.2, 0.0]))
    ego = b.observation["ego"]
    np.testing.assert_array_equal(ego, a.observation["ego"])  # same episode, same ego vector
    assert ego[0] > 1.0 and abs(ego[3]) > 0.0  # [m/s] moving; off the centre line after steering


def test_wide_camera_sees_a_road_user_beside_the_front_corner():
    """`camera="front_wide"` (120 deg) keeps in view a car alongside whose front end is 1.3 m ahead of the
    camera and whose side is 1.7 m right of it (beyond 45 deg), which the 90 deg front camera (the study's)
    misses; unknown cameras list the ego's."""
    changed = {}
    for camera in ("front", "front_wide"):
        env = suite.load("roundabout", "d120", {"random": 3, "observation": "camera", "camera": camera})
        env.reset()
        task, physics = env.task, env.physics
        mocap = task.traffic.mocap_ids
        data = physics.data
        data.mocap_pos[mocap] = [0.0, 0.0, -50.0]  # every road user out of sight
        physics.forward()
        empty = task.render_camera(physics, task.camera, 84, 84).astype(int)
        yaw = task.yaw
        ahead, right = np.array([np.cos(yaw), np.sin(yaw)]), np.array([np.sin(yaw), -np.cos(yaw)])
        car = task.traffic.kinds.index("car")
        half_length, half_width, half_height = task.traffic.half_size[car]  # [m]
        camera_x = physics.model.cam_pos[physics.model.camera(task.camera).id, 0]  # [m] ahead of the ego centre
        forward = camera_x + 1.3 - half_length  # [m] the car's centre ahead of the ego's
        data.mocap_pos[mocap[car], :2] = task.xy + forward * ahead + (1.7 + half_width) * right
        data.mocap_pos[mocap[car], 2] = half_height
        data.mocap_quat[mocap[car]] = [np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]
        physics.forward()
        image = task.render_camera(physics, task.camera, 84, 84).astype(int)
        changed[camera] = int((np.abs(image - empty).sum(axis=-1) > 30).sum())  # [px] showing the car
    assert changed["front"] < 0.25 * changed["front_wide"] and changed["front_wide"] > 150
    with pytest.raises(ValueError, match="camera=.rear.: must be one of .front., .front_wide."):
        suite.load("roundabout", "d120", {"observation": "camera", "camera": "rear"})


def test_features_observation_lists_the_nearest_road_users(env210):
    timestep = env210.reset()
    obs = timestep.observation
    assert obs["ego"].shape == (6,) and obs["destination"].shape == (2,)
    users = obs["road_users"]
    assert users.shape == (8, 13) and users[:, 0].all()
    distances = np.hypot(users[:, 1], users[:, 2])
    assert np.all(np.diff(distances) >= -1e-4)  # nearest first
    assert np.allclose(users[:, 9:].sum(axis=1), 1.0)  # one kind each
    nearest = np.sort(np.hypot(*(env210.task.road_users().poses[:, :2] - env210.task.xy).T))[:8]
    np.testing.assert_allclose(distances, nearest, atol=1e-3)


def test_features_observation_is_the_state_after_the_step(env210):
    """The ego vector and the road users' relative velocities use the pose and velocity read after the step
    (kept from `_update_ego`): they equal a fresh read of the chassis."""
    env = env210
    env.reset()
    task, data = env.task, env.physics.raw_data
    for k in range(12):
        obs = env.step(np.array([0.6, 0.2 if k < 6 else -0.2, 0.0])).observation
        vx, vy = task.vehicle.velocity_body(data)
        x, y, yaw = task.vehicle.pose(data)
        assert obs["ego"][4:].tolist() == np.array([np.cos(yaw), np.sin(yaw)], np.float32).tolist()
        users, traffic = obs["road_users"], task.traffic
        present = np.flatnonzero(traffic.present)
        nearest = present[np.argsort(np.hypot(*(traffic.positions()[present] - (x, y)).T), kind="stable")[:8]]
        dyaw = traffic.yaws()[nearest] - yaw
        expected = np.stack([traffic.speeds()[nearest] * np.cos(dyaw) - vx,
                             traffic.speeds()[nearest] * np.sin(dyaw) - vy], 1).astype(np.float32)
        np.testing.assert_allclose(users[:, 3:5], expected, atol=1e-5)
    assert abs(vy) > 1e-3  # the car turned: a stale or swapped lateral velocity would show


def test_ego_hitting_a_traffic_car_is_a_real_contact_and_ends_the_episode(env210):
    env = env210
    env.reset()
    task = env.task
    traffic = task.traffic
    traffic.remove_all()
    traffic.place(0, task.route[1:], s=6.5, speed=0.0, desired_speed=0.0)  # parked on the entry, ahead
    driver = Autopilot(task, env.control_timestep(), careful=False)  # drives into it
    for _ in range(30):
        timestep = env.step(driver(env.physics))
        if timestep.last():
            break
    assert timestep.last() and timestep.discount == 0.0
    assert task.info["collision"] and not task.info["success"]
    assert task.reward_terms["collision"] == -100.0
    name = mujoco.mj_id2name(env.physics.model.ptr, mujoco.mjtObj.mjOBJ_GEOM, task.collision_sensor.last_other_geom)
    assert name.startswith("traffic_0_")
    data = env.physics.data.ptr
    geoms = {(int(c.geom1), int(c.geom2)) for c in data.contact[: data.ncon]}
    assert any(task.collision_sensor.last_other_geom in pair for pair in geoms)  # a MuJoCo contact


def test_collision_penalty_sets_what_the_same_crash_costs():
    """`collision_penalty` replaces eq. 12's 100 in the collision term and nothing else."""
    costs = {}
    for penalty in (100.0, 300.0):
        env = suite.load("roundabout", "d210", {"random": 0, "collision_penalty": penalty})
        env.reset()
        task = env.task
        task.traffic.remove_all()
        task.traffic.place(0, task.route[1:], s=6.5, speed=0.0, desired_speed=0.0)
        driver = Autopilot(task, env.control_timestep(), careful=False)
        while not (timestep := env.step(driver(env.physics))).last():
            pass
        assert task.info["collision"]
        costs[penalty] = (timestep.reward, dict(task.reward_terms))
    (reward_100, terms_100), (reward_300, terms_300) = costs[100.0], costs[300.0]
    assert terms_100["collision"] == -100.0 and terms_300["collision"] == -300.0
    assert reward_100 - reward_300 == pytest.approx(200.0)  # the same crash, the other terms equal
    with pytest.raises(ValueError, match="collision_penalty"):
        suite.load("roundabout", "d120", {"collision_penalty": -1.0})


def test_reward_terms_follow_eq_12(env210):
    env = env210
    env.reset()
    task = env.task
    remaining = task.remaining
    episode_return = 0.0
    for k in range(25):
        timestep = env.step(np.array([0.5, 0.0, 0.0]) if k < 15 else np.array([0.0, 0.0, 1.0]))
        episode_return += timestep.reward
        terms = task.reward_terms
        assert set(terms) == TERMS
        assert timestep.reward == pytest.approx(sum(terms.values()))
        assert terms["progress"] == pytest.approx(remaining - task.remaining)
        assert terms["speed"] == pytest.approx(np.clip(task.speed * 3.6, 0, 30) / 10)
        assert -0.05 <= terms["off_road"] <= 0 and -0.05 <= terms["other_lane"] <= 0
        assert terms["arrival"] == (100.0 if task.info["success"] else 0.0)
        remaining = task.remaining
        if timestep.last():
            break
    assert task.info["steps"] == k + 1
    assert task.info["episode_reward"] == pytest.approx(episode_return)  # the sum of the step rewards


def test_episode_is_truncated_after_1100_steps():
    env = suite.load("roundabout", "d120", {"random": 0})
    timestep = env.reset()
    steps = 0
    while not timestep.last():
        timestep = env.step(np.array([0.0, 0.0, 1.0]))  # wait at the yield line for ever
        steps += 1
    assert steps == MAX_STEPS and timestep.discount == 1.0  # truncated, not terminated
    assert env.task.info["elapsed_time"] == pytest.approx(MAX_STEPS * 0.2)
    assert not env.task.info["collision"] and not env.task.info["success"]


@pytest.mark.parametrize("level", ["d120", "d210"])
def test_careful_autopilot_arrives(level):
    env = suite.load("roundabout", level, {"random": 3})
    driver = Autopilot(env.task, env.control_timestep(), careful=True)
    for _ in range(3):
        timestep, rewards = _drive(env, driver)
        info = env.task.info
        assert info["success"] and not info["collision"], info
        assert timestep.discount == 0.0 and rewards[-1] > 100.0  # the arrival bonus
        assert info["remaining_distance"] < 1.0
        assert info["distance"] == pytest.approx(info["route_length"], rel=0.1)
        assert info["average_speed"] == pytest.approx(info["distance"] / info["elapsed_time"])


def test_just_drive_collides_at_the_densest_level(env210):
    driver = Autopilot(env210.task, env210.control_timestep(), careful=False)
    collisions = sum(_drive(env210, driver)[0].discount == 0.0 and env210.task.info["collision"]
                     for _ in range(10))
    assert collisions >= 2


def _rollout(env_id, seed, steps=40):
    env = gym.make(env_id)
    observation, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    observations, users = [observation], []
    for _ in range(steps):
        action = rng.uniform([0, -0.3, 0], [1, 0.3, 0.2]).astype(np.float32)
        observation, _, terminated, truncated, _ = env.step(action)
        observations.append(observation)
        users.append(env.unwrapped.task.road_users().poses.copy())
        if terminated or truncated:
            observation, _ = env.reset()
    return observations, users


@pytest.mark.parametrize("env_id", ["mjdrive/Roundabout-D210-v0", "mjdrive/Roundabout-D120-Camera-v0"])
def test_same_seed_same_episode_bit_for_bit(env_id):
    obs_a, users_a = _rollout(env_id, 5)
    obs_b, users_b = _rollout(env_id, 5)
    for x, y in zip(obs_a, obs_b, strict=True):
        for key in x:
            assert np.array_equal(x[key], y[key]), key
    for x, y in zip(users_a, users_b, strict=True):
        assert np.array_equal(x, y)
    _, users_c = _rollout(env_id, 6)
    assert not all(np.array_equal(x, y) for x, y in zip(users_a, users_c, strict=False))


def test_roundabout7_actions():
    env = gym.make("mjdrive/Roundabout-D120-v0", actions="roundabout7")
    assert env.action_space == gym.spaces.Discrete(7)
    env.reset(seed=0)
    env.step(6)  # a6: brake 0.5
    np.testing.assert_allclose(env.unwrapped.task.last_action, [0.0, 0.0, 0.5])


def test_destination_vector_in_the_ego_frame_is_the_world_vector_rotated():
    world = suite.load("roundabout", "d120", {"random": 4})
    ego = suite.load("roundabout", "d120", {"random": 4, "destination_frame": "ego"})
    a, b = world.reset(), ego.reset()
    for _ in range(8):
        a, b = world.step(np.array([0.5, 0.3, 0.0])), ego.step(np.array([0.5, 0.3, 0.0]))
    yaw = ego.task.yaw
    rotation = np.array([[np.cos(yaw), np.sin(yaw)], [-np.sin(yaw), np.cos(yaw)]])
    np.testing.assert_allclose(b.observation["destination"], rotation @ a.observation["destination"], atol=1e-4)
    with pytest.raises(ValueError, match="destination_frame"):
        suite.load("roundabout", "d120", {"destination_frame": "car"})


def test_leaving_the_route_ends_the_episode_unless_disabled():
    """A hard left from the yield line leaves the route (missed exit / island): terminated, flagged, no success;
    with off_route=None the study's rule keeps the episode going."""
    ends = {}
    for off_route in (5.0, None):
        env = suite.load("roundabout", "d120", {"random": 2, "off_route": off_route, "off_route_penalty": 50.0,
                                                "road_users": {"car": 0, "pedestrian": 0}})
        timestep = env.reset()
        offsets = []
        for _ in range(60):
            timestep = env.step(np.array([0.4, 1.0, 0.0]))  # full left lock
            offsets.append(abs(env.task.lane_offset))
            if timestep.last():
                break
        ends[off_route] = (timestep.discount, dict(env.task.info), max(offsets))
        assert env.task.reward_terms["off_route"] == (-50.0 if off_route else 0.0)
    discount, info, max_offset = ends[5.0]
    assert discount == 0.0 and info["off_route"] and not info["success"] and not info["collision"]
    assert 5.0 < max_offset < 7.0  # ended on the first step past 5 m
    discount, info, max_offset = ends[None]
    assert not info["off_route"] and max_offset > 7.0


def test_off_road_ends_the_episode_only_when_asked():
    """Full right lock from the yield line runs over the verge within a few metres: with off_road_ends the
    episode ends there (terminated, not a success); by default (the study) it goes on until off the route."""
    lengths = {}
    for off_road_ends in (True, False):
        env = suite.load("roundabout", "d120", {"random": 2, "off_road_ends": off_road_ends,
                                                "road_users": {"car": 0, "pedestrian": 0}})
        env.reset()
        for _ in range(80):
            timestep = env.step(np.array([0.4, -1.0, 0.0]))  # full right lock
            if timestep.last():
                break
        info = env.task.info
        assert info["off_road"] and timestep.discount == 0.0 and not info["success"]
        lengths[off_road_ends] = (info["steps"], info["off_route"])
    assert lengths[True][0] < lengths[False][0] and not lengths[True][1] and lengths[False][1]


def test_collision_report_locates_the_road_user_hit_and_saves_what_the_agent_saw(tmp_path):
    """tools/collision_report.py on an agent that floors it into the densest roundabout: the car it hits is
    found just ahead, and --frames keeps the agent's last 8 camera frames, oldest left."""
    from PIL import Image

    from tools import collision_report as tool

    class FullThrottle:
        def act(self, obs):
            return np.array([[1.0, 0.0]], np.float32)  # pedal: throttle, steer

    env = gym.make("mjdrive/Roundabout-D210-v0", actions="pedal", observation="camera", exits=[1],
                   camera_ego=True)
    row = tool.describe_collision(FullThrottle(), env, seed=0, frames=tmp_path)
    env.close()
    assert row["kind"] == "car" and row["hit"].startswith("traffic_")
    assert 0.0 < row["ahead_m"] < 6.0 and abs(row["bearing_deg"]) < 90  # in front of the ego
    assert row["ego_speed"] > row["ego_speed_1s"]  # still accelerating into it
    strip = np.asarray(Image.open(tmp_path / "seed_0.png"))
    zoom, side = 3, 84
    assert strip.shape[:2] == (zoom * side, zoom * (tool.FRAMES * side + (tool.FRAMES - 1) * 2))
    first, last = strip[:, :zoom * side], strip[:, -zoom * side:]
    assert np.abs(first.astype(int) - last.astype(int)).mean() > 5  # the view changed as it drove in
