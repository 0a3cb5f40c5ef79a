"""Road maps: lane geometry, graph continuity, routing, lane-frame queries, markings, builders."""

import math

import numpy as np
import pytest

from mjdrive import roads
from mjdrive.roads import Lane, Marking, Path, RoadMap, wrap_angle

# --- Lane geometry ----------------------------------------------------------------------------------------
LANES = {
    "straight": Lane(Path((3.0, -2.0), 0.4).line(50.0).sample()),
    "arc": Lane(Path((0.0, 0.0), 1.0).arc(25.0, 2.0).sample()),
    "line_arc_line": Lane(Path((0.0, 0.0), -0.3).line(10).arc(12.0, -1.4).line(10).sample()),
}


@pytest.mark.parametrize("name", list(LANES))
def test_position_and_local_coordinates_round_trip(name):
    lane = LANES[name]
    rng = np.random.default_rng(0)
    s = rng.uniform(0, lane.length, 300)
    d = rng.uniform(-1.7, 1.7, 300)
    s2, d2 = lane.local_coordinates(lane.position(s, d))
    np.testing.assert_allclose(s2, s, atol=1e-6)
    np.testing.assert_allclose(d2, d, atol=1e-6)
    s1, d1 = lane.local_coordinates(lane.position(s[0], d[0]))
    assert isinstance(s1, float) and s1 == pytest.approx(s[0], abs=1e-6)
    assert d1 == pytest.approx(d[0], abs=1e-6)


def test_points_are_at_most_half_a_metre_apart_and_edges_at_half_width():
    lane = LANES["line_arc_line"]
    assert np.hypot(*np.diff(lane.centre, axis=0).T).max() <= 0.5 + 1e-9
    for edge, sign in ((lane.left_edge(), 1.0), (lane.right_edge(), -1.0)):
        _, d = lane.local_coordinates(edge)
        np.testing.assert_allclose(d, sign * lane.width / 2, atol=1e-6)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_arc_heading_and_curvature(sign):
    radius, h0 = 25.0, 1.0
    lane = Lane(Path((5.0, 5.0), h0).arc(radius, sign * 2.0).sample())
    assert lane.length == pytest.approx(radius * 2.0, rel=1e-4)
    s = np.linspace(0, lane.length, 97)
    np.testing.assert_allclose(wrap_angle(lane.heading(s) - (h0 + sign * s / radius)), 0, atol=1e-4)
    np.testing.assert_allclose(lane.curvature(s), sign / radius, rtol=1e-4)
    # the centre is at distance R from every lane point
    centre = np.array([5.0, 5.0]) + sign * radius * np.array([-math.sin(h0), math.cos(h0)])
    np.testing.assert_allclose(np.hypot(*(lane.position(s) - centre).T), radius, atol=2e-3)  # chord sagitta


def test_straight_lane_has_zero_curvature_and_ends_extrapolate_and_clamp():
    lane = LANES["straight"]
    assert np.abs(lane.curvature(np.linspace(0, lane.length, 11))).max() < 1e-9
    back = lane.position(-2.0)
    np.testing.assert_allclose(back, [3.0 - 2 * math.cos(0.4), -2.0 - 2 * math.sin(0.4)], atol=1e-9)
    s, d = lane.local_coordinates(lane.position(lane.length + 5.0, 1.0))
    assert s == pytest.approx(lane.length) and d == pytest.approx(1.0)


# --- builders: graph continuity ---------------------------------------------------------------------------
BUILDERS = {
    "straight_2": lambda: roads.straight(lanes_per_direction=2),
    "one_way": lambda: roads.straight(110.0, two_way=False),
    "curve_left": lambda: roads.curve(direction="left"),
    "curve_right_2": lambda: roads.curve(40.0, math.pi / 2, "right", lanes_per_direction=2),
    "junction": lambda: roads.junction(),
    "junction_2": lambda: roads.junction(lanes_per_direction=2),
    "town": lambda: roads.town(blocks=(2, 2)),
    "town_2lanes": lambda: roads.town(blocks=(1, 2), lanes_per_direction=2),
    "roundabout": lambda: roads.roundabout(),
    "roundabout_5": lambda: roads.roundabout(radius=25.0, lanes=2, arms=5),
    "merge": lambda: roads.merge(),
    "two_lane_road": lambda: roads.two_lane_road(),
    "crafted": lambda: roads.crafted_routes()[0],
}
MAPS = {name: build() for name, build in BUILDERS.items()}


@pytest.mark.parametrize("name", list(MAPS))
def test_successors_continue_their_predecessors(name):
    rm = MAPS[name]
    pairs = [(a, b) for a, succ in enumerate(rm.successors) for b in succ]
    assert pairs or name in ("straight_2", "one_way", "curve_left", "curve_right_2", "two_lane_road")
    for a, b in pairs:
        la, lb = rm.lanes[a], rm.lanes[b]
        assert np.hypot(*(la.centre[-1] - lb.centre[0])) < 0.05, (la.name, lb.name)
        assert abs(wrap_angle(la.heading(la.length) - lb.heading(0.0))) < 1e-3, (la.name, lb.name)
        # the strips join too: edges meet at the joint
        assert np.hypot(*(la.left_edge()[-1] - lb.left_edge()[0])) < 0.05
    for lane in rm.lanes:
        assert np.hypot(*np.diff(lane.centre, axis=0).T).max() <= 0.5 + 1e-9, lane.name
        if lane.in_junction:
            assert lane.left_marking == lane.right_marking == Marking.NONE


@pytest.mark.parametrize("name", list(MAPS))
def test_neighbours_are_symmetric_parallel_and_one_width_apart(name):
    rm = MAPS[name]
    for i, j in enumerate(rm.right_neighbour):
        if j is None:
            continue
        assert rm.left_neighbour[j] == i
        li, lj = rm.lanes[i], rm.lanes[j]
        s = np.linspace(0.1, 0.9, 5) * lj.length
        si, di = li.local_coordinates(lj.position(s))
        np.testing.assert_allclose(di, -(li.width + lj.width) / 2, atol=0.02)
        np.testing.assert_allclose(wrap_angle(li.heading(si) - lj.heading(s)), 0, atol=0.02)


def test_junction_lane_names_and_turns():
    rm = MAPS["junction"]
    turns = {"S->W_0": math.pi / 2, "S->N_0": 0.0, "S->E_0": -math.pi / 2, "E->S_0": math.pi / 2}
    for name, turn in turns.items():
        lane = rm.lanes[rm.lane_id(name)]
        assert lane.in_junction
        assert wrap_angle(lane.heading(lane.length) - lane.heading(0.0)) == pytest.approx(turn, abs=1e-3)
        assert rm.lane_id(name) in rm.successors[rm.lane_id(name.split("->")[0] + "_in_0")]
        assert rm.lane_id(name.split("->")[1][:-2] + "_out_0") in rm.successors[rm.lane_id(name)]
    s_in = rm.lanes[rm.lane_id("S_in_0")]
    assert s_in.centre[0, 0] > 0 and s_in.heading(0.0) == pytest.approx(math.pi / 2)  # right-hand traffic
    assert len(rm.successors[rm.lane_id("S_in_0")]) == 3
    two = MAPS["junction_2"]  # left turns from lane 0, right turns from lane 1, straight from both
    assert {two.lanes[j].name for j in two.successors[two.lane_id("S_in_0")]} == {"S->N_0", "S->W_0"}
    assert {two.lanes[j].name for j in two.successors[two.lane_id("S_in_1")]} == {"S->N_1", "S->E_1"}


def test_lane_id_unknown_name_lists_close_names():
    with pytest.raises(KeyError, match="S_in_0"):
        MAPS["junction"].lane_id("S_in0")


# --- routing ----------------------------------------------------------------------------------------------
def _assert_connected(rm, route):
    for a, b in zip(route[:-1], route[1:], strict=True):
        assert b in rm.successors[a] or b in (rm.left_neighbour[a], rm.right_neighbour[a]), (a, b)


def test_dijkstra_connects_random_spawn_points_in_the_town():
    rm = roads.town()
    spawns = roads.spawn_points(rm)
    assert all(not rm.lanes[lane].in_junction and 0 < s < rm.lanes[lane].length for lane, s in spawns)
    rng = np.random.default_rng(1)
    for _ in range(25):
        (a, _), (b, _) = (spawns[k] for k in rng.choice(len(spawns), 2, replace=False))
        route = rm.shortest_route(a, b)
        assert route[0] == a and route[-1] == b
        _assert_connected(rm, route)
        poly = rm.route_polyline(route)
        assert np.hypot(*np.diff(poly, axis=0).T).max() < 0.6
        length = sum(rm.lanes[i].length for i in route)
        assert Lane(poly).length == pytest.approx(length, rel=0.01)


def test_unreachable_goal_raises_and_lane_change_routes_are_smooth():
    rm = roads.straight(lanes_per_direction=2)
    fwd0, fwd1, bwd0 = rm.lane_id("fwd_0"), rm.lane_id("fwd_1"), rm.lane_id("bwd_0")
    with pytest.raises(ValueError, match="no route"):
        rm.shortest_route(fwd0, bwd0)
    with pytest.raises(ValueError):
        rm.shortest_route(fwd0, fwd1, allow_lane_change=False)
    route = rm.shortest_route(fwd0, fwd1)
    assert route == [fwd0, fwd1]
    poly = rm.route_polyline(route)
    assert poly[0] == pytest.approx([0.0, -1.75]) and poly[-1] == pytest.approx([200.0, -5.25])
    y = poly[:, 1]
    assert np.all(np.diff(y) <= 1e-12)  # moves right monotonically
    changing = poly[(y < -1.76) & (y > -5.24), 0]
    assert 15.0 < changing.max() - changing.min() < 21.0  # over ~20 m
    heading = np.arctan2(*np.diff(poly, axis=0)[:, ::-1].T)
    assert np.abs(heading).max() < 0.3


def test_lane_change_is_not_planned_across_a_solid_line():
    rm = roads.merge()
    route = rm.shortest_route(rm.lane_id("ramp_0"), rm.lane_id("main_1_2"))
    assert [rm.lanes[i].name for i in route] == ["ramp_0", "ramp_1", "main_1_1", "main_1_2"]
    with pytest.raises(ValueError):  # the ramp's approach has a solid line on its left
        rm.shortest_route(rm.lane_id("ramp_0"), rm.lane_id("main_1_0"))
    rm = roads.straight(lanes_per_direction=2)
    fwd0, fwd1 = rm.lane_id("fwd_0"), rm.lane_id("fwd_1")
    assert rm.shortest_route(fwd0, fwd1) == [fwd0, fwd1]
    rm.lanes[fwd0].right_marking = rm.lanes[fwd1].left_marking = Marking.SOLID
    with pytest.raises(ValueError):
        rm.shortest_route(fwd0, fwd1)


@pytest.mark.parametrize("spacing", [2.0, 5.0])
def test_waypoints_are_evenly_spaced_along_the_route(spacing):
    rm, routes = roads.crafted_routes()
    for route in routes.values():
        points, headings = rm.waypoints(route, spacing)
        steps = np.hypot(*np.diff(points, axis=0).T)
        np.testing.assert_allclose(steps, spacing, rtol=0.01)
        direction = np.arctan2(*np.diff(points, axis=0)[:, ::-1].T)
        assert np.abs(wrap_angle(direction - headings[:-1])).max() < spacing / 10
        start = rm.lanes[route[0]].centre[0]
        end = rm.lanes[route[-1]].centre[-1]
        assert points[0] == pytest.approx(start) and np.hypot(*(points[-1] - end)) < spacing


# --- lane-frame queries -----------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["curve_right_2", "town", "roundabout"])
def test_locate_gives_the_lateral_offset_from_the_lane_centre(name):
    rm = MAPS[name]
    rng = np.random.default_rng(2)
    spawns = roads.spawn_points(rm, spacing=7.0)
    for k in rng.choice(len(spawns), 40, replace=False):
        lane_id, s = spawns[k]
        lane = rm.lanes[lane_id]
        d = rng.uniform(-1.6, 1.6)
        q = rm.locate(lane.position(s, d), heading=lane.heading(s) + 0.1)
        assert q.lane == lane_id and q.s == pytest.approx(s, abs=1e-6) and q.d == pytest.approx(d, abs=1e-6)
        assert q.heading_error == pytest.approx(0.1, abs=1e-6) and q.on_road
        q = rm.locate(lane.position(s, d / 3))  # without heading: the nearest lane
        assert q.lane == lane_id and math.isnan(q.heading_error)


def test_locate_with_spatial_pruning_matches_a_search_over_every_segment():
    rm = MAPS["town"]
    rng = np.random.default_rng(4)
    (x0, y0, x1, y1) = rm.bounds()
    for k in range(300):
        xy = rng.uniform((x0 - 30, y0 - 30), (x1 + 30, y1 + 30))
        heading = None if k % 2 else rng.uniform(-np.pi, np.pi)
        q = rm.locate(xy, heading)
        cost, lane, s, d, _, on_lane = rm._locate_in(rm._f.table, xy[0], xy[1], heading)
        assert (q.lane, q.s, q.d) == pytest.approx((lane, s, d), abs=1e-9), (xy, heading)
        assert q.on_road == (on_lane or bool(rm._in_areas(xy[None])[0])) == rm.on_road(xy)


def test_locate_prefers_the_lane_pointing_the_way_of_the_heading():
    rm = MAPS["straight_2"]
    fwd0, bwd0 = rm.lane_id("fwd_0"), rm.lane_id("bwd_0")
    on_bwd = rm.lanes[bwd0].position(100.0)  # centre of the westbound lane
    assert rm.locate(on_bwd).lane == bwd0
    q = rm.locate(on_bwd, heading=0.05)  # but driving east: the eastbound lane, 3.5 m to its left
    assert q.lane == fwd0 and q.d == pytest.approx(3.5) and q.heading_error == pytest.approx(0.05)
    far = rm.locate((100.0, -30.0))
    assert far.lane == rm.lane_id("fwd_1") and not far.on_road and far.d == pytest.approx(-30.0 + 5.25)


def test_on_road_on_lanes_and_junction_boxes_not_beside_the_road():
    rm = MAPS["junction"]
    box = rm.areas[0]
    assert len(rm.areas) == 1 and rm.on_road(np.zeros(2)) is True
    lo, hi = box.min(axis=0), box.max(axis=0)
    xs, ys = np.meshgrid(np.linspace(lo[0], hi[0], 41), np.linspace(lo[1], hi[1], 41))
    grid = np.column_stack([xs.ravel(), ys.ravel()])
    edges = np.roll(box, -1, axis=0) - box
    rel = grid[:, None, :] - box[None]
    inside = (edges[None, :, 0] * rel[..., 1] - edges[None, :, 1] * rel[..., 0] >= 0).all(axis=1)
    assert inside.sum() > 500 and rm.on_road(grid[inside]).all()
    lanes_only = RoadMap()
    for lane in rm.lanes:
        lanes_only.add_lane(lane)
    assert not lanes_only.on_road(grid[inside]).all()  # the area polygon covers what lane strips miss
    straight = MAPS["straight_2"]
    s = np.linspace(1, 199, 50)
    for lane in straight.lanes:
        assert straight.on_road(lane.position(s, 1.7)).all()
        if lane.name.endswith("_1"):  # the outer lanes: 10 m beyond their right edge is off the road
            assert not straight.on_road(lane.position(s, -1.75 - 10.0)).any()
    assert not straight.on_road(np.column_stack([s, np.full(50, 17.0)])).any()
    assert not straight.on_road(np.column_stack([s, np.full(50, -7.1)])).any()
    assert straight.on_road(np.column_stack([s, np.full(50, -6.9)])).all()
    assert not MAPS["town"].on_road(np.array([40.0, 40.0]))  # the middle of a block


def test_crossed_solid_edges_and_centre_but_not_broken_lines():
    rm = MAPS["straight_2"]  # edges at y = -7, 7 (solid), centre y = 0 (solid), y = -3.5, 3.5 (broken)
    cross_edge = (np.array([[50.0, -6.5]]), np.array([[50.5, -7.5]]))
    along = (np.array([[50.0, -5.0]]), np.array([[51.0, -5.0]]))
    cross_broken = (np.array([[50.0, -3.0]]), np.array([[50.5, -4.0]]))
    cross_centre = (np.array([[50.0, -0.3]]), np.array([[50.5, 0.3]]))
    assert rm.crossed_solid(*cross_edge)
    assert not rm.crossed_solid(*along)
    assert not rm.crossed_solid(*cross_broken)
    assert rm.crossed_solid(*cross_centre)
    p0 = np.vstack([along[0], cross_broken[0], along[0] + 1, cross_edge[0]])
    p1 = np.vstack([along[1], cross_broken[1], along[1] + 1, cross_edge[1]])
    assert rm.crossed_solid(p0, p1) and not rm.crossed_solid(p0[:3], p1[:3])
    assert not rm.crossed_solid(np.array([[50.0, -6.5]]), np.array([[50.0, -6.5]]))  # standing still
    segs = rm.solid_segments()
    assert segs.shape[1:] == (2, 2) and np.isin(np.round(segs[:, :, 1], 6), [-7.0, 0.0, 7.0]).all()


def test_crossed_solid_on_the_town_uses_every_solid_segment():
    rm = MAPS["town"]
    segs = rm.solid_segments()
    rng = np.random.default_rng(3)
    k = rng.choice(len(segs), 200, replace=False)
    mid = segs[k].mean(axis=1)
    tangent = segs[k, 1] - segs[k, 0]
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]]) / np.hypot(*tangent.T)[:, None]
    for m, n in zip(mid, normal, strict=True):
        assert rm.crossed_solid((m - 0.2 * n)[None], (m + 0.2 * n)[None])
    lane = rm.lanes[rm.lane_id("J0_0>J1_0_0")]
    s = np.arange(0.0, lane.length, 0.5)
    path = lane.position(s, 0.8)
    assert not any(rm.crossed_solid(path[i][None], path[i + 1][None]) for i in range(len(s) - 1))


# --- markings ---------------------------------------------------------------------------------------------
def test_marking_lines_draw_each_boundary_once():
    lines = MAPS["two_lane_road"].marking_lines()
    assert len(roads.straight().marking_lines()) == 3
    assert sorted(kind for _, kind in lines) == [Marking.BROKEN, Marking.SOLID, Marking.SOLID]
    lines = MAPS["straight_2"].marking_lines()
    assert len(lines) == 5 and sum(kind == Marking.BROKEN for _, kind in lines) == 2
    assert len(MAPS["one_way"].marking_lines()) == 2
    assert len(MAPS["curve_right_2"].marking_lines()) == 5
    rm = MAPS["junction"]
    lines = rm.marking_lines()
    assert len(lines) == 12  # 3 per arm, nothing from the connectors
    half = 3.5 + 12.0  # lanes_per_direction * lane_width + corner_radius
    for line, _ in lines:  # markings stop at the junction box
        assert (np.abs(line).max(axis=1) >= half - 1e-6).all()


# --- roundabout and crafted routes ------------------------------------------------------------------------
def test_roundabout_ring_goes_counter_clockwise_and_every_arm_reaches_every_exit():
    rm = MAPS["roundabout"]
    ring = [lane for lane in rm.lanes if lane.name.startswith("ring_")]
    assert len(ring) == 2 * 8
    for lane in ring:
        p, t = lane.centre[:-1], np.diff(lane.centre, axis=0)
        assert (p[:, 0] * t[:, 1] - p[:, 1] * t[:, 0] > 0).all()  # angular momentum about the centre > 0
    radii = {lane.name[:6]: np.hypot(*lane.centre.T).mean() for lane in ring}
    assert radii["ring_0"] == pytest.approx(20 - 1.75) and radii["ring_1"] == pytest.approx(20 + 1.75)
    routes = roads.roundabout_routes(rm)
    assert sorted(routes) == [(a, b) for a in range(4) for b in range(4)]
    for (a, b), route in routes.items():
        assert rm.lanes[route[0]].name == f"arm{a}_in_0" and rm.lanes[route[-1]].name == f"arm{b}_out_0"
        assert all(b_ in rm.successors[a_] for a_, b_ in zip(route[:-1], route[1:], strict=True))
    turns = [len(routes[(0, b)]) for b in (1, 2, 3, 0)]
    assert turns == sorted(turns) and len(set(turns)) == 4  # later exits are further round
    assert len(roads.roundabout_routes(MAPS["roundabout_5"])) == 25
    # a crosswalk on every arm, a few metres out from the ring, across the road
    assert len(rm.crosswalks) == 4
    for cw in rm.crosswalks:
        assert 20 + 3.5 < np.hypot(*cw.centre) < 20 + 3.5 + 15
        assert rm.on_road(cw.centre + 0.99 * (cw.polygon() - cw.centre)).all()
        assert abs(math.cos(cw.heading - math.atan2(cw.centre[1], cw.centre[0]))) < 1e-9


def test_crafted_routes_are_four_disjoint_routes_of_the_right_shape():
    rm, routes = roads.crafted_routes()
    assert sorted(routes) == ["left_turn", "soft_left", "soft_right", "straight"]
    turn = {}
    for name, route in routes.items():
        _assert_connected(rm, route)
        points, headings = rm.waypoints(route)
        turn[name] = float(np.sum(wrap_angle(np.diff(np.unwrap(headings)))))
    assert turn["left_turn"] == pytest.approx(math.pi / 2, abs=0.05)
    assert turn["soft_left"] == pytest.approx(math.pi / 4, abs=0.05)
    assert turn["soft_right"] == pytest.approx(-math.pi / 4, abs=0.05)
    assert abs(turn["straight"]) < 1e-6
    (lane_id,) = routes["straight"]
    lane = rm.lanes[lane_id]
    assert 100.0 <= lane.length <= 120.0
    assert lane.left_marking == lane.right_marking == Marking.SOLID
    assert rm.left_neighbour[lane_id] is None and rm.right_neighbour[lane_id] is None
    # pieces far apart: the bounding boxes of any two pieces are >= 200 m apart
    boxes = {}
    for name in routes:
        pts = np.vstack([np.vstack([ln.left_edge(), ln.right_edge()]) for ln in rm.lanes
                         if ln.name.startswith(name + "/")])
        boxes[name] = (pts.min(axis=0), pts.max(axis=0))
    for a in routes:
        for b in routes:
            if a < b:
                gap = np.maximum(boxes[a][0] - boxes[b][1], boxes[b][0] - boxes[a][1])
                assert np.hypot(*np.maximum(gap, 0.0)) >= 200.0, (a, b)


def test_footprint_is_box_points_of_one_box():
    """The per-step footprint (scalars) gives `box_points`' corners bit for bit."""
    from mjdrive.roads.geometry import BOX_CORNERS, box_points, footprint

    rng = np.random.default_rng(0)
    for _ in range(2000):
        x, y, yaw = rng.normal(0, 100), rng.normal(0, 100), rng.uniform(-7, 7)
        length, width = rng.uniform(0.5, 6.0), rng.uniform(0.5, 2.5)
        expected = box_points((x, y), yaw, BOX_CORNERS * (0.5 * length, 0.5 * width))
        assert np.array_equal(footprint(x, y, yaw, length, width), expected)
        # with the centre first, and with the caller's cosine and sine: the same corners
        with_centre = footprint(x, y, yaw, length, width, centre=True, cos_sin=(np.cos(yaw), np.sin(yaw)))
        assert with_centre.shape == (5, 2) and with_centre[0].tolist() == [x, y]
        assert np.array_equal(with_centre[1:], expected)


def test_route_frame_projects_points_onto_the_nearest_segment_of_the_route():
    """RouteFrame's (s, d) of points near a roundabout route, searching every segment: the foot point at s is the
    polyline's nearest point, d the offset from its segment's line (the distance, but at a vertex's outer side),
    d > 0 to its left; `point` gives one point's numbers as floats from the same window."""
    from mjdrive.roads.junctions import roundabout_routes
    from mjdrive.roads.lane import Lane
    from mjdrive.roads.route_frame import RouteFrame
    from mjdrive.traffic.lanes import polyline_distance

    rm = roads.roundabout()
    rng = np.random.default_rng(1)
    for route in list(roundabout_routes(rm).values())[:4]:
        lane = Lane(rm.route_polyline(route), name="route")
        frame, single = RouteFrame(lane), RouteFrame(lane)
        for _ in range(50):
            centre = np.array(lane.position(rng.uniform(0, lane.length))) + rng.normal(0, 2.0, 2)
            points = np.vstack([centre[None], centre + rng.normal(0, 2.0, (4, 2))])
            s, d = frame(points, full=True)
            distance = polyline_distance(points, lane.centre)
            foot = lane.position(s)  # the nearest point of the polyline
            np.testing.assert_allclose(np.hypot(*(points - foot).T), distance, atol=1e-6)
            # d: the offset from the nearest segment's line (at a vertex's outer side, less than the distance)
            assert np.all(np.abs(d) <= distance + 1e-9) and np.mean(np.abs(np.abs(d) - distance) < 1e-9) > 0.5
            ahead = lane.position(np.minimum(s + 0.01, lane.length)) - lane.position(np.maximum(s - 0.01, 0.0))
            left = ahead[:, 0] * (points - foot)[:, 1] - ahead[:, 1] * (points - foot)[:, 0]
            assert np.all((left > 0) == (d > 0) | (np.abs(d) < 1e-6))
            single.segment = frame.segment
            x, y = float(points[0, 0]), float(points[0, 1])
            one = single.point(x, y)
            assert one == (float(frame(points[:1])[0][0]), float(frame(points[:1])[1][0]))
            assert all(type(v) is float for v in one)


def test_lane_one_point_projection_point_and_curvature_sampling_give_the_numpy_numbers():
    """One point's lane coordinates (a compiled pass over every segment, with numba) equal the batched numpy
    projection's bit for bit, ties at the vertices (the first segment wins) and points far off included; `point`
    equals `position` and `max_abs_curvature` max |curvature| over numpy's linspace (the pure-pursuit driver's
    look-ahead point and comfort speed)."""
    from mjdrive.roads.junctions import roundabout_routes

    rm = roads.roundabout()
    routes = list(roundabout_routes(rm).values())[:2]
    lanes = [*LANES.values(), *(Lane(rm.route_polyline(route), name="route") for route in routes)]
    rng = np.random.default_rng(4)
    for lane in lanes:
        along = lane.position(rng.uniform(-3, lane.length + 3, 150), rng.uniform(-4, 4, 150))
        vertices = lane.centre[1:-1:7] + lane.normals[1:-1:7] * rng.uniform(-2, 2, (len(lane.centre[1:-1:7]), 1))
        far = rng.uniform(lane.centre.min(0) - 40, lane.centre.max(0) + 40, (50, 2))
        points = np.vstack([along + rng.normal(0, 0.5, along.shape), vertices, far])
        batch_s, batch_d = lane.local_coordinates(points)
        for point, s, d in zip(points, batch_s, batch_d, strict=True):
            one = lane.local_coordinates(point)
            assert one == (s, d) and all(type(v) is float for v in one)
        for s in [*rng.uniform(-2, lane.length + 2, 200), *lane.s, 0.0, lane.length]:  # `point`: position's floats
            x, y = lane.position(s).tolist()
            got = lane.point(s)
            assert got == (x, y) and [math.copysign(1, v) for v in got] == [math.copysign(1, x), math.copysign(1, y)]
        for start in [*rng.uniform(-5, lane.length + 5, 100), *lane.s[1:-1:3], 0.0, lane.length, lane.length - 20.0]:
            for stop in (min(start + 20.0, lane.length), start, start + rng.uniform(0, 30)):
                expected = float(np.max(np.abs(lane.curvature(np.linspace(start, stop, 8)))))
                assert lane.max_abs_curvature(start, stop, 8) == expected
    assert max(lane.max_abs_curvature(0.0, lane.length) for lane in lanes) > 0.01  # the arcs' curvature is seen
