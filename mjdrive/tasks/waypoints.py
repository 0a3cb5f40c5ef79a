"""Waypoint following (study 004, Wedén 2023): drive along a route of waypoints without crossing solid
markings or colliding.

Observations (units as in the study, §3.2.1):
  "features": waypoint_angles (15,) [deg] angles between the ego heading and the next 15 waypoints
              (a queue, padded with the last waypoint), lane_offset d_c [m], heading_error θ [deg], speed v [km/h].
  "camera":   image (128,128,3) uint8 front camera with the next few waypoints drawn as green markers,
              waypoint_distance d [m], heading_error θ [deg], speed v [km/h].
Rewards: (3.1)/(3.2) for "camera", (3.3) for "features"; v in km/h, W=1 when a waypoint is reached (<3 m),
C collision, L solid marking crossed. Episodes end on collision, lane invasion, leaving the road,
reaching the last waypoint, or the time limit (truncation).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np
from dm_control.mujoco import wrapper
from dm_control.utils import containers
from dm_env import specs

from mjdrive import roads, world
from mjdrive.config import param
from mjdrive.roads import Lane, RoadMap
from mjdrive.roads.geometry import wrap_angle
from mjdrive.sensors import RouteTracker
from mjdrive.tasks.base import (
    DrivingConfig,
    DrivingEnvironment,
    DrivingTask,
    Physics,
    configured_task,
    environment_config,
)

SUITE = containers.TaggedTasks()

CONTROL_TIMESTEP = 0.1  # [s] 10 Hz
N_WAYPOINT_ANGLES = 15
REACH_RADIUS = 3.0  # [m] the study's W radius
MIN_RANDOM_ROUTE = 80.0  # [m]


@dataclass(frozen=True)
class WaypointsConfig(DrivingConfig):
    """The waypoints tasks' keywords."""

    buildings: bool = param(False, "line the roads with static boxes")
    waypoint_spacing: float = param(2.0, "distance between waypoints along the route", "m", ge=0.5, le=20.0)
    visible_waypoints: int = param(3, "waypoints drawn as green markers in the camera", ge=0, le=N_WAYPOINT_ANGLES)
    image_size: int = param(128, "side of the square camera image", "px", ge=16, le=1024)
    start_noise: tuple[float, float] = param(
        (0.3, 0.05), "uniform half-ranges of the start's lateral offset [m] and yaw [rad]", "m, rad", ge=0.0, le=2.0)
    speed_limit_reward: bool = param(
        False, "the features reward (3.3) pays -v above the lane's speed limit, as (3.2) does for the camera")


@dataclass(frozen=True)
class RandomRoutesConfig(WaypointsConfig):
    """`random_routes` adds the town's size."""

    town_blocks: tuple[int, int] = param((3, 3), "blocks of the town (columns, rows)", ge=1, le=8)


class WaypointTask(DrivingTask):
    """Follow the waypoints of one of `routes` (lists of lane ids), or of a random route if `routes` is None."""

    def __init__(self, model, road_map: RoadMap, routes: list[list[int]] | None, config: WaypointsConfig):
        super().__init__(model, road_map, config.vehicle, config.random, config.extra_sensors())
        self.config = config
        self.routes = routes
        self.observation = config.observation
        self.waypoint_spacing = config.waypoint_spacing  # [m]
        self.visible_waypoints = config.visible_waypoints
        self.image_size = config.image_size  # [px]
        self.start_noise = config.start_noise  # ([m] lateral, [rad] heading) uniform half-ranges
        self.speed_limit_reward = config.speed_limit_reward
        self.spawn_lanes = None if routes else [lane for lane, _ in roads.spawn_points(road_map)]
        self.tracker: RouteTracker | None = None
        self.route_lane: Lane | None = None

    # --- episode ------------------------------------------------------------------------------------
    def _sample_route(self) -> list[int]:
        if self.routes:
            return self.routes[self.random.randint(len(self.routes))]
        for _ in range(100):
            start, goal = self.random.choice(len(self.spawn_lanes), 2, replace=False)
            try:
                route = self.road_map.shortest_route(self.spawn_lanes[start], self.spawn_lanes[goal])
            except ValueError:
                continue
            if sum(self.road_map.lanes[i].length for i in route) >= MIN_RANDOM_ROUTE:
                return route
        raise RuntimeError(f"could not sample a random route of at least {MIN_RANDOM_ROUTE:.0f} m")

    def initialize_episode(self, physics: Physics) -> None:
        route = self._sample_route()
        points, headings = self.road_map.waypoints(route, self.waypoint_spacing)
        self.route = route
        self.route_lane = Lane(centre=self.road_map.route_polyline(route), name="route")
        self.route_s: float | None = None  # unknown until the first projection over the whole route
        # The car starts wholly on the road, on a waypoint; the route's waypoints are the ones ahead of it.
        start = int(np.ceil((0.5 * self.params.length + 1.0) / self.waypoint_spacing))
        # A small random offset and yaw at the start, so that evaluation episodes differ (set (0, 0) for none).
        lateral = self.random.uniform(-1.0, 1.0) * self.start_noise[0]
        yaw = headings[start] + self.random.uniform(-1.0, 1.0) * self.start_noise[1]
        x = points[start, 0] - lateral * np.sin(headings[start])
        y = points[start, 1] + lateral * np.cos(headings[start])
        self.vehicle.reset(physics.raw_data, x, y, yaw)
        self.tracker = RouteTracker(points[start + 1 :], headings[start + 1 :], REACH_RADIUS)
        self.reset_safety_sensors(physics)
        self.info = {
            "route_completion": 0.0, "waypoints_reached": 0, "waypoints_total": self.tracker.total,
            "collision": False, "lane_invasion": False, "off_road": False, "success": False,
            "physics_error": None, "elapsed_time": 0.0, "distance": 0.0,
        }
        self._step_reward = 0.0
        self._update_lane_frame(physics)

    def _update_lane_frame(self, physics: Physics) -> None:
        x, y, yaw = self.vehicle.pose(physics.raw_data)
        self.xy = np.array([x, y])
        s, d, lane_heading = self.route_lane.frame(self.xy, near_s=self.route_s)
        self.route_s = s  # [m] progress along the route polyline
        self.lane_offset = d  # [m] d_c, > 0 left of the lane centre
        self.heading_error = float(wrap_angle(yaw - lane_heading))  # [rad]
        self.yaw = yaw
        self.speed = float(self.vehicle.speed(physics.raw_data))  # [m/s]

    def after_step(self, physics: Physics) -> None:
        previous_xy = self.xy
        self._update_lane_frame(physics)
        info = self.info
        waypoint_reached = self.tracker.update(self.xy)
        collision = self.collision_sensor.collided(physics.raw_data)
        invasion = self.lane_invasion_sensor(self.ego_corners(physics), self._inside_route_lane())
        # Within its own lane the car is on the road; only a car outside it needs the map-wide query.
        in_lane = abs(self.lane_offset) <= 0.5 * self.route_lane.width
        off_road = not in_lane and not bool(self.road_map.on_road(self.xy))
        info["collision"] |= collision
        info["lane_invasion"] |= invasion
        info["off_road"] |= off_road
        info["waypoints_reached"] = self.tracker.reached
        info["route_completion"] = self.tracker.completion
        info["success"] = self.tracker.done and not (info["collision"] or info["lane_invasion"])
        info["elapsed_time"] = float(physics.data.time)
        info["distance"] += float(np.hypot(*(self.xy - previous_xy)))
        self._step_reward = self._reward(waypoint_reached, collision, invasion)

    def _inside_route_lane(self) -> bool:
        """Whether the whole footprint lies inside the route lane's strip (no marking can be touched)."""
        c, s = abs(np.cos(self.heading_error)), abs(np.sin(self.heading_error))
        half_extent = 0.5 * (self.params.width * c + self.params.length * s)  # [m] lateral
        return abs(self.lane_offset) + half_extent < 0.5 * self.route_lane.width - 0.05

    def _reward(self, waypoint: bool, collision: bool, invasion: bool) -> float:
        v = self.speed * 3.6  # [km/h]
        theta = self.heading_error
        limit = self.road_map.lanes[self.route[0]].speed_limit * 3.6  # [km/h]
        terms = {"waypoint": 100.0 * waypoint, "collision": -200.0 * collision, "lane_invasion": -200.0 * invasion}
        if self.observation == "camera":  # (3.1) below the limit, (3.2) above it
            terms["speed"] = v * np.cos(theta) if v < limit else -v
        else:  # (3.3); with speed_limit_reward, (3.2)'s -v above the limit
            over = self.speed_limit_reward and v >= limit
            terms["speed"] = -v if over else abs(v * np.cos(theta)) - abs(v * np.sin(theta))
            terms["lane_centre"] = -abs(v) * abs(self.lane_offset)
        self.reward_terms = terms
        return sum(terms.values())

    def get_reward(self, physics: Physics) -> float:
        return float(self._step_reward)

    def get_termination(self, physics: Physics) -> float | None:
        info = self.info
        if info["collision"] or info["lane_invasion"] or info["off_road"] or self.tracker.done:
            return 0.0
        return None

    # --- observation --------------------------------------------------------------------------------
    def observation_spec(self, physics: Physics) -> collections.OrderedDict:
        scalar = {name: specs.Array((1,), np.float32, name)
                  for name in ("lane_offset", "heading_error", "speed", "waypoint_distance")}
        if self.observation == "camera":
            size = self.image_size
            spec = collections.OrderedDict(
                image=specs.BoundedArray((size, size, 3), np.uint8, 0, 255, "image"),
                waypoint_distance=scalar["waypoint_distance"],
                heading_error=scalar["heading_error"], speed=scalar["speed"],
            )
        else:
            spec = collections.OrderedDict(
                waypoint_angles=specs.Array((N_WAYPOINT_ANGLES,), np.float32, "waypoint_angles"),
                lane_offset=scalar["lane_offset"], heading_error=scalar["heading_error"], speed=scalar["speed"],
            )
        spec.update(self.sensor_spec(physics))
        return spec

    def get_observation(self, physics: Physics) -> collections.OrderedDict:
        theta = np.float32(np.degrees(self.heading_error))
        speed = np.float32(self.speed * 3.6)
        obs = collections.OrderedDict()
        if self.observation == "camera":
            k = self.tracker.next_index
            markers = self.tracker.points[k : k + self.visible_waypoints]  # only the next few, as §5 wished
            size = self.image_size
            obs["image"] = self.render_camera(physics, "ego/front", size, size, markers).copy()
            nearest = self.tracker.upcoming(1)[0] - self.xy
            obs["waypoint_distance"] = np.array([np.hypot(*nearest)], np.float32)
        else:
            delta = self.tracker.upcoming(N_WAYPOINT_ANGLES) - self.xy
            angles = wrap_angle(np.arctan2(delta[:, 1], delta[:, 0]) - self.yaw)
            obs["waypoint_angles"] = np.degrees(angles).astype(np.float32)
            obs["lane_offset"] = np.array([self.lane_offset], np.float32)
        obs["heading_error"] = np.array([theta], np.float32)
        obs["speed"] = np.array([speed], np.float32)
        obs.update(self.sensor_observation(physics))
        return obs


# --- registered tasks -----------------------------------------------------------------------------------

_CRAFTED = None


def _crafted():
    """The crafted-routes map and its routes (built once per process; maps are immutable data)."""
    global _CRAFTED
    if _CRAFTED is None:
        _CRAFTED = roads.crafted_routes()
    return _CRAFTED


def _make(road_map, routes, config: WaypointsConfig, environment_kwargs, where: str) -> DrivingEnvironment:
    env_kwargs = environment_config(environment_kwargs, config.physics_dt, CONTROL_TIMESTEP, where)
    seed = config.random if isinstance(config.random, int) else 0
    model = world.build(road_map, vehicle=config.vehicle, buildings=config.buildings, seed=seed,
                        timestep=config.physics_dt)
    physics = Physics.from_model(wrapper.MjModel(model))
    task = WaypointTask(model, road_map, routes, config)
    return DrivingEnvironment(physics, task, time_limit=config.time_limit, **env_kwargs)


@SUITE.add("study004", "crafted", "evaluation")
@configured_task(WaypointsConfig, time_limit=20.0)
def straight(config: WaypointsConfig, environment_kwargs=None) -> DrivingEnvironment:
    """The study's evaluation route: a straight lane of ~100 m, 20 s limit."""
    road_map, routes = _crafted()
    return _make(road_map, [routes["straight"]], config, environment_kwargs, "waypoints/straight")


@SUITE.add("study004", "crafted")
@configured_task(WaypointsConfig, time_limit=30.0)
def four_routes(config: WaypointsConfig, environment_kwargs=None) -> DrivingEnvironment:
    """The four crafted routes (sharp left in a junction, straight, soft right, soft left), one per episode."""
    road_map, routes = _crafted()
    chosen = [routes[name] for name in ("left_turn", "straight", "soft_right", "soft_left")]
    return _make(road_map, chosen, config, environment_kwargs, "waypoints/four_routes")


@SUITE.add("study004", "random")
@configured_task(RandomRoutesConfig, time_limit=120.0)
def random_routes(config: RandomRoutesConfig, environment_kwargs=None) -> DrivingEnvironment:
    """Random start and destination in a small town of junctions (a new route every episode), 120 s limit.

    Routes are 120-570 m long; the longest takes 68 s at the town's 30 km/h limit, so the limit leaves room to
    slow for the junction turns (a limit of 60 s cut about a quarter of the routes short at 80% of the limit).
    """
    road_map = roads.town(blocks=config.town_blocks)
    return _make(road_map, None, config, environment_kwargs, "waypoints/random_routes")
