"""Compiled kernels (numba) of a decision's bookkeeping around the gap table: lanes passed, lane-change
options, clear spawn places, the corridor's obstacles, path starts, crossings and pedestrian poses.

Each repeats the numpy code it stands for (named in its docstring) operation for operation, as in `kernels`;
without numba (`KERNELS` False) the numpy code runs, and `tests/test_traffic_kernels.py` runs both at every
decision and compares the results and the state they leave bit for bit. What is drawn from a random generator
stays in numpy (the kernels return what the draws need).
"""

from __future__ import annotations

import numpy as np

from mjdrive.compiled import jit as _jit
from mjdrive.traffic.kernels import _maximum, _minimum, choose_successors


@_jit
def lanes_passed(s, path, active, v, lane_length):
    """One round of `Traffic._advance_lanes`, in place: active vehicles past the end of their lane (s >= its
    length [m]) move on to the next lane of their path (s less that length, the path shifted by one, its last
    entry left for the caller to draw); those whose path ends there leave the map (inactive, speed 0). Returns
    the rows that moved on (K,), in order, and how many of them left."""
    n_v, n_p = path.shape
    rows = np.empty(n_v, dtype=np.int64)
    k = 0
    for r in range(n_v):
        if active[r] and s[r] >= lane_length[max(path[r, 0], 0)]:
            rows[k] = r
            k += 1
    gone = 0
    for j in range(k):
        r = rows[j]
        s[r] -= lane_length[path[r, 0]]
        for c in range(n_p - 1):
            path[r, c] = path[r, c + 1]
        if path[r, 0] < 0:
            active[r] = False
            v[r] = 0.0
            gone += 1
    return rows[:k], gone


@_jit
def lane_change_options(path, s, lane_length, right_of, left_of, ends_at_merge, starts_at_merge, n_successors):
    """`lane_changes.lane_changes`' lane0 (current lanes), right and left neighbours (-1: none; not to the
    right in front of an exit) and whether each vehicle is near a merge."""
    n_v = len(s)
    lane0 = np.empty(n_v, dtype=np.int64)
    right = np.empty(n_v, dtype=np.int64)
    left = np.empty(n_v, dtype=np.int64)
    near_merge = np.empty(n_v, dtype=np.bool_)
    for r in range(n_v):
        lane = max(path[r, 0], 0)
        lane0[r] = lane
        length = lane_length[lane]
        near_merge[r] = (ends_at_merge[lane] and s[r] > length - 12.0) or (starts_at_merge[lane] and s[r] < 8.0)
        near_exit = n_successors[lane] > 1 and s[r] > length - 12.0
        right[r] = -1 if near_exit else right_of[lane]
        left[r] = left_of[lane]
    return lane0, right, left, near_merge


@_jit
def finish_lane_changes(lc_changing, lc_dist, intention, lc_signal, lane_change_length, column, keep):
    """`lane_changes._finish_intended`, in place: intended lane changes that are over (lc_dist [m] at least
    `lane_change_length`) keep their lane (intention[:, column] = keep), their signal goes off."""
    for r in range(len(lc_changing)):
        if lc_changing[r] and lc_dist[r] >= lane_change_length:
            intention[r, column] = keep
            lc_signal[r] = -1.0
            lc_changing[r] = False


@_jit
def random_lane_change_rows(active, right, left, lc_dist, s, lead_gap, near_merge, lane_change_length):
    """`lane_changes._random`'s candidates: the rows (K,) that may change lane now."""
    rows = np.empty(len(s), dtype=np.int64)
    k = 0
    for r in range(len(s)):
        if (active[r] and (right[r] >= 0 or left[r] >= 0) and lc_dist[r] >= lane_change_length and s[r] > 1.0
                and lead_gap[r] > lane_change_length and not near_merge[r]):
            rows[k] = r
            k += 1
    return rows[:k]


@_jit
def _spawn_clear(lanes, starts, place_xy, active, path, s, length, pos, vehicle_slots, urban, ego_x, ego_y, has_ego,
                clearance):
    """`spawning.spawn`'s clear places (Q,): no active vehicle on the place's lane within `clearance` [m] of its
    s (bumper to place); under urban rules none whose centre is within it, whatever its lane; and not the ego."""
    n_q, n_v = len(lanes), len(s)
    clear = np.ones(n_q, dtype=np.bool_)
    for q in range(n_q):
        for r in range(n_v):
            lane = path[r, 0] if active[r] else -1
            if lane == lanes[q] and abs(s[r] - starts[q]) - length[r] / 2 < clearance:
                clear[q] = False
        if urban:
            for r in range(n_v):
                if active[r]:
                    slot = vehicle_slots[r]
                    dist = np.hypot(pos[slot, 0] - place_xy[q, 0], pos[slot, 1] - place_xy[q, 1])
                    if dist < clearance:
                        clear[q] = False
        if has_ego and not np.hypot(place_xy[q, 0] - ego_x, place_xy[q, 1] - ego_y) >= clearance:
            clear[q] = False
    return clear


@_jit
def obstacles(active, vehicle_slots, pedestrian_slots, pos, yaw, speed, half_size, slot_row, has_ego, ego_x, ego_y,
              ego_yaw, ego_speed, ego_half_length, ego_half_width, ego_row):
    """`following.obstacles`: centre xy (O, 2) [m], yaw [rad], speed [m/s], half length and width [m] and follower
    row of the active vehicles, the pedestrians, then the ego (if `has_ego`)."""
    n_active = 0
    for r in range(len(active)):
        n_active += active[r]
    n = n_active + len(pedestrian_slots) + (1 if has_ego else 0)
    xy, out_yaw, out_speed = np.empty((n, 2)), np.empty(n), np.empty(n)
    hl, hw, idx = np.empty(n), np.empty(n), np.empty(n, dtype=np.int64)
    k = 0
    for j in range(len(active) + len(pedestrian_slots)):
        if j < len(active):
            if not active[j]:
                continue
            slot = vehicle_slots[j]
        else:
            slot = pedestrian_slots[j - len(active)]
        xy[k, 0], xy[k, 1] = pos[slot, 0], pos[slot, 1]
        out_yaw[k], out_speed[k] = yaw[slot], speed[slot]
        hl[k], hw[k], idx[k] = half_size[slot, 0], half_size[slot, 1], slot_row[slot]
        k += 1
    if has_ego:
        xy[k, 0], xy[k, 1], out_yaw[k], out_speed[k] = ego_x, ego_y, ego_yaw, ego_speed
        hl[k], hw[k], idx[k] = ego_half_length, ego_half_width, ego_row
    return xy, out_yaw, out_speed, hl, hw, idx


@_jit
def path_starts(path, lane_length):
    """`Traffic._path_starts`: (NV, PATH) [m] from each vehicle's lane start to the start of each lane on its path
    (inf past its end)."""
    n_v, n_p = path.shape
    before = np.zeros((n_v, n_p))
    for r in range(n_v):
        for j in range(1, n_p):
            previous = path[r, j - 1]
            length = lane_length[previous] if previous >= 0 else np.inf
            before[r, j] = length if j == 1 else before[r, j - 1] + length
    return before


@_jit
def occupied_crossings(walking, ped_cw, ped_u, ped_dir, cross_cw, cross_u, margin):
    """`pedestrians.occupied_crossings`: crossings (K,) with a pedestrian walking in the lane's band (+ margin
    [m]) or towards it."""
    n_k = len(cross_cw)
    out = np.zeros(n_k, dtype=np.bool_)
    for k in range(n_k):
        lo, hi = cross_u[k, 0] - margin, cross_u[k, 1] + margin
        for p in range(len(walking)):
            if walking[p] and ped_cw[p] == cross_cw[k]:
                if (ped_u[p] < hi) if ped_dir[p] > 0 else (ped_u[p] > lo):
                    out[k] = True
    return out


@_jit
def place_pedestrians(ped_u, ped_dir, ped_speed, walking, end, centre, along, side, heading, times, slots, out_pos,
                      out_yaw, out_speed):
    """`pedestrians.pedestrian_poses` at `times` (S, 1) [s] ahead, into columns `slots` of out_pos (S, N, 3),
    out_yaw (S, N) and out_speed (S, N) (as `Traffic._make_plan` places them)."""
    for i in range(times.shape[0]):
        t = times[i, 0]
        for p in range(len(ped_u)):
            slot = slots[p]
            u = _minimum(_maximum(ped_u[p] + (ped_dir[p] * ped_speed[p] * walking[p]) * t, -end[p]), end[p])
            out_pos[i, slot, 0] = centre[p, 0] + u * along[p, 0] + side[p, 0]
            out_pos[i, slot, 1] = centre[p, 1] + u * along[p, 1] + side[p, 1]
            out_pos[i, slot, 2] = 0.0
            out_yaw[i, slot] = heading[p] + (ped_dir[p] < 0) * np.pi
            out_speed[i, slot] = ped_speed[p] if walking[p] and abs(u) < end[p] else 0.0


@_jit
def pedestrian_starts(walking, wait, ped_cw, offset, s, v, length, b_agents, cross_lane, cross_s, cross_cw, cw_centre,
                      has_ego, ego_x, ego_y, ego_reach):
    """`pedestrians.pedestrian_starts`, in place: waiting pedestrians whose wait is over start walking unless an
    agent (A,) is on their crosswalk or too close to stop before it (`threatened_crosswalks`), or the ego's centre
    is within `ego_reach` [m] of the crosswalk's centre."""
    ready = np.empty(len(walking), dtype=np.bool_)
    any_ready = False
    for p in range(len(walking)):
        ready[p] = not walking[p] and wait[p] <= 0.0
        any_ready |= ready[p]
    if not any_ready:
        return
    unsafe = np.zeros(len(cw_centre), dtype=np.bool_)
    for a in range(len(s)):
        stopping = v[a] * v[a] / (2 * b_agents[a]) + v[a] + 1.0
        for k in range(len(cross_lane)):
            base = offset[a, cross_lane[k]]
            front = base + cross_s[k, 0] - (s[a] + length[a] / 2)
            rear_past = base + cross_s[k, 1] - (s[a] - length[a] / 2)
            if rear_past > 0 and front < stopping:
                unsafe[cross_cw[k]] = True
    if has_ego:
        for c in range(len(cw_centre)):
            if np.hypot(cw_centre[c, 0] - ego_x, cw_centre[c, 1] - ego_y) < ego_reach:
                unsafe[c] = True
    for p in range(len(walking)):
        if ready[p] and not unsafe[ped_cw[p]]:
            walking[p] = True


@_jit
def random_successors(lane, u, successors, n_successors):
    """`Traffic._choose_successor` without urban rules: successor floor(u * count) of each lane (-1 for a dead end
    or -1), with u (K,) uniform draws."""
    out = np.empty(len(lane), dtype=np.int64)
    for k in range(len(lane)):
        lane0 = max(lane[k], 0)
        count = n_successors[lane0] if lane[k] >= 0 else 0
        pick = np.int64(np.floor(u[k] * max(count, 1)))
        out[k] = successors[lane0, min(pick, successors.shape[1] - 1)] if count > 0 else -1
    return out


@_jit
def lane_change_room(row, s_new, target, after, lane_a, s_a, v_a, len_a, offset_a, successors, n_successors,
                     lane_length, length_row, v_row, min_gap):
    """`lane_changes._room`: whether lane `target` has room for vehicle `row` at s_new [m] (every other agent's
    coordinate along it, via its path, or beyond its end along `after`), the nearest agent behind (-1: none)
    and the gap [m] to it (inf if none)."""
    len_target = lane_length[target]
    nearest, nearest_gap = -1, np.inf
    for a in range(len(s_a)):
        off_after, off_target = offset_a[a, after], offset_a[a, target]
        coord = len_target + s_a[a] - off_after if np.isfinite(off_after) else np.nan
        for j in range(n_successors[target]):
            if lane_a[a] == successors[target, j]:  # e.g. just exited
                coord = len_target + s_a[a]
        if np.isfinite(off_target):
            coord = s_a[a] - off_target
        if a == row:
            coord = np.nan
        half = (len_a[a] + length_row) / 2
        if coord >= s_new and coord - s_new - half < min_gap + v_row * 0.8:
            return False, -1, np.inf
        if coord < s_new:
            gap = s_new - coord - half
            if gap < min_gap + v_a[a] * 1.2 + 2.0:
                return False, -1, np.inf
            if gap < nearest_gap or nearest < 0:
                nearest, nearest_gap = a, gap
    return True, nearest, nearest_gap


@_jit
def waiting_times(stopped_time, active, v, period, waiting_speed):
    """`Traffic._count_waiting`: each vehicle's waiting time [s] after a decision period [s] (reset when it is
    inactive or not slower than `waiting_speed` [m/s])."""
    out = np.empty(len(v))
    for r in range(len(v)):
        out[r] = stopped_time[r] + period if active[r] and v[r] < waiting_speed else 0.0
    return out


@_jit
def spawn_places(idle, u_pick, u_due, timed, due_below, lanes, starts, place_xy, active, path, s, length, pos,
                 vehicle_slots, urban, ego_x, ego_y, has_ego, clearance):
    """`spawning.spawn`'s choice: each idle vehicle (K,) picks place floor(u_pick * Q); under timed arrivals it is
    due when u_due < due_below; the due ones whose place is clear (`_spawn_clear`) enter there, the first one of
    each place only. Returns their rows, places, lanes and s [m] (clear of the lane start by half their length),
    by place."""
    n_k, n_q = len(idle), len(lanes)
    pick = np.empty(n_k, dtype=np.int64)
    due = np.ones(n_k, dtype=np.bool_)
    any_due = False
    for k in range(n_k):
        pick[k] = np.int64(u_pick[k] * n_q)
        if timed:
            due[k] = u_due[k] < due_below
        any_due |= due[k]
    n = 0
    rows, src = np.empty(min(n_k, n_q), dtype=np.int64), np.empty(min(n_k, n_q), dtype=np.int64)
    lane, at = np.empty(min(n_k, n_q), dtype=np.int64), np.empty(min(n_k, n_q))
    if not any_due:
        return rows[:0], src[:0], lane[:0], at[:0]
    clear = _spawn_clear(lanes, starts, place_xy, active, path, s, length, pos, vehicle_slots, urban, ego_x, ego_y,
                         has_ego, clearance)
    for q in range(n_q):
        if not clear[q]:
            continue
        for k in range(n_k):
            if pick[k] == q and due[k]:
                r = idle[k]
                rows[n], src[n], lane[n] = r, q, lanes[q]
                at[n] = _maximum(starts[q], length[r] / 2 + 0.5)
                n += 1
                break
    return rows[:n], src[:n], lane[:n], at[:n]


@_jit
def idle_rows(active):
    """np.flatnonzero(~active)."""
    out = np.empty(len(active), dtype=np.int64)
    n = 0
    for r in range(len(active)):
        if not active[r]:
            out[n] = r
            n += 1
    return out[:n]


@_jit
def activate_rows(rows, lane, s, vehicle_slots, generation, active, path, s_state, urban, u_intent, cdfs,
                  cdf_columns, intention, ring_passed, lc_signal, lc_changing, u_path, successors, n_successors, turn,
                  ring, ring_exit, ego_exit, crossroad, roundabout, before_code, after_code):
    """`spawning.activate`'s lane-graph part, in place: vehicles `rows` (K,) enter at (lane, s [m]) (a new
    generation of their slot), with (urban) intentions drawn from `cdfs` (I, W) (the scenarios' cumulative shares,
    inf-padded; into intention[:, cdf_columns]) by the uniform draws u_intent (I, K) (`intentions.draw`), signals off,
    and their paths filled by the draws u_path (PATH - 1, K) as `Traffic._fill_path` fills them."""
    n_k, n_p = len(rows), path.shape[1]
    for j in range(n_k):
        r = rows[j]
        generation[vehicle_slots[r]] += 1
        active[r] = True
        for c in range(n_p):
            path[r, c] = -1
        path[r, 0] = lane[j]
    if urban:
        for i in range(len(cdf_columns)):
            for j in range(n_k):
                c = 0  # cdf.searchsorted(u, side="right")
                while c < cdfs.shape[1] and cdfs[i, c] <= u_intent[i, j]:
                    c += 1
                intention[rows[j], cdf_columns[i]] = c
        for j in range(n_k):
            ring_passed[rows[j]] = False
            lc_signal[rows[j]] = -1.0
            lc_changing[rows[j]] = False
    previous = np.empty(n_k, dtype=np.int64)
    for c in range(1, n_p):
        for j in range(n_k):
            previous[j] = path[rows[j], c - 1]
        if urban:
            chosen = choose_successors(rows, previous, u_path[c - 1], successors, turn, ring, ring_exit, intention,
                                       ring_passed, ego_exit, crossroad, roundabout, before_code, after_code)
        else:
            chosen = random_successors(previous, u_path[c - 1], successors, n_successors)
        for j in range(n_k):
            path[rows[j], c] = chosen[j]
    for j in range(n_k):
        s_state[rows[j]] = s[j]


@_jit
def activate_speeds(rows, lane, v0_drawn, d_pref_drawn, share, speed_limit, v0, v, d_pref, lc_shift, lc_dist, accel):
    """`spawning.activate`'s speeds, in place: vehicles `rows` (K,) get their drawn desired speeds v0 [m/s] and
    lateral offsets [m], speed share * min(v0, the lane's limit) [m/s], and no lane change under way."""
    for j in range(len(rows)):
        r = rows[j]
        v0[r] = v0_drawn[j]
        v[r] = _minimum(v0_drawn[j], speed_limit[lane[j]]) * share[j]
        d_pref[r] = d_pref_drawn[j]
        lc_shift[r] = 0.0
        lc_dist[r] = 1e9
        accel[r] = 0.0


@_jit
def successors_then_lanes_passed(rows, u, urban, successors, n_successors, turn, ring, ring_exit, intention,
                                 ring_passed, ego_exit, crossroad, roundabout, before_code, after_code, s, path, active,
                                 v, lane_length):
    """The end of a round of `Traffic._advance_lanes` and the next round: the vehicles `rows` that moved on draw
    their path's new last lane with the uniform draws u (K,) (`Traffic._choose_successor`), then `lanes_passed`."""
    n_p = path.shape[1]
    previous = np.empty(len(rows), dtype=np.int64)
    for j in range(len(rows)):
        previous[j] = path[rows[j], n_p - 2]
    if urban:
        chosen = choose_successors(rows, previous, u, successors, turn, ring, ring_exit, intention, ring_passed,
                                   ego_exit, crossroad, roundabout, before_code, after_code)
    else:
        chosen = random_successors(previous, u, successors, n_successors)
    for j in range(len(rows)):
        path[rows[j], n_p - 1] = chosen[j]
    return lanes_passed(s, path, active, v, lane_length)


@_jit
def commit_vehicles(v, accel, active, t_end, t_end2, s, lc_dist):
    """`Traffic._commit`'s vehicle part: the distance each vehicle moved in `t_end` [s] (`t_end2` = t_end**2 as
    numpy squares it) at its constant acceleration, stopping at rest, added to s and lc_dist in place [m]; returns
    the new speeds [m/s] (0 for inactive vehicles)."""
    n = len(v)
    out = np.empty(n)
    for r in range(n):
        vr, ar = v[r], accel[r]
        if active[r]:
            if ar < 0 and vr + ar * t_end < 0:
                ds = vr * vr / _maximum(-2 * ar, 1e-9)
            else:
                ds = vr * t_end + 0.5 * ar * t_end2
        else:
            ds = 0.0
        s[r] += ds
        lc_dist[r] += ds
        out[r] = _maximum(vr + ar * t_end, 0.0) if active[r] else 0.0
    return out


@_jit
def commit_pedestrians(ped_u, ped_dir, ped_speed, walking, wait, end, t_end):
    """`pedestrians.commit_pedestrians` without its draws: the walkers move `t_end` [s] on along their crosswalk
    (clipped to the kerbs `end` [m]), those who reached the far kerb stop and turn; `walking` and `wait` [s] are
    updated in place. Returns the new positions [m] and directions, and who arrived (for the new waits' draws)."""
    n = len(ped_u)
    u_new, dir_new, arrived = np.empty(n), np.empty(n), np.zeros(n, dtype=np.bool_)
    for p in range(n):
        u = ped_u[p] + ped_dir[p] * ped_speed[p] * t_end if walking[p] else ped_u[p]
        arrived[p] = walking[p] and ped_dir[p] * u >= end[p]
        lo, hi = -end[p], end[p]
        u = u if (u != u or u > lo) else lo  # np.clip's maximum then minimum
        u_new[p] = u if (u != u or u < hi) else hi
        walking[p] = walking[p] and not arrived[p]
        dir_new[p] = -ped_dir[p] if arrived[p] else ped_dir[p]
        wait[p] -= t_end
    return u_new, dir_new, arrived
