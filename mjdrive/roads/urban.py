"""Study 002's strategy level on a composed map (§4.1): the global route (Dijkstra over the lane graph
through each piece's required lanes) and the tactical trajectory (where each scenario starts and ends along
the route), plus the concatenated map of Fig. 8: roundabout -> two-lane road -> crossroad -> merge.
"""

from __future__ import annotations

import bisect
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from mjdrive.config import ConfigError
from mjdrive.roads.conflicts import ConflictZones, RouteConflicts, conflict_zones
from mjdrive.roads.lane import Lane
from mjdrive.roads.ports import SCENARIOS, ComposedMap, Piece, compose
from mjdrive.roads.roadmap import RoadMap
from mjdrive.roads.urban_params import UrbanMap, check
from mjdrive.roads.urban_pieces import crossroad, merge_road, overtaking_road, roundabout_piece

FOLLOW = "follow"  # the scenario outside every interval of the tactical trajectory ("Follow Path")


@dataclass(frozen=True)
class TacticalTrajectory:
    """Scenario intervals (name, s_start [m], s_end [m]) along the route polyline, ordered and disjoint."""

    intervals: tuple[tuple[str, float, float], ...]

    def __post_init__(self) -> None:
        last = -np.inf
        for name, s0, s1 in self.intervals:
            check("scenario", name, name in SCENARIOS, f"one of {SCENARIOS}")
            check("interval", (name, s0, s1), last <= s0 < s1, "s_start < s_end, after the previous interval")
            last = s1
        object.__setattr__(self, "_starts", [s0 for _, s0, _ in self.intervals])  # for `scenario_at`

    @property
    def names(self) -> tuple[str, ...]:
        """Scenario names in route order."""
        return tuple(name for name, _, _ in self.intervals)

    def interval(self, name: str) -> tuple[float, float]:
        """(s_start, s_end) [m] of the first interval called `name`; KeyError if none."""
        for n, s0, s1 in self.intervals:
            if n == name:
                return s0, s1
        raise KeyError(f"no scenario {name!r} in {self.names}")

    def scenario_at(self, s: float) -> str:
        """The scenario at route arc length s [m] (intervals are [s_start, s_end)); FOLLOW outside them."""
        k = bisect.bisect_right(self._starts, s) - 1
        if k >= 0 and s < self.intervals[k][2]:
            return self.intervals[k][0]
        return FOLLOW


@dataclass(frozen=True)
class RouteWaypoints:
    """The lane waypoint planner's output (§4.1): points along the route with the map data at each."""

    s: np.ndarray  # (M,) [m] route arc length
    xy: np.ndarray  # (M, 2) [m]
    heading: np.ndarray  # (M,) [rad]
    lane: np.ndarray  # (M,) lane id
    lane_s: np.ndarray  # (M,) [m] arc length along that lane
    lane_width: np.ndarray  # (M,) [m]
    speed_limit: np.ndarray  # (M,) [m/s]
    scenario: tuple[str, ...]  # (M,) the tactical trajectory's scenario there


@dataclass(frozen=True)
class UrbanRoute:
    """A composed map with the ego's route and everything the tasks, agents and logs read."""

    composed: ComposedMap
    route: tuple[int, ...]  # lane ids, start to goal
    polyline: np.ndarray  # (M, 2) [m] route centre line
    tactical: TacticalTrajectory
    conflicts: ConflictZones  # the whole map's table
    route_conflicts: RouteConflicts  # the zones on the route

    @property
    def road_map(self) -> RoadMap:
        """The composed map."""
        return self.composed.road_map

    @property
    def length(self) -> float:
        """Route length [m] along the polyline."""
        return float(np.hypot(*np.diff(self.polyline, axis=0).T).sum())

    def route_lane(self) -> Lane:
        """The route polyline as a Lane (its lane frame is the route's path frame)."""
        return Lane(self.polyline, name="route")

    def waypoints(self, spacing: float = 2.0) -> RouteWaypoints:
        """Waypoints every `spacing` [m] from the route's start, with lane, width, speed limit, scenario."""
        check("spacing", spacing, isinstance(spacing, int | float) and spacing > 0, "a number > 0")
        rm, path = self.road_map, self.route_lane()
        s = np.arange(0.0, path.length + 1e-9, spacing)
        offsets = route_offsets(rm, self.route)
        k = np.clip(np.searchsorted(offsets, s, side="right") - 1, 0, len(self.route) - 1)
        lane = np.asarray(self.route)[k]
        lanes = [rm.lanes[i] for i in lane]
        return RouteWaypoints(s, path.position(s), path.heading(s), lane,
                              np.minimum(s - offsets[k], [ln.length for ln in lanes]),
                              np.array([ln.width for ln in lanes]), np.array([ln.speed_limit for ln in lanes]),
                              tuple(self.tactical.scenario_at(float(x)) for x in s))

    def to_dict(self) -> dict:
        """Plain data for logs: route lane names, length [m], the tactical trajectory and the conflict zones
        on the route (arc lengths [m] along it)."""
        rm, rc = self.road_map, self.route_conflicts
        zones = [{"s_in": float(rc.s_in[k]), "s_out": float(rc.s_out[k]), "s_point": float(rc.s_point[k]),
                  "lane": rm.lanes[rc.route_lane[k]].name, "other_lane": rm.lanes[rc.other_lane[k]].name,
                  "ego_yields": bool(rc.ego_yields[k]), "kind": ("crossing", "merge")[int(rc.kind[k])]}
                 for k in range(len(rc))]
        return {"route": [rm.lanes[i].name for i in self.route], "length": self.length,
                "tactical": [[name, s0, s1] for name, s0, s1 in self.tactical.intervals], "conflicts": zones}


def route_offsets(road_map: RoadMap, route: Sequence[int]) -> np.ndarray:
    """Arc length [m] along the route polyline where each route lane starts (a lane change, consecutive
    neighbours, keeps the arc length)."""
    out = np.zeros(len(route))
    for k in range(1, len(route)):
        joined = route[k] in road_map.successors[route[k - 1]]
        out[k] = out[k - 1] + (road_map.lanes[route[k - 1]].length if joined else 0.0)
    return out


def plan_route(road_map: RoadMap, checkpoints: Sequence[int]) -> list[int]:
    """Dijkstra (`RoadMap.shortest_route`) from each checkpoint lane to the next, joined: the route keeps
    its lanes where it can, and changes lane only if a checkpoint cannot be reached otherwise."""
    check("checkpoints", list(checkpoints), len(checkpoints) >= 2, "at least a start and a goal lane")
    route = [checkpoints[0]]
    for a, b in zip(checkpoints[:-1], checkpoints[1:], strict=True):
        if a == b:
            continue
        try:
            leg = road_map.shortest_route(a, b, allow_lane_change=False)
        except ValueError:
            leg = road_map.shortest_route(a, b, allow_lane_change=True)
        route.extend(leg[1:])
    return route


def tactical_trajectory(composed: ComposedMap, route: Sequence[int]) -> TacticalTrajectory:
    """Each piece's scenario spans located on the route: from the first route lane in the span's `start`
    to the first later route lane in its `end`; spans the route misses are left out."""
    offsets = route_offsets(composed.road_map, route)
    intervals = []
    for piece in composed.pieces:
        for span in piece.scenarios:
            start, end = dict(span.start), dict(span.end)
            k0 = next((k for k, lane in enumerate(route) if lane in start), None)
            if k0 is None:
                continue
            k1 = next((k for k in range(k0, len(route)) if route[k] in end), None)
            if k1 is None:
                continue
            s0, s1 = offsets[k0] + start[route[k0]], offsets[k1] + end[route[k1]]
            if s1 > s0:
                intervals.append((span.name, float(s0), float(s1)))
    intervals.sort(key=lambda row: row[1])
    return TacticalTrajectory(tuple(intervals))


def route_through(composed: ComposedMap) -> UrbanRoute:
    """The ego's route through a composed map (from its start lane via every piece's `via` lanes to its
    goal lane), the tactical trajectory and the conflict zones."""
    rm = composed.road_map
    checkpoints = [composed.start_lane] + [i for piece in composed.pieces for i in piece.via] + [composed.goal_lane]
    route = plan_route(rm, checkpoints)
    zones = conflict_zones(rm)
    polyline = rm.route_polyline(route)
    polyline.setflags(write=False)
    return UrbanRoute(composed, tuple(route), polyline, tactical_trajectory(composed, route), zones,
                      zones.on_route(rm, route))


JUNCTION_LEAD = 20.0  # [m] an imported map's crossroad scenario starts this far before a junction


def route_on(road_map: RoadMap, route: Sequence[int]) -> UrbanRoute:
    """A map without pieces (an imported one) with the ego's `route` (lane ids): a crossroad scenario from
    JUNCTION_LEAD m before each junction the route crosses to the junction's exit, the conflict zones."""
    offsets = route_offsets(road_map, route)
    intervals, k = [], 0
    while k < len(route):
        if road_map.lanes[route[k]].in_junction:
            j = k
            while j + 1 < len(route) and road_map.lanes[route[j + 1]].in_junction:
                j += 1
            s0, s1 = max(offsets[k] - JUNCTION_LEAD, 0.0), offsets[j] + road_map.lanes[route[j]].length
            if not intervals or s0 >= intervals[-1][2]:
                intervals.append(("crossroad", float(s0), float(s1)))
            k = j
        k += 1
    zones = conflict_zones(road_map)
    polyline = road_map.route_polyline(list(route))
    polyline.setflags(write=False)
    return UrbanRoute(ComposedMap(road_map, []), tuple(route), polyline, TacticalTrajectory(tuple(intervals)), zones,
                      zones.on_route(road_map, route))


def concatenated(urban_map: UrbanMap | Mapping | None = None, **keywords) -> ComposedMap:
    """The pieces of Fig. 8 chained in route order, built from their parameters: `urban_map` (an UrbanMap, or a
    dict of its keywords: `order`, `roundabout`, `road`, `crossroad`, `merge`) or those keywords directly.
    `order` None chains all four ("roundabout", "road", "crossroad", "merge"). Raises ConfigError (a ValueError)
    naming the piece and the parameter, or the pieces that would overlap."""
    if urban_map is None:
        urban_map = UrbanMap.from_dict(keywords)
    elif keywords:
        raise ConfigError(f"give the map either as urban_map or as keywords, not both ({', '.join(keywords)})")
    elif not isinstance(urban_map, UrbanMap):
        check("urban_map", urban_map, isinstance(urban_map, Mapping), "an UrbanMap or a dict of its keywords")
        urban_map = UrbanMap.from_dict(urban_map)
    if urban_map.order is None:  # all four: the map-wide lane_width checked against each
        urban_map = dataclasses.replace(urban_map, order=urban_map.pieces())
    builders = {"roundabout": lambda: roundabout_piece(urban_map.roundabout),
                "road": lambda: overtaking_road(urban_map.road),
                "crossroad": lambda: crossroad(urban_map.crossroad),
                "merge": lambda: merge_road(urban_map.merge)}
    pieces: list[Piece] = [builders[name]() for name in urban_map.pieces()]
    try:
        return compose(pieces, name="urban")
    except ValueError as error:  # pieces that run over each other: the map's order or sizes
        hint = " (set the map's lane_width, or the same lane_width on every piece)" if "lane widths" in str(error) \
            else ""
        raise ConfigError(f"order={list(urban_map.pieces())}: {error}{hint}") from None


def urban_route(**kwargs) -> UrbanRoute:
    """`route_through(concatenated(**kwargs))`: the study-002 map of Fig. 8 with the ego's route (enter the
    roundabout from the west, leave east; keep right on the two-lane road; cross the minor road at the
    crossroad; join the main road from the right), the tactical trajectory and the conflict zones."""
    return route_through(concatenated(**kwargs))
