"""Spawning: vehicles (re)enter at the map's sources when those are clear."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mjdrive.traffic.intentions import draw

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic


def spawn(t: Traffic) -> bool:
    """Inactive vehicles re-enter at a random clear source (at most one per source per decision)."""
    m, cfg = t.map, t.config
    if t.active.all() or not len(m.sources) or not cfg.respawn:
        return False
    idle = np.flatnonzero(~t.active)
    lane = np.where(t.active, t.path[:, 0], -1)
    near_start = (lane[:, None] == m.sources[None]) & ((t.s - t.length / 2)[:, None] < cfg.spawn_clear)
    clear = ~near_start.any(axis=0)
    if t.urban:  # short source lanes: anything near the source's start counts, whatever lane it is on
        xy = t._current_pos[t.vehicle_slots[t.active], :2]
        dist = np.hypot(xy[:, None, 0] - m.source_xy[None, :, 0], xy[:, None, 1] - m.source_xy[None, :, 1])
        clear &= ~(dist < cfg.spawn_clear).any(axis=0)
    if t.ego is not None:
        clear &= np.hypot(m.source_xy[:, 0] - t.ego.x, m.source_xy[:, 1] - t.ego.y) >= cfg.spawn_clear
    pick = (t.rng.random(len(idle)) * len(m.sources)).astype(np.int64)
    ok = clear[pick]
    if not ok.any():
        return False
    rows, src = idle[ok], pick[ok]
    _, first = np.unique(src, return_index=True)
    rows, src = rows[first], src[first]
    activate(t, rows, m.sources[src], t.length[rows] / 2 + 0.5)
    t.stats["spawned"] += len(rows)
    return True


def activate(t: Traffic, rows: np.ndarray, lane: np.ndarray, s: np.ndarray, speed_share=0.8) -> None:
    """Put vehicles `rows` at (lane, s) with random desired speed and lateral offset."""
    if not len(rows):
        return
    rng = t.rng
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
    t.v0[rows] = rng.uniform(low, high, len(rows))
    cap = np.minimum(t.v0[rows], t.map.speed_limit[lane])
    t.v[rows] = cap * speed_share
    t.d_pref[rows] = rng.uniform(t._lateral_range[rows, 0], t._lateral_range[rows, 1])
    t.lc_shift[rows] = 0.0
    t.lc_dist[rows] = 1e9
    t.accel[rows] = 0.0
