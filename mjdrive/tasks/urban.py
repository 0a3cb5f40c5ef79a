"""Urban driving (study 002, §5.1): the scenarios of the concatenated route in traffic with intentions.

Tasks: `urban/roundabout`, `urban/lane_change`, `urban/crossroad`, `urban/merge` (each scenario's map alone;
the ego starts `start_before` m before the scenario) and `urban/concatenated` (the whole route of Fig. 8:
roundabout, two-lane road, crossroad, merge). Maps: `roads.concatenated`; traffic: `traffic.urban` (urban
rules, intentions, maximum speeds 5-15 m/s).

Control at 10 Hz (throttle, steer, brake), fine enough for the comfort metrics (§5.2).
Observations (`observation=`):
  "features": ego (4,) in [0, 1]: speed / 15 m/s, (heading error + pi) / 2 pi, (lateral offset / off_route
              + 1) / 2, route progress; scenario (5,): one-hot of follow, roundabout, lane_change, crossroad,
              merge (the tactical trajectory at the ego's place, §4.1); adversaries (n, 4) in [0, 1], the
              paper's matrix (§5.1.2): present, distance to the relevant point / 60 m (the conflict point
              ahead on the route in the active scenario; the ego itself on the two-lane road and outside
              every scenario), speed / 15 m/s, intention / 2 (the active scenario's), nearest first.
  "camera":   image (84, 84, 3) uint8 from the front camera, and ego as above.
Reward (§5.1.4): 1e-3 x speed [m/s] every step, +1 on arriving at the end of the route, -2 on a collision.
Episodes end (terminated) on a collision, on arrival, or more than `off_route` m from the centre line of the route's
lane and of its same-direction neighbour (an overtaking car is on the road);
they are truncated at the time limit. `info`: success, collision, off_route, scenario, elapsed_time [s],
average_speed [m/s], distance [m], steps, episode_reward, route_length [m], and at the end the comfort
metrics (`mjdrive.comfort`, sampled at the control rate by the DrivingEnvironment, as on every task).
"""

from __future__ import annotations

import collections
import dataclasses
import functools
from dataclasses import dataclass

import numpy as np
from dm_control.mujoco import wrapper
from dm_control.utils import containers
from dm_env import specs

from mjdrive import world
from mjdrive.assets import MAPS_DIR
from mjdrive.config import ConfigError, action_index, param
from mjdrive.control.operative import OperativeConfig, OperativeLevel
from mjdrive.control.speed_profile import route_speed_profile
from mjdrive.roads import Lane
from mjdrive.roads.conflicts import MERGE
from mjdrive.roads.opendrive import longest_route, read_opendrive, route_between
from mjdrive.roads.ports import ComposedMap
from mjdrive.roads.route_frame import RouteFrame
from mjdrive.roads.urban import FOLLOW, UrbanRoute, concatenated, route_offsets, route_on, route_through
from mjdrive.roads.urban_params import UrbanMap
from mjdrive.tasks import kernels
from mjdrive.tasks.base import (
    DrivingConfig,
    DrivingEnvironment,
    DrivingTask,
    Physics,
    RoadUsers,
    configured_task,
    environment_config,
)
from mjdrive.tasks.decisions import ACTIONS, RouteTraffic
from mjdrive.tasks.junction_watch import FEATURES as JUNCTION_FEATURES
from mjdrive.tasks.junction_watch import JunctionWatch
from mjdrive.traffic import KIND_NAMES, EgoState, Traffic, TrafficConfig, counts_to_kinds, slots
from mjdrive.traffic.intentions import SCENARIOS as INTENTION_SCENARIOS
from mjdrive.traffic.junction_control import CONTROLS, KEYWORDS, STATE_NAMES, SignalTiming
from mjdrive.traffic.urban import URBAN_CONFIG, default_counts, urban_traffic

SUITE = containers.TaggedTasks()

CONTROL_TIMESTEP = 0.1  # [s] 10 Hz
SCENARIOS = (FOLLOW, "roundabout", "lane_change", "crossroad", "merge")  # the scenario one-hot, in order
_SCENARIO_ONE_HOT = {name: np.eye(len(SCENARIOS), dtype=np.float32)[i] for i, name in enumerate(SCENARIOS)}
_NO_INTENTIONS = np.zeros((0, len(INTENTION_SCENARIOS)), np.int64)  # the adversary rows' outside intention scenarios
_SCENARIO_CODE = {name: i for i, name in enumerate(SCENARIOS)}
_INTENTION_COLUMN = {name: i for i, name in enumerate(INTENTION_SCENARIOS)}  # the intentions' column by scenario
PIECES = {"roundabout": ("roundabout",), "lane_change": ("road",), "crossroad": ("crossroad",),
          "merge": ("merge",), "concatenated": ("roundabout", "road", "crossroad", "merge")}
SPEED_SCALE = 15.0  # [m/s] speeds normalised by this (§5.3's top speed)
DISTANCE_SCALE = 60.0  # [m] adversary distances normalised by this (farther ones: 1)
SPEED_REWARD = 1e-3  # k_v per m/s (§5.1.4)
ARRIVAL_REWARD = 1.0
COLLISION_REWARD = -2.0
ARRIVAL_MARGIN = 5.0  # [m] before the route's end counts as arrived
ADVERSARY_COLUMNS = 4  # present, distance, speed, intention


@dataclass(frozen=True)
class UrbanConfig(DrivingConfig):
    """The urban tasks' keywords."""

    time_limit: float = param(60.0, "episode length, then truncation", "s", gt=0.0, le=3600.0)
    adversaries: int = param(6, "n, adversaries in the features observation", ge=1, le=32)
    start_before: float = param(25.0, "the ego starts this far before its scenario (scenario tasks)", "m",
                                ge=5.0, le=200.0)
    warmup: float = param(10.0, "traffic simulated before the episode starts", "s", ge=0.0, le=120.0)
    off_route: float = param(4.0, "distance from the centre line of the route's lane (or of its same-direction "
                             "neighbour) that ends the episode", "m",
                             gt=0.0, le=20.0)
    map: UrbanMap | None = param(None, "the map: the pieces' order and parameters ({order: [...], roundabout: "
                                 "{...}, road: {...}, crossroad: {...}, merge: {...}}), or the path of a YAML or "
                                 "JSON file of them; None: the task's pieces at their defaults")
    opendrive: str | None = param(None, "urban/opendrive: the OpenDRIVE file (.xodr) to drive, or a shipped map's "
                                  "name (four_way, four_way_lights, multilane, roundabout) (the `opendrive` extra)")
    route_points: tuple[float, float, float, float] | None = param(
        None, "urban/opendrive: the route's start x, y and goal x, y (the nearest lanes; None: the longest route)",
        "m")
    road_users: dict[str, int] | None = param(None, "road users by kind, overriding the map's default",
                                              ge=0, le=100, keys=tuple(k for k in KIND_NAMES if k != "pedestrian"))
    traffic_config: TrafficConfig = param(URBAN_CONFIG, "traffic behaviour constants (a dict of its keywords)")
    piece_traffic: str = param("own", "on a chain of pieces: each piece keeps its own traffic (vehicles leave the map "
                               "where their lane passes into the next piece, as study 002 spawns and destroys "
                               "vehicles at the scenarios' critical points), or `through`: they drive on",
                               choices=("own", "through"))
    entry_traffic: bool = param(True, "traffic also enters on the route's first lane, ahead of the ego (false: the "
                                "ego meets its scenario alone, as on a chain whose previous piece keeps its traffic)")
    image_size: int = param(84, "side of the square camera image", "px", ge=16, le=512)
    decisions: bool = param(False, "study 002's decision actions (drive / stop, keep / left / right) instead of "
                            "throttle, steer, brake: one env step per decision period, the operative level "
                            "(LQR + MPC) driving underneath")
    decision_period: float = param(0.5, "env step with `decisions` (a multiple of the 0.1 s control period)", "s",
                                   ge=0.1, le=5.0)
    steering_latency: float = param(0.0, "with `decisions`: the car applies each steering command this much "
                                    "later (a multiple of the control period; the LQR compensates it)", "s",
                                    ge=0.0, le=1.0)
    operative: OperativeConfig = param(OperativeConfig(), "with `decisions`: the operative level's parameters "
                                       "(a dict of its keywords)")
    junction_control: str = param("give_way", "the junctions' control: give-way lines, stop signs on the minor road, "
                                  "traffic lights, the map's own signs and lights (an OpenDRIVE file's signals; give "
                                  "way where it has none), or one of the first three drawn per episode (then the "
                                  "observation gains `junction`)", choices=(*KEYWORDS, "random"))
    signals: SignalTiming = param(SignalTiming(), "the traffic lights' cycle (a dict of its keywords)")
    collision_reward: float = param(COLLISION_REWARD, "reward of a collision, and of running a red light or a stop "
                                    "sign (study 002 §5.1.4: -2)", ge=-100.0, le=0.0)

    def check(self) -> None:
        if self.road_users is not None and sum(self.road_users.values()) > 100:
            raise ConfigError(f"road_users={self.road_users}: at most 100 in all")
        for name in ("decision_period", "steering_latency"):
            periods = getattr(self, name) / CONTROL_TIMESTEP
            if abs(periods - round(periods)) > 1e-6:
                raise ConfigError(f"{name}={getattr(self, name):g} s must be a multiple of the control period "
                                  f"{CONTROL_TIMESTEP:g} s")


class UrbanTask(DrivingTask):
    """Drive the route (or one scenario of it) to its end in traffic (§5.1 reward)."""

    def __init__(self, model, route: UrbanRoute, kinds: list[str], scenario: str, config: UrbanConfig):
        super().__init__(model, route.road_map, config.vehicle, config.random, config.extra_sensors())
        self.config = config
        self.observation = config.observation
        self.urban = route
        self.name = scenario  # the task: a scenario or "concatenated"
        self.scenario = scenario
        self.route = list(route.route)  # lane ids (scripted drivers read them)
        self.traffic = urban_traffic(route.composed, counts=collections.Counter(kinds),
                                     config=config.traffic_config, own_traffic=config.piece_traffic == "own",
                                     closed=() if config.entry_traffic else (route.route[0],))
        self.traffic.bind(model)
        self.traffic.set_ego_route(route.route)
        self.route_lane = Lane(np.asarray(route.polyline), name="route")
        self.route_frame = RouteFrame(self.route_lane)
        self.route_starts = route_offsets(route.road_map, route.route)  # [m] along the route
        self._route_lanes = np.array(route.route, dtype=np.int64)  # the route's lane ids
        self.route_end = float(self.route_frame.s0[-1] + self.route_frame.length[-1])  # [m]
        self.start_s = 0.0 if scenario in ("concatenated", "opendrive") else max(
            0.0, route.tactical.interval(scenario)[0] - config.start_before)
        # the conflict points ahead on the route, by the scenario they lie in
        rc = route.route_conflicts
        self._points = np.asarray(route.conflicts.point)[rc.zone] if len(rc) else np.zeros((0, 2))
        self._point_s = np.asarray(rc.s_point, dtype=float)
        self._point_scenario = np.array([route.tactical.scenario_at(s) for s in self._point_s])
        self._route_points = kernels.RoutePoints(self._point_s, np.array(
            [_SCENARIO_CODE[name] for name in self._point_scenario], dtype=np.int64), self._points)
        self._scales = (SPEED_SCALE, config.off_route, self.route_end, DISTANCE_SCALE)
        # for the kernels: the tactical intervals as arrays
        intervals = route.tactical.intervals
        self._interval_starts = np.array([s0 for _, s0, _ in intervals], dtype=float)  # [m]
        self._interval_ends = np.array([s1 for _, _, s1 in intervals], dtype=float)  # [m]
        self._interval_names = [name for name, _, _ in intervals] + [FOLLOW]  # index -1: outside every interval
        self.junction_watch = JunctionWatch(route.route, self.route_starts, self.traffic.junctions,
                                            0.5 * self.params.length, DISTANCE_SCALE)
        # the observation's `junction`: under a control other than give-way (under "map": where the map has signs)
        self.junction_observed = config.junction_control != "give_way" and (
            config.junction_control != "map" or bool(route.road_map.entry_signs))
        self._lamps: np.ndarray | None = None  # [m] (E, 2) where the logs draw each entry's signal
        self.step_period = CONTROL_TIMESTEP  # [s] of one env step
        self._set_up_route_traffic()
        self.decisions: tuple[str, ...] | None = None  # the decision action set's names (None: pedals)
        if config.decisions:
            self._set_up_decisions(config)

    def _set_up_route_traffic(self) -> None:
        """The ground truth along the route (`RouteTraffic`): the operative level's, the privileged drivers'."""
        rm, route = self.road_map, self.route
        table = self.traffic.approaches
        lines, scenarios = [], []
        for k, lane in enumerate(route):  # the give-way lines of the conflict zones on the route
            rows = np.flatnonzero((table.lane == lane) & (table.yields | table.tie))
            for row in rows:
                s_line = float(self.route_starts[k] + table.stop[row])
                lines.append(s_line)
                scenarios.append(self.urban.tactical.scenario_at(s_line))
        order = np.argsort(lines, kind="stable")
        give_way = (np.asarray(lines, float)[order], np.asarray(scenarios, dtype=object)[order])
        rc = self.urban.route_conflicts
        merges = np.asarray(rc.s_point, dtype=float)[np.asarray(rc.kind) == MERGE] if len(rc) else np.zeros(0)
        self.route_traffic = RouteTraffic(rm, tuple(route), self.route_starts, RouteFrame(self.route_lane),
                                          self.route_lane.heading, self.urban.tactical.scenario_at, give_way, merges,
                                          self.params.length, self.params.width, CONTROL_TIMESTEP)

    def _set_up_decisions(self, config: UrbanConfig) -> None:
        """The decision action set: its names, the operative level and the ground truth it reads."""
        self.decisions = ACTIONS[self.name]
        self.step_period = config.decision_period
        self.control_ticks = int(round(config.decision_period / CONTROL_TIMESTEP))
        rm, route = self.road_map, self.route
        limits = np.array([rm.lanes[lane].speed_limit for lane in route])
        c = config.operative
        profile = route_speed_profile(self.route_lane, self.route_starts, limits, c.lateral_accel, c.lateral_jerk,
                                      c.curve_decel, c.path_deviation, c.smoothing, c.curve_footprint,
                                      reference=0.5 * self.params.wheelbase)
        self.operative = OperativeLevel(profile, self.params, CONTROL_TIMESTEP, c,
                                        extra_delay=config.steering_latency)
        self._steer_queue: list[float] = []  # steering commands still to act (steering_latency)
        self.ticks: list[dict] = []  # this env step's control periods, for the logs

    # --- episode ----------------------------------------------------------------------------------------
    def initialize_episode(self, physics: Physics) -> None:
        x, y = self.route_lane.position(self.start_s)
        self.vehicle.reset(physics.raw_data, float(x), float(y), float(self.route_lane.heading(self.start_s)))
        self.route_frame(np.array([[x, y]]), full=True)
        self.route_s, self.lane_offset, self.xy = self.start_s, 0.0, np.array([x, y], dtype=float)
        self._position = float(x), float(y)  # [m] self.xy as floats
        self._ego_fn = functools.partial(self.ego_state, physics)
        traffic_seed = self.random.randint(2**31)
        rng = np.random.default_rng(traffic_seed)
        self._set_junction_control(np.random.default_rng((traffic_seed, 44)))
        self.traffic.reset(rng, self.ego_state(physics), warmup=self.config.warmup)
        self.junction_watch.reset()
        self.traffic.write(physics.raw_data)
        self.reset_safety_sensors(physics)
        self._update_ego(physics)
        self.info = {
            "success": False, "collision": False, "off_route": False, "physics_error": None,
            "scenario": self.active_scenario(), "elapsed_time": 0.0, "average_speed": 0.0, "distance": 0.0,
            "steps": 0, "episode_reward": 0.0, "route_length": self.route_end - ARRIVAL_MARGIN - self.start_s,
            "junction_control": self.junction_control, "violation": None,
        }
        self._step_reward = 0.0
        self._ended = False
        self.reward_terms = {}
        if self.decisions is not None:
            self.operative.reset()
            self.route_traffic.reset(self.traffic.n)
            self._steer_queue = [0.0] * int(round(self.config.steering_latency / CONTROL_TIMESTEP))
            self.decision = self.decisions[0]
            self.ticks = []
            self.info.update(self._decision_info())

    def junction_signals(self) -> dict | None:
        """What every junction entry shows now, for the logs: {"control", "entries": [{"lane", "group", "state"}],
        "xy": (E, 2) [m] each entry's lamp at its line's kerb}; None under give-way."""
        traffic = self.traffic
        if not traffic.junctions.active:
            return None
        rm, junctions = self.road_map, traffic.junctions
        if self._lamps is None:
            lanes = [rm.lanes[int(i)] for i in junctions.lane]
            self._lamps = np.array([lane.position(line, -0.5 * lane.width - 0.7)
                                    for lane, line in zip(lanes, junctions.line, strict=True)]).reshape(-1, 2)
        entries = [{"lane": rm.lanes[int(lane)].name, "group": ("main", "minor")[int(group)],
                    "state": STATE_NAMES[int(state)]}
                   for lane, group, state in zip(junctions.lane, junctions.group, traffic.entry_state, strict=True)]
        return {"control": self.junction_control, "entries": entries, "xy": self._lamps}

    def _set_junction_control(self, rng: np.random.Generator) -> None:
        """This episode's junction control (`junction_control`; "random": drawn from `rng`, a stream of its own so
        that the traffic's draws stay those of a give-way episode), the lights starting anywhere in their cycle."""
        control = self.config.junction_control
        offset = 0.0
        if control != "give_way":
            control = CONTROLS[int(rng.integers(len(CONTROLS)))] if control == "random" else control
            offset = float(rng.uniform(0.0, self.config.signals.cycle))
        self.junction_control = control
        self.traffic.set_junction_control(control, self.config.signals, offset)

    def substep_period(self) -> float:
        """[s] between substeps: the traffic's pose period (mocap poses written and contacts sampled)."""
        return self.traffic.config.substep

    def substep_traffic(self) -> Traffic:
        return self.traffic

    def substep(self, physics: Physics, dt: float) -> None:
        """The substep callback (`tasks.stepping`): sample the ego's contacts, then move the traffic."""
        data = physics.raw_data
        self.collision_sensor.sample(data)
        self.traffic.advance(dt, self._ego_fn, data)

    # --- decisions ----------------------------------------------------------------------------------------
    def action_spec(self, physics: Physics) -> specs.BoundedArray:
        if self.decisions is None:
            return super().action_spec(physics)
        return specs.DiscreteArray(len(self.decisions), name=",".join(self.decisions))

    def before_step(self, action, physics: Physics) -> None:
        if self.decisions is None:
            super().before_step(action, physics)
            return
        index = action_index(action, len(self.decisions),
                             f"urban/{self.name} decisions ({', '.join(self.decisions)})")
        self.decision = self.decisions[index]
        self.last_action = index
        self.ticks = []

    def control_tick(self, physics: Physics, k: int) -> None:
        """One control period of the operative level under the decision: ground truth in, pedals and steering out
        (the steering through the car's latency queue)."""
        if self.decisions is None:
            return
        if k == 0:
            self._step_start = self._position  # [m] for the step's distance
        self._update_ego(physics)
        level, data = self.operative, physics.raw_data
        situation = self.route_traffic.situation(self.route_s, (*self._position, self.yaw), self.speed, self.decision,
                                                 level.lanes(), self.traffic, self.ego_state(physics),
                                                 self.params.wheelbase)
        throttle, steer, brake = level(situation)
        queue = self._steer_queue
        if queue:
            queue.append(steer)
            steer = queue.pop(0)
        self.vehicle.apply(data, throttle, steer, brake)
        self._chassis = None  # the physics moves next
        status = level.status
        tick = {"t": float(data.time), "route_s": self.route_s, "route_offset": self.lane_offset,
                "decision": status.decision, "mode": status.mode, "solver": status.solver,
                "throttle": throttle, "steer": steer, "brake": brake, "accel_command": status.accel,
                "v_ref": status.v_ref, "stop": status.stop, "offset": status.offset,
                "target_offset": status.target_offset, "lateral_error": status.lateral_error,
                "heading_error": status.heading_error, "leaders": len(situation.leaders), "solve_ms": status.solve_ms,
                "step_ms": status.step_ms}
        if k:
            vx, vy, yaw = self._planar_velocity(data)
            tick["comfort"] = (vx, vy, yaw)
        self.ticks.append(tick)

    def operative_path(self, length: float = 60.0) -> tuple[np.ndarray, np.ndarray | None]:
        """The path the operative level tracks over the next `length` [m] of the route (its lane offset and the
        smoothed curves included) as points (M, 2) [m], and its stop line across the lane (2, 2) [m] (None: no
        stop): for the logs' 3D scene."""
        level = self.operative
        s = self.route_s + np.arange(0.0, length, 1.0)
        offset = level.offset_target if level.manoeuvre is None else np.array(
            [level.manoeuvre(level.time + d / max(self.speed, 1.0))[0] for d in s - self.route_s])
        smooth = np.interp(s, level.profile.s, level.profile.offset)
        path = np.asarray(self.route_lane.position(s, smooth + offset)).reshape(-1, 2)
        stop = level.status.stop
        if stop is None:
            return path, None
        s_stop = self.route_s + 0.5 * self.params.length + stop
        half = 0.5 * self.route_lane.width
        line = np.asarray(self.route_lane.position(np.array([s_stop, s_stop]),
                                                   np.array([-half, half]) + level.offset_target))
        return path, line.reshape(2, 2)

    def _decision_info(self) -> dict:
        """`info`'s keys of the decision action set: the decision asked, the one the level applied, its mode."""
        status = self.operative.status
        return {"decision": self.decision, "decision_applied": status.decision, "manoeuvre": status.mode,
                "lane_offset_target": status.target_offset}

    def ego_state(self, physics: Physics) -> EgoState:
        """The ego for traffic: pose, speed, and its place on the lanes: the route's, or a neighbour lane's when
        it is there (beside the route where there is none: the route's); none farther off."""
        x, y, yaw = self.vehicle.pose(physics.raw_data)
        speed = self.vehicle.speed(physics.raw_data)
        half = 0.5 * self.route_lane.width
        if abs(self.lane_offset) > 3 * half:
            return EgoState(x, y, yaw, speed, self.params.length, self.params.width, None, 0.0)
        if abs(self.lane_offset) > half:  # in a neighbour lane
            neighbour = self.route_traffic.neighbour_path(self.route_s, 1 if self.lane_offset > 0 else -1)
            if neighbour is not None:
                return EgoState(x, y, yaw, speed, self.params.length, self.params.width, *neighbour)
        k = int(np.searchsorted(self.route_starts, self.route_s, side="right") - 1)
        return EgoState(x, y, yaw, speed, self.params.length, self.params.width, self._route_lanes[k:].copy(),
                        float(self.route_s - self.route_starts[k]))

    def _update_ego(self, physics: Physics) -> None:
        """The ego's chassis state, route coordinates, heading error and active scenario (in one compiled pass)."""
        data, frame = physics.raw_data, self.route_frame
        lo, hi = frame.window()
        qa, va = self.vehicle.state_addresses
        (x, y, yaw, self.speed, left, self.yaw_rate, self.route_s, self.lane_offset, frame.segment, k,
         self.heading_error) = kernels.urban_ego(data.qpos, data.qvel, qa, va, frame.x0, frame.y0, frame.tx, frame.ty,
                                                 frame.length, frame.s0, lo, hi, self._interval_starts,
                                                 self._interval_ends)
        self._chassis = yaw, self.speed, left  # `read_chassis`' hand-over to the comfort sample
        self.xy, self._position, self.yaw = np.array([x, y]), (x, y), yaw
        self.scenario = self._interval_names[k]
        if self.traffic.junctions.active:
            self.junction_watch.update(self.route_s, self.speed, self.traffic.entry_state)

    def active_scenario(self) -> str:
        """The tactical trajectory's scenario at the ego's place on the route."""
        return self.scenario

    def road_users(self) -> RoadUsers:
        """The road users (base class) with their intentions (N, 4) by scenario, for logs and viewers."""
        users = super().road_users()
        return RoadUsers(users.kinds, users.poses, users.half_sizes,
                         self.traffic.intentions()[self.traffic.present])

    def after_step(self, physics: Physics) -> None:
        (x0, y0) = self._position if self.decisions is None else self._step_start
        self._update_ego(physics)
        info = self.info
        collision = self.collision_sensor.collided(physics.raw_data)
        arrived = self.route_s >= self.route_end - ARRIVAL_MARGIN
        off_route = self.route_traffic.lane_distance(self.route_s, self.lane_offset) > self.config.off_route
        info["collision"] |= collision
        info["off_route"] |= off_route and not collision
        violation = self.junction_watch.violation if not info["collision"] else None
        info["violation"] = violation
        info["success"] = arrived and not info["collision"] and violation is None
        info["scenario"] = self.active_scenario()
        info["steps"] += 1
        info["elapsed_time"] = info["steps"] * self.step_period
        x, y = self._position
        info["distance"] += float(np.hypot(x - x0, y - y0))
        info["average_speed"] = info["distance"] / info["elapsed_time"]
        speed, arrival = SPEED_REWARD * self.speed, ARRIVAL_REWARD * info["success"]
        crash = self.config.collision_reward * collision
        self.reward_terms = {"speed": speed, "arrival": arrival, "collision": crash}
        self._step_reward = speed + arrival + crash  # their sum, in this order
        if violation is not None and not self._ended:  # running a red light or a stop sign: as a collision
            self.reward_terms["violation"] = self.config.collision_reward
            self._step_reward += self.config.collision_reward
        info["episode_reward"] += self._step_reward
        self._ended = collision or arrived or off_route or violation is not None
        if self.decisions is not None:
            info.update(self._decision_info())

    def get_reward(self, physics: Physics) -> float:
        return self._step_reward

    def get_termination(self, physics: Physics) -> float | None:
        return 0.0 if self._ended else None

    # --- observation -------------------------------------------------------------------------------------
    def observation_spec(self, physics: Physics) -> collections.OrderedDict:
        ego = specs.BoundedArray((4,), np.float32, 0.0, 1.0, "ego")
        if self.observation == "camera":
            size = self.config.image_size
            spec = collections.OrderedDict(image=specs.BoundedArray((size, size, 3), np.uint8, 0, 255, "image"),
                                           ego=ego)
        else:
            spec = collections.OrderedDict(
                ego=ego, scenario=specs.BoundedArray((len(SCENARIOS),), np.float32, 0.0, 1.0, "scenario"),
                adversaries=specs.BoundedArray((self.config.adversaries, ADVERSARY_COLUMNS), np.float32, 0.0, 1.0,
                                               "adversaries"))
        if self.junction_observed:
            spec["junction"] = specs.BoundedArray((JUNCTION_FEATURES,), np.float32, 0.0, 1.0, "junction")
        spec.update(self.sensor_spec(physics))
        return spec

    def _ego(self) -> tuple[float, ...]:
        """(speed [m/s], heading error [rad], lane offset [m], route s [m], x [m], y [m]) for the kernels."""
        return (self.speed, self.heading_error, self.lane_offset, self.route_s, *self._position)

    def _ego_vector(self) -> np.ndarray:
        """(4,) the ego's features in [0, 1] (module docstring)."""
        out = np.empty(4, np.float32)
        kernels.ego_features(out, self._ego(), self._scales)
        return out

    def relevant_point(self) -> np.ndarray:
        """Where adversaries' distances are measured (§5.1.2): the next conflict point on the route within
        the active scenario; the ego itself on the two-lane road and outside every scenario."""
        scenario = self.active_scenario()
        return np.array(kernels.relevant_point(self._route_points, _SCENARIO_CODE[scenario],
                                               scenario in (FOLLOW, "lane_change"), self._ego()))

    def adversary_matrix(self) -> np.ndarray:
        """(n, 4) the n road users nearest the relevant point: present, distance, speed, intention (in [0, 1])."""
        return self._features()[1]

    def _features(self) -> tuple[np.ndarray, np.ndarray]:
        """The "features" observation's ego (4,) and adversaries (n, 4) (`kernels.urban_features`)."""
        traffic, scenario = self.traffic, self.scenario
        column = _INTENTION_COLUMN.get(scenario, -1)
        ego, adversaries = np.empty(4, np.float32), np.zeros((self.config.adversaries, ADVERSARY_COLUMNS), np.float32)
        users = (traffic.present, traffic.positions(), traffic.speeds(),
                 traffic.intentions() if column >= 0 else _NO_INTENTIONS)
        kernels.urban_features(ego, adversaries, self._ego(), self._scales, self._route_points,
                               _SCENARIO_CODE[scenario], scenario in (FOLLOW, "lane_change"), users, column)
        return ego, adversaries

    def get_observation(self, physics: Physics) -> collections.OrderedDict:
        if self.observation == "camera":
            size = self.config.image_size
            obs = collections.OrderedDict(image=self.render_camera(physics, "ego/front", size, size).copy(),
                                          ego=self._ego_vector())
        else:
            ego, adversaries = self._features()
            obs = collections.OrderedDict(ego=ego, scenario=_SCENARIO_ONE_HOT[self.scenario].copy(),
                                          adversaries=adversaries)
        if self.junction_observed:
            obs["junction"] = self.junction_watch.features(self.route_s, self.traffic.entry_state,
                                                           self.traffic.junctions.control)
        obs.update(self.sensor_observation(physics))
        return obs


# --- registered tasks -----------------------------------------------------------------------------------


@functools.lru_cache(maxsize=8)
def _route(name: str, urban_map: UrbanMap | None, opendrive: str | None = None,
           route_points: tuple[float, ...] | None = None) -> UrbanRoute:
    """The map and route of a task (built once per process and map; maps are immutable data)."""
    if name == "opendrive":
        if opendrive is None:
            raise ConfigError("urban/opendrive needs opendrive=FILE.xodr (an OpenDRIVE file, or a shipped map: "
                              f"{', '.join(sorted(p.stem for p in MAPS_DIR.glob('*.xodr')))})")
        if urban_map is not None:
            raise ConfigError("urban/opendrive reads its map from `opendrive`; `map` is for the other urban tasks")
        shipped = MAPS_DIR / f"{opendrive}.xodr"
        road_map = read_opendrive(shipped if "/" not in opendrive and shipped.is_file() else opendrive)
        route = (longest_route(road_map) if route_points is None else
                 route_between(road_map, route_points[:2], route_points[2:]))
        return route_on(road_map, route)
    for keyword, value in (("opendrive", opendrive), ("route_points", route_points)):
        if value is not None:
            raise ConfigError(f"{keyword}={value!r}: only urban/opendrive takes it (urban/{name} takes `map`)")
    urban_map = urban_map or UrbanMap()
    pieces = urban_map.pieces(PIECES[name])
    if name != "concatenated" and PIECES[name][0] not in pieces:
        raise ConfigError(f"map={{'order': {list(pieces)}}}: urban/{name} needs the {PIECES[name][0]!r} piece in "
                          "the order")
    return route_through(concatenated(dataclasses.replace(urban_map, order=pieces)))


def _make(name: str, config: UrbanConfig, environment_kwargs) -> DrivingEnvironment:
    where = f"urban/{name}"
    period = config.decision_period if config.decisions else CONTROL_TIMESTEP  # [s] of one env step
    env_kwargs = environment_config(environment_kwargs, config.physics_dt, period, where)
    if config.decisions and abs(env_kwargs["control_timestep"] - period) > 1e-9:
        raise ConfigError(f"{where}: with decisions the env step is the decision period ({period:g} s); set "
                          "decision_period instead of control_timestep")
    try:
        route = _route(name, config.map, config.opendrive, config.route_points)
    except ConfigError as error:
        raise ConfigError(f"{where}: {error}") from None
    composed: ComposedMap = route.composed
    kinds = counts_to_kinds(default_counts(composed) if config.road_users is None else config.road_users)
    model = world.build(route.road_map, vehicle=config.vehicle, traffic=slots(kinds), timestep=config.physics_dt)
    physics = Physics.from_model(wrapper.MjModel(model))
    task = UrbanTask(model, route, kinds, name, config)
    return DrivingEnvironment(physics, task, time_limit=config.time_limit, **env_kwargs)


def _register(name: str, time_limit: float, doc: str, **defaults):
    def build(config: UrbanConfig, environment_kwargs=None) -> DrivingEnvironment:
        return _make(name, config, environment_kwargs)

    build.__name__ = name
    build.__doc__ = doc
    return SUITE.add("study002", "urban")(configured_task(UrbanConfig, time_limit=time_limit, **defaults)(build))


roundabout = _register("roundabout", 90.0, "Enter the roundabout and leave at the route's exit, in traffic.")
lane_change = _register("lane_change", 60.0, "Overtake slow vehicles on the two-lane road and come back.")
crossroad = _register("crossroad", 90.0, "Cross the main road from the minor road (give way), in traffic.")
merge = _register("merge", 60.0, "Join the main road from the right through the acceleration lane.")
concatenated_route = _register("concatenated", 400.0, "The whole route: roundabout, two-lane road, crossroad, "
                               "merge (Fig. 8).")
opendrive = _register("opendrive", 300.0, "Drive a route across an OpenDRIVE map (opendrive=FILE.xodr or a shipped "
                      "map's name), in traffic, under the file's stop signs and traffic lights.", opendrive="four_way",
                      junction_control="map")
