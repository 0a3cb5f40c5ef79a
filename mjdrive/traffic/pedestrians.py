"""Pedestrians: wait at the kerb, cross on their track when no vehicle could fail to stop, and the
crossings they occupy (vehicles stop before them)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mjdrive.traffic import state_kernels
from mjdrive.traffic.kernels import KERNELS
from mjdrive.traffic.spawning import uniform

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic


def commit_pedestrians(t: Traffic, t_end: float) -> None:
    """The pedestrians' state after `t_end` [s] of the plan: walkers move on, those at the far kerb stop, turn and
    draw a new wait (`state_kernels.commit_pedestrians` with numba: the same)."""
    cfg, end = t.config, t._ped_end  # [m] the kerbs along each pedestrian's crosswalk
    if KERNELS:
        t.ped_u, t.ped_dir, arrived = state_kernels.commit_pedestrians(t.ped_u, t.ped_dir, t.ped_speed, t.ped_walking,
                                                                       t.ped_wait, end, t_end)
        if arrived.any():
            lo, hi = cfg.pedestrian_wait
            t.ped_wait[arrived] = uniform(t.rng, lo, hi, int(arrived.sum()))
        return
    u = np.where(t.ped_walking, t.ped_u + t.ped_dir * t.ped_speed * t_end, t.ped_u)
    arrived = t.ped_walking & (t.ped_dir * u >= end)
    t.ped_u = np.clip(u, -end, end)
    t.ped_walking &= ~arrived
    t.ped_dir = np.where(arrived, -t.ped_dir, t.ped_dir)
    t.ped_wait -= t_end
    if arrived.any():
        lo, hi = cfg.pedestrian_wait
        t.ped_wait[arrived] = uniform(t.rng, lo, hi, int(arrived.sum()))


def pedestrian_starts(t: Traffic, ctx: dict) -> None:
    """Waiting pedestrians whose wait is over cross when no vehicle could fail to stop before them
    (`state_kernels.pedestrian_starts` with numba: the same)."""
    m = t.map
    if KERNELS:
        ego = t.ego
        state_kernels.pedestrian_starts(
            t.ped_walking, t.ped_wait, t.ped_cw, ctx["offset"], ctx["s"], ctx["v"], ctx["length"], t._b_agents,
            m.cross_lane, m.cross_s, m.cross_cw, m.cw_centre, ego is not None, ego.x if ego is not None else 0.0,
            ego.y if ego is not None else 0.0, 7.0 + 3.0 * max(ego.speed, 0.0) if ego is not None else 0.0)
        return
    ready = ~t.ped_walking & (t.ped_wait <= 0.0)
    if not ready.any():
        return
    unsafe = threatened_crosswalks(t, ctx)
    if t.ego is not None:
        dist = np.hypot(m.cw_centre[:, 0] - t.ego.x, m.cw_centre[:, 1] - t.ego.y)
        unsafe |= dist < 7.0 + 3.0 * max(t.ego.speed, 0.0)
    t.ped_walking |= ready & ~unsafe[t.ped_cw]


def threatened_crosswalks(t: Traffic, ctx: dict) -> np.ndarray:
    """Crosswalks (C,) that a vehicle on the lane graph is on, or too close to stop comfortably before."""
    m = t.map
    out = np.zeros(m.n_crosswalks, dtype=bool)
    if not len(m.cross_lane):
        return out
    s, v, length = ctx["s"], ctx["v"], ctx["length"]
    base = ctx["offset"][:, m.cross_lane]  # (A, K)
    front = base + m.cross_s[None, :, 0] - (s + length / 2)[:, None]  # bumper to the crossing [m]
    rear_past = base + m.cross_s[None, :, 1] - (s - length / 2)[:, None]  # > 0: rear not yet past it
    stopping = v * v / (2 * t._b_agents) + v + 1.0
    threat = (rear_past > 0) & (front < stopping[:, None])  # inf base: never
    np.logical_or.at(out, m.cross_cw, threat.any(axis=0))
    return out


def occupied_crossings(t: Traffic) -> np.ndarray:
    """Crossings (K,) with a pedestrian walking in the lane's band (+ margin) or towards it
    (`state_kernels.occupied_crossings` with numba: the same)."""
    m, cfg = t.map, t.config
    if KERNELS:
        return state_kernels.occupied_crossings(t.ped_walking, t.ped_cw, t.ped_u, t.ped_dir, m.cross_cw, m.cross_u,
                                                cfg.crosswalk_margin + 0.3)
    on = t.ped_walking[None] & (t.ped_cw[None] == m.cross_cw[:, None])  # (K, P)
    u, direction = t.ped_u[None], t.ped_dir[None]
    margin = cfg.crosswalk_margin + 0.3
    lo, hi = m.cross_u[:, :1] - margin, m.cross_u[:, 1:] + margin
    not_past = np.where(direction > 0, u < hi, u > lo)
    return (on & not_past).any(axis=1)


def pedestrian_poses(t: Traffic, times: np.ndarray):
    """Poses (S, P, 3), yaw (S, P) and speed (S, P) of the pedestrians at `times` (S, 1) [s] ahead."""
    end = t._ped_end[None]
    walking = t.ped_walking[None]
    u = np.minimum(np.maximum(t.ped_u[None] + (t.ped_dir * t.ped_speed * t.ped_walking)[None] * times,
                              -end), end)
    xy = t._ped_centre[None] + u[..., None] * t._ped_along[None] + t._ped_side[None]
    pos = np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], axis=-1)
    yaw = np.empty(u.shape)
    yaw[:] = t._ped_heading + (t.ped_dir < 0) * np.pi
    speed = np.where(walking & (np.abs(u) < end), t.ped_speed[None], 0.0)
    return pos, yaw, speed
