"""Spawning: vehicles (re)enter at the map's sources when those are clear."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mjdrive.traffic import state_kernels
from mjdrive.traffic.intentions import AFTER, BEFORE, CROSSROAD, LANE_CHANGE, ROUNDABOUT, draw, intention_table
from mjdrive.traffic.kernels import KERNELS
from mjdrive.traffic.params import PATH

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic


def uniform(rng: np.random.Generator, low, high, n: int) -> np.ndarray:
    """`rng.uniform(low, high, n)` (low, high: scalars or (n,) arrays, low <= high as the configuration checks):
    the same draws and numbers (numpy computes low + (high - low) * a `random()` draw), without its broadcasting
    machinery and checks (~13-60 us a call)."""
    return low + (high - low) * rng.random(n)


@dataclass(frozen=True)
class SpawnPoints:
    """Where vehicles (re)enter besides the map's sources (a scenario's critical points, §5.3): lane, s [m],
    the range of their maximum speed [m/s] and a lane-change intention (-1: drawn as usual)."""

    lane: np.ndarray  # (P,) int
    s: np.ndarray  # (P,) [m]
    speed: np.ndarray  # (P, 2) [m/s]
    lane_change: np.ndarray  # (P,) int


def spawn(t: Traffic) -> bool:
    """Inactive vehicles re-enter at a random clear source or spawn point (at most one per place per
    decision)."""
    cfg = t.config
    lanes, starts, place_xy = _places(t)
    if KERNELS:
        return _spawn_compiled(t, lanes, starts, place_xy)
    if t.active.all() or not len(lanes) or not cfg.respawn:
        return False
    idle = np.flatnonzero(~t.active)
    pick = (t.rng.random(len(idle)) * len(lanes)).astype(np.int64)  # a place for each idle vehicle
    due = np.ones(len(idle), dtype=bool)
    if t.urban and cfg.spawn_rate > 0:  # arrivals at random times (a Poisson demand), not back to back
        due = t.intent_rng.random(len(idle)) < cfg.spawn_rate * cfg.decision_period
        if not due.any():
            return False
    clear = _clear_places(t, lanes, starts, place_xy)
    ok = clear[pick] & due
    if not ok.any():
        return False
    rows, src = idle[ok], pick[ok]
    _, first = np.unique(src, return_index=True)
    rows, src = rows[first], src[first]
    activate(t, rows, lanes[src], np.maximum(starts[src], t.length[rows] / 2 + 0.5))
    _at_points(t, rows, src)
    t.stats["spawned"] += len(rows)
    return True


def _spawn_compiled(t: Traffic, lanes: np.ndarray, starts: np.ndarray, place_xy: np.ndarray) -> bool:
    """`spawn` with the choice of places in a kernel (`state_kernels.spawn_places`): the same draws, the same
    vehicles at the same places."""
    cfg = t.config
    idle = state_kernels.idle_rows(t.active)
    if not len(idle) or not len(lanes) or not cfg.respawn:
        return False
    u_pick = t.rng.random(len(idle))
    timed = bool(t.urban and cfg.spawn_rate > 0)  # arrivals at random times
    u_due = t.intent_rng.random(len(idle)) if timed else u_pick
    ego = t.ego
    rows, src, lane, at = state_kernels.spawn_places(
        idle, u_pick, u_due, timed, cfg.spawn_rate * cfg.decision_period, lanes, starts, place_xy, t.active, t.path,
        t.s, t.length, t._current_pos, t.vehicle_slots, bool(t.urban), ego.x if ego is not None else 0.0,
        ego.y if ego is not None else 0.0, ego is not None, cfg.spawn_clear)
    if not len(rows):
        return False
    activate(t, rows, lane, at)
    _at_points(t, rows, src)
    t.stats["spawned"] += len(rows)
    return True


def _at_points(t: Traffic, rows: np.ndarray, src: np.ndarray) -> None:
    """Vehicles `rows` that entered at spawn points (places `src` past the map's sources): the point's speed range
    and lane-change intention."""
    m, points = t.map, t.spawn_points
    planned = src >= len(m.sources)
    if planned.any():
        k = src[planned] - len(m.sources)
        low, high = points.speed[k, 0], points.speed[k, 1]
        t.v0[rows[planned]] = low + (high - low) * t.intent_rng.random(len(k))
        t.v[rows[planned]] = np.minimum(t.v[rows[planned]], t.v0[rows[planned]])
        wish = points.lane_change[k]
        t.intention[rows[planned], LANE_CHANGE] = np.where(wish >= 0, wish, t.intention[rows[planned], LANE_CHANGE])


def _clear_places(t: Traffic, lanes: np.ndarray, starts: np.ndarray, place_xy: np.ndarray) -> np.ndarray:
    """(Q,) places with no active vehicle on their lane within `spawn_clear` of them (bumper to place), under
    urban rules none whose centre is that close whatever its lane, and not the ego
    (`state_kernels._spawn_clear` with numba)."""
    cfg = t.config
    lane = np.where(t.active, t.path[:, 0], -1)
    near_start = (lane[:, None] == lanes[None]) & (np.abs(t.s[:, None] - starts[None]) - t.length[:, None] / 2
                                                   < cfg.spawn_clear)
    clear = ~near_start.any(axis=0)
    if t.urban:  # short source lanes: anything near the place counts, whatever lane it is on
        xy = t._current_pos[t.vehicle_slots[t.active], :2]
        dist = np.hypot(xy[:, None, 0] - place_xy[None, :, 0], xy[:, None, 1] - place_xy[None, :, 1])
        clear &= ~(dist < cfg.spawn_clear).any(axis=0)
    if t.ego is not None:
        clear &= np.hypot(place_xy[:, 0] - t.ego.x, place_xy[:, 1] - t.ego.y) >= cfg.spawn_clear
    return clear


def _places(t: Traffic) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where vehicles (re)enter: lanes (Q,), s (Q,) [m] and xy (Q, 2) [m] of the map's sources, then of the
    spawn points (computed once per Traffic)."""
    if t._spawn_places is None:
        m, points = t.map, t.spawn_points
        if points is None:
            t._spawn_places = (m.sources, np.zeros(len(m.sources)), m.source_xy)
        else:
            t._spawn_places = (np.concatenate([m.sources, points.lane]),
                               np.concatenate([np.zeros(len(m.sources)), points.s]),
                               np.concatenate([m.source_xy, np.column_stack(m.lookup(points.lane, points.s)[:2])]))
    return t._spawn_places


def activate(t: Traffic, rows: np.ndarray, lane: np.ndarray, s: np.ndarray, speed_share=0.8) -> None:
    """Put vehicles `rows` at (lane, s) with random desired speed and lateral offset
    (`state_kernels.activate_rows` and `activate_speeds` with numba: the same draws and state)."""
    if not len(rows):
        return
    rng = t.rng
    if KERNELS:
        _activate_compiled(t, rows, lane, s, speed_share)
        return
    t.generation[t.vehicle_slots[rows]] += 1
    t.active[rows] = True
    t.path[rows] = -1
    t.path[rows, 0] = lane
    if t.urban:
        draw(t, rows)
        t.lc_signal[rows] = -1.0
        t.lc_changing[rows] = False
    t._fill_path(rows)
    t.s[rows] = s
    low, high = t._speed_range[rows, 0], t._speed_range[rows, 1]
    if t.urban and t.config.desired_speed is not None:
        low, high = t.config.desired_speed
    t.v0[rows] = uniform(rng, low, high, len(rows))
    cap = np.minimum(t.v0[rows], t.map.speed_limit[lane])
    t.v[rows] = cap * speed_share
    t.d_pref[rows] = uniform(rng, t._lateral_range[rows, 0], t._lateral_range[rows, 1], len(rows))
    t.lc_shift[rows] = 0.0
    t.lc_dist[rows] = 1e9
    t.accel[rows] = 0.0


def _activate_compiled(t: Traffic, rows: np.ndarray, lane: np.ndarray, s: np.ndarray, speed_share) -> None:
    """`activate` in two kernels around the numpy draws, in the numpy code's order: the intentions
    (`intentions.draw`), the path's successors (`Traffic._fill_path`), desired speeds and lateral offsets."""
    n = len(rows)
    lane = np.asarray(lane, dtype=np.int64)
    cdfs, columns = intention_table(t.config) if t.urban else (_NO_CDFS, _NO_COLUMNS)
    u_intent = t.intent_rng.random((len(columns), n)) if t.urban else _NO_CDFS
    u_path = t.rng.random((PATH - 1, n))
    state_kernels.activate_rows(
        rows, lane, np.asarray(s, dtype=float), t.vehicle_slots, t.generation, t.active, t.path, t.s, bool(t.urban),
        u_intent, cdfs, columns, t.intention, t.ring_passed, t.lc_signal, t.lc_changing, u_path, t.map.successors,
        t.map.n_successors, *t._roles_arrays, int(t.ego_exit), CROSSROAD, ROUNDABOUT, BEFORE, AFTER)
    low, high = t._speed_range[rows, 0], t._speed_range[rows, 1]
    if t.urban and t.config.desired_speed is not None:
        low, high = t.config.desired_speed
    v0 = uniform(t.rng, low, high, n)
    d_pref = uniform(t.rng, t._lateral_range[rows, 0], t._lateral_range[rows, 1], n)
    share = np.full(n, speed_share) if np.isscalar(speed_share) else np.asarray(speed_share, dtype=float)
    state_kernels.activate_speeds(rows, lane, v0, d_pref, share, t.map.speed_limit, t.v0, t.v, t.d_pref, t.lc_shift,
                                  t.lc_dist, t.accel)


_NO_CDFS = np.zeros((0, 0))
_NO_COLUMNS = np.zeros(0, dtype=np.int64)
