"""Spawning: vehicles (re)enter at the map's sources and a scenario's spawn points when those are clear, with
drawn desired speeds, lateral offsets, intentions (urban rules) and paths."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from mjdrive.compiled import inline, jit, maximum, minimum
from mjdrive.traffic.intentions import LANE_CHANGE, draw_intentions, intention_table, next_lanes
from mjdrive.traffic.params import PATH

ENTRY_MARGIN = 0.5  # [m] a vehicle enters with its rear this far past the start of its lane


def uniform(rng: np.random.Generator, low, high, n: int) -> np.ndarray:
    """`rng.uniform(low, high, n)`'s numbers and draws (low <= high: scalars or (n,) arrays) without its checks
    (~13-60 us a call)."""
    return low + (high - low) * rng.random(n)


@dataclass(frozen=True)
class SpawnPoints:
    """Where vehicles (re)enter besides the map's sources (a scenario's critical points, §5.3): lane, s [m],
    the range of their maximum speed [m/s] and a lane-change intention (-1: drawn as usual)."""

    lane: np.ndarray  # (P,) int
    s: np.ndarray  # (P,) [m]
    speed: np.ndarray  # (P, 2) [m/s]
    lane_change: np.ndarray  # (P,) int


class Places(NamedTuple):
    """Where vehicles (re)enter (Q,): the map's sources, then the spawn points."""

    lane: np.ndarray  # int
    s: np.ndarray  # [m]
    xy: np.ndarray  # (Q, 2) [m]


class Spawner:
    """Puts vehicles on the map: `spawn` at a decision, `activate` wherever a caller says. It holds what never
    changes (places, the vehicles' speed and offset ranges, the configuration); the state comes with each call."""

    def __init__(self, traffic_map, spawn_points: SpawnPoints | None, speed_range: np.ndarray,
                 lateral_range: np.ndarray, config, urban: bool, closed: np.ndarray | None = None):
        """speed_range, lateral_range: (NV, 2) [m/s], [m] each vehicle's kind's desired speeds and lateral offsets
        (with urban rules `config.desired_speed` replaces the speeds); closed: (L,) bool, sources where nobody
        enters."""
        m = traffic_map
        open_ = np.ones(len(m.sources), dtype=bool) if closed is None else ~closed[m.sources]
        sources, source_xy = m.sources[open_], m.source_xy[open_]
        self.n_sources = len(sources)
        self.points = spawn_points
        if spawn_points is None:
            self.places = Places(sources, np.zeros(len(sources)), source_xy)
        else:
            self.places = Places(np.concatenate([sources, spawn_points.lane]),
                                 np.concatenate([np.zeros(len(sources)), spawn_points.s]),
                                 np.concatenate([source_xy, np.column_stack(m.lookup(spawn_points.lane,
                                                                                     spawn_points.s)[:2])]))
        self.speed_range, self.lateral_range = speed_range, lateral_range
        self.config, self.urban = config, urban
        self.speed_limit = m.speed_limit
        # arrivals at random times (a Poisson demand), not back to back: each idle vehicle is due with this chance
        timed = urban and config.spawn_rate > 0
        self.due_below = config.spawn_rate * config.decision_period if timed else np.inf
        self.cdfs, self.columns = intention_table(config) if urban else intention_table(config, scenarios=0)

    def spawn(self, vehicles, routes, generation: np.ndarray, now_pos: np.ndarray, ego, rng: np.random.Generator,
              intent_rng: np.random.Generator) -> int:
        """Inactive vehicles re-enter at a random clear place (at most one per place per decision); how many did.
        generation: (N,) per slot, +1 for each entry; now_pos: the slots' positions (N, 3) [m]; ego: EgoState or
        None."""
        idle = idle_rows(vehicles.active)
        if not len(idle) or not len(self.places.lane) or not self.config.respawn:
            return 0
        u_pick = rng.random(len(idle))
        u_due = intent_rng.random(len(idle)) if self.due_below < np.inf else u_pick
        ego_xy = np.zeros(0) if ego is None else np.array([ego.x, ego.y], dtype=float)
        rows, src, lane, at = spawn_places(idle, u_pick, u_due, self.due_below, self.places, vehicles, now_pos, ego_xy,
                                           self.config.spawn_clear, self.urban)
        if not len(rows):
            return 0
        self.activate(vehicles, routes, generation, rows, lane, at, rng, intent_rng)
        self._at_points(vehicles, rows, src, intent_rng)
        return len(rows)

    def activate(self, vehicles, routes, generation: np.ndarray, rows: np.ndarray, lane: np.ndarray, s: np.ndarray,
                 rng: np.random.Generator, intent_rng: np.random.Generator, speed_share=0.8) -> None:
        """Put vehicles `rows` at (lane, s [m]) (in place), with (urban rules) intentions drawn from their shares,
        paths drawn on, random desired speeds and lateral offsets, moving at `speed_share` (a number, or one per
        vehicle) of their desired speed capped by the lane's limit."""
        n = len(rows)
        if not n:
            return
        lane = np.asarray(lane, dtype=np.int64)
        u_intent = intent_rng.random((len(self.columns), n)) if self.urban else np.zeros((0, n))
        u_path = rng.random((PATH - 1, n))
        activate_rows(vehicles, routes, generation, rows, lane, np.asarray(s, dtype=float), u_intent, self.cdfs,
                      self.columns, u_path)
        low, high = self.speed_range[rows, 0], self.speed_range[rows, 1]
        if self.urban and self.config.desired_speed is not None:
            low, high = self.config.desired_speed
        v0 = uniform(rng, low, high, n)
        d_pref = uniform(rng, self.lateral_range[rows, 0], self.lateral_range[rows, 1], n)
        share = np.full(n, speed_share) if np.isscalar(speed_share) else np.asarray(speed_share, dtype=float)
        activate_speeds(vehicles, rows, lane, v0, d_pref, share, self.speed_limit)

    def _at_points(self, vehicles, rows: np.ndarray, src: np.ndarray, intent_rng: np.random.Generator) -> None:
        """Vehicles `rows` that entered at spawn points (places `src` past the map's sources): the point's speed range
        and lane-change intention."""
        planned = src >= self.n_sources
        if planned.any():
            k = src[planned] - self.n_sources
            low, high = self.points.speed[k, 0], self.points.speed[k, 1]
            entered = rows[planned]
            vehicles.v0[entered] = uniform(intent_rng, low, high, len(k))
            vehicles.v[entered] = np.minimum(vehicles.v[entered], vehicles.v0[entered])
            wish = self.points.lane_change[k]
            vehicles.intention[entered, LANE_CHANGE] = np.where(wish >= 0, wish,
                                                                vehicles.intention[entered, LANE_CHANGE])


@jit
def idle_rows(active):
    """The rows of the vehicles off the map, in order (np.flatnonzero(~active))."""
    out = np.empty(len(active), dtype=np.int64)
    n = 0
    for r in range(len(active)):
        if not active[r]:
            out[n] = r
            n += 1
    return out[:n]


@inline
def clear_places(places, vehicles, now_pos, ego_xy, clearance, urban):
    """Places (Q,) with no active vehicle on their lane within `clearance` [m] of their s (bumper to place); under
    urban rules (short source lanes) none whose centre is within it, whatever its lane; and not the ego (ego_xy:
    (2,) [m], or empty without an ego)."""
    path, s, length, active = vehicles.path, vehicles.s, vehicles.length, vehicles.active
    n_q, n_v = len(places.lane), len(s)
    clear = np.ones(n_q, dtype=np.bool_)
    for q in range(n_q):
        for r in range(n_v):
            lane = path[r, 0] if active[r] else -1
            if lane == places.lane[q] and abs(s[r] - places.s[q]) - length[r] / 2 < clearance:
                clear[q] = False
        if urban:
            for r in range(n_v):
                if active[r]:
                    slot = vehicles.slot[r]
                    dist = np.hypot(now_pos[slot, 0] - places.xy[q, 0], now_pos[slot, 1] - places.xy[q, 1])
                    if dist < clearance:
                        clear[q] = False
        if len(ego_xy) and not np.hypot(places.xy[q, 0] - ego_xy[0], places.xy[q, 1] - ego_xy[1]) >= clearance:
            clear[q] = False
    return clear


@jit
def spawn_places(idle, u_pick, u_due, due_below, places, vehicles, now_pos, ego_xy, clearance, urban):
    """Each idle vehicle (K,) picks place floor(u_pick * Q) and is due when u_due < due_below; the due ones whose
    place is clear (`clear_places`) enter there, the first one of each place only. Returns their rows, places,
    lanes and s [m] (clear of the lane start by half their length and ENTRY_MARGIN), by place."""
    n_k, n_q = len(idle), len(places.lane)
    pick = np.empty(n_k, dtype=np.int64)
    due = np.ones(n_k, dtype=np.bool_)
    any_due = False
    for k in range(n_k):
        pick[k] = np.int64(u_pick[k] * n_q)
        due[k] = u_due[k] < due_below
        any_due |= due[k]
    n = 0
    rows, src = np.empty(min(n_k, n_q), dtype=np.int64), np.empty(min(n_k, n_q), dtype=np.int64)
    lane, at = np.empty(min(n_k, n_q), dtype=np.int64), np.empty(min(n_k, n_q))
    if not any_due:
        return rows[:0], src[:0], lane[:0], at[:0]
    clear = clear_places(places, vehicles, now_pos, ego_xy, clearance, urban)
    for q in range(n_q):
        if not clear[q]:
            continue
        for k in range(n_k):
            if pick[k] == q and due[k]:
                r = idle[k]
                rows[n], src[n], lane[n] = r, q, places.lane[q]
                at[n] = maximum(places.s[q], vehicles.length[r] / 2 + ENTRY_MARGIN)
                n += 1
                break
    return rows[:n], src[:n], lane[:n], at[:n]


@jit
def activate_rows(vehicles, routes, generation, rows, lane, s, u_intent, cdfs, cdf_columns, u_path):
    """Vehicles `rows` (K,) enter at (lane, s [m]), in place: a new generation of their slot (generation (N,)),
    (urban rules) intentions drawn by the uniform draws u_intent (I, K) (`intentions.draw_intentions`), signals off,
    and their paths filled by the draws u_path (PATH - 1, K), one path column at a time."""
    n_k, n_p = len(rows), vehicles.path.shape[1]
    path = vehicles.path
    for j in range(n_k):
        r = rows[j]
        generation[vehicles.slot[r]] += 1
        vehicles.active[r] = True
        for c in range(n_p):
            path[r, c] = -1
        path[r, 0] = lane[j]
    if routes.urban:
        draw_intentions(vehicles.intention, rows, u_intent, cdfs, cdf_columns)
        for j in range(n_k):
            vehicles.ring_passed[rows[j]] = False
            vehicles.lc_signal[rows[j]] = -1.0
            vehicles.lc_changing[rows[j]] = False
    previous = np.empty(n_k, dtype=np.int64)
    for c in range(1, n_p):
        for j in range(n_k):
            previous[j] = path[rows[j], c - 1]
        chosen = next_lanes(routes, vehicles.intention, vehicles.ring_passed, rows, previous, u_path[c - 1])
        for j in range(n_k):
            path[rows[j], c] = chosen[j]
    for j in range(n_k):
        vehicles.s[rows[j]] = s[j]


@jit
def activate_speeds(vehicles, rows, lane, v0, d_pref, share, speed_limit):
    """Vehicles `rows` (K,) get their drawn desired speeds v0 [m/s] and lateral offsets [m], speed share * min(v0,
    the lane's limit) [m/s], no acceleration and no lane change under way (in place)."""
    for j in range(len(rows)):
        r = rows[j]
        vehicles.v0[r] = v0[j]
        vehicles.v[r] = minimum(v0[j], speed_limit[lane[j]]) * share[j]
        vehicles.d_pref[r] = d_pref[j]
        vehicles.lc_shift[r] = 0.0
        vehicles.lc_dist[r] = 1e9
        vehicles.accel[r] = 0.0
