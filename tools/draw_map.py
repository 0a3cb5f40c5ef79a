"""Top view of the study-002 concatenated map (Fig. 8): lanes, markings, give-way lines, the ego's route
(blue dots), the tactical trajectory's scenario starts and ends (red points) and the conflict zones on the
route (orange). Usage: python -m tools.draw_map [--out docs/urban_map.png] [--dpi 110]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from mjdrive.roads import Marking, UrbanRoute, urban_route

ROUTE_SPACING = 5.0  # [m] between route dots
SCENARIO_COLOURS = {"roundabout": "tab:purple", "lane_change": "tab:green", "crossroad": "tab:red",
                    "merge": "tab:orange"}


def draw(urban: UrbanRoute, ax) -> None:
    """Draw the map, route, tactical trajectory and route conflicts on a matplotlib axis."""
    from matplotlib.patches import Polygon

    rm = urban.road_map
    for lane in rm.lanes:
        ax.add_patch(Polygon(lane.polygon(), closed=True, fc="0.45", ec="none", zorder=1))
    for area in rm.areas:
        ax.add_patch(Polygon(area, closed=True, fc="0.48", ec="none", zorder=1))
    for line, kind in rm.marking_lines():
        style = "-" if kind == Marking.SOLID else (0, (3, 6))
        ax.plot(line[:, 0], line[:, 1], color="white", lw=0.5, ls=style, zorder=2)
    for lane_id, s in rm.give_way:
        lane = rm.lanes[lane_id]
        ends = lane.position(np.array([s, s]), np.array([-lane.width / 2, lane.width / 2]))
        ax.plot(ends[:, 0], ends[:, 1], color="white", lw=1.2, ls=(0, (1, 1)), zorder=2)
    route = urban.route_lane()
    dots = route.position(np.arange(0.0, route.length, ROUTE_SPACING))
    ax.plot(dots[:, 0], dots[:, 1], ".", color="tab:blue", ms=2, zorder=3, label="route")
    for name, s0, s1 in urban.tactical.intervals:
        seg = route.position(np.linspace(s0, s1, 50))
        ax.plot(seg[:, 0], seg[:, 1], color=SCENARIO_COLOURS[name], lw=2.5, alpha=0.6, zorder=3, label=name)
        ends = route.position(np.array([s0, s1]))
        ax.plot(ends[:, 0], ends[:, 1], "o", color="red", ms=3, zorder=4)
        ax.annotate(name, ends[0], xytext=(0, -14), textcoords="offset points", fontsize=7, ha="center",
                    color="darkred")
    rc = urban.route_conflicts
    for k in range(len(rc)):
        seg = route.position(np.linspace(rc.s_in[k], rc.s_out[k], 10))
        ax.plot(seg[:, 0], seg[:, 1], color="gold" if rc.ego_yields[k] else "tab:cyan", lw=1.2, zorder=4)
    ax.set_aspect("equal")
    ax.set_facecolor("#cfe3c4")
    ax.legend(loc="lower left", fontsize=6, markerscale=2)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def main() -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/urban_map.png")
    parser.add_argument("--dpi", type=int_at_least(1), default=110)
    args = parser.parse_args()
    urban = urban_route()
    x0, y0, x1, y1 = urban.road_map.bounds()
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(10, 10 * (y1 - y0 + 20) / (x1 - x0 + 20) + 0.6))
    draw(urban, ax)
    ax.set_xlim(x0 - 10, x1 + 10)
    ax.set_ylim(y0 - 10, y1 + 10)
    tt = ", ".join(f"{n} {a:.0f}-{b:.0f} m" for n, a, b in urban.tactical.intervals)
    ax.set_title(f"study 002 route: {urban.length:.0f} m; {tt}\n(gold: ego yields, cyan: ego has priority)",
                 fontsize=8)
    fig.tight_layout()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=args.dpi)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
