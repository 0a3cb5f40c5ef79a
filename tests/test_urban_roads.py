"""Study 002 roads: composable pieces with ports, the concatenated map of Fig. 8, the route, the tactical
trajectory, conflict zones and rendering."""

import json
import math

import mujoco
import numpy as np
import pytest

from mjdrive import roads, world
from mjdrive.roads import Marking, wrap_angle
from mjdrive.roads.conflicts import CROSSING, MERGE, TIE

URBAN = roads.urban_route()


def _names(rm, ids):
    return [rm.lanes[i].name for i in ids]


# --- ports and composition --------------------------------------------------------------------------------


def test_exit_port_of_each_piece_is_the_entry_port_of_the_next():
    pieces = URBAN.composed.pieces
    assert [p.name for p in pieces] == ["roundabout", "overtaking_road", "crossroad", "merge_road"]
    rm = URBAN.road_map
    for prev, nxt in zip(pieces[:-1], pieces[1:], strict=True):
        out, into = prev.exit_port, nxt.entry_port
        assert abs(out.x - into.x) < 1e-9 and abs(out.y - into.y) < 1e-9
        assert abs(wrap_angle(out.heading - into.heading)) < 1e-9
        for a, b in [*zip(out.lanes, into.lanes, strict=True), *zip(into.reverse, out.reverse, strict=True)]:
            assert b in rm.successors[a]
            np.testing.assert_allclose(rm.lanes[a].centre[-1], rm.lanes[b].centre[0], atol=1e-9)
            assert abs(wrap_angle(rm.lanes[a].vertex_heading[-1] - rm.lanes[b].vertex_heading[0])) < 1e-6


def test_port_lanes_lie_beside_the_reference_point():
    for piece in (roads.overtaking_road(lanes=3, opposite_lanes=2, entry_lanes=2), roads.crossroad(main_lanes=2),
                  roads.merge_road(), roads.roundabout_piece()):
        for port in piece.ports.values():
            right = np.array([math.sin(port.heading), -math.cos(port.heading)])
            ref = np.array([port.x, port.y])
            for k, lane in enumerate(port.lanes):  # lanes along the heading start or end at -(k + 1/2) w
                centre = piece.road_map.lanes[lane].centre
                end = min((centre[0], centre[-1]), key=lambda p: np.hypot(*(p - ref)))
                np.testing.assert_allclose(end, ref + (k + 0.5) * port.lane_width * right, atol=1e-9)
            for k, lane in enumerate(port.reverse):
                centre = piece.road_map.lanes[lane].centre
                end = min((centre[0], centre[-1]), key=lambda p: np.hypot(*(p - ref)))
                np.testing.assert_allclose(end, ref - (k + 0.5) * port.lane_width * right, atol=1e-9)


def test_compose_rejects_ports_that_do_not_match_and_pieces_that_overlap():
    with pytest.raises(ValueError, match="lane counts"):
        roads.compose([roads.overtaking_road(exit_lanes=2), roads.crossroad()])
    with pytest.raises(ValueError, match="lane widths"):
        roads.compose([roads.overtaking_road(), roads.crossroad(lane_width=3.0)])
    lefts = [roads.crossroad(turn="left") for _ in range(3)]
    roads.compose([roads.overtaking_road(), *lefts])  # turns back west, north of the road
    with pytest.raises(ValueError, match="overlaps"):  # and a fourth junction lands on the road
        roads.compose([roads.overtaking_road(), *lefts, roads.crossroad(turn="left")])


def test_roundabout_piece_keeps_the_roundabout_map():
    kwargs = dict(radius=14.0, lanes=2, arms=4, arm_length=50.0, lane_width=3.5, crosswalk_offset=6.0)
    piece = roads.roundabout_piece(**kwargs)
    plain = roads.roundabout(**kwargs)
    assert len(piece.road_map.lanes) == len(plain.lanes)
    for a, b in zip(piece.road_map.lanes, plain.lanes, strict=True):
        assert a.name == b.name and np.array_equal(a.centre, b.centre) and a.width == b.width
        assert (a.left_marking, a.right_marking, a.in_junction) == (b.left_marking, b.right_marking, b.in_junction)
    assert piece.road_map.successors == plain.successors
    assert piece.road_map.left_neighbour == plain.left_neighbour
    assert [c.centre.tolist() for c in piece.road_map.crosswalks] == [c.centre.tolist() for c in plain.crosswalks]
    assert plain.give_way == [] and {lane.priority for lane in plain.lanes} == {0}  # the study-000 map as before


# --- the route and its pieces -------------------------------------------------------------------------------


def test_route_runs_through_the_lane_graph_from_the_roundabout_to_after_the_merge():
    rm, route = URBAN.road_map, URBAN.route
    for a, b in zip(route[:-1], route[1:], strict=True):
        assert b in rm.successors[a]
    names = _names(rm, route)
    assert names[0] == "roundabout/arm2_in_0" and names[-1] == "merge_road/main_0_4"
    assert "overtaking_road/main_1" in names  # keeps right on the two-lane road
    assert "crossroad/approach->straight_0" in names and "merge_road/accel" in names
    steps = np.hypot(*np.diff(URBAN.polyline, axis=0).T)
    assert steps.max() <= 0.5 + 1e-6
    assert URBAN.length == pytest.approx(sum(rm.lanes[i].length for i in route), abs=1e-3)
    assert rm.shortest_route(route[0], route[-1], allow_lane_change=False) != []  # Dijkstra reaches the goal


def test_two_lane_road_lanes_are_neighbours_with_a_broken_line_and_a_solid_centre_line():
    piece = roads.overtaking_road()
    rm = piece.road_map
    left, right = rm.lane_id("main_0"), rm.lane_id("main_1")
    assert rm.right_neighbour[left] == right and rm.left_neighbour[right] == left
    assert rm.lanes[left].right_marking == Marking.BROKEN == rm.lanes[right].left_marking
    boundary = rm.lanes[left].right_edge()
    kinds = {kind for line, kind in rm.marking_lines()
             if len(line) == len(boundary) and np.allclose(line, boundary)}
    assert kinds == {Marking.BROKEN}
    # overtaking: changing to the left lane crosses no solid line, drifting into the opposite lane does
    opposite = rm.lanes[rm.lane_id("opp_main_0")]
    here = rm.lanes[left].position(100.0)
    assert not rm.crossed_solid(rm.lanes[right].position(100.0), here)
    assert rm.crossed_solid(here, opposite.position(opposite.length - 100.0))
    assert rm.shortest_route(right, rm.lane_id("taper_out_0")) == [right, left, rm.lane_id("taper_out_0")]
    # both lanes open from the single entry lane and close into the single exit lane
    entry, exit_ = rm.lane_id("in_1"), rm.lane_id("out_1")
    assert sorted(_names(rm, rm.successors[entry])) == ["taper_in_0", "taper_in_1"]
    assert sorted(_names(rm, rm.predecessors(exit_))) == ["taper_out_0", "taper_out_1"]
    # with three lanes closing into one, the leftmost yields to both others: no tie
    rm3 = roads.overtaking_road(lanes=3).road_map
    cz = roads.conflict_zones(rm3)
    assert sorted(_names(rm3, cz.yielding_lane)) == ["taper_out_0", "taper_out_0", "taper_out_1"]


def test_crossroad_minor_approach_has_left_straight_and_right_successors():
    for angle in (math.radians(60), math.pi / 2, math.radians(120)):
        piece = roads.crossroad(crossing_angle=angle)
        rm = piece.road_map
        approach = rm.lane_id("approach_in_0")
        turns = {}
        for c in rm.successors[approach]:
            lane = rm.lanes[c]
            turns[lane.name] = float(wrap_angle(lane.vertex_heading[-1] - lane.vertex_heading[0]))
            (nxt,) = rm.successors[c]
            assert rm.lanes[nxt].name == lane.name.split("->")[1][:-2] + "_out_0"
        assert set(turns) == {"approach->left_0", "approach->straight_0", "approach->right_0"}
        assert turns["approach->left_0"] == pytest.approx(angle, abs=1e-3)
        assert turns["approach->straight_0"] == pytest.approx(0.0, abs=1e-6)
        assert turns["approach->right_0"] == pytest.approx(angle - math.pi, abs=1e-3)
        assert (approach, pytest.approx(rm.lanes[approach].length)) in rm.give_way


def test_merge_acceleration_lane_leads_onto_the_main_road():
    piece = roads.merge_road(main_lanes=2)
    rm = piece.road_map
    accel, taper, main = rm.lane_id("accel"), rm.lane_id("taper"), rm.lane_id("main_1_4")
    assert rm.successors[rm.lane_id("slip")] == [accel] and rm.successors[accel] == [taper]
    assert rm.successors[taper] == [main]
    assert rm.left_neighbour[accel] == rm.lane_id("main_1_2")  # a lane change onto the main road is legal
    assert rm.lanes[accel].left_marking == Marking.BROKEN
    np.testing.assert_allclose(rm.lanes[taper].centre[-1], rm.lanes[main].centre[0], atol=1e-9)
    route = rm.shortest_route(piece.entry_port.lanes[0], piece.exit_port.lanes[-1], allow_lane_change=False)
    assert _names(rm, route) == ["approach_in_0", "slip", "accel", "taper", "main_1_4"]
    assert piece.via == (taper,)


@pytest.mark.parametrize("degrees", [20, 30, 45, 60, 90])
def test_merge_approach_stays_clear_of_the_main_road(degrees):
    angle = math.radians(degrees)
    least = next(r / 10 for r in range(80, 2000) if _valid(roads.MergeParams, merge_angle=angle, slip_radius=r / 10))
    for lanes in (1, 2):
        piece = roads.merge_road(merge_angle=angle, slip_radius=least, main_lanes=lanes)
        rm = piece.road_map
        main = roads.RoadMap("main")
        for lane in rm.lanes:
            if lane.name.split("_")[0] in ("main", "opp") and lane.name != "main_to_approach":
                main.add_lane(lane)
        approach = [rm.lanes[rm.lane_id(n)] for n in ("approach_in_0", "approach_out_0")]
        edges = np.vstack([e for lane in approach for e in (lane.left_edge(), lane.right_edge())])
        assert not main.on_road(edges).any()
        turns = [lane for lane in rm.lanes if lane.name == "main_to_approach"]
        if turns:  # where the right turn into the approach exists, it is drivable
            assert np.abs(turns[0].vertex_curvature).max() <= 1 / 6.0 + 1e-6
            assert rm.predecessors(rm.lane_id("approach_out_0")) == [rm.lane_id("main_to_approach")]
    if degrees >= 45:  # a wide bend and a long main road leave room for the turn into the approach
        turn = roads.merge_road(merge_angle=angle, slip_radius=40.0, main_before=300.0).road_map.lanes[-1]
        assert turn.name == "main_to_approach" and np.abs(turn.vertex_curvature).max() <= 1 / 6.0 + 1e-6


def _valid(cls, **kwargs):
    try:
        cls(**kwargs)
    except ValueError:
        return False
    return True


# --- tactical trajectory -------------------------------------------------------------------------------------


def test_tactical_trajectory_intervals_are_ordered_disjoint_and_inside_the_route():
    tt = URBAN.tactical
    assert tt.names == ("roundabout", "lane_change", "crossroad", "merge")
    bounds = np.array([(s0, s1) for _, s0, s1 in tt.intervals])
    assert bounds[0, 0] >= 0 and bounds[-1, 1] <= URBAN.length + 1e-9
    assert np.all(bounds[:, 0] < bounds[:, 1]) and np.all(bounds[1:, 0] >= bounds[:-1, 1])
    assert tt.scenario_at(0.0) == roads.FOLLOW
    for name, s0, s1 in tt.intervals:
        assert tt.scenario_at(s0) == name and tt.scenario_at((s0 + s1) / 2) == name
        assert tt.scenario_at(s1) != name
    assert tt.scenario_at(URBAN.length) == roads.FOLLOW
    # each interval covers its piece: the roundabout entry, the two-lane section, the give-way line, the taper
    rm, route = URBAN.road_map, list(URBAN.route)
    offsets = np.cumsum([0.0] + [rm.lanes[i].length for i in route[:-1]])
    at = {rm.lanes[i].name: offsets[k] for k, i in enumerate(route)}
    assert tt.interval("roundabout")[0] < at["roundabout/arm2_entry"] < tt.interval("roundabout")[1]
    assert tt.interval("lane_change") == pytest.approx((at["overtaking_road/main_1"], at["overtaking_road/out_1"]))
    assert tt.interval("crossroad")[0] < at["crossroad/approach->straight_0"] < tt.interval("crossroad")[1]
    assert tt.interval("merge")[0] < at["merge_road/taper"] < tt.interval("merge")[1]


def test_waypoints_carry_lane_data_and_scenario_and_the_route_serialises():
    wp = URBAN.waypoints(spacing=2.0)
    rm = URBAN.road_map
    assert wp.s[0] == 0.0 and wp.s[-1] > URBAN.length - 2.0 and np.allclose(np.diff(wp.s), 2.0)
    for k in range(0, len(wp.s), 7):
        lane = rm.lanes[wp.lane[k]]
        np.testing.assert_allclose(lane.position(wp.lane_s[k]), wp.xy[k], atol=1e-3)
        assert wp.speed_limit[k] == lane.speed_limit and wp.lane_width[k] == lane.width
        assert wp.scenario[k] == URBAN.tactical.scenario_at(wp.s[k])
    assert set(wp.scenario) == {roads.FOLLOW, "roundabout", "lane_change", "crossroad", "merge"}
    assert {rm.lanes[i].speed_limit for i in wp.lane} == {30 / 3.6, 50 / 3.6}
    data = json.loads(json.dumps(URBAN.to_dict()))
    assert data["route"][0] == "roundabout/arm2_in_0" and len(data["tactical"]) == 4
    assert any(z["other_lane"] == "merge_road/main_0_3" and z["ego_yields"] for z in data["conflicts"])


def test_tactical_trajectory_rejects_overlaps_and_unknown_scenarios():
    with pytest.raises(ValueError, match="interval"):
        roads.TacticalTrajectory((("roundabout", 0.0, 10.0), ("merge", 5.0, 20.0)))
    with pytest.raises(ValueError, match="scenario"):
        roads.TacticalTrajectory((("parking", 0.0, 10.0),))


# --- conflict zones ------------------------------------------------------------------------------------------


def _arm(name):
    return name.split("->")[0].split("_")[0]


def test_crossroad_conflicts_minor_road_yields_to_main_road():
    piece = roads.crossroad()
    rm = piece.road_map
    cz = roads.conflict_zones(rm)
    rows = list(range(len(cz)))
    assert rows
    assert all(rm.lanes[a].in_junction and rm.lanes[b].in_junction for a, b in zip(cz.lane_a, cz.lane_b, strict=True))
    minor_vs_main = 0
    for z in rows:
        a, b = rm.lanes[cz.lane_a[z]].name, rm.lanes[cz.lane_b[z]].name
        major = {"left", "right"}
        if (_arm(a) in major) != (_arm(b) in major):
            minor_vs_main += 1
            minor_lane = cz.lane_a[z] if _arm(a) not in major else cz.lane_b[z]
            assert cz.yielding_lane[z] == minor_lane, (a, b)
    assert minor_vs_main >= 12
    straight = rm.lane_id("approach->straight_0")
    others = {rm.lanes[cz.lane_b[z] if cz.lane_a[z] == straight else cz.lane_a[z]].name: cz.kind[z]
              for z in cz.involving(straight)}
    assert others == {"left->right_0": CROSSING, "right->left_0": CROSSING, "right->approach_0": CROSSING,
                      "straight->right_0": CROSSING, "left->straight_0": MERGE, "right->straight_0": MERGE}
    # the opposite minor left turn yields to the ego going straight; no zone is a tie
    (z,) = cz.between(straight, rm.lane_id("straight->right_0"))
    assert cz.yielding_lane[z] == rm.lane_id("straight->right_0")
    assert TIE not in cz.who_yields
    # zone limits bracket the crossing point on both lanes
    assert np.all(cz.s_a_in <= cz.s_a_point + 1e-9) and np.all(cz.s_a_point <= cz.s_a_out + 1e-9)
    assert np.all(cz.s_b_in <= cz.s_b_point + 1e-9) and np.all(cz.s_b_point <= cz.s_b_out + 1e-9)
    for z in np.flatnonzero(cz.kind == CROSSING):
        np.testing.assert_allclose(rm.lanes[cz.lane_a[z]].position(cz.s_a_point[z]), cz.point[z], atol=1e-9)
        np.testing.assert_allclose(rm.lanes[cz.lane_b[z]].position(cz.s_b_point[z]), cz.point[z], atol=1e-6)


def test_merge_and_roundabout_conflicts():
    rm = roads.merge_road().road_map
    cz = roads.conflict_zones(rm)
    assert len(cz) == 1 and cz.kind[0] == MERGE
    assert set(_names(rm, [cz.lane_a[0], cz.lane_b[0]])) == {"taper", "main_0_3"}
    assert cz.yielding_lane[0] == rm.lane_id("taper")
    assert cz.s_a_out[0] == pytest.approx(rm.lanes[cz.lane_a[0]].length)
    assert 0 < cz.s_a_in[0] < cz.s_a_out[0]
    rm = roads.roundabout_piece().road_map
    cz = roads.conflict_zones(rm)
    assert sorted(_names(rm, cz.yielding_lane)) == [f"arm{a}_entry" for a in range(4)]
    assert set(cz.kind) == {MERGE}
    assert all(rm.lanes[i].name.startswith("ring_") for i in cz.priority_lane)


def test_conflicts_on_the_route():
    rc, cz, rm = URBAN.route_conflicts, URBAN.conflicts, URBAN.road_map
    assert np.all(np.diff(rc.s_in) >= 0) and np.all(rc.s_in <= rc.s_point + 1e-9)
    route_lane = URBAN.route_lane()
    for k in range(len(rc)):
        z = rc.zone[k]
        assert rc.route_lane[k] in URBAN.route and rc.other_lane[k] not in URBAN.route
        expected = cz.point[z]
        np.testing.assert_allclose(route_lane.position(rc.s_point[k]), expected, atol=1e-3)
        assert rc.ego_yields[k] == (cz.yielding_lane[z] == rc.route_lane[k])
    by_name = {rm.lanes[o].name: bool(y) for o, y in zip(rc.other_lane, rc.ego_yields, strict=True)}
    assert by_name["crossroad/left->right_0"] and by_name["crossroad/right->left_0"]
    assert by_name["merge_road/main_0_3"] and by_name["roundabout/ring_1_4"]
    assert not by_name["crossroad/straight->right_0"] and not by_name["overtaking_road/taper_out_0"]
    with pytest.raises(ValueError):
        cz.lane_a[0] = 5  # the table is read-only data


# --- variations and validation -------------------------------------------------------------------------------

VARIATIONS = [
    {},
    {"crossroad": {"turn": "left"}},
    {"crossroad": {"turn": "right", "main_lanes": 2}, "order": ("roundabout", "road", "crossroad")},
    {"crossroad": {"crossing_angle": math.radians(60)}},
    {"crossroad": {"crossing_angle": math.radians(120), "approach_length": 80.0}},
    {"road": {"lanes": 3, "length": 300.0}},
    {"road": {"length": 150.0, "taper_length": 20.0}},
    {"merge": {"main_lanes": 2, "merge_angle": math.radians(30), "slip_radius": 30.0, "accel_length": 100.0}},
    {"merge": {"merge_angle": math.radians(90), "slip_radius": 12.0}},
    {"roundabout": {"exit_arm": 1, "arms": 3, "entry_arm": 0, "radius": 20.0}},
    {"roundabout": {"exit_arm": 3}},
    {"order": ("roundabout", "crossroad", "road", "merge")},
    {"order": ("road", "merge")},
    {"road": {"exit_lanes": 2, "opposite_lanes": 2}, "crossroad": {"minor_lanes": 2, "turn": "left"},
     "order": ("road", "crossroad")},
]


@pytest.mark.parametrize("kwargs", VARIATIONS, ids=[str(v) for v in VARIATIONS])
def test_variations_build_a_connected_route(kwargs):
    u = roads.urban_route(**kwargs)
    rm = u.road_map
    order = kwargs.get("order", ("roundabout", "road", "crossroad", "merge"))
    scenario = {"roundabout": "roundabout", "road": "lane_change", "crossroad": "crossroad", "merge": "merge"}
    assert u.tactical.names == tuple(scenario[n] for n in order)
    for a, b in zip(u.route[:-1], u.route[1:], strict=True):
        assert b in rm.successors[a] or b in (rm.left_neighbour[a], rm.right_neighbour[a])
    assert u.route[-1] == u.composed.goal_lane
    piece = [rm.lanes[i].name.split("/")[0] for i in range(len(rm.lanes))]
    for a, b in zip(u.conflicts.lane_a, u.conflicts.lane_b, strict=True):
        assert piece[a] == piece[b]  # pieces meet only at their ports
    turn = kwargs.get("crossroad", {}).get("turn")
    if turn:
        assert f"crossroad/approach->{turn}_0" in _names(rm, u.route)


BAD = [
    (roads.overtaking_road, {"lanes": 0}, "lanes"),
    (roads.overtaking_road, {"entry_lanes": 3}, "entry_lanes"),
    (roads.overtaking_road, {"length": -5.0}, "length"),
    (roads.overtaking_road, {"lane_width": 1.0}, "lane_width"),
    (roads.overtaking_road, {"speed_limit": float("nan")}, "speed_limit"),
    (roads.overtaking_road, {"taper_length": 2.0}, "taper_length"),
    (roads.crossroad, {"crossing_angle": 0.2}, "crossing_angle"),
    (roads.crossroad, {"turn": "back"}, "turn"),
    (roads.crossroad, {"main_lanes": 1.5}, "main_lanes"),
    (roads.crossroad, {"approach_length": 5.0}, "approach_length"),
    (roads.merge_road, {"merge_angle": 2.0}, "merge_angle"),
    (roads.merge_road, {"merge_angle": math.radians(30), "slip_radius": 20.0}, "slip_radius"),
    (roads.merge_road, {"main_lanes": True}, "main_lanes"),
    (roads.roundabout_piece, {"exit_arm": 2}, "exit_arm"),
    (roads.roundabout_piece, {"entry_arm": 4}, "entry_arm"),
    (roads.roundabout_piece, {"radius": 2.0}, "radius"),
    (roads.urban_route, {"order": ("road", "road")}, "order"),
    (roads.urban_route, {"crossroad": {"turns": "left"}}, "turns"),
    (roads.urban_route, {"merge": {"merge_angle": 0.4, "slip_radius": 9.0}}, "slip_radius"),
    (roads.urban_route, {"order": ("bridge",)}, "order"),
]


@pytest.mark.parametrize("builder, kwargs, name", BAD, ids=[f"{b.__name__}-{n}" for b, _, n in BAD])
def test_bad_parameters_raise_value_errors_naming_them(builder, kwargs, name):
    # the name alone, or a piece's (map.merge.slip_radius=...)
    with pytest.raises(ValueError, match=rf"(^|: |\.)(unknown keyword '{name}'|{name}=.*: (must|element) )"):
        builder(**kwargs)


# --- rendering -----------------------------------------------------------------------------------------------


def test_world_renders_surfaces_markings_and_give_way_lines():
    rm = URBAN.road_map
    model = world.build(rm)
    for name in ("road_surface", "road_areas", "markings", "give_way_lines"):
        g = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)
        assert g >= 0 and model.mesh_vertnum[model.geom_dataid[g]] > 0, name
    kinds = [kind for _, kind in rm.marking_lines()]
    assert Marking.BROKEN in kinds and Marking.SOLID in kinds
    give_way = _names(rm, [lane for lane, _ in rm.give_way])
    assert sorted(give_way) == sorted([f"roundabout/arm{a}_in_0" for a in range(4)]
                                      + ["crossroad/approach_in_0", "crossroad/straight_in_0"])
    # a map without give-way lines gets no such geom (the study-000 and study-004 worlds are unchanged)
    plain = world.build(roads.roundabout())
    assert mujoco.mj_name2id(plain, mujoco.mjtObj.mjOBJ_GEOM, "give_way_lines") == -1
