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


def _checked_accelerations(monkeypatch) -> list[int]:
    """Make every IDM acceleration (the traffic's and the autopilot's advice) run both ways and compare."""
    calls = []
    accelerations = following.accelerations

    def both(t, f, ctx):
        lead_gap = t.lead_gap.copy()
        monkeypatch.setattr(following, "KERNELS", False)
        expected, expected_lead_gap = accelerations(t, f, ctx), t.lead_gap.copy()
        t.lead_gap = lead_gap
        monkeypatch.setattr(following, "KERNELS", True)
        got = accelerations(t, f, ctx)
        assert np.array_equal(expected, got) and np.array_equal(expected_lead_gap, t.lead_gap)
        calls.append(len(f["rows"]))
        return got

    monkeypatch.setattr(model, "accelerations", both)
    return calls


def _checked_lane_changes(monkeypatch) -> list[int]:
    """Make every intended lane-change choice (urban) run both ways and compare the choice and the signals."""
    calls = []
    intended = lane_changes._intended

    def both(t, right, left, near_merge):
        signal = t.lc_signal.copy()
        monkeypatch.setattr(lane_changes, "KERNELS", False)
        expected, expected_signal = intended(t, right, left, near_merge), t.lc_signal.copy()
        t.lc_signal = signal
        monkeypatch.setattr(lane_changes, "KERNELS", True)
        got = intended(t, right, left, near_merge)
        assert expected == got and np.array_equal(expected_signal, t.lc_signal), (expected, got)
        calls.append(got is not None)
        return got

    monkeypatch.setattr(lane_changes, "_intended", both)
    return calls


def _checked_successors(monkeypatch) -> list[int]:
    """Make every choice of successors under urban rules run both ways (same draws) and compare the choice,
    the intentions and ring progress it updates."""
    calls = []
    choose = model.Traffic._choose_successor

    def both(self, lane, rows=None):
        saved = (copy.deepcopy(self.rng.bit_generator.state), self.intention.copy(), self.ring_passed.copy())
        monkeypatch.setattr(model, "KERNELS", False)
        expected = choose(self, lane, rows)
        after = (self.intention.copy(), self.ring_passed.copy())
        self.rng.bit_generator.state, self.intention, self.ring_passed = saved
        monkeypatch.setattr(model, "KERNELS", True)
        got = choose(self, lane, rows)
        assert np.array_equal(expected, got), (expected, got)
        assert np.array_equal(after[0], self.intention) and np.array_equal(after[1], self.ring_passed)
        calls.append(len(lane))
        return got

    monkeypatch.setattr(model.Traffic, "_choose_successor", both)
    return calls


def _checked_contexts(monkeypatch) -> list[int]:
    """Make every decision's lane-graph tables (and the autopilot's) run both ways and compare them."""
    calls = []
    context = model.Traffic._context

    def both(self):
        monkeypatch.setattr(model, "KERNELS", False)
        expected = context(self)
        monkeypatch.setattr(model, "KERNELS", True)
        got = context(self)
        assert expected.keys() == got.keys()
        for key in expected:
            assert expected[key].dtype == got[key].dtype and np.array_equal(expected[key], got[key]), key
        calls.append(1)
        return got

    monkeypatch.setattr(model.Traffic, "_context", both)
    return calls


def _checked_plans(monkeypatch) -> list[int]:
    """Make every plan of poses run both ways and compare them."""
    calls = []
    make_plan = model.Traffic._make_plan

    def both(self, start=None):
        monkeypatch.setattr(model, "KERNELS", False)
        expected = make_plan(self, start)
        monkeypatch.setattr(model, "KERNELS", True)
        got = make_plan(self, start)
        for name in ("pos", "quat", "yaw", "speed"):
            assert np.array_equal(getattr(expected, name), getattr(got, name)), name
        calls.append(1)
        return got

    monkeypatch.setattr(model.Traffic, "_make_plan", both)
    return calls


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
        assert any(changes)  # ... and lane changes chosen
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


def _random_states(task: str, trials: int, seed: int = 0):
    """A traffic of `task` after a while, then `trials` random edits of its state (positions along the lanes,
    speeds, waiting times, lane-change progress, intentions, signals): the kernels' branches, rare and common."""
    env = suite.load("urban", task, {"random": seed})
    env.reset()
    for _ in range(100):
        env.step(np.array([0.0, 0.0, 1.0]))
    t = env.task.traffic
    rng = np.random.default_rng(seed)
    lane_length = t.map.length[np.maximum(t.path[:, 0], 0)]
    base = {name: getattr(t, name).copy() for name in ("s", "v", "stopped_time", "lc_dist", "lc_signal", "intention")}
    table = t.approaches
    lane0 = np.maximum(t.path[:, 0], 0)
    for _ in range(trials):
        t.s = rng.uniform(0.0, 1.0, t.nv) * lane_length
        for row in rng.permutation(t.nv)[: t.nv // 2]:  # half of them near a give-way line of their lane
            stops = table.stop[table.lane == lane0[row]]
            if len(stops):
                front = rng.choice(stops) + rng.uniform(-8.0, 3.0)
                t.s[row] = np.clip(front - t.length[row] / 2, 0.0, lane_length[row])
        t.v = rng.choice([0.0, 0.5, 3.0, 9.0, 14.0], t.nv) * rng.uniform(0.8, 1.2, t.nv)
        t.stopped_time = rng.choice([0.0, 2.0, 3.0, 25.0], t.nv)
        t.lc_dist = rng.choice([0.0, 7.0, 1e9], t.nv)
        t.lc_signal = rng.choice([-1.0, t.time - 2.0, t.time], t.nv)
        t.intention = rng.integers(0, 3, t.intention.shape)
        t._refresh_vehicle_poses()
        t._obstacle_cache = None
        yield t
    for name, value in base.items():
        setattr(t, name, value)


def test_kernels_agree_on_random_states(monkeypatch):
    accelerations = _checked_accelerations(monkeypatch)
    changes, successors = _checked_lane_changes(monkeypatch), _checked_successors(monkeypatch)
    contexts = _checked_contexts(monkeypatch)
    for task in ("concatenated", "lane_change"):
        for t in _random_states(task, 300):
            model.accelerations(t, following.follower_table(t, t._context()), t._context())
            lane0 = np.maximum(t.path[:, 0], 0)
            lane_changes._intended(t, t.map.right[lane0], t.map.left[lane0], np.zeros(t.nv, dtype=bool))
            t._choose_successor(t.path[:, 1].copy(), np.arange(t.nv))
    assert len(accelerations) >= 600 and len(changes) >= 600  # the random states and the decisions before them
    assert sum(changes) >= 20  # lane changes chosen in some of the states
    assert len(successors) >= 600 and len(contexts) >= 1200
