"""3D scene content for Foxglove: the road (once per file, encoded once per map), the route and its
waypoints (once per episode; urban tasks: the tactical trajectory's scenario segments, coloured and labelled),
the ego box (locked to the "ego" frame), road-user colours and the urban road users' intention labels."""

from __future__ import annotations

import zlib

import numpy as np
from foxglove import messages as fm

from mjdrive.roads import Marking, RoadMap
from mjdrive.traffic import intentions

WORLD, EGO = "world", "ego"  # frame ids
ROAD_Z, MARKING_Z, ROUTE_Z = 0.01, 0.02, 0.05  # [m] drawing heights (above MuJoCo's road meshes)
SCENARIO_Z, LABEL_Z = 0.08, 1.0  # [m] scenario segments; labels above a road user's roof (+ its height)
PLAN_Z = 0.12  # [m] the operative level's path ahead
SCENARIO_WIDTH, SCENARIO_STEP = 1.2, 1.0  # [m] scenario segments' line width and point spacing
MARKING_WIDTH = 0.15  # [m]
DASH_ON, DASH_OFF = 3.0, 6.0  # [m] broken-line pattern, as in world.py

ASPHALT = (0.32, 0.32, 0.34, 1.0)
PAVED_AREA = (0.36, 0.36, 0.38, 1.0)
WHITE = (0.95, 0.95, 0.95, 1.0)
ROUTE = (0.1, 0.6, 1.0, 0.9)
WAYPOINT = (0.1, 0.9, 0.2, 0.9)
EGO_RGBA = (0.9, 0.3, 0.1, 0.9)
KIND_RGBA = {  # road users by kind; other kinds get a stable colour from their name
    "car": (0.2, 0.45, 0.9, 1.0), "truck": (0.55, 0.35, 0.2, 1.0), "bus": (0.95, 0.75, 0.1, 1.0),
    "motorcycle": (0.7, 0.2, 0.8, 1.0), "bicycle": (0.2, 0.8, 0.7, 1.0), "cyclist": (0.2, 0.8, 0.7, 1.0),
    "pedestrian": (0.95, 0.3, 0.5, 1.0), "obstacle": (0.5, 0.5, 0.5, 1.0),
}
SCENARIO_RGBA = {  # the urban route's scenario segments (tactical trajectory)
    "roundabout": (0.95, 0.55, 0.1, 0.6), "lane_change": (0.3, 0.85, 0.3, 0.6),
    "crossroad": (0.9, 0.2, 0.25, 0.6), "merge": (0.65, 0.35, 0.95, 0.6), "follow": (0.6, 0.6, 0.6, 0.4),
}
# intention labels: short scenario prefix and value names, columns as `intentions.SCENARIOS`
INTENTION_NAMES = {
    "lane_change": ("LC", ("keep", "left", "right")), "crossroad": ("X", ("straight", "left", "right")),
    "merge": ("M", ("yield", "take way")), "roundabout": ("R", ("before", "after")),
}
INTENTION_RGBA = ((0.3, 0.95, 0.3, 1.0), (1.0, 0.6, 0.1, 1.0), (0.95, 0.35, 0.95, 1.0))  # by value 0, 1, 2
NO_INTENTION_RGBA = (0.95, 0.95, 0.95, 1.0)  # outside the scenarios with intentions


def color(rgba: tuple[float, float, float, float]) -> fm.Color:
    return fm.Color(r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3])


def kind_rgba(kind: str) -> tuple[float, float, float, float]:
    """Colour of a road-user kind (known kinds fixed, others hashed from the name)."""
    if kind in KIND_RGBA:
        return KIND_RGBA[kind]
    h = zlib.crc32(kind.encode())
    return (0.3 + 0.6 * (h & 0xFF) / 255, 0.3 + 0.6 * (h >> 8 & 0xFF) / 255, 0.3 + 0.6 * (h >> 16 & 0xFF) / 255, 1.0)


class KindColors:
    """(N,4) colours of a tuple of kinds, cached per distinct tuple (kinds rarely change between steps)."""

    def __init__(self):
        self._cache: dict[tuple[str, ...], np.ndarray] = {}

    def __call__(self, kinds: tuple[str, ...]) -> np.ndarray:
        rgba = self._cache.get(kinds)
        if rgba is None:
            if len(self._cache) > 256:
                self._cache.clear()
            rgba = self._cache[kinds] = np.array([kind_rgba(k) for k in kinds], np.float64).reshape(-1, 4)
        return rgba


def _points(xy: np.ndarray, z: float) -> list[fm.Point3]:
    return [fm.Point3(x=float(x), y=float(y), z=z) for x, y in xy]


def _strip_triangles(left: np.ndarray, right: np.ndarray, base: int) -> np.ndarray:
    """Indices (2(N-1)*3,) of the triangles between two polylines stored interleaved from `base`."""
    i = np.arange(len(left) - 1)
    l0, r0 = base + 2 * i, base + 2 * i + 1
    return np.stack([l0, r0, l0 + 2, r0, r0 + 2, l0 + 2], 1).ravel()


def _dashes(line: np.ndarray) -> list[np.ndarray]:
    """DASH_ON pieces of a polyline separated by DASH_OFF gaps."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])
    pieces = []
    for start in np.arange(0.0, s[-1], DASH_ON + DASH_OFF):
        ss = np.linspace(start, min(start + DASH_ON, s[-1]), 4)
        pieces.append(np.stack([np.interp(ss, s, line[:, 0]), np.interp(ss, s, line[:, 1])], 1))
    return pieces


def _segments(line: np.ndarray) -> np.ndarray:
    """(2(N-1),2) endpoints of a polyline's segments, for a LineList."""
    return np.stack([line[:-1], line[1:]], 1).reshape(-1, 2)


def road_entities(road_map: RoadMap) -> list[fm.SceneEntity]:
    """Lane surfaces and paved areas (triangle lists), markings (line lists, solid and dashed), crosswalks."""
    points: list[np.ndarray] = []
    indices: list[np.ndarray] = []
    count = 0
    for lane in road_map.lanes:
        left, right = lane.left_edge(), lane.right_edge()
        pts = np.empty((2 * len(left), 2))
        pts[0::2], pts[1::2] = left, right
        points.append(pts)
        indices.append(_strip_triangles(left, right, count))
        count += len(pts)
    surface = fm.TriangleListPrimitive(
        points=_points(np.concatenate(points), ROAD_Z) if points else [],
        indices=np.concatenate(indices).tolist() if indices else [], color=color(ASPHALT))
    areas = []
    for polygon in road_map.areas:  # convex polygons: triangle fans
        k = len(polygon)
        fan = np.stack([np.zeros(k - 2, int), np.arange(1, k - 1), np.arange(2, k)], 1).ravel()
        areas.append(fm.TriangleListPrimitive(points=_points(np.asarray(polygon), ROAD_Z + 0.002),
                                              indices=fan.tolist(), color=color(PAVED_AREA)))
    solid, broken = [], []
    for line, kind in road_map.marking_lines():
        line = np.asarray(line, float)
        if len(line) < 2 or kind == Marking.NONE:
            continue
        if kind == Marking.SOLID:
            solid.append(_segments(line))
        else:
            broken.extend(_segments(piece) for piece in _dashes(line))
    lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineList, thickness=MARKING_WIDTH,
                              points=_points(np.concatenate(group), MARKING_Z), color=color(WHITE))
             for group in (solid, broken) if group]
    crosswalks = []
    for cw in getattr(road_map, "crosswalks", []):
        corners = cw.polygon()
        crosswalks.append(fm.TriangleListPrimitive(points=_points(corners, MARKING_Z), indices=[0, 1, 2, 0, 2, 3],
                                                   color=color((0.85, 0.85, 0.85, 0.6))))
    return [
        fm.SceneEntity(frame_id=WORLD, id="road/surface", triangles=[surface, *areas]),
        fm.SceneEntity(frame_id=WORLD, id="road/markings", lines=lines),
        fm.SceneEntity(frame_id=WORLD, id="road/crosswalks", triangles=crosswalks),
    ]


def route_entities(task, stamp: fm.Timestamp | None = None) -> list[fm.SceneEntity]:
    """The task's route centre line (`task.route_lane`), waypoints (`task.tracker.points`) and scenario
    segments (`task.urban.tactical`), if any."""
    entities = []
    route_lane = getattr(task, "route_lane", None)
    if route_lane is not None:
        entities.append(fm.SceneEntity(timestamp=stamp, frame_id=WORLD, id="route/line", lines=[fm.LinePrimitive(
            type=fm.LinePrimitiveLineType.LineStrip, thickness=0.3,
            points=_points(np.asarray(route_lane.centre), ROUTE_Z), color=color(ROUTE))]))
    tactical = getattr(getattr(task, "urban", None), "tactical", None)  # urban tasks: the scenario segments
    if route_lane is not None and tactical is not None:
        entities.append(scenario_entity(route_lane, tactical, stamp))
    tracker = getattr(task, "tracker", None)
    if tracker is not None and len(tracker.points):
        size = fm.Vector3(x=0.6, y=0.6, z=0.1)
        spheres = [fm.SpherePrimitive(pose=fm.Pose(position=fm.Vector3(x=float(x), y=float(y), z=ROUTE_Z),
                                                   orientation=fm.Quaternion(w=1.0)),
                                      size=size, color=color(WAYPOINT)) for x, y in tracker.points]
        entities.append(fm.SceneEntity(timestamp=stamp, frame_id=WORLD, id="route/waypoints", spheres=spheres))
    return entities


def plan_entity(path: np.ndarray, stop_line: np.ndarray | None, rgba, stop_rgba,
                stamp: fm.Timestamp | None = None) -> fm.SceneEntity:
    """A planned path (N, 2) [m] as a line strip, and a stop line (2, 2) [m] across it where there is one."""
    lines = [fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.25,
                              points=_points(np.asarray(path, float), PLAN_Z), color=color(rgba))]
    if stop_line is not None:
        lines.append(fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.4,
                                      points=_points(np.asarray(stop_line, float), PLAN_Z), color=color(stop_rgba)))
    return fm.SceneEntity(timestamp=stamp, frame_id=WORLD, id="operative/plan", lines=lines)


def scenario_entity(route_lane, tactical, stamp: fm.Timestamp | None = None) -> fm.SceneEntity:
    """The tactical trajectory's scenario intervals along the route line (`route_lane`, a Lane): a wide line
    per interval coloured by scenario (SCENARIO_RGBA), its name written at its start."""
    lines, texts = [], []
    for name, s0, s1 in tactical.intervals:
        s = np.append(np.arange(s0, s1, SCENARIO_STEP), s1)
        xy = np.asarray(route_lane.position(s)).reshape(-1, 2)
        rgba = SCENARIO_RGBA.get(name, kind_rgba(name))
        lines.append(fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=SCENARIO_WIDTH,
                                      points=_points(xy, SCENARIO_Z), color=color(rgba)))
        texts.append(fm.TextPrimitive(
            pose=fm.Pose(position=fm.Vector3(x=float(xy[0, 0]), y=float(xy[0, 1]), z=2.0),
                         orientation=fm.Quaternion(w=1.0)),
            billboard=True, font_size=16.0, scale_invariant=True, color=color((*rgba[:3], 1.0)), text=name))
    return fm.SceneEntity(timestamp=stamp, frame_id=WORLD, id="route/scenarios", lines=lines, texts=texts)


class IntentionLabels:
    """Text labels of road users' intentions, e.g. "LC keep | X left | M yield | R after" (pedestrians, whose
    intentions are -1, get none), coloured by the value in the active scenario (INTENTION_RGBA; white outside
    the scenarios with intentions). Each (intentions, colour) label is encoded once (`proto.text_field`)."""

    def __init__(self):
        self._fields: dict[tuple[tuple[int, ...], int], tuple[bytes, int]] = {}

    @staticmethod
    def text(row: tuple[int, ...]) -> str:
        """The label of one road user's intentions (columns `intentions.SCENARIOS`)."""
        parts = []
        for scenario, value in zip(intentions.SCENARIOS, row, strict=True):
            prefix, names = INTENTION_NAMES[scenario]
            parts.append(f"{prefix} {names[value] if 0 <= value < len(names) else value}")
        return " | ".join(parts)

    def __call__(self, users, scenario: str | None) -> bytes:
        """The `texts` fields of a SceneEntity for `users` (a RoadUsers with intentions) when the ego's active
        scenario is `scenario`."""
        from mjdrive.record import proto

        rows = np.asarray(users.intentions).reshape(len(users.kinds), -1)
        labelled = np.flatnonzero((rows >= 0).all(axis=1))
        if not len(labelled):
            return b""
        column = intentions.SCENARIOS.index(scenario) if scenario in intentions.SCENARIOS else None
        shade = rows[labelled, column] if column is not None else np.full(len(labelled), -1)  # colour index
        z = 2.0 * users.half_sizes[labelled, 2] + LABEL_Z
        out = bytearray()
        for row, (x, y), height, c in zip(rows[labelled].tolist(), users.poses[labelled, :2].tolist(), z.tolist(),
                                          shade.tolist(), strict=True):
            key = (tuple(row), c)
            cached = self._fields.get(key)
            if cached is None:
                if len(self._fields) > 4096:
                    self._fields.clear()
                rgba = INTENTION_RGBA[c] if 0 <= c < len(INTENTION_RGBA) else NO_INTENTION_RGBA
                cached = self._fields[key] = proto.text_field(self.text(key[0]).encode(), rgba)
            field, at = cached
            start = len(out)
            out += field
            proto.place(out, start + at, x, y, height)
        return bytes(out)


def ego_entity(length: float, width: float, height: float, stamp: fm.Timestamp | None = None) -> fm.SceneEntity:
    """The ego car as a box in its own frame (origin on the ground at the footprint centre)."""
    cube = fm.CubePrimitive(
        pose=fm.Pose(position=fm.Vector3(z=height / 2), orientation=fm.Quaternion(w=1.0)),
        size=fm.Vector3(x=length, y=width, z=height), color=color(EGO_RGBA))
    return fm.SceneEntity(timestamp=stamp, frame_id=EGO, id="ego", frame_locked=True, cubes=[cube])


SIGNAL_RGBA = {"green": (0.1, 0.85, 0.25, 1.0), "amber": (1.0, 0.7, 0.0, 1.0), "red": (0.9, 0.1, 0.1, 1.0),
               "stop": (0.8, 0.05, 0.05, 1.0)}  # by what a junction entry shows
SIGNAL_SIZE, SIGNAL_HEIGHT = 0.6, 3.0  # [m] the lamp's cube and how high it hangs


def signals_entity(xy: np.ndarray, states: list[str], stamp: fm.Timestamp | None = None) -> fm.SceneEntity:
    """The junction entries' signals at their lines' kerbside points (E, 2) [m]: a lamp coloured by what each
    shows (green, amber, red), a stop sign's lamp red and labelled STOP."""
    cubes, texts = [], []
    for (x, y), state in zip(np.asarray(xy, float).reshape(-1, 2), states, strict=True):
        position = fm.Vector3(x=float(x), y=float(y), z=SIGNAL_HEIGHT)
        cubes.append(fm.CubePrimitive(pose=fm.Pose(position=position, orientation=fm.Quaternion(w=1.0)),
                                      size=fm.Vector3(x=SIGNAL_SIZE, y=SIGNAL_SIZE, z=SIGNAL_SIZE),
                                      color=color(SIGNAL_RGBA[state])))
        if state == "stop":
            texts.append(fm.TextPrimitive(
                pose=fm.Pose(position=fm.Vector3(x=float(x), y=float(y), z=SIGNAL_HEIGHT + 0.8),
                             orientation=fm.Quaternion(w=1.0)),
                billboard=True, font_size=14.0, scale_invariant=True, color=color(SIGNAL_RGBA["stop"]), text="STOP"))
    return fm.SceneEntity(timestamp=stamp, frame_id=WORLD, id="junction/signals", cubes=cubes, texts=texts)
