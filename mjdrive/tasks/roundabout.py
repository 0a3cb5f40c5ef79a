"""Roundabout entry in dense mixed traffic (study 000, Ben Elallid et al. 2024): from the yield line of
one approach, enter a two-lane roundabout and leave it at a chosen exit without colliding.

Map: `roads.roundabout` (two-lane ring of `radius` 14 m driven counter-clockwise, four two-way arms,
a crosswalk on every arm `crosswalk_offset` 6 m from the ring). The ego starts at rest at the yield line of
a random approach; its destination is `destination_offset` 10 m into a random exit (first, second or
third after its entry: right turn, straight on, left turn; paths of about 38, 62 and 87 m, mean ~62 m;
`exits=(1,)` keeps the study's short ~32-38 m paths). Traffic (`mjdrive.traffic`) runs around it.

Density levels, named after the study's 120/140/160/210 vehicles in the whole CARLA town (Table 3); here
the road users around the roundabout (each slot is a MuJoCo mocap box):

| task | cars | motorcycles | bicycles | pedestrians | road users |
| --- | ---: | ---: | ---: | ---: | ---: |
| d120 | 12 | 3 | 3 | 4 | 22 |
| d140 | 14 | 3 | 3 | 5 | 25 |
| d160 | 17 | 4 | 4 | 6 | 31 |
| d210 | 22 | 5 | 5 | 8 | 40 |

Observations (`observation=`):
  "camera":   image (4, 84, 84) uint8, the last 4 front-camera frames in gray (oldest first, §4.2), and
              destination (2,) [m] = [x_dest - x_av, y_dest - y_av] (world frame, as in the study).
  "features": ego (6,) = speed [m/s], yaw rate [rad/s], heading error to the route [rad], lateral offset
              from the route [m], cos(yaw), sin(yaw); destination (2,) [m] as above; road_users (K, 13) for
              the K nearest road users: present, dx, dy, dvx, dvy [m, m/s] in the ego frame, cos and sin of
              the relative yaw, length, width [m], one-hot kind (car, motorcycle, bicycle, pedestrian).
Reward, eq. (12): -100 on collision; d_pre - d_cu (remaining route distance [m] to the destination, one
step to the next); v/10 with v in km/h clipped to [0, 30] (at most 3); -0.05 x off-road share of the
footprint; -0.05 x share of the footprint in another lane than the route; +100 on arrival.
`task.reward_terms` holds the terms of the last step. Episodes end on collision or arrival (terminated)
or after 1100 steps (truncated). Control at 5 Hz (§5.1). `info` names the entry and exit arms ("entry",
"exit": absolute arm indices) and the exit counted from the entry ("exit_number", 1: the first exit).

Leaving the route (`off_route` 5 m from its centre line: a missed exit, a drive across the island) also
ends the episode (terminated, `info["off_route"]`, not a success). The study lists only collision, arrival
and 1100 steps, but under eq. 12 alone circling the ring pays: v/10 earns up to 3 per step, so over 1100
steps a missed exit outscores arriving (+100) many times over. Pass `off_route=None` for the study's rule.
`off_route_penalty` (default 0, the study's eq. 12) is subtracted on that step (term "off_route");
`collision_penalty` (default 100, eq. 12) is what a collision costs (a larger one trades speed for caution);
`destination_frame="ego"` gives the destination vector in the car's frame (x ahead, y left) instead of
the study's world frame. `camera_ego=True` adds the features' ego vector to the "camera" observation (the
study's camera agent sees only frames and the destination). Leaving the road costs only 0.05 per step
under eq. 12, and a learner may find that a shortcut across the verge (CARLA's kerbs and street furniture
would stop it): `off_road_ends=True` ends the episode (terminated, not a success) once the whole footprint
is off the road. `camera="front_wide"` renders the "camera" observation from the same eye with a 120 deg
field of view instead of the front camera's 90 deg (a road user stopping just ahead of a front corner stays
in the image; not in the study).
"""

from __future__ import annotations

import collections
import functools
import math
from dataclasses import dataclass

import numpy as np
from dm_control.mujoco import wrapper
from dm_control.utils import containers
from dm_env import specs

from mjdrive import roads, world
from mjdrive.config import ConfigError, param
from mjdrive.roads import Lane, RoadMap
from mjdrive.roads.route_frame import RouteFrame
from mjdrive.tasks import kernels
from mjdrive.tasks.base import (
    DrivingConfig,
    DrivingEnvironment,
    DrivingTask,
    Physics,
    configured_task,
    environment_config,
)
from mjdrive.traffic import KIND_NAMES, EgoState, Traffic, TrafficConfig, counts_to_kinds, slots

SUITE = containers.TaggedTasks()

CONTROL_TIMESTEP = 0.2  # [s] 5 Hz (§5.1)
MAX_STEPS = 1100  # (§5.1)
SPEED_LIMIT_KMH = 30.0  # [km/h] the study's limit: v/10 is at most 3
MAX_ARMS = 8
MAX_ROAD_USERS = 200
ROAD_USER_COLUMNS = 9 + len(KIND_NAMES)
DENSITIES: dict[str, dict[str, int]] = {
    "d120": {"car": 12, "motorcycle": 3, "bicycle": 3, "pedestrian": 4},
    "d140": {"car": 14, "motorcycle": 3, "bicycle": 3, "pedestrian": 5},
    "d160": {"car": 17, "motorcycle": 4, "bicycle": 4, "pedestrian": 6},
    "d210": {"car": 22, "motorcycle": 5, "bicycle": 5, "pedestrian": 8},
}


@dataclass(frozen=True)
class RoundaboutConfig(DrivingConfig):
    """The roundabout tasks' keywords: the episode, the observation, eq. 12's terms, traffic and the map."""

    time_limit: float = param(MAX_STEPS * CONTROL_TIMESTEP, "episode length, then truncation (1100 steps)", "s",
                              gt=0.0, le=3600.0)
    exits: tuple[int, ...] = param((1, 2, 3), "exits drawn from, counted after the entry (1: first exit)",
                                   ge=1, le=MAX_ARMS)
    entries: tuple[int, ...] | None = param(None, "arms the ego may start from (arm index); None: every arm",
                                            ge=0, le=MAX_ARMS - 1)
    destination_offset: float = param(10.0, "destination this far into the exit arm", "m", ge=1.0, le=400.0)
    start_offset: float = param(0.5, "ego's centre to the end of its approach lane at the start", "m",
                                ge=0.0, le=20.0)
    warmup: float = param(5.0, "traffic simulated before the episode starts", "s", ge=0.0, le=120.0)
    neighbours: int = param(8, "K, road users in the features observation", ge=1, le=64)
    image_size: int = param(84, "side of the square camera frames", "px", ge=16, le=512)
    frames: int = param(4, "stacked camera frames", ge=1, le=16)
    speed_reward: bool = param(True, "eq. 12's R_t3 speed term")
    collision_penalty: float = param(100.0, "subtracted on a collision (eq. 12's 100)", ge=0.0, le=1e6)
    off_route: float | None = param(5.0, "distance from the route's centre line that ends the episode; "
                                    "None: never (the study)", "m", gt=0.0, le=100.0)
    off_route_penalty: float = param(0.0, "subtracted when the episode ends off the route", ge=0.0, le=1e6)
    destination_frame: str = param("world", "frame of the destination vector (world: the study)",
                                   choices=("world", "ego"))
    camera_ego: bool = param(False, "camera observation also carries the features' ego vector")
    off_road_ends: bool = param(False, "end the episode once the whole footprint is off the road")
    camera: str = param("front", "ego camera of the camera observation (90 or 120 deg)",
                        choices=("front", "front_wide"))
    road_users: dict[str, int] | None = param(None, "road users by kind, overriding the level's counts",
                                              ge=0, le=100, keys=KIND_NAMES)
    traffic_config: TrafficConfig = param(TrafficConfig(), "traffic behaviour constants (a dict of its keywords)")
    radius: float = param(14.0, "radius of the ring's middle", "m", ge=6.0, le=100.0)
    lanes: int = param(2, "ring lanes", ge=1, le=4)
    arms: int = param(4, "two-way arms", ge=3, le=MAX_ARMS)
    arm_length: float = param(50.0, "length of each arm", "m", ge=20.0, le=500.0)
    lane_width: float = param(3.5, "lane width", "m", ge=2.5, le=5.0)
    crosswalk_offset: float = param(6.0, "crosswalk this far past the arm's start", "m", ge=1.0, le=400.0)

    def check(self) -> None:
        if any(e > self.arms for e in self.exits):
            raise ConfigError(f"exits={self.exits}: must be in 1..{self.arms} (arms={self.arms})")
        if self.entries is not None and any(e >= self.arms for e in self.entries):
            raise ConfigError(f"entries={self.entries}: arms are numbered 0..{self.arms - 1} (arms={self.arms})")
        if self.radius - self.lanes * self.lane_width / 2 < 3.0:
            raise ConfigError(f"radius={self.radius:g} with lanes={self.lanes} of lane_width={self.lane_width:g} m "
                              "leaves an island under 3 m: raise radius or lower lanes/lane_width")
        for name in ("destination_offset", "crosswalk_offset"):
            if getattr(self, name) >= self.arm_length - 2.0:
                raise ConfigError(f"{name}={getattr(self, name):g} m must lie inside the arm "
                                  f"(< arm_length - 2 = {self.arm_length - 2:g} m)")
        if sum((self.road_users or {}).values()) > MAX_ROAD_USERS:
            raise ConfigError(f"road_users={self.road_users}: at most {MAX_ROAD_USERS} in all")


class RoundaboutTask(DrivingTask):
    """Enter the roundabout from a yield line and reach the destination on a chosen exit (eq. 12 reward)."""

    def __init__(self, model, road_map: RoadMap, kinds: list[str], config: RoundaboutConfig):
        super().__init__(model, road_map, config.vehicle, config.random, config.extra_sensors())
        self.config = config
        self.observation = config.observation
        self.routes = roads.roundabout_routes(road_map)
        self.arms = sorted({a for a, _ in self.routes})
        self.exits = config.exits
        self.entries = tuple(self.arms if config.entries is None else config.entries)
        self.destination_offset = config.destination_offset  # [m]
        self.start_offset = config.start_offset  # [m]
        self.warmup = config.warmup  # [s]
        self.neighbours = config.neighbours
        self.image_size = config.image_size  # [px]
        self.frames = config.frames
        self.speed_reward = config.speed_reward
        self.collision_penalty = config.collision_penalty
        self.off_route = config.off_route  # [m]
        self.off_route_penalty = config.off_route_penalty
        self.destination_frame = config.destination_frame
        self.camera_ego = config.camera_ego
        self.off_road_ends = config.off_road_ends
        self.camera = f"ego/{config.camera}"
        if self.camera not in [model.camera(i).name for i in range(model.ncam)]:
            raise ConfigError(f"camera={config.camera!r}: the ego car has no such camera")
        self.traffic = Traffic(road_map, kinds, config.traffic_config)
        self.traffic.bind(model)
        self._kind_onehot = np.eye(len(KIND_NAMES), dtype=np.float32)[self.traffic.kind_id]
        self._lengths = 2 * self.traffic.half_size[:, :2]
        self.route: list[int] = []
        self.route_lane: Lane | None = None
        self._corner_buffers = (np.empty((4, 2)), np.empty(4))  # `roundabout_ego`'s corners [m] and their offsets [m]

    # --- episode ----------------------------------------------------------------------------------
    def initialize_episode(self, physics: Physics) -> None:
        rm = self.road_map
        entry = self.entries[self.random.randint(len(self.entries))]
        exit_number = self.exits[self.random.randint(len(self.exits))]  # counted from the entry (1: the first)
        exit_arm = (entry + exit_number) % len(self.arms)
        self.entry_arm, self.exit_arm = entry, exit_arm
        self.route = list(self.routes[(entry, exit_arm)])
        self.route_lane = Lane(rm.route_polyline(self.route), name="route")
        self.route_frame = RouteFrame(self.route_lane)
        lengths = np.array([rm.lanes[i].length for i in self.route])
        self._route_starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])  # [m] along the route
        self._route_width = rm.lanes[self.route[0]].width
        start_s = lengths[0] - self.start_offset
        self.destination_s = float(self._route_starts[-1] + self.destination_offset)  # [m] along the route
        self.destination = self.route_lane.position(self.destination_s)
        x, y = self.route_lane.position(start_s)
        self.vehicle.reset(physics.raw_data, x, y, float(self.route_lane.heading(start_s)))
        self.route_frame(np.array([[x, y]]), full=True)
        self._frame_time = -1.0
        self._ego_fn = functools.partial(self.ego_state, physics)
        rng = np.random.default_rng(self.random.randint(2**31))
        self.traffic.reset(rng, self.ego_state(physics), warmup=self.warmup)
        self.traffic.write(physics.raw_data)
        self.reset_safety_sensors(physics)
        self._update_ego(physics)
        self.remaining = self._remaining()
        self._frames: collections.deque | None = None
        self.info = {
            "success": False, "collision": False, "off_road": False, "off_route": False, "physics_error": None,
            "elapsed_time": 0.0, "average_speed": 0.0, "distance": 0.0, "steps": 0, "episode_reward": 0.0,
            "remaining_distance": self.remaining, "route_length": self.destination_s - start_s,
            "entry": entry, "exit": exit_arm, "exit_number": exit_number,
        }
        self._step_reward = 0.0
        self.reward_terms = {}

    def substep_period(self) -> float:
        """[s] between substeps: the traffic's pose period (mocap poses written and contacts sampled)."""
        return self.traffic.config.substep

    def substep_traffic(self) -> Traffic:
        return self.traffic

    def substep(self, physics: Physics, dt: float) -> None:
        """The substep callback (`tasks.stepping`): sample the ego's contacts, then move the traffic (mocap poses)."""
        data = physics.raw_data
        self.collision_sensor.sample(data)  # DrivingTask.substep
        self.traffic.advance(dt, self._ego_fn, data)

    def ego_state(self, physics: Physics) -> EgoState:
        """The ego for traffic (and the scripted drivers): pose, speed, and its place on the route."""
        x, y, yaw = self.vehicle.pose(physics.raw_data)
        speed = self.vehicle.speed(physics.raw_data)
        if self._frame_time >= 0.0:  # the route coordinates of the last control step (a few cm old at most)
            s, d = self.route_s, self.lane_offset
        else:
            s, d = self.route_frame(np.array([[x, y]]))
            s, d = float(s[0]), float(d[0])
        path, s_lane = None, 0.0
        if abs(d) <= self._route_width:
            k = int(np.searchsorted(self._route_starts, s, side="right") - 1)
            path = np.array(self.route[k:], dtype=np.int64)
            s_lane = float(s - self._route_starts[k])
        return EgoState(x, y, yaw, speed, self.params.length, self.params.width, path, s_lane)

    def _update_ego(self, physics: Physics) -> None:
        """The ego's chassis state, footprint, route coordinates (its centre's and its corners') and heading error (in
        one compiled pass)."""
        data, frame = physics.raw_data, self.route_frame
        lo, hi = frame.window()
        qa, va = self.vehicle.state_addresses
        self.corners, self.corner_offsets = self._corner_buffers  # filled in place: read within this step only
        (x, y, yaw, self.speed, self._left, self.yaw_rate, c, s, self.route_s, self.lane_offset, frame.segment,
         self.heading_error) = kernels.roundabout_ego(
            data.qpos, data.qvel, qa, va, self.params.length, self.params.width, frame.segments, lo, hi, self.corners,
            self.corner_offsets)
        self._chassis = yaw, self.speed, self._left  # `read_chassis`' hand-over to the comfort sample
        self.xy, self.yaw, self._yaw_cos_sin = np.array([x, y]), yaw, (c, s)
        self._frame_time = data.time

    def _remaining(self) -> float:
        """Route distance [m] from the ego to the destination."""
        return max(self.destination_s - self.route_s, 0.0)

    def after_step(self, physics: Physics) -> None:
        previous_xy = self.xy
        self._update_ego(physics)
        info = self.info
        collision = self.collision_sensor.collided(physics.raw_data)
        half_width = self._route_width / 2
        if all(abs(d) <= half_width for d in self.corner_offsets.tolist()):  # on the route's lanes: on the road
            off_share = other_share = 0.0
        else:
            in_route = np.abs(self.corner_offsets) <= half_width
            on_road = self.road_map.on_road(self.corners)
            off_share = 1.0 - np.count_nonzero(on_road) / 4.0
            other_share = np.count_nonzero(on_road & ~in_route) / 4.0
        remaining = self._remaining()
        arrived = self.route_s >= self.destination_s - 0.5 and abs(self.lane_offset) <= self._route_width / 2
        info["collision"] |= collision
        info["off_road"] |= off_share == 1.0
        info["off_route"] |= self.off_route is not None and abs(self.lane_offset) > self.off_route
        info["success"] = bool(arrived and not info["collision"])
        info["steps"] += 1
        info["elapsed_time"] = float(physics.raw_data.time)
        info["distance"] += math.hypot(self.xy[0] - previous_xy[0], self.xy[1] - previous_xy[1])
        info["average_speed"] = info["distance"] / max(info["elapsed_time"], 1e-9)
        info["remaining_distance"] = remaining
        v_kmh = min(max(self.speed * 3.6, 0.0), SPEED_LIMIT_KMH)
        terms = {
            "collision": -self.collision_penalty * collision,
            "progress": self.remaining - remaining,
            "speed": v_kmh / 10.0 if self.speed_reward else 0.0,
            "off_road": -0.05 * off_share,
            "other_lane": -0.05 * other_share,
            "arrival": 100.0 * info["success"],
            "off_route": -self.off_route_penalty * info["off_route"],
        }
        self.remaining = remaining
        self.reward_terms = terms
        self._step_reward = float(sum(terms.values()))
        info["episode_reward"] += self._step_reward

    def get_reward(self, physics: Physics) -> float:
        return self._step_reward

    def get_termination(self, physics: Physics) -> float | None:
        info = self.info
        if info["collision"] or info["success"] or info["off_route"] or (self.off_road_ends and info["off_road"]):
            return 0.0
        return None

    # --- observation ---------------------------------------------------------------------------------
    def observation_spec(self, physics: Physics) -> collections.OrderedDict:
        destination = specs.Array((2,), np.float32, "destination")
        if self.observation == "camera":
            size = self.image_size
            spec = collections.OrderedDict(
                image=specs.BoundedArray((self.frames, size, size), np.uint8, 0, 255, "image"),
                destination=destination,
            )
            if self.camera_ego:
                spec["ego"] = specs.Array((6,), np.float32, "ego")
        else:
            spec = collections.OrderedDict(
                ego=specs.Array((6,), np.float32, "ego"),
                destination=destination,
                road_users=specs.Array((self.neighbours, ROAD_USER_COLUMNS), np.float32, "road_users"),
            )
        spec.update(self.sensor_spec(physics))
        return spec

    def destination_vector(self, frame: str | None = None) -> np.ndarray:
        """(2,) [m] from the ego to its destination: world axes, or the car's ("ego": x ahead, y to the left).
        `frame=None`: the task's `destination_frame`."""
        destination = (self.destination - self.xy).astype(np.float32)
        if (frame or self.destination_frame) == "ego":
            c, s = self._yaw_cos_sin
            destination = np.array([c * destination[0] + s * destination[1],
                                    -s * destination[0] + c * destination[1]], np.float32)
        return destination

    def features_observation(self, physics: Physics, destination_frame: str | None = None) -> collections.OrderedDict:
        """The "features" observation of the current state whatever `observation` is (a privileged teacher's
        input while a camera policy drives)."""
        return collections.OrderedDict(ego=self._ego_vector(), destination=self.destination_vector(destination_frame),
                                       road_users=self._nearest_road_users(physics))

    def get_observation(self, physics: Physics) -> collections.OrderedDict:
        if self.observation == "camera":
            obs = collections.OrderedDict()
            destination = self.destination_vector()
            size = self.image_size
            rgb = self.render_camera(physics, self.camera, size, size)
            gray = (rgb @ np.array([0.299, 0.587, 0.114])).astype(np.uint8)
            if self._frames is None:
                self._frames = collections.deque([gray] * self.frames, maxlen=self.frames)
            else:
                self._frames.append(gray)
            obs["image"] = np.stack(self._frames)
            obs["destination"] = destination
            if self.camera_ego:
                obs["ego"] = self._ego_vector()
        else:
            obs = self.features_observation(physics)
        obs.update(self.sensor_observation(physics))
        return obs

    def _ego_vector(self) -> np.ndarray:
        """(6,) speed [m/s], yaw rate [rad/s], heading error [rad], lateral offset [m], cos/sin(yaw)."""
        c, s = self._yaw_cos_sin
        return np.array([self.speed, self.yaw_rate, self.heading_error, self.lane_offset, c, s], np.float32)

    def _nearest_road_users(self, physics: Physics) -> np.ndarray:
        """(K, ROAD_USER_COLUMNS) the K nearest present road users in the ego frame, zero-padded."""
        traffic = self.traffic
        out = np.zeros((self.neighbours, ROAD_USER_COLUMNS), np.float32)
        present = np.flatnonzero(traffic.present)
        if not len(present) or not self.neighbours:
            return out
        c, s = self._yaw_cos_sin
        vx, vy = self.speed, self._left  # `Vehicle.velocity_body`'s numbers, read with the pose
        kernels.road_user_rows(out, traffic.positions(), present, float(self.xy[0]), float(self.xy[1]), float(c),
                               float(s), vx, vy, traffic.speeds(), traffic.yaws(), float(self.yaw), self._lengths,
                               self._kind_onehot)
        return out


# --- registered tasks -----------------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def _road_map(radius: float, lanes: int, arms: int, arm_length: float, lane_width: float,
              crosswalk_offset: float) -> RoadMap:
    """The roundabout map (built once per parameter set; maps are immutable data)."""
    try:
        return roads.roundabout(radius=radius, lanes=lanes, arms=arms, arm_length=arm_length,
                                lane_width=lane_width, crosswalk_offset=crosswalk_offset)
    except ValueError as error:  # a combination of map parameters the geometry cannot hold
        raise ConfigError(f"map radius={radius:g} lanes={lanes} arms={arms} arm_length={arm_length:g} "
                          f"lane_width={lane_width:g}: {error}") from None


def _make(level: str, config: RoundaboutConfig, environment_kwargs) -> DrivingEnvironment:
    where = f"roundabout/{level}"
    env_kwargs = environment_config(environment_kwargs, config.physics_dt, CONTROL_TIMESTEP, where)
    road_map = _road_map(config.radius, config.lanes, config.arms, config.arm_length, config.lane_width,
                         config.crosswalk_offset)
    kinds = counts_to_kinds(DENSITIES[level] if config.road_users is None else config.road_users)
    model = world.build(road_map, vehicle=config.vehicle, traffic=slots(kinds), timestep=config.physics_dt)
    physics = Physics.from_model(wrapper.MjModel(model))
    task = RoundaboutTask(model, road_map, kinds, config)
    return DrivingEnvironment(physics, task, time_limit=config.time_limit, **env_kwargs)


def _register(level: str):
    counts = DENSITIES[level]

    def build(config: RoundaboutConfig, environment_kwargs=None) -> DrivingEnvironment:
        return _make(level, config, environment_kwargs)

    build.__name__ = level
    build.__doc__ = (f"Roundabout entry with the study's {level[1:]}-vehicle density: "
                     + ", ".join(f"{n} {k}s" for k, n in counts.items()) + ".")
    return SUITE.add("study000", "density")(configured_task(RoundaboutConfig)(build))


d120 = _register("d120")
d140 = _register("d140")
d160 = _register("d160")
d210 = _register("d210")
