"""Compiled kernels (numba) for the traffic decision's gap table: the same numbers as the numpy code in
`following` and `conflicts`, bit for bit, without building (followers x obstacles) tables.

A decision of the traffic is some 500 numpy calls on arrays of a few dozen elements, so it costs the calls'
overhead, not the arithmetic. The kernel here walks every (follower, obstacle) pair once in compiled code
and keeps only what the IDM needs of each follower's gap table: the smallest gap, the strongest
interaction term and the least stopping room. It repeats the numpy expressions operation for operation
(same order, same rounding; sines and cosines are libm's in both, since numpy (>= 1.25) has no vectorised
float64 sine or cosine; powers stay in numpy), and `tests/test_traffic_kernels.py` checks that both give
identical arrays at every decision of simulated traffic on every map.

numba is an optional dependency (the `fast` extra, installed by `make`; `mjdrive.compiled`): without it
`KERNELS` is False and the traffic runs the numpy code, which is the specification of this module. Compiled
code is cached on disk (by default under ~/.cache/mjdrive), so only the first process on a machine pays the
compilation (a few seconds).
"""

from __future__ import annotations

import math

import numpy as np

from mjdrive.compiled import KERNELS as KERNELS
from mjdrive.compiled import inline as _inline
from mjdrive.compiled import jit as _jit

INF = np.inf


@_inline
def _maximum(a: float, b: float) -> float:
    """np.maximum of two floats (NaN wins)."""
    if a != a or a >= b:
        return a
    return b


@_inline
def _minimum(a: float, b: float) -> float:
    """np.minimum of two floats (NaN wins)."""
    if a != a or a <= b:
        return a
    return b


@_inline
def _can_stop(v: float, to_line: float, claim_decel: float, stop_margin: float, held_speed: float,
              committed: float) -> bool:
    """conflicts._can_stop for one pair."""
    return (v * v < 2.0 * claim_decel * _maximum(to_line - stop_margin, -1e9)) or (
        v < held_speed and to_line > -committed)


@_jit
def gap_summary(
    # followers (F,)
    rows, path, offset, s, v, length, width, T, den, yaw_f, xy, kappa, courteous_f,
    # agents of the decision (A,)
    lane_a, s_a, v_a, len_a, offset_a,
    # obstacles of the corridor (O,)
    xy_o, yaw_o, v_o, hl_o, hw_o, idx_o,
    # crosswalks blocked by pedestrians (K,); roundabout merges (Y,) in conflict, with a committed entry
    blocked_k, conflict_y, committed_y,
    # the vehicles' waiting times [s] (NV,) and intentions (NV, 4): courteous at merges where column `merge_column`
    # holds `yield_code` (the ego, row NV, never waits and is never courteous)
    stopped_time, intention,
    # vehicles changing lane (NV,): active and lc_dist [m] below lane_change_length; their slots' poses (N, 3)
    active_v, lc_dist, slot_pos,
    # --- the rest is the traffic's own, the same at every decision (`following._gap_constants`) ---
    # crosswalks (K,)
    cross_lane, cross_s,
    # roundabout merges (Y,)
    yield_lane, yield_stop, yield_merge,
    # ending lanes (L,) (urban), all False elsewhere
    ending, lane_length,
    # conflict-zone approaches (R,) (urban), empty elsewhere
    ap_lane, ap_s_in, ap_s_out, ap_other, ap_o_in, ap_o_out, ap_yields, ap_tie, ap_timed, ap_merge, ap_stop,
    ap_courtesy, ap_point, ap_partner,
    merge_column, yield_code, ego_row, lane_change_length, vehicle_slots,
    # scalars: config
    min_gap, stop_gap, max_decel, corridor_range, corridor_margin, crosswalk_margin, merge_clearance,
    merge_speed, critical_gap_crossing, impatience, critical_gap_merge, courtesy_range, urban,
    # scalars: conflicts' constants
    committed_m, edge_margin, merge_range, clear_accel, changing_radius, held_speed, standing_room, at_line_m,
    turn_wait, claim_decel, stop_margin,
):
    """For every follower: the smallest gap [m] of its gap table (inf if none), the largest IDM
    interaction term (s*/gap)^2, the least stopping room [m] (gap - s0 + v_lead^2 / 2 max_decel; inf if
    none) and the distance [m] to its nearest give-way line still ahead (inf if none): what
    `following.accelerations` reduces its (F, columns) table to. Arguments as in `accelerations_kernel`."""
    n_f, n_a, n_o, n_k, n_y, n_r = len(s), len(s_a), len(xy_o), len(cross_lane), len(yield_lane), len(ap_lane)
    lead_gap = np.full(n_f, INF)
    interaction = np.zeros(n_f)
    room = np.full(n_f, INF)
    to_give_way = np.full(n_f, INF)
    two_b = 2 * max_decel
    c, sn = np.empty(n_f), np.empty(n_f)  # the followers' headings' cosines and sines (libm's, as numpy's)
    for f in range(n_f):
        c[f], sn[f] = math.cos(yaw_f[f]), math.sin(yaw_f[f])
    co, so = np.empty(n_o), np.empty(n_o)  # the obstacles'
    for o in range(n_o):
        co[o], so[o] = math.cos(yaw_o[o]), math.sin(yaw_o[o])
    waited_all = np.zeros(n_a)  # [s]
    courteous_a = np.zeros(n_a, dtype=np.bool_)
    for a in range(min(n_a, len(stopped_time))):
        waited_all[a] = stopped_time[a]
        courteous_a[a] = intention[a, merge_column] == yield_code

    # --- per agent and approach (urban): agents on the zone's other lane (the rest never conflict there) ----
    # (written, and read, only for the agents on each approach's other lane)
    inside = np.empty((n_a, n_r), dtype=np.bool_)
    ttz = np.empty((n_a, n_r))
    held = np.empty((n_a, n_r), dtype=np.bool_)
    can_stop = np.empty((n_a, n_r), dtype=np.bool_)
    claiming = np.empty((n_a, n_r), dtype=np.bool_)
    in_zone = np.empty((n_a, n_r), dtype=np.bool_)
    t_line_o = np.empty((n_a, n_r))
    waiting_o = np.empty((n_a, n_r), dtype=np.bool_)
    d_them = np.empty((n_a, n_r))
    near = np.empty((n_a, n_r), dtype=np.bool_)
    on_lane = np.empty((n_r, n_a), dtype=np.int64)  # on_lane[r, :n_on[r]]: the agents on approach r's other lane
    n_on = np.zeros(n_r, dtype=np.int64)
    for a in range(n_a):
        half = len_a[a] / 2
        pace = _maximum(v_a[a], merge_speed)
        for r in range(n_r):
            off_other = offset_a[a, ap_other[r]]
            if not np.isfinite(off_other):
                continue
            on_lane[r, n_on[r]] = a
            n_on[r] += 1
            off_own = offset_a[a, ap_lane[r]]
            base = -off_other
            f_o = base + (s_a[a] + half)
            rear_o = base + (s_a[a] - half)
            on_other = np.isfinite(f_o) and not np.isfinite(off_own)
            partner = ap_partner[r]
            other_stop = ap_stop[partner]
            entered = _minimum(ap_o_in[r], other_stop + committed_m) if (ap_yields[partner] or ap_tie[partner]) \
                else ap_o_in[r]
            ins = on_other and f_o > entered and rear_o < ap_o_out[r]
            inside[a, r] = ins
            before = on_other and not ins and f_o <= ap_o_in[r]
            if before:
                ttz[a, r] = (ap_o_in[r] - f_o) / pace
            elif ins:
                ttz[a, r] = 0.0
            else:
                ttz[a, r] = INF
            before_line = v_a[a] < held_speed and f_o <= other_stop + committed_m
            at_line = other_stop - f_o < at_line_m
            held[a, r] = before_line and not (at_line and waited_all[a] >= turn_wait)
            to_own = other_stop - f_o
            if not np.isfinite(to_own):
                to_own = -INF
            can_stop[a, r] = a != ego_row and _can_stop(v_a[a], to_own, claim_decel, stop_margin, held_speed,
                                                        committed_m)
            claiming[a, r] = before_line and at_line and waited_all[a] >= impatience and ap_yields[partner]
            in_zone[a, r] = ins and f_o > ap_o_in[r]
            t_line_o[a, r] = _maximum(other_stop - f_o, 0.0) / pace
            waiting_o[a, r] = np.isfinite(f_o) and not ins and f_o <= ap_o_in[r] and not np.isfinite(off_own)
            dt_ = ap_o_out[r] - f_o
            d_them[a, r] = dt_
            near[a, r] = np.isfinite(dt_) and dt_ > -len_a[a] and dt_ < merge_range

    changing = np.empty(len(active_v), dtype=np.int64)  # vehicles moving over between lanes
    n_changing = 0
    for j in range(len(active_v)):
        if active_v[j] and lc_dist[j] < lane_change_length:
            changing[n_changing] = j
            n_changing += 1

    needed = np.empty(n_a)  # [m] the headway of an agent behind a merging follower
    for a in range(n_a):
        needed[a] = min_gap + v_a[a] * critical_gap_merge if v_a[a] >= held_speed else standing_room

    for f in range(n_f):
        row = rows[f]
        front = s[f] + length[f] / 2
        vf = v[f]
        vT = vf * T[f]
        state = (INF, 0.0, INF)  # smallest gap, largest interaction, least room

        # 1. Leaders along the planned path (vehicles and the ego).
        best_path, best_a = INF, 0
        for a in range(n_a):
            pos = offset[f, lane_a[a]] + s_a[a]
            ahead = (pos > s[f] or (pos == s[f] and a > row)) and a != row
            g = pos - front - len_a[a] / 2 if ahead else INF
            if g < best_path:
                best_path, best_a = g, a
            state = _fold(state, g, v_a[a], min_gap, vf, vT, den[f], two_b)

        # 2. The corridor ahead (curvature-corrected).
        for o in range(n_o):
            rx = xy_o[o, 0] - xy[f, 0]
            ry = xy_o[o, 1] - xy[f, 1]
            dx = c[f] * rx + sn[f] * ry
            dy = -sn[f] * rx + c[f] * ry - 0.5 * kappa[f] * dx * dx
            cos_d = co[o] * c[f] + so[o] * sn[f]
            cd, sd = abs(cos_d), abs(so[o] * c[f] - co[o] * sn[f])
            ins = dx > 0 and dx < corridor_range and idx_o[o] != row
            ins = ins and abs(dy) < (width[f] / 2 + corridor_margin) + sd * hl_o[o] + cd * hw_o[o]
            g = dx - length[f] / 2 - cd * hl_o[o] - sd * hw_o[o] if ins else INF
            state = _fold(state, g, v_o[o] * cos_d, min_gap, vf, vT, den[f], two_b)

        # 3. Crosswalk stop lines.
        if n_k:
            path_gap = _minimum(best_path, 1e9)
            slow_leader = path_gap < 1e9 and v_a[best_a] < 3.0
            for k in range(n_k):
                stop = offset[f, cross_lane[k]] + (cross_s[k, 0] - crosswalk_margin) - front
                beyond = stop + (cross_s[k, 1] - cross_s[k, 0] + 2 * crosswalk_margin)
                no_room = slow_leader and path_gap - beyond < length[f] + min_gap
                blocked = no_room or blocked_k[k]
                g = stop if blocked and stop > -0.5 else INF
                state = _fold(state, g, 0.0, stop_gap, vf, vT, den[f], two_b)

        # 4. Roundabout merges: stop lines while a priority agent comes, room for committed entries.
        for y in range(n_y):
            if conflict_y[y]:
                stop = offset[f, yield_lane[y]] + yield_stop[y] - front
                holding = stop > -0.5 or (stop > -1.0 and vf < 1.0)
                state = _fold(state, stop if holding else INF, 0.0, stop_gap, vf, vT, den[f], two_b)
            if committed_y[y]:
                to_merge = offset[f, yield_merge[y]]
                through = offset[f, yield_lane[y]] < INF
                stop = to_merge - merge_clearance - front
                keep_out = not through and to_merge > 0 and stop > -0.5
                state = _fold(state, stop if keep_out else INF, 0.0, stop_gap, vf, vT, den[f], two_b)

        # 5. Urban: conflict zones on the follower's path.
        half_me = len_a[row] / 2
        for r in range(n_r):
            front_me = -offset_a[row, ap_lane[r]] + (s_a[row] + half_me)
            if not np.isfinite(front_me):
                continue
            timed, yields, tie = ap_timed[r], ap_yields[r], ap_tie[r]
            gives_way = yields or tie
            v_me, length_me = _maximum(v_a[row], 0.0), len_a[row]
            to_clear = _maximum(ap_s_out[r] + length_me - front_me, 0.0)
            t_clear = (np.sqrt(v_me * v_me + 2 * clear_accel * to_clear) - v_me) / clear_accel
            waited = waited_all[row]
            critical = critical_gap_crossing * _maximum(0.0, 1.0 - waited / impatience)
            me_stop = ap_stop[r] - front_me
            forcing = (waited >= impatience and v_me < held_speed and me_stop < at_line_m
                       and me_stop >= -committed_m and yields)
            # crossings (and merges inside junctions)
            soon = claimed_any = promised = occupied = first = False
            pace_me = _maximum(v_a[row], merge_speed)
            t_line_me = _maximum(ap_stop[r] - front_me, 0.0) / pace_me
            for k in range(n_on[r]):  # the agents on the other lane (the others neither conflict nor lead here)
                a = on_lane[r, k]
                if a == row:
                    continue
                stoppable = forcing and can_stop[a, r]
                if not held[a, r] and not stoppable and ttz[a, r] < t_clear + critical:
                    soon = True
                if claiming[a, r]:
                    claimed_any = True
                if inside[a, r]:
                    promised = True
                if in_zone[a, r]:
                    occupied = True
                if waiting_o[a, r]:
                    longer = waited_all[a] > waited or (waited_all[a] == waited and a < row)
                    if t_line_o[a, r] < t_line_me or (t_line_o[a, r] == t_line_me and longer):
                        first = True
            claimed = claimed_any and not yields and not tie and _can_stop(
                v_me, me_stop, claim_decel, stop_margin, held_speed, committed_m)
            for j in changing[:n_changing]:
                if j != row and np.hypot(slot_pos[vehicle_slots[j], 0] - ap_point[r, 0],
                                         slot_pos[vehicle_slots[j], 1] - ap_point[r, 1]) < changing_radius:
                    promised = True
            wait_timed = timed and ((yields and soon) or (tie and first))

            # merges: committed agents ahead are virtual leaders; outside junctions, a zipper
            d_me = ap_s_out[r] - front_me
            courteous = courteous_f[f] and ap_courtesy[r] and d_me < courtesy_range
            zipper = not timed and (gives_way or courteous)
            leader_gap, leader = INF, 0
            room_nearest, nearest = INF, 0
            for k in range(n_on[r]):
                a = on_lane[r, k]
                if a == row or not near[a, r]:
                    continue
                dt_ = d_them[a, r]
                if ap_merge[r] and dt_ < d_me and (inside[a, r] or zipper):
                    spacing = d_me - dt_ - len_a[a]
                    if spacing < leader_gap:
                        leader_gap, leader = spacing, a
                if not timed and dt_ >= d_me:
                    room_a = dt_ - d_me - length_me
                    if room_a < room_nearest:
                        room_nearest, nearest = room_a, a
            leader_speed = v_a[leader]
            letting_in = courteous_a[nearest] and ap_courtesy[r]
            cut_off = np.isfinite(room_nearest) and not letting_in and room_nearest < needed[nearest]
            wait_merge = not timed and yields and cut_off

            # stop lines
            holding = me_stop > -committed_m
            edge = ap_s_in[r] - edge_margin - front_me
            line_gap = INF
            if (wait_timed or wait_merge or (timed and (promised or claimed))) and holding:
                line_gap = me_stop
            if timed and occupied and edge > -committed_m:
                line_gap = _minimum(line_gap, edge)
            to_line = me_stop if gives_way and holding else INF
            to_give_way[f] = _minimum(to_give_way[f], to_line)
            state = _fold(state, line_gap, 0.0, stop_gap, vf, vT, den[f], two_b)
            state = _fold(state, leader_gap, leader_speed, min_gap, vf, vT, den[f], two_b)

        # ... and the end of an ending lane (an on-ramp) is a wall until the vehicle has moved over.
        if urban:
            k_end = -1
            for j in range(path.shape[1]):
                if path[f, j] >= 0:
                    k_end += 1
            last = path[f, max(k_end, 0)]
            lane_last = max(last, 0)
            ends = ending[lane_last] and last >= 0
            to_end = offset[f, lane_last] + lane_length[lane_last] - front
            state = _fold(state, to_end if ends else INF, 0.0, stop_gap, vf, vT, den[f], two_b)

        lead_gap[f], interaction[f], room[f] = state
    return lead_gap, interaction, room, to_give_way


@_inline
def _fold(state, gap: float, lead: float, s0: float, v: float, vT: float, den: float, two_b: float):
    """Add one column (gap [m], obstacle speed [m/s], s0 [m]) to a follower's (smallest gap, largest
    interaction, least room)."""
    smallest, strongest, least = state
    smallest = _minimum(smallest, gap)
    if gap < INF:
        s_star = s0 + _maximum(0.0, vT + v * (v - lead) / den)
        q = s_star / _maximum(gap, 0.05)
        strongest = _maximum(strongest, q * q)
        v_lead = _maximum(lead, 0.0)
        least = _minimum(least, gap - s0 + v_lead * v_lead / two_b)
    return smallest, strongest, least


@_jit
def _plan_distances(v, accel, t_plan):
    """Distance [m] (S, NV) each vehicle moves by each substep time t_plan (S,) [s] at speed v [m/s] and constant
    acceleration [m/s^2], stopping at zero speed (as `Traffic._make_plan`)."""
    n_s, n_v = len(t_plan), len(v)
    ds = np.empty((n_s, n_v))
    for i in range(n_s):
        t = t_plan[i]
        for n in range(n_v):
            vn, an = v[n], accel[n]
            if an < 0 and vn + an * t < 0:
                ds[i, n] = vn * vn / _maximum(-2 * an, 1e-9)
            else:
                ds[i, n] = vn * t + 0.5 * an * t * t
    return ds


@_inline
def _find_segment(g, gq: float, first: int, last: int) -> int:
    """`TrafficMap._segment`'s segment of a lane (segments first..last): np.searchsorted(g, gq, side="right") - 1
    clamped to [first, last], searched among the lane's own vertices (the same index: g is sorted, so the
    vertices before `first` and after `last` only move the unclamped index outside [first, last])."""
    if gq != gq:  # NaN sorts past the end
        return last
    lo, hi = first, last + 1
    while lo < hi:
        mid = (lo + hi) >> 1
        if g[mid] <= gq:
            lo = mid + 1
        else:
            hi = mid
    return max(lo - 1, first)


@_jit
def plan_centre_poses(v, accel, t_plan, s, before, path, base, lane_length, first, last_segment, g, inv, x0, dx, y0,
                      dy, h0, dh):
    """`_plan_distances` and then `centre_poses` of a plan in one pass: ds (S, NV) [m] and the centre-line x, y [m]
    and heading [rad] (S, NV)."""
    ds = _plan_distances(v, accel, t_plan)
    x, y, h = centre_poses(s, ds, before, path, base, lane_length, first, last_segment, g, inv, x0, dx, y0, dy, h0, dh)
    return ds, x, y, h


@_jit
def centre_poses(s, ds, before, path, base, lane_length, first, last_segment, g, inv, x0, dx, y0, dy, h0, dh):
    """Centre-line x, y [m] and heading [rad] (S, NV) of each vehicle's lane after moving ds (S, NV) [m] from s
    along its path (`before` (NV, PATH) [m]: to the start of each path lane), as `Traffic._centre_poses` and
    `TrafficMap.lookup` compute them. Each vehicle's segment search goes on from its previous substep's."""
    n_s, n_v, n_p = ds.shape[0], len(s), before.shape[1]
    x = np.empty((n_s, n_v))
    y = np.empty((n_s, n_v))
    h = np.empty((n_s, n_v))
    for n in range(n_v):
        last_index = -1  # `Traffic._last_path_index`
        for j in range(n_p):
            if path[n, j] >= 0:
                last_index += 1
        last_index = max(last_index, 0)
        previous_lane, seg = -1, 0
        for i in range(n_s):
            p = s[n] + ds[i, n]
            k = 0
            for j in range(1, n_p):
                if p >= before[n, j]:
                    k += 1
            k = min(k, last_index)
            lane = max(path[n, k], 0)
            gq = base[lane] + _minimum(_maximum(p - before[n, k], 0.0), lane_length[lane])
            if lane == previous_lane and gq >= g[seg]:  # further along the same lane: walk on
                while seg < last_segment[lane] and g[seg + 1] <= gq:
                    seg += 1
            else:
                seg = _find_segment(g, gq, first[lane], last_segment[lane])
            previous_lane = lane
            u = (gq - g[seg]) * inv[seg]
            x[i, n] = x0[seg] + u * dx[seg]
            y[i, n] = y0[seg] + u * dy[seg]
            h[i, n] = h0[seg] + u * dh[seg]
    return x, y, h


@_jit
def curve_speed(lane, s, base, lane_length, first, last_segment, g, inv, v0, dv, k0, dk):
    """`TrafficMap.curve_speed`: the anticipated curve speed [m/s] and the curvature [1/m] at s [m] on `lane`."""
    n = len(s)
    speed = np.empty(n)
    kappa = np.empty(n)
    for f in range(n):
        lane_f = lane[f]
        gq = base[lane_f] + _minimum(_maximum(s[f], 0.0), lane_length[lane_f])
        seg = _find_segment(g, gq, first[lane_f], last_segment[lane_f])
        u = (gq - g[seg]) * inv[seg]
        speed[f] = v0[seg] + u * dv[seg]
        kappa[f] = k0[seg] + u * dk[seg]
    return speed, kappa


@_jit
def desired_speed(path, offset, s, length, v0_own, vcurve, to_give_way, lane_length, entry_speed, speed_limit,
                  anticipation, yield_lane, yield_stop, yield_speed, v):
    """`following.idm`'s desired speed [m/s] of each follower: its own, the lane's limit, the curves ahead on
    this lane and the next, and slow enough to stop at yield lines (roundabout) and give-way lines ahead; and
    its speed's ratio to it, v / max(v0, 0.1) (whose 4th power, left to numpy, enters IDM)."""
    n_f, n_y = len(s), len(yield_lane)
    out = np.empty(n_f)
    ratio = np.empty(n_f)
    ys2 = yield_speed**2
    for f in range(n_f):
        lane0 = max(path[f, 0], 0)
        nxt = path[f, 1]
        vnext = INF
        if nxt >= 0:
            e = entry_speed[max(nxt, 0)]
            vnext = np.sqrt(e * e + 2 * anticipation * _maximum(lane_length[lane0] - s[f], 0.0))
        v0 = _minimum(_minimum(v0_own[f], speed_limit[lane0]), _minimum(vcurve[f], vnext))
        if n_y:
            front = s[f] + length[f] / 2
            to_line = INF
            for y in range(n_y):
                to_line = _minimum(to_line, offset[f, yield_lane[y]] + yield_stop[y] - front)
            if to_line > -0.5 and to_line < INF:
                v0 = _minimum(v0, np.sqrt(ys2 + 2 * 1.5 * _maximum(to_line, 0.0)))
        if to_give_way[f] < INF:
            v0 = _minimum(v0, np.sqrt(ys2 + 2 * 1.5 * _maximum(to_give_way[f], 0.0)))
        out[f] = v0
        ratio[f] = v[f] / _maximum(v0, 0.1)
    return out, ratio


@_jit
def idm_accel(a, v, v0, ratio4, interaction, room, tau, max_decel):
    """`following.idm`'s accelerations [m/s^2] from the desired speed v0, ratio4 = (v / max(v0, 0.1))^4 (a power,
    left to numpy), the interaction terms and the stopping rooms."""
    out = np.empty(len(v))
    b = max_decel
    for f in range(len(v)):
        vf = v[f]
        acc = a[f] * (1.0 - ratio4[f] - interaction[f])
        if vf <= v0[f]:
            acc = _minimum(acc, (v0[f] - vf) / tau)
        disc = 0.25 * tau * tau + 2.0 * (room[f] - 0.5 * vf * tau) / b
        w = b * (np.sqrt(_maximum(disc, 0.0)) - 0.5 * tau) if disc > 0 else 0.0
        acc = _minimum(acc, (w - vf) / tau if w > 0 else -vf * vf / (2 * _maximum(room[f], 1e-3)))
        out[f] = _maximum(_minimum(acc, a[f]), -max_decel)
    return out


@_jit
def place_vehicles(x, y, h, d, yaw, v, accel, t_plan, active, hidden_pos, slots, out_pos, out_yaw, out_speed):
    """Write the vehicles' poses into a plan: the centre line x, y [m] (S, NV) shifted by the lateral offset d
    [m] (S or 1, NV) along the normal (-sin h, cos h) of its heading h [rad] (S, NV), their yaw [rad] (S, NV) and
    speed max(v + a t, 0) [m/s]; inactive vehicles at their hidden pose. Into columns `slots` of out_pos (S, N, 3),
    out_yaw (S, N), out_speed (S, N), as `Traffic._offset_poses` and `_make_plan` do."""
    n_s, n_v = x.shape
    one_d = d.shape[0] == 1
    sin_h, cos_h = np.empty(n_v), np.empty(n_v)  # each vehicle's last heading's (libm's, as numpy's): a heading
    last_h = np.full(n_v, np.nan)  # held (along a straight, at rest) is not computed again (zeros are: their sign)
    for i in range(n_s):
        t = t_plan[i]
        for n in range(n_v):
            slot = slots[n]
            if active[n]:
                dn = d[0, n] if one_d else d[i, n]
                hn = h[i, n]
                if hn != last_h[n] or hn == 0.0:
                    sin_h[n], cos_h[n], last_h[n] = math.sin(hn), math.cos(hn), hn
                out_pos[i, slot, 0] = x[i, n] - sin_h[n] * dn
                out_pos[i, slot, 1] = y[i, n] + cos_h[n] * dn
                out_pos[i, slot, 2] = 0.0
                out_yaw[i, slot] = yaw[i, n]
                out_speed[i, slot] = _maximum(v[n] + accel[n] * t, 0.0)
            else:
                out_pos[i, slot, 0] = hidden_pos[n, 0]
                out_pos[i, slot, 1] = hidden_pos[n, 1]
                out_pos[i, slot, 2] = hidden_pos[n, 2]
                out_yaw[i, slot] = 0.0
                out_speed[i, slot] = _maximum(v[n] + accel[n] * t, 0.0) * 0.0  # as numpy's x * False


@_jit
def yaw_quats(yaw):
    """`geometry.yaw_quat` of a plan's yaw [rad] (S, N): quaternions (S, N, 4) (w, x, y, z) about z."""
    n_s, n = yaw.shape
    out = np.zeros((n_s, n, 4))
    for i in range(n_s):
        for j in range(n):
            if i and yaw[i, j] == yaw[i - 1, j] and yaw[i, j] != 0.0:  # a yaw held: the same quaternion (zeros
                # are computed again: their sign)
                out[i, j, 0], out[i, j, 3] = out[i - 1, j, 0], out[i - 1, j, 3]
                continue
            half = 0.5 * yaw[i, j]
            out[i, j, 0] = math.cos(half)
            out[i, j, 3] = math.sin(half)
    return out


@_jit
def intended_lane_change(intention, column, lane0, left, right, near_merge, ending, n_successors, priority, active,
                         lc_dist, s, lc_signal, lc_changing, pos, vehicle_slots, points, now, lane_change_length,
                         zone_distance, signal_time, left_code, right_code):
    """`lane_changes._intended`: update the signals `lc_signal` [s] (in place) and return the (row, side) of
    the vehicle that has signalled longest for at least `signal_time` (side 0: right, 1: left), or (-1, -1).
    Wishes: intention[:, column]; positions: pos (N, 3) [m] of the vehicles' slots."""
    wish = intention[:, column]
    best_row, best_signal = -1, INF
    for n in range(len(wish)):
        w = wish[n]
        if ending[lane0[n]]:  # a lane that ends beside a neighbour must be left, whatever the intention
            goes_on = left[n] >= 0 and n_successors[max(left[n], 0)] > 0
            w = left_code if goes_on else right_code
        target = left[n] if w == left_code else (right[n] if w == right_code else -1)
        if not (ending[lane0[n]] or priority[max(target, 0)] >= priority[lane0[n]]):
            target = -1  # never into a lane of lower rank
        able = active[n] and target >= 0 and lc_dist[n] >= lane_change_length and s[n] > 1.0 and not near_merge[n]
        if able and len(points):  # not across a conflict zone: the move takes a while
            nearest = INF
            for r in range(len(points)):
                slot = vehicle_slots[n]
                nearest = _minimum(nearest, np.hypot(pos[slot, 0] - points[r, 0], pos[slot, 1] - points[r, 1]))
            able = nearest > zone_distance
        if able and lc_signal[n] < 0:
            lc_signal[n] = now
        elif not (able or lc_changing[n]):
            lc_signal[n] = -1.0
        if able and lc_signal[n] >= 0 and now - lc_signal[n] >= signal_time and lc_signal[n] < best_signal:
            best_row, best_signal = n, lc_signal[n]
    if best_row < 0:
        return -1, -1
    w = wish[best_row]
    if ending[lane0[best_row]]:
        w = left_code if (left[best_row] >= 0 and n_successors[max(left[best_row], 0)] > 0) else right_code
    return best_row, (0 if w == right_code else 1)


@_jit
def choose_successors(rows, lane, u, successors, turn, ring, ring_exit, intention, ring_passed, ego_exit,
                      crossroad, roundabout, before_code, after_code):
    """`Traffic._choose_successor` under urban rules for vehicles `rows` on `lane` (K,), with their uniform
    draws u (K,): a random successor that honours their intentions (`intentions.successor_preference`), -1
    for dead ends; then `intentions.note_ring_progress` (updates `intention` and `ring_passed` in place)."""
    n_k, n_w = len(rows), successors.shape[1]
    chosen = np.empty(n_k, dtype=np.int64)
    allowed = np.zeros(n_w, dtype=np.bool_)
    valid_w = np.zeros(n_w, dtype=np.bool_)
    for k in range(n_k):
        row = rows[k]
        lane0 = max(lane[k], 0)
        wanted = intention[row, crossroad]
        before = intention[row, roundabout] == before_code
        passed = ring_passed[row]
        any_ok = any_take = any_exit = False
        for j in range(n_w):
            succ = successors[lane0, j]
            s0 = max(succ, 0)
            valid = succ >= 0
            exit_ = valid and ring_exit[s0]
            valid_w[j] = valid
            allowed[j] = valid and (turn[s0] < 0 or turn[s0] == wanted or ring_exit[s0])
            any_exit |= exit_
        if ego_exit >= 0 and any_exit:
            for j in range(n_w):
                succ = successors[lane0, j]
                exit_ = valid_w[j] and ring_exit[max(succ, 0)]
                take = exit_ and succ != ego_exit and (not passed if before else passed)
                any_take |= take
            for j in range(n_w):
                succ = successors[lane0, j]
                exit_ = valid_w[j] and ring_exit[max(succ, 0)]
                if any_take:
                    allowed[j] = exit_ and succ != ego_exit and (not passed if before else passed)
                else:
                    allowed[j] = valid_w[j] and not exit_
        for j in range(n_w):
            any_ok |= allowed[j]
        count = 0
        for j in range(n_w):
            if not any_ok:
                allowed[j] = valid_w[j]
            count += allowed[j]
        if lane[k] < 0:
            count = 0
        pick = np.int64(np.floor(u[k] * max(count, 1)))
        column, running = 0, 0
        for j in range(n_w):
            running += allowed[j]
            if running > pick:
                column = j
                break
        chosen[k] = successors[lane0, column] if count > 0 else -1
    if ego_exit >= 0:  # note_ring_progress
        for k in range(n_k):
            row, lane0, c = rows[k], max(lane[k], 0), chosen[k]
            at_ego_exit = False
            for j in range(n_w):
                at_ego_exit |= successors[lane0, j] == ego_exit
            passed = at_ego_exit and c != ego_exit and c >= 0
            if passed:
                intention[row, roundabout] = after_code
            left_ring = c >= 0 and not ring[max(c, 0)] and not ring_exit[max(c, 0)]
            ring_passed[row] = (ring_passed[row] or passed) and not left_ring
    return chosen


@_jit
def path_context(vehicle_path, active, ego_path, lane_length, n_lanes, s, v, length, ego_s, ego_v, ego_length):
    """`Traffic._context`'s lane-graph tables: the paths (A, PATH) of the vehicles (-1 rows for inactive ones)
    and the ego (last row, `ego_path`), the distance (A, PATH) [m] from each agent's lane start to the start
    of each lane on its path, and `offset` (A, n_lanes + 1) [m] to the start of every lane (inf off the
    path; the first occurrence on a path wins; column n_lanes collects the -1 lanes and is inf); and the agents'
    s [m], speed [m/s] and length [m] (A,): the vehicles', then the ego's."""
    nv, n_p = vehicle_path.shape
    s_a, v_a, length_a = np.empty(nv + 1), np.empty(nv + 1), np.empty(nv + 1)
    for r in range(nv):
        s_a[r], v_a[r], length_a[r] = s[r], v[r], length[r]
    s_a[nv], v_a[nv], length_a[nv] = ego_s, ego_v, ego_length
    path = np.full((nv + 1, n_p), -1, dtype=np.int64)
    for r in range(nv):
        if active[r]:
            for j in range(n_p):
                path[r, j] = vehicle_path[r, j]
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
    return path, start, offset, s_a, v_a, length_a


@_jit
def merge_state(lane_a, s_a, v_a, len_a, offset_a, yield_lane, yield_merge, yield_stop, active_v, lc_dist,
                lane_change_length, vehicle_slots, slot_pos, v, length, merge_xy, accept_gap, merge_clearance,
                merge_speed, start_clearance):
    """Roundabout merges (Y,): `merges.merge_conflicts` (a priority agent reaches the merge point too soon,
    still occupies the start of the merged lane, or is moving over near it) and whether an entering agent is
    committed past its yield line, as `following._merge_state` computes them."""
    n_y, n_a = len(yield_lane), len(s_a)
    conflict = np.zeros(n_y, dtype=np.bool_)
    committed = np.zeros(n_y, dtype=np.bool_)
    for y in range(n_y):
        merge = yield_merge[y]
        for a in range(n_a):
            to_merge = offset_a[a, merge]
            via = np.isfinite(offset_a[a, yield_lane[y]])
            dist = INF if (via or to_merge <= 0) else to_merge - (s_a[a] + len_a[a] / 2)
            soon = dist - merge_clearance < _maximum(v_a[a], merge_speed) * accept_gap
            on_start = lane_a[a] == merge and s_a[a] - len_a[a] / 2 < start_clearance
            if soon or on_start:
                conflict[y] = True
            if lane_a[a] == yield_lane[y]:
                past = s_a[a] + len_a[a] / 2 - yield_stop[y]
                if past > 1.0 or (past > 0.5 and v_a[a] >= 1.0):
                    committed[y] = True
        for c in range(len(active_v)):  # vehicles changing lane
            if not (active_v[c] and lc_dist[c] < lane_change_length):
                continue
            slot = vehicle_slots[c]
            near = np.hypot(slot_pos[slot, 0] - merge_xy[y, 0], slot_pos[slot, 1] - merge_xy[y, 1])
            reach = _maximum(v[c], merge_speed) * accept_gap + merge_clearance
            if near - length[c] / 2 < reach:
                conflict[y] = True
    return conflict, committed
