"""The compiled traffic kernels (mjdrive.traffic.kernels) give the numpy code's numbers bit for bit: at every
decision of real traffic (the roundabout with pedestrians, every urban map, the autopilot's own advice), and
over whole trajectories. (Without numba the kernels run as plain Python, slowly, and must agree all the same.)"""

from __future__ import annotations

import copy
import hashlib

import numpy as np
import pytest

import mjdrive.traffic.following as following
import mjdrive.traffic.lane_changes as lane_changes
import mjdrive.traffic.merges as merges
import mjdrive.traffic.model as model
from mjdrive import suite
from mjdrive.envs.gym_env import make_env
from mjdrive.policies import make_policy


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
    """Equal bit for bit: arrays (and their dtypes), plans, dicts, tuples, scalars."""
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
    """Copies of the traffic attributes `state` ("rng": its generator's state)."""
    return {name: copy.deepcopy(traffic.rng.bit_generator.state if name == "rng" else getattr(traffic, name))
            for name in state}


def _restore(traffic, saved: dict) -> None:
    for name, value in saved.items():
        if name == "rng":
            traffic.rng.bit_generator.state = value
        else:
            setattr(traffic, name, copy.deepcopy(value))


def _both_ways(monkeypatch, owner, name: str, flags, state: tuple[str, ...] = ()) -> list:
    """Replace `owner.name` (a function or method whose first argument is the Traffic) by one that runs it with
    `flags.KERNELS` False (numpy), then from the same state (the traffic's attributes `state`) with True (the
    kernels), and asserts the results and the states equal bit for bit. Returns the list of kernel results."""
    calls = []
    original = getattr(owner, name)

    def both(traffic, *args):
        saved = _snapshot(traffic, state)
        monkeypatch.setattr(flags, "KERNELS", False)
        expected = original(traffic, *args)
        expected_state = _snapshot(traffic, state)
        _restore(traffic, saved)
        monkeypatch.setattr(flags, "KERNELS", True)
        got = original(traffic, *args)
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
    """Every plan of poses."""
    return _both_ways(monkeypatch, model.Traffic, "_make_plan", model)


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
    env = make_env(domain, task, random=3)
    act = (lambda obs: np.array([0.0, 0.0, 1.0])) if policy == "brake" else make_policy(policy, env, 3)
    observation, _ = env.reset(seed=3)
    for _ in range(300 if domain == "urban" else 150):
        observation, _, terminated, truncated, _ = env.step(act(observation))
        if terminated or truncated:
            observation, _ = env.reset()
    assert len(plans) >= 40 and len(accelerations) >= 40 and len(contexts) >= 40
    assert sum(n > 1 for n in summaries) >= 40  # the traffic's own decisions
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
        t.lc_dist = rng.choice([0.0, 7.0, 1e9], t.nv)
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
