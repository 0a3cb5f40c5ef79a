"""The small OpenDRIVE maps shipped in mjdrive/maps/ (the `urban/opendrive` task's named maps and the tests'),
written with scenariogeneration (the dev extra), and their drawing in docs/.

    python -m tools.opendrive_maps [NAME ...]      # writes mjdrive/maps/*.xodr and docs/opendrive_maps.png

- four_way: a four-arm junction, one lane each way per arm (line arms), connecting roads for every movement;
- four_way_lights: the same junction with a traffic light on every arm, the west-east arms on the junction's first
  controller (the main road's phase), the south-north arms on its second (`junction_control="map"`);
- multilane: a two-lanes-each-way road whose reference line runs through a line, a spiral, an arc, a spiral and a
  paramPoly3, linked (a road link, no junction) to a straight road;
- roundabout: a one-lane ring of four arcs between four junctions, each with a two-way arm (written element by
  element: entries and exits are paramPoly3 curves); each junction ranks the ring over the arm (<priority>).

The maps are the project's own (generated here, same licence as the code).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

MAPS_DIR = Path(__file__).resolve().parents[1] / "mjdrive" / "maps"
LANE_WIDTH = 3.5  # [m]


def four_way(path: Path, lights: bool = False) -> None:
    from scenariogeneration import xodr

    roads = [xodr.create_road(xodr.Line(80.0), i, left_lanes=1, right_lanes=1, lane_width=LANE_WIDTH)
             for i in range(4)]
    if lights:  # a light before the junction, facing the lane that enters it (along the road)
        for i, road in enumerate(roads):
            road.add_signal(xodr.Signal(s=78.0, t=-LANE_WIDTH - 0.5, country="DEU", Type="1000001", id=str(200 + i),
                                        name=f"light{i}", dynamic=xodr.Dynamic.yes,
                                        orientation=xodr.Orientation.positive))
    junction = xodr.CommonJunctionCreator(id=100, name="four_way")
    for i, road in enumerate(roads):
        junction.add_incoming_road_circular_geometry(road=road, radius=16.0, angle=i * math.pi / 2,
                                                     road_connection="successor")
    for i in range(4):
        for j in range(i + 1, 4):
            junction.add_connection(i, j)
    _write(path, "four_way_lights" if lights else "four_way", roads, [junction])
    if lights:  # controllers (scenariogeneration writes none): arms 0 and 2, then arms 1 and 3
        from lxml import etree

        tree = etree.parse(str(path), etree.XMLParser(remove_blank_text=True))  # re-indented on writing
        root = tree.getroot()
        junction_xml = root.find("junction")
        for k, arms in enumerate(((0, 2), (1, 3))):
            controller = etree.Element("controller", id=str(300 + k), name=f"phase{k}")
            for arm in arms:
                etree.SubElement(controller, "control", signalId=str(200 + arm), type="0")
            junction_xml.addprevious(controller)
            etree.SubElement(junction_xml, "controller", id=str(300 + k), type="0", sequence=str(k + 1))
        tree.write(str(path), pretty_print=True, xml_declaration=True, encoding="utf-8")


def multilane(path: Path) -> None:
    from scenariogeneration import xodr

    geometry = [xodr.Line(60.0), xodr.Spiral(0.0, 0.01, 40.0), xodr.Arc(0.01, 50.0), xodr.Spiral(0.01, 0.0, 40.0),
                xodr.ParamPoly3(0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.002, -0.00004, "arcLength", 30.0)]
    main = xodr.create_road(geometry, 0, left_lanes=2, right_lanes=2, lane_width=LANE_WIDTH)
    narrow = xodr.create_road(xodr.Line(80.0), 1, left_lanes=2, right_lanes=2, lane_width=LANE_WIDTH)
    main.add_successor(xodr.ElementType.road, 1, xodr.ContactPoint.start)
    narrow.add_predecessor(xodr.ElementType.road, 0, xodr.ContactPoint.end)
    _write(path, "multilane", [main, narrow], [])


def roundabout(path: Path, radius: float = 20.0, arms: int = 4, mouth: float = 9.0, arm_length: float = 60.0,
               half_gap: float = 0.35) -> None:
    """A one-lane roundabout written element by element (scenariogeneration's junction builder gives no closed
    ring): the ring is `arms` arc roads between junctions; junction k, at arm k's angle, holds the ring's way
    through, the entry from the arm and the exit to it (paramPoly3 Hermite curves); one-way roads carry their lane's
    centre on the reference line (laneOffset); the arms are two-way roads. Traffic circulates counter-clockwise."""
    from lxml import etree

    root = etree.Element("OpenDRIVE")
    etree.SubElement(root, "header", revMajor="1", revMinor="6", name="roundabout")
    w = LANE_WIDTH
    angle = [2 * math.pi * k / arms for k in range(arms)]

    def ids(k: int) -> dict[str, str]:
        k %= arms
        return {"ring": str(10 + k), "arm": str(20 + k), "through": str(100 + 10 * k), "entry": str(101 + 10 * k),
                "exit": str(102 + 10 * k), "junction": str(300 + k)}

    def ring_pose(a: float) -> tuple[np.ndarray, float]:
        return radius * _unit(a), a + math.pi / 2  # on the ring's lane centre, heading counter-clockwise

    def add_road(rid, length, start, hdg, shape, lanes, junction="-1", links=()):
        road = etree.SubElement(root, "road", id=rid, length=repr(float(length)), junction=junction)
        link = etree.SubElement(road, "link")
        for kind, element, eid, contact in links:
            attrs = {"elementType": element, "elementId": eid, **({"contactPoint": contact} if contact else {})}
            etree.SubElement(link, kind, **attrs)
        etree.SubElement(etree.SubElement(road, "type", s="0", type="town"), "speed", max="30", unit="km/h")
        geometry = etree.SubElement(etree.SubElement(road, "planView"), "geometry", s="0", x=repr(float(start[0])),
                                    y=repr(float(start[1])), hdg=repr(float(hdg)), length=repr(float(length)))
        etree.SubElement(geometry, shape[0], **{key: str(value) for key, value in shape[1].items()})
        road.append(etree.fromstring(lanes))

    lane = ('<lane id="%d" type="driving" level="false">%s<width sOffset="0" a="%r" b="0" c="0" d="0"/></lane>')
    centre = '<center><lane id="0" type="none" level="false"/></center>'

    def one_way(predecessor: int) -> str:  # lane -1 with its centre on the reference line
        link = f'<link><predecessor id="{predecessor}"/><successor id="-1"/></link>'
        return (f'<lanes><laneOffset s="0" a="{w / 2!r}" b="0" c="0" d="0"/><laneSection s="0">{centre}'
                f'<right>{lane % (-1, link, w)}</right></laneSection></lanes>')

    two_way = (f'<lanes><laneSection s="0"><left>{lane % (1, "", w)}</left>{centre}<right>{lane % (-1, "", w)}</right>'
               '</laneSection></lanes>')

    def hermite(start, h0, end, h1):
        """A normalized paramPoly3 from a pose to a pose (cubic Hermite, end tangents the chord's length), and its
        length [m] (sampled)."""
        c, s = math.cos(h0), math.sin(h0)
        d = np.asarray(end, float) - np.asarray(start, float)
        p1 = np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
        chord = float(np.hypot(*p1))
        t0, t1 = np.array([chord, 0.0]), chord * np.array([math.cos(h1 - h0), math.sin(h1 - h0)])
        cc, dd = 3 * p1 - 2 * t0 - t1, -2 * p1 + t0 + t1
        p = np.linspace(0.0, 1.0, 1000)[:, None]
        points = t0 * p + cc * p**2 + dd * p**3
        shape = ("paramPoly3", {"aU": 0.0, "bU": t0[0], "cU": cc[0], "dU": dd[0], "aV": 0.0, "bV": t0[1],
                                "cV": cc[1], "dV": dd[1], "pRange": "normalized"})
        return float(np.hypot(*np.diff(points, axis=0).T).sum()), shape

    for k in range(arms):
        this, previous, following = ids(k), ids(k - 1), ids(k + 1)
        a0 = angle[k] + half_gap
        a1 = angle[k] + 2 * math.pi / arms - half_gap
        start, hdg = ring_pose(a0)
        add_road(this["ring"], radius * (a1 - a0), start, hdg, ("arc", {"curvature": 1 / radius}), one_way(-1),
                 links=(("predecessor", "junction", this["junction"], None),
                        ("successor", "junction", following["junction"], None)))
        mouth_point = (radius + mouth) * _unit(angle[k])
        left = _unit(angle[k] + math.pi / 2)
        add_road(this["arm"], arm_length, mouth_point, angle[k], ("line", {}), two_way,
                 links=(("predecessor", "junction", this["junction"], None),))
        (p0, h0), (p1, h1) = ring_pose(angle[k] - half_gap), ring_pose(angle[k] + half_gap)
        add_road(this["through"], 2 * half_gap * radius, p0, h0, ("arc", {"curvature": 1 / radius}), one_way(-1),
                 this["junction"], (("predecessor", "road", previous["ring"], "end"),
                                    ("successor", "road", this["ring"], "start")))
        entry_start = mouth_point + (w / 2) * left
        length, shape = hermite(entry_start, angle[k] + math.pi, p1, h1)
        add_road(this["entry"], length, entry_start, angle[k] + math.pi, shape, one_way(1), this["junction"],
                 (("predecessor", "road", this["arm"], "start"), ("successor", "road", this["ring"], "start")))
        exit_end = mouth_point - (w / 2) * left
        length, shape = hermite(p0, h0, exit_end, angle[k])
        add_road(this["exit"], length, p0, h0, shape, one_way(-1), this["junction"],
                 (("predecessor", "road", previous["ring"], "end"), ("successor", "road", this["arm"], "start")))
    for k in range(arms):
        this, previous = ids(k), ids(k - 1)
        junction = etree.SubElement(root, "junction", id=this["junction"], name=f"entry{k}")
        for n, (incoming, connecting, from_lane) in enumerate(((previous["ring"], this["through"], -1),
                                                              (previous["ring"], this["exit"], -1),
                                                              (this["arm"], this["entry"], 1))):
            connection = etree.SubElement(junction, "connection", id=str(n), incomingRoad=incoming,
                                          connectingRoad=connecting, contactPoint="start")
            etree.SubElement(connection, "laneLink", **{"from": str(from_lane), "to": "-1"})
        etree.SubElement(junction, "priority", high=previous["ring"], low=this["arm"])  # the ring has the way
    etree.ElementTree(root).write(str(path), pretty_print=True, xml_declaration=True, encoding="utf-8")


def _unit(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle)])


def _write(path: Path, name: str, roads: list, junctions: list) -> None:
    from scenariogeneration import xodr

    odr = xodr.OpenDrive(name)
    for road in roads:
        odr.add_road(road)
    for junction in junctions:
        odr.add_junction_creator(junction)
    odr.adjust_roads_and_lanes()
    odr.write_xml(str(path))


MAPS = {"four_way": four_way, "four_way_lights": lambda path: four_way(path, lights=True), "multilane": multilane,
        "roundabout": roundabout}


def draw(out: Path) -> None:
    """The shipped maps' lanes (arrows in the direction of travel), junction areas and the files' signals, side by
    side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mjdrive.roads.opendrive import longest_route, read_opendrive

    fig, axes = plt.subplots(1, len(MAPS), figsize=(6 * len(MAPS), 6))
    for ax, name in zip(axes, MAPS, strict=True):
        rm = read_opendrive(MAPS_DIR / f"{name}.xodr")
        for area in rm.areas:
            ax.fill(*np.vstack([area, area[:1]]).T, color="0.85", zorder=0)
        route = set(longest_route(rm))
        for i, lane in enumerate(rm.lanes):
            colour = "tab:red" if i in route else ("tab:orange" if lane.in_junction else "tab:blue")
            ax.plot(*lane.centre.T, color=colour, lw=1.2)
            mid = len(lane.centre) // 2
            (x0, y0), (x1, y1) = lane.centre[mid - 1], lane.centre[mid]
            ax.annotate("", (x1, y1), (x0, y0), arrowprops={"arrowstyle": "->", "color": colour})
        for lane, sign in rm.entry_signs.items():  # the file's lights (circles) and stop signs (octagons)
            ax.plot(*rm.lanes[lane].centre[-1], "o" if sign == "lights" else "8", color="black", ms=7)
        ax.set_title(f"{name}.xodr: {len(rm.lanes)} lanes (red: the default route)")
        ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out, dpi=90)


def main(argv: list[str] | None = None) -> int:
    """Writes the maps named in argv (all when none) and the drawing of them all."""
    names = argv or list(MAPS)
    unknown = sorted(set(names) - set(MAPS))
    if unknown:
        print(f"opendrive_maps: error: unknown map {', '.join(unknown)}; maps: {', '.join(MAPS)}", file=sys.stderr)
        return 2
    MAPS_DIR.mkdir(parents=True, exist_ok=True)
    for name in names:
        MAPS[name](MAPS_DIR / f"{name}.xodr")
        print(f"wrote {MAPS_DIR / name}.xodr")
    out = Path(__file__).resolve().parents[1] / "docs" / "opendrive_maps.png"
    draw(out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
