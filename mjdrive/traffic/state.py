"""Traffic state as named structures of arrays (NamedTuples, which the kernels take as they are), and the
decision's view of where every agent is on the lane graph (`agents_on_paths`).

Rows: the NV vehicles are rows 0..NV-1 of `Vehicles`; the agents of a decision are the vehicles and then the ego
(row NV). Slots: all N road users in the order of the model's `traffic_{i}` bodies (`Vehicles.slot` and
`Pedestrians.slot` give each row's slot). A kernel that changes the state writes into these arrays in place.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mjdrive.compiled import jit
from mjdrive.traffic.params import PATH, EgoState

INF = np.inf


class Vehicles(NamedTuple):
    """Every vehicle (NV,): its slot and length, then its state (reset each episode)."""

    slot: np.ndarray  # (NV,) int: the vehicle's slot among all road users
    length: np.ndarray  # [m]
    active: np.ndarray  # bool: on the map
    path: np.ndarray  # (NV, PATH) int: the current lane and the next ones (-1: none)
    s: np.ndarray  # [m] along path[:, 0]
    v: np.ndarray  # [m/s]
    v0: np.ndarray  # [m/s] desired speed
    d_pref: np.ndarray  # [m] preferred lateral offset
    lc_shift: np.ndarray  # [m] lateral offset left to remove by the current lane change
    lc_dist: np.ndarray  # [m] distance driven since the lane change began
    accel: np.ndarray  # [m/s^2] of the current decision period
    lead_gap: np.ndarray  # [m] to the nearest obstacle ahead at the last decision
    intention: np.ndarray  # (NV, 4) int: by scenario (`intentions.SCENARIOS`)
    ring_passed: np.ndarray  # bool: the planned path went past the ego's exit
    lc_signal: np.ndarray  # [s] time the lane-change signal came on (-1: off)
    lc_changing: np.ndarray  # bool: an intended lane change under way
    stopped_time: np.ndarray  # [s] since the vehicle last moved (at decisions)


class VehicleKinds(NamedTuple):
    """Every vehicle's kind (NV,) as the IDM and the corridor see it (read in Python, into `Followers`; kernels take
    only the arrays they read, and each array a kernel takes costs its call some 0.15 us)."""

    width: np.ndarray  # [m]
    a_max: np.ndarray  # [m/s^2] IDM's maximum acceleration a
    b_comf: np.ndarray  # [m/s^2] IDM's comfortable deceleration b
    headway: np.ndarray  # [s] IDM's time headway T


def new_vehicles(slot: np.ndarray, length: np.ndarray) -> Vehicles:
    """Vehicles in `slot` of `length` [m] with a fresh state: nobody on the map."""
    nv = len(slot)
    return Vehicles(
        slot=slot, length=length, active=np.zeros(nv, dtype=bool), path=np.full((nv, PATH), -1, dtype=np.int64),
        s=np.zeros(nv), v=np.zeros(nv), v0=np.zeros(nv), d_pref=np.zeros(nv), lc_shift=np.zeros(nv),
        lc_dist=np.full(nv, 1e9), accel=np.zeros(nv), lead_gap=np.zeros(nv),
        intention=np.zeros((nv, 4), dtype=np.int64),
        ring_passed=np.zeros(nv, dtype=bool), lc_signal=np.full(nv, -1.0), lc_changing=np.zeros(nv, dtype=bool),
        stopped_time=np.zeros(nv))


class Pedestrians(NamedTuple):
    """Every pedestrian (P,): where it walks (constants), then its state (reset each episode)."""

    slot: np.ndarray  # (P,) int
    crosswalk: np.ndarray  # (P,) int
    end: np.ndarray  # [m] the kerbs' position along the crosswalk (+-end)
    centre: np.ndarray  # (P, 2) [m] the crosswalk's centre
    along: np.ndarray  # (P, 2) unit vector along the crosswalk
    side: np.ndarray  # (P, 2) [m] the track's offset across it
    heading: np.ndarray  # [rad] along the crosswalk
    u: np.ndarray  # [m] position along the crosswalk
    direction: np.ndarray  # +1 / -1 along the crosswalk
    walking: np.ndarray  # bool
    wait: np.ndarray  # [s] left to wait at the kerb before looking for a gap
    speed: np.ndarray  # [m/s]


class Poses(NamedTuple):
    """Every slot's pose: now (N, ...), or at each substep of a decision period's plan (S, N, ...)."""

    pos: np.ndarray  # (..., N, 3) [m]
    quat: np.ndarray  # (..., N, 4) (w, x, y, z)
    yaw: np.ndarray  # (..., N) [rad]
    speed: np.ndarray  # (..., N) [m/s]


class PlanCursor(NamedTuple):
    """Where the traffic stands in its plan of poses, for the substep loop (`tasks.stepping`) that takes its plain
    substeps: the plan's positions (S, N, 3) [m] and quaternions (S, N, 4) (S = 0: no plan, the next substep
    decides), the substeps taken of it, their count S, the time [s] accumulated toward the next substep, the
    substep [s], the traffic's time [s], and whether there is traffic to move."""

    pos: np.ndarray
    quat: np.ndarray
    k: int
    n_plan: int
    accumulated: float
    substep: float
    time: float
    moving: bool


class Agents(NamedTuple):
    """The vehicles and the ego (last row) on the lane graph at a decision (A = NV + 1 rows)."""

    path: np.ndarray  # (A, PATH) int: lanes ahead (-1 rows for inactive vehicles, an ego off the lanes)
    start: np.ndarray  # (A, PATH) [m] from the agent's lane start to the start of each lane on its path
    offset: np.ndarray  # (A, L + 1) [m] ... to the start of every lane (inf off its path; column L: inf)
    s: np.ndarray  # [m] along path[:, 0]
    v: np.ndarray  # [m/s]
    length: np.ndarray  # [m]
    waited: np.ndarray  # [s] how long each has waited (urban rules' patience: vehicles' stopped_time, the ego's)


class Followers(NamedTuple):
    """Whose accelerations a decision computes (F,): the vehicles, or the ego when traffic advises it."""

    row: np.ndarray  # (F,) int: agent row
    path: np.ndarray  # (F, PATH)
    offset: np.ndarray  # (F, L + 1) [m]
    s: np.ndarray  # [m]
    v: np.ndarray  # [m/s]
    v0: np.ndarray  # [m/s] desired speed
    length: np.ndarray  # [m]
    width: np.ndarray  # [m]
    a_max: np.ndarray  # [m/s^2] IDM a
    b_comf: np.ndarray  # [m/s^2] IDM b
    headway: np.ndarray  # [s] IDM T
    xy: np.ndarray  # (F, 2) [m]
    yaw: np.ndarray  # [rad]
    courteous: np.ndarray  # bool: opens gaps at merges (merge intention YIELD; never the ego)


NO_PATH = np.zeros(0, dtype=np.int64)


def ego_on_lanes(ego: EgoState | None) -> tuple[np.ndarray, float, float, float]:
    """The ego's path (lane ids, at most PATH; empty when it is off the lanes), s [m], speed (>= 0) [m/s] and
    length [m] as an agent (an empty path and zeros without an ego); its waiting time is the traffic's
    (`Traffic.ego_waited`)."""
    if ego is None:
        return NO_PATH, 0.0, 0.0, 0.0
    if ego.path is not None and len(ego.path) and ego.path[0] >= 0:
        return np.asarray(ego.path[:PATH], dtype=np.int64), ego.s, max(ego.speed, 0.0), ego.length
    return NO_PATH, 0.0, max(ego.speed, 0.0), ego.length


@jit
def agents_on_paths(vehicles, ego_path, ego_s, ego_v, ego_length, ego_waited, lane_length, n_lanes):
    """The vehicles and the ego (last row, `ego_path`, s [m], speed [m/s], length [m], waiting time [s]) as
    `Agents`: their paths
    (-1 rows for inactive vehicles), the distance from each one's lane start to the start of each lane on its path,
    and to the start of every lane (inf off the path; the first occurrence on a path wins)."""
    v_path, active, v_s, v_v, v_length = vehicles.path, vehicles.active, vehicles.s, vehicles.v, vehicles.length
    nv, n_p = v_path.shape
    s_a, v_a, length_a, waited = np.empty(nv + 1), np.empty(nv + 1), np.empty(nv + 1), np.empty(nv + 1)
    stopped_time = vehicles.stopped_time
    for r in range(nv):
        s_a[r], v_a[r], length_a[r], waited[r] = v_s[r], v_v[r], v_length[r], stopped_time[r]
    s_a[nv], v_a[nv], length_a[nv], waited[nv] = ego_s, ego_v, ego_length, ego_waited
    path = np.full((nv + 1, n_p), -1, dtype=np.int64)
    for r in range(nv):
        if active[r]:
            for j in range(n_p):
                path[r, j] = v_path[r, j]
    for j in range(len(ego_path)):
        path[nv, j] = ego_path[j]
    start = np.zeros((nv + 1, n_p))
    offset = np.full((nv + 1, n_lanes + 1), INF)
    for r in range(nv + 1):
        for j in range(1, n_p):
            previous = path[r, j - 1]
            length = lane_length[previous] if previous >= 0 else INF
            start[r, j] = length if j == 1 else start[r, j - 1] + length
        for j in range(n_p - 1, -1, -1):
            lane = path[r, j]
            offset[r, lane if lane >= 0 else n_lanes] = start[r, j]
        offset[r, n_lanes] = INF
    return Agents(path, start, offset, s_a, v_a, length_a, waited)
