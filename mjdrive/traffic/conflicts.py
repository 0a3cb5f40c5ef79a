"""Right of way at conflict zones (crossings and merges of lanes), from the map's conflict-zone table.

`ApproachTable` turns the roads' `ConflictZones` (one row per pair of lanes that cross or merge, with who
yields) into approaches: one row per (zone, side), the stretch [s_in, s_out] [m] of the approach lane inside
the zone and the same stretch on the other lane. At every decision `zone_stops` gives every follower a stop line
before each zone it must not enter yet, and in merges a virtual leader (its docstring has the rules). What every
agent is to every approach (inside the zone, its time to it, waiting at its line, ...) is computed once per decision
(`zone_state`), for the agents on each approach's other lane only.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from mjdrive.compiled import helper, inline, jit, maximum, minimum
from mjdrive.roads.conflicts import CROSSING, TIE, YIELD_A, YIELD_B, ConflictZones
from mjdrive.traffic.intentions import MERGE, YIELD
from mjdrive.traffic.lanes import REFERENCE_HALF_SIZE, footprint_points, polyline_distance

STOP_MARGIN = 1.0  # [m] a waiting vehicle's front bumper stays at least this far before the zone
STOP_CLEARANCE = 0.5  # [m] ... and its footprint this far outside the other lane's strip
STOP_SEARCH = 15.0  # [m] how far back the stop line may move
COMMITTED = 0.5  # [m] past the stop line: the vehicle goes on (it could not stop before the zone)
EDGE_MARGIN = 0.5  # [m] before an occupied zone
MERGE_RANGE = 60.0  # [m] agents farther from a merge point than this do not take part in the zipper
CLEAR_ACCEL = 2.0  # [m/s^2] a yielding vehicle's acceleration through the zone, for its time to clear it
CHANGING_RADIUS = 8.0  # [m] a vehicle changing lane this close to a zone's point occupies it
HELD_SPEED = 1.0  # [m/s] a vehicle slower than this before its give-way line is waiting
STANDING_ROOM = 0.5  # [m] a merging vehicle goes ahead of a standing one behind it at least this far
AT_LINE = 3.0  # [m] a waiting vehicle this close to its give-way line is first in line
TURN_WAIT = 3.0  # [s] a priority vehicle first in line this long gets its turn
CLAIM_DECEL = 4.0  # [m/s^2] a priority vehicle stops for a vehicle past its patience if it can at this braking
PRIORITY_ACCEL = 2.5  # [m/s^2] a priority agent may speed up this hard toward a zone (the quickest kind's IDM a)


class ApproachTable(NamedTuple):
    """One row per (zone, side) of a map's conflict zones (R,)."""

    lane: np.ndarray  # (R,) the approach lane
    s_in: np.ndarray  # (R,) [m] where the zone starts on it
    s_out: np.ndarray  # (R,) [m] where it ends
    other: np.ndarray  # (R,) the other lane of the zone
    o_in: np.ndarray  # (R,) [m] the zone on the other lane
    o_out: np.ndarray  # (R,) [m]
    yields: np.ndarray  # (R,) bool: this side gives way
    tie: np.ndarray  # (R,) bool: equal ranks, first come first served
    timed: np.ndarray  # (R,) bool: taken by time gaps at the give-way line (crossings, merges in a junction)
    merge: np.ndarray  # (R,) bool: the lanes merge (else they cross)
    zone: np.ndarray  # (R,) row in the ConflictZones table
    stop: np.ndarray  # (R,) [m] front-bumper stop line along the approach lane
    courtesy: np.ndarray  # (R,) bool: a merge where courteous vehicles open gaps (not a roundabout entry)
    point: np.ndarray  # (R, 2) [m] where the centre lines cross, or the merge point
    partner: np.ndarray  # (R,) the row of the zone's other side

    @classmethod
    def none(cls) -> ApproachTable:
        """No approaches (a map without conflict zones, or traffic without urban rules)."""
        i, f, b = np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=bool)
        return cls(i, f, f, i, f, f, b, b, b, b, i, f, b, np.zeros((0, 2)), i)

    @classmethod
    def from_zones(cls, zones: ConflictZones, road_map=None, ring: np.ndarray | None = None) -> ApproachTable:
        """The approaches of `zones`; with `road_map`, each stop line is moved back until a car waiting
        there keeps STOP_CLEARANCE outside the other lane's strip (an angled approach's front corner would
        otherwise reach into it)."""
        z = np.arange(len(zones))
        tie = zones.who_yields == TIE
        n = 2 * len(zones)
        table = cls(
            lane=np.concatenate([zones.lane_a, zones.lane_b]).astype(np.int64),
            s_in=np.concatenate([zones.s_a_in, zones.s_b_in]), s_out=np.concatenate([zones.s_a_out, zones.s_b_out]),
            other=np.concatenate([zones.lane_b, zones.lane_a]).astype(np.int64),
            o_in=np.concatenate([zones.s_b_in, zones.s_a_in]), o_out=np.concatenate([zones.s_b_out, zones.s_a_out]),
            yields=np.concatenate([zones.who_yields == YIELD_A, zones.who_yields == YIELD_B]),
            tie=np.concatenate([tie, tie]), timed=np.concatenate([zones.kind == CROSSING] * 2),
            merge=np.concatenate([zones.kind != CROSSING] * 2),
            zone=np.concatenate([z, z]), stop=np.concatenate([zones.s_a_in, zones.s_b_in]) - STOP_MARGIN,
            courtesy=np.concatenate([zones.kind != CROSSING] * 2), point=np.concatenate([zones.point] * 2),
            partner=(np.arange(n) + n // 2) % max(n, 1),
        )
        if road_map is not None:  # merges inside a junction are taken like crossings, at the junction's entry
            in_junction = np.array([road_map.lanes[int(i)].in_junction for i in range(len(road_map.lanes))])
            junction_merge = table.merge & (in_junction[table.lane] | in_junction[table.other])
            table = table._replace(timed=table.timed | junction_merge, courtesy=table.courtesy & ~junction_merge)
        if ring is not None:  # entries join a ring: circulating vehicles keep their right of way
            ring_merge = ring[table.lane] | ring[table.other]
            table = table._replace(courtesy=table.courtesy & ~ring_merge)
        if road_map is not None:
            stops = np.array([_stop_line(road_map.lanes[int(lane)], road_map.lanes[int(other)], float(s_in))
                              for lane, other, s_in in zip(table.lane, table.other, table.s_in, strict=True)])
            # Inside a junction nobody stops halfway: the stop line of every zone on a junction lane is its
            # entry (the give-way line), and a vehicle that has entered clears the junction.
            junction = np.array([road_map.lanes[int(lane)].in_junction for lane in table.lane], dtype=bool)
            stops = np.where(junction, -STOP_MARGIN, stops)
            table = table._replace(stop=np.minimum(table.stop, stops))
        return table


def _stop_line(lane, other, s_in: float) -> float:
    """The farthest front-bumper position [m] along `lane`, before `s_in`, where a reference car keeps
    STOP_CLEARANCE outside `other`'s strip (build time)."""
    half_length, half_width = REFERENCE_HALF_SIZE
    front = np.arange(s_in - STOP_MARGIN, s_in - STOP_SEARCH, -0.1)
    centre_s = front - half_length
    corners = footprint_points(lane.position(centre_s), lane.heading(centre_s), half_length, half_width)
    distance = polyline_distance(corners.reshape(-1, 2), other.centre).reshape(len(front), -1).min(axis=1)
    clear = np.flatnonzero(distance >= other.width / 2 + STOP_CLEARANCE)
    return float(front[clear[0]]) if len(clear) else float(front[-1])


@helper
def can_stop(v: float, to_line: float) -> bool:
    """Whether a vehicle at speed v [m/s], to_line [m] before its give-way line, can stop there braking at most
    CLAIM_DECEL, or stands before it already."""
    return (v * v < 2.0 * CLAIM_DECEL * maximum(to_line - STOP_MARGIN, -1e9)) or (
        v < HELD_SPEED and to_line > -COMMITTED)


@helper
def reach_time(distance: float, v: float, v_top: float) -> float:
    """[s] to cover `distance` [m] from speed `v` [m/s] speeding up at PRIORITY_ACCEL to at most `v_top` [m/s]: the
    soonest a priority agent free to go (not held) may arrive, as it may speed up at any moment."""
    v = maximum(v, 0.0)
    v_top = maximum(v_top, v)
    d_accel = (v_top * v_top - v * v) / (2.0 * PRIORITY_ACCEL)  # [m] to reach v_top
    if distance <= d_accel or v_top <= 0.0:
        return (np.sqrt(v * v + 2.0 * PRIORITY_ACCEL * maximum(distance, 0.0)) - v) / PRIORITY_ACCEL
    return (v_top - v) / PRIORITY_ACCEL + (distance - d_accel) / v_top


@inline
def zone_state(agents, vehicles, approaches, c, control):
    """Every agent (A,) (`Agents`: the vehicles, then the ego, which waits as they do (`Traffic.ego_waited`) but is
    never courteous and never counted on to stop for a claim) at every approach (R,), for the agents on the
    approach's other lane (on_lane[r, :n_on[r]]; the other entries are never read): inside the zone (or committed
    to it), its time to the zone [s], held before its give-way line, able to stop there for a vehicle past its
    patience, claiming the zone itself, physically in the zone, its time to its give-way line [s], waiting before
    the zone, its distance to the merge point [m] and whether that is near (A, R); on_lane (R, A), n_on (R,); per
    agent (A,): how long it has waited [s], whether it opens gaps (courteous), the headway [m] it needs behind a
    merging vehicle; the vehicles changing lane (rows). control (A,): [m] to the junction-control line each agent must
    stop at (inf: none); an agent whose line comes before a zone is held there."""
    ap = approaches
    s_a, v_a, len_a, offset_a = agents.s, agents.v, agents.length, agents.offset
    n_a, n_r, nv = len(s_a), len(ap.lane), len(vehicles.v)
    waited = agents.waited  # [s]
    courteous = np.zeros(n_a, dtype=np.bool_)
    for a in range(min(n_a, nv)):
        courteous[a] = vehicles.intention[a, MERGE] == YIELD
    inside = np.empty((n_a, n_r), dtype=np.bool_)
    ttz = np.empty((n_a, n_r))
    held = np.empty((n_a, n_r), dtype=np.bool_)
    stoppable = np.empty((n_a, n_r), dtype=np.bool_)
    claiming = np.empty((n_a, n_r), dtype=np.bool_)
    in_zone = np.empty((n_a, n_r), dtype=np.bool_)
    t_line = np.empty((n_a, n_r))
    waiting = np.empty((n_a, n_r), dtype=np.bool_)
    d_merge = np.empty((n_a, n_r))
    near = np.empty((n_a, n_r), dtype=np.bool_)
    on_lane = np.empty((n_r, n_a), dtype=np.int64)
    n_on = np.zeros(n_r, dtype=np.int64)
    top_any = 0.0  # [m/s] the fastest vehicle's desired speed: the ego's top speed as the traffic judges it
    for j in range(nv):
        if vehicles.active[j]:
            top_any = maximum(top_any, vehicles.v0[j])
    for a in range(n_a):
        half = len_a[a] / 2
        pace = maximum(v_a[a], c.merge_speed)
        v_top = vehicles.v0[a] if a < nv else top_any  # [m/s]
        for r in range(n_r):
            off_other = offset_a[a, ap.other[r]]
            if not np.isfinite(off_other):
                continue
            on_lane[r, n_on[r]] = a
            n_on[r] += 1
            off_own = offset_a[a, ap.lane[r]]
            base = -off_other
            f_o = base + (s_a[a] + half)
            rear_o = base + (s_a[a] - half)
            # an agent on both lanes' paths (the zone's lanes follow each other) comes the same way: no conflict
            on_other = np.isfinite(f_o) and not np.isfinite(off_own)
            partner = ap.partner[r]
            other_stop = ap.stop[partner]
            # inside the zone, or committed past the give-way line of a yielding approach (it will enter)
            entered = minimum(ap.o_in[r], other_stop + COMMITTED) if (ap.yields[partner] or ap.tie[partner]) \
                else ap.o_in[r]
            ins = on_other and f_o > entered and rear_o < ap.o_out[r]
            inside[a, r] = ins
            before = on_other and not ins and f_o <= ap.o_in[r]
            if before:  # at its present pace (counted at merge_speed at least), or sooner if it speeds up
                ttz[a, r] = minimum((ap.o_in[r] - f_o) / pace, reach_time(ap.o_in[r] - f_o, v_a[a], v_top))
            elif ins:
                ttz[a, r] = 0.0
            else:
                ttz[a, r] = np.inf
            # A priority agent standing before its own give-way line (waiting there, or queued behind one that
            # waits) will see the follower committed when it gets there: no conflict; unless it has stood first
            # at the line for TURN_WAIT already: then it is its turn (no stream of yielders starves it).
            before_line = v_a[a] < HELD_SPEED and f_o <= other_stop + COMMITTED
            at_line = other_stop - f_o < AT_LINE
            held[a, r] = (before_line and not (at_line and waited[a] >= TURN_WAIT)) or control[a] < ap.o_in[r] - f_o
            to_own = other_stop - f_o
            if not np.isfinite(to_own):
                to_own = -np.inf
            stoppable[a, r] = a != nv and can_stop(v_a[a], to_own)
            claiming[a, r] = before_line and at_line and waited[a] >= c.impatience and ap.yields[partner]
            in_zone[a, r] = ins and f_o > ap.o_in[r]
            t_line[a, r] = 0.0 if before_line and at_line else maximum(other_stop - f_o, 0.0) / pace
            waiting[a, r] = np.isfinite(f_o) and not ins and f_o <= ap.o_in[r] and not np.isfinite(off_own)
            d = ap.o_out[r] - f_o
            d_merge[a, r] = d
            near[a, r] = np.isfinite(d) and d > -len_a[a] and d < MERGE_RANGE
    changing = np.empty(nv, dtype=np.int64)  # vehicles moving over between lanes
    n_changing = 0
    for j in range(nv):
        if vehicles.active[j] and vehicles.lc_dist[j] < c.lane_change_length:
            changing[n_changing] = j
            n_changing += 1
    needed = np.empty(n_a)  # [m] the headway of an agent behind a merging follower
    for a in range(n_a):
        # one standing still only needs the follower not to touch it (the follower moves away from it, and it
        # may be standing for the follower: waiting for it would never end)
        needed[a] = c.min_gap + v_a[a] * c.critical_gap_merge if v_a[a] >= HELD_SPEED else STANDING_ROOM
    return (inside, ttz, held, stoppable, claiming, in_zone, t_line, waiting, d_merge, near, on_lane, n_on, waited,
            courteous, needed, changing[:n_changing])


@helper
def zone_stops(followers, agents, vehicles, approaches, slot_pos, c, control):
    """Every follower (`Followers`, rows of `agents`) at every approach on its path: its stop line [m] (inf: none), its
    virtual leader's gap [m] and speed [m/s] in a merge, as pairs in follower then approach order (those of follower
    f: start[f] to start[f + 1]); and per follower, the distance [m] to its nearest give-way line where it gives way
    and has not committed (inf: none, then it need not slow down for one).

    Crossings: stop at the give-way line while a priority agent would reach the zone less than the critical gap
    after the follower has cleared it (on a tie: while another agent gets there first); stop at the zone's edge
    while an agent from the other lane occupies it. Merges (a zipper over the distance to the merge point): agents
    of the other lane nearer the merge point are virtual leaders of the yielding side, and of the priority side once
    committed (or, for a courteous vehicle, within `courtesy_range`); a yielding vehicle waits at its give-way line
    while a priority agent behind it in that order would come closer than its headway. control (A,): [m] to each
    agent's junction-control line (`zone_state`)."""
    (inside, ttz, held, stoppable_a, claiming, in_zone, t_line, waiting, d_merge, near, on_lane, n_on, waited_a,
     courteous_a, needed, changing) = zone_state(agents, vehicles, approaches, c, control)
    ap = approaches
    ap_lane, ap_s_in, ap_s_out, ap_stop, ap_point = ap.lane, ap.s_in, ap.s_out, ap.stop, ap.point
    ap_timed, ap_yields, ap_tie, ap_merge, ap_courtesy = ap.timed, ap.yields, ap.tie, ap.merge, ap.courtesy
    s_a, v_a, len_a, offset_a = agents.s, agents.v, agents.length, agents.offset
    rows, courteous_f, slot = followers.row, followers.courteous, vehicles.slot
    n_vehicles = len(vehicles.v)  # the ego's agent row
    n_f, n_r = len(rows), len(ap_lane)
    start = np.zeros(n_f + 1, dtype=np.int64)
    for f in range(n_f):
        start[f + 1] = start[f]
        for r in range(n_r):
            start[f + 1] += np.isfinite(offset_a[rows[f], ap_lane[r]])
    line, leader_gaps, leader_speeds = np.empty(start[n_f]), np.empty(start[n_f]), np.empty(start[n_f])
    to_give_way = np.full(n_f, np.inf)
    p = 0
    for f in range(n_f):
        row = rows[f]
        for r in range(n_r):
            if not np.isfinite(offset_a[row, ap_lane[r]]):  # not on the follower's path
                continue
            front_me = -offset_a[row, ap_lane[r]] + (s_a[row] + len_a[row] / 2)
            timed, yields, tie = ap_timed[r], ap_yields[r], ap_tie[r]
            gives_way = yields or tie
            v_me, length_me = maximum(v_a[row], 0.0), len_a[row]
            to_clear = maximum(ap_s_out[r] + length_me - front_me, 0.0)
            t_clear = (np.sqrt(v_me * v_me + 2 * CLEAR_ACCEL * to_clear) - v_me) / CLEAR_ACCEL  # [s]
            # Impatience: the critical gap shrinks to zero over `impatience` seconds of waiting (the gap must still
            # let the follower clear the zone before the priority agent arrives).
            waited = waited_a[row]
            critical = c.critical_gap_crossing * maximum(0.0, 1.0 - waited / c.impatience)
            # Past its patience a vehicle standing at its give-way line claims the zone: priority vehicles that can
            # still stop before their own line (braking at most CLAIM_DECEL) or stand before it stop there for it,
            # and it no longer waits for them; never the ego, whose driver the traffic cannot count on.
            me_stop = ap_stop[r] - front_me  # [m] to the follower's own give-way line
            forcing = (waited >= c.impatience and v_me < HELD_SPEED and me_stop < AT_LINE and me_stop >= -COMMITTED
                       and yields)
            # --- crossings (and merges inside junctions) ---------------------------------------------------------
            soon = claimed_any = promised = occupied = first = ego_promised = False
            # standing first in line (within AT_LINE of it) is arriving now, wherever before the line one stopped
            standing = v_me < HELD_SPEED and me_stop < AT_LINE and me_stop > -COMMITTED
            t_line_me = 0.0 if standing else maximum(ap_stop[r] - front_me, 0.0) / maximum(v_a[row], c.merge_speed)
            for k in range(n_on[r]):  # the agents on the other lane (the others neither conflict nor lead here)
                a = on_lane[r, k]
                if a == row:
                    continue
                stoppable = forcing and stoppable_a[a, r]
                if not held[a, r] and not stoppable and ttz[a, r] < t_clear + critical:
                    soon = True
                if claiming[a, r]:
                    claimed_any = True
                # Occupied: someone from the other lane is committed to the zone (past its give-way line) or in it.
                # A vehicle not yet committed waits at its give-way line for either; a committed one stops at the
                # zone's edge only for a vehicle physically in it (committed vehicles never wait for each other's
                # promises, which could go round in a circle).
                if inside[a, r]:
                    promised = True
                    ego_promised = ego_promised or a == n_vehicles
                if in_zone[a, r]:
                    occupied = True
                # Ties: whoever reaches its give-way line sooner goes first, then whoever has waited longer, then the
                # lower row: a strict order, so waiting never goes round in a circle.
                if waiting[a, r]:
                    longer = waited_a[a] > waited or (waited_a[a] == waited and a < row)
                    if t_line[a, r] < t_line_me or (t_line[a, r] == t_line_me and longer):
                        first = True
            # The ego does not stop for a claim either: a claimant does not count on it (it would wait for the ego
            # standing at its line, which waited for the claim)
            claimed = claimed_any and not yields and not tie and can_stop(v_me, me_stop) and row != n_vehicles
            for j in changing:  # a vehicle moving over between lanes is on neither lane's path near the zone:
                if j != row and np.hypot(slot_pos[slot[j], 0] - ap_point[r, 0],  # judge it by distance
                                         slot_pos[slot[j], 1] - ap_point[r, 1]) < CHANGING_RADIUS:
                    promised = True
            wait_timed = timed and ((yields and soon) or (tie and first))
            # --- merges: committed agents ahead are virtual leaders; outside junctions, a zipper -----------------
            d_me = ap_s_out[r] - front_me  # [m] my front bumper to the merge point
            courteous = courteous_f[f] and ap_courtesy[r] and d_me < c.courtesy_range
            zipper = not timed and (gives_way or courteous)
            leader_gap, leader = np.inf, 0
            room_nearest, nearest = np.inf, 0
            for k in range(n_on[r]):
                a = on_lane[r, k]
                if a == row or not near[a, r]:
                    continue
                d = d_merge[a, r]
                if ap_merge[r] and d < d_me and (inside[a, r] or zipper):
                    spacing = d_me - d - len_a[a]
                    if spacing < leader_gap:
                        leader_gap, leader = spacing, a
                if not timed and d >= d_me:
                    room = d - d_me - length_me
                    if room < room_nearest:
                        room_nearest, nearest = room, a
            # Only the nearest agent behind matters (the follower's follower after the merge; the rest queue behind
            # it), and not if it is courteous: it keeps its distance to the follower, a virtual leader of its own.
            letting_in = courteous_a[nearest] and ap_courtesy[r]
            # Standing first at its line for TURN_WAIT, it is its turn before a priority agent standing behind it (a
            # vehicle abreast in a third lane may be waiting for that one: three lanes of a drop side by side, each
            # waiting for the next, would stand for ever); once it has committed, that agent falls in behind it.
            my_turn = standing and waited >= TURN_WAIT and v_a[nearest] < HELD_SPEED
            cut_off = np.isfinite(room_nearest) and not letting_in and room_nearest < needed[nearest] and not my_turn
            wait_merge = not timed and yields and cut_off
            # --- stop lines -------------------------------------------------------------------------------------
            holding = me_stop > -COMMITTED  # not yet committed
            edge = ap_s_in[r] - EDGE_MARGIN - front_me  # [m] to the zone's edge
            line_gap = np.inf
            if (wait_timed or wait_merge or (timed and (promised or claimed))) and holding:
                line_gap = me_stop
            if timed and occupied and edge > -COMMITTED:
                line_gap = minimum(line_gap, edge)
            # The ego committed to the zone (past its give-way line) will cross: a vehicle committed too stops at the
            # zone's edge for it if it still can (braking at most CLAIM_DECEL), as a driver brakes for a car that
            # has pulled out in front, whoever had the right of way. Only for the ego: two committed vehicles of
            # the traffic waiting for each other's promises could go round in a circle.
            if timed and ego_promised and not holding and edge > -COMMITTED and can_stop(v_me, edge + STOP_MARGIN):
                line_gap = minimum(line_gap, edge)
            line[p], leader_gaps[p], leader_speeds[p] = line_gap, leader_gap, v_a[leader]
            to_give_way[f] = minimum(to_give_way[f], me_stop if gives_way and holding else np.inf)
            p += 1
    return start, line, leader_gaps, leader_speeds, to_give_way


@jit
def ego_give_way(followers, agents, vehicles, approaches, slot_pos, c, control):
    """What `zone_stops` asks of one follower (the ego, `Traffic.give_way`): the nearest stop line [m] before a zone
    (inf: none), and in a merge its nearest virtual leader's gap [m] (inf: none) and speed [m/s]."""
    start, line, leader_gaps, leader_speeds, _ = zone_stops(followers, agents, vehicles, approaches, slot_pos, c,
                                                            control)
    stop, gap, speed = np.inf, np.inf, 0.0
    for k in range(start[0], start[1]):
        stop = minimum(stop, line[k])
        if leader_gaps[k] < gap:
            gap, speed = leader_gaps[k], leader_speeds[k]
    return stop, gap, speed
