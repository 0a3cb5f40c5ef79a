"""Compiled parts of the tasks' per-step work (numba, `mjdrive.compiled`): the nearest road users' rows, the
roundabout and urban tasks' ego updates, the urban task's ego features. Sines, cosines and hypot are libm's.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from mjdrive.compiled import inline, jit
from mjdrive.roads.route_frame import nearest_on_segments
from mjdrive.vehicle import chassis_state


@inline
def adversary_rows(out: np.ndarray, present: np.ndarray, positions: np.ndarray, px: float, py: float,
                   speeds: np.ndarray, intentions: np.ndarray, column: int, distance_scale: float,
                   speed_scale: float) -> None:
    """Fill `out` (n, 4) float32 with the urban task's adversary rows of the min(n, P) present road users
    nearest the point (px, py) [m]: 1, distance / distance_scale, speed / speed_scale (both capped at 1), and
    max(intention, 0) / 2 in the scenario's `column` of `intentions` (0 where column < 0: none in this scenario).

    present (N,) bool, positions (N, 2) [m], speeds (N,) [m/s] and intentions (N, 4) of every slot. The order is
    numpy's stable argsort of the distances (np.hypot: libm's, in numpy and in numba alike)."""
    slots = np.flatnonzero(present)
    p = slots.shape[0]
    dist = np.empty(p)
    for j in range(p):
        i = slots[j]
        dist[j] = np.hypot(positions[i, 0] - px, positions[i, 1] - py)
    order = np.argsort(dist, kind="mergesort")  # stable, as numpy's "stable"
    for r in range(min(out.shape[0], p)):
        j = order[r]
        i = slots[j]
        d = dist[j] / distance_scale
        v = speeds[i] / speed_scale
        out[r, 0] = 1.0
        out[r, 1] = 1.0 if d > 1.0 else d  # np.minimum(., 1.0), NaN kept
        out[r, 2] = 1.0 if v > 1.0 else v
        if column >= 0:
            out[r, 3] = max(intentions[i, column], 0) / 2.0


@jit
def road_user_rows(out: np.ndarray, positions: np.ndarray, present: np.ndarray, x: float, y: float, c: float,
                   s: float, vx: float, vy: float, speeds: np.ndarray, yaws: np.ndarray, ego_yaw: float,
                   lengths: np.ndarray, kind_onehot: np.ndarray) -> None:
    """Fill `out` (K, 9 + kinds) float32 with the roundabout task's rows of the min(K, P) present road users
    nearest the ego at (x, y) [m] (numpy's stable order of squared distances): 1, position in the ego frame
    (c, s: cos and sin of the ego's yaw) [m], velocity relative to the ego's (vx, vy) [m/s] in the ego frame,
    cos and sin of the heading difference (yaw - ego_yaw) [rad], length and width [m], kind one-hot.

    positions (N, 2) [m], speeds (N,) [m/s], yaws (N,) [rad], lengths (N, 2) [m] and kind_onehot (N, kinds) of
    every slot; present (P,) the slots in the world."""
    p = present.shape[0]
    dist2 = np.empty(p)
    for j in range(p):
        i = present[j]
        rx, ry = positions[i, 0] - x, positions[i, 1] - y
        dist2[j] = rx * rx + ry * ry
    order = np.argsort(dist2, kind="mergesort")  # stable, as numpy's "stable"
    for r in range(min(out.shape[0], p)):
        i = present[order[r]]
        rx, ry = positions[i, 0] - x, positions[i, 1] - y
        dyaw = yaws[i] - ego_yaw
        cos_dyaw, sin_dyaw = math.cos(dyaw), math.sin(dyaw)
        out[r, 0] = 1.0
        out[r, 1] = c * rx + s * ry
        out[r, 2] = -s * rx + c * ry
        out[r, 3] = speeds[i] * cos_dyaw - vx
        out[r, 4] = speeds[i] * sin_dyaw - vy
        out[r, 5] = cos_dyaw
        out[r, 6] = sin_dyaw
        out[r, 7] = lengths[i, 0]
        out[r, 8] = lengths[i, 1]
        for m in range(kind_onehot.shape[1]):
            out[r, 9 + m] = kind_onehot[i, m]


@jit
def urban_ego(qpos: np.ndarray, qvel: np.ndarray, qa: int, va: int, x0: np.ndarray, y0: np.ndarray, tx: np.ndarray,
              ty: np.ndarray, length: np.ndarray, s0: np.ndarray, lo: int, hi: int, starts: np.ndarray,
              ends: np.ndarray):
    """The urban task's ego update in one pass: `Vehicle.planar_state` of the free joint at qpos[qa], qvel[va];
    `RouteFrame.point` on its segments lo..hi (x0 ... s0); the tactical interval [starts, ends) [m] holding the
    route position (-1: none); the heading error [rad] to the route segment, wrapped as `wrap_angle` wraps a float.
    Returns (x, y, yaw, forward, left, yaw rate, s, d, segment, interval, heading error)."""
    px, py, yaw, forward, left, yaw_rate = chassis_state(
        qpos[qa], qpos[qa + 1], qpos[qa + 3], qpos[qa + 4], qpos[qa + 5], qpos[qa + 6],
        qvel[va], qvel[va + 1], qvel[va + 2], qvel[va + 3], qvel[va + 4], qvel[va + 5])
    s, d, segment = nearest_on_segments(px, py, x0, y0, tx, ty, length, s0, lo, hi)
    k = np.searchsorted(starts, s, side="right") - 1
    interval = k if k >= 0 and s < ends[k] else -1
    error = yaw - math.atan2(ty[segment], tx[segment])
    error = (error + math.pi) % (2 * math.pi) - math.pi
    return px, py, yaw, forward, left, yaw_rate, s, d, segment, interval, error


@jit
def roundabout_ego(qpos: np.ndarray, qvel: np.ndarray, qa: int, va: int, length: float, width: float, segments,
                   lo: int, hi: int, corners: np.ndarray, offsets: np.ndarray):
    """The roundabout task's ego update in one pass: `Vehicle.planar_state` of the free joint at qpos[qa], qvel[va];
    the car's `footprint` (length x width [m]) into `corners` (4, 2) [m]; `RouteFrame.__call__` of its centre and
    corners on the `segments` (`route_frame.Segments`) lo..hi, the corners' offsets [m] into `offsets` (4,); the
    heading error [rad] to the centre's segment, wrapped as `wrap_angle` wraps a float. Returns (x, y, yaw,
    forward, left, yaw rate, cos yaw, sin yaw, s, d, segment, heading error)."""
    x0, y0, tx, ty, seg_length, s0 = (segments.x0, segments.y0, segments.tx, segments.ty, segments.length,
                                      segments.s0)
    px, py, yaw, forward, left, yaw_rate = chassis_state(
        qpos[qa], qpos[qa + 1], qpos[qa + 3], qpos[qa + 4], qpos[qa + 5], qpos[qa + 6],
        qvel[va], qvel[va + 1], qvel[va + 2], qvel[va + 3], qvel[va + 4], qvel[va + 5])
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = 0.5 * length, 0.5 * width
    corners[0, 0], corners[0, 1] = px + c * hl - s * hw, py + s * hl + c * hw  # `footprint`, term for term
    corners[1, 0], corners[1, 1] = px + c * hl - s * -hw, py + s * hl + c * -hw
    corners[2, 0], corners[2, 1] = px + c * -hl - s * -hw, py + s * -hl + c * -hw
    corners[3, 0], corners[3, 1] = px + c * -hl - s * hw, py + s * -hl + c * hw
    route_s, d, segment = nearest_on_segments(px, py, x0, y0, tx, ty, seg_length, s0, lo, hi)
    for k in range(4):
        offsets[k] = nearest_on_segments(corners[k, 0], corners[k, 1], x0, y0, tx, ty, seg_length, s0, lo, hi)[1]
    error = yaw - math.atan2(ty[segment], tx[segment])
    error = (error + math.pi) % (2 * math.pi) - math.pi
    return px, py, yaw, forward, left, yaw_rate, c, s, route_s, d, segment, error


@inline
def _unit(v: float) -> float:
    """min(max(v, 0.0), 1.0) as Python evaluates it (NaN and -0.0 kept)."""
    if 0.0 > v:
        v = 0.0
    if 1.0 < v:
        v = 1.0
    return v


@inline
def ego_features(out: np.ndarray, ego, scales) -> None:
    """The urban task's ego features into `out` (4,) float32, each clipped to [0, 1]: speed / speed scale,
    (heading error + pi) / 2 pi, (lane offset / off_route + 1) / 2, route s / route end. ego: (speed [m/s], heading
    error [rad], lane offset [m], route s [m], x [m], y [m]); scales: (speed [m/s], off_route [m], route end [m],
    distance [m])."""
    out[0] = _unit(ego[0] / scales[0])
    out[1] = _unit((ego[1] + math.pi) / (2 * math.pi))
    out[2] = _unit((ego[2] / scales[1] + 1.0) / 2.0)
    out[3] = _unit(ego[3] / scales[2])


class RoutePoints(NamedTuple):
    """The conflict points ahead on the urban route: where along it (C,) [m], the scenario each lies in (its index in
    the task's SCENARIOS), and where they are (C, 2) [m]."""

    s: np.ndarray
    scenario: np.ndarray
    xy: np.ndarray


@jit
def relevant_point(points, scenario: int, at_ego: bool, ego) -> tuple[float, float]:
    """Where the urban task measures adversaries' distances (§5.1.2): the first conflict point of the active
    `scenario` no more than 2 m behind the ego (`ego` as `ego_features` takes it), or the ego itself (`at_ego`, or
    none)."""
    if not at_ego:
        for j in range(points.s.shape[0]):
            if points.s[j] >= ego[3] - 2.0 and points.scenario[j] == scenario:
                return points.xy[j, 0], points.xy[j, 1]
    return ego[4], ego[5]


@jit
def urban_features(out_ego: np.ndarray, out_adversaries: np.ndarray, ego, scales, points, scenario: int,
                   at_ego: bool, users, column: int) -> None:
    """The urban task's features: `ego_features` into out_ego, and `adversary_rows` (users: present, positions,
    speeds, intentions of every slot) from the `relevant_point` into out_adversaries (zeros)."""
    ego_features(out_ego, ego, scales)
    px, py = relevant_point(points, scenario, at_ego, ego)
    adversary_rows(out_adversaries, users[0], users[1], px, py, users[2], users[3], column, scales[3], scales[0])
