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
from typing import NamedTuple

import numpy as np

from mjdrive.compiled import inline, jit

SCENARIOS = ("lane_change", "crossroad", "merge", "roundabout")  # columns of Traffic.intention
LANE_CHANGE, CROSSROAD, MERGE, ROUNDABOUT = range(4)
KEEP, LEFT, RIGHT = 0, 1, 2  # lane change
STRAIGHT = 0  # crossroad: STRAIGHT 0, LEFT 1, RIGHT 2 (the turn of the connector taken)
YIELD, TAKE_WAY = 0, 1  # merge
BEFORE, AFTER = 0, 1  # roundabout: leaves the ring before / after the ego's exit
TURN_ANGLE = np.radians(30.0)  # [rad] heading change above which a junction connector is a turn


class LaneRoles(NamedTuple):
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

    @classmethod
    def none(cls) -> LaneRoles:
        """No roles (no urban rules: successors are drawn at random)."""
        return cls(np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool), np.zeros(0, dtype=bool),
                   np.zeros(0, dtype=np.int64))


@functools.lru_cache(maxsize=32)
def intention_table(cfg, scenarios: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Each scenario's intention shares of a TrafficConfig as a cumulative distribution (normalised as
    `Generator.choice` normalises p), in a table (I, W) padded with inf (never <= a draw) for `draw_intentions`,
    and their columns of `Vehicles.intention` (I,) (the first `scenarios` of them: 0 without urban rules)."""
    scenarios = ((LANE_CHANGE, cfg.lane_change_intentions), (CROSSROAD, cfg.turn_intentions),
                 (MERGE, cfg.merge_intentions), (ROUNDABOUT, cfg.roundabout_intentions))[:scenarios]
    table = np.full((len(scenarios), max((len(shares) for _, shares in scenarios), default=0)), np.inf)
    for i, (_, shares) in enumerate(scenarios):
        p = np.asarray(shares, dtype=float)
        if not (np.all(p >= 0) and p.sum() > 0):
            raise ValueError(f"intention shares must be >= 0 and not all 0, got {shares}")
        cdf = (p / p.sum()).cumsum()
        table[i, : len(cdf)] = cdf / cdf[-1]
    table.flags.writeable = False
    columns = np.array([column for column, _ in scenarios], dtype=np.int64)
    columns.flags.writeable = False
    return table, columns


@inline
def draw_intentions(intention, rows, u, cdfs, columns):
    """New intentions for vehicles `rows` (K,), in place: intention[rows, columns[i]] is the index where the uniform
    draw u[i, j] falls in the cumulative shares cdfs[i] (inf-padded; `intention_table`), cdf.searchsorted(u,
    side="right"): `Generator.choice(n, K, p=shares)`'s values for the same draws."""
    for i in range(len(columns)):
        for j in range(len(rows)):
            c = 0
            while c < cdfs.shape[1] and cdfs[i, c] <= u[i, j]:
                c += 1
            intention[rows[j], columns[i]] = c


class Routes(NamedTuple):
    """What the choice of a vehicle's next lane reads: the lane graph's successors (L, W) (-1 padded) and their
    counts, the lanes' roles, the ego's ring exit (-1: none) and whether intentions rule the choice (urban)."""

    successors: np.ndarray
    n_successors: np.ndarray
    roles: LaneRoles
    ego_exit: int
    urban: bool


def draw_successors(routes: Routes, vehicles, rows: np.ndarray, lane: np.ndarray, rng: np.random.Generator
                    ) -> np.ndarray:
    """A successor of each lane (K,) (-1 for a dead end or -1) for vehicles `rows` (K,) (whose paths `lane` belongs
    to): `next_lanes` with a uniform draw each from `rng`."""
    return next_lanes(routes, vehicles.intention, vehicles.ring_passed, rows, lane, rng.random(len(lane)))


def fill_paths(routes: Routes, vehicles, rows: np.ndarray, rng: np.random.Generator, start: int = 1) -> None:
    """Successors for vehicles.path[rows, start:] (in place), drawn one path column at a time."""
    path = vehicles.path
    for k in range(start, path.shape[1]):  # loops over path depth, not over road users
        path[rows, k] = draw_successors(routes, vehicles, rows, path[rows, k - 1], rng)


@jit
def next_lanes(routes, intention, ring_passed, rows, lane, u):
    """A successor of each lane (K,) of vehicles `rows` with their uniform draws u (K,): under urban rules one that
    honours their intentions (`honoured_successors`), else any (`random_successors`)."""
    if routes.urban:
        return honoured_successors(routes, intention, ring_passed, rows, lane, u)
    return random_successors(routes, lane, u)


@inline
def random_successors(routes, lane, u):
    """Successor floor(u * count) of each lane (-1 for a dead end or -1), with u (K,) uniform draws."""
    successors = routes.successors
    out = np.empty(len(lane), dtype=np.int64)
    for k in range(len(lane)):
        lane0 = max(lane[k], 0)
        count = routes.n_successors[lane0] if lane[k] >= 0 else 0
        pick = np.int64(np.floor(u[k] * max(count, 1)))
        out[k] = successors[lane0, min(pick, successors.shape[1] - 1)] if count > 0 else -1
    return out


@inline
def honoured_successors(routes, intention, ring_passed, rows, lane, u):
    """Under urban rules, a random successor of each lane (K,) among those that honour the intentions of vehicles
    `rows` (K,), with their uniform draws u (K,): the connector of their turn at a junction; at a ring exit, leave
    before the ego's exit (BEFORE) or only after passing it (AFTER); any where nothing applies (-1 for dead ends).
    Then remember (in `ring_passed`, in place) which planned paths go past the ego's exit (a ring lane with the
    ego's exit as successor, followed by the ring), forgetting it when a path leaves the ring; a vehicle meant to
    leave before the ego's exit that reaches it first leaves after it (its intention, in place, becomes AFTER)."""
    successors, roles, ego_exit = routes.successors, routes.roles, routes.ego_exit
    turn, ring, ring_exit = roles.turn, roles.ring, roles.ring_exit
    n_k, n_w = len(rows), successors.shape[1]
    chosen = np.empty(n_k, dtype=np.int64)
    valid, exits = np.zeros(n_w, dtype=np.bool_), np.zeros(n_w, dtype=np.bool_)
    take, allowed = np.zeros(n_w, dtype=np.bool_), np.zeros(n_w, dtype=np.bool_)
    for k in range(n_k):
        row, lane0 = rows[k], max(lane[k], 0)
        wanted, before, passed = intention[row, CROSSROAD], intention[row, ROUNDABOUT] == BEFORE, ring_passed[row]
        for j in range(n_w):
            succ = successors[lane0, j]
            s0 = max(succ, 0)
            valid[j] = succ >= 0
            exits[j] = valid[j] and ring_exit[s0]
            take[j] = exits[j] and succ != ego_exit and (not passed if before else passed)
            allowed[j] = valid[j] and (turn[s0] < 0 or turn[s0] == wanted or ring_exit[s0])
        if ego_exit >= 0 and exits.any():  # at a ring exit: leave before (after) the ego's exit, or stay
            allowed[:] = take if take.any() else valid & ~exits
        if not allowed.any():
            allowed[:] = valid
        count = allowed.sum() if lane[k] >= 0 else 0
        pick = np.int64(np.floor(u[k] * max(count, 1)))
        column, running = 0, 0
        for j in range(n_w):
            running += allowed[j]
            if running > pick:
                column = j
                break
        chosen[k] = successors[lane0, column] if count > 0 else -1
    if ego_exit >= 0:  # the ring progress
        for k in range(n_k):
            row, lane0, c = rows[k], max(lane[k], 0), chosen[k]
            at_ego_exit = False
            for j in range(n_w):
                at_ego_exit |= successors[lane0, j] == ego_exit
            passed = at_ego_exit and c != ego_exit and c >= 0
            if passed:
                intention[row, ROUNDABOUT] = AFTER
            left_ring = c >= 0 and not ring[max(c, 0)] and not ring_exit[max(c, 0)]
            ring_passed[row] = (ring_passed[row] or passed) and not left_ring
    return chosen
