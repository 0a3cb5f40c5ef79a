"""Lane changes to a same-direction neighbour lane when the target lane has room."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mjdrive.traffic.geometry import smoothstep

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic


def lane_changes(t: Traffic) -> None:
    """At most one lane change per decision: each vehicle beside a neighbour lane tries at the rates of
    `lane_change_rate` (one random try per decision); the change happens if the target lane has room."""
    m, cfg = t.map, t.config
    lane0 = np.maximum(t.path[:, 0], 0)
    right, left = m.right[lane0], m.left[lane0]
    # Not near a merge point (an entry joining the ring), where entering vehicles cut in, and not to the
    # right just before a diverge (an exit), where exiting vehicles slow down.
    s, length = t.s, m.length[lane0]
    near_merge = ((m.ends_at_merge[lane0] & (s > length - 12.0)) | (m.starts_at_merge[lane0] & (s < 8.0)))
    near_exit = (m.n_successors[lane0] > 1) & (s > length - 12.0)  # moving right in front of an exit
    right = np.where(near_exit, -1, right)
    ok = (t.active & ((right >= 0) | (left >= 0)) & (t.lc_dist >= cfg.lane_change_length)
          & (s > 1.0) & (t.lead_gap > cfg.lane_change_length) & ~near_merge)
    rows = np.flatnonzero(ok)
    if not len(rows):
        return
    rate_right, rate_left = cfg.lane_change_rate
    u = t.rng.random(3)
    if u[0] >= (rate_right + rate_left) * cfg.decision_period * len(rows):
        return
    row = int(rows[int(u[1] * len(rows))])
    side = 0 if u[2] * (rate_right + rate_left) < rate_right else 1  # 0: to the right, 1: to the left
    target = int(right[row] if side == 0 else left[row])
    if target < 0:
        return
    s_new = t.s[row] * m.length[target] / m.length[lane0[row]]
    # The move must be over before any junction lane (an exit): the lane after the target goes on.
    after = int(t._choose_successor(np.array([target]))[0])
    if after < 0 or m.in_junction[after]:
        return
    beyond = m.successors[after, : m.n_successors[after]]
    if m.length[target] - s_new + m.length[after] < cfg.lane_change_length and m.in_junction[beyond].any():
        return
    ctx = t._context()
    s, v, length, offset = ctx["s"], ctx["v"], ctx["length"], ctx["offset"]
    # Every other vehicle's coordinate along the target lane (via its own path), if it passes there,
    # or beyond its end along the lane that follows it (on it or coming to it from another lane).
    coord = np.where(np.isfinite(offset[:, after]), m.length[target] + s - offset[:, after], np.nan)
    leaving = np.isin(ctx["lane"], m.successors[target, : m.n_successors[target]])  # e.g. just exited
    coord = np.where(leaving, m.length[target] + s, coord)
    coord = np.where(np.isfinite(offset[:, target]), s - offset[:, target], coord)
    coord[row] = np.nan
    gap_ahead = coord - s_new - (length + t.length[row]) / 2
    gap_behind = s_new - coord - (length + t.length[row]) / 2
    ahead, behind = coord >= s_new, coord < s_new
    if np.any(ahead & (gap_ahead < cfg.min_gap + t.v[row] * 0.8)):
        return
    if np.any(behind & (gap_behind < cfg.min_gap + v * 1.2 + 2.0)):
        return
    if t.ego is not None and np.hypot(*(t._current_pos[t.vehicle_slots[row], :2]
                                           - (t.ego.x, t.ego.y))) < 12.0:
        return
    shift = m.width[lane0[row]] * (1.0 if side == 0 else -1.0)  # the old centre seen from the new lane
    sm, _ = smoothstep(t.lc_dist[row] / cfg.lane_change_length)
    d_now = t.d_pref[row] + t.lc_shift[row] * (1.0 - sm)
    t.path[row, 0] = target
    t.path[row, 1] = after
    t._fill_path(np.array([row]), start=2)
    t.s[row] = s_new
    t.lc_shift[row] = d_now + shift - t.d_pref[row]
    t.lc_dist[row] = 0.0
    t.stats["lane_changes"] += 1
