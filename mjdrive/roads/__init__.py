"""Road maps for mjdrive: lanes, lane graphs, lane-frame queries and map builders (pure numpy).

Coordinates: x east, y north [m]; headings [rad] counter-clockwise from +x; right-hand traffic; lateral
offsets d > 0 to the left of the direction of travel.
"""

from mjdrive.roads.builders import crafted_routes, curve, merge, spawn_points, straight, two_lane_road
from mjdrive.roads.geometry import Path, fillet, s_curve, wrap_angle
from mjdrive.roads.junctions import junction, roundabout, roundabout_routes, town
from mjdrive.roads.lane import Lane, Marking, resample
from mjdrive.roads.roadmap import Crosswalk, LaneQuery, RoadMap

__all__ = [
    "Crosswalk", "Lane", "LaneQuery", "Marking", "Path", "RoadMap",
    "crafted_routes", "curve", "fillet", "junction", "merge", "resample", "roundabout", "roundabout_routes",
    "s_curve", "spawn_points", "straight", "town", "two_lane_road", "wrap_angle",
]
