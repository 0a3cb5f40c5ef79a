"""Lane changes to a same-direction neighbour lane when the target lane has room: at random rates (the
roundabout), or by intention with a signalling phase and MOBIL's safety criterion (urban rules)."""

from __future__ import annotations

import numpy as np

from mjdrive.compiled import inline, jit, minimum
from mjdrive.traffic.geometry import smoothstep
from mjdrive.traffic.intentions import KEEP, LANE_CHANGE, LEFT, RIGHT, draw_successors, fill_paths

ZONE_CLEARANCE = 8.0  # [m] intended lane changes start at least this plus their length from any zone point
EGO_IDM = (2.0, 3.0, 1.5)  # [m/s^2, m/s^2, s] a, b, T assumed for the ego as a follower
EGO_CLEARANCE = 12.0  # [m] nobody changes lane this close to the ego (centre to centre)
MERGE_END_ZONE = 12.0  # [m] no change in the last metres of a lane ending at a merge, nor to the right before a
# diverge (an exit), where exiting vehicles slow down ...
MERGE_START_ZONE = 8.0  # [m] ... nor in the first metres of a lane that entering lanes join
START_ZONE = 1.0  # [m] nor in a lane's first metre
AHEAD_HEADWAY = 0.8  # [s] room in the target lane: min_gap plus the changer's speed times this to the agent ahead
BEHIND_HEADWAY = 1.2  # [s] ... min_gap plus the agent behind's speed times this (plus BEHIND_MARGIN) to it
BEHIND_MARGIN = 2.0  # [m]


def lane_changes(vehicles, kinds, agents, lanes, routes, config, c, rng: np.random.Generator, time: float,
                 now_pos: np.ndarray, ego, zone_points: np.ndarray) -> bool:
    """At most one lane change per decision (in place), into a same-direction neighbour lane that has room: at random
    rates (`lane_changes="random"`) or, under urban rules (`"intention"`), by each vehicle's lane-change intention after
    `signal_time` of signalling, if the new follower need not brake harder than `safe_decel` (MOBIL's safety criterion).
    kinds: the vehicles' `VehicleKinds`; `agents`: the decision's Agents; now_pos: the slots' positions (N, 3) [m];
    zone_points: (R, 2) [m] the conflict zones' points (no intended change starts near them); config: the TrafficConfig,
    c: its Constants. True if a vehicle changed lane."""
    if config.lane_changes == "intention":
        lane0, right, left, row, side = intended_lane_change(vehicles, lanes, routes.roles.priority, now_pos,
                                                             zone_points, time, c)
    else:
        lane0, right, left, rows = random_candidates(vehicles, lanes, c.lane_change_length)
        row, side = _random_try(rows, config, rng)
    if row < 0:
        return False
    return _change(vehicles, kinds, agents, lanes, routes, config, rng, now_pos, ego, row, side, lane0, right, left)


def _random_try(rows: np.ndarray, config, rng: np.random.Generator) -> tuple[int, int]:
    """(row, side) of one random try among the candidates `rows` at the rates of `lane_change_rate` (side 0: right,
    1: left), or (-1, -1)."""
    if not len(rows):
        return -1, -1
    rate_right, rate_left = config.lane_change_rate
    u = rng.random(3)
    if u[0] >= (rate_right + rate_left) * config.decision_period * len(rows):
        return -1, -1
    row = int(rows[int(u[1] * len(rows))])
    side = 0 if u[2] * (rate_right + rate_left) < rate_right else 1  # 0: to the right, 1: to the left
    return row, side


def _change(vehicles, kinds, agents, lanes, routes, config, rng: np.random.Generator, now_pos: np.ndarray, ego,
            row: int, side: int, lane0: np.ndarray, right: np.ndarray, left: np.ndarray) -> bool:
    """Move vehicle `row` to its right (side 0) or left (1) neighbour if the target lane has room."""
    target = int(right[row] if side == 0 else left[row])
    if target < 0:
        return False
    s_new = vehicles.s[row] * lanes.length[target] / lanes.length[lane0[row]]
    # The move must be over before any junction lane (an exit): the lane after the target goes on.
    after = int(draw_successors(routes, vehicles, np.array([row]), np.array([target]), rng)[0])
    if after < 0 or lanes.in_junction[after]:
        return False
    beyond = lanes.successors[after, : lanes.n_successors[after]]
    if (lanes.length[target] - s_new + lanes.length[after] < config.lane_change_length
            and lanes.in_junction[beyond].any()):
        return False
    room, behind, gap_behind = lane_change_room(agents, row, s_new, target, after, lanes, vehicles.length[row],
                                                vehicles.v[row], config.min_gap)
    if not room:
        return False
    if ego is not None and np.hypot(*(now_pos[vehicles.slot[row], :2] - (ego.x, ego.y))) < EGO_CLEARANCE:
        return False
    if (config.lane_changes == "intention" and behind >= 0
            and not safe_for_follower(vehicles, kinds, row, behind, gap_behind, agents.v[behind], config)):
        return False
    shift = lanes.width[lane0[row]] * (1.0 if side == 0 else -1.0)  # the old centre seen from the new lane
    sm, _ = smoothstep(vehicles.lc_dist[row] / config.lane_change_length)
    d_now = vehicles.d_pref[row] + vehicles.lc_shift[row] * (1.0 - sm)
    vehicles.path[row, 0] = target
    vehicles.path[row, 1] = after
    fill_paths(routes, vehicles, np.array([row]), rng, start=2)
    vehicles.s[row] = s_new
    vehicles.lc_shift[row] = d_now + shift - vehicles.d_pref[row]
    vehicles.lc_dist[row] = 0.0
    vehicles.lc_changing[row] = config.lane_changes == "intention"
    return True


def safe_for_follower(vehicles, kinds, row: int, j: int, gap: float, vf: float, config) -> bool:
    """MOBIL's safety criterion: the nearest agent `j` behind in the target lane (gap [m], speed vf [m/s]), with
    the changer `row` as its new leader, needs an IDM deceleration of at most `safe_decel` (the ego, agent row NV,
    counts with `EGO_IDM`'s parameters)."""
    nv = len(vehicles.v)
    a, b, headway = (kinds.a_max[j], kinds.b_comf[j], kinds.headway[j]) if j < nv else EGO_IDM
    vc = vehicles.v[row]
    s_star = config.min_gap + max(0.0, vf * headway + vf * (vf - vc) / (2.0 * np.sqrt(a * b)))
    decel = a * ((s_star / max(gap, 0.05)) ** 2 - 1.0)
    return bool(decel <= config.safe_decel)


@inline
def options(vehicles, lanes):
    """Each vehicle's current lane, its right and left neighbours it may change to (-1: none; not to the right
    before a diverge, where exiting vehicles slow down) and whether it is near a merge (the end of a lane ending at
    one, the start of a lane that entering lanes join), where entering vehicles cut in."""
    path, s = vehicles.path, vehicles.s
    n_v = len(s)
    lane0 = np.empty(n_v, dtype=np.int64)
    right = np.empty(n_v, dtype=np.int64)
    left = np.empty(n_v, dtype=np.int64)
    near_merge = np.empty(n_v, dtype=np.bool_)
    for r in range(n_v):
        lane = max(path[r, 0], 0)
        lane0[r] = lane
        length = lanes.length[lane]
        near_merge[r] = ((lanes.ends_at_merge[lane] and s[r] > length - MERGE_END_ZONE)
                         or (lanes.starts_at_merge[lane] and s[r] < MERGE_START_ZONE))
        near_exit = lanes.n_successors[lane] > 1 and s[r] > length - MERGE_END_ZONE
        right[r] = -1 if near_exit else lanes.right[lane]
        left[r] = lanes.left[lane]
    return lane0, right, left, near_merge


@inline
def finish_lane_changes(vehicles, lane_change_length):
    """Intended lane changes that are over (lc_dist [m] at least `lane_change_length`), in place: the vehicle now
    keeps its lane, its signal goes off."""
    for r in range(len(vehicles.lc_changing)):
        if vehicles.lc_changing[r] and vehicles.lc_dist[r] >= lane_change_length:
            vehicles.intention[r, LANE_CHANGE] = KEEP
            vehicles.lc_signal[r] = -1.0
            vehicles.lc_changing[r] = False


@jit
def random_candidates(vehicles, lanes, lane_change_length):
    """`options`, and the rows (K,) that may change lane at random now: active, a neighbour to change to, no change
    under way, past the lane's start, a leader farther than a lane change's length and not near a merge."""
    lane0, right, left, near_merge = options(vehicles, lanes)
    rows = np.empty(len(vehicles.s), dtype=np.int64)
    k = 0
    for r in range(len(vehicles.s)):
        if (vehicles.active[r] and (right[r] >= 0 or left[r] >= 0) and vehicles.lc_dist[r] >= lane_change_length
                and vehicles.s[r] > START_ZONE and vehicles.lead_gap[r] > lane_change_length and not near_merge[r]):
            rows[k] = r
            k += 1
    return lane0, right, left, rows[:k]


@jit
def intended_lane_change(vehicles, lanes, priority, now_pos, zone_points, now, c):
    """After `finish_lane_changes`, vehicles whose lane-change intention has a neighbour lane (`options`) on its side
    signal (`lc_signal` [s], updated in place at time `now` [s]); returns the options and (row, side) of the one that
    has signalled longest for at least `signal_time` (side 0: right, 1: left), or (-1, -1). A lane that ends beside a
    neighbour (an on-ramp) must be left, whatever the intention; nobody changes into a lane of lower rank (`priority`:
    an acceleration lane that must give way at its end), nor starts within ZONE_CLEARANCE plus a lane change's length of
    a conflict zone's point (the move takes a while). now_pos: the slots' positions (N, 3) [m]."""
    lane0, right, left, near_merge = options(vehicles, lanes)
    finish_lane_changes(vehicles, c.lane_change_length)
    wish = vehicles.intention[:, LANE_CHANGE]
    signal = vehicles.lc_signal
    zone_distance = ZONE_CLEARANCE + c.lane_change_length
    signal_time = c.signal_time - 1e-9
    best_row, best_signal = -1, np.inf
    for n in range(len(wish)):
        w = wish[n]
        if lanes.ending[lane0[n]]:
            goes_on = left[n] >= 0 and lanes.n_successors[max(left[n], 0)] > 0
            w = LEFT if goes_on else RIGHT
        target = left[n] if w == LEFT else (right[n] if w == RIGHT else -1)
        if not (lanes.ending[lane0[n]] or priority[max(target, 0)] >= priority[lane0[n]]):
            target = -1
        able = (vehicles.active[n] and target >= 0 and vehicles.lc_dist[n] >= c.lane_change_length
                and vehicles.s[n] > START_ZONE and not near_merge[n])
        if able and len(zone_points):
            nearest = np.inf
            slot = vehicles.slot[n]
            for r in range(len(zone_points)):
                nearest = minimum(nearest, np.hypot(now_pos[slot, 0] - zone_points[r, 0],
                                                    now_pos[slot, 1] - zone_points[r, 1]))
            able = nearest > zone_distance
        if able and signal[n] < 0:
            signal[n] = now
        elif not (able or vehicles.lc_changing[n]):
            signal[n] = -1.0
        if able and signal[n] >= 0 and now - signal[n] >= signal_time and signal[n] < best_signal:
            best_row, best_signal = n, signal[n]
    if best_row < 0:
        return lane0, right, left, -1, -1
    w = wish[best_row]
    if lanes.ending[lane0[best_row]]:
        w = LEFT if (left[best_row] >= 0 and lanes.n_successors[max(left[best_row], 0)] > 0) else RIGHT
    return lane0, right, left, best_row, (0 if w == RIGHT else 1)


@jit
def lane_change_room(agents, row, s_new, target, after, lanes, length_row, v_row, min_gap):
    """Whether lane `target` has room for vehicle `row` (length [m], speed [m/s]) at s_new [m]: every other agent's
    coordinate along it (via its path, or beyond its end along `after`, or just past its end on a successor) keeps
    min_gap plus AHEAD_HEADWAY of the changer's speed ahead of it, and min_gap plus BEHIND_HEADWAY of its own speed
    plus BEHIND_MARGIN behind it; also the nearest agent behind (-1: none) and the gap [m] to it (inf if none)."""
    len_target = lanes.length[target]
    s_a, offset_a = agents.s, agents.offset
    nearest, nearest_gap = -1, np.inf
    for a in range(len(s_a)):
        off_after, off_target = offset_a[a, after], offset_a[a, target]
        coord = len_target + s_a[a] - off_after if np.isfinite(off_after) else np.nan
        for j in range(lanes.n_successors[target]):
            if agents.path[a, 0] == lanes.successors[target, j]:  # e.g. just exited
                coord = len_target + s_a[a]
        if np.isfinite(off_target):
            coord = s_a[a] - off_target
        if a == row:
            coord = np.nan
        half = (agents.length[a] + length_row) / 2
        if coord >= s_new and coord - s_new - half < min_gap + v_row * AHEAD_HEADWAY:
            return False, -1, np.inf
        if coord < s_new:
            gap = s_new - coord - half
            if gap < min_gap + agents.v[a] * BEHIND_HEADWAY + BEHIND_MARGIN:
                return False, -1, np.inf
            if gap < nearest_gap or nearest < 0:
                nearest, nearest_gap = a, gap
    return True, nearest, nearest_gap

