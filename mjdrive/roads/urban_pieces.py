"""Urban road pieces with ports (study 002): roundabout, overtaking road, crossroad, merge.

Each builder returns a `Piece` in its own frame; `ports.compose` chains them. Lane priorities (`Lane.priority`)
give the right of way where lanes cross or merge (`conflicts.conflict_zones`): the main road over the
minor road, circulating lanes over entries, the main road over the merging lane; a left turn yields to
the other movements of its road, a lane that ends yields to the lane it joins.

Lane names (k counts from the centre line outward):
  roundabout_piece: those of `roads.roundabout`; ports "arm{a}_in" (entering by arm a) and "arm{a}_out".
  overtaking_road: ego direction "in_k" -> "taper_in_k" -> "main_k" -> "taper_out_k" -> "out_k", opposite
      direction "opp_{section}_k" (sections in, taper_in, main, taper_out, out); ports "in", "out".
  crossroad: arms "approach" (the ego's), "straight", "left", "right" with lanes "{arm}_in_k" (towards the
      junction) and "{arm}_out_k"; connectors "{from}->{to}_k"; ports "in" and one per exit arm.
  merge_road: approach "approach_in_0" / "approach_out_0", "slip" (the bend), "accel" (acceleration lane),
      "taper" (joins the main road); main road "main_k_p" in sections p = 0..4 (4 after the taper),
      opposite "opp_k_p"; "main_to_approach" (a right turn from the main road into the approach, where an
      arc of MIN_TURN_RADIUS fits); ports "in", "main_in", "out".
"""

from __future__ import annotations

import math

import numpy as np

from mjdrive.roads.geometry import Path, convex_hull, left_normal, s_curve, unit, wrap_angle
from mjdrive.roads.junctions import roundabout
from mjdrive.roads.lane import Lane, Marking
from mjdrive.roads.pieces import STRAIGHT_TOLERANCE, Arm, add_connectors, add_road, connector
from mjdrive.roads.ports import Piece, Port, ScenarioSpan
from mjdrive.roads.roadmap import MAIN_ROAD, MINOR_ROAD, RoadMap
from mjdrive.roads.urban_params import CrossroadParams, MergeParams, OvertakingRoadParams, RoundaboutParams, check

PRIORITY_MAJOR = 2  # main road, circulating lanes
PRIORITY_MINOR = 0  # minor road, roundabout entries, merging lanes
YIELD_STEP = 1  # a left turn or an ending lane ranks this much below its road
SCENARIO_LEAD = 20.0  # [m] a scenario starts this far before its give-way line / bend
MIN_TURN_RADIUS = 6.0  # [m] the merge's right turn from the main road into the approach exists from this radius
MIN_SECTION = 5.0  # [m] shortest main-road section before that turn


def connector_priority(lane: Lane, incoming: int) -> int:
    """The rank of a junction's connecting lane from its incoming road's rank: a left turn one step lower (it yields to
    the traffic it crosses)."""
    turn = float(wrap_angle(lane.vertex_heading[-1] - lane.vertex_heading[0]))
    return incoming - (YIELD_STEP if turn > STRAIGHT_TOLERANCE else 0)


def _set_priority(rm: RoadMap, ids, priority: int) -> None:
    for i in ids:
        rm.lanes[i].priority = priority


def _add(rm: RoadMap, pts: np.ndarray, name: str, width: float, left: Marking, right: Marking,
         speed_limit: float, priority: int, in_junction: bool = False) -> int:
    return rm.add_lane(Lane(pts, width, left, right, speed_limit, name, in_junction, priority))


def _port(name: str, point: np.ndarray, heading: float, lanes: list[int], reverse: list[int],
          width: float) -> Port:
    return Port(name, float(point[0]), float(point[1]), float(heading), tuple(lanes), tuple(reverse), width)


# --- roundabout -------------------------------------------------------------------------------------------


def roundabout_piece(params: RoundaboutParams | None = None, **kwargs) -> Piece:
    """`roads.roundabout` (unchanged geometry) with a port per arm end, priorities (ring lanes over entries)
    and a give-way line at the end of every inbound arm lane. Keyword arguments are `RoundaboutParams`."""
    p = params or RoundaboutParams(**kwargs)
    check("exit_arm", p.exit_arm, p.exit_arm != p.entry_arm, f"an arm other than entry_arm={p.entry_arm}")
    rm = roundabout(radius=p.radius, lanes=p.lanes, arms=p.arms, arm_length=p.arm_length,
                    lane_width=p.lane_width, speed_limit=p.speed_limit, crosswalk_offset=p.crosswalk_offset)
    ring = [i for i, lane in enumerate(rm.lanes) if lane.name.startswith("ring_") or lane.name.endswith("_exit")]
    _set_priority(rm, range(len(rm.lanes)), PRIORITY_MINOR)
    _set_priority(rm, ring, PRIORITY_MAJOR)
    ports = {}
    w = p.lane_width
    for a in range(p.arms):
        angle = 2 * math.pi * a / p.arms
        out, inn = rm.lane_id(f"arm{a}_out_0"), rm.lane_id(f"arm{a}_in_0")
        end = rm.lanes[out].centre[-1] + 0.5 * w * left_normal(angle)  # the arm's centre line end
        ports[f"arm{a}_in"] = _port(f"arm{a}_in", end, float(wrap_angle(angle + math.pi)), [inn], [out], w)
        ports[f"arm{a}_out"] = _port(f"arm{a}_out", end, float(wrap_angle(angle)), [out], [inn], w)
        rm.give_way.append((inn, rm.lanes[inn].length))
    entry = rm.lane_id(f"arm{p.entry_arm}_in_0")
    span = ScenarioSpan("roundabout", ((entry, max(rm.lanes[entry].length - SCENARIO_LEAD, 0.0)),),
                        tuple((rm.lane_id(f"arm{a}_out_0"), 0.0) for a in range(p.arms)))
    return Piece("roundabout", rm.freeze(), ports, f"arm{p.entry_arm}_in", f"arm{p.exit_arm}_out", (), (span,))


# --- overtaking road --------------------------------------------------------------------------------------


def overtaking_road(params: OvertakingRoadParams | None = None, **kwargs) -> Piece:
    """Straight two-way road from the origin heading east (see `OvertakingRoadParams`): the middle section
    has `lanes` lanes in the ego's direction, BROKEN lines between them and set as left/right neighbours;
    entry and exit lanes keep to the right and run straight through, the extra lanes open and close on
    the left (a closing lane merges into the lane right of it and yields). The route keeps right."""
    p = params or OvertakingRoadParams(**kwargs)
    w, n, m_in, m_out = p.lane_width, p.lanes, p.entry_lanes, p.exit_lanes
    x = np.cumsum([0.0, p.stub_length, p.taper_length, p.length, p.taper_length, p.stub_length])
    a = (n - m_in) * w  # [m] centre line in the middle section
    y_out = a - (n - m_out) * w  # [m] centre line at the exit
    reference = [Path((x[0], 0.0), 0.0).line(p.stub_length), s_curve((x[1], 0.0), 0.0, p.taper_length, a),
                 Path((x[2], a), 0.0).line(p.length), s_curve((x[3], a), 0.0, p.taper_length, y_out - a),
                 Path((x[4], y_out), 0.0).line(p.stub_length)]
    rm = RoadMap("overtaking_road")
    opp_centre = p.centre_marking
    fwd_centre = p.centre_marking if p.opposite_lanes else Marking.SOLID

    def row(section: str, path: Path, ks: range, first: int, centre_marking: Marking, shift: float) -> list[int]:
        ids = []
        for k in ks:
            left = centre_marking if k == first else Marking.BROKEN
            right = Marking.SOLID if k == n - 1 else Marking.BROKEN
            pts = path.sample(-(k + 0.5) * w + shift)
            ids.append(_add(rm, pts, f"{section}_{k}", w, left, right, p.speed_limit, PRIORITY_MAJOR))
        for i, j in zip(ids[:-1], ids[1:], strict=True):
            rm.set_neighbours(i, j)
        return ids

    # Ego direction: lanes indexed by their middle-section k; entry / exit lanes are the rightmost ones.
    inn = row("in", reference[0], range(n - m_in, n), n - m_in, fwd_centre, (n - m_in) * w)
    main = row("main", reference[2], range(n), 0, fwd_centre, 0.0)
    out = row("out", reference[4], range(n - m_out, n), n - m_out, fwd_centre, (n - m_out) * w)
    taper_in = row("taper_in", Path((x[1], a), 0.0).line(p.taper_length), range(n - m_in, n), n - m_in,
                   fwd_centre if m_in == n else Marking.NONE, 0.0)
    taper_out = row("taper_out", Path((x[3], a), 0.0).line(p.taper_length), range(n - m_out, n), n - m_out,
                    fwd_centre if m_out == n else Marking.NONE, 0.0)
    edge = Marking.NONE if p.opposite_lanes else Marking.SOLID
    opening = [_add(rm, s_curve((x[1], -0.5 * w), 0.0, p.taper_length, a - k * w).sample(), f"taper_in_{k}", w,
                    edge if k == 0 else Marking.NONE, Marking.NONE, p.speed_limit, PRIORITY_MAJOR)
               for k in range(n - m_in)]
    closing = [_add(rm, s_curve((x[3], a - (k + 0.5) * w), 0.0, p.taper_length,
                                (y_out - 0.5 * w) - (a - (k + 0.5) * w)).sample(), f"taper_out_{k}", w,
                    edge if k == 0 else Marking.NONE, Marking.NONE, p.speed_limit,
                    PRIORITY_MAJOR - YIELD_STEP * (n - m_out - k))  # the leftmost yields to all
               for k in range(n - m_out)]
    taper_in, taper_out = opening + taper_in, closing + taper_out  # ordered by k
    for j, i in enumerate(inn):
        rm.connect(i, taper_in[j + n - m_in])
    for k in range(n - m_in):
        rm.connect(inn[0], taper_in[k])
    for k in range(n):
        rm.connect(taper_in[k], main[k])
        rm.connect(main[k], taper_out[k])
        rm.connect(taper_out[k], out[max(k - (n - m_out), 0)])
    # Opposite direction, section by section against the reference line.
    opp = []
    for name, path in zip(("in", "taper_in", "main", "taper_out", "out"), reference, strict=True):
        ids = []
        for k in range(p.opposite_lanes):
            left = opp_centre if k == 0 else Marking.BROKEN
            right = Marking.SOLID if k == p.opposite_lanes - 1 else Marking.BROKEN
            ids.append(_add(rm, path.sample((k + 0.5) * w)[::-1], f"opp_{name}_{k}", w, left, right,
                            p.speed_limit, PRIORITY_MAJOR))
        for i, j in zip(ids[:-1], ids[1:], strict=True):
            rm.set_neighbours(i, j)
        opp.append(ids)
    for later, earlier in zip(opp[1:], opp[:-1], strict=True):
        for i, j in zip(later, earlier, strict=True):
            rm.connect(i, j)
    ports = {"in": _port("in", np.array([x[0], 0.0]), 0.0, inn, opp[0], w),
             "out": _port("out", np.array([x[5], y_out]), 0.0, out, opp[-1], w)}
    # The scenario runs to the end of the closing taper: a car still in a closing lane changes back there.
    span = ScenarioSpan("lane_change", tuple((i, 0.0) for i in main), tuple((i, 0.0) for i in out))
    return Piece("overtaking_road", rm.freeze(), ports, "in", "out", (main[-1],), (span,))


# --- crossroad --------------------------------------------------------------------------------------------


def crossroad(params: CrossroadParams | None = None, **kwargs) -> Piece:
    """Four-way crossroad without signals (see `CrossroadParams`): the ego's approach runs east from the
    origin; it and the "straight" arm are the minor road (give-way lines at the end of their inbound
    lanes), the "left" / "right" arms the main road. Left, straight and right connectors from every arm;
    a left turn yields to the other movements of its road. The chain leaves by the `turn` arm."""
    p = params or CrossroadParams(**kwargs)
    w, alpha = p.lane_width, p.crossing_angle
    hw_minor, hw_main = p.minor_lanes * w, p.main_lanes * w
    sin, cos = math.sin(alpha), abs(math.cos(alpha))
    r_minor = (hw_main + hw_minor * cos) / sin + p.corner_radius  # [m] centre to a minor arm's mouth
    r_main = (hw_minor + hw_main * cos) / sin + p.corner_radius  # [m] centre to a main arm's mouth
    centre = np.array([p.approach_length + r_minor, 0.0])
    spec = {"approach": (math.pi, r_minor, p.approach_length, p.minor_lanes, p.speed_limit),
            "straight": (0.0, r_minor, p.arm_length, p.minor_lanes, p.speed_limit),
            "left": (alpha, r_main, p.arm_length, p.main_lanes, p.main_speed_limit),
            "right": (alpha - math.pi, r_main, p.arm_length, p.main_lanes, p.main_speed_limit)}
    rm = RoadMap("crossroad")
    arms, ports, mouths = [], {}, []
    for name, (angle, reach, length, lanes, limit) in spec.items():
        path = Path(centre + reach * unit(angle), angle).line(length)
        out, inn = add_road(rm, path, lanes, lanes, f"{name}_out_{{k}}", f"{name}_in_{{k}}", w, limit)
        major = name in ("left", "right")
        _set_priority(rm, out + inn, PRIORITY_MAJOR if major else PRIORITY_MINOR)
        if not major:
            rm.give_way.extend((i, rm.lanes[i].length) for i in inn)
        rm.junction_entries.extend((i, MAIN_ROAD if major else MINOR_ROAD) for i in inn)
        arms.append(Arm(name, angle, inn, out))
        end, _ = path.end()
        if name == "approach":
            ports["in"] = _port("in", end, 0.0, inn, out, w)
        else:
            ports[name] = _port(name, end, angle, out, inn, w)
        for side in (-1.0, 1.0):
            mouths.append(centre + reach * unit(angle) + side * lanes * w * left_normal(angle))
    for i in add_connectors(rm, arms):
        rm.lanes[i].priority = connector_priority(rm.lanes[i], rm.lanes[rm.predecessors(i)[0]].priority)
    rm.add_area(convex_hull(np.array(mouths)))
    k = 0 if p.turn == "left" else p.minor_lanes - 1
    via = (rm.lane_id(f"approach->{p.turn}_{k}"),)
    approach = [rm.lane_id(f"approach_in_{j}") for j in range(p.minor_lanes)]
    span = ScenarioSpan("crossroad", tuple((i, max(rm.lanes[i].length - SCENARIO_LEAD, 0.0)) for i in approach),
                        tuple((i, 0.0) for arm in arms[1:] for i in arm.outbound))
    return Piece("crossroad", rm.freeze(), ports, "in", p.turn, via, (span,))


# --- merge ------------------------------------------------------------------------------------------------


def merge_road(params: MergeParams | None = None, **kwargs) -> Piece:
    """The ego's lane joins a main road from the right (see `MergeParams`). Main road along +x from the
    origin, its ego-direction lanes on the right of y = 0; the acceleration lane starts at x = main_before
    and its taper ends on the main road's rightmost lane, which it yields to."""
    p = params or MergeParams(**kwargs)
    w, n, theta = p.lane_width, p.main_lanes, p.merge_angle
    x_m = p.main_before
    y_acc, y_right = -(n + 0.5) * w, -(n - 0.5) * w  # [m] acceleration lane, rightmost main lane
    slip_end = np.array([x_m, y_acc])
    slip_start, _ = Path(slip_end, math.pi).arc(p.slip_radius, theta).end()
    main_turn = left_normal(theta)
    b = slip_start + w * main_turn  # start of the approach's outbound lane
    reach = (y_right - b[1]) / math.sin(theta)  # [m] from b back along the approach to the rightmost lane
    x_a = b[0] + reach * math.cos(theta) - reach  # [m] where main traffic turns into the approach
    turn_radius = reach / math.tan((math.pi - theta) / 2)  # [m] of that right turn
    with_turn = turn_radius >= MIN_TURN_RADIUS and x_a >= MIN_SECTION
    if not with_turn:  # the approach's outbound lane starts there (a source of traffic)
        x_a = x_m / 2
    cuts = np.cumsum([0.0, x_a, x_m - x_a, p.accel_length, p.taper_length, p.exit_length])
    rm = RoadMap("merge_road")
    main, opp = [], []
    for sec in range(5):
        path = Path((cuts[sec], 0.0), 0.0).line(cuts[sec + 1] - cuts[sec])
        ids = []
        for k in range(n):
            left = Marking.SOLID if k == 0 else Marking.BROKEN
            right = Marking.BROKEN if k < n - 1 else (Marking.SOLID, Marking.SOLID, Marking.BROKEN,
                                                       Marking.NONE, Marking.SOLID)[sec]
            ids.append(_add(rm, path.sample(-(k + 0.5) * w), f"main_{k}_{sec}", w, left, right,
                            p.main_speed_limit, PRIORITY_MAJOR))
        back = []
        for k in range(p.main_opposite_lanes):
            right = Marking.SOLID if k == p.main_opposite_lanes - 1 else Marking.BROKEN
            back.append(_add(rm, path.sample((k + 0.5) * w)[::-1], f"opp_{k}_{sec}", w,
                             Marking.SOLID if k == 0 else Marking.BROKEN, right, p.main_speed_limit,
                             PRIORITY_MAJOR))
        for row in (ids, back):
            for i, j in zip(row[:-1], row[1:], strict=True):
                rm.set_neighbours(i, j)
        main.append(ids)
        opp.append(back)
    for sec in range(4):
        for i, j in zip(main[sec], main[sec + 1], strict=True):
            rm.connect(i, j)
        for i, j in zip(opp[sec + 1], opp[sec], strict=True):
            rm.connect(i, j)
    # The approach: a two-way road ending where the slip bend starts.
    approach = Path(slip_start - p.approach_length * unit(theta) + 0.5 * w * main_turn, theta)
    approach.line(p.approach_length)
    app_out, app_in = add_road(rm, Path(approach.end()[0], theta + math.pi).line(p.approach_length), 1, 1,
                               "approach_out_{k}", "approach_in_{k}", w, p.speed_limit)
    _set_priority(rm, app_out + app_in, PRIORITY_MINOR)
    slip = _add(rm, Path(slip_start, theta).arc(p.slip_radius, -theta).sample(), "slip", w, Marking.SOLID,
                Marking.SOLID, p.speed_limit, PRIORITY_MINOR)
    accel = _add(rm, Path(slip_end, 0.0).line(p.accel_length).sample(), "accel", w, Marking.BROKEN,
                 Marking.SOLID, p.main_speed_limit, PRIORITY_MINOR)
    taper = _add(rm, s_curve((cuts[3], y_acc), 0.0, p.taper_length, w).sample(), "taper", w, Marking.NONE,
                 Marking.SOLID, p.main_speed_limit, PRIORITY_MINOR)
    rm.connect(app_in[0], slip)
    rm.connect(slip, accel)
    rm.connect(accel, taper)
    rm.connect(taper, main[4][-1])
    rm.set_neighbours(main[2][-1], accel)
    if with_turn:
        turn = connector(rm, main[0][-1], app_out[0], "main_to_approach")
        rm.lanes[turn].priority = PRIORITY_MAJOR
    ports = {"in": _port("in", approach.start, theta, app_in, app_out, w),
             "main_in": _port("main_in", np.zeros(2), 0.0, main[0], opp[0], w),
             "out": _port("out", np.array([cuts[5], 0.0]), 0.0, main[4], opp[4], w)}
    span = ScenarioSpan("merge", ((app_in[0], max(p.approach_length - SCENARIO_LEAD, 0.0)),),
                        tuple((i, 0.0) for i in main[4]))
    return Piece("merge_road", rm.freeze(), ports, "in", "out", (taper,), (span,))
