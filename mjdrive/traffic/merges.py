"""Right of way at merges: entering lanes yield to priority lanes with gap acceptance."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic


def merge_conflicts(t: Traffic, ctx: dict, accept_gap: float) -> np.ndarray:
    """(Y,): whether a priority agent (vehicle or ego) reaches merge y's point within `accept_gap` [s] or
    is nearer than merge_clearance, or still occupies the start of the merged lane."""
    m, cfg = t.map, t.config
    offset, s, v, length = ctx["offset"], ctx["s"], ctx["v"], ctx["length"]
    merge = m.yield_merge
    # Agents approaching the merge point, not through this yielding lane (not queued behind it).
    to_merge = offset[:, merge]  # (A, Y) 0 for agents already on the merged lane
    via = np.isfinite(offset[:, m.yield_lane])
    dist = np.where(via | (to_merge <= 0), np.inf, to_merge - (s + length / 2)[:, None])  # (A, Y)
    # slow or stopped circulating vehicles may speed up: count them at `merge_speed` at least
    soon = dist - cfg.merge_clearance < np.maximum(v, cfg.merge_speed)[:, None] * accept_gap
    # Agents already on the merged lane whose rear is still near its start.
    on_start = (ctx["lane"][:, None] == merge[None]) & ((s - length / 2)[:, None] < cfg.merge_clearance + 3.0)
    conflict = (soon | on_start).any(axis=0)
    # Vehicles moving over to another lane still occupy the old one: judge them by straight distance.
    changing = np.flatnonzero(t.active & (t.lc_dist < cfg.lane_change_length))
    if len(changing):
        xy = t._current_pos[t.vehicle_slots[changing], :2]
        near = np.hypot(xy[:, None, 0] - m.merge_xy[None, :, 0], xy[:, None, 1] - m.merge_xy[None, :, 1])
        reach = np.maximum(t.v[changing], cfg.merge_speed)[:, None] * accept_gap + cfg.merge_clearance
        conflict |= (near - t.length[changing, None] / 2 < reach).any(axis=0)
    return conflict
