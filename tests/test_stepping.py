"""The substep loop (mjdrive.tasks.stepping): the chunks it hands back to Python are the ones that need it, and
handing every chunk back gives the same trajectories bit for bit (physics, traffic poses and state, contacts and
episode info, through decisions, collisions and resets, with chunks that are one traffic substep and with chunks
that are not); its mj_step is MuJoCo's; a task's tick comes at its period; the batched env runs the same loop."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mjdrive import suite
from mjdrive.tasks import stepping


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
            cursor = traffic.cursor()
            row += [traffic.poses(), traffic.speeds(), cursor.time, cursor.k, cursor.accumulated]
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
def test_every_chunk_in_python_gives_the_same_trajectory(domain, task, kwargs, steps):
    rng = np.random.default_rng(7)
    actions = np.column_stack([rng.uniform(0.5, 1.0, steps), rng.uniform(-0.3, 0.3, steps), np.zeros(steps)])
    compiled = suite.load(domain, task, {"random": 3, **kwargs})
    python = suite.load(domain, task, {"random": 3, **kwargs})
    python.physics.every_chunk = True  # the task's callback after every chunk
    compiled.reset()
    python.reset()
    trace_c, seen_c = _trace(compiled, steps, actions)
    trace_p, seen_p = _trace(python, steps, actions)
    assert seen_c == seen_p
    _same(trace_c, trace_p)
    if domain == "roundabout" and not kwargs:
        assert seen_c["collisions"] >= 1 and seen_c["resets"] >= 1  # the contact hand-back and resets ran


def test_the_loop_hands_back_the_chunks_that_need_the_callback(monkeypatch):
    """On d210 a decision is due every 0.6 s (3 control steps): the loop hands back one chunk per decision and
    does every other chunk's work itself."""
    env = suite.load("roundabout", "d210", {"random": 0})
    env.reset()
    statuses = []
    kernel = stepping.run_chunks

    def counted(*args):
        result = kernel(*args)
        statuses.append(result[1])
        return result

    traffic, decisions = env.task.traffic, []
    decide = traffic._decide
    monkeypatch.setattr(stepping, "run_chunks", counted)
    monkeypatch.setattr(traffic, "_decide", lambda: (decisions.append(traffic.time), decide()))
    hold = np.array([0.0, 0.0, 1.0])
    for _ in range(30):
        env.step(hold)
    assert statuses.count(stepping.DONE) == 30  # each control step ends in the kernel
    assert len(decisions) in (9, 10)  # 300 chunks of 0.02 s, a decision every 0.6 s
    # handed back for those only (the episode's first chunk included: no plan yet, that substep decides)
    assert decisions[0] == 0.0 and statuses.count(stepping.CALLBACK) == len(decisions)


def test_the_loops_mj_step_is_mujocos():
    """`run_chunks` without contacts or traffic is `mj_step` n times: the same state as the bindings'."""
    model = mujoco.MjModel.from_xml_string(
        '<mujoco><worldbody><body><freejoint/><geom size=".1"/></body></worldbody></mujoco>')
    ours, theirs = mujoco.MjData(model), mujoco.MjData(model)
    ours.qvel[:3] = theirs.qvel[:3] = (1.0, -0.5, 2.0)
    contacts = stepping.Contacts(np.zeros(2), 0, 1, True)  # (counts 0: never touching)
    mocap = stepping.Mocap(ours.mocap_pos, ours.mocap_quat, stepping.NO_ROWS)
    done, status, *_ = stepping.run_chunks((stepping.mj_step_address(), model._address, ours._address), 37, 5,
                                           model.opt.timestep, contacts, stepping.NO_CURSOR, mocap, 0, 0)
    mujoco.mj_step(model, theirs, 37)
    assert (done, status) == (37, stepping.DONE)
    assert ours.time == theirs.time and np.array_equal(ours.qpos, theirs.qpos)
    assert np.array_equal(ours.qvel, theirs.qvel)


def test_a_tick_at_its_period_within_each_control_step():
    """A task's tick every 0.1 s of a 0.2 s roundabout step (5 chunks of 0.02 s): once per step, after its fifth
    chunk, whatever else the chunks hand back (decisions, contacts); the trajectory is the same as without."""
    env, plain = suite.load("roundabout", "d120", {"random": 1}), suite.load("roundabout", "d120", {"random": 1})
    env.reset()
    plain.reset()
    ticks = []
    env.physics.substeps.set_tick(lambda physics: ticks.append(round(physics.data.time, 9)), 0.1)
    assert env.physics.substeps.tick_every == 5
    rng = np.random.default_rng(0)
    for step in range(40):
        action = np.array([0.6, rng.uniform(-0.1, 0.1), 0.0])
        start = env.physics.data.time
        last = env.step(action).last()
        plain.step(action)
        assert ticks[-1] == pytest.approx(start + 0.1, abs=1e-9) and len(ticks) == step + 1
        assert np.array_equal(env.physics.data.qpos, plain.physics.data.qpos)
        assert np.array_equal(env.physics.data.mocap_pos, plain.physics.data.mocap_pos)
        if last:  # the next step resets (a new episode's substeps: no tick set)
            break
    assert len(ticks) >= 10
