"""Motion: the closed-form motion of the vehicles over a decision period (constant acceleration, stopping at rest)
as a plan of poses at every substep, its commit as the new state, lanes passed, and waiting times.

Between decisions every vehicle moves ds = v t + a t^2 / 2 along its planned path (or v^2 / 2|a| once it would
stop), at its lateral offset; a lane change under way moves across along a smoothstep over `lane_change_length`.
"""

from __future__ import annotations

import math

import numpy as np

from mjdrive.compiled import inline, jit, maximum
from mjdrive.traffic.geometry import smoothstep
from mjdrive.traffic.intentions import next_lanes
from mjdrive.traffic.lanes import find_segment, flat_position
from mjdrive.traffic.pedestrians import commit_pedestrians, place_pedestrians
from mjdrive.traffic.state import Poses

STOPPED_SPEED = 1.0  # [m/s] a vehicle slower than this is waiting (urban rules: its patience runs down)


@jit
def substeps_due(accumulated, dt, substep):
    """The whole substeps [s] due after `dt` [s] more time, with `accumulated` [s] toward the next one, and the time
    [s] left toward the one after them."""
    total = accumulated + dt
    n = int(total / substep + 1e-6)
    return n, total - n * substep


@jit
def path_starts(path, lane_length):
    """(NV, PATH) [m] from each vehicle's lane start to the start of each lane on its path (inf past its end)."""
    n_v, n_p = path.shape
    before = np.zeros((n_v, n_p))
    for r in range(n_v):
        for j in range(1, n_p):
            previous = path[r, j - 1]
            length = lane_length[previous] if previous >= 0 else np.inf
            before[r, j] = length if j == 1 else before[r, j - 1] + length
    return before


@inline
def plan_distances(v, accel, t_plan):
    """Distance [m] (S, NV) each vehicle moves by each substep time t_plan (S,) [s] at speed v [m/s] and constant
    acceleration [m/s^2], stopping at zero speed."""
    n_s, n_v = len(t_plan), len(v)
    ds = np.empty((n_s, n_v))
    for i in range(n_s):
        t = t_plan[i]
        for n in range(n_v):
            vn, an = v[n], accel[n]
            if an < 0 and vn + an * t < 0:
                ds[i, n] = vn * vn / maximum(-2 * an, 1e-9)
            else:
                ds[i, n] = vn * t + 0.5 * an * t * t
    return ds


@inline
def centre_poses(lines, path, s, ds, before):
    """Centre-line x, y [m] and heading [rad] (S, NV) of each vehicle's lane after moving ds (S, NV) [m] from s
    along its path (`before` (NV, PATH) [m]: to the start of each path lane; a dead end's vehicle stays on its last
    lane). Each vehicle's segment search goes on from its previous substep's."""
    n_s, n_v, n_p = ds.shape[0], len(s), before.shape[1]
    x = np.empty((n_s, n_v))
    y = np.empty((n_s, n_v))
    h = np.empty((n_s, n_v))
    g, first, last_segment, inv = lines.g, lines.first, lines.last_segment, lines.inv
    x0, dx, y0, dy, h0, dh = lines.x0, lines.dx, lines.y0, lines.dy, lines.h0, lines.dh
    for n in range(n_v):
        last_index = -1  # the last lane on the path
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
            gq = flat_position(lines, lane, p - before[n, k])
            if lane == previous_lane and gq >= g[seg]:  # further along the same lane: walk on
                while seg < last_segment[lane] and g[seg + 1] <= gq:
                    seg += 1
            else:
                seg = find_segment(g, gq, first[lane], last_segment[lane])
            previous_lane = lane
            u = (gq - g[seg]) * inv[seg]
            x[i, n] = x0[seg] + u * dx[seg]
            y[i, n] = y0[seg] + u * dy[seg]
            h[i, n] = h0[seg] + u * dh[seg]
    return x, y, h


def lateral(vehicles, ds: np.ndarray, h: np.ndarray, lane_change_length: float) -> tuple[np.ndarray, np.ndarray]:
    """Lateral offset d [m] (S or 1, NV) from the centre line and yaw [rad] (S, NV) after moving ds (S, NV) [m]
    (lane changes under way move across along a smoothstep; h: the centre line's heading)."""
    if (vehicles.lc_dist < lane_change_length).any():  # lane changes under way
        sm, dsm = smoothstep((vehicles.lc_dist[None] + ds) / lane_change_length)
        d = vehicles.d_pref[None] + vehicles.lc_shift[None] * (1.0 - sm)
        return d, h + np.arctan(-vehicles.lc_shift[None] * dsm / lane_change_length)
    return vehicles.d_pref[None], h


@inline
def place_vehicles(vehicles, x, y, h, d, yaw, t_plan, hidden, out):
    """Write the vehicles' poses into `out` (Poses (S, N, ...), at their slots): the centre line x, y [m] (S, NV)
    shifted by the lateral offset d [m] (S or 1, NV) along the normal (-sin h, cos h) of its heading h [rad] (S, NV),
    their yaw [rad] (S, NV) and speed max(v + a t, 0) [m/s] at the times t_plan (S,) [s]; inactive vehicles at their
    hidden position (NV, 3) [m]. (Quaternions: `yaw_quats`.)"""
    n_s, n_v = x.shape
    one_d = d.shape[0] == 1
    v, accel, active, slots = vehicles.v, vehicles.accel, vehicles.active, vehicles.slot
    out_pos, out_yaw, out_speed = out.pos, out.yaw, out.speed
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
                out_speed[i, slot] = maximum(v[n] + accel[n] * t, 0.0)
            else:
                out_pos[i, slot, 0] = hidden[n, 0]
                out_pos[i, slot, 1] = hidden[n, 1]
                out_pos[i, slot, 2] = hidden[n, 2]
                out_yaw[i, slot] = 0.0
                out_speed[i, slot] = maximum(v[n] + accel[n] * t, 0.0) * 0.0  # as numpy's x * False


@inline
def yaw_quats(yaw, out):
    """Quaternions (w, x, y, z) about z of yaw [rad] (S, N) into out (S, N, 4) (zeros in x and y)."""
    n_s, n = yaw.shape
    for i in range(n_s):
        for j in range(n):
            if i and yaw[i, j] == yaw[i - 1, j] and yaw[i, j] != 0.0:  # a yaw held: the same quaternion (zeros
                # are computed again: their sign)
                out[i, j, 0], out[i, j, 3] = out[i - 1, j, 0], out[i - 1, j, 3]
                continue
            half = 0.5 * yaw[i, j]
            out[i, j, 0] = math.cos(half)
            out[i, j, 3] = math.sin(half)


@jit
def plan_centres(vehicles, lines, t_plan, before, distances):
    """The distances ds (S, NV) [m] the vehicles move by the times t_plan (S,) [s] (`plan_distances`; without
    `distances`, none: ds (1, NV) of zeros) and their centre-line poses there (`centre_poses`; before:
    `path_starts`)."""
    ds = plan_distances(vehicles.v, vehicles.accel, t_plan) if distances else np.zeros((1, len(vehicles.v)))
    x, y, h = centre_poses(lines, vehicles.path, vehicles.s, ds, before)
    return ds, x, y, h


@jit
def place(vehicles, pedestrians, x, y, h, d, yaw, t_plan, hidden, out, walkers):
    """The vehicles' poses from their centre-line poses and lateral offsets (`place_vehicles`), the pedestrians' if
    `walkers` (`pedestrians.place_pedestrians`), at the times t_plan (S,) [s] into `out` (Poses (S, N, ...)), and
    every slot's quaternion from its yaw (`yaw_quats`)."""
    place_vehicles(vehicles, x, y, h, d, yaw, t_plan, hidden, out)
    if walkers:
        place_pedestrians(pedestrians, t_plan, out)
    yaw_quats(out.yaw, out.quat)


def vehicle_plan(vehicles, pedestrians, lines, t_plan: np.ndarray, before: np.ndarray, hidden: np.ndarray,
                 lane_change_length: float, out: Poses, distances: bool = True, walkers: bool = True) -> None:
    """The vehicles' poses at the times t_plan (S,) [s] of a plan into `out` (their slots of its pos, yaw and
    speed): moved along their paths (`before`: `path_starts`) by `plan_distances` (or not at all, without
    `distances`), at their lateral offsets; the pedestrians' with `walkers`; every slot's quaternion."""
    ds, x, y, h = plan_centres(vehicles, lines, t_plan, before, distances)
    d, yaw = lateral(vehicles, ds, h, lane_change_length)
    place(vehicles, pedestrians, x, y, h, d, yaw, t_plan, hidden, out, walkers and len(pedestrians.u) > 0)


@inline
def commit_vehicles(vehicles, t_end, t_end2):
    """The vehicles' state `t_end` [s] into the plan (`t_end2` = t_end**2 as numpy squares it), in place: the
    distance each moved at its constant acceleration, stopping at rest, added to s and lc_dist [m]; its new speed
    [m/s] (0 for inactive vehicles)."""
    v, accel, active, s, lc_dist = vehicles.v, vehicles.accel, vehicles.active, vehicles.s, vehicles.lc_dist
    for r in range(len(v)):
        vr, ar = v[r], accel[r]
        if active[r]:
            if ar < 0 and vr + ar * t_end < 0:
                ds = vr * vr / maximum(-2 * ar, 1e-9)
            else:
                ds = vr * t_end + 0.5 * ar * t_end2
        else:
            ds = 0.0
        s[r] += ds
        lc_dist[r] += ds
        v[r] = maximum(vr + ar * t_end, 0.0) if active[r] else 0.0


@jit
def commit(vehicles, pedestrians, t_end, t_end2):
    """The state `t_end` [s] into the plan (`t_end2` = t_end**2 as numpy squares it), in place: the vehicles'
    (`commit_vehicles`) and the pedestrians' (`pedestrians.commit_pedestrians`); returns who arrived at a kerb."""
    commit_vehicles(vehicles, t_end, t_end2)
    return commit_pedestrians(pedestrians, t_end)


@inline
def waited_after(waited: float, present: bool, speed: float, period: float) -> float:
    """A road user's waiting time [s] one decision period [s] on: reset unless it is present and slower than
    STOPPED_SPEED (creeping up to a give-way line does not reset it). The vehicles' (`count_waiting`) and the
    ego's (`Traffic.ego_waited`)."""
    return waited + period if present and speed < STOPPED_SPEED else 0.0


@inline
def count_waiting(vehicles, period):
    """Each vehicle's waiting time [s] one decision period [s] on, in place (`waited_after`)."""
    active, v, stopped_time = vehicles.active, vehicles.v, vehicles.stopped_time
    for r in range(len(v)):
        stopped_time[r] = waited_after(stopped_time[r], active[r], v[r], period)


@inline
def lanes_passed(vehicles, lane_length, exits):
    """One round of moving on along the paths, in place: active vehicles past the end of their lane (s >= its
    length [m]) move on to the next lane of their path (s less that length, the path shifted by one, its last
    entry left for the caller to draw); those whose path ends there, or whose lane was an exit (exits (L,) bool:
    the road goes on, the traffic does not), leave the map (inactive, speed 0). Returns the rows that moved on (K,),
    in order, and how many of them left."""
    path, s, active, v = vehicles.path, vehicles.s, vehicles.active, vehicles.v
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
        passed = path[r, 0]
        s[r] -= lane_length[passed]
        for c in range(n_p - 1):
            path[r, c] = path[r, c + 1]
        if path[r, 0] < 0 or exits[passed]:
            active[r] = False
            v[r] = 0.0
            gone += 1
    return rows[:k], gone


@jit
def end_period(vehicles, lane_length, exits, waiting_period):
    """A decision period over: the waiting times run on by `waiting_period` [s] (urban rules; 0: not counted;
    `count_waiting`), then one round of `lanes_passed`."""
    if waiting_period > 0:
        count_waiting(vehicles, waiting_period)
    return lanes_passed(vehicles, lane_length, exits)


@jit
def extend_then_lanes_passed(vehicles, routes, lane_length, exits, rows, u):
    """The end of a round of `lanes_passed` and the next round: the vehicles `rows` that moved on draw their path's
    new last lane with the uniform draws u (K,) (`intentions.next_lanes`), then `lanes_passed`."""
    path = vehicles.path
    n_p = path.shape[1]
    previous = np.empty(len(rows), dtype=np.int64)
    for j in range(len(rows)):
        previous[j] = path[rows[j], n_p - 2]
    chosen = next_lanes(routes, vehicles.intention, vehicles.ring_passed, rows, previous, u)
    for j in range(len(rows)):
        path[rows[j], n_p - 1] = chosen[j]
    return lanes_passed(vehicles, lane_length, exits)


def move_on(vehicles, routes, lane_length: np.ndarray, exits: np.ndarray, rng: np.random.Generator,
            waiting_period: float) -> int:
    """A decision period over (`end_period`), vehicles past the end of their lane move on along their path, drawing
    the lanes their paths gain (or leave the map at dead ends and exits, (L,) bool); how many left."""
    rows, gone = end_period(vehicles, lane_length, exits, waiting_period)
    left = 0
    while len(rows):
        left += gone
        rows, gone = extend_then_lanes_passed(vehicles, routes, lane_length, exits, rows, rng.random(len(rows)))
    return left
