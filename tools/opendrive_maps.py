"""The small OpenDRIVE maps shipped in mjdrive/maps/ (the `urban/opendrive` task's named maps and the tests'),
written with scenariogeneration (the dev extra), and their drawing in docs/.

    python -m tools.opendrive_maps                 # writes mjdrive/maps/*.xodr and docs/opendrive_maps.png

- four_way: a four-arm junction, one lane each way per arm (line arms), connecting roads for every movement;
- multilane: a two-lanes-each-way road whose reference line runs through a line, a spiral, an arc, a spiral and a
  paramPoly3, linked (a road link, no junction) to a straight road.

The maps are the project's own (generated here, same licence as the code).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

MAPS_DIR = Path(__file__).resolve().parents[1] / "mjdrive" / "maps"
LANE_WIDTH = 3.5  # [m]


def four_way(path: Path) -> None:
    from scenariogeneration import xodr

    roads = [xodr.create_road(xodr.Line(80.0), i, left_lanes=1, right_lanes=1, lane_width=LANE_WIDTH)
             for i in range(4)]
    junction = xodr.CommonJunctionCreator(id=100, name="four_way")
    for i, road in enumerate(roads):
        junction.add_incoming_road_circular_geometry(road=road, radius=16.0, angle=i * math.pi / 2,
                                                     road_connection="successor")
    for i in range(4):
        for j in range(i + 1, 4):
            junction.add_connection(i, j)
    _write(path, "four_way", roads, [junction])


def multilane(path: Path) -> None:
    from scenariogeneration import xodr

    geometry = [xodr.Line(60.0), xodr.Spiral(0.0, 0.01, 40.0), xodr.Arc(0.01, 50.0), xodr.Spiral(0.01, 0.0, 40.0),
                xodr.ParamPoly3(0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.002, -0.00004, "arcLength", 30.0)]
    main = xodr.create_road(geometry, 0, left_lanes=2, right_lanes=2, lane_width=LANE_WIDTH)
    narrow = xodr.create_road(xodr.Line(80.0), 1, left_lanes=2, right_lanes=2, lane_width=LANE_WIDTH)
    main.add_successor(xodr.ElementType.road, 1, xodr.ContactPoint.start)
    narrow.add_predecessor(xodr.ElementType.road, 0, xodr.ContactPoint.end)
    _write(path, "multilane", [main, narrow], [])


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


MAPS = {"four_way": four_way, "multilane": multilane}


def draw(out: Path) -> None:
    """The shipped maps' lanes (arrows in the direction of travel) and junction areas, side by side."""
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
        ax.set_title(f"{name}.xodr: {len(rm.lanes)} lanes (red: the default route)")
        ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out, dpi=90)


def main(argv: list[str] | None = None) -> int:
    MAPS_DIR.mkdir(parents=True, exist_ok=True)
    for name, build in MAPS.items():
        build(MAPS_DIR / f"{name}.xodr")
        print(f"wrote {MAPS_DIR / name}.xodr")
    out = Path(__file__).resolve().parents[1] / "docs" / "opendrive_maps.png"
    draw(out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
