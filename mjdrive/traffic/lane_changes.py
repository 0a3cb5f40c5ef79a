"""Lane changes to a same-direction neighbour lane when the target lane has room."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mjdrive.traffic import kernels, state_kernels
from mjdrive.traffic.geometry import smoothstep
from mjdrive.traffic.intentions import KEEP, LANE_CHANGE, LEFT, RIGHT
from mjdrive.traffic.kernels import KERNELS

ZONE_CLEARANCE = 8.0  # [m] intended lane changes start at least this plus their length from any zone point
EGO_IDM = (2.0, 3.0, 1.5)  # [m/s^2, m/s^2, s] a, b, T assumed for the ego as a follower

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic


def lane_changes(t: Traffic) -> None:
    """At most one lane change per decision, into a same-direction neighbour lane that has room: at random
    rates (`lane_changes="random"`) or, under urban rules (`"intention"`), by each vehicle's lane-change
    intention after `signal_time` of signalling, if the new follower need not brake harder than
    `safe_decel` (MOBIL's safety criterion)."""
    cfg = t.config
    lane0, right, left, near_merge = _options(t)
    if cfg.lane_changes == "intention":
        _finish_intended(t)
        chosen = _intended(t, right, left, near_merge, lane0)
    else:
        chosen = _random(t, right, left, near_merge)
    if chosen is not None:
        _change(t, *chosen, lane0, right, left)


def _options(t: Traffic) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Current lanes (NV,), right and left neighbours (-1: none) and whether each vehicle is near a merge
    (`state_kernels.lane_change_options` with numba: the same)."""
    m = t.map
    if KERNELS:
        return state_kernels.lane_change_options(t.path, t.s, m.length, m.right, m.left, m.ends_at_merge,
                                                 m.starts_at_merge, m.n_successors)
    lane0 = np.maximum(t.path[:, 0], 0)
    right, left = m.right[lane0], m.left[lane0]
    # Not near a merge point (an entry joining the ring), where entering vehicles cut in, and not to the
    # right just before a diverge (an exit), where exiting vehicles slow down.
    s, length = t.s, m.length[lane0]
    near_merge = ((m.ends_at_merge[lane0] & (s > length - 12.0)) | (m.starts_at_merge[lane0] & (s < 8.0)))
    near_exit = (m.n_successors[lane0] > 1) & (s > length - 12.0)  # moving right in front of an exit
    right = np.where(near_exit, -1, right)
    return lane0, right, left, near_merge


def _random(t: Traffic, right: np.ndarray, left: np.ndarray, near_merge: np.ndarray) -> tuple[int, int] | None:
    """(row, side) of one random try at the rates of `lane_change_rate` (side 0: right, 1: left), or None."""
    cfg = t.config
    rows = _candidates(t, right, left, near_merge)
    if not len(rows):
        return None
    rate_right, rate_left = cfg.lane_change_rate
    u = t.rng.random(3)
    if u[0] >= (rate_right + rate_left) * cfg.decision_period * len(rows):
        return None
    row = int(rows[int(u[1] * len(rows))])
    side = 0 if u[2] * (rate_right + rate_left) < rate_right else 1  # 0: to the right, 1: to the left
    return row, side


def _candidates(t: Traffic, right: np.ndarray, left: np.ndarray, near_merge: np.ndarray) -> np.ndarray:
    """Rows (K,) that may change lane at random now (`state_kernels.random_lane_change_rows` with numba)."""
    cfg = t.config
    if KERNELS:
        return state_kernels.random_lane_change_rows(t.active, right, left, t.lc_dist, t.s, t.lead_gap, near_merge,
                                                     cfg.lane_change_length)
    ok = (t.active & ((right >= 0) | (left >= 0)) & (t.lc_dist >= cfg.lane_change_length)
          & (t.s > 1.0) & (t.lead_gap > cfg.lane_change_length) & ~near_merge)
    return np.flatnonzero(ok)


def _intended(t: Traffic, right: np.ndarray, left: np.ndarray, near_merge: np.ndarray,
              lane0: np.ndarray | None = None) -> tuple[int, int] | None:
    """Vehicles whose intention has a neighbour lane on its side signal; the one signalling longest for at
    least `signal_time` tries (row, side), or None (`lane0`: the current lanes, if known).
    (`kernels.intended_lane_change` with numba: the same.)"""
    cfg = t.config
    if KERNELS:
        points = t.approaches.point if t.approaches is not None else np.zeros((0, 2))
        signal = t.lc_signal.copy()
        row, side = kernels.intended_lane_change(
            t.intention, LANE_CHANGE, np.maximum(t.path[:, 0], 0) if lane0 is None else lane0, left, right, near_merge,
            t.map.ending, t.map.n_successors, t.roles.priority, t.active, t.lc_dist, t.s, signal, t.lc_changing,
            t._current_pos, t.vehicle_slots, np.ascontiguousarray(points), t.time,
            cfg.lane_change_length, ZONE_CLEARANCE + cfg.lane_change_length, cfg.signal_time - 1e-9, LEFT, RIGHT)
        t.lc_signal = signal
        return None if row < 0 else (row, side)
    wish = t.intention[:, LANE_CHANGE]
    lane0 = np.maximum(t.path[:, 0], 0)
    # A lane that ends beside a neighbour (an on-ramp) must be left, whatever the intention.
    ending = t.map.ending[lane0]
    goes_on = (left >= 0) & (t.map.n_successors[np.maximum(left, 0)] > 0)
    wish = np.where(ending, np.where(goes_on, LEFT, RIGHT), wish)
    target = np.where(wish == LEFT, left, np.where(wish == RIGHT, right, -1))
    # Never into a lane of lower rank (an acceleration lane that must give way at its end).
    target = np.where(ending | (t.roles.priority[np.maximum(target, 0)] >= t.roles.priority[lane0]), target, -1)
    able = t.active & (target >= 0) & (t.lc_dist >= cfg.lane_change_length) & (t.s > 1.0) & ~near_merge
    if t.approaches is not None and len(t.approaches) and able.any():  # not across a conflict zone: the move
        rows = np.flatnonzero(able)  # takes a while
        xy = t._current_pos[t.vehicle_slots[rows], :2]
        point = t.approaches.point
        nearest = np.hypot(xy[:, None, 0] - point[None, :, 0], xy[:, None, 1] - point[None, :, 1]).min(axis=1)
        able[rows] = nearest > ZONE_CLEARANCE + cfg.lane_change_length
    t.lc_signal = np.where(able & (t.lc_signal < 0), t.time, np.where(able | t.lc_changing, t.lc_signal, -1.0))
    ready = able & (t.lc_signal >= 0) & (t.time - t.lc_signal >= cfg.signal_time - 1e-9)
    if not ready.any():
        return None
    row = int(np.flatnonzero(ready)[np.argmin(t.lc_signal[ready])])
    return row, (0 if wish[row] == RIGHT else 1)


def _finish_intended(t: Traffic) -> None:
    """Intended lane changes that are over: the vehicle now keeps its lane, its signal goes off."""
    if KERNELS:
        state_kernels.finish_lane_changes(t.lc_changing, t.lc_dist, t.intention, t.lc_signal,
                                          t.config.lane_change_length, LANE_CHANGE, KEEP)
        return
    done = t.lc_changing & (t.lc_dist >= t.config.lane_change_length)
    t.intention[done, LANE_CHANGE] = KEEP
    t.lc_signal[done] = -1.0
    t.lc_changing &= ~done


def _change(t: Traffic, row: int, side: int, lane0: np.ndarray, right: np.ndarray, left: np.ndarray) -> None:
    """Move vehicle `row` to its right (side 0) or left (1) neighbour if the target lane has room."""
    m, cfg = t.map, t.config
    target = int(right[row] if side == 0 else left[row])
    if target < 0:
        return
    s_new = t.s[row] * m.length[target] / m.length[lane0[row]]
    # The move must be over before any junction lane (an exit): the lane after the target goes on.
    after = int(t._choose_successor(np.array([target]), np.array([row]) if t.urban else None)[0])
    if after < 0 or m.in_junction[after]:
        return
    beyond = m.successors[after, : m.n_successors[after]]
    if m.length[target] - s_new + m.length[after] < cfg.lane_change_length and m.in_junction[beyond].any():
        return
    ctx = t._context()
    room, behind, gap_behind = _room(t, row, s_new, target, after, ctx)
    if not room:
        return
    if t.ego is not None and np.hypot(*(t._current_pos[t.vehicle_slots[row], :2]
                                           - (t.ego.x, t.ego.y))) < 12.0:
        return
    if (cfg.lane_changes == "intention" and behind >= 0
            and not _safe_for_follower(t, row, behind, gap_behind, ctx["v"][behind])):
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
    t.lc_changing[row] = cfg.lane_changes == "intention"
    t.stats["lane_changes"] += 1


def _room(t: Traffic, row: int, s_new: float, target: int, after: int, ctx: dict) -> tuple[bool, int, float]:
    """Whether the target lane has room for vehicle `row` at s_new [m] (gaps to the agents ahead and behind it
    along `target` and the lane `after` it), the nearest agent behind it there (-1: none) and the gap [m] to
    it (`state_kernels.lane_change_room` with numba: the same)."""
    m, cfg = t.map, t.config
    s, v, length, offset = ctx["s"], ctx["v"], ctx["length"], ctx["offset"]
    if KERNELS:
        return state_kernels.lane_change_room(row, s_new, target, after, ctx["lane"], s, v, length, offset,
                                              m.successors, m.n_successors, m.length, t.length[row], t.v[row],
                                              cfg.min_gap)
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
        return False, -1, np.inf
    if np.any(behind & (gap_behind < cfg.min_gap + v * 1.2 + 2.0)):
        return False, -1, np.inf
    if not behind.any():
        return True, -1, np.inf
    candidates = np.flatnonzero(behind)
    j = int(candidates[np.argmin(gap_behind[candidates])])
    return True, j, gap_behind[j]


def _safe_for_follower(t: Traffic, row: int, j: int, gap: float, vf: float) -> bool:
    """MOBIL's safety criterion: the nearest agent `j` behind in the target lane (gap [m], speed vf [m/s]), with
    the changer as its new leader, needs an IDM deceleration of at most `safe_decel` (the ego counts with
    `EGO_IDM`'s parameters)."""
    cfg = t.config
    a, b, headway = (t.a_max[j], t.b_comf[j], t.headway[j]) if j < t.nv else EGO_IDM
    vc = t.v[row]
    s_star = cfg.min_gap + max(0.0, vf * headway + vf * (vf - vc) / (2.0 * np.sqrt(a * b)))
    decel = a * ((s_star / max(gap, 0.05)) ** 2 - 1.0)
    return bool(decel <= cfg.safe_decel)
