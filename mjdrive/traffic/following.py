"""Following: every obstacle of every vehicle (path leaders, the corridor ahead, crosswalk and merge
stop lines) as columns of one gap table, and the IDM acceleration with a safety cap over it."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from mjdrive.traffic import kernels, state_kernels
from mjdrive.traffic.conflicts import (
    AT_LINE,
    CHANGING_RADIUS,
    CLAIM_DECEL,
    CLEAR_ACCEL,
    COMMITTED,
    EDGE_MARGIN,
    HELD_SPEED,
    MERGE_RANGE,
    STANDING_ROOM,
    STOP_MARGIN,
    TURN_WAIT,
    ApproachTable,
    conflict_columns,
)
from mjdrive.traffic.intentions import MERGE, YIELD
from mjdrive.traffic.kernels import KERNELS
from mjdrive.traffic.merges import merge_conflicts
from mjdrive.traffic.pedestrians import occupied_crossings

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic


def follower_table(t: Traffic, ctx: dict) -> dict:
    """The vehicles as followers for `_accelerations`."""
    nv = t.nv
    vs = t.vehicle_slots
    return {"rows": t._vehicle_rows, "path": ctx["path"][:nv], "offset": ctx["offset"][:nv], "s": t.s,
            "v": t.v, "v0": t.v0, "length": t.length, "width": t.width, "a": t.a_max,
            "b": t.b_comf, "T": t.headway, "xy": t._current_pos[vs, :2],
            "yaw": t._current_yaw[vs], "accept_gap": t.config.accept_gap,
            "courteous": t.intention[:, MERGE] == YIELD}  # `courteous_agents`' vehicle rows


def accelerations(t: Traffic, f: dict, ctx: dict) -> np.ndarray:
    """IDM accelerations [m/s^2] of followers `f` (dict of arrays, see `_follower_table`).

    Every obstacle of every follower is a column of one (F, columns) table of gaps [m] (bumper to
    obstacle, inf where none), obstacle speeds [m/s] and minimum gaps s0 [m]: path leaders, the corridor,
    crosswalk stop lines, merge stop lines. IDM takes the most constraining one. The table is reduced to
    what IDM needs of it by `gap_summary` (numpy), or by the compiled kernel with the same numbers
    (`kernels.gap_summary`, when numba is installed)."""
    m = t.map
    lane0 = np.maximum(f["path"][:, 0], 0)
    vcurve, kappa = m.curve_speed(lane0, f["s"])
    own = f["a"] is t.a_max and f["b"] is t.b_comf  # the vehicles' own IDM parameters: 2 sqrt(a b) computed once
    den = t._den if own else 2.0 * np.sqrt(f["a"] * f["b"])  # IDM's 2 sqrt(a b) [m/s^2]
    summary = gap_summary_kernel if KERNELS else gap_summary
    lead_gap, interaction, room, to_give_way = summary(t, f, ctx, kappa, den)
    if len(f["rows"]) == t.nv:
        t.lead_gap = lead_gap
    if not KERNELS:
        return idm(t, f, ctx, vcurve, interaction, room, to_give_way)
    n_y = len(m.yield_lane) if t.approaches is None else 0
    cfg, v = t.config, f["v"]
    v0, ratio = kernels.desired_speed(f["path"], f["offset"], f["s"], f["length"], f["v0"], vcurve, to_give_way,
                                      m.length, m.entry_speed, m.speed_limit, m.anticipation, m.yield_lane[:n_y],
                                      m.yield_stop[:n_y], cfg.yield_speed, v)
    ratio4 = ratio**4  # numpy's power of (v / max(v0, 0.1)), as in `idm`
    return kernels.idm_accel(f["a"], v, v0, ratio4, interaction, room, cfg.decision_period, cfg.max_decel)


def gap_summary(t: Traffic, f: dict, ctx: dict, kappa: np.ndarray, den: np.ndarray):
    """Every follower's gap table (F, columns) reduced to: the smallest gap [m], the largest IDM interaction
    term (s*/gap)^2, the least stopping room [m] (gap - s0 + v_lead^2 / 2 max_decel) and the distance [m]
    to its nearest give-way line still ahead (inf where none)."""
    m, cfg = t.map, t.config
    path, offset, s, v = f["path"], f["offset"], f["s"], f["v"]
    rows, length = f["rows"], f["length"]
    front = s + length / 2
    xy_o, yaw_o, v_o, hl_o, hw_o, idx_o = obstacles(t)
    lane_a = ctx["lane"]
    n_y = len(m.yield_lane) if t.approaches is None else 0  # urban rules: conflict zones instead
    n_a, n_o, n_k = len(lane_a), len(xy_o), len(m.cross_lane)
    c1, c2, c3, c4 = n_a, n_a + n_o, n_a + n_o + n_k, n_a + n_o + n_k + n_y
    gap = np.full((len(s), c4 + n_y), np.inf)
    lead = np.zeros_like(gap)
    s0 = np.full(gap.shape[1], cfg.stop_gap)
    s0[:c2] = cfg.min_gap

    # 1. Leaders along the planned path (vehicles and the ego).
    pos = offset[:, lane_a] + ctx["s"][None]  # (F, A) [m] from the start of the follower's lane
    a_idx = np.arange(n_a)
    ahead = (pos > s[:, None]) | ((pos == s[:, None]) & (a_idx[None] > rows[:, None]))
    ahead &= a_idx[None] != rows[:, None]
    gap[:, :c1] = np.where(ahead, pos - front[:, None] - ctx["length"][None] / 2, np.inf)
    lead[:, :c1] = ctx["v"][None]

    # 2. Anything in the corridor ahead (curvature-corrected): vehicles, the ego, pedestrians.
    c, sn = np.cos(f["yaw"])[:, None], np.sin(f["yaw"])[:, None]
    co, so = np.cos(yaw_o)[None], np.sin(yaw_o)[None]
    rx = xy_o[None, :, 0] - f["xy"][:, None, 0]
    ry = xy_o[None, :, 1] - f["xy"][:, None, 1]
    dx = c * rx + sn * ry
    dy = -sn * rx + c * ry - 0.5 * kappa[:, None] * dx * dx
    cos_d = co * c + so * sn  # cos and sin of the obstacle's yaw relative to the follower
    cd, sd = np.abs(cos_d), np.abs(so * c - co * sn)
    inside = (dx > 0) & (dx < cfg.corridor_range) & (idx_o[None] != rows[:, None])
    inside &= np.abs(dy) < (f["width"] / 2 + cfg.corridor_margin)[:, None] + sd * hl_o[None] + cd * hw_o[None]
    gap[:, c1:c2] = np.where(inside, dx - (length / 2)[:, None] - cd * hl_o[None] - sd * hw_o[None], np.inf)
    lead[:, c1:c2] = v_o[None] * cos_d

    # 3. Crosswalk stop lines where a pedestrian walks in the lane's band, or where the queue ahead
    #    leaves no room beyond the crosswalk (keep it clear).
    if n_k:
        base = offset[:, m.cross_lane]  # (F, K)
        stop = base + (m.cross_s[:, 0] - cfg.crosswalk_margin)[None] - front[:, None]
        leader = np.argmin(gap[:, :c1], axis=1)
        path_gap = np.minimum(gap[np.arange(len(s)), leader], 1e9)
        slow_leader = (path_gap < 1e9) & (ctx["v"][leader] < 3.0)
        beyond = stop + (m.cross_s[:, 1] - m.cross_s[:, 0] + 2 * cfg.crosswalk_margin)[None]
        no_room = slow_leader[:, None] & (path_gap[:, None] - beyond < (length + cfg.min_gap)[:, None])
        blocked = (no_room | occupied_crossings(t)[None]) if t.np_ else no_room
        gap[:, c2:c3] = np.where(blocked & (stop > -0.5), stop, np.inf)  # at / past the line: go on

    # 4. Merge stop lines while a priority vehicle (or the ego) would reach the merge point too soon.
    if n_y:
        conflict = merge_conflicts(t, ctx, f["accept_gap"])  # (Y,)
        if conflict.any():
            stop = offset[:, m.yield_lane] + m.yield_stop[None] - front[:, None]
            holding = (stop > -0.5) | ((stop > -1.0) & (v < 1.0)[:, None])  # not yet committed
            gap[:, c3:c4] = np.where(conflict[None] & holding, stop, np.inf)
        # ... and circulating vehicles let in an entering vehicle committed past its yield line.
        on_entry = ctx["lane"][:, None] == m.yield_lane[None]  # (A, Y)
        past = (ctx["s"] + ctx["length"] / 2)[:, None] - m.yield_stop[None]
        committed = (on_entry & ((past > 1.0) | ((past > 0.5) & (ctx["v"] >= 1.0)[:, None]))).any(axis=0)
        if committed.any():
            to_merge = offset[:, m.yield_merge]  # (F, Y)
            through = offset[:, m.yield_lane] < np.inf
            stop = to_merge - cfg.merge_clearance - front[:, None]
            keep_out = committed[None] & ~through & (to_merge > 0) & (stop > -0.5)
            gap[:, c4:] = np.where(keep_out, stop, np.inf)

    # 5. Urban rules: stop lines of conflict zones not to be entered now, and gaps opened at merges.
    to_give_way = np.full(len(s), np.inf)  # [m] to the nearest give-way line of a conflict zone
    if t.approaches is not None and len(t.approaches):
        extra_gap, extra_lead, extra_s0, to_give_way = conflict_columns(t, ctx, f)
        used = np.isfinite(extra_gap).any(axis=0)  # most approaches are on nobody's path right now
        extra_gap, extra_lead, extra_s0 = extra_gap[:, used], extra_lead[:, used], extra_s0[used]
        gap = np.concatenate([gap, extra_gap], axis=1)
        lead = np.concatenate([lead, extra_lead], axis=1)
        s0 = np.concatenate([s0, extra_s0])
    if t.urban:  # the end of an ending lane (an on-ramp) is a wall until the vehicle has moved over
        k_end = (path >= 0).sum(axis=1) - 1  # the last lane of the planned path
        last = path[np.arange(len(s)), np.maximum(k_end, 0)]
        ends = m.ending[np.maximum(last, 0)] & (last >= 0)
        to_end = offset[np.arange(len(s)), np.maximum(last, 0)] + m.length[np.maximum(last, 0)] - front
        gap = np.concatenate([gap, np.where(ends, to_end, np.inf)[:, None]], axis=1)
        lead = np.concatenate([lead, np.zeros((len(s), 1))], axis=1)
        s0 = np.concatenate([s0, [cfg.stop_gap]])

    finite = gap < np.inf
    s_star = s0[None] + np.maximum(0.0, (v * f["T"])[:, None] + v[:, None] * (v[:, None] - lead) / den[:, None])
    interaction = np.where(finite, (s_star / np.maximum(gap, 0.05)) ** 2, 0.0).max(axis=1)
    v_lead = np.maximum(lead, 0.0)
    room = np.where(finite, gap - s0[None] + v_lead * v_lead / (2 * cfg.max_decel), np.inf).min(axis=1)
    return gap.min(axis=1), interaction, room, to_give_way


def gap_summary_kernel(t: Traffic, f: dict, ctx: dict, kappa: np.ndarray, den: np.ndarray):
    """`gap_summary` by the compiled kernel (`kernels.gap_summary`): the same four arrays, bit for bit."""
    n_k, n_y = len(t.map.cross_lane), (len(t.map.yield_lane) if t.approaches is None else 0)
    xy_o, yaw_o, v_o, hl_o, hw_o, idx_o = obstacles(t)
    blocked = occupied_crossings(t) if (t.np_ and n_k) else np.zeros(n_k, dtype=bool)
    conflict, committed = _merge_state(t, ctx, f["accept_gap"]) if n_y else (_NO_BOOL, _NO_BOOL)
    c = np.ascontiguousarray  # the kernel is compiled for C-contiguous arrays
    return kernels.gap_summary(
        f["rows"], c(f["path"]), c(f["offset"]), f["s"], f["v"], f["length"], f["width"], f["T"], den,
        f["yaw"], c(f["xy"]), kappa, f["courteous"],
        ctx["lane"], ctx["s"], ctx["v"], ctx["length"], c(ctx["offset"]),
        c(xy_o), yaw_o, v_o, hl_o, hw_o, idx_o,
        blocked, conflict, committed, t.stopped_time, t.intention, t.active, t.lc_dist, c(t._current_pos),
        *_gap_constants(t))


def _gap_constants(t: Traffic) -> tuple:
    """`kernels.gap_summary`'s arguments that are the traffic's own (map, approaches, configuration, constants),
    gathered once per Traffic."""
    if t._gap_constants is None:
        m, cfg = t.map, t.config
        n_y = len(m.yield_lane) if t.approaches is None else 0
        table = t.approaches if t.approaches is not None and len(t.approaches) else _NO_APPROACHES
        c = np.ascontiguousarray
        t._gap_constants = (
            m.cross_lane, c(m.cross_s), m.yield_lane[:n_y], m.yield_stop[:n_y], m.yield_merge[:n_y],
            m.ending, m.length,
            table.lane, table.s_in, table.s_out, table.other, table.o_in, table.o_out, table.yields, table.tie,
            table.timed, table.merge, table.stop, table.courtesy, c(table.point), table.partner,
            MERGE, YIELD, t.nv, cfg.lane_change_length, t.vehicle_slots,
            cfg.min_gap, cfg.stop_gap, cfg.max_decel, cfg.corridor_range, cfg.corridor_margin, cfg.crosswalk_margin,
            cfg.merge_clearance, cfg.merge_speed, cfg.critical_gap_crossing, cfg.impatience, cfg.critical_gap_merge,
            cfg.courtesy_range, bool(t.urban),
            COMMITTED, EDGE_MARGIN, MERGE_RANGE, CLEAR_ACCEL, CHANGING_RADIUS, HELD_SPEED, STANDING_ROOM, AT_LINE,
            TURN_WAIT, CLAIM_DECEL, STOP_MARGIN)
    return t._gap_constants


def _merge_state(t: Traffic, ctx: dict, accept_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """Roundabout merges (Y,): whether a priority agent comes too soon (`merges.merge_conflicts`), and whether
    an entering agent is committed past its yield line (circulating vehicles keep out of its way), in the
    kernel (`kernels.merge_state`)."""
    m, cfg = t.map, t.config
    return kernels.merge_state(
        np.ascontiguousarray(ctx["lane"]), ctx["s"], ctx["v"], ctx["length"], ctx["offset"], m.yield_lane,
        m.yield_merge, m.yield_stop, t.active, t.lc_dist, cfg.lane_change_length, t.vehicle_slots,
        np.ascontiguousarray(t._current_pos), t.v, t.length, np.ascontiguousarray(m.merge_xy), accept_gap,
        cfg.merge_clearance, cfg.merge_speed, cfg.merge_clearance + 3.0)


_NO_BOOL = np.zeros(0, dtype=bool)
_NO_INT = np.zeros(0, dtype=np.int64)
_NO_FLOAT = np.zeros(0)
_NO_APPROACHES = ApproachTable(
    lane=_NO_INT, s_in=_NO_FLOAT, s_out=_NO_FLOAT, other=_NO_INT, o_in=_NO_FLOAT, o_out=_NO_FLOAT, yields=_NO_BOOL,
    tie=_NO_BOOL, timed=_NO_BOOL, merge=_NO_BOOL, zone=_NO_INT, stop=_NO_FLOAT, courtesy=_NO_BOOL,
    point=np.zeros((0, 2)))


def idm(t: Traffic, f: dict, ctx: dict, vcurve: np.ndarray, interaction: np.ndarray, room: np.ndarray,
        to_give_way: np.ndarray) -> np.ndarray:
    """IDM accelerations [m/s^2] from the followers' gap summaries (see `gap_summary`), capped so that each
    can still stop within its room whatever the obstacle does."""
    m, cfg = t.map, t.config
    path, offset, s, v = f["path"], f["offset"], f["s"], f["v"]
    front = s + f["length"] / 2
    lane0 = np.maximum(path[:, 0], 0)
    n_y = len(m.yield_lane) if t.approaches is None else 0
    # Desired speed: own v0, the lane's speed limit, the curves ahead on this lane and the next.
    nxt = path[:, 1]
    to_end = m.length[lane0] - s
    vnext = np.where(nxt >= 0, np.sqrt(m.entry_speed[np.maximum(nxt, 0)] ** 2
                                       + 2 * m.anticipation * np.maximum(to_end, 0)), np.inf)
    v0 = np.minimum(np.minimum(f["v0"], m.speed_limit[lane0]), np.minimum(vcurve, vnext))
    if n_y:  # approach yield lines slowly enough to stop at them when a gap closes
        to_line = (offset[:, m.yield_lane] + m.yield_stop[None] - front[:, None]).min(axis=1)
        ahead_line = (to_line > -0.5) & (to_line < np.inf)
        v0 = np.where(ahead_line, np.minimum(v0, np.sqrt(cfg.yield_speed**2 + 2 * 1.5 * np.maximum(to_line, 0))),
                      v0)
    slow = to_give_way < np.inf  # approach give-way lines slowly enough to stop at them
    v0 = np.where(slow, np.minimum(v0, np.sqrt(cfg.yield_speed**2 + 2 * 1.5 * np.maximum(to_give_way, 0))), v0)
    acc = f["a"] * (1.0 - (v / np.maximum(v0, 0.1)) ** 4 - interaction)
    tau = cfg.decision_period
    acc = np.where(v <= v0, np.minimum(acc, (v0 - v) / tau), acc)  # no overshoot of v0 in one period
    # Safety cap (Krauss-like): whatever the obstacle does (braking at max_decel), the follower can
    # still stop s0 short of it after this decision period: with the end speed w of the period,
    # distance (v + w) tau / 2 + w^2 / (2 b) <= gap - s0 + v_lead^2 / (2 b).
    b = cfg.max_decel
    disc = 0.25 * tau * tau + 2.0 * (room - 0.5 * v * tau) / b
    w = np.where(disc > 0, b * (np.sqrt(np.maximum(disc, 0.0)) - 0.5 * tau), 0.0)
    # no positive end speed fits: stop within the room (the period's motion stops at v = 0)
    acc = np.minimum(acc, np.where(w > 0, (w - v) / tau, -v * v / (2 * np.maximum(room, 1e-3))))
    return np.maximum(np.minimum(acc, f["a"]), -cfg.max_decel)


def obstacles(t: Traffic):
    """Everything the corridor check sees: centre xy (O,2), yaw, speed, half length, half width, and the
    follower row it is (vehicle row, nv for the ego, -1 for pedestrians); inactive vehicles left out."""
    if t._obstacle_cache is not None:
        return t._obstacle_cache
    ego = t.ego
    if KERNELS:  # the same arrays in one compiled pass
        t._obstacle_cache = state_kernels.obstacles(
            t.active, t.vehicle_slots, t.pedestrian_slots, t._current_pos, t._current_yaw, t._current_speed,
            t.half_size, t._slot_row, ego is not None, *_ego_obstacle(ego), t.nv)
        return t._obstacle_cache
    slots = np.concatenate([t.vehicle_slots[t.active], t.pedestrian_slots])
    n = len(slots) + (ego is not None)
    xy, yaw, speed = np.empty((n, 2)), np.empty(n), np.empty(n)
    hl, hw, idx = np.empty(n), np.empty(n), np.empty(n, dtype=np.int64)
    k = len(slots)
    xy[:k], yaw[:k], speed[:k] = t._current_pos[slots, :2], t._current_yaw[slots], t._current_speed[slots]
    hl[:k], hw[:k] = t.half_size[slots, 0], t.half_size[slots, 1]
    idx[:k] = t._slot_row[slots]
    if ego is not None:
        xy[k], yaw[k], speed[k] = (ego.x, ego.y), ego.yaw, max(ego.speed, 0.0)
        hl[k], hw[k], idx[k] = ego.length / 2, ego.width / 2, t.nv
    t._obstacle_cache = (xy, yaw, speed, hl, hw, idx)
    return t._obstacle_cache


def _ego_obstacle(ego) -> tuple[float, float, float, float, float, float]:
    """The ego's x, y [m], yaw [rad], speed [m/s], half length and half width [m] as `obstacles` takes them
    (zeros without an ego)."""
    if ego is None:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    return float(ego.x), float(ego.y), float(ego.yaw), max(ego.speed, 0.0), ego.length / 2, ego.width / 2
