"""Traffic: IDM following, no overlaps, yielding at the roundabout entry, crosswalks, the ego, determinism,
and no Python loop per road user."""

import sys

import numpy as np
import pytest

from mjdrive import roads
from mjdrive.tasks.roundabout import DENSITIES
from mjdrive.traffic import EgoState, Traffic, TrafficConfig, counts_to_kinds, overlapping_pairs

SUBSTEP = 0.02  # [s]
NO_RESPAWN = TrafficConfig(respawn=False, lane_change_rate=(0.0, 0.0))  # scenes: nobody enters or moves over


@pytest.fixture(scope="module")
def roundabout_map():
    return roads.roundabout(radius=14.0, arm_length=50.0, crosswalk_offset=6.0)


def _run(traffic, seconds, ego=None, each=None):
    for _ in range(int(round(seconds / SUBSTEP))):
        traffic.advance(SUBSTEP, ego)
        if each is not None:
            each(traffic)


def _front(traffic, row):
    """Front-bumper arc length [m] of vehicle `row` along its current lane."""
    return traffic.vehicles.s[row] + traffic.vehicles.length[row] / 2


def test_idm_keeps_the_safe_gap_behind_a_braking_leader():
    rm = roads.straight(length=400.0, two_way=False)
    lane = rm.lane_id("fwd_0")
    traffic = Traffic(rm, ["car", "car"], NO_RESPAWN)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    traffic.place(0, [lane], s=20.0, speed=8.0, desired_speed=8.33)  # follower
    traffic.place(1, [lane], s=60.0, speed=6.0, desired_speed=6.0)  # slower leader
    _run(traffic, 20.0)  # the follower catches up and settles into car following
    gap = traffic.poses()[1, 0] - traffic.poses()[0, 0] - 4.5
    assert 2.5 + 6.0 < gap < 12.0, gap  # about s0 + v T (IDM equilibrium)
    traffic.vehicles.v0[1] = 0.0  # the leader brakes as hard as it can (8 m/s^2) to a stop
    gaps = []
    _run(traffic, 10.0, each=lambda t: gaps.append(t.poses()[1, 0] - t.poses()[0, 0] - 4.5))
    assert traffic.vehicles.v[1] == 0.0 and traffic.vehicles.v[0] < 0.3  # both (nearly) stopped
    assert min(gaps) >= 2.5, min(gaps)


def test_leader_query_finds_the_nearest_vehicle_ahead_along_a_lane_path():
    """`Traffic.leader(path, s)`: the distance from the point to the nearest vehicle's rear bumper and its speed,
    across lane ends along the path; nobody ahead: (inf, 0)."""
    rm = roads.straight(length=400.0, two_way=False)
    lane = rm.lane_id("fwd_0")
    traffic = Traffic(rm, ["car", "car", "car"], NO_RESPAWN)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    traffic.place(0, [lane], s=50.0, speed=5.0)
    traffic.place(1, [lane], s=120.0, speed=7.0)
    half = traffic.vehicles.length[0] / 2  # [m] a car's half length
    assert traffic.leader([lane], 10.0) == (50.0 - half - 10.0, 5.0)
    assert traffic.leader([lane], 60.0) == (120.0 - half - 60.0, 7.0)  # the one behind the point does not count
    assert traffic.leader([lane], 200.0) == (np.inf, 0.0)
    chain = roads.concatenated(order=("crossroad",)).road_map
    first = next(i for i, lane in enumerate(chain.lanes) if chain.successors[i] and not lane.in_junction)
    after = chain.successors[first][0]
    traffic = Traffic(chain, ["car"], NO_RESPAWN)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    traffic.place(0, [after], s=3.0, speed=2.0)
    gap, speed = traffic.leader([first, after], chain.lanes[first].length - 4.0)
    assert gap == pytest.approx(4.0 + 3.0 - traffic.vehicles.length[0] / 2) and speed == 2.0


def test_no_overlaps_over_a_long_run_at_the_densest_level(roundabout_map):
    traffic = Traffic(roundabout_map, counts_to_kinds(DENSITIES["d210"]))
    # a stationary ego at the yield line of arm 0, as at the start of an episode
    entry = roundabout_map.lanes[roundabout_map.lane_id("arm0_in_0")]
    x, y = entry.position(entry.length - 0.5)
    ego = EgoState(x, y, entry.heading(entry.length), 0.0, 4.8, 1.83,
                   np.array([roundabout_map.lane_id(n) for n in ("arm0_in_0", "arm0_entry")]), entry.length - 0.5)
    traffic.reset(np.random.default_rng(0), ego)
    ego_box = np.array([[x, y, ego.yaw]]), np.array([[2.4, 0.92, 0.7]])
    worst = []

    def check(t):
        present = t.present
        poses = np.vstack([t.poses()[present], ego_box[0]])
        sizes = np.vstack([t.half_size[present], ego_box[1]])
        worst.append(len(overlapping_pairs(poses, sizes)))

    _run(traffic, 400.0, ego=lambda: ego, each=check)
    assert max(worst) == 0
    assert traffic.stats["spawned"] > 50 and traffic.stats["lane_changes"] >= 1  # traffic flowed
    assert traffic.pedestrians.walking.any() or (traffic.pedestrians.wait < 0).any()


def _roundabout_traffic(rm, kinds, seed=0):
    traffic = Traffic(rm, kinds, NO_RESPAWN)
    traffic.reset(np.random.default_rng(seed))
    traffic.remove_all()
    return traffic


def _entry_time(rm, circulating: bool) -> float:
    """Time [s] at which a car approaching arm 0 passes its yield line, with or without a circulating car
    arriving at the merge point about then; asserts it never went before that car had passed."""
    ids = {name: rm.lane_id(name) for name in ("arm0_in_0", "arm0_entry", "ring_1_0", "ring_1_1", "ring_1_7")}
    traffic = _roundabout_traffic(rm, ["car", "car"])
    traffic.place(0, [ids["arm0_in_0"], ids["arm0_entry"], ids["ring_1_1"]],
                  s=rm.lanes[ids["arm0_in_0"]].length - 12.0, speed=4.0)
    if circulating:  # reaches the merge point (the start of ring_1_1) in about 3 s
        traffic.place(1, [ids["ring_1_7"], ids["ring_1_0"], ids["ring_1_1"]], s=8.0, speed=5.0)
    stop = traffic.map.merges.stop[list(traffic.map.merges.lane).index(ids["arm0_entry"])]
    passed_line, crossed = [], []

    def watch(t):
        passed_line.append(t.vehicles.path[0, 0] == ids["arm0_entry"] and _front(t, 0) > stop + 0.3)
        # the circulating car's rear has passed the merge point, now or before
        v = t.vehicles
        crossed.append(not circulating or (crossed and crossed[-1])
                       or (v.path[1, 0] == ids["ring_1_1"] and v.s[1] - v.length[1] / 2 > 0.0))
        present = t.present
        assert not len(overlapping_pairs(t.poses()[present], t.half_size[present]))

    _run(traffic, 12.0, each=watch)
    first = passed_line.index(True)  # it entered eventually
    assert crossed[first], "the entering car went before the circulating one had passed"
    return first * SUBSTEP


def test_entering_vehicle_yields_to_a_circulating_one(roundabout_map):
    assert _entry_time(roundabout_map, True) > _entry_time(roundabout_map, False) + 1.0  # it waited


def test_vehicles_stop_for_a_pedestrian_on_the_crosswalk(roundabout_map):
    rm = roundabout_map
    traffic = _roundabout_traffic(rm, ["car", "pedestrian", "pedestrian", "pedestrian", "pedestrian"])
    lane = rm.lane_id("arm0_in_0")
    crossings = traffic.map.crossings
    k = int(np.flatnonzero(crossings.lane == lane)[0])
    crossing_s, crossing_u, cw = crossings.s[k], crossings.u[k], crossings.crosswalk[k]
    ped = int(np.flatnonzero(traffic.pedestrians.crosswalk == cw)[0])
    for other in range(traffic.np_):
        if other != ped:
            traffic.place_pedestrian(other, u=-10.0 * traffic.pedestrians.direction[other], direction=1.0,
                                     walking=False)
    # a slow pedestrian inside the lane's band, walking across it
    traffic.place_pedestrian(ped, u=crossing_u[0] + 0.5, direction=1.0, walking=True, speed=0.3)
    traffic.place(0, [lane], s=crossing_s[0] - 30.0, speed=7.0)
    fronts, speeds = [], []
    _run(traffic, 10.0, each=lambda t: (fronts.append(_front(t, 0)), speeds.append(t.vehicles.v[0])))
    assert min(speeds) < 0.1  # it stopped ...
    assert max(fronts) < crossing_s[0] - 0.5  # ... before the crosswalk, and stayed there
    traffic.place_pedestrian(ped, u=20.0, direction=1.0, walking=False)  # the pedestrian has gone
    _run(traffic, 6.0)
    v = traffic.vehicles
    assert v.v[0] > 2.0 and (v.path[0, 0] != lane or _front(traffic, 0) > crossing_s[1])  # on


@pytest.mark.parametrize("on_lane", [True, False])
def test_vehicles_brake_for_the_ego_ahead(on_lane):
    rm = roads.straight(length=400.0, two_way=False)
    lane = rm.lane_id("fwd_0")
    traffic = Traffic(rm, ["car"], NO_RESPAWN)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    traffic.place(0, [lane], s=30.0, speed=8.0)
    ego = EgoState(120.0, 0.0, 0.0, 0.0, 4.8, 1.83, np.array([lane]) if on_lane else None, 120.0)
    _run(traffic, 25.0, ego=lambda: ego)
    gap = 120.0 - 2.4 - traffic.poses()[0, 0] - 2.25
    assert traffic.vehicles.v[0] < 0.05 and 1.5 < gap < 8.0, gap


def test_reckless_ego_still_hits_traffic():
    """Traffic reacts to the ego but is kinematic: an ego cutting in right in front of a car is hit."""
    rm = roads.straight(length=400.0, two_way=False)
    lane = rm.lane_id("fwd_0")
    traffic = Traffic(rm, ["car"], NO_RESPAWN)
    traffic.reset(np.random.default_rng(0))
    traffic.remove_all()
    traffic.place(0, [lane], s=30.0, speed=8.0)
    ego = EgoState(36.5, 0.0, 0.0, 0.0, 4.8, 1.83, None, 0.0)  # appears 2 m ahead of the car's bumper
    boxes = []
    _run(traffic, 1.0, ego=lambda: ego, each=lambda t: boxes.append(len(overlapping_pairs(
        np.vstack([t.poses(), [[36.5, 0.0, 0.0]]]), np.vstack([t.half_size, [[2.4, 0.92, 0.7]]])))))
    assert max(boxes) == 1


def _trajectory(rm, seed, seconds=20.0):
    traffic = Traffic(rm, counts_to_kinds(DENSITIES["d160"]))
    traffic.reset(np.random.default_rng(seed), warmup=2.0)
    poses = []
    _run(traffic, seconds, each=lambda t: poses.append(t.poses().copy()))
    return np.array(poses)


def test_same_seed_same_traffic_bit_for_bit(roundabout_map):
    a, b = _trajectory(roundabout_map, 7), _trajectory(roundabout_map, 7)
    c = _trajectory(roundabout_map, 8)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_poses_move_smoothly_every_substep(roundabout_map):
    """Poses change every 0.02 s and by at most a little (no jumps between decisions)."""
    traffic = Traffic(roundabout_map, counts_to_kinds(DENSITIES["d120"]))
    traffic.reset(np.random.default_rng(3), warmup=2.0)
    previous, steps = traffic.poses().copy(), []
    present, generation = traffic.present.copy(), traffic.generation.copy()

    def record(t):
        nonlocal previous, present, generation
        now = t.poses().copy()
        keep = present & t.present & (generation == t.generation)  # skip users that left or (re)entered
        steps.append(np.hypot(*(now[keep, :2] - previous[keep, :2]).T).max())
        previous, present, generation = now, t.present.copy(), t.generation.copy()

    _run(traffic, 10.0, each=record)
    assert max(steps) < 10.0 * SUBSTEP + 0.05  # below ~10 m/s x 0.02 s
    assert np.mean(np.array(steps) > 0) > 0.95  # something moves every substep


def _python_lines(kinds, rm, decisions=20):
    """Python line events inside mjdrive/traffic*.py while traffic runs `decisions` decision periods."""
    traffic = Traffic(rm, kinds)
    traffic.reset(np.random.default_rng(0), warmup=2.0)
    count = 0

    def tracer(frame, event, arg):
        nonlocal count
        if "mjdrive/traffic" not in frame.f_code.co_filename:
            return None
        if event == "line":
            count += 1
        return tracer

    steps = int(round(decisions * traffic.config.decision_period / SUBSTEP))
    sys.settrace(tracer)
    try:
        _run(traffic, steps * SUBSTEP)
    finally:
        sys.settrace(None)
    return count


def test_traffic_step_has_no_python_loop_per_road_user(roundabout_map):
    """The Python work per step is the same for 10 and 60 road users (numpy does the rest)."""
    few = _python_lines(counts_to_kinds({"car": 8, "pedestrian": 2}), roundabout_map)
    many = _python_lines(counts_to_kinds({"car": 40, "motorcycle": 6, "bicycle": 6, "pedestrian": 8}),
                         roundabout_map)
    assert many < 1.5 * few, (few, many)


def test_uniform_draws_are_generator_uniform():
    """`spawning.uniform` (the spawns' and pedestrians' draws) gives `Generator.uniform`'s numbers and leaves the
    generator in the same state: scalar and per-element bounds, one to many draws, empty ranges."""
    from mjdrive.traffic.spawning import uniform

    bounds = np.random.default_rng(7)
    for seed in range(50):
        n = 1 + seed % 9
        low = bounds.uniform(-5.0, 5.0, n)
        high = low + bounds.uniform(0.0, 4.0, n) * (seed % 5 > 0)  # every fifth: high == low
        for lo, hi in ((low, high), (float(low[0]), float(high[0])), (0.5, 2.5)):
            expected, got = np.random.default_rng(seed), np.random.default_rng(seed)
            want = expected.uniform(lo, hi) if np.ndim(lo) else expected.uniform(lo, hi, n)
            assert np.array_equal(uniform(got, lo, hi, n), want)
            assert got.bit_generator.state == expected.bit_generator.state


def test_advance_writes_each_substep_pose_into_the_data_given():
    """Every `advance` writes the new poses into the MjData it is given, whichever (kept views are per data),
    at plan substeps and at decisions alike, as `write` does."""
    import mujoco

    from mjdrive import suite

    env = suite.load("roundabout", "d120", {"random": 1})
    env.reset()
    traffic, model = env.task.traffic, env.physics.raw_model
    datas = [mujoco.MjData(model), mujoco.MjData(model)]
    decisions = 0
    for i in range(3 * traffic.n_plan + 5):
        data = datas[(i // 4) % 2]  # four substeps into one, then four into the other
        k = traffic.cursor().k
        traffic.advance(SUBSTEP, None, data)
        decisions += traffic.cursor().k < k
        expected = mujoco.MjData(model)
        traffic.write(expected)
        assert np.array_equal(data.mocap_pos, expected.mocap_pos), i
        assert np.array_equal(data.mocap_quat, expected.mocap_quat), i
        assert np.abs(data.mocap_pos - datas[1 - (i // 4) % 2].mocap_pos).max() > 0.0  # the other data is older
    assert decisions >= 3
