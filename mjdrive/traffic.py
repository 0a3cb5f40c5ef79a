"""Kinematic traffic on a road map's lane graph, all road users as numpy arrays (no Python loop per user).

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

import mujoco
import numpy as np

from mjdrive.config import Config, ConfigError, param
from mjdrive.roads import RoadMap
from mjdrive.traffic_map import TrafficMap
from mjdrive.world import TrafficSlot

PATH = 4  # lanes held in each vehicle's planned path (the current one and the next three)
HIDDEN_Z = -50.0  # [m] where inactive slots wait (below the ground, never seen, never touched)
N_TRACKS = 3  # pedestrian tracks per crosswalk


@dataclass(frozen=True)
class RoadUserType:
    """A kind of road user: box half sizes [m], colour, desired speed range [m/s] (walking speed for
    pedestrians) and IDM parameters: max acceleration a [m/s^2], comfortable deceleration b [m/s^2],
    time headway T [s]; preferred lateral offset range in the lane [m] (> 0 left)."""

    name: str
    half_size: tuple[float, float, float]
    rgba: tuple[float, float, float, float]
    speed: tuple[float, float]
    accel: float = 1.5
    decel: float = 2.5
    headway: float = 1.0
    lateral: tuple[float, float] = (0.0, 0.0)

    @property
    def slot(self) -> TrafficSlot:
        return TrafficSlot(self.name, self.half_size, self.rgba)

    @property
    def is_vehicle(self) -> bool:
        return self.name != "pedestrian"


ROAD_USER_TYPES: dict[str, RoadUserType] = {
    "car": RoadUserType("car", (2.25, 0.9, 0.75), (0.75, 0.15, 0.12, 1.0), (6.5, 8.33), 1.5, 2.5, 1.0,
                        (-0.2, 0.2)),
    "motorcycle": RoadUserType("motorcycle", (1.1, 0.4, 0.7), (0.15, 0.15, 0.18, 1.0), (7.0, 8.33), 2.5, 3.0,
                               0.8, (-0.6, 0.6)),
    "bicycle": RoadUserType("bicycle", (0.9, 0.3, 0.85), (0.95, 0.75, 0.1, 1.0), (3.5, 5.5), 1.0, 2.0, 1.0,
                            (-0.9, -0.8)),
    "pedestrian": RoadUserType("pedestrian", (0.25, 0.3, 0.88), (0.2, 0.35, 0.75, 1.0), (1.1, 1.6)),
}  # fmt: skip
KIND_NAMES = tuple(ROAD_USER_TYPES)
KIND_INDEX = {name: i for i, name in enumerate(KIND_NAMES)}


@dataclass(frozen=True)
class TrafficConfig(Config):
    """Behaviour constants shared by every road user (validated; `TrafficConfig.from_dict` takes a dict)."""

    min_gap: float = param(2.5, "IDM s0: the study's safe distance to the vehicle ahead", "m", ge=0.5, le=20.0)
    stop_gap: float = param(0.5, "IDM s0 in front of a stop line", "m", ge=0.0, le=10.0)
    max_decel: float = param(8.0, "emergency braking limit", "m/s^2", gt=0.0, le=15.0)
    lateral_accel: float = param(2.0, "curve speed: v <= sqrt(lateral_accel / curvature)", "m/s^2", gt=0.0, le=10.0)
    accept_gap: float = param(3.5, "an entering vehicle goes if no priority vehicle reaches the merge sooner", "s",
                              ge=0.0, le=20.0)
    merge_clearance: float = param(5.0, "... and none is nearer than this (bumper to merge point)", "m",
                                   ge=0.0, le=50.0)
    merge_speed: float = param(3.0, "slower circulating vehicles count as this fast in the gap check", "m/s",
                               ge=0.0, le=20.0)
    yield_speed: float = param(2.5, "entering vehicles reach their yield line no faster than this", "m/s",
                               gt=0.0, le=20.0)
    corridor_range: float = param(25.0, "how far ahead the corridor check looks", "m", gt=0.0, le=100.0)
    corridor_margin: float = param(0.3, "lateral margin of the corridor", "m", ge=0.0, le=3.0)
    lane_change_rate: tuple[float, float] = param((0.5, 0.5), "lane changes to the right, to the left neighbour",
                                                  "1/s", ge=0.0, le=10.0)
    lane_change_length: float = param(15.0, "distance over which a lane change moves across", "m", gt=1.0, le=100.0)
    spawn_clear: float = param(14.0, "a source spawns only if nothing is this close to its start", "m",
                               ge=0.0, le=100.0)
    crosswalk_margin: float = param(1.0, "vehicles stop this far before a crosswalk / a pedestrian's band", "m",
                                    ge=0.0, le=10.0)
    kerb: float = param(0.9, "where pedestrians wait, beyond the end of the crosswalk", "m", ge=0.0, le=5.0)
    pedestrian_wait: tuple[float, float] = param((2.0, 10.0), "wait at the kerb before looking for a gap "
                                                 "(uniform, min and max)", "s", ge=0.0, le=120.0)
    respawn: bool = param(True, "vehicles that left the map re-enter at the sources")
    decision_period: float = param(0.6, "behaviour updates (about a driver's reaction time)", "s", gt=0.0, le=5.0)
    substep: float = param(0.02, "pose resolution (mocap written at this period)", "s", gt=0.0, le=0.2)

    def check(self) -> None:
        if self.pedestrian_wait[0] > self.pedestrian_wait[1]:
            raise ConfigError(f"pedestrian_wait={self.pedestrian_wait}: the minimum must not exceed the maximum")


@dataclass
class EgoState:
    """The ego as traffic sees it: pose [m, m, rad], speed [m/s], size [m], and optionally its place in
    the lane graph: `path` (lane ids from its current lane on, -1 padded) and `s` [m] along path[0]."""

    x: float
    y: float
    yaw: float
    speed: float
    length: float
    width: float
    path: np.ndarray | None = None
    s: float = 0.0


def counts_to_kinds(counts: dict[str, int]) -> list[str]:
    """Slot kinds from counts by kind, vehicles first in ROAD_USER_TYPES order, e.g. {"car": 2, ...}."""
    unknown = set(counts) - set(ROAD_USER_TYPES)
    if unknown:
        raise ValueError(f"unknown road-user kinds {sorted(unknown)}; valid: {', '.join(ROAD_USER_TYPES)}")
    return [name for name in ROAD_USER_TYPES for _ in range(int(counts.get(name, 0)))]


def slots(kinds: Sequence[str]) -> list[TrafficSlot]:
    """The world.TrafficSlot of each kind (for `world.build(traffic=...)`)."""
    return [ROAD_USER_TYPES[k].slot for k in kinds]


def _smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """3x^2 - 2x^3 on [0, 1] and its derivative."""
    x = np.minimum(np.maximum(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)


def _yaw_quat(yaw: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) (w, x, y, z) of rotations by yaw [rad] about z."""
    q = np.zeros(yaw.shape + (4,))
    half = 0.5 * yaw
    np.cos(half, out=q[..., 0])
    np.sin(half, out=q[..., 3])
    return q


def overlapping_pairs(poses: np.ndarray, half_sizes: np.ndarray, margin: float = 0.0) -> np.ndarray:
    """Pairs (K,2) of oriented rectangles (x, y, yaw) (N,3) [m, m, rad] with half sizes (N,>=2) [m] that
    overlap (separating-axis test; each rectangle grown by `margin` [m])."""
    n = len(poses)
    if n < 2:
        return np.zeros((0, 2), dtype=np.int64)
    i, j = np.triu_indices(n, 1)
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    axes = np.stack([np.stack([c, s], -1), np.stack([-s, c], -1)], 1)  # (N, 2 axes, 2)
    half = half_sizes[:, :2] + margin
    d = poses[j, :2] - poses[i, :2]
    separated = np.zeros(len(i), dtype=bool)
    for owner in (i, j):
        for k in range(2):
            axis = axes[owner, k]
            ri = np.abs(np.einsum("pa,pba->pb", axis, axes[i])) * half[i]
            rj = np.abs(np.einsum("pa,pba->pb", axis, axes[j])) * half[j]
            separated |= np.abs(np.einsum("pa,pa->p", d, axis)) > ri.sum(1) + rj.sum(1)
    return np.stack([i[~separated], j[~separated]], 1)


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
                 config: TrafficConfig | None = None):
        self.config = cfg = config or TrafficConfig()
        self.map = road_map if isinstance(road_map, TrafficMap) else TrafficMap(road_map, cfg.lateral_accel)
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
        self.mocap_ids: np.ndarray | None = None
        self._mocap: slice | np.ndarray | None = None  # where the slots are in data.mocap_*
        self._views = None  # (data, data.mocap_pos, data.mocap_quat) of the last `write`
        self.cpu_time = 0.0  # [s] wall time spent in `advance` (for benchmarks)
        self.stats = {"spawned": 0, "despawned": 0, "lane_changes": 0}
        self.generation = np.zeros(self.n, dtype=np.int64)  # per slot: +1 each time a road user (re)enters
        self.ego: EgoState | None = None
        self._obstacle_cache = None
        self._ctx_s, self._ctx_v, self._ctx_len = np.zeros(self.nv + 1), np.zeros(self.nv + 1), np.zeros(self.nv + 1)
        self._b_agents = np.append(self.b_comf, 3.0)  # [m/s^2] comfortable deceleration, the ego last
        self._row_base = np.arange(self.nv) * PATH
        self._slot_row = np.full(self.n, -1, dtype=np.int64)  # vehicle row of each slot (-1: pedestrian)
        self._slot_row[self.vehicle_slots] = np.arange(self.nv)
        self.rng = np.random.default_rng(0)
        self._reset_state()

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
        self.time = 0.0  # [s]
        self._plan: _Plan | None = None
        self._k = 0  # index of the current substep in the plan
        self._accumulated = 0.0
        self._current_pos = self._hidden.copy()
        self._current_yaw = np.zeros(self.n)
        self._current_quat = _yaw_quat(self._current_yaw)
        self._current_speed = np.zeros(self.n)

    def _choose_successor(self, lane: np.ndarray) -> np.ndarray:
        """A uniformly random successor of each lane (-1 for a dead end or -1)."""
        m = self.map
        valid = lane >= 0
        lane0 = np.maximum(lane, 0)
        count = np.where(valid, m.n_successors[lane0], 0)
        pick = np.floor(self.rng.random(len(lane)) * np.maximum(count, 1)).astype(np.int64)
        return np.where(count > 0, m.successors[lane0, np.minimum(pick, m.successors.shape[1] - 1)], -1)

    def _fill_path(self, rows: np.ndarray, start: int = 1) -> None:
        """Random successors for path[rows, start:]."""
        for k in range(start, PATH):  # loop over path depth, not over road users
            self.path[rows, k] = self._choose_successor(self.path[rows, k - 1])

    # --- episodes --------------------------------------------------------------------------------------
    def reset(self, rng: np.random.Generator, ego: EgoState | None = None, keep_clear: float = 12.0,
              warmup: float = 0.0, density: float = 1.0) -> None:
        """New episode: place a random `density` share of the vehicles on the map's spawn points (none within
        `keep_clear` [m] of the ego), pedestrians at kerbs, then run `warmup` [s] of traffic."""
        self.rng = rng
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
        self._activate(rows, m.spawn_lane[chosen], m.spawn_s[chosen], speed_share=rng.uniform(0.3, 1.0, n_place))
        if self.np_:
            self.ped_dir = rng.choice([-1.0, 1.0], self.np_)
            self.ped_u = -self.ped_dir * (m.cw_half_length[self.ped_cw] + self.config.kerb)
            self.ped_wait = rng.uniform(0.0, self.config.pedestrian_wait[1], self.np_)
            self.ped_speed = rng.uniform(self._walk_range[:, 0], self._walk_range[:, 1])
        self._current_pos, self._current_yaw, self._current_speed = self._poses_now()
        self._current_quat = _yaw_quat(self._current_yaw)
        steps = int(round(warmup / self.config.decision_period))
        for _ in range(steps):
            self._decide()
            self._commit()
        self.time = 0.0
        self._plan = None
        self._k = 0

    def _activate(self, rows: np.ndarray, lane: np.ndarray, s: np.ndarray, speed_share=0.8) -> None:
        """Put vehicles `rows` at (lane, s) with random desired speed and lateral offset."""
        if not len(rows):
            return
        rng = self.rng
        self.generation[self.vehicle_slots[rows]] += 1
        self.active[rows] = True
        self.path[rows] = -1
        self.path[rows, 0] = lane
        self._fill_path(rows)
        self.s[rows] = s
        self.v0[rows] = rng.uniform(self._speed_range[rows, 0], self._speed_range[rows, 1])
        cap = np.minimum(self.v0[rows], self.map.speed_limit[lane])
        self.v[rows] = cap * speed_share
        self.d_pref[rows] = rng.uniform(self._lateral_range[rows, 0], self._lateral_range[rows, 1])
        self.lc_shift[rows] = 0.0
        self.lc_dist[rows] = 1e9
        self.accel[rows] = 0.0

    def place(self, row: int, path: Sequence[int], s: float, speed: float, desired_speed: float | None = None,
              lateral: float = 0.0) -> None:
        """Put vehicle `row` (index among the vehicle slots) at s [m] on path[0], moving at `speed` [m/s]
        along `path` (lane ids; random successors after it), with a desired speed [m/s] and lateral offset
        [m] (for scenes and tests). Takes effect from the next decision."""
        m = self.map
        self._settle()
        lanes = [int(x) for x in path][:PATH]
        self.generation[self.vehicle_slots[row]] += 1
        self.active[row] = True
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
        self._current_quat = _yaw_quat(self._current_yaw)

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

    def write(self, data: mujoco.MjData) -> None:
        """Write the current poses into data.mocap_pos / mocap_quat."""
        if self._mocap is None:
            raise RuntimeError("call Traffic.bind(model) before writing poses")
        if self._views is None or self._views[0] is not data:  # the arrays are views into data: keep them
            self._views = (data, data.mocap_pos, data.mocap_quat)
        self._views[1][self._mocap] = self._current_pos
        self._views[2][self._mocap] = self._current_quat

    def _commit(self, k: int = -1) -> None:
        """Make the plan's substep k (default: its end) the new state."""
        t_end = self._t_plan[k]
        v, a = self.v, self.accel
        stop = (a < 0) & (v + a * t_end < 0)
        ds = np.where(stop, v * v / np.maximum(-2 * a, 1e-9), v * t_end + 0.5 * a * t_end**2)
        ds = np.where(self.active, ds, 0.0)
        self.s += ds
        self.lc_dist += ds
        self.v = np.where(self.active, np.maximum(v + a * t_end, 0.0), 0.0)
        if self.np_:
            self._commit_pedestrians(t_end)
        self._current_pos = self._plan.pos[k]
        self._current_yaw = self._plan.yaw[k]
        self._current_speed = self._plan.speed[k]
        self._current_quat = self._plan.quat[k]
        self._plan = None

    def _commit_pedestrians(self, t_end: float) -> None:
        m, cfg = self.map, self.config
        end = m.cw_half_length[self.ped_cw] + cfg.kerb
        u = np.where(self.ped_walking, self.ped_u + self.ped_dir * self.ped_speed * t_end, self.ped_u)
        arrived = self.ped_walking & (self.ped_dir * u >= end)
        self.ped_u = np.clip(u, -end, end)
        self.ped_walking &= ~arrived
        self.ped_dir = np.where(arrived, -self.ped_dir, self.ped_dir)
        self.ped_wait -= t_end
        if arrived.any():
            lo, hi = cfg.pedestrian_wait
            self.ped_wait[arrived] = self.rng.uniform(lo, hi, int(arrived.sum()))

    # --- decisions -------------------------------------------------------------------------------------
    def _decide(self) -> None:
        """New accelerations, lane changes, spawns and pedestrian starts; then the plan of poses."""
        self._obstacle_cache = None
        self._advance_lanes()
        if self._spawn():
            self._refresh_vehicle_poses()
        self._lane_changes()
        ctx = self._context()
        if self.np_:
            self._pedestrian_starts(ctx)
        self.accel = np.where(self.active, self._accelerations(self._follower_table(ctx), ctx), 0.0)
        self._plan = self._make_plan(ctx["start"][: self.nv])

    def _advance_lanes(self) -> None:
        """Vehicles past the end of their lane move on along their path (or leave the map at dead ends)."""
        while True:
            over = self.active & (self.s >= self.map.length[np.maximum(self.path[:, 0], 0)])
            if not over.any():
                return
            rows = np.flatnonzero(over)
            self.s[rows] -= self.map.length[self.path[rows, 0]]
            self.path[rows, :-1] = self.path[rows, 1:]
            self.path[rows, -1] = self._choose_successor(self.path[rows, -2])
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
        path = np.full((nv + 1, PATH), -1, dtype=np.int64)
        path[:nv] = self.path
        path[:nv][~self.active] = -1
        s, v, length = self._ctx_s, self._ctx_v, self._ctx_len
        s[:nv], v[:nv], length[:nv] = self.s, self.v, self.length
        s[nv] = v[nv] = length[nv] = 0.0
        if ego is not None:
            v[nv], length[nv] = max(ego.speed, 0.0), ego.length
            if ego.path is not None and len(ego.path) and ego.path[0] >= 0:
                k = min(len(ego.path), PATH)
                path[nv, :k] = ego.path[:k]
                s[nv] = ego.s
        plen = np.where(path >= 0, self.map.length[path], np.inf)
        start = np.zeros((nv + 1, PATH))
        np.cumsum(plen[:, :-1], axis=1, out=start[:, 1:])
        offset = np.full((nv + 1, self.map.n_lanes + 1), np.inf)  # column -1 collects the -1 lanes
        rows = np.repeat(np.arange(nv + 1), PATH)
        offset[rows, path[:, ::-1].ravel()] = start[:, ::-1].ravel()  # reversed: the nearest occurrence wins
        offset[:, -1] = np.inf
        return {"lane": path[:, 0], "s": s.copy(), "v": v.copy(), "length": length.copy(), "path": path,
                "start": start, "offset": offset}

    def _spawn(self) -> bool:
        """Inactive vehicles re-enter at a random clear source (at most one per source per decision)."""
        m, cfg = self.map, self.config
        if self.active.all() or not len(m.sources) or not cfg.respawn:
            return False
        idle = np.flatnonzero(~self.active)
        lane = np.where(self.active, self.path[:, 0], -1)
        near_start = (lane[:, None] == m.sources[None]) & ((self.s - self.length / 2)[:, None] < cfg.spawn_clear)
        clear = ~near_start.any(axis=0)
        if self.ego is not None:
            clear &= np.hypot(m.source_xy[:, 0] - self.ego.x, m.source_xy[:, 1] - self.ego.y) >= cfg.spawn_clear
        pick = (self.rng.random(len(idle)) * len(m.sources)).astype(np.int64)
        ok = clear[pick]
        if not ok.any():
            return False
        rows, src = idle[ok], pick[ok]
        _, first = np.unique(src, return_index=True)
        rows, src = rows[first], src[first]
        self._activate(rows, m.sources[src], self.length[rows] / 2 + 0.5)
        self.stats["spawned"] += len(rows)
        return True

    def _lane_changes(self) -> None:
        """At most one lane change per decision: each vehicle beside a neighbour lane tries at the rates of
        `lane_change_rate` (one random try per decision); the change happens if the target lane has room."""
        m, cfg = self.map, self.config
        lane0 = np.maximum(self.path[:, 0], 0)
        right, left = m.right[lane0], m.left[lane0]
        # Not near a merge point (an entry joining the ring), where entering vehicles cut in, and not to the
        # right just before a diverge (an exit), where exiting vehicles slow down.
        s, length = self.s, m.length[lane0]
        near_merge = ((m.ends_at_merge[lane0] & (s > length - 12.0)) | (m.starts_at_merge[lane0] & (s < 8.0)))
        near_exit = (m.n_successors[lane0] > 1) & (s > length - 12.0)  # moving right in front of an exit
        right = np.where(near_exit, -1, right)
        ok = (self.active & ((right >= 0) | (left >= 0)) & (self.lc_dist >= cfg.lane_change_length)
              & (s > 1.0) & (self.lead_gap > cfg.lane_change_length) & ~near_merge)
        rows = np.flatnonzero(ok)
        if not len(rows):
            return
        rate_right, rate_left = cfg.lane_change_rate
        u = self.rng.random(3)
        if u[0] >= (rate_right + rate_left) * cfg.decision_period * len(rows):
            return
        row = int(rows[int(u[1] * len(rows))])
        side = 0 if u[2] * (rate_right + rate_left) < rate_right else 1  # 0: to the right, 1: to the left
        target = int(right[row] if side == 0 else left[row])
        if target < 0:
            return
        s_new = self.s[row] * m.length[target] / m.length[lane0[row]]
        # The move must be over before any junction lane (an exit): the lane after the target goes on.
        after = int(self._choose_successor(np.array([target]))[0])
        if after < 0 or m.in_junction[after]:
            return
        beyond = m.successors[after, : m.n_successors[after]]
        if m.length[target] - s_new + m.length[after] < cfg.lane_change_length and m.in_junction[beyond].any():
            return
        ctx = self._context()
        s, v, length, offset = ctx["s"], ctx["v"], ctx["length"], ctx["offset"]
        # Every other vehicle's coordinate along the target lane (via its own path), if it passes there,
        # or beyond its end along the lane that follows it (on it or coming to it from another lane).
        coord = np.where(np.isfinite(offset[:, after]), m.length[target] + s - offset[:, after], np.nan)
        leaving = np.isin(ctx["lane"], m.successors[target, : m.n_successors[target]])  # e.g. just exited
        coord = np.where(leaving, m.length[target] + s, coord)
        coord = np.where(np.isfinite(offset[:, target]), s - offset[:, target], coord)
        coord[row] = np.nan
        gap_ahead = coord - s_new - (length + self.length[row]) / 2
        gap_behind = s_new - coord - (length + self.length[row]) / 2
        ahead, behind = coord >= s_new, coord < s_new
        if np.any(ahead & (gap_ahead < cfg.min_gap + self.v[row] * 0.8)):
            return
        if np.any(behind & (gap_behind < cfg.min_gap + v * 1.2 + 2.0)):
            return
        if self.ego is not None and np.hypot(*(self._current_pos[self.vehicle_slots[row], :2]
                                               - (self.ego.x, self.ego.y))) < 12.0:
            return
        shift = m.width[lane0[row]] * (1.0 if side == 0 else -1.0)  # the old centre seen from the new lane
        sm, _ = _smoothstep(self.lc_dist[row] / cfg.lane_change_length)
        d_now = self.d_pref[row] + self.lc_shift[row] * (1.0 - sm)
        self.path[row, 0] = target
        self.path[row, 1] = after
        self._fill_path(np.array([row]), start=2)
        self.s[row] = s_new
        self.lc_shift[row] = d_now + shift - self.d_pref[row]
        self.lc_dist[row] = 0.0
        self.stats["lane_changes"] += 1

    def _pedestrian_starts(self, ctx: dict) -> None:
        """Waiting pedestrians whose wait is over cross when no vehicle could fail to stop before them."""
        m = self.map
        ready = ~self.ped_walking & (self.ped_wait <= 0.0)
        if not ready.any():
            return
        unsafe = self._threatened_crosswalks(ctx)
        if self.ego is not None:
            dist = np.hypot(m.cw_centre[:, 0] - self.ego.x, m.cw_centre[:, 1] - self.ego.y)
            unsafe |= dist < 7.0 + 3.0 * max(self.ego.speed, 0.0)
        self.ped_walking |= ready & ~unsafe[self.ped_cw]

    def _threatened_crosswalks(self, ctx: dict) -> np.ndarray:
        """Crosswalks (C,) that a vehicle on the lane graph is on, or too close to stop comfortably before."""
        m = self.map
        out = np.zeros(m.n_crosswalks, dtype=bool)
        if not len(m.cross_lane):
            return out
        s, v, length = ctx["s"], ctx["v"], ctx["length"]
        base = ctx["offset"][:, m.cross_lane]  # (A, K)
        front = base + m.cross_s[None, :, 0] - (s + length / 2)[:, None]  # bumper to the crossing [m]
        rear_past = base + m.cross_s[None, :, 1] - (s - length / 2)[:, None]  # > 0: rear not yet past it
        stopping = v * v / (2 * self._b_agents) + v + 1.0
        threat = (rear_past > 0) & (front < stopping[:, None])  # inf base: never
        np.logical_or.at(out, m.cross_cw, threat.any(axis=0))
        return out

    # --- accelerations -----------------------------------------------------------------------------------
    def _follower_table(self, ctx: dict) -> dict:
        """The vehicles as followers for `_accelerations`."""
        nv = self.nv
        vs = self.vehicle_slots
        return {"rows": np.arange(nv), "path": ctx["path"][:nv], "offset": ctx["offset"][:nv], "s": self.s,
                "v": self.v, "v0": self.v0, "length": self.length, "width": self.width, "a": self.a_max,
                "b": self.b_comf, "T": self.headway, "xy": self._current_pos[vs, :2],
                "yaw": self._current_yaw[vs], "accept_gap": self.config.accept_gap}

    def _accelerations(self, f: dict, ctx: dict) -> np.ndarray:
        """IDM accelerations [m/s^2] of followers `f` (dict of arrays, see `_follower_table`).

        Every obstacle of every follower is a column of one (F, columns) table of gaps [m] (bumper to
        obstacle, inf where none), obstacle speeds [m/s] and minimum gaps s0 [m]: path leaders, the corridor,
        crosswalk stop lines, merge stop lines. IDM takes the most constraining one."""
        m, cfg = self.map, self.config
        path, offset, s, v = f["path"], f["offset"], f["s"], f["v"]
        rows, length = f["rows"], f["length"]
        front = s + length / 2
        xy_o, yaw_o, v_o, hl_o, hw_o, idx_o = self._obstacles()
        lane_a = ctx["lane"]
        n_a, n_o, n_k, n_y = len(lane_a), len(xy_o), len(m.cross_lane), len(m.yield_lane)
        c1, c2, c3, c4 = n_a, n_a + n_o, n_a + n_o + n_k, n_a + n_o + n_k + n_y
        gap = np.full((len(s), c4 + n_y), np.inf)
        lead = np.zeros_like(gap)
        s0 = np.full(gap.shape[1], cfg.stop_gap)
        s0[:c2] = cfg.min_gap

        # 1. Leaders along the planned path (vehicles and the ego).
        pos = offset[:, lane_a] + ctx["s"][None]  # (F, A) [m] from the start of the follower's lane
        a_idx = np.arange(n_a)
        ahead = (pos > s[:, None]) | ((pos == s[:, None]) & (a_idx[None] > rows[:, None]))
        ahead &= a_idx[None] != rows[:, None]
        gap[:, :c1] = np.where(ahead, pos - front[:, None] - ctx["length"][None] / 2, np.inf)
        lead[:, :c1] = ctx["v"][None]

        # 2. Anything in the corridor ahead (curvature-corrected): vehicles, the ego, pedestrians.
        lane0 = np.maximum(path[:, 0], 0)
        vcurve, kappa = m.curve_speed(lane0, s)
        c, sn = np.cos(f["yaw"])[:, None], np.sin(f["yaw"])[:, None]
        co, so = np.cos(yaw_o)[None], np.sin(yaw_o)[None]
        rx = xy_o[None, :, 0] - f["xy"][:, None, 0]
        ry = xy_o[None, :, 1] - f["xy"][:, None, 1]
        dx = c * rx + sn * ry
        dy = -sn * rx + c * ry - 0.5 * kappa[:, None] * dx * dx
        cos_d = co * c + so * sn  # cos and sin of the obstacle's yaw relative to the follower
        cd, sd = np.abs(cos_d), np.abs(so * c - co * sn)
        inside = (dx > 0) & (dx < cfg.corridor_range) & (idx_o[None] != rows[:, None])
        inside &= np.abs(dy) < (f["width"] / 2 + cfg.corridor_margin)[:, None] + sd * hl_o[None] + cd * hw_o[None]
        gap[:, c1:c2] = np.where(inside, dx - (length / 2)[:, None] - cd * hl_o[None] - sd * hw_o[None], np.inf)
        lead[:, c1:c2] = v_o[None] * cos_d

        # 3. Crosswalk stop lines where a pedestrian walks in the lane's band, or where the queue ahead
        #    leaves no room beyond the crosswalk (keep it clear).
        if n_k:
            base = offset[:, m.cross_lane]  # (F, K)
            stop = base + (m.cross_s[:, 0] - cfg.crosswalk_margin)[None] - front[:, None]
            leader = np.argmin(gap[:, :c1], axis=1)
            path_gap = np.minimum(gap[np.arange(len(s)), leader], 1e9)
            slow_leader = (path_gap < 1e9) & (ctx["v"][leader] < 3.0)
            beyond = stop + (m.cross_s[:, 1] - m.cross_s[:, 0] + 2 * cfg.crosswalk_margin)[None]
            no_room = slow_leader[:, None] & (path_gap[:, None] - beyond < (length + cfg.min_gap)[:, None])
            blocked = (no_room | self._occupied_crossings()[None]) if self.np_ else no_room
            gap[:, c2:c3] = np.where(blocked & (stop > -0.5), stop, np.inf)  # at / past the line: go on

        # 4. Merge stop lines while a priority vehicle (or the ego) would reach the merge point too soon.
        if n_y:
            conflict = self._merge_conflicts(ctx, f["accept_gap"])  # (Y,)
            if conflict.any():
                stop = offset[:, m.yield_lane] + m.yield_stop[None] - front[:, None]
                holding = (stop > -0.5) | ((stop > -1.0) & (v < 1.0)[:, None])  # not yet committed
                gap[:, c3:c4] = np.where(conflict[None] & holding, stop, np.inf)
            # ... and circulating vehicles let in an entering vehicle committed past its yield line.
            on_entry = ctx["lane"][:, None] == m.yield_lane[None]  # (A, Y)
            past = (ctx["s"] + ctx["length"] / 2)[:, None] - m.yield_stop[None]
            committed = (on_entry & ((past > 1.0) | ((past > 0.5) & (ctx["v"] >= 1.0)[:, None]))).any(axis=0)
            if committed.any():
                to_merge = offset[:, m.yield_merge]  # (F, Y)
                through = offset[:, m.yield_lane] < np.inf
                stop = to_merge - cfg.merge_clearance - front[:, None]
                keep_out = committed[None] & ~through & (to_merge > 0) & (stop > -0.5)
                gap[:, c4:] = np.where(keep_out, stop, np.inf)

        finite = gap < np.inf
        self.lead_gap = gap.min(axis=1) if len(rows) == self.nv else self.lead_gap
        s_star = s0[None] + np.maximum(0.0, (v * f["T"])[:, None] + v[:, None] * (v[:, None] - lead)
                                       / (2.0 * np.sqrt(f["a"] * f["b"]))[:, None])
        interaction = np.where(finite, (s_star / np.maximum(gap, 0.05)) ** 2, 0.0).max(axis=1)

        # Desired speed: own v0, the lane's speed limit, the curves ahead on this lane and the next.
        nxt = path[:, 1]
        to_end = m.length[lane0] - s
        vnext = np.where(nxt >= 0, np.sqrt(m.entry_speed[np.maximum(nxt, 0)] ** 2
                                           + 2 * m.anticipation * np.maximum(to_end, 0)), np.inf)
        v0 = np.minimum(np.minimum(f["v0"], m.speed_limit[lane0]), np.minimum(vcurve, vnext))
        if n_y:  # approach yield lines slowly enough to stop at them when a gap closes
            to_line = (offset[:, m.yield_lane] + m.yield_stop[None] - front[:, None]).min(axis=1)
            ahead_line = (to_line > -0.5) & (to_line < np.inf)
            v0 = np.where(ahead_line, np.minimum(v0, np.sqrt(cfg.yield_speed**2 + 2 * 1.5 * np.maximum(to_line, 0))),
                          v0)
        acc = f["a"] * (1.0 - (v / np.maximum(v0, 0.1)) ** 4 - interaction)
        tau = cfg.decision_period
        acc = np.where(v <= v0, np.minimum(acc, (v0 - v) / tau), acc)  # no overshoot of v0 in one period
        # Safety cap (Krauss-like): whatever the obstacle does (braking at max_decel), the follower can
        # still stop s0 short of it after this decision period: with the end speed w of the period,
        # distance (v + w) tau / 2 + w^2 / (2 b) <= gap - s0 + v_lead^2 / (2 b).
        b = cfg.max_decel
        v_lead = np.maximum(lead, 0.0)
        room = np.where(finite, gap - s0[None] + v_lead * v_lead / (2 * b), np.inf).min(axis=1)
        disc = 0.25 * tau * tau + 2.0 * (room - 0.5 * v * tau) / b
        w = np.where(disc > 0, b * (np.sqrt(np.maximum(disc, 0.0)) - 0.5 * tau), 0.0)
        # no positive end speed fits: stop within the room (the period's motion stops at v = 0)
        acc = np.minimum(acc, np.where(w > 0, (w - v) / tau, -v * v / (2 * np.maximum(room, 1e-3))))
        return np.maximum(np.minimum(acc, f["a"]), -cfg.max_decel)

    def _obstacles(self):
        """Everything the corridor check sees: centre xy (O,2), yaw, speed, half length, half width, and the
        follower row it is (vehicle row, nv for the ego, -1 for pedestrians); inactive vehicles left out."""
        if self._obstacle_cache is not None:
            return self._obstacle_cache
        ego = self.ego
        slots = np.concatenate([self.vehicle_slots[self.active], self.pedestrian_slots])
        n = len(slots) + (ego is not None)
        xy, yaw, speed = np.empty((n, 2)), np.empty(n), np.empty(n)
        hl, hw, idx = np.empty(n), np.empty(n), np.empty(n, dtype=np.int64)
        k = len(slots)
        xy[:k], yaw[:k], speed[:k] = self._current_pos[slots, :2], self._current_yaw[slots], self._current_speed[slots]
        hl[:k], hw[:k] = self.half_size[slots, 0], self.half_size[slots, 1]
        idx[:k] = self._slot_row[slots]
        if ego is not None:
            xy[k], yaw[k], speed[k] = (ego.x, ego.y), ego.yaw, max(ego.speed, 0.0)
            hl[k], hw[k], idx[k] = ego.length / 2, ego.width / 2, self.nv
        self._obstacle_cache = (xy, yaw, speed, hl, hw, idx)
        return self._obstacle_cache

    def _occupied_crossings(self) -> np.ndarray:
        """Crossings (K,) with a pedestrian walking in the lane's band (+ margin) or towards it."""
        m, cfg = self.map, self.config
        on = self.ped_walking[None] & (self.ped_cw[None] == m.cross_cw[:, None])  # (K, P)
        u, direction = self.ped_u[None], self.ped_dir[None]
        margin = cfg.crosswalk_margin + 0.3
        lo, hi = m.cross_u[:, :1] - margin, m.cross_u[:, 1:] + margin
        not_past = np.where(direction > 0, u < hi, u > lo)
        return (on & not_past).any(axis=1)

    def _merge_conflicts(self, ctx: dict, accept_gap: float) -> np.ndarray:
        """(Y,): whether a priority agent (vehicle or ego) reaches merge y's point within `accept_gap` [s] or
        is nearer than merge_clearance, or still occupies the start of the merged lane."""
        m, cfg = self.map, self.config
        offset, s, v, length = ctx["offset"], ctx["s"], ctx["v"], ctx["length"]
        merge = m.yield_merge
        # Agents approaching the merge point, not through this yielding lane (not queued behind it).
        to_merge = offset[:, merge]  # (A, Y) 0 for agents already on the merged lane
        via = np.isfinite(offset[:, m.yield_lane])
        dist = np.where(via | (to_merge <= 0), np.inf, to_merge - (s + length / 2)[:, None])  # (A, Y)
        # slow or stopped circulating vehicles may speed up: count them at `merge_speed` at least
        soon = dist - cfg.merge_clearance < np.maximum(v, cfg.merge_speed)[:, None] * accept_gap
        # Agents already on the merged lane whose rear is still near its start.
        on_start = (ctx["lane"][:, None] == merge[None]) & ((s - length / 2)[:, None] < cfg.merge_clearance + 3.0)
        conflict = (soon | on_start).any(axis=0)
        # Vehicles moving over to another lane still occupy the old one: judge them by straight distance.
        changing = np.flatnonzero(self.active & (self.lc_dist < cfg.lane_change_length))
        if len(changing):
            xy = self._current_pos[self.vehicle_slots[changing], :2]
            near = np.hypot(xy[:, None, 0] - m.merge_xy[None, :, 0], xy[:, None, 1] - m.merge_xy[None, :, 1])
            reach = np.maximum(self.v[changing], cfg.merge_speed)[:, None] * accept_gap + cfg.merge_clearance
            conflict |= (near - self.length[changing, None] / 2 < reach).any(axis=0)
        return conflict

    # --- poses -------------------------------------------------------------------------------------------
    def _make_plan(self, start: np.ndarray | None = None) -> _Plan:
        t = self._t_plan[:, None]  # (S, 1)
        v, a = self.v[None], self.accel[None]
        stopped = (a < 0) & (v + a * t < 0)
        ds = np.where(stopped, v * v / np.maximum(-2 * a, 1e-9), v * t + 0.5 * a * t * t)  # (S, NV)
        out_pos = np.empty((len(t), self.n, 3))
        out_yaw = np.empty((len(t), self.n))
        out_speed = np.zeros((len(t), self.n))
        vs = self.vehicle_slots
        out_pos[:, vs], out_yaw[:, vs] = self._vehicle_poses(ds, start)
        out_speed[:, vs] = np.maximum(v + a * t, 0.0) * self.active[None]
        if self.np_:
            ps = self.pedestrian_slots
            out_pos[:, ps], out_yaw[:, ps], out_speed[:, ps] = self._pedestrian_poses(t)
        return _Plan(out_pos, _yaw_quat(out_yaw), out_yaw, out_speed)

    def _vehicle_poses(self, ds: np.ndarray, before: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Poses (S, NV, 3), yaw (S, NV) of the vehicles after moving ds (S, NV) [m] along their paths
        (`before`: distance (NV, PATH) [m] to the start of each path lane, if known)."""
        m, nv = self.map, self.nv
        path = self.path
        if before is None:
            before = np.zeros((nv, PATH))
            np.cumsum(np.where(path[:, :-1] >= 0, m.length[path[:, :-1]], np.inf), axis=1, out=before[:, 1:])
        p = self.s[None] + ds
        k = (p[..., None] >= before[None, :, 1:]).sum(-1)  # (S, NV) index into the path
        k = np.minimum(k, self._last_path_index()[None])  # stay on a dead end's last lane
        flat = self._row_base + k
        lane = np.maximum(path.ravel()[flat], 0)
        x, y, h = m.lookup(lane, p - before.ravel()[flat])
        if np.any(self.lc_dist < self.config.lane_change_length):  # lane changes under way
            sm, dsm = _smoothstep((self.lc_dist[None] + ds) / self.config.lane_change_length)
            d = self.d_pref[None] + self.lc_shift[None] * (1.0 - sm)
            yaw = h + np.arctan(-self.lc_shift[None] * dsm / self.config.lane_change_length)
        else:
            d, yaw = self.d_pref[None], h
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

    def _pedestrian_poses(self, t: np.ndarray):
        """Poses (S, P, 3), yaw (S, P) and speed (S, P) of the pedestrians at times t (S, 1) [s] ahead."""
        end = self._ped_end[None]
        walking = self.ped_walking[None]
        u = np.minimum(np.maximum(self.ped_u[None] + (self.ped_dir * self.ped_speed * self.ped_walking)[None] * t,
                                  -end), end)
        xy = self._ped_centre[None] + u[..., None] * self._ped_along[None] + self._ped_side[None]
        pos = np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], axis=-1)
        yaw = np.empty(u.shape)
        yaw[:] = self._ped_heading + (self.ped_dir < 0) * np.pi
        speed = np.where(walking & (np.abs(u) < end), self.ped_speed[None], 0.0)
        return pos, yaw, speed

    def _refresh_vehicle_poses(self) -> None:
        """Current vehicle poses from the state (after spawns)."""
        pos, yaw = self._vehicle_poses(np.zeros((1, self.nv)))
        self._current_pos = self._current_pos.copy()
        self._current_yaw = self._current_yaw.copy()
        self._current_pos[self.vehicle_slots] = pos[0]
        self._current_yaw[self.vehicle_slots] = yaw[0]
        self._current_quat = _yaw_quat(self._current_yaw)

    def _poses_now(self):
        """Poses of every slot at the current state (no plan)."""
        pos = self._hidden.copy()
        yaw = np.zeros(self.n)
        speed = np.zeros(self.n)
        vpos, vyaw = self._vehicle_poses(np.zeros((1, self.nv)))
        pos[self.vehicle_slots], yaw[self.vehicle_slots] = vpos[0], vyaw[0]
        speed[self.vehicle_slots] = np.where(self.active, self.v, 0.0)
        if self.np_:
            ppos, pyaw, pspeed = self._pedestrian_poses(np.zeros((1, 1)))
            pos[self.pedestrian_slots], yaw[self.pedestrian_slots] = ppos[0], pyaw[0]
            speed[self.pedestrian_slots] = pspeed[0]
        return pos, yaw, speed

    # --- queries -----------------------------------------------------------------------------------------
    @property
    def present(self) -> np.ndarray:
        """(N,) slots in the world now (active vehicles and all pedestrians)."""
        out = np.ones(self.n, dtype=bool)
        out[self.vehicle_slots] = self.active
        return out

    def poses(self) -> np.ndarray:
        """(N,3) [m, m, rad] x, y, yaw of every slot now (inactive slots are below the ground)."""
        return np.column_stack([self._current_pos[:, :2], self._current_yaw])

    def velocities(self) -> np.ndarray:
        """(N,2) [m/s] world velocity of every slot now."""
        return self._current_speed[:, None] * np.column_stack([np.cos(self._current_yaw),
                                                              np.sin(self._current_yaw)])

    def advise(self, ego: EgoState, accel: float = 2.0, decel: float = 3.0, headway: float = 1.5,
               desired_speed: float = 8.0, accept_gap: float | None = None) -> float:
        """The acceleration [m/s^2] traffic's own rules give the ego (a privileged autopilot): IDM behind
        leaders and the corridor, stops for pedestrians, and gap acceptance at merges. Needs ego.path."""
        if ego.path is None:
            raise ValueError("advise needs the ego's lane path")
        self.ego = ego
        self._obstacle_cache = None
        ctx = self._context()
        f = {"rows": np.array([self.nv]), "path": ctx["path"][-1:], "offset": ctx["offset"][-1:],
             "s": np.array([ego.s]), "v": np.array([max(ego.speed, 0.0)]), "v0": np.array([desired_speed]),
             "length": np.array([ego.length]), "width": np.array([ego.width]), "a": np.array([accel]),
             "b": np.array([decel]), "T": np.array([headway]), "xy": np.array([[ego.x, ego.y]]),
             "yaw": np.array([ego.yaw]),
             "accept_gap": self.config.accept_gap if accept_gap is None else accept_gap}
        return float(self._accelerations(f, ctx)[0])
