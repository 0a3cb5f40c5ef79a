"""Intentions (study 002, §5.1.1): one integer per vehicle and scenario, drawn at spawn, logged, and honoured
by what the vehicle does.

| scenario      | values                                   | honoured by                                   |
| ------------- | ---------------------------------------- | --------------------------------------------- |
| lane change   | KEEP 0, LEFT 1, RIGHT 2                  | a lane change to that side (lane_changes.py)  |
| crossroad     | STRAIGHT 0, LEFT 1, RIGHT 2              | the connector it takes at a junction          |
| merge         | YIELD 0, TAKE_WAY 1                      | opening a gap for a merging agent, or not     |
| roundabout    | BEFORE 0, AFTER 1 (the ego's exit)       | the ring exit it takes                        |

Observations normalise them to [0, 1] as value / 2 (§5.1.2).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from mjdrive.traffic.model import Traffic

SCENARIOS = ("lane_change", "crossroad", "merge", "roundabout")  # columns of Traffic.intention
LANE_CHANGE, CROSSROAD, MERGE, ROUNDABOUT = range(4)
KEEP, LEFT, RIGHT = 0, 1, 2  # lane change
STRAIGHT = 0  # crossroad: STRAIGHT 0, LEFT 1, RIGHT 2 (the turn of the connector taken)
YIELD, TAKE_WAY = 0, 1  # merge
BEFORE, AFTER = 0, 1  # roundabout: leaves the ring before / after the ego's exit
TURN_ANGLE = np.radians(30.0)  # [rad] heading change above which a junction connector is a turn


@dataclass(frozen=True)
class LaneRoles:
    """Build-time facts of a map's lanes for intentions: the turn of each junction connector (STRAIGHT,
    LEFT, RIGHT; -1 for other lanes), ring lanes (on a cycle of non-junction lanes) and ring exits."""

    turn: np.ndarray  # (L,) int
    ring: np.ndarray  # (L,) bool
    ring_exit: np.ndarray  # (L,) bool: a junction lane leaving a ring lane
    priority: np.ndarray  # (L,) int: right-of-way rank (`Lane.priority`); nobody changes into a lower one

    @classmethod
    def of(cls, road_map) -> LaneRoles:
        lanes, successors = road_map.lanes, road_map.successors
        n = len(lanes)
        turn = np.full(n, -1, dtype=np.int64)
        for i, lane in enumerate(lanes):  # build time: loops over lanes are fine
            if lane.in_junction:
                h = lane.vertex_heading
                change = float(h[-1] - h[0])
                turn[i] = LEFT if change > TURN_ANGLE else RIGHT if change < -TURN_ANGLE else STRAIGHT
        ring = np.zeros(n, dtype=bool)
        for i in range(n):  # a lane on a cycle of non-junction lanes (a roundabout's ring)
            seen, frontier = set(), [i]
            for _ in range(64):
                frontier = [j for k in frontier for j in successors[k] if not lanes[j].in_junction and j not in seen]
                seen.update(frontier)
                if i in seen:
                    ring[i] = True
                    break
                if not frontier:
                    break
        ring_exit = np.array([lane.in_junction and any(ring[p] for p in road_map.predecessors(i))
                              and not any(ring[s] for s in successors[i]) for i, lane in enumerate(lanes)])
        priority = np.array([getattr(lane, "priority", 0) for lane in lanes], dtype=np.int64)
        return cls(turn, ring, ring_exit, priority)


def draw(t: Traffic, rows: np.ndarray) -> None:
    """New intentions for vehicles `rows` (at spawn), from the configured shares: for each scenario a uniform
    draw per vehicle against the shares' cumulative distribution (what `Generator.choice(n, size, p=shares)`
    does, the same draws and values, without its checks of p on every call)."""
    rng = t.intent_rng
    for column, cdf in intention_cdfs(t.config):
        t.intention[rows, column] = cdf.searchsorted(rng.random(len(rows)), side="right")
    t.ring_passed[rows] = False


@functools.lru_cache(maxsize=32)
def intention_cdfs(cfg) -> tuple[tuple[int, np.ndarray], ...]:
    """(column, cumulative distribution) of each scenario's intention shares of a TrafficConfig (normalised as
    `Generator.choice` normalises p)."""
    out = []
    for column, shares in ((LANE_CHANGE, cfg.lane_change_intentions), (CROSSROAD, cfg.turn_intentions),
                           (MERGE, cfg.merge_intentions), (ROUNDABOUT, cfg.roundabout_intentions)):
        p = np.asarray(shares, dtype=float)
        if not (np.all(p >= 0) and p.sum() > 0):
            raise ValueError(f"intention shares must be >= 0 and not all 0, got {shares}")
        p = p / p.sum()
        cdf = p.cumsum()
        cdf /= cdf[-1]
        cdf.flags.writeable = False
        out.append((column, cdf))
    return tuple(out)


@functools.lru_cache(maxsize=32)
def intention_table(cfg) -> tuple[np.ndarray, np.ndarray]:
    """`intention_cdfs` as arrays for kernels: the cumulative distributions (I, W), padded with inf (never <= a
    draw), and their columns of Traffic.intention (I,)."""
    cdfs = intention_cdfs(cfg)
    table = np.full((len(cdfs), max(len(cdf) for _, cdf in cdfs)), np.inf)
    for i, (_, cdf) in enumerate(cdfs):
        table[i, : len(cdf)] = cdf
    table.flags.writeable = False
    columns = np.array([column for column, _ in cdfs], dtype=np.int64)
    columns.flags.writeable = False
    return table, columns


def successor_preference(t: Traffic, rows: np.ndarray, lane: np.ndarray) -> np.ndarray:
    """(K, W) bool: the successors of `lane` (rows' path lanes) that honour the rows' intentions: the
    connector of their turn at a junction; at a ring exit, leave before the ego's exit (BEFORE) or only
    after passing it (AFTER). All successors where nothing applies."""
    m, roles = t.map, t.roles
    lane0 = np.maximum(lane, 0)
    succ = m.successors[lane0]  # (K, W)
    valid = succ >= 0
    s0 = np.maximum(succ, 0)
    turn = roles.turn[s0]
    wanted = t.intention[rows, CROSSROAD][:, None]
    ok = valid & ((turn < 0) | (turn == wanted) | roles.ring_exit[s0])
    exits = valid & roles.ring_exit[s0]
    if t.ego_exit >= 0 and exits.any():
        ego_exit = exits & (succ == t.ego_exit)
        before = t.intention[rows, ROUNDABOUT] == BEFORE
        passed = t.ring_passed[rows]
        take = np.where(before[:, None], exits & ~ego_exit & ~passed[:, None], exits & passed[:, None] & ~ego_exit)
        stay = valid & ~exits
        choose_exit = take.any(axis=1)
        ok = np.where(choose_exit[:, None], take, np.where(exits.any(axis=1)[:, None], stay, ok))
    none = ~ok.any(axis=1)
    return np.where(none[:, None], valid, ok)


def note_ring_progress(t: Traffic, rows: np.ndarray, lane: np.ndarray, chosen: np.ndarray) -> None:
    """Remember which planned paths go past the ego's exit (a ring lane with the ego's exit as successor,
    followed by the ring), and forget it when a path leaves the ring."""
    if t.ego_exit < 0 or not len(rows):
        return
    m = t.map
    lane0 = np.maximum(lane, 0)
    at_ego_exit = (m.successors[lane0] == t.ego_exit).any(axis=1)
    passed = at_ego_exit & (chosen != t.ego_exit) & (chosen >= 0)
    # A vehicle meant to leave before the ego's exit that reaches it first cannot: it leaves after it.
    t.intention[rows[passed], ROUNDABOUT] = AFTER
    left_ring = (chosen >= 0) & ~t.roles.ring[np.maximum(chosen, 0)] & ~t.roles.ring_exit[np.maximum(chosen, 0)]
    t.ring_passed[rows] = (t.ring_passed[rows] | passed) & ~left_ring
