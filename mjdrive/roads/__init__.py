"""Road maps for mjdrive: lanes, lane graphs, lane-frame queries and map builders (pure numpy).

Coordinates: x east, y north [m]; headings [rad] counter-clockwise from +x; right-hand traffic; lateral
offsets d > 0 to the left of the direction of travel.
"""

from mjdrive.roads.builders import crafted_routes, curve, merge, spawn_points, straight, two_lane_road
from mjdrive.roads.conflicts import ConflictZones, RouteConflicts, conflict_zones
from mjdrive.roads.geometry import Path, fillet, s_curve, wrap_angle
from mjdrive.roads.junctions import junction, roundabout, roundabout_routes, town
from mjdrive.roads.lane import Lane, Marking, resample
from mjdrive.roads.ports import ComposedMap, Piece, Port, ScenarioSpan, compose
from mjdrive.roads.roadmap import Crosswalk, LaneQuery, RoadMap
from mjdrive.roads.urban import (
    FOLLOW,
    RouteWaypoints,
    TacticalTrajectory,
    UrbanRoute,
    concatenated,
    plan_route,
    route_through,
    tactical_trajectory,
    urban_route,
)
from mjdrive.roads.urban_params import (
    CrossroadParams,
    MergeParams,
    OvertakingRoadParams,
    RoundaboutParams,
    UrbanMap,
)
from mjdrive.roads.urban_pieces import crossroad, merge_road, overtaking_road, roundabout_piece

__all__ = [
    "Crosswalk", "Lane", "LaneQuery", "Marking", "Path", "RoadMap",
    "crafted_routes", "curve", "fillet", "junction", "merge", "resample", "roundabout", "roundabout_routes",
    "s_curve", "spawn_points", "straight", "town", "two_lane_road", "wrap_angle",
    # study 002: composable pieces, routes, tactical trajectory, conflict zones
    "FOLLOW", "ComposedMap", "ConflictZones", "CrossroadParams", "MergeParams", "OvertakingRoadParams", "Piece",
    "Port", "RoundaboutParams", "RouteConflicts", "RouteWaypoints", "ScenarioSpan", "TacticalTrajectory",
    "UrbanMap", "UrbanRoute", "compose", "concatenated", "conflict_zones", "crossroad", "merge_road", "overtaking_road",
    "plan_route", "roundabout_piece", "route_through", "tactical_trajectory", "urban_route",
]
