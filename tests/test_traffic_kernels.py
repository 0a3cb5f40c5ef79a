"""The compiled traffic kernels (mjdrive.traffic.kernels) give the numpy code's numbers bit for bit: at every
decision of real traffic (the roundabout with pedestrians, every urban map, the autopilot's own advice), and
over whole trajectories. (Without numba the kernels run as plain Python, slowly, and must agree all the same.)"""

from __future__ import annotations

import copy
import hashlib
import math
import subprocess
import sys

import numpy as np
import pytest

import mjdrive.traffic.following as following
import mjdrive.traffic.lane_changes as lane_changes
import mjdrive.traffic.lanes as lanes
import mjdrive.traffic.merges as merges
import mjdrive.traffic.model as model
import mjdrive.traffic.pedestrians as pedestrians
import mjdrive.traffic.spawning as spawning
from mjdrive import roads, suite
from mjdrive.envs.gym_env import make_env
from mjdrive.policies import make_policy
from mjdrive.traffic import kernels


def _checked_summaries(monkeypatch) -> list[int]:
    """Make every gap summary run both ways and compare them; returns a list that counts the comparisons."""
    calls = []
    kernel = following.gap_summary_kernel

    def both(t, f, ctx, kappa, den):
        expected = following.gap_summary(t, f, ctx, kappa, den)
        got = kernel(t, f, ctx, kappa, den)
        for name, e, g in zip(("lead_gap", "interaction", "room", "to_give_way"), expected, got, strict=True):
            assert e.dtype == g.dtype and np.array_equal(e, g), (name, e, g)
        calls.append(len(f["rows"]))
        return got

    monkeypatch.setattr(following, "gap_summary_kernel", both)
    monkeypatch.setattr(following, "KERNELS", True)  # the kernel's path even without numba (plain Python then)
    return calls


def _assert_same(expected, got, where: str = "") -> None:
    """Equal: arrays (and their dtypes), plans, dicts, tuples, scalars, value for value (a zero's sign aside: numpy's
    vectorised minimum and maximum return either zero of a tie, as the CPU's instructions do)."""
    if isinstance(expected, np.ndarray):
        assert isinstance(got, np.ndarray) and expected.dtype == got.dtype and np.array_equal(expected, got), where
    elif isinstance(expected, dict):
        assert expected.keys() == got.keys(), where
        for key in expected:
            _assert_same(expected[key], got[key], f"{where}.{key}")
    elif isinstance(expected, tuple | list):
        assert len(expected) == len(got), where
        for k, (e, g) in enumerate(zip(expected, got, strict=True)):
            _assert_same(e, g, f"{where}[{k}]")
    elif isinstance(expected, model._Plan):
        _assert_same(vars(expected), vars(got), where)
    else:
        assert expected == got, (where, expected, got)


def _snapshot(traffic, state: tuple[str, ...]) -> dict:
    """Copies of the traffic attributes `state` (random generators: their states)."""
    return {name: copy.deepcopy(getattr(traffic, name).bit_generator.state if name.endswith("rng")
                                else getattr(traffic, name)) for name in state}


def _restore(traffic, saved: dict) -> None:
    for name, value in saved.items():
        if name.endswith("rng"):
            getattr(traffic, name).bit_generator.state = value
        else:
            setattr(traffic, name, copy.deepcopy(value))


def _both_ways(monkeypatch, owner, name: str, flags, state: tuple[str, ...] = ()) -> list:
    """Replace `owner.name` (a function or method whose first argument is the Traffic) by one that runs it with
    `flags.KERNELS` False (numpy), then from the same state (the traffic's attributes `state`) with True (the
    kernels), and asserts the results and the states equal bit for bit. Returns the list of kernel results."""
    calls = []
    original = getattr(owner, name)

    def both(traffic, *args):
        saved, before = _snapshot(traffic, state), flags.KERNELS
        monkeypatch.setattr(flags, "KERNELS", False)
        expected = original(traffic, *args)
        expected_state = _snapshot(traffic, state)
        _restore(traffic, saved)
        monkeypatch.setattr(flags, "KERNELS", True)
        got = original(traffic, *args)
        monkeypatch.setattr(flags, "KERNELS", before)  # as the caller runs (a wrapped function may call another)
        _assert_same(expected, got, name)
        _assert_same(expected_state, _snapshot(traffic, state), f"{name} state")
        calls.append(got)
        return got

    monkeypatch.setattr(owner, name, both)
    return calls


def _checked_accelerations(monkeypatch) -> list:
    """Every IDM acceleration (the traffic's and the autopilot's advice), and the leaders' gaps it keeps."""
    return _both_ways(monkeypatch, model, "accelerations", following, ("lead_gap",))


def _checked_lane_changes(monkeypatch) -> list:
    """Every intended lane-change choice (urban), and the signals it updates."""
    return _both_ways(monkeypatch, lane_changes, "_intended", lane_changes, ("lc_signal",))


def _checked_successors(monkeypatch) -> list:
    """Every choice of successors under urban rules (the same draws), the intentions and ring progress it updates."""
    return _both_ways(monkeypatch, model.Traffic, "_choose_successor", model, ("rng", "intention", "ring_passed"))


def _checked_contexts(monkeypatch) -> list:
    """Every decision's lane-graph tables (and the autopilot's)."""
    return _both_ways(monkeypatch, model.Traffic, "_context", model)


def _checked_plans(monkeypatch) -> list:
    """Every plan of poses (pedestrians' included)."""
    return _both_ways(monkeypatch, model.Traffic, "_make_plan", model)


VEHICLE_STATE = ("active", "path", "s", "v", "v0", "d_pref", "lc_shift", "lc_dist", "lc_changing", "lc_signal",
                 "accel", "intention", "ring_passed", "generation", "stats", "rng", "intent_rng")


COMMITTED_STATE = ("_plan", "_current_pos", "_current_yaw", "_current_speed", "_current_quat", "ped_u", "ped_walking",
                   "ped_dir", "ped_wait")


def _checked_bookkeeping(monkeypatch) -> dict[str, list]:
    """Every decision's bookkeeping (`state_kernels`): lanes passed, spawns, lane changes, the corridor's
    obstacles, occupied crossings, curve speeds, vehicle poses and path starts, with the state they leave."""
    return {
        "advance": _both_ways(monkeypatch, model.Traffic, "_advance_lanes", model, VEHICLE_STATE),
        "waiting": _both_ways(monkeypatch, model.Traffic, "_count_waiting", model, ("stopped_time",)),
        "spawn": _both_ways(monkeypatch, model, "spawn", spawning, VEHICLE_STATE),
        "activate": _both_ways(monkeypatch, spawning, "activate", spawning, VEHICLE_STATE),
        "lane_changes": _both_ways(monkeypatch, model, "lane_changes", lane_changes, VEHICLE_STATE),
        "options": _both_ways(monkeypatch, lane_changes, "_options", lane_changes),
        "finish": _both_ways(monkeypatch, lane_changes, "_finish_intended", lane_changes,
                             ("intention", "lc_signal", "lc_changing")),
        "candidates": _both_ways(monkeypatch, lane_changes, "_candidates", lane_changes),
        "room": _both_ways(monkeypatch, lane_changes, "_room", lane_changes),
        "obstacles": _both_ways(monkeypatch, following, "obstacles", following, ("_obstacle_cache",)),
        "crossings": _both_ways(monkeypatch, following, "occupied_crossings", pedestrians),
        "pedestrians": _both_ways(monkeypatch, model, "pedestrian_starts", pedestrians, ("ped_walking",)),
        "curve_speed": _both_ways(monkeypatch, lanes.TrafficMap, "curve_speed", lanes),
        "poses": _both_ways(monkeypatch, model.Traffic, "_vehicle_poses", model),
        "starts": _both_ways(monkeypatch, model.Traffic, "_path_starts", model),
        "centre": _both_ways(monkeypatch, model.Traffic, "_centre_poses", model),
        "commit": _both_ways(monkeypatch, model.Traffic, "_commit", model, VEHICLE_STATE + COMMITTED_STATE),
        "walkers": _both_ways(monkeypatch, model, "commit_pedestrians", pedestrians, COMMITTED_STATE + ("rng",)),
    }


@pytest.mark.parametrize("domain, task, policy", [
    ("roundabout", "d210", "brake"),  # pedestrians, crosswalks, roundabout merges
    ("urban", "concatenated", "autopilot"),  # every conflict zone; the autopilot's advice (one follower)
    ("urban", "merge", "always_go"),
    ("urban", "lane_change", "brake"),  # intended lane changes on the two-lane road
])
def test_kernels_give_the_numpy_numbers_at_every_decision(monkeypatch, domain, task, policy):
    summaries, plans = _checked_summaries(monkeypatch), _checked_plans(monkeypatch)
    accelerations, changes = _checked_accelerations(monkeypatch), _checked_lane_changes(monkeypatch)
    successors, contexts = _checked_successors(monkeypatch), _checked_contexts(monkeypatch)
    bookkeeping = _checked_bookkeeping(monkeypatch)
    env = make_env(domain, task, random=3)
    act = (lambda obs: np.array([0.0, 0.0, 1.0])) if policy == "brake" else make_policy(policy, env, 3)
    observation, _ = env.reset(seed=3)
    for _ in range(300 if domain == "urban" else 150):
        observation, _, terminated, truncated, _ = env.step(act(observation))
        if terminated or truncated:
            observation, _ = env.reset()
    assert len(plans) >= 40 and len(accelerations) >= 40 and len(contexts) >= 40
    assert sum(n > 1 for n in summaries) >= 40  # the traffic's own decisions
    for name in ("advance", "spawn", "lane_changes", "options", "obstacles", "curve_speed", "commit"):
        assert len(bookkeeping[name]) >= 40, name
    if domain == "urban":
        assert len(bookkeeping["finish"]) >= 40 and len(bookkeeping["waiting"]) >= 40
    if domain == "roundabout":  # random lane changes
        assert len(bookkeeping["candidates"]) >= 40 and any(len(rows) for rows in bookkeeping["candidates"])
    if domain == "roundabout" or task == "lane_change":  # room in the target lane, or not; someone behind, or not
        assert {(room, behind >= 0) for room, behind, _ in bookkeeping["room"]} >= {(True, True), (False, False)}
    assert any(bookkeeping["spawn"]) and len(bookkeeping["poses"]) >= 1 and len(bookkeeping["starts"]) >= 1
    if domain == "roundabout":
        assert len(bookkeeping["crossings"]) >= 40 and any(c.any() for c in bookkeeping["crossings"])
        assert len(bookkeeping["pedestrians"]) >= 40 and len(bookkeeping["walkers"]) >= 40
    if domain == "urban":
        assert len(changes) >= 40 and len(successors) >= 5  # the signals at every decision, paths that go on
    if task == "lane_change":
        assert any(change is not None for change in changes)  # ... and lane changes chosen
    if policy == "autopilot":
        assert sum(n == 1 for n in summaries) >= 100  # the autopilot's advice, every control step


def _trajectory_hash(domain: str, task: str, steps: int) -> str:
    env = suite.load(domain, task, {"random": 1})
    env.reset()
    digest = hashlib.sha256()
    for i in range(steps):
        timestep = env.step(np.array([0.4, 0.02, 0.0]) if i % 40 < 25 else np.array([0.0, 0.0, 1.0]))
        digest.update(env.task.traffic.poses().tobytes())
        digest.update(env.physics.data.qpos.tobytes())
        if timestep.last():
            env.reset()
    return digest.hexdigest()


@pytest.mark.parametrize("domain, task", [("roundabout", "d120"), ("urban", "crossroad")])
def test_same_trajectories_with_and_without_kernels(monkeypatch, domain, task):
    with_kernels = _trajectory_hash(domain, task, 200)
    monkeypatch.setattr(following, "KERNELS", False)
    monkeypatch.setattr(model, "KERNELS", False)
    monkeypatch.setattr(lane_changes, "KERNELS", False)
    without = _trajectory_hash(domain, task, 200)
    assert with_kernels == without


def _random_states(name: str, trials: int, seed: int = 0):
    """A traffic of `task` after a while, then `trials` random edits of its state (positions along the lanes,
    speeds, waiting times, lane-change progress, intentions, signals): the kernels' branches, rare and common."""
    domain, task = name.split("/")
    env = suite.load(domain, task, {"random": seed})
    env.reset()
    for _ in range(100):
        env.step(np.array([0.0, 0.0, 1.0]))
    t = env.task.traffic
    rng = np.random.default_rng(seed)
    lane_length = t.map.length[np.maximum(t.path[:, 0], 0)]
    base = {name: getattr(t, name).copy()
            for name in ("s", "v", "stopped_time", "lc_dist", "lc_signal", "intention", "active")}
    base_active = t.active.copy()
    # give-way lines (urban) or yield lines (roundabout entries): (lane, front-bumper position [m])
    lines = ((t.approaches.lane, t.approaches.stop) if t.approaches is not None
             else (t.map.yield_lane, t.map.yield_stop))
    lane0 = np.maximum(t.path[:, 0], 0)
    for _ in range(trials):
        t.s = rng.uniform(0.0, 1.0, t.nv) * lane_length
        for row in rng.permutation(t.nv)[: t.nv // 2]:  # half of them near a give-way line of their lane
            stops = lines[1][lines[0] == lane0[row]]
            if len(stops):
                front = rng.choice(stops) + rng.uniform(-8.0, 3.0)
                t.s[row] = np.clip(front - t.length[row] / 2, 0.0, lane_length[row])
        t.v = rng.choice([0.0, 0.5, 3.0, 9.0, 14.0], t.nv) * rng.uniform(0.8, 1.2, t.nv)
        t.stopped_time = rng.choice([0.0, 2.0, 3.0, 25.0], t.nv)
        t.lc_dist = rng.choice([0.0, 7.0, 12.0, 15.0, 1e9], t.nv)  # [m] (lane_change_length: 15 m)
        t.lc_signal = rng.choice([-1.0, t.time - 2.0, t.time], t.nv)
        t.intention = rng.integers(0, 3, t.intention.shape)
        if rng.random() < 0.5:  # sparse traffic: gaps open and close at merges and crossings
            t.active = base_active & (rng.random(t.nv) < 0.3)
        else:
            t.active = base_active.copy()
        t._refresh_vehicle_poses()
        t._obstacle_cache = None
        yield t
    for name, value in base.items():
        setattr(t, name, value)


def test_kernels_agree_on_random_states(monkeypatch):
    accelerations = _checked_accelerations(monkeypatch)
    changes, successors = _checked_lane_changes(monkeypatch), _checked_successors(monkeypatch)
    contexts = _checked_contexts(monkeypatch)
    for name in ("urban/concatenated", "urban/lane_change", "roundabout/d210"):
        for t in _random_states(name, 300):
            model.accelerations(t, following.follower_table(t, t._context()), t._context())
            lane0 = np.maximum(t.path[:, 0], 0)
            if t.urban:
                lane_changes._intended(t, t.map.right[lane0], t.map.left[lane0], np.zeros(t.nv, dtype=bool))
                t._choose_successor(t.path[:, 1].copy(), np.arange(t.nv))
    assert len(accelerations) >= 900 and len(changes) >= 600  # the random states and the decisions before them
    assert sum(change is not None for change in changes) >= 20  # lane changes chosen in some of the states
    assert len(successors) >= 600 and len(contexts) >= 1800


def test_roundabout_merge_state_agrees_in_sparse_traffic():
    """The roundabout entries' gap check in the kernel (`kernels.merge_state`) against the numpy code, with a
    few vehicles only, so that gaps open and close: conflicts and commitments both ways, bit for bit."""
    seen = set()
    for t in _random_states("roundabout/d210", 200, seed=2):
        t.active &= np.random.default_rng(len(seen) + int(t.s.sum())).random(t.nv) < 0.1
        t._refresh_vehicle_poses()
        ctx = t._context()
        conflict, committed = following._merge_state(t, ctx, t.config.accept_gap)
        m = t.map
        assert np.array_equal(conflict, merges.merge_conflicts(t, ctx, t.config.accept_gap))
        on_entry = ctx["lane"][:, None] == m.yield_lane[None]
        past = (ctx["s"] + ctx["length"] / 2)[:, None] - m.yield_stop[None]
        expected = (on_entry & ((past > 1.0) | ((past > 0.5) & (ctx["v"] >= 1.0)[:, None]))).any(axis=0)
        assert np.array_equal(committed, expected)
        seen |= {("conflict", bool(c)) for c in conflict} | {("committed", bool(c)) for c in committed}
    assert seen == {("conflict", True), ("conflict", False), ("committed", True), ("committed", False)}


def test_bookkeeping_kernels_agree_on_random_states(monkeypatch):
    """Lanes passed (some vehicles far past their lane's end), spawns into sparse traffic, lane changes, obstacles,
    crossings, curve speeds (also off the lane's ends) and poses, both ways from random states."""
    checked, accelerations = _checked_bookkeeping(monkeypatch), _checked_accelerations(monkeypatch)
    rng = np.random.default_rng(5)
    for name in ("urban/concatenated", "urban/lane_change", "roundabout/d210"):
        for t in _random_states(name, 150, seed=1):
            saved = _snapshot(t, (*VEHICLE_STATE, "_current_pos", "_current_yaw", "_current_speed", "ped_walking",
                                  "ped_wait"))
            t._obstacle_cache = None
            following.obstacles(t)
            if t.np_:
                following.occupied_crossings(t)
                t.ped_walking = rng.random(t.np_) < 0.3
                t.ped_wait = rng.choice([-1.0, 0.0, 2.0], t.np_)
                model.pedestrian_starts(t, t._context())
            lane0 = np.maximum(t.path[:, 0], 0)
            t.map.curve_speed(lane0, t.s * rng.uniform(-0.2, 1.5, t.nv))
            t._vehicle_poses(np.zeros((1, t.nv)))
            t._path_starts()
            # along each vehicle's lane from vertex to vertex (the segment search's ties), and on
            m = t.map
            vertex = np.minimum(m.first[lane0][None] + np.arange(12)[:, None], m.last_segment[lane0][None] + 1)
            ds = np.maximum(m.g[vertex] - m.base[lane0][None] - t.s[None], 0.0)
            t._centre_poses(np.vstack([ds, ds[-1] + np.arange(1, 20)[:, None] * 4.0]))
            ctx = t._context()
            t.v0 = rng.choice([0.0, 0.05, 0.15, 8.0], t.nv)  # desired speeds near IDM's floor (0.1 m/s) too
            model.accelerations(t, following.follower_table(t, ctx), ctx)
            for _ in range(8):  # a lane change's room: any vehicle, any lane and the one after it, anywhere on it
                target = int(rng.integers(t.map.n_lanes))
                after = int(t.map.successors[target, 0])
                if after >= 0:
                    s_new = rng.uniform(0.0, t.map.length[target])
                    lane_changes._room(t, int(rng.integers(t.nv)), s_new, target, after, ctx)
            for _ in range(3):  # every lane, near its end (merges, exits) or past it
                t.path[:, 0] = rng.integers(0, t.map.n_lanes, t.nv)
                t.s = t.map.length[t.path[:, 0]] - rng.uniform(-1.0, 20.0, t.nv)
                lane_changes._options(t)
                t.map.curve_speed(t.path[:, 0], t.s)
            _restore(t, saved)
            t.s = t.s + rng.choice([0.0, 0.0, 30.0, 80.0], t.nv)  # past the lane's end, or the next one's
            t._advance_lanes()
            if t.urban:
                t._count_waiting()
            model.spawn(t)
            model.lane_changes(t)
            _restore(t, saved)
    assert all(len(checked[name]) >= 450 for name in ("advance", "spawn", "lane_changes", "curve_speed"))
    assert sum(checked["spawn"]) >= 20 and len(accelerations) >= 450
    assert {(room, behind >= 0) for room, behind, _ in checked["room"]} == {(True, True), (True, False), (False, False)}
    assert all(len(checked[name]) >= 150 for name in ("crossings", "pedestrians", "candidates", "centre"))


@pytest.mark.parametrize("road_map", [roads.concatenated().road_map, roads.roundabout()], ids=["urban", "roundabout"])
def test_segment_search_within_a_lane_is_numpys_search(road_map):
    """`kernels._find_segment` (a lane's own vertices) gives `TrafficMap._segment`'s index (a search of every
    vertex, clamped to the lane): at the vertices, between them, off both ends of the lane, and NaN."""
    m = lanes.TrafficMap(road_map)
    assert np.all(np.diff(m.g) >= 0)  # the searches need the flat arc lengths sorted
    rng = np.random.default_rng(0)
    for lane in range(m.n_lanes):
        vertices = m.g[m.first[lane]: m.last_segment[lane] + 2]
        gq = np.concatenate([vertices, np.nextafter(vertices, -np.inf), np.nextafter(vertices, np.inf),
                             rng.uniform(vertices[0] - 2.0, vertices[-1] + 2.0, 20), [np.nan, -np.inf, np.inf]])
        expected = np.minimum(np.maximum(np.searchsorted(m.g, gq, side="right") - 1, m.first[lane]),
                              m.last_segment[lane])
        got = [kernels._find_segment(m.g, q, m.first[lane], m.last_segment[lane]) for q in gq]
        assert np.array_equal(expected, got), lane


def test_compile_kernels_compiles_every_traffic_kernel():
    """`mjdrive.traffic.compile_kernels.compile_kernels` runs every kernel (a fresh process: none compiled before)."""
    code = ("from mjdrive.traffic.compile_kernels import compile_kernels, uncompiled; "
            "compile_kernels(); print(uncompiled())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip().splitlines()[-1] == "[]"


def test_desired_speed_ratio_is_numpys():
    """`kernels.desired_speed`'s speed ratio v / max(v0, 0.1), whose numpy power enters IDM, bit for bit, also
    for desired speeds at and below IDM's floor."""
    t = next(_random_states("roundabout/d210", 1))
    rng = np.random.default_rng(3)
    ctx = t._context()
    f = following.follower_table(t, ctx)
    for _ in range(50):
        v0_own, v = rng.choice([0.0, 0.05, 0.1, 0.15, 0.3, 8.0], t.nv), rng.uniform(0.0, 0.5, t.nv)
        m = t.map
        v0, ratio = kernels.desired_speed(f["path"], f["offset"], f["s"], f["length"], v0_own, np.full(t.nv, 30.0),
                                          np.full(t.nv, np.inf), m.length, m.entry_speed, m.speed_limit,
                                          m.anticipation, m.yield_lane, m.yield_stop, t.config.yield_speed, v)
        assert np.array_equal(ratio, v / np.maximum(v0, 0.1)) and np.any(v0 < 0.2)


def test_numpys_float64_sine_and_cosine_are_libms():
    """The kernels compute sines and cosines with libm (`math`), the numpy code with numpy: the same bits only while
    numpy's float64 sin and cos call libm (numpy >= 1.25 has no vectorised version of them). Headings, their halves
    and far angles, in arrays of every length a plan has (a vectorised loop would differ on some)."""
    rng = np.random.default_rng(0)
    for n in (1, 3, 8, 17, 64, 960, 4096):
        x = np.concatenate([rng.uniform(-2 * np.pi, 2 * np.pi, n), rng.uniform(-1e3, 1e3, n), [0.0, -0.0, np.pi]])
        for ours, theirs in ((np.sin, math.sin), (np.cos, math.cos)):
            expected = np.array([theirs(v) for v in x])
            assert ours(x).tobytes() == expected.tobytes(), (ours.__name__, n)
            assert ours(0.5 * x).tobytes() == np.array([theirs(0.5 * v) for v in x]).tobytes(), (ours.__name__, n)
