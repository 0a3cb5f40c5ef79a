"""Composable road pieces: a piece is a RoadMap plus named ports where other pieces join it.

A `Port` is the end of a road: a reference point on the line between the two directions (x, y [m]), the
heading [rad] pointing along `lanes` (the lanes driving in that direction, ordered from the centre line
outward), the opposite lanes `reverse` (same order) and the lane width [m]. A piece's entry port points
into the piece (its `lanes` start there), an exit port points out of it (its `lanes` end there).

`compose` places each piece by the rigid transform that puts its entry port on the previous piece's exit
port (same point, same heading) and joins the lanes there into one lane graph: no hand-placed coordinates
and no name matching. Lane k of a port lies at lateral offset -(k + 1/2) * lane_width from the reference
point (on its right) and reverse lane k at +(k + 1/2) * lane_width.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from mjdrive.roads.geometry import wrap_angle
from mjdrive.roads.roadmap import RoadMap

PORT_TOLERANCE = 1e-6  # [m] largest gap between joined lane ends
OVERLAP_STEP = 1.0  # [m] spacing of the lane points checked against the pieces placed before
END_CLEARANCE = 0.5  # [m] lane points this close to a lane end are not checked (they touch the port)
SCENARIOS = ("roundabout", "lane_change", "crossroad", "merge")  # scenario names of the tactical trajectory


@dataclass(frozen=True)
class Port:
    """Where a piece meets another: end pose of its lanes (see the module docstring)."""

    name: str
    x: float  # [m]
    y: float  # [m]
    heading: float  # [rad] direction of travel of `lanes`
    lanes: tuple[int, ...]  # lane ids driving along `heading`, from the centre line outward
    reverse: tuple[int, ...]  # lane ids driving against `heading`, from the centre line outward
    lane_width: float  # [m]

    @property
    def n_lanes(self) -> int:
        """Number of lanes driving along the port's heading."""
        return len(self.lanes)

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x [m], y [m], heading [rad])."""
        return self.x, self.y, self.heading

    def moved(self, rotation: float, offset: np.ndarray, lane_offset: int) -> Port:
        """The port after rotating by `rotation` [rad] about the origin, shifting by `offset` [m] and
        renumbering lanes by `lane_offset`."""
        c, s = math.cos(rotation), math.sin(rotation)
        x = c * self.x - s * self.y + float(offset[0])
        y = s * self.x + c * self.y + float(offset[1])
        return replace(self, x=x, y=y, heading=float(wrap_angle(self.heading + rotation)),
                       lanes=tuple(i + lane_offset for i in self.lanes),
                       reverse=tuple(i + lane_offset for i in self.reverse))


@dataclass(frozen=True)
class ScenarioSpan:
    """Where a scenario of the tactical trajectory starts and ends on a route through a piece: the first
    route lane listed in `start` at its s [m], up to the first later route lane listed in `end`."""

    name: str  # one of SCENARIOS
    start: tuple[tuple[int, float], ...]  # (lane id, s [m])
    end: tuple[tuple[int, float], ...]  # (lane id, s [m])

    def __post_init__(self) -> None:
        if self.name not in SCENARIOS:
            raise ValueError(f"name={self.name!r} is not allowed: one of {SCENARIOS}")

    def moved(self, lane_offset: int) -> ScenarioSpan:
        """The span with lane ids renumbered by `lane_offset`."""
        return ScenarioSpan(self.name, tuple((i + lane_offset, s) for i, s in self.start),
                            tuple((i + lane_offset, s) for i, s in self.end))


@dataclass
class Piece:
    """A road piece: its map, ports by name, the ports a chain enters and leaves by, the lanes a route
    through it must take (`via`, in order) and its scenario spans."""

    name: str
    road_map: RoadMap
    ports: dict[str, Port]
    entry: str  # name of the port a chain enters by
    exit: str  # name of the port a chain leaves by
    via: tuple[int, ...] = ()
    scenarios: tuple[ScenarioSpan, ...] = ()
    lane_offset: int = 0  # id of the piece's first lane in a composed map (0 for a piece on its own)

    def __post_init__(self) -> None:
        for role in ("entry", "exit"):
            port = getattr(self, role)
            if port not in self.ports:
                raise ValueError(f"{role}={port!r} is not allowed: one of the ports {sorted(self.ports)}")

    @property
    def entry_port(self) -> Port:
        """The port a chain enters by."""
        return self.ports[self.entry]

    @property
    def exit_port(self) -> Port:
        """The port a chain leaves by."""
        return self.ports[self.exit]


@dataclass
class ComposedMap:
    """Pieces joined into one RoadMap; `pieces` hold their ports, vias and spans in the map's lane ids."""

    road_map: RoadMap
    pieces: list[Piece] = field(default_factory=list)

    @property
    def start_lane(self) -> int:
        """The rightmost lane of the first piece's entry port."""
        return self.pieces[0].entry_port.lanes[-1]

    @property
    def goal_lane(self) -> int:
        """The rightmost lane of the last piece's exit port."""
        return self.pieces[-1].exit_port.lanes[-1]


def transform_to(port: Port, target: tuple[float, float, float]) -> tuple[float, np.ndarray]:
    """(rotation [rad], offset (2,) [m]) of the rigid transform that moves `port` onto pose `target`."""
    rotation = float(wrap_angle(target[2] - port.heading))
    c, s = math.cos(rotation), math.sin(rotation)
    offset = np.array([target[0] - (c * port.x - s * port.y), target[1] - (s * port.x + c * port.y)])
    return rotation, offset


def place(dst: RoadMap, piece: Piece, rotation: float = 0.0, offset=(0.0, 0.0), prefix: str = "") -> Piece:
    """Copy `piece` into `dst` (rotated by `rotation` [rad], shifted by `offset` [m], names prefixed);
    returns the piece as placed (ports, vias and spans in `dst`'s lane ids)."""
    off = np.asarray(offset, dtype=float)
    base = dst.add_map(piece.road_map, offset=off, rotation=rotation, prefix=prefix)
    ports = {name: p.moved(rotation, off, base) for name, p in piece.ports.items()}
    return Piece(piece.name, dst, ports, piece.entry, piece.exit, tuple(i + base for i in piece.via),
                 tuple(span.moved(base) for span in piece.scenarios), base)


def join(rm: RoadMap, out: Port, into: Port) -> None:
    """Connect the lanes of exit port `out` to those of entry port `into` (both in `rm`, at one pose)."""
    where = f"ports {out.name!r} -> {into.name!r}"
    if (out.n_lanes, len(out.reverse)) != (into.n_lanes, len(into.reverse)):
        raise ValueError(f"{where}: lane counts (forward, reverse) {(out.n_lanes, len(out.reverse))} and "
                         f"{(into.n_lanes, len(into.reverse))} differ; allowed: equal counts")
    if abs(out.lane_width - into.lane_width) > 1e-9:
        raise ValueError(f"{where}: lane widths {out.lane_width} m and {into.lane_width} m differ; allowed: equal")
    pairs = list(zip(out.lanes, into.lanes, strict=True)) + list(zip(into.reverse, out.reverse, strict=True))
    for a, b in pairs:
        gap = float(np.hypot(*(rm.lanes[a].centre[-1] - rm.lanes[b].centre[0])))
        if gap > PORT_TOLERANCE:
            raise ValueError(f"{where}: lane {rm.lanes[a].name!r} ends {gap:.3g} m from {rm.lanes[b].name!r}")
        rm.connect(a, b)


def compose(pieces: Sequence[Piece], name: str = "composed") -> ComposedMap:
    """Chain `pieces`: the first stays where it was built, each next one is moved so that its entry port
    lies on the previous piece's exit port, and the lanes are joined there. Lane names are prefixed with
    the piece name ("roundabout/arm2_in_0"; a repeated name gets its index appended)."""
    if not pieces:
        raise ValueError("pieces=[] is not allowed: at least one piece")
    rm = RoadMap(name)
    placed: list[Piece] = []
    used: set[str] = set()
    for k, piece in enumerate(pieces):
        prefix = piece.name if piece.name not in used else f"{piece.name}{k}"
        used.add(prefix)
        if k == 0:
            rotation, offset = 0.0, np.zeros(2)
        else:
            rotation, offset = transform_to(piece.entry_port, placed[-1].exit_port.pose)
        before = (len(rm.lanes), len(rm.areas))
        placed.append(place(rm, piece, rotation, offset, prefix + "/"))
        if k:
            _check_clear(rm, *before, piece.name)
        if k:
            join(rm, placed[-2].exit_port, placed[-1].entry_port)
    return ComposedMap(rm.freeze(), placed)


def _check_clear(rm: RoadMap, first: int, first_area: int, name: str) -> None:
    """ValueError if a lane from id `first` on runs over the lanes before it or areas before `first_area`."""
    pts = []
    for lane in rm.lanes[first:]:
        s = np.arange(END_CLEARANCE, lane.length - END_CLEARANCE, OVERLAP_STEP)
        pts.append(lane.position(s).reshape(-1, 2))
    earlier = RoadMap("earlier")
    for lane in rm.lanes[:first]:
        earlier.add_lane(lane)
    for area in rm.areas[:first_area]:
        earlier.add_area(area)
    pts = np.vstack(pts)
    hit = earlier.on_road(pts)
    if np.any(hit):
        x, y = pts[np.argmax(hit)]
        raise ValueError(f"piece {name!r} overlaps the pieces placed before it at ({x:.1f}, {y:.1f}) m; "
                         "allowed: pieces that meet only at their ports (change lengths or angles)")
