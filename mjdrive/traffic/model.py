"""The traffic model: kinematic traffic on a lane graph, all road users as arrays (no Python loop per user).

Road users are MuJoCo mocap boxes (`world.TrafficSlot`, one per slot, fixed count and kind per slot at build
time) whose geoms collide with the ego only, so the ego hitting one is a real contact.

Vehicles (cars, motorcycles, bicycles; `ROAD_USER_TYPES` gives each its size, desired speed range and IDM
parameters) follow lanes at a lateral offset of their own (bicycles keep right) and choose a random
successor at every lane end. Their acceleration is the Intelligent Driver Model (IDM) against the most
constraining of:
  * leaders on their planned path (the next lanes), the ego included when it is on a lane;
  * anything in a short corridor ahead of them (curvature-corrected): the ego anywhere on the road,
    pedestrians, vehicles changing lane or leaving the ring;
  * a stop line before a crosswalk where a pedestrian walks in their lane's band;
  * a stop line at a merge (a roundabout entry) while a circulating vehicle, or the ego, would reach the
    merge point within `accept_gap` seconds (gap acceptance; the entering vehicle yields, approaching its
    yield line slowly enough to stop there);
  * for circulating vehicles, a point before the merge while an entering vehicle that has passed its yield
    line is still coming in;
  * under urban rules (a map's conflict zones) stop lines at crossings and merges by right of way, gaps opened
    at merges, intentions (conflicts.py, intentions.py).
Speeds respect the lane speed limit and a lateral-acceleration cap in curves; a Krauss-like safety cap
keeps the s0 gap even when the obstacle ahead brakes at `max_decel` within the decision period. Vehicles
change to a same-direction neighbour lane (across a broken line) at random when the target lane has room
(not next to merges and exits), moving over smoothly along `lane_change_length` metres. Vehicles leave the
map at dead ends and respawn at the map's sources (lanes without predecessors) when the source is clear,
so the count stays at its target.

Pedestrians shuttle across their crosswalk on one of three tracks (so two never overlap): they wait at the
kerb for a random time, then for a gap (no vehicle, ego included, that could not stop comfortably before
the crosswalk), then walk across at their own speed; vehicles stop for them.

Time: decisions (IDM accelerations, lane changes, spawns, pedestrian starts) every `decision_period`
seconds; between decisions the motion is integrated in closed form at `substep` resolution for all users
at once, and `advance` (called every substep, by the substep loop `tasks.stepping` where a decision is due)
writes the poses of the current substep into mocap_pos / mocap_quat. Seeded by the np.random.Generator given to
`reset`.
"""


from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import NamedTuple

import mujoco
import numpy as np

from mjdrive.compiled import announce_compilation
from mjdrive.roads import RoadMap
from mjdrive.roads.conflicts import ConflictZones
from mjdrive.traffic import junction_control as jc
from mjdrive.traffic import motion, state
from mjdrive.traffic.conflicts import ApproachTable, ego_give_way
from mjdrive.traffic.following import accelerations, path_leader, queued_rows
from mjdrive.traffic.intentions import LANE_CHANGE, LEFT, MERGE, RIGHT, SCENARIOS, YIELD, LaneRoles, Routes, fill_paths
from mjdrive.traffic.lane_changes import lane_changes
from mjdrive.traffic.lanes import Crossings, LaneTables, Merges, Polylines, TrafficMap
from mjdrive.traffic.params import HIDDEN_Z, KIND_INDEX, PATH, ROAD_USER_TYPES, EgoState, TrafficConfig
from mjdrive.traffic.pedestrians import (
    EGO_REACH,
    EGO_REACH_PER_SPEED,
    new_waits,
    on_crosswalks,
    start_crossing,
)
from mjdrive.traffic.spawning import Spawner, SpawnPoints
from mjdrive.traffic.state import Agents, Followers, PlanCursor, Poses, VehicleKinds

EGO_DECEL = 3.0  # [m/s^2] the ego's comfortable deceleration, as pedestrians judge whether it could stop
QUEUE_GAP = 8.0  # [m] bumper to bumper behind a slow leader: queued (`Traffic.queued`)
QUEUE_SPEED = 0.5  # [m/s] ... a leader slower than this
STOPPED_SPEED = 0.1  # [m/s] slower than this: stopped (`Traffic.stopped`)
_NO_PLAN = Poses(np.zeros((0, 0, 3)), np.zeros((0, 0, 4)), np.zeros((0, 0)), np.zeros((0, 0)))

class GiveWay(NamedTuple):
    """What the urban rules ask of the ego (`Traffic.give_way`)."""

    stop: float  # [m] front bumper to the give-way line where it must wait now (inf: it may go)
    leader_gap: float  # [m] front bumper to the rear of the vehicle it merges behind (inf: none)
    leader_speed: float  # [m/s] that vehicle's speed


class MapTables(NamedTuple):
    """The traffic's road as the kernels read it: lanes, their centre lines, crossings, roundabout merges (none under
    urban rules), conflict-zone approaches (none without), and whether urban rules apply."""

    lanes: LaneTables
    polylines: Polylines
    crossings: Crossings
    merges: Merges
    approaches: ApproachTable
    urban: bool


def _lane_mask(lanes: Sequence[int], n_lanes: int, name: str) -> np.ndarray:
    """(n_lanes,) bool, True at `lanes` (lane ids, checked)."""
    ids = np.asarray(lanes, dtype=np.int64).reshape(-1)
    if len(ids) and (ids.min() < 0 or ids.max() >= n_lanes):
        raise ValueError(f"{name}: lane ids must be in [0, {n_lanes}), got {ids.tolist()}")
    mask = np.zeros(n_lanes, dtype=bool)
    mask[ids] = True
    return mask


class Traffic:
    """All road users of one world. `kinds` gives each slot's kind (in the order of the model's
    `traffic_{i}` bodies); the count of active users per kind is the slot count (minus users that just
    left the map and wait to respawn). State: `vehicles` and `pedestrians` (`state.py`), the slots' poses `now`."""

    def __init__(self, road_map: RoadMap | TrafficMap, kinds: Sequence[str],
                 config: TrafficConfig | None = None, conflicts: ConflictZones | None = None,
                 spawn_points: SpawnPoints | None = None, exits: Sequence[int] = (), closed: Sequence[int] = ()):
        """`conflicts` (the map's conflict-zone table, `roads.conflict_zones`) switches on the urban rules:
        right of way at every crossing and merge of the table, intentions, intention-driven lane changes
        with a signalling phase; without it, entries yield at merges by gap acceptance (the roundabout).
        `exits`: lanes at whose end vehicles leave the map although the road goes on (a chain's piece borders);
        `closed`: lanes where no vehicle enters, neither at a source nor at an episode's start."""
        self.config = cfg = config or TrafficConfig()
        self.constants = cfg.constants()
        announce_compilation()
        self.map = m = road_map if isinstance(road_map, TrafficMap) else TrafficMap(road_map, cfg.lateral_accel)
        self.urban = conflicts is not None
        self.zones = conflicts
        self.exits = _lane_mask(exits, m.n_lanes, "exits")  # (L,) lanes whose vehicles leave the map at their end
        self.closed = _lane_mask(closed, m.n_lanes, "closed")  # (L,) lanes where no vehicle enters
        self.roles = LaneRoles.of(m.road_map) if self.urban else LaneRoles.none()
        self.approaches = (ApproachTable.from_zones(conflicts, m.road_map, self.roles.ring) if self.urban
                           else ApproachTable.none())
        merges = Merges(*(a[:0] for a in m.merges)) if self.urban else m.merges  # urban: conflict zones instead
        self.tables = MapTables(m.lane_tables, m.polylines, m.crossings, merges, self.approaches, self.urban)
        self.routes = Routes(m.successors, m.n_successors, self.roles, -1, self.urban)
        self.kinds = tuple(kinds)
        unknown = set(self.kinds) - set(ROAD_USER_TYPES)
        if unknown:
            raise ValueError(f"unknown road-user kinds {sorted(unknown)}; valid: {', '.join(ROAD_USER_TYPES)}")
        types = [ROAD_USER_TYPES[k] for k in self.kinds]
        self.n = len(types)
        self.kind_id = np.array([KIND_INDEX[k] for k in self.kinds], dtype=np.int64)
        self.half_size = np.array([t.half_size for t in types]).reshape(-1, 3)
        is_vehicle = np.array([t.is_vehicle for t in types], dtype=bool)
        self.vehicle_slots = np.flatnonzero(is_vehicle)
        self.pedestrian_slots = np.flatnonzero(~is_vehicle)
        self.nv, self.np_ = len(self.vehicle_slots), len(self.pedestrian_slots)
        vt = [types[i] for i in self.vehicle_slots]
        half = self.half_size[self.vehicle_slots]  # [m]
        self.vehicles = state.new_vehicles(self.vehicle_slots, 2 * half[:, 0])
        self.vehicle_kinds = VehicleKinds(2 * half[:, 1], np.array([t.accel for t in vt]),
                                          np.array([t.decel for t in vt]), np.array([t.headway for t in vt]))
        self._b_agents = np.append(self.vehicle_kinds.b_comf, EGO_DECEL)  # [m/s^2] comfortable decelerations; ego
        self.spawner = Spawner(m, spawn_points, np.array([t.speed for t in vt]).reshape(-1, 2),
                               np.array([t.lateral for t in vt]).reshape(-1, 2), cfg, self.urban, self.closed)
        self._walk_range = np.array([types[i].speed for i in self.pedestrian_slots]).reshape(-1, 2)
        self.pedestrians = on_crosswalks(m, self.pedestrian_slots, cfg.kerb)
        self.n_plan = max(1, int(round(cfg.decision_period / cfg.substep)))
        self._t_plan = cfg.substep * np.arange(1, self.n_plan + 1)  # [s]
        self._hidden = np.column_stack([np.zeros(self.n), np.zeros(self.n), HIDDEN_Z - 5.0 * np.arange(self.n)])
        self._hidden_vehicles = self._hidden[self.vehicle_slots]  # [m] (NV, 3)
        self.mocap_ids: np.ndarray | None = None  # the slots' rows in data.mocap_*
        self.cpu_time = 0.0  # [s] wall time spent in `advance` (for benchmarks)
        self.stats = {"spawned": 0, "despawned": 0, "lane_changes": 0, "red_light_violations": 0,
                      "stop_sign_violations": 0}
        self.junctions = jc.Junctions.of(m.road_map)  # junction entries; give-way until `set_junction_control`
        self._no_control = np.full(self.nv + 1, np.inf)  # (A,) no junction-control line for anyone (read only)
        self._no_control.flags.writeable = False
        self.generation = np.zeros(self.n, dtype=np.int64)  # per slot: +1 each time a road user (re)enters
        self.ego: EgoState | None = None
        self.rng = np.random.default_rng(0)
        self.intent_rng = np.random.default_rng(1)
        self._reset_state()

    def set_ego_route(self, route: Sequence[int] | None) -> None:
        """The ego's route (lane ids): roundabout intentions are relative to its ring exit (`routes.ego_exit`)."""
        ego_exit = -1
        if self.urban and route is not None:
            exits = [lane for lane in route if self.roles.ring_exit[lane]]
            ego_exit = int(exits[0]) if exits else -1
        self.routes = self.routes._replace(ego_exit=ego_exit)

    # --- binding and state ----------------------------------------------------------------------------
    def bind(self, model: mujoco.MjModel, prefix: str = "traffic_") -> None:
        """Look up the mocap ids of the slots' bodies (`traffic_{i}`) once."""
        ids = []
        for i in range(self.n):
            body = model.body(f"{prefix}{i}")
            if model.body_mocapid[body.id] < 0:
                raise ValueError(f"body {prefix}{i} is not a mocap body")
            ids.append(int(model.body_mocapid[body.id]))
        self.mocap_ids = np.array(ids, dtype=np.int64)

    def _reset_state(self) -> None:
        self.vehicles = state.new_vehicles(self.vehicles.slot, self.vehicles.length)
        n = self.np_
        self.pedestrians = self.pedestrians._replace(u=np.zeros(n), direction=np.ones(n),
                                                     walking=np.zeros(n, dtype=bool), wait=np.zeros(n),
                                                     speed=np.zeros(n))
        self.time = 0.0  # [s]
        self.ego_waited = 0.0  # [s] how long the ego has waited (slower than motion.STOPPED_SPEED), at decisions
        self._plan: Poses | None = None
        self._k = 0  # index of the current substep in the plan
        self._accumulated = 0.0
        quat = np.zeros((self.n, 4))
        quat[:, 0] = 1.0  # yaw 0: cos 0 = 1, sin 0 = 0
        self.now = Poses(self._hidden.copy(), quat, np.zeros(self.n), np.zeros(self.n))
        self.signal_time = 0.0  # [s] the junction signals' clock (runs through the warmup)
        self.entry_state = jc.entry_states(self.junctions, 0.0)  # (E,) what each junction entry shows
        self.halted = np.full(self.nv, -1, dtype=np.int64)  # the stop-sign entry each vehicle has stopped at
        self.ego_halted = -1  # ... and the ego

    def set_junction_control(self, control: str, timing: jc.SignalTiming | None = None, offset: float = 0.0) -> None:
        """The control of the map's junctions from now on: "give_way", "stop" (stop signs on the minor road),
        "lights" (`timing`, starting `offset` [s] into its cycle) or "map" (the map's own, `RoadMap.entry_signs`)."""
        if control not in jc.KEYWORDS:
            raise ValueError(f"junction control {control!r}: must be one of {', '.join(jc.KEYWORDS)}")
        self.junctions = self.junctions.controlled(jc.KEYWORDS.index(control), timing, offset)
        self.entry_state = jc.entry_states(self.junctions, self.signal_time)

    def junction_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The junction entries' lane ids (E,) and what each shows now (`junction_control.GREEN`, AMBER, RED or
        STOP_SIGN; GREEN under give-way)."""
        return self.junctions.lane.copy(), self.entry_state.copy()

    # --- episodes --------------------------------------------------------------------------------------
    def reset(self, rng: np.random.Generator, ego: EgoState | None = None, keep_clear: float = 12.0,
              warmup: float = 0.0, density: float = 1.0) -> None:
        """New episode: place a random `density` share of the vehicles on the map's spawn points (none within
        `keep_clear` [m] of the ego), pedestrians at kerbs, then run `warmup` [s] of traffic."""
        self.rng = rng
        if self.urban:
            self.intent_rng = np.random.default_rng(int(rng.integers(2**63)))
        self._reset_state()
        self.ego = ego
        m = self.map
        free = ~self.closed[m.spawn_lane]
        if ego is not None:
            free &= np.hypot(m.spawn_xy[:, 0] - ego.x, m.spawn_xy[:, 1] - ego.y) >= keep_clear
        points = np.flatnonzero(free)
        n_place = min(int(round(density * self.nv)), len(points))
        chosen = rng.permutation(points)[:n_place]
        rows = rng.permutation(self.nv)[:n_place]
        self.spawner.activate(self.vehicles, self.routes, self.generation, rows, m.spawn_lane[chosen],
                              m.spawn_s[chosen], rng, self.intent_rng, speed_share=rng.uniform(0.3, 1.0, n_place))
        if self.np_:
            p = self.pedestrians
            p.direction[:] = rng.choice([-1.0, 1.0], self.np_)
            p.u[:] = -p.direction * p.end
            p.wait[:] = rng.uniform(0.0, self.config.pedestrian_wait[1], self.np_)
            p.speed[:] = rng.uniform(self._walk_range[:, 0], self._walk_range[:, 1])
        self.now = self._poses_now()
        for _ in range(int(round(warmup / self.config.decision_period))):
            self._decide()
            self._commit()
        self.time = 0.0
        self._plan = None
        self._k = 0

    def place(self, row: int, path: Sequence[int], s: float, speed: float, desired_speed: float | None = None,
              lateral: float = 0.0, intentions: dict[str, int] | None = None) -> None:
        """Put vehicle `row` (index among the vehicle slots) at s [m] on path[0], moving at `speed` [m/s]
        along `path` (lane ids; random successors after it), with a desired speed [m/s] and lateral offset
        [m], and `intentions` by scenario name (e.g. {"merge": TAKE_WAY}; urban rules; others 0), for scenes
        and tests. Takes effect from the next decision."""
        self._settle()
        v = self.vehicles
        lanes = [int(x) for x in path][:PATH]
        self.generation[v.slot[row]] += 1
        v.active[row] = True
        v.intention[row] = 0
        for name, value in (intentions or {}).items():
            if name not in SCENARIOS:
                raise ValueError(f"unknown intention scenario {name!r}; valid: {', '.join(SCENARIOS)}")
            v.intention[row, SCENARIOS.index(name)] = int(value)
        v.ring_passed[row], v.lc_signal[row], v.lc_changing[row] = False, -1.0, False
        v.path[row] = -1
        v.path[row, : len(lanes)] = lanes
        if len(lanes) < PATH:
            fill_paths(self.routes, v, np.array([row]), self.rng, start=len(lanes))
        v.s[row], v.v[row] = s, speed
        v.v0[row] = self.map.speed_limit[lanes[0]] if desired_speed is None else desired_speed
        v.d_pref[row], v.lc_shift[row], v.lc_dist[row] = lateral, 0.0, 1e9
        v.accel[row] = 0.0
        self.halted[row] = -1
        self._restart()

    def place_pedestrian(self, row: int, u: float, direction: float, walking: bool = True,
                         speed: float = 1.3) -> None:
        """Put pedestrian `row` (index among the pedestrian slots) at u [m] along its crosswalk, walking (or
        waiting) in `direction` (+1 / -1 along the crosswalk) at `speed` [m/s]."""
        self._settle()
        p = self.pedestrians
        p.u[row], p.direction[row] = u, float(np.sign(direction) or 1.0)
        p.walking[row], p.speed[row] = walking, speed
        p.wait[row] = 1e9 if not walking else 0.0
        self._restart()

    def remove_all(self) -> None:
        """Take every vehicle off the map (pedestrians stay)."""
        self._settle()
        self.vehicles.active[:] = False
        self.vehicles.v[:] = 0.0
        self._restart()

    def _settle(self) -> None:
        """Make the present substep the state and drop the rest of the plan (before editing the state)."""
        if self._plan is not None and self._k > 0:
            self._commit(self._k - 1)
        self._plan = None
        self._k = 0

    def _restart(self) -> None:
        """After an edit: the next `advance` decides from the edited present state."""
        self.now = self._poses_now()

    # --- stepping --------------------------------------------------------------------------------------
    def advance(self, dt: float, ego: Callable[[], EgoState | None] | None = None,
                data: mujoco.MjData | None = None) -> None:
        """Move every road user by `dt` [s] (a whole number of substeps, usually one) and write the new
        poses into `data`'s mocap arrays if given. `ego` is called at each decision for the ego's state."""
        start = time.perf_counter()
        substep = self.config.substep
        n, self._accumulated = motion.substeps_due(self._accumulated, dt, substep)
        for _ in range(n):  # usually once; loops over substeps, never over road users
            if self._plan is None or self._k >= self.n_plan:
                if self._plan is not None:
                    self._commit()
                if ego is not None:
                    self.ego = ego()
                self._decide()
                self._k = 0
            self._k += 1
        if n:
            self.time += n * substep
            self.now = Poses(*(a[self._k - 1] for a in self._plan))
        if data is not None:
            self.write(data)
        self.cpu_time += time.perf_counter() - start

    def cursor(self) -> PlanCursor:
        """Where `advance` stands in the plan (`state.PlanCursor`), for the substep loop that takes its plain
        substeps (`tasks.stepping`)."""
        plan = self._plan or _NO_PLAN
        return PlanCursor(plan.pos, plan.quat, self._k, len(plan.pos), self._accumulated, self.config.substep,
                          self.time, True)

    def moved(self, k: int, accumulated: float, time: float) -> None:
        """The substep loop took the plan's substeps up to k (of `cursor`), leaving `accumulated` [s] toward the
        next, at traffic time `time` [s], and wrote their poses: the state `advance` would have left."""
        if k != self._k:
            self.now = Poses(*(a[k - 1] for a in self._plan))
        self._k, self._accumulated, self.time = k, accumulated, time

    def write(self, data: mujoco.MjData) -> None:
        """Write the current poses into data.mocap_pos / mocap_quat."""
        if self.mocap_ids is None:
            raise RuntimeError("call Traffic.bind(model) before writing poses")
        data.mocap_pos[self.mocap_ids] = self.now.pos
        data.mocap_quat[self.mocap_ids] = self.now.quat

    def _commit(self, k: int = -1) -> None:
        """Make the plan's substep k (default: its end) the new state."""
        t_end = self._t_plan[k]
        arrived = motion.commit(self.vehicles, self.pedestrians, t_end, t_end**2)
        new_waits(self.pedestrians, arrived, self.config.pedestrian_wait, self.rng)
        self.now = Poses(*(a[k] for a in self._plan))
        self._plan = None

    # --- decisions -------------------------------------------------------------------------------------
    def _decide(self) -> None:
        """New accelerations, lane changes, spawns and pedestrian starts; then the plan of poses."""
        v, cfg = self.vehicles, self.config
        period = cfg.decision_period if self.urban else 0.0  # urban rules: waiting times count
        lane_before, active_before = v.path[:, 0].copy(), v.active.copy()
        self.stats["despawned"] += motion.move_on(v, self.routes, self.map.length, self.exits, self.rng,
                                                  period)
        if self.junctions.active:
            self._count_violations(lane_before, active_before)
            self.entry_state = jc.entry_states(self.junctions, self.signal_time)
        self.signal_time += cfg.decision_period
        ego = self.ego
        on_lanes = ego is not None and ego.path is not None
        self.ego_waited = motion.waited_after(self.ego_waited, on_lanes, ego.speed if on_lanes else 0.0, period) \
            if period > 0 else 0.0
        spawned = self.spawner.spawn(v, self.routes, self.generation, self.now.pos, self.ego, self.rng,
                                     self.intent_rng)
        if spawned:
            self.stats["spawned"] += spawned
            self.now = self._poses_now(vehicles_only=True)
        agents = self.agents()
        if lane_changes(v, self.vehicle_kinds, agents, self.map.lane_tables, self.routes, cfg, self.constants, self.rng,
                        self.time, self.now.pos, self.ego, self.approaches.point):
            self.stats["lane_changes"] += 1
            agents = self.agents()
        if self.np_:
            ego = self.ego
            reach = -1.0 if ego is None else EGO_REACH + EGO_REACH_PER_SPEED * max(ego.speed, 0.0)
            start_crossing(self.pedestrians, agents, self._b_agents, self.map.crossings,
                           0.0 if ego is None else ego.x, 0.0 if ego is None else ego.y, reach)
        if self.junctions.active:
            self._update_halted(agents)
        followers = Followers(np.arange(self.nv), agents.path[: self.nv], agents.offset[: self.nv], v.s, v.v, v.v0,
                              v.length, *self.vehicle_kinds, self.now.pos[v.slot, :2],
                              self.now.yaw[v.slot], v.intention[:, MERGE] == YIELD)
        accel, v.lead_gap[:] = self._accelerations(followers, agents, cfg.accept_gap)
        v.accel[:] = np.where(v.active, accel, 0.0)
        self._plan = self._make_plan(agents.start[: self.nv])

    def agents(self) -> Agents:
        """Where every vehicle and the ego (the last row) is on the lane graph now (`state.Agents`)."""
        ego_path, ego_s, ego_v, ego_length = state.ego_on_lanes(self.ego)
        return state.agents_on_paths(self.vehicles, ego_path, ego_s, ego_v, ego_length, self.ego_waited,
                                     self.map.length, self.map.n_lanes)

    def _accelerations(self, followers: Followers, agents: Agents, accept_gap: float
                       ) -> tuple[np.ndarray, np.ndarray]:
        """`following.accelerations` of `followers` among everyone now."""
        ego = self.ego
        ego_box = np.zeros(0) if ego is None else np.array(
            [ego.x, ego.y, ego.yaw, max(ego.speed, 0.0), ego.length / 2, ego.width / 2], dtype=float)
        return accelerations(followers, agents, self.vehicles, self.pedestrians, self.now, self.half_size, ego_box,
                             self.tables, self.constants, accept_gap, self._control_gaps(agents))

    def _control_gaps(self, agents: Agents) -> np.ndarray:
        """(A,) [m] to the junction-control line each agent (the vehicles, the ego) must stop at now (inf: none)."""
        if not self.junctions.active:
            return self._no_control
        gaps = jc.line_gaps(self.junctions, agents.offset, agents.s, agents.length)
        return jc.stop_gaps(self.junctions, self.entry_state, gaps, agents.v, np.append(self.halted, self.ego_halted))

    def _update_halted(self, agents: Agents) -> None:
        """Who has come to rest at a stop sign's line (the vehicles and the ego, at decisions)."""
        v = self.vehicles
        gaps = jc.line_gaps(self.junctions, agents.offset, agents.s, agents.length)
        lanes = agents.path[:, 0]
        halted = jc.halted_lanes(self.junctions, self.entry_state, lanes, gaps, agents.v,
                                 np.append(self.halted, self.ego_halted))
        self.halted = np.where(v.active, halted[: self.nv], -1)
        self.ego_halted = int(halted[self.nv]) if self.ego is not None and self.ego.path is not None else -1

    def _count_violations(self, lane_before: np.ndarray, active_before: np.ndarray) -> None:
        """Vehicles that left a junction entry in the last decision period while it showed red, or a stop sign they
        had not come to rest at (`stats`)."""
        v, junctions = self.vehicles, self.junctions
        left = active_before & v.active & (v.path[:, 0] != lane_before)
        for row, entry in zip(*np.nonzero((lane_before[:, None] == junctions.lane[None, :]) & left[:, None]),
                              strict=True):  # the few vehicles that entered the junction in this period
            kind = jc.violation(self.entry_state[entry], self.halted[row] == junctions.lane[entry])
            if kind is not None:
                self.stats[f"{kind}_violations"] += 1

    # --- poses -------------------------------------------------------------------------------------------
    def _make_plan(self, start: np.ndarray) -> Poses:
        """Poses of every slot at the substeps of the next decision period (`start`: distance (NV, PATH) [m]
        to the start of each path lane)."""
        s, n = self.n_plan, self.n
        plan = Poses(np.empty((s, n, 3)), np.zeros((s, n, 4)), np.empty((s, n)), np.zeros((s, n)))
        motion.vehicle_plan(self.vehicles, self.pedestrians, self.map.polylines, self._t_plan, start,
                            self._hidden_vehicles, self.config.lane_change_length, plan)
        return plan

    def _poses_now(self, vehicles_only: bool = False) -> Poses:
        """Poses of every slot at the current state (no plan); `vehicles_only` (after spawns): the pedestrians' poses
        and every speed as they were."""
        pos, yaw = (self.now.pos.copy(), self.now.yaw.copy()) if vehicles_only else (self._hidden.copy(),
                                                                                       np.zeros(self.n))
        now = Poses(pos[None], np.zeros((1, self.n, 4)), yaw[None], np.zeros((1, self.n)))
        motion.vehicle_plan(self.vehicles, self.pedestrians, self.map.polylines, np.zeros(1),
                            motion.path_starts(self.vehicles.path, self.map.length), self._hidden_vehicles,
                            self.config.lane_change_length, now, distances=False, walkers=not vehicles_only)
        return Poses(now.pos[0], now.quat[0], now.yaw[0], self.now.speed if vehicles_only else now.speed[0])

    # --- queries -----------------------------------------------------------------------------------------
    @property
    def present(self) -> np.ndarray:
        """(N,) slots in the world now (active vehicles and all pedestrians)."""
        if not self.np_:  # slot i is vehicle row i
            return self.vehicles.active.copy()
        out = np.ones(self.n, dtype=bool)
        out[self.vehicle_slots] = self.vehicles.active
        return out

    def poses(self) -> np.ndarray:
        """(N,3) [m, m, rad] x, y, yaw of every slot now (inactive slots are below the ground)."""
        return np.column_stack([self.now.pos[:, :2], self.now.yaw])

    def positions(self) -> np.ndarray:
        """(N,2) [m] x, y of every slot now (read-only view)."""
        view = self.now.pos[:, :2]
        view.flags.writeable = False
        return view

    def speeds(self) -> np.ndarray:
        """(N,) [m/s] speed of every slot now (0 for inactive slots)."""
        return self.now.speed.copy()

    def yaws(self) -> np.ndarray:
        """(N,) [rad] heading of every slot now."""
        return self.now.yaw.copy()

    def intentions(self) -> np.ndarray:
        """(N, 4) intention of every slot by scenario (columns `intentions.SCENARIOS`; -1 for pedestrians)."""
        if not self.np_:  # slot i is vehicle row i
            return self.vehicles.intention.copy()
        out = np.full((self.n, len(SCENARIOS)), -1, dtype=np.int64)
        out[self.vehicle_slots] = self.vehicles.intention
        return out

    def indicators(self) -> np.ndarray:
        """(N,) the lane-change indicator each slot shows now: +1 left, -1 right, 0 none (pedestrians: 0)."""
        out = np.zeros(self.n, dtype=np.int64)
        v = self.vehicles
        intended = v.intention[:, LANE_CHANGE]
        on = (v.lc_signal >= 0.0) & v.active
        out[v.slot] = np.where(on & (intended == LEFT), 1, np.where(on & (intended == RIGHT), -1, 0))
        return out

    def velocities(self) -> np.ndarray:
        """(N,2) [m/s] world velocity of every slot now."""
        return self.now.speed[:, None] * np.column_stack([np.cos(self.now.yaw), np.sin(self.now.yaw)])

    def leader(self, path: Sequence[int], s: float) -> tuple[float, float]:
        """The nearest vehicle ahead of the point s [m] along the lanes `path` (lane ids, the point's lane first; the
        first PATH count): the distance [m] from the point to its rear bumper and its speed [m/s]; (inf, 0.0) when
        none is on them. The ego is not counted (the point stands in for it)."""
        agents = state.agents_on_paths(self.vehicles, np.asarray(path, dtype=np.int64)[:PATH], float(s), 0.0, 0.0, 0.0,
                                       self.map.length, self.map.n_lanes)
        return path_leader(agents, self.nv)

    def queued(self, gap: float = QUEUE_GAP, speed: float = QUEUE_SPEED) -> np.ndarray:
        """(NV,) vehicles in a queue: within `gap` [m] (bumper to bumper) behind a leader on their path that moves
        slower than `speed` [m/s] (the ego counts as a leader). A stopped vehicle that is not queued waits on its
        own: at a give-way or yield line, for a pedestrian, or stuck."""
        return queued_rows(self.agents(), self.nv, float(gap), float(speed)) & self.vehicles.active

    def stopped(self, speed: float = STOPPED_SPEED) -> np.ndarray:
        """(NV,) active vehicles slower than `speed` [m/s] now."""
        return self.vehicles.active & (self.now.speed[self.vehicle_slots] < speed)

    def give_way(self, ego: EgoState) -> GiveWay:
        """What the urban rules (`conflicts.zone_stops`, the rules every vehicle obeys) ask of the ego now: the
        give-way line it must wait at, and the vehicle it must merge behind. Needs ego.path and urban rules (a map
        with conflict zones); without either, nothing is asked."""
        if ego.path is None or not len(self.approaches):
            return GiveWay(np.inf, np.inf, 0.0)
        self.ego = ego
        agents = self.agents()
        followers = self._ego_followers(ego, agents, 8.0, 2.0, 3.0, 1.5)
        control = self._control_gaps(agents)
        stop, gap, speed = ego_give_way(followers, agents, self.vehicles, self.approaches, self.now.pos, self.constants,
                                        control)
        return GiveWay(min(stop, float(control[self.nv])), gap, speed)

    def _ego_followers(self, ego: EgoState, agents: Agents, desired_speed: float, accel: float, decel: float,
                       headway: float) -> Followers:
        """The ego as the one follower (`state.Followers`) of the traffic's rules: the last row of `agents`."""
        one = lambda value: np.array([value], dtype=float)  # noqa: E731
        return Followers(np.array([self.nv]), agents.path[-1:], agents.offset[-1:], one(ego.s),
                         one(max(ego.speed, 0.0)), one(desired_speed), one(ego.length), one(ego.width), one(accel),
                         one(decel), one(headway), np.array([[ego.x, ego.y]], dtype=float), one(ego.yaw),
                         np.zeros(1, dtype=bool))

    def advise(self, ego: EgoState, accel: float = 2.0, decel: float = 3.0, headway: float = 1.5,
               desired_speed: float = 8.0, accept_gap: float | None = None) -> float:
        """The acceleration [m/s^2] traffic's own rules give the ego (a privileged autopilot): IDM behind
        leaders and the corridor, stops for pedestrians, and gap acceptance at merges. Needs ego.path."""
        if ego.path is None:
            raise ValueError("advise needs the ego's lane path")
        self.ego = ego
        agents = self.agents()
        followers = self._ego_followers(ego, agents, desired_speed, accel, decel, headway)
        accel_ego, _ = self._accelerations(followers, agents,
                                           self.config.accept_gap if accept_gap is None else accept_gap)
        return float(accel_ego[0])
