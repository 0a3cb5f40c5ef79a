"""The compiled physics chunks (mjdrive.tasks.chunks) give the Python loop's trajectories bit for bit: physics,
traffic poses and state, contacts and episode info, through decisions, collisions and resets, with chunks that
are one traffic substep and with chunks that are not."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mjdrive import suite
from mjdrive.compiled import KERNELS
from mjdrive.tasks import chunks

pytestmark = pytest.mark.skipif(not KERNELS, reason="the compiled chunks need numba (the `fast` extra)")


def _trace(env, steps: int, actions: np.ndarray) -> tuple[list, dict]:
    """Per step: qpos, qvel, mocap poses, reward, the traffic's state; and counts of what happened."""
    out, seen = [], {"collisions": 0, "resets": 0}
    for i in range(steps):
        ts = env.step(actions[i])
        data = env.physics.data
        row = [data.qpos.copy(), data.qvel.copy(), data.mocap_pos.copy(), data.mocap_quat.copy(), ts.reward,
               env.task.info.get("collision"), env.task.collision_sensor.last_other_geom]
        traffic = getattr(env.task, "traffic", None)
        if traffic is not None:
            row += [traffic.poses(), traffic.speeds(), traffic.time, traffic._k, traffic._accumulated]
        out.append(row)
        seen["collisions"] += bool(env.task.info.get("collision"))
        if ts.last():
            seen["resets"] += 1
            env.reset()
    return out, seen


def _same(a: list, b: list) -> None:
    for i, (row_a, row_b) in enumerate(zip(a, b, strict=True)):
        for j, (x, y) in enumerate(zip(row_a, row_b, strict=True)):
            assert np.array_equal(np.asarray(x), np.asarray(y)), f"step {i}, field {j}: {x} != {y}"


@pytest.mark.parametrize("domain, task, kwargs, steps", [
    ("roundabout", "d210", {}, 260),  # dense traffic: decisions every 3 steps, collisions at full throttle
    ("urban", "concatenated", {}, 240),
    ("waypoints", "straight", {}, 200),  # no traffic: the contact checks alone
    ("roundabout", "d120", {"physics_dt": 0.008}, 160),  # chunks of 0.016 s: 0 or 1 traffic substep each
])
def test_compiled_chunks_give_the_python_loops_trajectory(domain, task, kwargs, steps):
    rng = np.random.default_rng(7)
    actions = np.column_stack([rng.uniform(0.5, 1.0, steps), rng.uniform(-0.3, 0.3, steps), np.zeros(steps)])
    compiled = suite.load(domain, task, {"random": 3, **kwargs})
    python = suite.load(domain, task, {"random": 3, **kwargs})
    python.physics.python_chunks = True  # `step_in_chunks` with the task's callback
    compiled.reset()
    python.reset()
    assert isinstance(compiled.physics.substep_runner, chunks.ChunkRunner)
    trace_c, seen_c = _trace(compiled, steps, actions)
    trace_p, seen_p = _trace(python, steps, actions)
    assert seen_c == seen_p
    _same(trace_c, trace_p)
    if domain == "roundabout" and not kwargs:
        assert seen_c["collisions"] >= 1 and seen_c["resets"] >= 1  # the contact hand-back and resets ran


def test_runner_hands_back_the_chunks_that_need_the_callback(monkeypatch):
    """On d210 a decision is due every 0.6 s (3 control steps): the kernel hands back one chunk per decision
    and steps every other chunk itself."""
    env = suite.load("roundabout", "d210", {"random": 0})
    env.reset()
    statuses = []
    kernel = chunks.run_chunks

    def counted(*args):
        result = kernel(*args)
        statuses.append(result[1])
        return result

    traffic, decisions = env.task.traffic, []
    decide = traffic._decide
    monkeypatch.setattr(chunks, "run_chunks", counted)
    monkeypatch.setattr(traffic, "_decide", lambda: (decisions.append(traffic.time), decide()))
    hold = np.array([0.0, 0.0, 1.0])
    for _ in range(30):
        env.step(hold)
    assert statuses.count(chunks.DONE) == 30  # each control step ends in the kernel
    assert len(decisions) in (9, 10)  # 300 chunks of 0.02 s, a decision every 0.6 s
    # handed back for those only, but the episode's first: no plan yet, that chunk runs in Python
    assert decisions[0] == 0.0 and statuses.count(chunks.CALLBACK) == len(decisions) - 1


def test_kernels_mj_step_is_mujocos():
    """`run_chunks` without contacts or traffic is `mj_step` n times: the same state as the bindings'."""
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom size=".1"/></body></worldbody></mujoco>')
    ours, theirs = mujoco.MjData(model), mujoco.MjData(model)
    ours.qvel[:3] = theirs.qvel[:3] = (1.0, -0.5, 2.0)
    address = chunks.mj_step_address()
    assert address
    empty = np.zeros(1)
    done, status, _, _, _, _ = chunks.run_chunks(
        address, model._address, ours._address, 37, 5, model.opt.timestep, empty, 0, 0, False, False,
        np.zeros((0, 0, 3)), np.zeros((0, 0, 4)), 0, 0, 0.0, 1.0, 0.0, ours.mocap_pos, ours.mocap_quat,
        np.zeros(0, dtype=np.int64))
    mujoco.mj_step(model, theirs, 37)
    assert (done, status) == (37, chunks.DONE)
    assert ours.time == theirs.time and np.array_equal(ours.qpos, theirs.qpos)
    assert np.array_equal(ours.qvel, theirs.qvel)
