"""OpenDRIVE (.xodr) road networks as mjdrive maps, read by pyxodr (the `opendrive` extra).

pyxodr samples every road's reference line (line, arc, spiral, poly3, paramPoly3), its lane offset, lane sections
and lane widths, and links lanes through road links and junction connections; this module turns its driving lanes
into `Lane`s (centre lines in the direction of travel, mean width, the road's speed limit, in_junction for a
junction's connecting roads), the lane graph (successors, same-direction neighbours), a paved area per junction, and
finds routes between two points (Dijkstra over the lane graph). Conflict zones come from the map as for any other
(`roads.conflict_zones`). A junction's lanes all have the same rank (first come, first served) unless the file ranks
its roads (`<junction><priority high="ROAD" low="ROAD"/>`): then a connecting lane takes its incoming road's rank
(a road named low anywhere in the junction is the minor road, one named only high the main road), a left turn one
step lower, as on the crossroad piece; the minor roads' lanes give way at the junction's mouth, and every entry
lane is a junction entry of its road's group (stop signs and traffic lights, `junction_control`, apply).

The file's own stop signs and traffic lights (`<signal>` on a road, or a `<signalReference>` to one) mark the
junction entries they face (`RoadMap.entry_signs`, in force under `junction_control="map"`): the lanes of that road
that drive in the signal's orientation ("+": along the road, "-": against it, "none": both; within its
`<validity>` lanes) and end at a junction. A dynamic signal or one of the catalogue's 1000xxx types is a traffic
light, type 206 (or a name with "stop") a stop sign; other signs are left out. Lights switch by group: the signals
of a junction's first controller (`<junction><controller sequence>`) are the main road's, the others the minor
road's; without controllers an entry that the ranks have not grouped joins the main road's group when it runs
parallel to the junction's first signalised entry, else the minor road's.

    rm = read_opendrive("town.xodr")
    route = route_between(rm, (x0, y0), (x1, y1))   # lane ids

Why pyxodr: a maintained pure-Python reader (MIT) that samples the geometry itself, with light dependencies (lxml,
shapely, scipy); CommonRoad's opendrive2lanelet pulls in commonroad-io, pyproj and protobuf and converts to lanelets
rather than reading lanes. One defect is worked around here: pyxodr divides by the curvature's rate of change of a
spiral, so a spiral of constant curvature (which generators such as scenariogeneration write) is given to it as the
arc or line it is (its curvature changing slower than FLAT_SPIRAL: pyxodr's clothoid fails there).
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence

import numpy as np

from mjdrive.config import ConfigError
from mjdrive.roads.geometry import convex_hull
from mjdrive.roads.lane import Lane, Marking, resample
from mjdrive.roads.roadmap import MAIN_ROAD, MINOR_ROAD, RoadMap
from mjdrive.roads.urban_pieces import PRIORITY_MAJOR, PRIORITY_MINOR, connector_priority

SPEED_UNITS = {"m/s": 1.0, "km/h": 1 / 3.6, "mph": 0.44704}  # OpenDRIVE's speed units, to m/s
DEFAULT_SPEED = 50 / 3.6  # [m/s] a road without a speed record
SAMPLE_STEP = 0.5  # [m] pyxodr's sampling resolution
LANE_STEP = 1.0  # [m] the lanes' vertex spacing
MIN_LANE_LENGTH = 1.0  # [m] shorter driving lanes (slivers between lane sections) are left out
FLAT_SPIRAL = 1e-9  # [1/m^2] a spiral whose curvature changes slower than this is read as an arc


def _missing_extra() -> ConfigError:
    return ConfigError("reading OpenDRIVE needs the `opendrive` extra: pip install 'mjdrive[opendrive]'")


def _parse(path: str | os.PathLike):
    """The file's XML tree, its degenerate spirals normalised; ConfigError naming the file if it is not OpenDRIVE."""
    try:
        from lxml import etree
    except ImportError:
        raise _missing_extra() from None
    name = os.fspath(path)
    if not os.path.isfile(name):
        raise ConfigError(f"opendrive={name!r}: cannot read the file (no such file)")
    try:
        tree = etree.parse(name)
    except OSError as error:
        raise ConfigError(f"opendrive={name!r}: cannot read the file ({error})") from None
    except etree.XMLSyntaxError as error:
        raise ConfigError(f"opendrive={name!r}: not an XML file ({error.msg})") from None
    root = tree.getroot()
    if root.tag != "OpenDRIVE":
        raise ConfigError(f"opendrive={name!r}: the root element is <{root.tag}>, not <OpenDRIVE>")
    if not root.findall("road"):
        raise ConfigError(f"opendrive={name!r}: no <road> in the file")
    for geometry in root.iter("geometry"):
        spiral = geometry.find("spiral")
        if spiral is None:
            continue
        start, end, length = (float(spiral.get("curvStart")), float(spiral.get("curvEnd")),
                              float(geometry.get("length")))
        if abs(end - start) < FLAT_SPIRAL * length:  # a spiral of (all but) constant curvature: the arc it is
            curvature = 0.5 * (start + end)
            geometry.remove(spiral)
            if curvature == 0.0:
                etree.SubElement(geometry, "line")
            else:
                etree.SubElement(geometry, "arc", curvature=repr(curvature))
    return tree


def _speed_limit(road_xml) -> float:
    """[m/s] the road's first speed record (<type><speed max unit>), else DEFAULT_SPEED."""
    for speed in road_xml.iter("speed"):
        value = speed.get("max")
        try:
            limit = float(value) * SPEED_UNITS.get(speed.get("unit", "m/s"), 1.0)
        except (TypeError, ValueError):
            continue
        if math.isfinite(limit) and limit > 0:
            return limit
    return DEFAULT_SPEED


def _signal_kind(signal) -> str | None:
    """"lights", "stop" or None (a sign mjdrive does not model) for a <signal> element (module docstring)."""
    kind = signal.get("type") or ""
    if signal.get("dynamic") == "yes" or kind.startswith("1000"):
        return "lights"
    if kind == "206" or "stop" in (signal.get("name") or "").lower():
        return "stop"
    return None


def _validity(element) -> tuple[int, int] | None:
    """The lane ids (low, high) a signal's first <validity fromLane toLane> covers; None: every lane."""
    validity = element.find("validity")
    try:
        low, high = int(validity.get("fromLane")), int(validity.get("toLane"))
    except (AttributeError, TypeError, ValueError):
        return None
    return min(low, high), max(low, high)


def _road_signals(root) -> dict[str, list[tuple[str, str, tuple[int, int] | None, str]]]:
    """Road id -> its stop signs and traffic lights, each (kind, orientation, validity, signal id); a
    <signalReference> counts on the road that holds it, as the signal it names."""
    kinds = {signal.get("id"): _signal_kind(signal) for signal in root.iter("signal")}
    signals: dict[str, list[tuple[str, str, tuple[int, int] | None, str]]] = {}
    for road in root.iter("road"):
        for element in (*road.iter("signal"), *road.iter("signalReference")):
            kind = kinds.get(element.get("id"))
            if kind is not None:
                signals.setdefault(road.get("id"), []).append(
                    (kind, element.get("orientation") or "none", _validity(element), element.get("id")))
    return signals


def _signal_groups(root) -> dict[str, int]:
    """Signal id -> MAIN_ROAD (the signals of a junction's first controller by `sequence`) or MINOR_ROAD (the rest)."""
    controlled = {controller.get("id"): [control.get("signalId") for control in controller.iter("control")]
                  for controller in root.findall("controller")}
    groups: dict[str, int] = {}
    for junction in root.iter("junction"):
        refs = junction.findall("controller")
        order = sorted(range(len(refs)), key=lambda k: (_number(refs[k].get("sequence"), k), k))
        for rank, k in enumerate(order):
            for signal in controlled.get(refs[k].get("id"), []):
                groups[signal] = MAIN_ROAD if rank == 0 else MINOR_ROAD
    return groups


def _number(text: str | None, default: float) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return default


def _apply_signals(rm: RoadMap, root, lane_of: dict[int, tuple[str, int, bool]], junction_of: dict[int, str]) -> None:
    """The file's stop signs and traffic lights at the junction entries they face (module docstring); entries that
    the ranks did not make are added, grouped by controller or by heading. lane_of: our lane -> (road id, lane id,
    whether it drives along the road)."""
    signals, groups = _road_signals(root), _signal_groups(root)
    if not signals:
        return
    entries = dict(rm.junction_entries)
    ungrouped: list[tuple[int, str]] = []
    for index, (road, lane_id, forward) in lane_of.items():
        ahead = [junction_of[j] for j in rm.successors[index] if j in junction_of]
        if rm.lanes[index].in_junction or not ahead:
            continue
        for kind, orientation, lanes, signal in signals.get(road, ()):
            if (orientation == "+" and not forward) or (orientation == "-" and forward):
                continue
            if lanes is not None and not lanes[0] <= lane_id <= lanes[1]:
                continue
            if rm.entry_signs.get(index) != "lights":  # lights and a sign on one lane: the lights rule
                rm.entry_signs[index] = kind
            if index not in entries and signal in groups:
                entries[index] = groups[signal]
                rm.junction_entries.append((index, groups[signal]))
        if index in rm.entry_signs and index not in entries:
            ungrouped.append((index, ahead[0]))
    axes: dict[str, float] = {}
    for index, junction in ungrouped:
        end = np.diff(rm.lanes[index].centre[-2:], axis=0)[0]
        heading = math.atan2(end[1], end[0])  # [rad] where the lane enters the junction
        axis = axes.setdefault(junction, heading)
        group = MAIN_ROAD if abs(math.sin(heading - axis)) < math.sqrt(0.5) else MINOR_ROAD  # within 45 deg
        entries[index] = group
        rm.junction_entries.append((index, group))


def _road_ranks(root) -> dict[str, dict[str, int]]:
    """Junction id -> {road id: PRIORITY_MAJOR or PRIORITY_MINOR} from the junctions' <priority high low> records."""
    ranks: dict[str, dict[str, int]] = {}
    for junction in root.iter("junction"):
        pairs = [(record.get("high"), record.get("low")) for record in junction.iter("priority")]
        if not pairs:
            continue
        low = {b for _, b in pairs if b is not None}
        ranks[junction.get("id")] = {road: PRIORITY_MINOR if road in low else PRIORITY_MAJOR
                                     for pair in pairs for road in pair if road is not None}
    return ranks


def _apply_ranks(rm: RoadMap, ranks: dict[str, dict[str, int]], road_of: dict[int, str],
                 junction_of: dict[int, str]) -> None:
    """Right of way from the junctions' road ranks (module docstring): lane priorities, give-way lines at the minor
    roads' mouths, junction entries."""
    for index, lane in enumerate(rm.lanes):
        if lane.in_junction or index not in road_of:
            continue
        entered = {junction_of[j] for j in rm.successors[index] if j in junction_of}
        for junction in sorted(entered & ranks.keys()):  # sorted: a set's order changes between processes
            rank = ranks[junction].get(road_of[index])
            if rank is None:
                continue
            lane.priority = rank
            rm.junction_entries.append((index, MAIN_ROAD if rank == PRIORITY_MAJOR else MINOR_ROAD))
            if rank == PRIORITY_MINOR:
                rm.give_way.append((index, lane.length))
    for index, junction in junction_of.items():
        sources = [road_of[j] for j in rm.predecessors(index) if j in road_of]
        rank = ranks.get(junction, {}).get(sources[0]) if sources else None
        if rank is None:
            continue
        rm.lanes[index].priority = connector_priority(rm.lanes[index], rank)


def read_opendrive(path: str | os.PathLike, name: str | None = None) -> RoadMap:
    """The driving lanes of an OpenDRIVE file as a RoadMap (module docstring). ConfigError for a file that cannot be
    read, is not OpenDRIVE, uses what pyxodr does not support, or has no driving lane."""
    tree = _parse(path)
    try:
        from lxml import etree
        from pyxodr.road_objects.network import RoadNetwork
    except ImportError:
        raise _missing_extra() from None
    label = os.fspath(path)
    try:
        roads = RoadNetwork(io.BytesIO(etree.tostring(tree)), resolution=SAMPLE_STEP).get_roads()
        lanes = [(road, k, lane) for road in roads for k, section in enumerate(road.lane_sections)
                 for lane in section.lanes if lane.type == "driving"]
        flows = {id(lane): lane.traffic_flow_line[:, :2] for _, _, lane in lanes}
        successors = {id(lane): [id(s) for s in lane.traffic_flow_successors] for _, _, lane in lanes}
    except (ValueError, KeyError, IndexError, ZeroDivisionError, AttributeError, TypeError) as error:
        raise ConfigError(f"opendrive={label!r}: pyxodr cannot read it ({type(error).__name__}: {error})") from None
    rm = RoadMap(name or os.path.splitext(os.path.basename(label))[0])
    ids: dict[int, int] = {}
    by_section: dict[tuple[str, int], dict[int, int]] = {}
    junctions: dict[str, list[int]] = {}  # OpenDRIVE junction id -> its lanes
    lane_of: dict[int, tuple[str, int, bool]] = {}  # our lane -> (road id, lane id, whether it drives along the road)
    for road, k, lane in lanes:
        centre = resample(flows[id(lane)], LANE_STEP)
        length = float(np.hypot(*np.diff(centre, axis=0).T).sum()) if len(centre) > 1 else 0.0
        if length < MIN_LANE_LENGTH:
            continue
        width = float(np.mean(np.hypot(*(lane.boundary_line[:, :2] - lane.lane_reference_line[:, :2]).T)))
        junction = road.road_xml.get("junction", "-1")
        inside = junction != "-1"
        # markings: the centre line solid, between lanes of one direction broken (set below), the kerb solid
        marking = Marking.NONE if inside else Marking.SOLID
        index = rm.add_lane(Lane(centre, width, marking, marking, _speed_limit(road.road_xml),
                                 f"road{road.id}/section{k}/lane{lane.id}", inside))
        ids[id(lane)] = index
        lane_of[index] = (str(road.id), int(lane.id), (lane.id < 0) == (road.road_xml.get("rule", "RHT") != "LHT"))
        by_section.setdefault((road.id, k), {})[lane.id] = index
        if inside:
            junctions.setdefault(junction, []).append(index)
    if not ids:
        raise ConfigError(f"opendrive={label!r}: no driving lane in the file")
    for key, index in ids.items():  # pyxodr's successors are a set (its order changes between processes): ours, sorted
        for successor in sorted(ids[s] for s in successors[key] if s in ids):
            rm.connect(index, successor)
    for section in by_section.values():  # the lane one step nearer the reference line is the left neighbour
        for lane_id, index in section.items():
            inner = section.get(lane_id - int(np.sign(lane_id)))
            if inner is not None:
                rm.set_neighbours(inner, index)
                if not rm.lanes[index].in_junction:
                    rm.lanes[index].left_marking = rm.lanes[inner].right_marking = Marking.BROKEN
    for group in junctions.values():  # each junction's paved area: the convex hull of its lanes' strips
        strips = [np.vstack([lane.centre + lane.normals * lane.width / 2, lane.centre - lane.normals * lane.width / 2])
                  for lane in (rm.lanes[i] for i in group)]
        rm.add_area(convex_hull(np.vstack(strips)))
    junction_of = {index: junction for junction, group in junctions.items() for index in group}
    road_of = {index: road for index, (road, _, _) in lane_of.items()}  # our lane -> its OpenDRIVE road id
    _apply_ranks(rm, _road_ranks(tree.getroot()), road_of, junction_of)
    _apply_signals(rm, tree.getroot(), lane_of, junction_of)
    return rm.freeze()


def route_between(road_map: RoadMap, start: Sequence[float], goal: Sequence[float]) -> list[int]:
    """Lane ids of the shortest route (Dijkstra, `RoadMap.shortest_route`) from the lane nearest `start` (x, y) [m]
    to the lane nearest `goal`; ConfigError if the goal cannot be reached from there."""
    a, b = (road_map.locate(np.asarray(p, dtype=float)).lane for p in (start, goal))
    try:
        return road_map.shortest_route(int(a), int(b))
    except ValueError:
        raise ConfigError(f"route ({start[0]:g}, {start[1]:g}) -> ({goal[0]:g}, {goal[1]:g}): lane "
                          f"{road_map.lanes[a].name} does not lead to lane {road_map.lanes[b].name}") from None


def longest_route(road_map: RoadMap) -> list[int]:
    """The longest of the shortest routes from a lane without a predecessor to any lane it reaches (a default route
    across an imported map)."""
    has_predecessor = {s for successors in road_map.successors for s in successors}
    best: list[int] = []
    best_length = -1.0
    for start in (i for i in range(len(road_map.lanes)) if i not in has_predecessor):
        for goal in range(len(road_map.lanes)):
            if goal == start:
                continue
            try:
                route = road_map.shortest_route(start, goal, allow_lane_change=False)
            except ValueError:
                continue
            length = sum(road_map.lanes[i].length for i in route)
            if length > best_length:
                best, best_length = route, length
    if not best:
        raise ConfigError(f"map {road_map.name!r}: no route of two lanes or more")
    return best
