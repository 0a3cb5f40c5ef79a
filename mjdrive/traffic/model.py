"""The traffic model: kinematic traffic on a lane graph, all road users as numpy arrays (no loop per user).

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
    line is still coming in.
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
at once, and `advance` (called every substep, e.g. by `Physics.substep_callback`) writes the poses of the
current substep into mocap_pos / mocap_quat. Seeded by the np.random.Generator given to `reset`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import mujoco
import numpy as np

from mjdrive.compiled import announce_compilation
from mjdrive.roads import RoadMap
from mjdrive.roads.conflicts import ConflictZones
from mjdrive.traffic import kernels, state_kernels
from mjdrive.traffic.conflicts import ApproachTable, conflict_columns
from mjdrive.traffic.following import accelerations, follower_table
from mjdrive.traffic.geometry import smoothstep, yaw_quat
from mjdrive.traffic.intentions import (
    AFTER,
    BEFORE,
    CROSSROAD,
    LANE_CHANGE,
    LEFT,
    RIGHT,
    ROUNDABOUT,
    SCENARIOS,
    LaneRoles,
    note_ring_progress,
    successor_preference,
)
from mjdrive.traffic.kernels import KERNELS
from mjdrive.traffic.lane_changes import lane_changes
from mjdrive.traffic.lanes import TrafficMap
from mjdrive.traffic.params import (
    HIDDEN_Z,
    KIND_INDEX,
    N_TRACKS,
    PATH,
    ROAD_USER_TYPES,
    EgoState,
    TrafficConfig,
)
from mjdrive.traffic.pedestrians import commit_pedestrians, pedestrian_poses, pedestrian_starts
from mjdrive.traffic.spawning import SpawnPoints, activate, spawn

_NO_PATH = np.zeros(0, dtype=np.int64)
WAITING_SPEED = 1.0  # [m/s] a vehicle slower than this is waiting (urban rules: its patience runs down)

class GiveWay(NamedTuple):
    """What the urban rules ask of the ego (`Traffic.give_way`)."""

    stop: float  # [m] front bumper to the give-way line where it must wait now (inf: it may go)
    leader_gap: float  # [m] front bumper to the rear of the vehicle it merges behind (inf: none)
    leader_speed: float  # [m/s] that vehicle's speed


@dataclass
class _Plan:
    """Poses of every slot at the substeps of one decision period."""

    pos: np.ndarray  # (S, N, 3) [m]
    quat: np.ndarray  # (S, N, 4)
    yaw: np.ndarray  # (S, N) [rad]
    speed: np.ndarray  # (S, N) [m/s]


class Traffic:
    """All road users of one world. `kinds` gives each slot's kind (in the order of the model's
    `traffic_{i}` bodies); the count of active users per kind is the slot count (minus users that just
    left the map and wait to respawn)."""

    def __init__(self, road_map: RoadMap | TrafficMap, kinds: Sequence[str],
                 config: TrafficConfig | None = None, conflicts: ConflictZones | None = None,
                 spawn_points: SpawnPoints | None = None):
        """`conflicts` (the map's conflict-zone table, `roads.conflict_zones`) switches on the urban rules:
        right of way at every crossing and merge of the table, intentions, intention-driven lane changes
        with a signalling phase; without it, entries yield at merges by gap acceptance (the roundabout)."""
        self.config = cfg = config or TrafficConfig()
        announce_compilation()
        self.map = road_map if isinstance(road_map, TrafficMap) else TrafficMap(road_map, cfg.lateral_accel)
        self.urban = conflicts is not None
        self.zones = conflicts
        self.roles = LaneRoles.of(self.map.road_map) if self.urban else None
        no_roles = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool), np.zeros(0, dtype=bool))
        self._roles_arrays = (self.roles.turn, self.roles.ring, self.roles.ring_exit) if self.urban else no_roles
        self.approaches = (ApproachTable.from_zones(conflicts, self.map.road_map, self.roles.ring) if self.urban
                           else None)
        self.ego_exit = -1  # the ego's ring exit lane (roundabout intentions), see `set_ego_route`
        self.spawn_points = spawn_points
        self._spawn_places: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # spawning._places
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
        self._vehicles_only = self.np_ == 0  # then slot i is vehicle row i
        vt = [types[i] for i in self.vehicle_slots]
        self._vtypes = vt
        self.length = 2 * self.half_size[self.vehicle_slots, 0]  # [m]
        self.width = 2 * self.half_size[self.vehicle_slots, 1]  # [m]
        self.a_max = np.array([t.accel for t in vt])
        self.b_comf = np.array([t.decel for t in vt])
        self.headway = np.array([t.headway for t in vt])
        self._speed_range = np.array([t.speed for t in vt]).reshape(-1, 2)
        self._lateral_range = np.array([t.lateral for t in vt]).reshape(-1, 2)
        self._walk_range = np.array([types[i].speed for i in self.pedestrian_slots]).reshape(-1, 2)
        if self.np_ and self.map.n_crosswalks == 0:
            raise ValueError("pedestrians need a road map with crosswalks")
        if self.np_ > N_TRACKS * max(self.map.n_crosswalks, 1):
            raise ValueError(f"at most {N_TRACKS} pedestrians per crosswalk "
                             f"({N_TRACKS * self.map.n_crosswalks} on this map), got {self.np_}")
        self.ped_cw = np.arange(self.np_) % max(self.map.n_crosswalks, 1)
        tracks = (np.arange(self.np_) // max(self.map.n_crosswalks, 1)) % N_TRACKS
        if self.map.n_crosswalks:
            self.ped_offset = (tracks - 1.0) * self.map.cw_width[self.ped_cw] / N_TRACKS  # [m] along the road
        else:
            self.ped_offset = np.zeros(0)
        m = self.map
        if self.np_:
            cw = self.ped_cw
            self._ped_end = m.cw_half_length[cw] + cfg.kerb  # [m] kerb position along the crosswalk
            self._ped_centre, self._ped_along = m.cw_centre[cw], m.cw_along[cw]
            self._ped_side = self.ped_offset[:, None] * m.cw_across[cw]
            self._ped_heading = m.cw_heading[cw]
        self.n_plan = max(1, int(round(cfg.decision_period / cfg.substep)))
        self._t_plan = cfg.substep * np.arange(1, self.n_plan + 1)  # [s]
        self._hidden = np.column_stack([np.zeros(self.n), np.zeros(self.n), HIDDEN_Z - 5.0 * np.arange(self.n)])
        self._hidden_vehicles = self._hidden[self.vehicle_slots]  # [m] (NV, 3)
        self._vehicle_rows = np.arange(self.nv)
        self.mocap_ids: np.ndarray | None = None
        self._mocap: slice | np.ndarray | None = None  # where the slots are in data.mocap_*
        self._views = None  # (data, its mocap_pos and mocap_quat rows (views), their index) of the last `write`
        self.cpu_time = 0.0  # [s] wall time spent in `advance` (for benchmarks)
        self.stats = {"spawned": 0, "despawned": 0, "lane_changes": 0}
        self.generation = np.zeros(self.n, dtype=np.int64)  # per slot: +1 each time a road user (re)enters
        self.ego: EgoState | None = None
        self._obstacle_cache = None
        self._gap_constants: tuple | None = None  # following._gap_constants
        self._ctx_s, self._ctx_v, self._ctx_len = np.zeros(self.nv + 1), np.zeros(self.nv + 1), np.zeros(self.nv + 1)
        self._den = 2.0 * np.sqrt(self.a_max * self.b_comf)  # [m/s^2] IDM's 2 sqrt(a b) (following.accelerations)
        self._b_agents = np.append(self.b_comf, 3.0)  # [m/s^2] comfortable deceleration, the ego last
        self._row_base = np.arange(self.nv) * PATH
        self._slot_row = np.full(self.n, -1, dtype=np.int64)  # vehicle row of each slot (-1: pedestrian)
        self._slot_row[self.vehicle_slots] = np.arange(self.nv)
        self.rng = np.random.default_rng(0)
        self.intent_rng = np.random.default_rng(1)
        self._reset_state()

    def set_ego_route(self, route: Sequence[int] | None) -> None:
        """The ego's route (lane ids): roundabout intentions are relative to its ring exit."""
        self.ego_exit = -1
        if self.urban and route is not None:
            exits = [lane for lane in route if self.roles.ring_exit[lane]]
            self.ego_exit = int(exits[0]) if exits else -1

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
        contiguous = not ids or np.array_equal(self.mocap_ids, np.arange(ids[0], ids[0] + self.n))
        self._mocap = slice(ids[0] if ids else 0, (ids[0] if ids else 0) + self.n) if contiguous else self.mocap_ids
        self._views = None

    def _reset_state(self) -> None:
        nv, npd = self.nv, self.np_
        self.active = np.zeros(nv, dtype=bool)
        self.path = np.full((nv, PATH), -1, dtype=np.int64)
        self.s = np.zeros(nv)  # [m] along path[:, 0]
        self.v = np.zeros(nv)  # [m/s]
        self.v0 = np.zeros(nv)  # [m/s] desired speed
        self.d_pref = np.zeros(nv)  # [m] preferred lateral offset
        self.lc_shift = np.zeros(nv)  # [m] lateral offset left to remove by the current lane change
        self.lc_dist = np.full(nv, 1e9)  # [m] distance driven since the lane change began
        self.accel = np.zeros(nv)  # [m/s^2] of the current decision period
        self.lead_gap = np.zeros(nv)  # [m] to the nearest obstacle ahead at the last decision
        self.ped_u = np.zeros(npd)  # [m] position along the crosswalk
        self.ped_dir = np.ones(npd)  # +1 / -1: walking direction along the crosswalk
        self.ped_walking = np.zeros(npd, dtype=bool)
        self.ped_wait = np.zeros(npd)  # [s] left to wait at the kerb before looking for a gap
        self.ped_speed = np.zeros(npd)  # [m/s]
        self.intention = np.zeros((nv, len(SCENARIOS)), dtype=np.int64)  # see intentions.py
        self.ring_passed = np.zeros(nv, dtype=bool)  # planned path went past the ego's exit
        self.lc_signal = np.full(nv, -1.0)  # [s] time the lane-change signal came on (-1: off)
        self.lc_changing = np.zeros(nv, dtype=bool)  # an intended lane change under way
        self.stopped_time = np.zeros(nv)  # [s] since the vehicle last moved (at decisions)
        self.time = 0.0  # [s]
        self._plan: _Plan | None = None
        self._k = 0  # index of the current substep in the plan
        self._accumulated = 0.0
        self._current_pos = self._hidden.copy()
        self._current_yaw = np.zeros(self.n)
        self._current_quat = yaw_quat(self._current_yaw)
        self._current_speed = np.zeros(self.n)

    def _choose_successor(self, lane: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """A uniformly random successor of each lane (-1 for a dead end or -1); with urban rules, one that
        honours the intentions of vehicles `rows` (whose paths `lane` belongs to)."""
        m = self.map
        intended = self.urban and rows is not None and len(rows)
        if KERNELS and intended:  # the same in one compiled pass
            roles = self.roles
            return kernels.choose_successors(
                rows, lane, self.rng.random(len(lane)), m.successors, roles.turn, roles.ring, roles.ring_exit,
                self.intention, self.ring_passed, int(self.ego_exit), CROSSROAD, ROUNDABOUT, BEFORE, AFTER)
        if KERNELS:
            return state_kernels.random_successors(lane, self.rng.random(len(lane)), m.successors, m.n_successors)
        valid = lane >= 0
        lane0 = np.maximum(lane, 0)
        if intended:
            allowed = successor_preference(self, rows, lane)  # (K, W)
            count = allowed.sum(axis=1) * valid
            pick = np.floor(self.rng.random(len(lane)) * np.maximum(count, 1)).astype(np.int64)
            column = np.argmax(np.cumsum(allowed, axis=1) > pick[:, None], axis=1)
            chosen = np.where(count > 0, m.successors[lane0, column], -1)
            note_ring_progress(self, rows, lane, chosen)
            return chosen
        count = np.where(valid, m.n_successors[lane0], 0)
        pick = np.floor(self.rng.random(len(lane)) * np.maximum(count, 1)).astype(np.int64)
        return np.where(count > 0, m.successors[lane0, np.minimum(pick, m.successors.shape[1] - 1)], -1)

    def _fill_path(self, rows: np.ndarray, start: int = 1) -> None:
        """Random successors for path[rows, start:]."""
        for k in range(start, PATH):  # loop over path depth, not over road users
            self.path[rows, k] = self._choose_successor(self.path[rows, k - 1], rows)

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
        free = np.ones(len(m.spawn_lane), dtype=bool)
        if ego is not None:
            free &= np.hypot(m.spawn_xy[:, 0] - ego.x, m.spawn_xy[:, 1] - ego.y) >= keep_clear
        points = np.flatnonzero(free)
        n_place = min(int(round(density * self.nv)), len(points))
        chosen = rng.permutation(points)[:n_place]
        rows = rng.permutation(self.nv)[:n_place]
        activate(self, rows, m.spawn_lane[chosen], m.spawn_s[chosen], speed_share=rng.uniform(0.3, 1.0, n_place))
        if self.np_:
            self.ped_dir = rng.choice([-1.0, 1.0], self.np_)
            self.ped_u = -self.ped_dir * (m.cw_half_length[self.ped_cw] + self.config.kerb)
            self.ped_wait = rng.uniform(0.0, self.config.pedestrian_wait[1], self.np_)
            self.ped_speed = rng.uniform(self._walk_range[:, 0], self._walk_range[:, 1])
        self._current_pos, self._current_yaw, self._current_speed = self._poses_now()
        self._current_quat = yaw_quat(self._current_yaw)
        steps = int(round(warmup / self.config.decision_period))
        for _ in range(steps):
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
        m = self.map
        self._settle()
        lanes = [int(x) for x in path][:PATH]
        self.generation[self.vehicle_slots[row]] += 1
        self.active[row] = True
        self.intention[row] = 0
        for name, value in (intentions or {}).items():
            if name not in SCENARIOS:
                raise ValueError(f"unknown intention scenario {name!r}; valid: {', '.join(SCENARIOS)}")
            self.intention[row, SCENARIOS.index(name)] = int(value)
        self.ring_passed[row], self.lc_signal[row], self.lc_changing[row] = False, -1.0, False
        self.path[row] = -1
        self.path[row, : len(lanes)] = lanes
        if len(lanes) < PATH:
            self._fill_path(np.array([row]), start=len(lanes))
        self.s[row], self.v[row] = s, speed
        self.v0[row] = m.speed_limit[lanes[0]] if desired_speed is None else desired_speed
        self.d_pref[row], self.lc_shift[row], self.lc_dist[row] = lateral, 0.0, 1e9
        self.accel[row] = 0.0
        self._restart()

    def place_pedestrian(self, row: int, u: float, direction: float, walking: bool = True,
                         speed: float = 1.3) -> None:
        """Put pedestrian `row` (index among the pedestrian slots) at u [m] along its crosswalk, walking (or
        waiting) in `direction` (+1 / -1 along the crosswalk) at `speed` [m/s]."""
        self._settle()
        self.ped_u[row], self.ped_dir[row] = u, float(np.sign(direction) or 1.0)
        self.ped_walking[row], self.ped_speed[row] = walking, speed
        self.ped_wait[row] = 1e9 if not walking else 0.0
        self._restart()

    def remove_all(self) -> None:
        """Take every vehicle off the map (pedestrians stay)."""
        self._settle()
        self.active[:] = False
        self.v[:] = 0.0
        self._restart()

    def _settle(self) -> None:
        """Make the present substep the state and drop the rest of the plan (before editing the state)."""
        if self._plan is not None and self._k > 0:
            self._commit(self._k - 1)
        self._plan = None
        self._k = 0

    def _restart(self) -> None:
        """After an edit: the next `advance` decides from the edited present state."""
        self._obstacle_cache = None
        self._current_pos, self._current_yaw, self._current_speed = self._poses_now()
        self._current_quat = yaw_quat(self._current_yaw)

    # --- stepping --------------------------------------------------------------------------------------
    def advance(self, dt: float, ego: Callable[[], EgoState | None] | None = None,
                data: mujoco.MjData | None = None) -> None:
        """Move every road user by `dt` [s] (a whole number of substeps, usually one) and write the new
        poses into `data`'s mocap arrays if given. `ego` is called at each decision for the ego's state."""
        start = time.perf_counter()
        substep = self.config.substep
        accumulated = self._accumulated + dt
        n = int(accumulated / substep + 1e-6)
        self._accumulated = accumulated - n * substep
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
            plan, k = self._plan, self._k - 1
            self._current_pos, self._current_yaw = plan.pos[k], plan.yaw[k]
            self._current_speed, self._current_quat = plan.speed[k], plan.quat[k]
        if data is not None:
            self.write(data)
        self.cpu_time += time.perf_counter() - start

    def pose_cursor(self) -> tuple[np.ndarray, np.ndarray, int, int, float, float, float] | None:
        """Where `advance` stands in the plan, for a compiled loop that takes its plain substeps
        (`tasks.chunks`): the plan's positions (S, N, 3) [m] and quaternions (S, N, 4), the substeps taken of
        it and their count S, the time [s] accumulated toward the next substep, the substep [s] and the traffic's
        time [s]; None without a plan (the next substep decides)."""
        plan = self._plan
        if plan is None:
            return None
        return plan.pos, plan.quat, self._k, self.n_plan, self._accumulated, self.config.substep, self.time

    def moved(self, k: int, accumulated: float, time: float) -> None:
        """The compiled loop took the plan's substeps up to k (of `pose_cursor`), leaving `accumulated` [s] toward
        the next, at traffic time `time` [s], and wrote their poses: the state `advance` would have left."""
        if k != self._k:
            plan, i = self._plan, k - 1
            self._current_pos, self._current_yaw = plan.pos[i], plan.yaw[i]
            self._current_speed, self._current_quat = plan.speed[i], plan.quat[i]
        self._k, self._accumulated, self.time = k, accumulated, time

    def write(self, data: mujoco.MjData) -> None:
        """Write the current poses into data.mocap_pos / mocap_quat."""
        if self._mocap is None:
            raise RuntimeError("call Traffic.bind(model) before writing poses")
        views = self._views
        if views is None or views[0] is not data:  # views into data's arrays: kept (the slots' rows, when contiguous)
            if isinstance(self._mocap, slice):
                views = self._views = (data, data.mocap_pos[self._mocap], data.mocap_quat[self._mocap], Ellipsis)
            else:
                views = self._views = (data, data.mocap_pos, data.mocap_quat, self._mocap)
        views[1][views[3]] = self._current_pos
        views[2][views[3]] = self._current_quat

    def _commit(self, k: int = -1) -> None:
        """Make the plan's substep k (default: its end) the new state."""
        t_end = self._t_plan[k]
        v, a = self.v, self.accel
        if KERNELS:  # the same numbers in one compiled pass
            self.v = state_kernels.commit_vehicles(v, a, self.active, t_end, t_end**2, self.s, self.lc_dist)
        else:
            stop = (a < 0) & (v + a * t_end < 0)
            ds = np.where(stop, v * v / np.maximum(-2 * a, 1e-9), v * t_end + 0.5 * a * t_end**2)
            ds = np.where(self.active, ds, 0.0)
            self.s += ds
            self.lc_dist += ds
            self.v = np.where(self.active, np.maximum(v + a * t_end, 0.0), 0.0)
        if self.np_:
            commit_pedestrians(self, t_end)
        self._current_pos = self._plan.pos[k]
        self._current_yaw = self._plan.yaw[k]
        self._current_speed = self._plan.speed[k]
        self._current_quat = self._plan.quat[k]
        self._plan = None

    # --- decisions -------------------------------------------------------------------------------------
    def _decide(self) -> None:
        """New accelerations, lane changes, spawns and pedestrian starts; then the plan of poses."""
        self._obstacle_cache = None
        if self.urban:
            self._count_waiting()
        self._advance_lanes()
        if spawn(self):
            self._refresh_vehicle_poses()
        lane_changes(self)
        ctx = self._context()
        if self.np_:
            pedestrian_starts(self, ctx)
        self.accel = np.where(self.active, accelerations(self, follower_table(self, ctx), ctx), 0.0)
        self._plan = self._make_plan(ctx["start"][: self.nv])

    def _count_waiting(self) -> None:
        """Waiting times [s] one decision period on (`state_kernels.waiting_times` with numba: the same)."""
        if KERNELS:
            self.stopped_time = state_kernels.waiting_times(self.stopped_time, self.active, self.v,
                                                            self.config.decision_period, WAITING_SPEED)
            return
        # creeping up to a give-way line (slower than WAITING_SPEED) does not reset it
        self.stopped_time = np.where(self.active & (self.v < WAITING_SPEED),
                                     self.stopped_time + self.config.decision_period, 0.0)

    def _advance_lanes(self) -> None:
        """Vehicles past the end of their lane move on along their path (or leave the map at dead ends)."""
        if KERNELS:  # the same, a round per compiled pass (the successors' draws stay here)
            m = self.map
            rows, gone = state_kernels.lanes_passed(self.s, self.path, self.active, self.v, m.length)
            while len(rows):
                self.stats["despawned"] += gone
                rows, gone = state_kernels.successors_then_lanes_passed(
                    rows, self.rng.random(len(rows)), self.urban, m.successors, m.n_successors, *self._roles_arrays,
                    self.intention, self.ring_passed, int(self.ego_exit), CROSSROAD, ROUNDABOUT, BEFORE, AFTER, self.s,
                    self.path, self.active, self.v, m.length)
            return
        while True:
            over = self.active & (self.s >= self.map.length[np.maximum(self.path[:, 0], 0)])
            if not over.any():
                return
            rows = np.flatnonzero(over)
            self.s[rows] -= self.map.length[self.path[rows, 0]]
            self.path[rows, :-1] = self.path[rows, 1:]
            self.path[rows, -1] = self._choose_successor(self.path[rows, -2], rows)
            gone = rows[self.path[rows, 0] < 0]
            if len(gone):
                self.active[gone] = False
                self.v[gone] = 0.0
                self.stats["despawned"] += len(gone)

    def _context(self) -> dict:
        """Lane-graph rows of the vehicles and the ego (last row) shared by one decision: current lane,
        s [m], speed [m/s], length [m], path (A, PATH), and `offset` (A, L): the distance [m] from the start
        of each agent's current lane to the start of every lane on its path (inf for lanes off its path),
        so that a point (lane, s) lies offset[:, lane] + s ahead of the start of each agent's lane."""
        ego, nv = self.ego, self.nv
        if KERNELS:  # the same tables in one compiled pass
            ego_path, ego_s, ego_v, ego_length = _NO_PATH, 0.0, 0.0, 0.0
            if ego is not None:
                ego_v, ego_length = max(ego.speed, 0.0), ego.length
                if ego.path is not None and len(ego.path) and ego.path[0] >= 0:
                    ego_path, ego_s = np.asarray(ego.path[:PATH], dtype=np.int64), ego.s
            path, start, offset, s, v, length = kernels.path_context(
                self.path, self.active, ego_path, self.map.length, self.map.n_lanes, self.s, self.v, self.length,
                ego_s, ego_v, ego_length)
            return {"lane": path[:, 0], "s": s, "v": v, "length": length, "path": path, "start": start,
                    "offset": offset}
        s, v, length = self._ctx_s, self._ctx_v, self._ctx_len
        s[:nv], v[:nv], length[:nv] = self.s, self.v, self.length
        s[nv] = v[nv] = length[nv] = 0.0
        ego_path = _NO_PATH
        if ego is not None:
            v[nv], length[nv] = max(ego.speed, 0.0), ego.length
            if ego.path is not None and len(ego.path) and ego.path[0] >= 0:
                ego_path = np.asarray(ego.path[:PATH], dtype=np.int64)
                s[nv] = ego.s
        path = np.full((nv + 1, PATH), -1, dtype=np.int64)
        path[:nv] = self.path
        path[:nv][~self.active] = -1
        path[nv, : len(ego_path)] = ego_path
        plen = np.where(path >= 0, self.map.length[path], np.inf)
        start = np.zeros((nv + 1, PATH))
        np.cumsum(plen[:, :-1], axis=1, out=start[:, 1:])
        offset = np.full((nv + 1, self.map.n_lanes + 1), np.inf)  # column -1 collects the -1 lanes
        rows = np.repeat(np.arange(nv + 1), PATH)
        offset[rows, path[:, ::-1].ravel()] = start[:, ::-1].ravel()  # reversed: the nearest occurrence wins
        offset[:, -1] = np.inf
        return {"lane": path[:, 0], "s": s.copy(), "v": v.copy(), "length": length.copy(), "path": path,
                "start": start, "offset": offset}

    # --- accelerations -----------------------------------------------------------------------------------
    # --- poses -------------------------------------------------------------------------------------------
    def _make_plan(self, start: np.ndarray | None = None) -> _Plan:
        """Poses of every slot at the substeps of the next decision period (`start`: distance (NV, PATH) [m]
        to the start of each path lane, if known)."""
        t = self._t_plan[:, None]  # (S, 1)
        if KERNELS:  # the same numbers in one compiled pass
            m = self.map
            ds, x, y, h = kernels.plan_centre_poses(
                self.v, self.accel, self._t_plan, self.s, self._path_starts() if start is None else start, self.path,
                m.base, m.length, m.first, m.last_segment, m.g, m._inv, m._x0, m._dx, m._y0, m._dy, m._h0, m._dh)
        else:
            v, a = self.v[None], self.accel[None]
            stopped = (a < 0) & (v + a * t < 0)
            ds = np.where(stopped, v * v / np.maximum(-2 * a, 1e-9), v * t + 0.5 * a * t * t)  # (S, NV)
            x, y, h = self._centre_poses(ds, start)
        out_pos = np.empty((len(t), self.n, 3))
        out_yaw = np.empty((len(t), self.n))
        out_speed = np.zeros((len(t), self.n))
        vs = self.vehicle_slots
        if KERNELS:
            d, yaw = self._lateral(ds, h)
            kernels.place_vehicles(x, y, h, d, yaw, self.v, self.accel, self._t_plan, self.active,
                                   self._hidden_vehicles, vs, out_pos, out_yaw, out_speed)
        else:
            out_pos[:, vs], out_yaw[:, vs] = self._offset_poses(ds, x, y, h)
            out_speed[:, vs] = np.maximum(v + a * t, 0.0) * self.active[None]
        if self.np_ and KERNELS:
            state_kernels.place_pedestrians(self.ped_u, self.ped_dir, self.ped_speed, self.ped_walking, self._ped_end,
                                            self._ped_centre, self._ped_along, self._ped_side, self._ped_heading, t,
                                            self.pedestrian_slots, out_pos, out_yaw, out_speed)
        elif self.np_:
            ps = self.pedestrian_slots
            out_pos[:, ps], out_yaw[:, ps], out_speed[:, ps] = pedestrian_poses(self, t)
        return _Plan(out_pos, kernels.yaw_quats(out_yaw) if KERNELS else yaw_quat(out_yaw), out_yaw, out_speed)

    def _vehicle_poses(self, ds: np.ndarray, before: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Poses (S, NV, 3), yaw (S, NV) of the vehicles after moving ds (S, NV) [m] along their paths
        (`before`: distance (NV, PATH) [m] to the start of each path lane, if known)."""
        if KERNELS:  # placed as in `_make_plan`
            x, y, h = self._centre_poses(ds, before)
            d, yaw = self._lateral(ds, h)
            pos, out_yaw = np.empty(ds.shape + (3,)), np.empty(ds.shape)
            kernels.place_vehicles(x, y, h, d, yaw, self.v, self.accel, self._t_plan, self.active,
                                   self._hidden_vehicles, self._vehicle_rows, pos, out_yaw, np.empty(ds.shape))
            return pos, out_yaw
        return self._offset_poses(ds, *self._centre_poses(ds, before))

    def _path_starts(self) -> np.ndarray:
        """(NV, PATH) [m] from each vehicle's lane start to the start of each lane on its path (inf past its end)."""
        if KERNELS:
            return state_kernels.path_starts(self.path, self.map.length)
        before = np.zeros((self.nv, PATH))
        path = self.path
        np.cumsum(np.where(path[:, :-1] >= 0, self.map.length[path[:, :-1]], np.inf), axis=1, out=before[:, 1:])
        return before

    def _centre_poses(self, ds: np.ndarray, before: np.ndarray | None = None):
        """Centre-line x, y [m] and heading [rad] (S, NV) of the vehicles' lanes after moving ds (S, NV) [m]."""
        if before is None:
            before = self._path_starts()
        path, m = self.path, self.map
        if KERNELS:  # the same numbers in one compiled pass
            return kernels.centre_poses(self.s, ds, before, path, m.base, m.length, m.first, m.last_segment, m.g,
                                        m._inv, m._x0, m._dx, m._y0, m._dy, m._h0, m._dh)
        p = self.s[None] + ds
        k = (p[..., None] >= before[None, :, 1:]).sum(-1)  # (S, NV) index into the path
        k = np.minimum(k, self._last_path_index()[None])  # stay on a dead end's last lane
        flat = self._row_base + k
        lane = np.maximum(path.ravel()[flat], 0)
        return m.lookup(lane, p - before.ravel()[flat])

    def _lateral(self, ds: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lateral offset d [m] (S or 1, NV) from the centre line and yaw [rad] (S, NV) after moving ds (S, NV) [m]
        (lane changes under way move across along a smoothstep; h: the centre line's heading)."""
        if (self.lc_dist < self.config.lane_change_length).any():  # lane changes under way
            sm, dsm = smoothstep((self.lc_dist[None] + ds) / self.config.lane_change_length)
            d = self.d_pref[None] + self.lc_shift[None] * (1.0 - sm)
            return d, h + np.arctan(-self.lc_shift[None] * dsm / self.config.lane_change_length)
        return self.d_pref[None], h

    def _offset_poses(self, ds: np.ndarray, x: np.ndarray, y: np.ndarray, h: np.ndarray):
        """Poses (S, NV, 3), yaw (S, NV) at the vehicles' lateral offsets (and lane changes under way) from
        the centre line x, y [m], heading h [rad] after moving ds (S, NV) [m]."""
        d, yaw = self._lateral(ds, h)
        pos = np.zeros(x.shape + (3,))
        pos[..., 0] = x - np.sin(h) * d
        pos[..., 1] = y + np.cos(h) * d
        if not self.active.all():
            hidden = ~self.active
            pos[:, hidden] = self._hidden[self.vehicle_slots[hidden]][None]
            yaw[:, hidden] = 0.0
        return pos, yaw

    def _last_path_index(self) -> np.ndarray:
        """(NV,) index of the last lane on each path (a dead end's lane when the path ends early)."""
        return np.maximum((self.path >= 0).sum(1) - 1, 0)

    def _refresh_vehicle_poses(self) -> None:
        """Current vehicle poses from the state (after spawns)."""
        pos, yaw = self._vehicle_poses(np.zeros((1, self.nv)))
        self._current_pos = self._current_pos.copy()
        self._current_yaw = self._current_yaw.copy()
        self._current_pos[self.vehicle_slots] = pos[0]
        self._current_yaw[self.vehicle_slots] = yaw[0]
        self._current_quat = yaw_quat(self._current_yaw)

    def _poses_now(self):
        """Poses of every slot at the current state (no plan)."""
        pos = self._hidden.copy()
        yaw = np.zeros(self.n)
        speed = np.zeros(self.n)
        vpos, vyaw = self._vehicle_poses(np.zeros((1, self.nv)))
        pos[self.vehicle_slots], yaw[self.vehicle_slots] = vpos[0], vyaw[0]
        speed[self.vehicle_slots] = np.where(self.active, self.v, 0.0)
        if self.np_:
            ppos, pyaw, pspeed = pedestrian_poses(self, np.zeros((1, 1)))
            pos[self.pedestrian_slots], yaw[self.pedestrian_slots] = ppos[0], pyaw[0]
            speed[self.pedestrian_slots] = pspeed[0]
        return pos, yaw, speed

    # --- queries -----------------------------------------------------------------------------------------
    @property
    def present(self) -> np.ndarray:
        """(N,) slots in the world now (active vehicles and all pedestrians)."""
        if self._vehicles_only:
            return self.active.copy()
        out = np.ones(self.n, dtype=bool)
        out[self.vehicle_slots] = self.active
        return out

    def poses(self) -> np.ndarray:
        """(N,3) [m, m, rad] x, y, yaw of every slot now (inactive slots are below the ground)."""
        return np.column_stack([self._current_pos[:, :2], self._current_yaw])

    def positions(self) -> np.ndarray:
        """(N,2) [m] x, y of every slot now (read-only view)."""
        view = self._current_pos[:, :2]
        view.flags.writeable = False
        return view

    def speeds(self) -> np.ndarray:
        """(N,) [m/s] speed of every slot now (0 for inactive slots)."""
        return self._current_speed.copy()

    def yaws(self) -> np.ndarray:
        """(N,) [rad] heading of every slot now."""
        return self._current_yaw.copy()

    def intentions(self) -> np.ndarray:
        """(N, 4) intention of every slot by scenario (columns `intentions.SCENARIOS`; -1 for pedestrians)."""
        if self._vehicles_only:
            return self.intention.copy()
        out = np.full((self.n, len(SCENARIOS)), -1, dtype=np.int64)
        out[self.vehicle_slots] = self.intention
        return out

    def indicators(self) -> np.ndarray:
        """(N,) the lane-change indicator each slot shows now: +1 left, -1 right, 0 none (pedestrians: 0)."""
        out = np.zeros(self.n, dtype=np.int64)
        intended = self.intention[:, LANE_CHANGE]
        on = (self.lc_signal >= 0.0) & self.active
        out[self.vehicle_slots] = np.where(on & (intended == LEFT), 1, np.where(on & (intended == RIGHT), -1, 0))
        return out

    def velocities(self) -> np.ndarray:
        """(N,2) [m/s] world velocity of every slot now."""
        return self._current_speed[:, None] * np.column_stack([np.cos(self._current_yaw),
                                                              np.sin(self._current_yaw)])

    def give_way(self, ego: EgoState) -> GiveWay:
        """What the urban rules (`conflicts.conflict_columns`, the rules every vehicle obeys) ask of the ego now:
        the give-way line it must wait at, and the vehicle it must merge behind. Needs ego.path and urban rules
        (a map with conflict zones); without either, nothing is asked."""
        if ego.path is None or self.approaches is None or not len(self.approaches):
            return GiveWay(np.inf, np.inf, 0.0)
        self.ego = ego
        self._obstacle_cache = None
        ctx = self._context()
        f = self._ego_follower(ego, ctx, self.config.accept_gap, np.array([ego.length]), np.array([3.0]),
                               np.array([1.5]), 8.0, 2.0)
        gap, lead, _, _ = conflict_columns(self, ctx, f)
        n_r = len(self.approaches)
        k = int(np.argmin(gap[0, n_r:]))
        return GiveWay(float(gap[0, :n_r].min()), float(gap[0, n_r + k]), float(lead[0, n_r + k]))

    def _ego_follower(self, ego: EgoState, ctx: dict, accept_gap: float, length: np.ndarray, decel: np.ndarray,
                      headway: np.ndarray, desired_speed: float, accel: float) -> dict:
        """The ego as the one follower of `following.accelerations` (the last row of `ctx`)."""
        return {"rows": np.array([self.nv]), "path": ctx["path"][-1:], "offset": ctx["offset"][-1:],
                "s": np.array([ego.s]), "v": np.array([max(ego.speed, 0.0)]), "v0": np.array([desired_speed]),
                "length": length, "width": np.array([ego.width]), "a": np.array([accel]), "b": decel,
                "T": headway, "xy": np.array([[ego.x, ego.y]]), "yaw": np.array([ego.yaw]),
                "accept_gap": accept_gap, "courteous": np.zeros(1, dtype=bool)}

    def advise(self, ego: EgoState, accel: float = 2.0, decel: float = 3.0, headway: float = 1.5,
               desired_speed: float = 8.0, accept_gap: float | None = None) -> float:
        """The acceleration [m/s^2] traffic's own rules give the ego (a privileged autopilot): IDM behind
        leaders and the corridor, stops for pedestrians, and gap acceptance at merges. Needs ego.path."""
        if ego.path is None:
            raise ValueError("advise needs the ego's lane path")
        self.ego = ego
        self._obstacle_cache = None
        ctx = self._context()
        f = self._ego_follower(ego, ctx, self.config.accept_gap if accept_gap is None else accept_gap,
                               np.array([ego.length]), np.array([decel]), np.array([headway]), desired_speed, accel)
        return float(accelerations(self, f, ctx)[0])
