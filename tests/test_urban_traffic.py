"""Urban traffic (study 002): intentions honoured by behaviour, right of way at conflict zones, the old jam
at a four-way junction and the vanishing at an on-ramp's end gone, and no overlap on the concatenated map.
Traffic alone (no MuJoCo), so every scene runs in a fraction of a second of wall time."""

from __future__ import annotations

import numpy as np
import pytest

from mjdrive import roads
from mjdrive.roads.conflicts import conflict_zones
from mjdrive.roads.urban import concatenated
from mjdrive.traffic import EgoState, Traffic, TrafficConfig, overlapping_pairs
from mjdrive.traffic.conflicts import PRIORITY_ACCEL, reach_time
from mjdrive.traffic.intentions import AFTER, BEFORE, LANE_CHANGE, LEFT, RIGHT, ROUNDABOUT, STRAIGHT, TAKE_WAY, YIELD
from mjdrive.traffic.urban import URBAN_CONFIG, piece_exits, urban_traffic

SUBSTEP = URBAN_CONFIG.substep  # [s]
QUIET = TrafficConfig.from_dict({**URBAN_CONFIG.to_dict(), "respawn": False})  # scenes: nobody else enters


def scene(order: tuple[str, ...], n: int = 2) -> tuple[Traffic, roads.RoadMap]:
    """A piece's map with `n` cars, none on it yet (place them)."""
    composed = concatenated(order=order)
    traffic = urban_traffic(composed, counts={"car": n}, config=QUIET)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    return traffic, composed.road_map


def lane(road_map, name: str) -> int:
    return road_map.lane_id(name)


def run(traffic: Traffic, seconds: float, watch=None) -> None:
    for _ in range(int(round(seconds / SUBSTEP))):
        traffic.advance(SUBSTEP)
        if watch is not None:
            watch()


def lanes_driven(traffic: Traffic, row: int, seconds: float) -> list[int]:
    """The lanes vehicle `row` drives through, in order."""
    seen: list[int] = []

    def note():
        current = int(traffic.vehicles.path[row, 0])
        if traffic.vehicles.active[row] and (not seen or seen[-1] != current):
            seen.append(current)

    run(traffic, seconds, note)
    return seen


@pytest.mark.parametrize("turn, exit_lane", [(STRAIGHT, "crossroad/straight_out_0"), (LEFT, "crossroad/left_out_0"),
                                             (1 + 1, "crossroad/right_out_0")])
def test_crossroad_intention_is_the_turn_taken(turn, exit_lane):
    traffic, rm = scene(("crossroad",), n=1)
    traffic.place(0, [lane(rm, "crossroad/approach_in_0")], 20.0, 6.0, intentions={"crossroad": turn})
    driven = lanes_driven(traffic, 0, 25.0)
    assert lane(rm, exit_lane) in driven, [rm.lanes[i].name for i in driven]


def merge_order(courtesy: int) -> tuple[int, int]:
    """A car on the acceleration lane nearer the merge point than a main-road car behind it: which one
    reaches the lane after the merge first (row), and when each does."""
    traffic, rm = scene(("merge",), n=2)
    main, accel, after = lane(rm, "merge_road/main_0_2"), lane(rm, "merge_road/accel"), lane(rm, "merge_road/main_0_4")
    traffic.place(0, [main], 30.0, 10.0, desired_speed=12.0, intentions={"merge": courtesy})
    traffic.place(1, [accel], 45.0, 3.0, desired_speed=12.0)
    first: list[int] = []

    def note():
        for row in (0, 1):
            if traffic.vehicles.path[row, 0] == after and row not in first:
                first.append(row)

    run(traffic, 20.0, note)
    return tuple(first)


def test_a_yielding_vehicle_lets_the_merging_car_in_and_a_take_way_one_does_not():
    assert merge_order(YIELD) == (1, 0)  # the merging car first
    assert merge_order(TAKE_WAY) == (0, 1)  # the main-road car keeps its way


@pytest.mark.parametrize("start, wish, end", [("overtaking_road/main_1", LEFT, "overtaking_road/main_0"),
                                              ("overtaking_road/main_0", RIGHT, "overtaking_road/main_1")])
def test_a_lane_change_intention_ends_in_the_named_lane(start, wish, end):
    traffic, rm = scene(("road",), n=1)
    traffic.place(0, [lane(rm, start)], 20.0, 8.0, desired_speed=8.0, intentions={"lane_change": wish})
    run(traffic, 12.0)
    assert traffic.vehicles.path[0, 0] == lane(rm, end)
    assert traffic.vehicles.lc_dist[0] >= traffic.config.lane_change_length  # moved over completely
    x, y, yaw = traffic.poses()[traffic.vehicle_slots[0]]
    s, d = rm.lanes[lane(rm, end)].frame(np.array([x, y]))[:2]
    assert abs(d - traffic.vehicles.d_pref[0]) < 0.05  # centred in the new lane (at its own preferred offset)
    assert traffic.vehicles.intention[0, LANE_CHANGE] == 0  # the manoeuvre is over: it now keeps its lane


def test_keep_intention_never_changes_lane():
    traffic, rm = scene(("road",), n=1)
    right = lane(rm, "overtaking_road/main_1")
    traffic.place(0, [right], 10.0, 8.0, desired_speed=8.0, intentions={"lane_change": 0})
    assert lane(rm, "overtaking_road/main_0") not in lanes_driven(traffic, 0, 20.0)


@pytest.mark.parametrize("wish", [BEFORE, AFTER])
def test_roundabout_intention_is_the_exit_relative_to_the_egos(wish):
    """The ego enters at arm 2 and leaves at arm 0 (two exits on); a car entering at arm 3 meets the exit of
    arm 0 first (the ego's: it cannot leave before it), one entering at arm 1 meets arm 2's exit first."""
    traffic, rm = scene(("roundabout",), n=1)
    route = rm.shortest_route(lane(rm, "roundabout/arm2_in_0"), lane(rm, "roundabout/arm0_out_0"))
    traffic.set_ego_route(route)
    ego_exit = traffic.routes.ego_exit
    assert rm.lanes[ego_exit].name == "roundabout/arm0_exit"
    traffic.place(0, [lane(rm, "roundabout/arm1_in_0")], 40.0, 4.0, intentions={"roundabout": wish})
    driven = lanes_driven(traffic, 0, 40.0)
    exits = [i for i in driven if traffic.roles.ring_exit[i]]
    assert len(exits) == 1
    if wish == BEFORE:  # arm 1 -> the exit of arm 2 or 3, never reaching the ego's exit
        assert exits[0] != ego_exit and ego_exit not in driven
    else:  # past the ego's exit first, then out
        assert ego_exit not in driven
        ring_before_exit = driven[: driven.index(exits[0])]
        ego_exit_ring = rm.predecessors(ego_exit)[0]
        assert ego_exit_ring in ring_before_exit
    assert traffic.vehicles.intention[0, ROUNDABOUT] == wish


def test_the_minor_road_gives_way_at_the_crossroad():
    """A car on the minor approach waits at its give-way line while a main-road car crosses, then goes."""
    traffic, rm = scene(("crossroad",), n=2)
    traffic.place(0, [lane(rm, "crossroad/approach_in_0")], 40.0, 3.0, intentions={"crossroad": STRAIGHT})
    traffic.place(1, [lane(rm, "crossroad/left_in_0")], 25.0, 8.0, desired_speed=8.0,
                  intentions={"crossroad": STRAIGHT})
    order: list[int] = []
    crossing = {lane(rm, "crossroad/approach->straight_0"), lane(rm, "crossroad/left->right_0")}

    def note():
        for row in (0, 1):
            if int(traffic.vehicles.path[row, 0]) in crossing and row not in order:
                order.append(row)

    run(traffic, 20.0, note)
    assert order == [1, 0]


def test_a_priority_vehicle_that_may_speed_up_is_not_cut_off():
    """A minor-road car standing at its give-way line, a main-road motorcycle rolling at 2 m/s more than 30 m
    before the zone (counted at `merge_speed`, over 10 s away) that speeds up to its 8 m/s: the car counts the
    motorcycle's time to the zone with the acceleration it may take (`conflicts.reach_time`), so it waits, and the
    motorcycle never has to brake for it (judged at its present pace, the car went first and the motorcycle braked
    at 2.3 m/s^2)."""
    composed = concatenated(order=("crossroad",))
    rm = composed.road_map
    traffic = urban_traffic(composed, counts={"car": 1, "motorcycle": 1}, config=QUIET)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    traffic.place(0, [lane(rm, "crossroad/approach_in_0")], 45.5, 0.0, intentions={"crossroad": STRAIGHT})
    traffic.place(1, [lane(rm, "crossroad/left_in_0")], 20.0, 2.0, desired_speed=8.0,
                  intentions={"crossroad": STRAIGHT})
    crossing = {lane(rm, "crossroad/approach->straight_0"), lane(rm, "crossroad/left->right_0")}
    order: list[int] = []
    braking = [0.0]  # [m/s^2] the motorcycle's hardest

    def note():
        for row in (0, 1):
            if int(traffic.vehicles.path[row, 0]) in crossing and row not in order:
                order.append(row)
        if traffic.vehicles.active[1]:
            braking[0] = min(braking[0], float(traffic.vehicles.accel[1]))
        present = traffic.present
        assert not len(overlapping_pairs(traffic.poses()[present], traffic.half_size[present]))

    run(traffic, 20.0, note)
    assert order == [1, 0]
    assert braking[0] > -0.5


def test_reach_time_is_the_kinematics_of_a_start_at_the_priority_acceleration():
    """`conflicts.reach_time`: from rest, d = a t^2 / 2; at its top speed, d / v; speeding up to it, then cruising
    (the time to the top speed plus the rest of the way at it)."""
    a = PRIORITY_ACCEL
    assert reach_time(20.0, 0.0, 100.0) == pytest.approx(np.sqrt(2 * 20.0 / a))
    assert reach_time(30.0, 10.0, 10.0) == pytest.approx(3.0)
    to_top = (8.0 - 2.0) / a  # [s]
    run_up = (8.0**2 - 2.0**2) / (2 * a)  # [m]
    assert reach_time(40.0, 2.0, 8.0) == pytest.approx(to_top + (40.0 - run_up) / 8.0)
    assert reach_time(0.0, 3.0, 8.0) == 0.0
    assert reach_time(40.0, 2.0, 8.0) < 40.0 / 3.0  # sooner than at the merge_speed floor of its pace


def free_run(traffic: Traffic, seconds: float) -> tuple[int, float, dict]:
    """Overlapping substeps, the longest stop [s] of a vehicle not queued (`Traffic.queued`), and where vehicles
    left the map."""
    overlaps, stopped, worst = 0, np.zeros(traffic.nv), 0.0
    vanished: dict[str, int] = {}
    queued = np.zeros(traffic.nv, dtype=bool)
    for step in range(int(round(seconds / SUBSTEP))):
        before, was_active = traffic.vehicles.path[:, 0].copy(), traffic.vehicles.active.copy()
        generation = traffic.generation[traffic.vehicle_slots].copy()
        traffic.advance(SUBSTEP)
        replaced = traffic.generation[traffic.vehicle_slots] != generation  # left and re-entered at once
        for row in np.flatnonzero(was_active & (~traffic.vehicles.active | replaced)):  # rare: where vehicles leave
            name = traffic.map.road_map.lanes[before[row]].name
            vanished[name] = vanished.get(name, 0) + 1
        present = traffic.present
        overlaps += len(overlapping_pairs(traffic.poses()[present], traffic.half_size[present])) > 0
        if step % traffic.n_plan == 0:
            queued = traffic.queued()
        stopped = np.where(traffic.stopped() & ~queued, stopped + SUBSTEP, 0.0)
        worst = max(worst, stopped.max())
    return overlaps, worst, vanished


def test_queued_tells_a_queue_from_a_stop_of_its_own():
    """Two cars on one lane: the front one stopped by hand (its desired speed 0), the other arrives behind it and
    stops: the one behind is queued, the front one is stopped but not queued; once the front one drives off, the
    queue is gone."""
    rm = roads.two_lane_road(length=200.0)
    traffic = Traffic(rm, ["car", "car"], URBAN_CONFIG)
    traffic.remove_all()
    lane = rm.lane_id("fwd_0")
    traffic.place(0, [lane], 100.0, 0.0, desired_speed=0.0)
    traffic.place(1, [lane], 60.0, 8.0, desired_speed=8.0)
    run(traffic, 20.0)
    assert traffic.stopped().tolist() == [True, True]
    assert traffic.queued().tolist() == [False, True]
    traffic.vehicles.v0[0] = 10.0
    run(traffic, 10.0)
    assert traffic.stopped().tolist() == [False, False] and traffic.queued().tolist() == [False, False]


@pytest.mark.parametrize("lane_width", [2.5, 3.0])
def test_narrow_crossroads_keep_flowing(lane_width):
    """The crossroad with 2.5-3 m lanes and 20 cars (more than twice its default) used to gridlock within a
    minute: a turning car's corridor caught the oncoming car turning beside it, and each waited for the other.
    Oncoming vehicles keep to their lanes (crossing lanes are conflict zones): three minutes, no overlap, nobody
    stands 45 s unqueued."""
    traffic = urban_traffic(concatenated(order=("crossroad",), crossroad={"lane_width": lane_width}),
                            counts={"car": 20})
    traffic.reset(np.random.default_rng(0))
    overlaps, worst, _ = free_run(traffic, 180.0)
    assert overlaps == 0 and worst < 45.0


def test_the_old_junction_jam_is_gone():
    """`roads.junction()` with 16 cars used to stand still after 30-60 s with cars overlapping. Every lane
    has the same rank there (an all-way give-way junction, first come first served), so a car may wait
    for a minute or so at rush hour, but the junction keeps flowing."""
    rm = roads.junction()
    traffic = Traffic(rm, ["car"] * 16, URBAN_CONFIG, conflicts=conflict_zones(rm))
    traffic.reset(np.random.default_rng(3))
    overlaps, worst, _ = free_run(traffic, 120.0)
    spawned = traffic.stats["spawned"]
    assert overlaps == 0 and worst < 90.0
    run(traffic, 30.0)
    assert traffic.stats["spawned"] > spawned  # still flowing: vehicles leave and new ones enter


def test_nobody_vanishes_at_the_end_of_an_on_ramp():
    """`roads.merge()`'s ramp ends beside the main road: its cars move over instead of leaving the map."""
    rm = roads.merge()
    traffic = Traffic(rm, ["car"] * 12, URBAN_CONFIG, conflicts=conflict_zones(rm))
    traffic.reset(np.random.default_rng(1))
    overlaps, worst, vanished = free_run(traffic, 120.0)
    assert overlaps == 0 and worst < 30.0
    assert set(vanished) <= {"main_0_2", "main_1_2"} and sum(vanished.values()) > 10, vanished
    assert traffic.stats["lane_changes"] > 0


def test_concatenated_map_two_minutes_without_overlap_or_deadlock():
    """No overlap, and nobody stands for half a minute unless queued (results/urban/traffic.md reports the
    longest waits over 10-minute runs)."""
    traffic = urban_traffic(concatenated())
    traffic.reset(np.random.default_rng(0))
    overlaps, worst, _ = free_run(traffic, 120.0)
    assert overlaps == 0 and worst < 30.0
    assert traffic.stats["spawned"] > 20
    assert set(np.unique(traffic.vehicles.intention[traffic.vehicles.active], axis=0).ravel()) <= {0, 1, 2}


def test_a_waiting_minor_road_car_gets_its_turn_within_half_a_minute():
    """A minor-road car turning across the crossroad's busy flows waits for a gap; past its patience it
    claims the zone and priority cars that can still stop let it go (without the claim this seed kept a
    left-turner waiting 38 s at 190 s)."""
    traffic = urban_traffic(concatenated(order=("crossroad",)))
    traffic.reset(np.random.default_rng(0))
    overlaps, worst, _ = free_run(traffic, 240.0)
    assert overlaps == 0 and worst < 30.0



def test_intention_draws_are_generator_choice():
    """`intentions.draw_intentions` makes the same values from the same draws as `Generator.choice(n, size,
    p=shares)` (what the committed urban results were made with), for any shares and any number of vehicles."""
    from mjdrive.traffic.intentions import SCENARIOS, draw_intentions, intention_table

    rng = np.random.default_rng(0)
    for _ in range(300):
        shares = [tuple(float(x) for x in rng.random(n) * rng.choice([0.0, 0.99], n, p=[0.2, 0.8]) + 1e-3)
                  for n in (3, 3, 2, 2)]
        cfg = TrafficConfig(lane_change_intentions=shares[0], turn_intentions=shares[1], merge_intentions=shares[2],
                            roundabout_intentions=shares[3])
        rows = np.sort(rng.choice(12, int(rng.integers(1, 6)), replace=False))
        seed = int(rng.integers(2**31))
        intention = np.zeros((12, 4), dtype=np.int64)
        cdfs, columns = intention_table(cfg)
        draws = np.random.default_rng(seed)
        draw_intentions(intention, rows, draws.random((len(columns), len(rows))), cdfs, columns)
        reference = np.random.default_rng(seed)
        for column, p in enumerate(shares):
            p = np.asarray(p) / np.sum(p)
            assert np.array_equal(intention[rows, column], reference.choice(len(p), size=len(rows), p=p))
        assert draws.random() == reference.random()  # the same draws consumed
        assert not intention[np.setdiff1d(np.arange(12), rows)].any() and len(SCENARIOS) == 4


def _pieces_driven(own: bool) -> int:
    """How many times a vehicle drove from one piece of the concatenated map into another in 3 minutes."""
    composed = concatenated()
    traffic = urban_traffic(composed, own_traffic=own)
    traffic.reset(np.random.default_rng(0))
    piece = np.array([lane.name.partition("/")[0] for lane in composed.road_map.lanes])
    before = traffic.vehicles.path[:, 0].copy()
    generation = traffic.generation[traffic.vehicles.slot].copy()
    crossings = 0
    for _ in range(int(round(180.0 / URBAN_CONFIG.decision_period))):
        traffic.advance(URBAN_CONFIG.decision_period)
        v = traffic.vehicles
        now_generation = traffic.generation[v.slot]
        same = v.active & (now_generation == generation) & (before >= 0)
        crossings += int(np.sum(same & (piece[np.maximum(v.path[:, 0], 0)] != piece[np.maximum(before, 0)])))
        before, generation = np.where(v.active, v.path[:, 0], -1), now_generation.copy()
    return crossings


def test_each_piece_of_a_chain_keeps_its_own_traffic():
    """With own traffic (the urban tasks' default, `piece_traffic="own"`) no vehicle drives from one piece of the
    chain into the next: it leaves the map at the border (`piece_exits`: the lanes leading into another piece,
    both ways) and re-enters at a source; with `through` vehicles do drive on."""
    composed = concatenated()
    rm = composed.road_map
    exits = piece_exits(composed)
    names = {rm.lanes[i].name for i in exits}
    assert names == {"roundabout/arm0_out_0", "overtaking_road/out_1", "overtaking_road/opp_in_0",
                     "crossroad/approach_out_0", "crossroad/straight_out_0", "merge_road/approach_out_0"}
    assert len(piece_exits(concatenated(order=("crossroad",)))) == 0  # one piece: nothing to leave
    assert _pieces_driven(own=True) == 0
    assert _pieces_driven(own=False) > 5


def test_a_closed_lane_takes_no_traffic_in():
    """`urban_traffic(closed=...)` (the urban tasks' `entry_traffic=false` closes the route's first lane): no vehicle
    enters there, neither at the start nor later; the same map with the lane open fills it."""
    composed = concatenated(order=("crossroad",))
    approach = composed.road_map.lane_id("crossroad/approach_in_0")

    def on_approach(closed: tuple[int, ...]) -> int:
        traffic = urban_traffic(composed, closed=closed)
        traffic.reset(np.random.default_rng(0))
        seen = 0
        for _ in range(int(round(120.0 / URBAN_CONFIG.decision_period))):
            seen += int(np.sum(traffic.vehicles.active & (traffic.vehicles.path[:, 0] == approach)))
            traffic.advance(URBAN_CONFIG.decision_period)
        return seen

    assert on_approach((approach,)) == 0
    assert on_approach(()) > 10


def test_a_committed_vehicle_stops_at_the_zone_for_the_ego_committed_to_it():
    """The ego standing past its give-way line (committed to the crossing, not yet in the zone) and a main-road car
    past its own line at 4 m/s: the car stops at the zone's edge, as a driver brakes for a car that has pulled out in
    front whoever had the right of way (it used to drive on into the ego's path: the hybrid's crossroad
    collisions), and goes on once the ego has crossed."""
    traffic, rm = scene(("crossroad",), n=1)
    approach, crossing = lane(rm, "crossroad/approach_in_0"), lane(rm, "crossroad/approach->straight_0")
    car_lane = lane(rm, "crossroad/left->right_0")
    ap = traffic.approaches
    r = next(r for r in range(len(ap.lane)) if ap.lane[r] == car_lane and ap.other[r] == crossing)
    traffic.place(0, [car_lane], 2.0 - traffic.vehicles.length[0] / 2, 4.0, desired_speed=8.0,
                  intentions={"crossroad": STRAIGHT})  # front 2 m into its connector: past its line
    length, half_width = 4.8, 0.92
    path = np.array([approach, crossing, lane(rm, "crossroad/straight_out_0")])
    s = [rm.lanes[approach].length + 1.0 - length / 2]  # front 1 m past the give-way line, before the zone

    def ego() -> EgoState:
        on = 0 if s[0] < rm.lanes[approach].length else 1
        here = s[0] - (rm.lanes[approach].length if on else 0.0)
        x, y = rm.lanes[path[on]].position(here)
        return EgoState(x, y, rm.lanes[path[on]].heading(here), 0.0, length, 2 * half_width, path[on:], here)

    fronts = []

    def advance(seconds: float) -> None:
        for _ in range(int(round(seconds / SUBSTEP))):
            traffic.advance(SUBSTEP, ego)
            e = ego()
            poses = np.vstack([traffic.poses()[:1], [[e.x, e.y, e.yaw]]])
            half = np.vstack([traffic.half_size[:1], [[length / 2, half_width, 0.7]]])
            assert not len(overlapping_pairs(poses, half))
            if int(traffic.vehicles.path[0, 0]) == car_lane:
                fronts.append((traffic.vehicles.s[0] + traffic.vehicles.length[0] / 2, traffic.vehicles.v[0]))

    advance(6.0)  # the ego stands committed
    front, speed = fronts[-1]
    assert speed < 0.1 and front <= ap.s_in[r]  # the car waits before the zone
    for _ in range(int(round(8.0 / SUBSTEP))):  # the ego crosses at 3 m/s
        s[0] += 3.0 * SUBSTEP
        advance(SUBSTEP)
    assert traffic.vehicles.v[0] > 1.0 or int(traffic.vehicles.path[0, 0]) != car_lane  # and goes on


def test_three_lanes_abreast_at_a_lane_drop_do_not_wait_for_each_other_for_ever():
    """Three cars standing abreast where a three-lane road drops to one, each waiting for the next: the left lane's car
    behind the courteous right lane's car it lets in (a zipper), that one behind the middle lane's, and the middle
    lane's at its line for the left lane's car beside it (once a stand-off for good: the maps sweep's three-lane road
    ended at the time limit). Standing first at its line for `TURN_WAIT`, a car goes before the standing one beside
    it, and all three pass the drop without touching."""
    composed = concatenated({"order": ["road"], "road": {"lanes": 3, "opposite_lanes": 2, "taper_length": 60.0}})
    rm = composed.road_map
    traffic = urban_traffic(composed, counts={"car": 3}, config=QUIET)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    for row, (name, front, wish) in enumerate((("main_0", 201.3, TAKE_WAY), ("main_1", 199.5, TAKE_WAY),
                                               ("main_2", 199.5, YIELD))):
        traffic.place(row, [lane(rm, f"overtaking_road/{name}")], front - traffic.vehicles.length[row] / 2, 0.0,
                      desired_speed=8.0, intentions={"merge": wish})
    out = lane(rm, "overtaking_road/out_2")
    through: set[int] = set()

    def note():
        through.update(row for row in range(3) if traffic.vehicles.path[row, 0] == out)
        present = traffic.present
        assert not len(overlapping_pairs(traffic.poses()[present], traffic.half_size[present]))

    run(traffic, 30.0, note)
    assert through == {0, 1, 2}
