"""Following: the IDM acceleration of every follower against the most constraining of its obstacles (path
leaders, the corridor ahead, crosswalk and merge stop lines, conflict zones, the end of an ending lane), with a
safety cap.

Every obstacle is a column of a follower's gap table: a gap [m] (bumper to obstacle), the obstacle's speed [m/s]
and the minimum gap s0 [m]. `gap_summary` walks every (follower, obstacle) pair once and keeps only what the IDM
needs of the table (`_fold`): the smallest gap, the strongest interaction (s*/gap)^2 and the least stopping room.
"""

from __future__ import annotations

import math

import numpy as np

from mjdrive.compiled import helper, inline, jit, maximum, minimum
from mjdrive.traffic.conflicts import zone_stops
from mjdrive.traffic.lanes import curve_speed
from mjdrive.traffic.merges import merge_state, merge_stops
from mjdrive.traffic.pedestrians import BAND_MARGIN, SLOW_LEADER, crosswalk_stop, occupied_crossings
from mjdrive.traffic.state import Agents, Followers

INF = np.inf
LINE_DECEL = 1.5  # [m/s^2] followers approach yield and give-way lines slowly enough to stop there at this braking
MIN_DESIRED_SPEED = 0.1  # [m/s] IDM's free-road term divides by the desired speed, at least this
MIN_GAP_DIVISOR = 0.05  # [m] ... and its interaction term by the gap, at least this
ONCOMING_COS = -0.5  # a vehicle heading more than 120 degrees away from a follower's heading comes towards it


def accelerations(followers: Followers, agents: Agents, vehicles, pedestrians, now, half_size: np.ndarray,
                  ego: np.ndarray, tables, c, accept_gap: float, control: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IDM accelerations [m/s^2] of `followers` (rows of `agents`) and their smallest gaps [m] (inf where none), capped
    so that each can still stop within its room whatever the obstacle does (`gap_table`, `idm`). control (A,): [m] to
    the junction-control line each agent must stop at (inf: none; `junction_control.stop_gaps`)."""
    lead_gap, interaction, room, v0, ratio = gap_table(followers, agents, vehicles, pedestrians, now, half_size, ego,
                                                       tables, c, accept_gap, control)
    ratio4 = ratio**4  # numpy's power (the numbers every trajectory was recorded with; not libm's pow)
    return idm(followers.a_max, followers.v, v0, ratio4, interaction, room, c.decision_period, c.max_decel), lead_gap


@jit
def gap_table(followers, agents, vehicles, pedestrians, now, half_size, ego, tables, c, accept_gap, control):
    """Every follower's gap table reduced (`gap_summary`: the smallest gap [m], the largest interaction term, the least
    room [m]) and its desired speed [m/s] with its speed's ratio to it (`desired_speed`), among the corridor's
    obstacles now (`obstacles_now`; ego: its box, or empty) and the agents on the lane graph. `tables`: the traffic's
    `MapTables`; c: its `Constants`; accept_gap [s]: at roundabout merges; control (A,) [m]: junction-control lines."""
    obstacles = obstacles_now(vehicles, pedestrians.slot, now, half_size, ego)
    vcurve, kappa = curve_speed(tables.polylines, np.maximum(followers.path[:, 0], 0), followers.s)
    lead_gap, interaction, room, to_give_way = gap_summary(followers, agents, obstacles, vehicles, pedestrians,
                                                           now.pos, kappa, tables, c, accept_gap, control)
    v0, ratio = desired_speed(followers, vcurve, to_give_way, tables.lanes, tables.merges, c.yield_speed)
    return lead_gap, interaction, room, v0, ratio


@inline
def obstacles_now(vehicles, pedestrian_slots, now, half_size, ego):
    """What the corridor check sees (O,): the active vehicles, the pedestrians (slots), then the ego if `ego` (x, y [m],
    yaw [rad], speed [m/s], half length and width [m]) is not empty, at the slots' poses `now` (half sizes (N, 3)
    [m]): centres (O, 2) [m], yaws [rad], speeds [m/s], half lengths and widths [m], and the follower row each is
    (vehicle row, NV for the ego, -1 for pedestrians)."""
    active, vehicle_slots = vehicles.active, vehicles.slot
    n_active = 0
    for r in range(len(active)):
        n_active += active[r]
    n = n_active + len(pedestrian_slots) + (1 if len(ego) else 0)
    xy, yaw, speed = np.empty((n, 2)), np.empty(n), np.empty(n)
    hl, hw, row = np.empty(n), np.empty(n), np.empty(n, dtype=np.int64)
    k = 0
    for j in range(len(active) + len(pedestrian_slots)):
        if j < len(active):
            if not active[j]:
                continue
            slot, row[k] = vehicle_slots[j], j
        else:
            slot, row[k] = pedestrian_slots[j - len(active)], -1
        xy[k, 0], xy[k, 1] = now.pos[slot, 0], now.pos[slot, 1]
        yaw[k], speed[k] = now.yaw[slot], now.speed[slot]
        hl[k], hw[k] = half_size[slot, 0], half_size[slot, 1]
        k += 1
    if len(ego):
        xy[k, 0], xy[k, 1], yaw[k], speed[k], hl[k], hw[k] = ego[0], ego[1], ego[2], ego[3], ego[4], ego[5]
        row[k] = len(active)
    return xy, yaw, speed, hl, hw, row


@helper
def _fold(state, gap: float, lead: float, s0: float, v: float, vT: float, den: float, two_b: float):
    """Add one column (gap [m], obstacle speed [m/s], s0 [m]) to a follower's (smallest gap, largest
    interaction, least room) (v: its speed [m/s], vT: v times its headway [m], den: IDM's 2 sqrt(a b) [m/s^2],
    two_b: twice the emergency braking [m/s^2])."""
    smallest, strongest, least = state
    smallest = minimum(smallest, gap)
    if gap < INF:
        s_star = s0 + maximum(0.0, vT + v * (v - lead) / den)
        q = s_star / maximum(gap, MIN_GAP_DIVISOR)
        strongest = maximum(strongest, q * q)
        v_lead = maximum(lead, 0.0)
        least = minimum(least, gap - s0 + v_lead * v_lead / two_b)
    return smallest, strongest, least


@helper
def gap_summary(followers, agents, obstacles, vehicles, pedestrians, slot_pos, kappa, tables, c, accept_gap, control):
    """For every follower: the smallest gap [m] of its gap table (inf if none), the largest IDM interaction term
    (s*/gap)^2, the least stopping room [m] (gap - s0 + v_lead^2 / 2 max_decel; inf if none) and the distance [m]
    to its nearest give-way line still ahead (inf if none). kappa: the curvature [1/m] at each follower (the
    corridor bends with it)."""
    f_, lanes, crossings, merges = followers, tables.lanes, tables.crossings, tables.merges
    # the arrays the loops read, as locals (reading a NamedTuple's array in a loop costs reference counting there)
    path, offset, s, v, length, width, f_xy = f_.path, f_.offset, f_.s, f_.v, f_.length, f_.width, f_.xy
    lane_a, s_a, v_a, len_a = agents.path[:, 0], agents.s, agents.v, agents.length
    o_xy, o_yaw, o_speed, o_hl, o_hw, o_row = obstacles
    n_f, n_a, n_o, n_k = len(s), len(s_a), len(o_row), len(crossings.lane)
    n_vehicles = len(vehicles.active)  # obstacle rows below this are the traffic's vehicles (this one: the ego)
    ego_on_lanes = agents.path[n_vehicles, 0] >= 0  # the ego is on its route's lanes
    lead_gap = np.full(n_f, INF)
    interaction = np.zeros(n_f)
    room = np.full(n_f, INF)
    two_b = 2 * c.max_decel
    den = 2.0 * np.sqrt(f_.a_max * f_.b_comf)  # [m/s^2] IDM's 2 sqrt(a b)
    cos_f, sin_f = np.empty(n_f), np.empty(n_f)  # the followers' headings' cosines and sines (libm's, as numpy's)
    for f in range(n_f):
        cos_f[f], sin_f[f] = math.cos(f_.yaw[f]), math.sin(f_.yaw[f])
    cos_o, sin_o = np.empty(n_o), np.empty(n_o)  # the obstacles'
    for o in range(n_o):
        cos_o[o], sin_o[o] = math.cos(o_yaw[o]), math.sin(o_yaw[o])
    blocked = occupied_crossings(pedestrians, crossings, c.crosswalk_margin + BAND_MARGIN)
    conflict, committed = merge_state(agents, vehicles, merges, slot_pos, accept_gap, c)
    z_start, z_line, z_gap, z_speed, to_give_way = zone_stops(f_, agents, vehicles, tables.approaches, slot_pos, c,
                                                              control)

    for f in range(n_f):
        row, offset_f = f_.row[f], offset[f]
        front = s[f] + length[f] / 2
        vf = v[f]
        vT = vf * f_.headway[f]
        state = (INF, 0.0, INF)  # smallest gap, largest interaction, least room

        # 1. Leaders along the planned path (vehicles and the ego).
        best_path, best_a = INF, 0
        for a in range(n_a):
            g = path_gap(offset_f, s[f], front, row, a, lane_a, s_a, len_a)
            if g < best_path:
                best_path, best_a = g, a
            state = _fold(state, g, v_a[a], c.min_gap, vf, vT, den[f], two_b)

        # 2. Anything in the corridor ahead (curvature-corrected): vehicles, the ego, pedestrians.
        for o in range(n_o):
            rx = o_xy[o, 0] - f_xy[f, 0]
            ry = o_xy[o, 1] - f_xy[f, 1]
            dx = cos_f[f] * rx + sin_f[f] * ry
            dy = -sin_f[f] * rx + cos_f[f] * ry - 0.5 * kappa[f] * dx * dx
            cos_d = cos_o[o] * cos_f[f] + sin_o[o] * sin_f[f]  # of the obstacle's yaw relative to the follower
            cd, sd = abs(cos_d), abs(sin_o[o] * cos_f[f] - cos_o[o] * sin_f[f])
            hl, hw = o_hl[o], o_hw[o]
            # Under urban rules an oncoming vehicle of the traffic, or the ego on its lanes, keeps to its own lane: the
            # lanes that cross or merge are conflict zones (5.), so the corridor does not stop for it (two oncoming
            # turners would wait for each other). The ego off its lanes stays in the corridor; the roundabouts of
            # study 000 keep their rules.
            oncoming = tables.urban and cos_d < ONCOMING_COS and o_row[o] >= 0 and (
                o_row[o] < n_vehicles or ego_on_lanes)
            inside = dx > 0 and dx < c.corridor_range and o_row[o] != row and not oncoming
            inside = inside and abs(dy) < (width[f] / 2 + c.corridor_margin) + sd * hl + cd * hw
            g = dx - length[f] / 2 - cd * hl - sd * hw if inside else INF
            state = _fold(state, g, o_speed[o] * cos_d, c.min_gap, vf, vT, den[f], two_b)

        # 3. Crosswalk stop lines.
        if n_k:
            leader_gap = minimum(best_path, 1e9)
            slow_leader = leader_gap < 1e9 and v_a[best_a] < SLOW_LEADER
            for k in range(n_k):
                g = crosswalk_stop(offset_f, front, length[f], crossings, k, blocked[k], slow_leader, leader_gap,
                                   c.crosswalk_margin, c.min_gap)
                state = _fold(state, g, 0.0, c.stop_gap, vf, vT, den[f], two_b)

        # 4. Roundabout merges: stop lines while a priority agent comes, room for committed entries.
        for y in range(len(merges.lane)):
            line, keep_out = merge_stops(offset_f, front, vf, merges, y, conflict[y], committed[y],
                                         c.merge_clearance)
            state = _fold(state, line, 0.0, c.stop_gap, vf, vT, den[f], two_b)
            state = _fold(state, keep_out, 0.0, c.stop_gap, vf, vT, den[f], two_b)

        # 5. Urban rules: conflict zones on the follower's path.
        for k in range(z_start[f], z_start[f + 1]):
            state = _fold(state, z_line[k], 0.0, c.stop_gap, vf, vT, den[f], two_b)
            state = _fold(state, z_gap[k], z_speed[k], c.min_gap, vf, vT, den[f], two_b)

        # ... and the end of an ending lane (an on-ramp) is a wall until the vehicle has moved over.
        if tables.urban:
            k_end = -1
            for j in range(path.shape[1]):
                if path[f, j] >= 0:
                    k_end += 1
            last = path[f, max(k_end, 0)]
            lane_last = max(last, 0)
            ends = lanes.ending[lane_last] and last >= 0
            to_end = offset_f[lane_last] + lanes.length[lane_last] - front
            state = _fold(state, to_end if ends else INF, 0.0, c.stop_gap, vf, vT, den[f], two_b)

        # 6. Junction control: red lights, amber, stop signs not yet stopped at (a line, like a give-way line).
        state = _fold(state, control[row], 0.0, c.stop_gap, vf, vT, den[f], two_b)
        to_give_way[f] = minimum(to_give_way[f], control[row])

        lead_gap[f], interaction[f], room[f] = state
    return lead_gap, interaction, room, to_give_way


@inline
def path_gap(offset_f, s, front, row, a, lane_a, s_a, len_a):
    """The gap [m] from a follower (agent `row`, at s [m] along its lane, its front bumper at `front` [m]; offset_f:
    its row of `Agents.offset`) to agent a's rear bumper if a is ahead on its path (at the same s: the higher row is
    ahead), else inf (the agents' lanes, s [m] and lengths [m]: lane_a, s_a, len_a)."""
    pos = offset_f[lane_a[a]] + s_a[a]
    ahead = (pos > s or (pos == s and a > row)) and a != row
    return pos - front - len_a[a] / 2 if ahead else INF


@jit
def path_leader(agents, row):
    """The nearest agent ahead of agent `row` on its path: the gap [m] from its front bumper to that agent's rear
    bumper and that agent's speed [m/s] ((inf, 0.0): none)."""
    lane_a, s_a, len_a = agents.path[:, 0], agents.s, agents.length
    s, front, offset_row = s_a[row], s_a[row] + len_a[row] / 2, agents.offset[row]
    best, speed = INF, 0.0
    for a in range(len(s_a)):
        g = path_gap(offset_row, s, front, row, a, lane_a, s_a, len_a)
        if g < best:
            best, speed = g, agents.v[a]
    return best, speed


@jit
def queued_rows(agents, rows, gap, speed):
    """(len(rows),) whether each agent row stands within `gap` [m] behind a leader on its path slower than
    `speed` [m/s] (a queue, not a stop of its own)."""
    out = np.zeros(rows, dtype=np.bool_)
    for row in range(rows):
        g, v = path_leader(agents, row)
        out[row] = g < gap and v < speed
    return out


@inline
def desired_speed(followers, vcurve, to_give_way, lanes, merges, yield_speed):
    """Each follower's desired speed [m/s]: its own, the lane's limit, the curves ahead on this lane and the next
    (vcurve [m/s]: this lane's), and slow enough to stop at yield lines (roundabout merges) and give-way lines ahead
    (to_give_way [m]) braking at LINE_DECEL, reaching them at `yield_speed` [m/s] at most; and its speed's ratio to
    it, v / max(v0, MIN_DESIRED_SPEED) (whose 4th power, left to numpy, enters IDM)."""
    f_ = followers
    path, s = f_.path, f_.s
    n_f, n_y = len(s), len(merges.lane)
    out = np.empty(n_f)
    ratio = np.empty(n_f)
    ys2 = yield_speed**2
    for f in range(n_f):
        lane0 = max(path[f, 0], 0)
        nxt = path[f, 1]
        vnext = INF
        if nxt >= 0:
            e = lanes.entry_speed[max(nxt, 0)]
            vnext = np.sqrt(e * e + 2 * lanes.anticipation * maximum(lanes.length[lane0] - s[f], 0.0))
        v0 = minimum(minimum(f_.v0[f], lanes.speed_limit[lane0]), minimum(vcurve[f], vnext))
        if n_y:
            front = s[f] + f_.length[f] / 2
            to_line = INF
            for y in range(n_y):
                to_line = minimum(to_line, f_.offset[f, merges.lane[y]] + merges.stop[y] - front)
            if to_line > -0.5 and to_line < INF:
                v0 = minimum(v0, np.sqrt(ys2 + 2 * LINE_DECEL * maximum(to_line, 0.0)))
        if to_give_way[f] < INF:
            v0 = minimum(v0, np.sqrt(ys2 + 2 * LINE_DECEL * maximum(to_give_way[f], 0.0)))
        out[f] = v0
        ratio[f] = f_.v[f] / maximum(v0, MIN_DESIRED_SPEED)
    return out, ratio


@jit
def idm(a, v, v0, ratio4, interaction, room, tau, max_decel):
    """IDM accelerations [m/s^2] (a: the maximum [m/s^2]; v, v0: speed and desired speed [m/s]; ratio4: (v /
    max(v0, MIN_DESIRED_SPEED))^4; the interaction terms and stopping rooms [m] of `gap_summary`), no overshoot of
    v0 within the decision period tau [s], and capped (Krauss-like) so that whatever the obstacle does (braking at
    max_decel [m/s^2]) the follower can still stop s0 short of it after this period: with the end speed w of the
    period, distance (v + w) tau / 2 + w^2 / (2 b) <= gap - s0 + v_lead^2 / (2 b)."""
    out = np.empty(len(v))
    b = max_decel
    for f in range(len(v)):
        vf = v[f]
        acc = a[f] * (1.0 - ratio4[f] - interaction[f])
        if vf <= v0[f]:
            acc = minimum(acc, (v0[f] - vf) / tau)
        disc = 0.25 * tau * tau + 2.0 * (room[f] - 0.5 * vf * tau) / b
        w = b * (np.sqrt(maximum(disc, 0.0)) - 0.5 * tau) if disc > 0 else 0.0
        # no positive end speed fits: stop within the room (the period's motion stops at v = 0)
        acc = minimum(acc, (w - vf) / tau if w > 0 else -vf * vf / (2 * maximum(room[f], 1e-3)))
        out[f] = maximum(minimum(acc, a[f]), -max_decel)
    return out
