"""Right of way at conflict zones (crossings and merges of lanes), from the map's conflict-zone table.

`ApproachTable` turns the roads' `ConflictZones` (one row per pair of lanes that cross or merge, with who
yields) into approaches: one row per (zone, side), the stretch [s_in, s_out] [m] of the approach lane inside
the zone and the same stretch on the other lane. At every decision `conflict_stops` adds, for every vehicle,
a stop line before each zone it must not enter yet:

* a yielding approach waits while a priority agent (a vehicle or the ego) reaches the zone within the
  critical gap (crossings and merges have their own) or is inside it;
* on a tie (equal ranks) the agent that reaches the zone later waits;
* nobody enters a zone while an agent coming from the other lane occupies it;
* a vehicle that has passed its stop line (committed) goes on.
Every quantity is an (agents x approaches) array: no loop over road users.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from mjdrive.roads.conflicts import CROSSING, TIE, YIELD_A, YIELD_B, ConflictZones
from mjdrive.traffic.intentions import MERGE, YIELD
from mjdrive.traffic.lanes import REFERENCE_HALF_SIZE, footprint_points, polyline_distance

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic

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


@dataclass(frozen=True)
class ApproachTable:
    """One row per (zone, side) of a map's conflict zones."""

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

    @functools.cached_property
    def partner(self) -> np.ndarray:
        """(R,) the row of the zone's other side."""
        half = len(self.lane) // 2
        return (np.arange(len(self.lane)) + half) % max(len(self.lane), 1)

    @property
    def other_stop(self) -> np.ndarray:
        """(R,) [m] the give-way line of the other side's approach, along the other lane."""
        return self.stop[self.partner]

    def __len__(self) -> int:
        return len(self.lane)

    @classmethod
    def from_zones(cls, zones: ConflictZones, road_map=None, ring: np.ndarray | None = None) -> ApproachTable:
        """The approaches of `zones`; with `road_map`, each stop line is moved back until a car waiting
        there keeps STOP_CLEARANCE outside the other lane's strip (an angled approach's front corner would
        otherwise reach into it)."""
        z = np.arange(len(zones))
        tie = zones.who_yields == TIE
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
        )
        if road_map is not None:  # merges inside a junction are taken like crossings, at the junction's entry
            in_junction = np.array([road_map.lanes[int(i)].in_junction for i in range(len(road_map.lanes))])
            junction_merge = table.merge & (in_junction[table.lane] | in_junction[table.other])
            object.__setattr__(table, "timed", table.timed | junction_merge)
            object.__setattr__(table, "courtesy", table.courtesy & ~junction_merge)
        if ring is not None:  # entries join a ring: circulating vehicles keep their right of way
            ring_merge = ring[table.lane] | ring[table.other]
            object.__setattr__(table, "courtesy", table.courtesy & ~ring_merge)
        if road_map is not None:
            stops = np.array([_stop_line(road_map.lanes[int(lane)], road_map.lanes[int(other)], float(s_in))
                              for lane, other, s_in in zip(table.lane, table.other, table.s_in, strict=True)])
            # Inside a junction nobody stops halfway: the stop line of every zone on a junction lane is its
            # entry (the give-way line), and a vehicle that has entered clears the junction.
            junction = np.array([road_map.lanes[int(lane)].in_junction for lane in table.lane], dtype=bool)
            stops = np.where(junction, -STOP_MARGIN, stops)
            object.__setattr__(table, "stop", np.minimum(table.stop, stops))
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


def _positions(offset: np.ndarray, s: np.ndarray, length: np.ndarray, lanes: np.ndarray):
    """Front and rear bumper (A, R) [m] of every agent along each lane of `lanes` (inf off its path)."""
    base = -offset[:, lanes]  # where the agent's lane starts, seen from the start of each lane
    front = base + (s + length / 2)[:, None]
    rear = base + (s - length / 2)[:, None]
    return front, rear


def zone_state(t: Traffic, ctx: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every agent and approach: its front bumper along the approach lane (A, R) [m] (-inf off its
    path), its time to the zone along the other lane (A, R) [s] (inf off it), and whether it occupies the
    zone from the other lane (A, R): inside it, or committed past its own give-way line."""
    table, cfg = t.approaches, t.config
    offset, s, v, length = ctx["offset"], ctx["s"], ctx["v"], ctx["length"]
    front_own, _ = _positions(offset, s, length, table.lane)
    front_own = np.where(np.isfinite(front_own), front_own, -np.inf)
    front_o, rear_o = _positions(offset, s, length, table.other)
    on_other = np.isfinite(front_o)
    # An agent on both lanes' paths (the zone's lanes follow each other) comes the same way: not a conflict.
    on_other &= ~np.isfinite(offset[:, table.lane])
    # Inside the zone, or committed past the give-way line of a yielding approach (it will enter).
    gives_way = (table.yields | table.tie)[table.partner]
    entered = np.where(gives_way, np.minimum(table.o_in, table.other_stop + COMMITTED), table.o_in)  # (R,) [m]
    inside = on_other & (front_o > entered[None]) & (rear_o < table.o_out[None])
    before = on_other & ~inside & (front_o <= table.o_in[None])
    speed = np.maximum(v, cfg.merge_speed)[:, None]
    ttz = np.where(before, (table.o_in[None] - front_o) / speed, np.where(inside, 0.0, np.inf))
    return front_own, ttz, inside


def conflict_columns(t: Traffic, ctx: dict, f: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gap columns (F, 2R) [m], their obstacle speeds (F, 2R) [m/s] and minimum gaps (2R,) [m] for the
    followers `f` (rows of the agents in `ctx`), and the distance (F,) [m] to the nearest give-way line
    still ahead (inf if none: the follower approaches it slowly enough to stop).

    Crossings: stop at the give-way line while a priority agent would reach the zone less than the
    critical gap after the follower has cleared it (on a tie: while another agent gets there first); stop
    at the zone's edge while an agent from the other lane occupies it.
    Merges (a zipper over the distance to the merge point): agents of the other lane nearer the merge
    point are virtual leaders of the yielding side, and of the priority side once committed (or, for a
    courteous vehicle, within `courtesy_range`); a yielding vehicle waits at its give-way line while a
    priority agent behind it in that order would come closer than its headway."""
    table, cfg = t.approaches, t.config
    rows = f["rows"]
    n_f, n_r = len(rows), len(table)
    offset, s, v, length = ctx["offset"], ctx["s"], ctx["v"], ctx["length"]
    front_own, ttz, inside = zone_state(t, ctx)
    front_o, _ = _positions(offset, s, length, table.other)
    # Only the (follower, approach) pairs on the follower's path matter: P pairs, each against every agent.
    pf, pr = np.nonzero(np.isfinite(front_own[rows]))  # (P,) follower index, approach row
    me = rows[pf]  # (P,) the follower's agent row
    others = np.arange(len(s))[None] != me[:, None]  # (P, A)
    tr = lambda a: a[:, pr].T  # noqa: E731  (A, R) -> (P, A)
    front_me = front_own[me, pr]  # (P,) [m]
    timed, gives_way = table.timed[pr], (table.yields | table.tie)[pr]

    # --- crossings (and merges inside junctions) ---------------------------------------------------------
    v_me, length_me = np.maximum(v[me], 0.0), length[me]
    to_clear = np.maximum(table.s_out[pr] + length_me - front_me, 0.0)
    t_clear = (np.sqrt(v_me**2 + 2 * CLEAR_ACCEL * to_clear) - v_me) / CLEAR_ACCEL  # (P,) [s]
    # A priority agent standing before its own give-way line (waiting there, or queued behind one that
    # waits) will see the follower committed when it gets there: no conflict; unless it has stood first at
    # the line for TURN_WAIT already: then it is its turn (no stream of yielders starves it).
    before_line = (v[:, None] < HELD_SPEED) & (front_o <= table.other_stop[None] + COMMITTED)  # (A, R)
    at_line = table.other_stop[None] - front_o < AT_LINE
    waited_all = np.append(t.stopped_time, 0.0)  # (A,) [s] how long each agent has waited (the ego: never)
    waited_long = waited_all[:, None] >= TURN_WAIT  # (A, 1)
    held = before_line & ~(at_line & waited_long)
    # Impatience: the critical gap shrinks to zero over `impatience` seconds of waiting (the gap must still
    # let the follower clear the zone before the priority agent arrives).
    waited = waited_all[me]  # (P,) [s]
    critical = cfg.critical_gap_crossing * np.maximum(0.0, 1.0 - waited / cfg.impatience)
    # Past its patience a vehicle standing at its give-way line claims the zone: priority vehicles that can
    # still stop before their own line (braking at most CLAIM_DECEL) or stand before it stop there for it,
    # and it no longer waits for them; never the ego, whose driver the traffic cannot count on.
    to_own_line = table.other_stop[None] - front_o  # (A, R) [m] (-inf off the other lane)
    to_own_line = np.where(np.isfinite(to_own_line), to_own_line, -np.inf)
    can_stop = _can_stop(v[:, None], to_own_line)  # (A, R)
    can_stop[t.nv] = False
    patient = waited_all[:, None] >= cfg.impatience  # (A, 1)
    claiming = before_line & at_line & patient & table.yields[table.partner][None]  # (A, R) on the other lane
    me_stop = table.stop[pr] - front_me  # (P,) [m] to the follower's own give-way line
    forcing = ((waited >= cfg.impatience) & (v_me < HELD_SPEED) & (me_stop < AT_LINE) & (me_stop >= -COMMITTED)
               & table.yields[pr])  # (P,) the follower claims this zone (as `claiming` sees it)
    stoppable = forcing[:, None] & tr(can_stop)  # (P, A)
    soon = (others & ~tr(held) & ~stoppable & (tr(ttz) < (t_clear + critical)[:, None])).any(axis=1)  # (P,)
    claimed = (others & tr(claiming)).any(axis=1) & ~table.yields[pr] & ~table.tie[pr] & _can_stop(v_me, me_stop)
    # Occupied: someone from the other lane is committed to the zone (past its give-way line) or in it. A
    # vehicle not yet committed waits at its give-way line for either; a committed one stops at the zone's
    # edge only for a vehicle physically in it (committed vehicles never wait for each other's promises,
    # which could go round in a circle).
    in_zone = inside & (front_o > table.o_in[None])  # (A, R) physically in it
    promised = (others & tr(inside)).any(axis=1)  # (P,)
    # A vehicle moving over between lanes is on neither lane's path near the zone: judge it by distance.
    changing = np.flatnonzero(t.active & (t.lc_dist < cfg.lane_change_length))
    if len(changing):
        xy = t._current_pos[t.vehicle_slots[changing], :2]
        point = table.point[pr]  # (P, 2)
        near_point = np.hypot(xy[None, :, 0] - point[:, None, 0], xy[None, :, 1] - point[:, None, 1])
        promised |= ((changing[None] != me[:, None]) & (near_point < CHANGING_RADIUS)).any(axis=1)
    occupied = (others & tr(in_zone)).any(axis=1)
    # Ties: whoever reaches its give-way line sooner goes first (then the lower row): a strict order, so
    # waiting never goes round in a circle.
    pace = np.maximum(v, cfg.merge_speed)
    t_line_me = np.maximum(table.stop[pr] - front_me, 0.0) / pace[me]  # (P,) [s]
    t_line_o = np.maximum(table.other_stop[None] - front_o, 0.0) / pace[:, None]  # (A, R) along the other
    waiting_o = np.isfinite(front_o) & ~inside & (front_o <= table.o_in[None]) & ~np.isfinite(offset[:, table.lane])
    # ... and of those at their lines, whoever has waited longer, then the lower row.
    longer = (waited_all[None] > waited[:, None]) | (
        (waited_all[None] == waited[:, None]) & (np.arange(len(s))[None] < me[:, None]))
    earlier = (tr(t_line_o) < t_line_me[:, None]) | ((tr(t_line_o) == t_line_me[:, None]) & longer)
    first = (others & tr(waiting_o) & earlier).any(axis=1)  # another agent goes first
    wait_timed = timed & ((table.yields[pr] & soon) | (table.tie[pr] & first))

    # --- merges: committed agents ahead are virtual leaders; outside junctions, a zipper ------------------
    d_me = table.s_out[pr] - front_me  # (P,) [m] my front bumper to the merge point
    d_them = table.o_out[None] - front_o  # (A, R) [m] theirs (inf off the other lane)
    near = np.isfinite(d_them) & (d_them > -length[:, None]) & (d_them < MERGE_RANGE)  # (A, R)
    courteous = f["courteous"][pf] & table.courtesy[pr] & (d_me < cfg.courtesy_range)  # (P,)
    zipper = ~timed & (gives_way | courteous)  # (P,)
    follows = tr(inside) | zipper[:, None]  # (P, A): committed agents ahead are leaders in every merge
    d_them_p = tr(d_them)
    ahead = others & table.merge[pr][:, None] & tr(near) & (d_them_p < d_me[:, None]) & follows
    spacing = np.where(ahead, d_me[:, None] - np.where(ahead, d_them_p, 0.0) - length[None], np.inf)  # (P, A)
    leader_gap = spacing.min(axis=1) if len(s) else np.full(len(pf), np.inf)
    leader_speed = v[np.argmin(spacing, axis=1)] if len(s) else np.zeros(len(pf))
    behind = others & ~timed[:, None] & tr(near) & (d_them_p >= d_me[:, None])
    room = np.where(behind, d_them_p - d_me[:, None] - length_me[:, None], np.inf)  # (P, A) [m]
    # [m] the agent behind's headway; one standing still only needs the follower not to touch it (the follower
    # moves away from it, and it may be standing for the follower: waiting for it would never end)
    needed = np.where(v >= HELD_SPEED, cfg.min_gap + v * cfg.critical_gap_merge, STANDING_ROOM)[None]  # (1, A)
    # Only the nearest agent behind matters (the follower's follower after the merge; the rest queue behind
    # it), and not if it is courteous: it keeps its distance to the follower, a virtual leader of its own.
    nearest = np.argmin(room, axis=1) if len(s) else np.zeros(len(pf), dtype=np.int64)  # (P,)
    room_nearest = room[np.arange(len(pf)), nearest] if len(s) else np.full(len(pf), np.inf)
    letting_in = courteous_agents(t, ctx)[nearest] & table.courtesy[pr]
    cut_off = np.isfinite(room_nearest) & ~letting_in & (room_nearest < needed[0, nearest])  # (P,)
    wait_merge = ~timed & table.yields[pr] & cut_off

    # --- stop lines, back to (F, R) columns ------------------------------------------------------------------
    stop = table.stop[pr] - front_me  # (P,) [m] to the give-way line
    holding = stop > -COMMITTED  # not yet committed
    edge = table.s_in[pr] - EDGE_MARGIN - front_me  # (P,) [m] to the zone's edge
    stops = np.minimum(np.where((wait_timed | wait_merge | (timed & (promised | claimed))) & holding, stop, np.inf),
                       np.where(timed & occupied & (edge > -COMMITTED), edge, np.inf))
    gap = np.full((n_f, 2 * n_r), np.inf)
    lead = np.zeros((n_f, 2 * n_r))
    gap[pf, pr], gap[pf, n_r + pr], lead[pf, n_r + pr] = stops, leader_gap, leader_speed
    to_line = np.full(n_f, np.inf)
    np.minimum.at(to_line, pf, np.where(gives_way & holding, stop, np.inf))
    s0 = np.concatenate([np.full(n_r, cfg.stop_gap), np.full(n_r, cfg.min_gap)])
    return gap, lead, s0, to_line


def _can_stop(v: np.ndarray, to_line: np.ndarray) -> np.ndarray:
    """Whether a vehicle at speed v [m/s], to_line [m] before its give-way line, can stop there braking at
    most CLAIM_DECEL, or stands before it already."""
    return (v * v < 2.0 * CLAIM_DECEL * np.maximum(to_line - STOP_MARGIN, -1e9)) | (
        (v < HELD_SPEED) & (to_line > -COMMITTED))


def courteous_agents(t: Traffic, ctx: dict) -> np.ndarray:
    """(A,) agents that open gaps at merges: vehicles with merge intention YIELD (never the ego)."""
    out = np.zeros(len(ctx["s"]), dtype=bool)
    out[: t.nv] = t.intention[:, MERGE] == YIELD
    return out
