"""Right of way at roundabout merges (without urban rules): entering lanes yield to the ring with gap acceptance,
and circulating vehicles let in an entering vehicle that has committed past its yield line."""

from __future__ import annotations

import numpy as np

from mjdrive.compiled import inline, maximum

START_CLEARANCE = 3.0  # [m] beyond merge_clearance: an agent whose rear is this near the merged lane's start holds it
COMMITTED_PAST = 1.0  # [m] an entering vehicle's front this far past its yield line has committed ...
ROLLING_PAST = 0.5  # [m] ... or this far while moving at ROLLING_SPEED at least
ROLLING_SPEED = 1.0  # [m/s]
HOLD_LINE = -0.5  # [m] a yielding vehicle stops at its yield line until its front is this far past it ...
CREEP_LINE = -1.0  # [m] ... or this far, while slower than ROLLING_SPEED


@inline
def merge_state(agents, vehicles, merges, slot_pos, accept_gap, c):
    """Every merge (Y,): whether a priority agent (vehicle or ego) reaches its merge point within `accept_gap` [s]
    (counted at `merge_speed` at least: slow or stopped circulating vehicles may speed up) or is nearer than
    merge_clearance [m], still occupies the start of the merged lane, or is moving over near it (vehicles
    changing lane still occupy the old one: judged by straight distance, slot_pos (N, 3) [m]); and whether an
    entering agent is committed past its yield line."""
    s_a, v_a, len_a, offset_a = agents.s, agents.v, agents.length, agents.offset
    n_y, n_a = len(merges.lane), len(s_a)
    conflict = np.zeros(n_y, dtype=np.bool_)
    committed = np.zeros(n_y, dtype=np.bool_)
    for y in range(n_y):
        merge = merges.merge[y]
        for a in range(n_a):
            to_merge = offset_a[a, merge]  # 0 for agents already on the merged lane
            via = np.isfinite(offset_a[a, merges.lane[y]])  # queued behind the entry, not approaching the merge
            dist = np.inf if (via or to_merge <= 0) else to_merge - (s_a[a] + len_a[a] / 2)
            soon = dist - c.merge_clearance < maximum(v_a[a], c.merge_speed) * accept_gap
            on_start = agents.path[a, 0] == merge and s_a[a] - len_a[a] / 2 < c.merge_clearance + START_CLEARANCE
            if soon or on_start:
                conflict[y] = True
            if agents.path[a, 0] == merges.lane[y]:
                past = s_a[a] + len_a[a] / 2 - merges.stop[y]
                if past > COMMITTED_PAST or (past > ROLLING_PAST and v_a[a] >= ROLLING_SPEED):
                    committed[y] = True
        for j in range(len(vehicles.active)):  # vehicles changing lane
            if not (vehicles.active[j] and vehicles.lc_dist[j] < c.lane_change_length):
                continue
            slot = vehicles.slot[j]
            near = np.hypot(slot_pos[slot, 0] - merges.xy[y, 0], slot_pos[slot, 1] - merges.xy[y, 1])
            reach = maximum(vehicles.v[j], c.merge_speed) * accept_gap + c.merge_clearance
            if near - vehicles.length[j] / 2 < reach:
                conflict[y] = True
    return conflict, committed


@inline
def merge_stops(offset_f, front, v, merges, y, conflict, committed, merge_clearance):
    """A follower's stop lines [m] at merge y (inf: none): at the yield line while a priority agent comes
    (`conflict`) and it has not committed; as a circulating vehicle, `merge_clearance` [m] before the merge point
    while an entering agent has committed (`committed`). offset_f: the follower's row of `Agents.offset`; front:
    its front bumper [m]; v: its speed [m/s]."""
    line = np.inf
    if conflict:
        stop = offset_f[merges.lane[y]] + merges.stop[y] - front
        if stop > HOLD_LINE or (stop > CREEP_LINE and v < ROLLING_SPEED):
            line = stop
    keep_out = np.inf
    if committed:
        to_merge = offset_f[merges.merge[y]]
        through = offset_f[merges.lane[y]] < np.inf
        stop = to_merge - merge_clearance - front
        if not through and to_merge > 0 and stop > HOLD_LINE:
            keep_out = stop
    return line, keep_out
