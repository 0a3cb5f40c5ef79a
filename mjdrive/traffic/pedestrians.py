"""Pedestrians: wait at the kerb, cross on their track when no vehicle could fail to stop, and the crossings they
occupy (vehicles stop before them: `crosswalk_stop`)."""

from __future__ import annotations

import numpy as np

from mjdrive.compiled import inline, jit, maximum, minimum
from mjdrive.traffic.params import N_TRACKS
from mjdrive.traffic.spawning import uniform
from mjdrive.traffic.state import Pedestrians

BAND_MARGIN = 0.3  # [m] a crossing is occupied by a walker this far beyond the lane's band (plus crosswalk_margin)
EGO_REACH = 7.0  # [m] pedestrians do not start while the ego's centre is this close to the crosswalk's centre ...
EGO_REACH_PER_SPEED = 3.0  # [s] ... plus this times its speed
SLOW_LEADER = 3.0  # [m/s] a leader slower than this may leave no room beyond a crosswalk


def on_crosswalks(traffic_map, slots: np.ndarray, kerb: float) -> Pedestrians:
    """Pedestrians in `slots` on the map's crosswalks, in turn, each on one of N_TRACKS tracks (so two never
    overlap), waiting `kerb` [m] beyond the crosswalk's end; at rest, for `reset` to place."""
    m, n = traffic_map, len(slots)
    if n and m.n_crosswalks == 0:
        raise ValueError("pedestrians need a road map with crosswalks")
    if n > N_TRACKS * max(m.n_crosswalks, 1):
        raise ValueError(f"at most {N_TRACKS} pedestrians per crosswalk ({N_TRACKS * m.n_crosswalks} on this map), "
                         f"got {n}")
    cw = np.arange(n) % max(m.n_crosswalks, 1)
    tracks = (np.arange(n) // max(m.n_crosswalks, 1)) % N_TRACKS
    offset = (tracks - 1.0) * m.cw_width[cw] / N_TRACKS if n else np.zeros(0)  # [m] along the road
    return Pedestrians(slots, cw, m.cw_half_length[cw] + kerb, m.cw_centre[cw].reshape(-1, 2),
                       m.cw_along[cw].reshape(-1, 2), (offset[:, None] * m.cw_across[cw]).reshape(-1, 2),
                       m.cw_heading[cw], np.zeros(n), np.ones(n), np.zeros(n, dtype=bool), np.zeros(n), np.zeros(n))


def new_waits(pedestrians: Pedestrians, arrived: np.ndarray, wait: tuple[float, float],
              rng: np.random.Generator) -> None:
    """Pedestrians who `arrived` at the far kerb (`commit_pedestrians`) draw a new wait [s] (uniform in `wait`)."""
    if arrived.any():
        lo, hi = wait
        pedestrians.wait[arrived] = uniform(rng, lo, hi, int(arrived.sum()))


@inline
def commit_pedestrians(pedestrians, t_end):
    """The walkers move `t_end` [s] on along their crosswalk (clipped to the kerbs), those who reached the far kerb
    stop and turn; every wait runs down by t_end (in place). Returns who arrived (for their new waits' draws)."""
    p_ = pedestrians
    n = len(p_.u)
    arrived = np.zeros(n, dtype=np.bool_)
    for p in range(n):
        u = p_.u[p] + p_.direction[p] * p_.speed[p] * t_end if p_.walking[p] else p_.u[p]
        arrived[p] = p_.walking[p] and p_.direction[p] * u >= p_.end[p]
        lo, hi = -p_.end[p], p_.end[p]
        u = u if (u != u or u > lo) else lo  # np.clip's maximum then minimum
        p_.u[p] = u if (u != u or u < hi) else hi
        p_.walking[p] = p_.walking[p] and not arrived[p]
        if arrived[p]:
            p_.direction[p] = -p_.direction[p]
        p_.wait[p] -= t_end
    return arrived


@jit
def start_crossing(pedestrians, agents, b_agents, crossings, ego_x, ego_y, ego_reach):
    """Waiting pedestrians whose wait is over start walking (in place) unless an agent (A,) is on their crosswalk or
    too close to stop before it (braking at b_agents (A,) [m/s^2]), or the ego's centre (x, y) [m] is within
    `ego_reach` [m] of the crosswalk's centre (no ego: a negative reach)."""
    p_ = pedestrians
    ready = np.empty(len(p_.walking), dtype=np.bool_)
    any_ready = False
    for p in range(len(p_.walking)):
        ready[p] = not p_.walking[p] and p_.wait[p] <= 0.0
        any_ready |= ready[p]
    if not any_ready:
        return
    s, v, length = agents.s, agents.v, agents.length
    unsafe = np.zeros(len(crossings.centre), dtype=np.bool_)
    for a in range(len(s)):
        stopping = v[a] * v[a] / (2 * b_agents[a]) + v[a] + 1.0
        for k in range(len(crossings.lane)):
            base = agents.offset[a, crossings.lane[k]]
            front = base + crossings.s[k, 0] - (s[a] + length[a] / 2)
            rear_past = base + crossings.s[k, 1] - (s[a] - length[a] / 2)
            if rear_past > 0 and front < stopping:
                unsafe[crossings.crosswalk[k]] = True
    if ego_reach >= 0:
        for c in range(len(crossings.centre)):
            if np.hypot(crossings.centre[c, 0] - ego_x, crossings.centre[c, 1] - ego_y) < ego_reach:
                unsafe[c] = True
    for p in range(len(p_.walking)):
        if ready[p] and not unsafe[p_.crosswalk[p]]:
            p_.walking[p] = True


@inline
def occupied_crossings(pedestrians, crossings, margin):
    """Crossings (K,) with a pedestrian walking in the lane's band (+ margin [m]) or towards it."""
    p_ = pedestrians
    n_k = len(crossings.lane)
    out = np.zeros(n_k, dtype=np.bool_)
    for k in range(n_k):
        lo, hi = crossings.u[k, 0] - margin, crossings.u[k, 1] + margin
        for p in range(len(p_.walking)):
            if p_.walking[p] and p_.crosswalk[p] == crossings.crosswalk[k]:
                if (p_.u[p] < hi) if p_.direction[p] > 0 else (p_.u[p] > lo):
                    out[k] = True
    return out


@inline
def crosswalk_stop(offset_f, front, length, crossings, k, blocked, slow_leader, path_gap, margin, min_gap):
    """A follower's stop line [m] before crossing k (inf: none): where a pedestrian walks in the lane's band
    (`blocked`), or where the queue ahead (a `slow_leader` path_gap [m] ahead) leaves no room beyond the crosswalk
    (keep it clear); offset_f: the follower's row of `Agents.offset`, front: its front bumper [m]."""
    stop = offset_f[crossings.lane[k]] + (crossings.s[k, 0] - margin) - front
    beyond = stop + (crossings.s[k, 1] - crossings.s[k, 0] + 2 * margin)
    no_room = slow_leader and path_gap - beyond < length + min_gap
    return stop if (no_room or blocked) and stop > -0.5 else np.inf


@inline
def place_pedestrians(pedestrians, times, out):
    """The pedestrians' poses at `times` (S,) [s] ahead into `out` (Poses (S, N, ...), at their slots)."""
    p_ = pedestrians
    for i in range(len(times)):
        t = times[i]
        for p in range(len(p_.u)):
            slot, end = p_.slot[p], p_.end[p]
            u = minimum(maximum(p_.u[p] + (p_.direction[p] * p_.speed[p] * p_.walking[p]) * t, -end), end)
            out.pos[i, slot, 0] = p_.centre[p, 0] + u * p_.along[p, 0] + p_.side[p, 0]
            out.pos[i, slot, 1] = p_.centre[p, 1] + u * p_.along[p, 1] + p_.side[p, 1]
            out.pos[i, slot, 2] = 0.0
            out.yaw[i, slot] = p_.heading[p] + (p_.direction[p] < 0) * np.pi
            out.speed[i, slot] = p_.speed[p] if p_.walking[p] and abs(u) < end else 0.0
