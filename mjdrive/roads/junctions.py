"""Junction builders: a four-way crossroad, a town grid of junctions, a roundabout.

Lane names (k counts from the road's centre line outward, 0 = next to it):
  junction:   arms "N", "E", "S", "W"; "S_in_k" arrives from the south (drives north), "S_out_k" leaves
              southwards; connectors "S->W_k" from inbound lane k of arm S to arm W (here a left turn).
  town:       node (i, j) of the grid is at (i, j) * block_size and called "J{i}_{j}"; road lanes
              "J0_0>J1_0_k" drive from J0_0 to J1_0; connectors "J1_0:W->N_k" inside J1_0 (arm letters
              as in `junction`, the arm towards the neighbour in that compass direction).
  roundabout: arms a = 0..arms-1 at angles 2*pi*a/arms (arm 0 east); "arm{a}_in_0" / "arm{a}_out_0";
              ring lanes "ring_{k}_{i}" (k = 0 inner, lanes-1 outer) run counter-clockwise; segment
              i = 2a passes arm a (from its exit to its entry), i = 2a+1 runs from arm a's entry to arm
              a+1's exit; "arm{a}_entry" joins the outer ring lane, "arm{a}_exit" leaves it.
"""

from __future__ import annotations

import math
import re

import numpy as np

from mjdrive.roads.geometry import Path, unit
from mjdrive.roads.lane import Lane, Marking
from mjdrive.roads.pieces import Arm, add_connectors, add_road, connector, junction_box
from mjdrive.roads.roadmap import Crosswalk, RoadMap

COMPASS = {"E": 0.0, "N": math.pi / 2, "W": math.pi, "S": -math.pi / 2}


def _add_crossroad(rm: RoadMap, centre: tuple[float, float], arms: list[Arm], half_size: float,
                   road_half_width: float, prefix: str = "") -> None:
    add_connectors(rm, arms, prefix)
    rm.add_area(junction_box(centre, half_size, road_half_width, [a.angle for a in arms]))


def junction(
    arm_length: float = 60.0,
    lanes_per_direction: int = 1,
    lane_width: float = 3.5,
    speed_limit: float = 30 / 3.6,
    corner_radius: float = 12.0,
) -> RoadMap:
    """Four-way crossroad centred at the origin, arms N/E/S/W of `arm_length` [m] beyond the junction box
    (half size lanes_per_direction * lane_width + corner_radius [m]); left/straight/right connectors."""
    n, w = lanes_per_direction, lane_width
    half = n * w + corner_radius
    rm = RoadMap("junction")
    arms = []
    for name, angle in COMPASS.items():
        path = Path(half * unit(angle), angle).line(arm_length)
        out, inn = add_road(rm, path, n, n, f"{name}_out_{{k}}", f"{name}_in_{{k}}", w, speed_limit)
        arms.append(Arm(name, angle, inn, out))
    _add_crossroad(rm, (0.0, 0.0), arms, half, n * w)
    return rm.freeze()


def town(
    blocks: tuple[int, int] = (3, 3),
    block_size: float = 80.0,
    lanes_per_direction: int = 1,
    lane_width: float = 3.5,
    speed_limit: float = 30 / 3.6,
    corner_radius: float = 12.0,
) -> RoadMap:
    """A grid of blocks[0] x blocks[1] blocks of `block_size` [m]; a junction at every node (T junctions on
    the border, corner junctions at the corners), two-way roads between. Without U-turns a single block
    is two one-way loops; with >= 2 blocks along one axis every lane reaches every other."""
    bx, by = blocks
    n, w, size = lanes_per_direction, lane_width, block_size
    half = n * w + corner_radius
    if size - 2 * half < 10.0:
        raise ValueError(f"block_size {size} m leaves less than 10 m of road between junctions")
    rm = RoadMap(f"town_{bx}x{by}")
    arms: dict[tuple[int, int], list[Arm]] = {(i, j): [] for i in range(bx + 1) for j in range(by + 1)}
    for i in range(bx + 1):
        for j in range(by + 1):
            for di, dj, here, there in ((1, 0, "E", "W"), (0, 1, "N", "S")):
                if i + di > bx or j + dj > by:
                    continue
                angle = COMPASS[here]
                a, b = f"J{i}_{j}", f"J{i + di}_{j + dj}"
                path = Path(np.array([i, j]) * size + half * unit(angle), angle).line(size - 2 * half)
                fwd, bwd = add_road(rm, path, n, n, f"{a}>{b}_{{k}}", f"{b}>{a}_{{k}}", w, speed_limit)
                arms[(i, j)].append(Arm(here, angle, bwd, fwd))
                arms[(i + di, j + dj)].append(Arm(there, COMPASS[there], fwd, bwd))
    for (i, j), node_arms in arms.items():
        _add_crossroad(rm, (i * size, j * size), node_arms, half, n * w, prefix=f"J{i}_{j}:")
    return rm.freeze()


def roundabout(
    radius: float = 20.0,
    lanes: int = 2,
    arms: int = 4,
    arm_length: float = 60.0,
    lane_width: float = 3.5,
    speed_limit: float = 30 / 3.6,
    entry_angle: float | None = None,
    crosswalk_offset: float = 2.5,
) -> RoadMap:
    """Roundabout centred at the origin: a ring of `lanes` lanes whose middle has `radius` [m], driven
    counter-clockwise, and `arms` two-way arms (one lane each way) of `arm_length` [m].

    Entries join and exits leave the outer ring lane `entry_angle` [rad] after / before each arm's axis
    (tangentially, through single arcs); a crosswalk crosses each arm `crosswalk_offset` [m] past the
    arm's start (a few metres from the ring).
    """
    w = lane_width
    inner = radius - lanes * w / 2  # [m] radius of the central island
    if inner < 3.0 or arms < 1:
        raise ValueError("the ring needs an island of >= 3 m radius and at least one arm")
    ring_r = [inner + (k + 0.5) * w for k in range(lanes)]
    r_out, offset = ring_r[-1], w / 2
    delta = min(0.35, 0.3 * 2 * math.pi / arms) if entry_angle is None else entry_angle
    if r_out * math.sin(delta) <= offset + 0.5:
        raise ValueError(f"entry_angle {delta:.3f} rad too small for the ring")
    # Entry geometry in the arm frame (x out along the arm): the inbound lane y = offset meets the ring's
    # tangent at angle delta in X; the arm starts where the entry becomes a single arc.
    lb = (r_out * math.sin(delta) - offset) / math.cos(delta)
    start = max(r_out * math.cos(delta) + lb * math.sin(delta) + lb, radius + lanes * w / 2 + 2.0)

    rm = RoadMap(f"roundabout_{arms}arms")
    axes = [2 * math.pi * a / arms for a in range(arms)]
    cuts = [ang + sign * delta for ang in axes for sign in (-1.0, 1.0)]  # exit, entry of each arm
    nseg = len(cuts)
    ring = [[0] * nseg for _ in range(lanes)]
    for k, r in enumerate(ring_r):
        for i in range(nseg):
            a0, a1 = cuts[i], cuts[(i + 1) % nseg] + (2 * math.pi if i == nseg - 1 else 0.0)
            pts = Path(r * unit(a0), a0 + math.pi / 2).arc(r, a1 - a0).sample()
            left = Marking.SOLID if k == 0 else Marking.BROKEN
            right = (Marking.SOLID if i % 2 else Marking.NONE) if k == lanes - 1 else Marking.BROKEN
            ring[k][i] = rm.add_lane(Lane(pts, w, left, right, speed_limit, f"ring_{k}_{i}"))
    for k in range(lanes):
        for i in range(nseg):
            rm.connect(ring[k][i], ring[k][(i + 1) % nseg])
            if k:
                rm.set_neighbours(ring[k - 1][i], ring[k][i])
    outer = ring[-1]
    for a, ang in enumerate(axes):
        path = Path(start * unit(ang), ang).line(arm_length)
        out, inn = add_road(rm, path, 1, 1, f"arm{a}_out_{{k}}", f"arm{a}_in_{{k}}", w, speed_limit)
        connector(rm, inn[0], outer[2 * a + 1], f"arm{a}_entry")
        connector(rm, outer[(2 * a - 1) % nseg], out[0], f"arm{a}_exit")
        rm.crosswalks.append(Crosswalk((start + crosswalk_offset) * unit(ang), ang + math.pi / 2, 2 * w, 3.0))
    return rm.freeze()


def roundabout_routes(rm: RoadMap) -> dict[tuple[int, int], list[int]]:
    """Route (lane ids, no lane changes) from every arm's inbound lane to every arm's outbound lane of a
    `roundabout` map, keyed (entry arm, exit arm); (a, a) goes once around."""
    arms = sorted(int(m.group(1)) for lane in rm.lanes if (m := re.fullmatch(r"arm(\d+)_in_0", lane.name)))
    return {(a, b): rm.shortest_route(rm.lane_id(f"arm{a}_in_0"), rm.lane_id(f"arm{b}_out_0"),
                                      allow_lane_change=False)
            for a in arms for b in arms}
