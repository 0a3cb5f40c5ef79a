"""Choosing the physics step: the car's physics, collisions with every road-user kind, solver stability
and throughput at several physics timesteps, in one run (progress on stderr, a markdown report on stdout
or --out).

    python -m tools.physics_dt --dts 0.002 0.003 0.004 0.005 0.008 0.01 --out runs/physics_dt.md

Sections (--sections, all by default):
  vehicle     for both cars, control at 20 Hz (the nearest whole number of steps): full braking from 50 km/h
              against v^2 / (2 mu g), circle radius at steer 0.25 / 0.5 / 1.0 against wheelbase / tan(delta),
              creep of a parked car over 10 s (brake on, all commands zero), 0-50 km/h at full throttle.
  collision   the sedan against one road user of every kind (a mocap box written every 0.02 s, as traffic
              does), head-on and crossing, at 5 / 10 / 15 m/s closing speed (the road user at its top speed,
              capped by the closing speed; the ego makes up the rest): whether the collision sensor (sampled
              every 0.02 s, as the tasks do) reports the contact, how long after the footprints first overlap,
              and how deep the boxes were at that moment (a contact missed or reported late would be
              tunnelling).
  stability   roundabout/d210 with the privileged autopilot for --stability-steps physics steps (new episode
              whenever one ends): physics errors (NaN, warnings) counted.
  throughput  raw `mj_step` of the d210 and the straight-route models, and the env (features) on
              waypoints/straight and roundabout/d210, every timestep interleaved in rounds (best round kept),
              as simulated seconds per wall second and as ratios to the 2 ms figure.
  profile     (only when named) one env step of roundabout/d210 (or --profile-tasks) at the default step, part
              by part; MuJoCo's cost per physics step in place against a tight loop, and with the traffic's
              motion replayed.
"""

from __future__ import annotations

import math
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

import mujoco
import numpy as np

from mjdrive import world
from mjdrive.bench import calls_per_second
from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.sensors import CollisionSensor
from mjdrive.tasks import stepping
from mjdrive.traffic import ROAD_USER_TYPES, TrafficConfig, overlapping_pairs, slots
from mjdrive.vehicle import VEHICLES, Vehicle

KMH = 1 / 3.6  # [m/s] per km/h
CONTROL_DT = 0.05  # [s] 20 Hz commands in the vehicle section
CHUNK = TrafficConfig().substep  # [s] mocap write and contact sample period of the tasks
STEERS = (0.25, 0.5, 1.0)
CLOSING = (5.0, 10.0, 15.0)  # [m/s]


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def substeps(dt: float, period: float) -> int:
    """Physics steps per `period` [s] (the nearest whole number)."""
    return max(1, int(round(period / dt)))


# --- vehicle ------------------------------------------------------------------------------------------


def car_model(name: str, dt: float) -> tuple[mujoco.MjModel, Vehicle]:
    model = world.build(None, vehicle=name, timestep=dt)
    return model, Vehicle(model, model_name=name)


Policy = Callable[[float, mujoco.MjData], tuple[float, float, float]]


def drive(model, data, vehicle: Vehicle, policy: Policy, seconds: float, log=None, until=None,
          nsub: int | None = None) -> float:
    """Run the car under `policy(t, data) -> (throttle, steer, brake)`, a command every `nsub` physics steps
    (default: CONTROL_DT's worth) for `seconds`, calling `log(t, data)` after each and stopping early when
    `until(data)`; returns the time driven [s] (the physics tests drive the car with it too)."""
    n = substeps(model.opt.timestep, CONTROL_DT) if nsub is None else nsub
    t, control_dt = 0.0, n * model.opt.timestep
    for _ in range(int(round(seconds / control_dt))):
        vehicle.apply(data, *policy(t, data))
        mujoco.mj_step(model, data, n)
        t += control_dt
        if log is not None:
            log(t, data)
        if until is not None and until(data):
            break
    return t


def vehicle_figures(name: str, dt: float) -> dict[str, float]:
    model, veh = car_model(name, dt)
    p = veh.params
    nsub = substeps(dt, CONTROL_DT)
    g = -model.opt.gravity[2]
    out: dict[str, float] = {"control_dt": nsub * dt}
    # full braking from 50 km/h
    data = mujoco.MjData(model)
    veh.reset(data, 0.0, 0.0, 0.0, 50 * KMH)
    drive(model, data, veh, lambda t, d: (0.0, 0.0, 1.0), 4.0, nsub=nsub)
    theory = (50 * KMH) ** 2 / (2 * p.tire_mu * g)
    out["brake_m"] = veh.pose(data)[0]
    out["brake_err"] = out["brake_m"] / theory - 1
    # circle radius at ~3 m/s (rear-axle centre, steady state after 4 s)
    for steer in STEERS:
        data = mujoco.MjData(model)
        veh.reset(data, 0.0, 0.0, 0.0, 3.0)
        points: list[tuple[float, float]] = []

        def rear_axle(t, d, points=points):
            if t > 4.0:
                x, y, yaw = veh.pose(d)
                points.append((x - 0.5 * p.wheelbase * math.cos(yaw), y - 0.5 * p.wheelbase * math.sin(yaw)))

        drive(model, data, veh, lambda t, d, s=steer: (min(1.0, max(0.0, 0.5 * (3.0 - veh.speed(d)))), s, 0.0), 16.0,
              rear_axle, nsub=nsub)
        xy = np.array(points)
        cx, cy, c = np.linalg.lstsq(np.c_[2 * xy, np.ones(len(xy))], (xy**2).sum(1), rcond=None)[0]
        out[f"circle_err_{steer}"] = math.sqrt(c + cx**2 + cy**2) / (p.wheelbase / math.tan(steer * p.max_steer)) - 1
    # parked 10 s
    for brake in (1.0, 0.0):
        data = mujoco.MjData(model)
        veh.reset(data, 3.0, -2.0, 0.7)
        start = data.xpos[veh.body_id].copy()
        drive(model, data, veh, lambda t, d, b=brake: (0.0, 0.0, b), 10.0, nsub=nsub)
        out[f"creep_mm_{brake:.0f}"] = 1e3 * float(np.linalg.norm(data.xpos[veh.body_id] - start))
    # 0-50 km/h
    data = mujoco.MjData(model)
    veh.reset(data, 0.0, 0.0, 0.0)
    out["t_0_50"] = drive(model, data, veh, lambda t, d: (1.0, 0.0, 0.0), 15.0,
                          until=lambda d: veh.speed(d) >= 50 * KMH, nsub=nsub)
    out["physics_ok"] = float(np.isfinite(data.qpos).all())
    return out


def vehicle_section(dts: list[float]) -> list[str]:
    lines = ["## Vehicle physics (tests/test_vehicle.py's checks)", "",
             "| car | dt [ms] | control [ms] | braking 50-0 km/h [m] | vs v²/2μg | circle radius vs L/tan δ, steer "
             + " / ".join(str(s) for s in STEERS) + " | parked 10 s, brake / no command [mm] | 0-50 km/h [s] |",
             "| --- | ---: | ---: | ---: | ---: | --- | --- | ---: |"]
    for name in sorted(VEHICLES):
        for dt in dts:
            start = time.perf_counter()
            r = vehicle_figures(name, dt)
            log(f"vehicle {name} dt={dt * 1e3:g} ms: {time.perf_counter() - start:.1f} s")
            circles = " / ".join(f"{100 * r[f'circle_err_{s}']:+.2f}%" for s in STEERS)
            lines.append(f"| {name} | {dt * 1e3:g} | {r['control_dt'] * 1e3:g} | {r['brake_m']:.2f} "
                         f"| {100 * r['brake_err']:+.1f}% | {circles} | {r['creep_mm_1']:.2f} / {r['creep_mm_0']:.2f} "
                         f"| {r['t_0_50']:.2f} |")
    return lines


# --- collisions -----------------------------------------------------------------------------------------


def footprint_overlap_time(ego_xy0, ego_v, user_xy0, user_yaw, user_v, user_half, ego_half, horizon: float) -> float:
    """First time [s] (1 ms resolution) at which the two footprints, moving on straight lines at constant
    velocity (the ego heading +x), overlap; inf if never within `horizon`."""
    for t in np.arange(0.0, horizon, 0.001):
        poses = np.array([[ego_xy0[0] + ego_v[0] * t, ego_xy0[1] + ego_v[1] * t, 0.0],
                          [user_xy0[0] + user_v[0] * t, user_xy0[1] + user_v[1] * t, user_yaw]])
        if len(overlapping_pairs(poses, np.array([ego_half, user_half]))):
            return float(t)
    return math.inf


def impact(kind: str, geometry: str, closing: float, dt: float) -> dict[str, float]:
    """One impact of the sedan with a road user of `kind`; see the module docstring."""
    model = world.build(None, vehicle="sedan", traffic=slots([kind]), timestep=dt)
    data = mujoco.MjData(model)
    veh = Vehicle(model, model_name="sedan")
    sensor = CollisionSensor(model)
    mocap = int(model.body_mocapid[model.body("traffic_0").id])
    user = ROAD_USER_TYPES[kind]
    top = user.speed[1]  # [m/s]
    p = veh.params
    ego_half = (p.length / 2, p.width / 2)
    lead = 1.0  # [s] before the footprints would meet
    if geometry == "head-on":
        v_user = min(top, closing)
        v_ego = closing - v_user
        user_yaw, user_vel = math.pi, np.array([-v_user, 0.0])
        gap = p.length / 2 + user.half_size[0] + closing * lead
        user_xy0 = np.array([gap, 0.0])
    else:  # crossing from the right, perpendicular, aimed at the ego's centre
        v_user = min(top, closing)
        v_ego = math.sqrt(max(closing**2 - v_user**2, 0.0))
        user_yaw, user_vel = math.pi / 2, np.array([0.0, v_user])
        t_meet = lead + (p.width / 2 + user.half_size[0]) / max(v_user, 1e-9)
        user_xy0 = np.array([v_ego * t_meet, -v_user * t_meet])
    veh.reset(data, 0.0, 0.0, 0.0, v_ego)
    horizon = 3.0
    t_overlap = footprint_overlap_time((0.0, 0.0), (v_ego, 0.0), user_xy0, user_yaw, user_vel, user.half_size[:2],
                                       ego_half, horizon)
    quat = [math.cos(user_yaw / 2), 0.0, 0.0, math.sin(user_yaw / 2)]
    nsub = substeps(dt, CHUNK)
    chunk = nsub * dt
    t, detected, depth = 0.0, math.inf, 0.0
    while t < horizon:
        xy = user_xy0 + user_vel * t  # poses written per chunk, as traffic does
        data.mocap_pos[mocap] = (xy[0], xy[1], 0.0)
        data.mocap_quat[mocap] = quat
        veh.apply(data, 0.0, 0.0, 0.0)  # coasting: the ego keeps its speed
        mujoco.mj_step(model, data, nsub)
        t += chunk
        sensor.sample(data)
        if sensor.collided(data):
            detected = t
            ego_hits = [c.dist for c in data.contact[: data.ncon]] if data.ncon else [0.0]
            depth = -min(ego_hits)
            break
    return {"v_user": v_user, "v_ego": v_ego, "overlap": t_overlap, "detected": detected,
            "delay": detected - t_overlap, "depth": depth, "finite": float(np.isfinite(data.qpos).all())}


def collision_section(dts: list[float]) -> list[str]:
    lines = ["## Collisions with every road-user kind", "",
             "Delay: from the first overlap of the footprints (straight-line motion, 1 ms resolution) to the "
             f"first contact sample that reports it (samples every {CHUNK * 1e3:g} ms, the road user's pose "
             f"written every {CHUNK * 1e3:g} ms, so up to two periods pass before a sample can see an overlap "
             "that began just after a write: 'detected' means reported within two periods and one physics step). "
             "Depth: the deepest contact penetration at that sample.", "",
             "| dt [ms] | kind | geometry | closing [m/s] | road user / ego [m/s] | detected | delay [ms] "
             "| depth [mm] |", "| ---: | --- | --- | ---: | --- | --- | ---: | ---: |"]
    worst: dict[float, tuple[int, int, float, float]] = {}
    for dt in dts:
        start = time.perf_counter()
        missed, total, max_delay, max_depth = 0, 0, 0.0, 0.0
        for kind in ROAD_USER_TYPES:
            for geometry in ("head-on", "crossing"):
                for closing in CLOSING:
                    r = impact(kind, geometry, closing, dt)
                    ok = math.isfinite(r["detected"]) and r["delay"] <= 2 * CHUNK + dt + 1e-9
                    missed += not ok
                    total += 1
                    if math.isfinite(r["delay"]):
                        max_delay, max_depth = max(max_delay, r["delay"]), max(max_depth, r["depth"])
                    lines.append(f"| {dt * 1e3:g} | {kind} | {geometry} | {closing:g} | {r['v_user']:.2f} / "
                                 f"{r['v_ego']:.2f} | {'yes' if ok else 'NO'} | {1e3 * r['delay']:.0f} "
                                 f"| {1e3 * r['depth']:.0f} |")
        worst[dt] = (missed, total, max_delay, max_depth)
        log(f"collision dt={dt * 1e3:g} ms: {time.perf_counter() - start:.1f} s, {missed} of {total} missed or late")
    lines += ["", "| dt [ms] | impacts | missed or late | worst delay [ms] | deepest [mm] |",
              "| ---: | ---: | ---: | ---: | ---: |"]
    for dt, (missed, total, max_delay, max_depth) in worst.items():
        lines.append(f"| {dt * 1e3:g} | {total} | {missed} | {1e3 * max_delay:.0f} | {1e3 * max_depth:.0f} |")
    return lines


# --- stability and throughput (tasks) -----------------------------------------------------------------


def load(domain: str, task: str, dt: float, **task_kwargs):
    """suite.load with the physics step `dt` [s]."""
    from mjdrive import suite

    return suite.load(domain, task, {"random": 0, "physics_dt": dt, **task_kwargs})


def stability(dt: float, physics_steps: int) -> dict[str, float]:
    from mjdrive.control.autopilot import Autopilot

    env = load("roundabout", "d210", dt)
    n_sub = env.n_sub_steps
    pilot = Autopilot(env.task, n_sub * dt)
    steps, errors, episodes, collisions = 0, 0, 0, 0
    env.reset()
    pilot.reset()
    while steps < physics_steps:
        timestep = env.step(pilot(env.physics))
        steps += n_sub
        if timestep.last():
            episodes += 1
            errors += env.task.info["physics_error"] is not None
            collisions += bool(env.task.info["collision"])
            env.reset()
            pilot.reset()
    warnings = int(env.physics.data.warning.number.sum())
    return {"steps": steps, "episodes": episodes, "errors": errors, "collisions": collisions, "warnings": warnings}


def stability_section(dts: list[float], physics_steps: int) -> list[str]:
    lines = ["## Solver stability: roundabout/d210, privileged autopilot", "",
             "| dt [ms] | physics steps | simulated [s] | episodes ended | physics errors | MuJoCo warnings "
             "| collisions |", "| ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for dt in dts:
        start = time.perf_counter()
        r = stability(dt, physics_steps)
        log(f"stability dt={dt * 1e3:g} ms: {time.perf_counter() - start:.1f} s, {r}")
        lines.append(f"| {dt * 1e3:g} | {r['steps']:,} | {r['steps'] * dt:,.0f} | {r['episodes']} | {r['errors']} "
                     f"| {r['warnings']} | {r['collisions']} |")
    return lines


def throughput_section(dts: list[float], seconds: float, rounds: int) -> list[str]:
    hold = np.array([0.0, 0.0, 1.0])
    cruise = np.array([0.25, 0.0, 0.0])
    cases: dict[tuple[str, float], Callable[[], None]] = {}
    sim_per_call: dict[tuple[str, float], float] = {}
    for dt in dts:
        for name, (domain, task, action) in {"waypoints/straight": ("waypoints", "straight", cruise),
                                              "roundabout/d210": ("roundabout", "d210", hold)}.items():
            env = load(domain, task, dt)
            env.reset()
            n_sub = env.n_sub_steps
            model = env.physics.model.ptr
            data = mujoco.MjData(model)
            src = env.physics.data
            for field in ("qpos", "qvel", "ctrl", "mocap_pos", "mocap_quat"):
                getattr(data, field)[:] = getattr(src, field)
            qpos0 = data.qpos.copy()

            def raw(model=model, data=data, n=n_sub, qpos0=qpos0):
                mujoco.mj_step(model, data, n)
                if data.time > 15.0:
                    mujoco.mj_resetData(model, data)
                    data.qpos[:] = qpos0

            def step(env=env, action=action):
                if env.step(action).last():
                    env.reset()

            control_dt = n_sub * dt
            cases[(f"{name} raw", dt)], sim_per_call[(f"{name} raw", dt)] = raw, control_dt
            cases[(f"{name} env", dt)], sim_per_call[(f"{name} env", dt)] = step, control_dt
    best = {key: 0.0 for key in cases}
    for r in range(rounds):
        for key, fn in cases.items():
            best[key] = max(best[key], calls_per_second(fn, seconds / rounds) * sim_per_call[key])
        log(f"throughput round {r + 1}/{rounds}")
    base = min(dts, key=lambda d: abs(d - 0.002))
    lines = ["## Throughput (simulated seconds per wall second, best of "
             f"{rounds} interleaved rounds)", "",
             "| case | " + " | ".join(f"{dt * 1e3:g} ms" for dt in dts) + f" | best / {base * 1e3:g} ms |",
             "| --- | " + " | ".join("---:" for _ in dts) + " | --- |"]
    for case in dict.fromkeys(k for k, _ in cases):
        values = [best[(case, dt)] for dt in dts]
        ratios = " / ".join(f"{best[(case, dt)] / best[(case, base)]:.2f}x" for dt in dts)
        lines.append(f"| {case} | " + " | ".join(f"{v:.0f}" for v in values) + f" | {ratios} |")
    for name in ("waypoints/straight", "roundabout/d210"):
        shares = [best[(f"{name} env", dt)] / best[(f"{name} raw", dt)] for dt in dts]
        lines.append(f"| {name} env/raw | " + " | ".join(f"{r:.0%}" for r in shares) + " | |")
    return lines


def profile(dt: float, steps: int, task_name: str = "roundabout/d210") -> dict[str, float]:
    """Wall time [ms] per env step of a task with traffic (features, the ego braking where it starts: at its
    yield line on the roundabout) by part: each part's functions are wrapped with a timer on this env only.
    Also MuJoCo's time per physics step [us] in the substep loop (a control step's first chunk run alone, right
    after the step's Python, and all other runs), raw `mj_step` in a tight loop from the env's own state, and the
    traffic's motion replayed (`traffic_replay`)."""
    env = load(*task_name.split("/"), dt)
    env.reset()
    task, traffic, physics = env.task, env.task.traffic, env.physics
    spent: dict[str, float] = {}

    def timed(owner, name: str, key: str) -> None:
        inner = getattr(owner, name)
        spent[key] = 0.0

        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            out = inner(*args, **kwargs)
            spent[key] += time.perf_counter() - start
            return out

        setattr(owner, name, wrapper)

    timed(task, "before_step", "task: action to controls")
    timed(task, "after_step", "task: ego state, sensors, reward")
    timed(task, "get_observation", "task: observation")
    timed(traffic, "_decide", f"traffic: decisions (every {traffic.config.decision_period:g} s)")
    timed(traffic, "advance", "traffic: advance (all)")
    timed(task.collision_sensor, "sample", "contact samples (every 0.02 s)")
    timed(physics, "advance", "physics.advance (all)")
    timed(env, "reset", "episode resets (traffic warm-up), averaged over the steps")
    # [s], physics steps: kernel runs of a control step's first chunk alone (handed back after it: a decision is
    # due), and all other runs
    kernel_runs = {"first": [0.0, 0], "rest": [0.0, 0]}
    kernel = stepping.run_chunks

    def timed_kernel(*args):
        start = time.perf_counter()
        out = kernel(*args)
        first = args[1] == env.n_sub_steps and out[0] == physics.substeps.chunk  # args[1]: steps left; out[0]: done
        runs = kernel_runs["first" if first else "rest"]
        runs[0] += time.perf_counter() - start
        runs[1] += out[0]
        return out

    stepping.run_chunks = timed_kernel
    hold = np.array([0.0, 0.0, 1.0])
    try:
        for _ in range(20):
            env.step(hold)
        task.comfort_metrics()  # the metrics' one-off import (scipy.signal) before the timed steps
        spent.update({key: 0.0 for key in spent})
        kernel_runs.update({key: [0.0, 0] for key in kernel_runs})
        start = time.perf_counter()
        for _ in range(steps):
            if env.step(hold).last():
                env.reset()
        total = time.perf_counter() - start
    finally:
        stepping.run_chunks = kernel
    model = physics.model.ptr
    data = mujoco.MjData(model)  # the env's state, its traffic held where it is (as `mjdrive bench` measures)
    for field in ("qpos", "qvel", "act", "ctrl", "mocap_pos", "mocap_quat"):
        getattr(data, field)[:] = getattr(physics.data, field)
    mujoco.mj_forward(model, data)
    start = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(model, data, env.n_sub_steps)
    raw = time.perf_counter() - start
    ms = {key: 1e3 * value / steps for key, value in spent.items()}
    out = {"env step": 1e3 * total / steps, "raw mj_step of a control step": 1e3 * raw / steps}
    decisions = f"traffic: decisions (every {traffic.config.decision_period:g} s)"
    handed_back = "traffic: substeps handed back to Python, beyond decisions (commit, pose writes)"
    out[handed_back] = ms["traffic: advance (all)"] - ms[decisions]
    out[decisions] = ms[decisions]
    out["contact samples handed back to Python"] = ms["contact samples (every 0.02 s)"]
    beyond_raw = "physics chunks beyond raw mj_step (moving traffic, first chunk after Python, pose writes)"
    out[beyond_raw] = (ms["physics.advance (all)"] - out["raw mj_step of a control step"]
                       - ms["traffic: advance (all)"] - ms["contact samples (every 0.02 s)"])
    for key in ("task: action to controls", "task: ego state, sensors, reward", "task: observation"):
        out[key] = ms[key]
    resets = "episode resets (traffic warm-up), averaged over the steps"
    out[resets] = ms[resets]
    parts = ("task: action to controls", "task: ego state, sensors, reward", "task: observation", resets)
    out["dm_control's step beyond these (comfort sample, checks)"] = (
        out["env step"] - ms["physics.advance (all)"] - sum(ms[key] for key in parts))
    n_raw = steps * env.n_sub_steps
    per_step = {key: 1e6 * seconds / max(n, 1) for key, (seconds, n) in kernel_runs.items()}
    out["us per mj_step"] = {"raw": 1e6 * raw / n_raw, **per_step, **traffic_replay(env, min(steps, 1000))} \
        if kernel_runs["rest"][1] else None
    return out


def traffic_replay(env, steps: int, rounds: int = 5) -> dict[str, float]:
    """Raw `mj_step` [us per physics step] of `steps` control steps of `env` (the ego braking) replayed in a tight
    loop from the same state: with the traffic held where it starts ("held"), and with its poses written after
    each substep as the env wrote them ("moving", the writes' own time taken off): what moving traffic costs
    MuJoCo itself. Best of `rounds`."""
    physics, traffic = env.physics, env.task.traffic
    physics.every_chunk = True  # every substep's poses through `Traffic.advance`, recorded here
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    advance = traffic.advance

    def recorded(*args, **kwargs):
        advance(*args, **kwargs)
        poses.append((physics.data.mocap_pos.copy(), physics.data.mocap_quat.copy()))

    hold = np.array([0.0, 0.0, 1.0])
    env.reset()
    state = {field: getattr(physics.data, field).copy() for field in ("qpos", "qvel", "act", "ctrl", "mocap_pos",
                                                                       "mocap_quat")}
    traffic.advance = recorded
    try:
        for _ in range(steps):
            if env.step(hold).last():
                break
    finally:
        traffic.advance = advance
        physics.every_chunk = False
    model, data = physics.model.ptr, mujoco.MjData(physics.model.ptr)
    chunk = physics.substeps.chunk

    def replay(write: bool, step: bool) -> float:
        mujoco.mj_resetData(model, data)
        for field, value in state.items():
            getattr(data, field)[:] = value
        mujoco.mj_forward(model, data)
        mocap_pos, mocap_quat = data.mocap_pos, data.mocap_quat
        start = time.perf_counter()
        for pos, quat in poses:
            if step:
                mujoco.mj_step(model, data, chunk)
            if write:
                mocap_pos[:] = pos
                mocap_quat[:] = quat
        return time.perf_counter() - start

    best = {"held": math.inf, "moving": math.inf, "writes": math.inf}
    for _ in range(rounds):
        best["held"] = min(best["held"], replay(False, True))
        best["moving"] = min(best["moving"], replay(True, True))
        best["writes"] = min(best["writes"], replay(True, False))
    n = len(poses) * chunk
    return {"held": 1e6 * best["held"] / n, "moving": 1e6 * (best["moving"] - best["writes"]) / n}


def profile_section(dt: float, steps: int, task_name: str = "roundabout/d210") -> list[str]:
    r = profile(dt, steps, task_name)
    log(f"profile {task_name} dt={dt * 1e3:g} ms: {r['env step']:.3f} ms per step")
    lines = [f"## One env step of {task_name} at {dt * 1e3:g} ms, part by part", "",
             f"{steps} steps (features, the ego braking where it starts); each part timed by a wrapper on this env "
             "(a wrapper adds ~1 us per call).", "", "| part | ms per env step | share of the env step |",
             "| --- | ---: | ---: |"]
    per_step = r.pop("us per mj_step")
    for key, value in r.items():
        lines.append(f"| {key} | {value:.3f} | {value / r['env step']:.0%} |")
    lines.append(f"| env/raw | {r['raw mj_step of a control step'] / r['env step']:.0%} | |")
    if per_step:  # the substep loop's kernel ran
        lines += ["", f"MuJoCo per physics step in the substep loop: {per_step['first']:.2f} us in a control step's "
                  f"first chunk run alone (right after the step's Python, a decision due after it), "
                  f"{per_step['rest']:.2f} us in all other runs; raw `mj_step` in a tight loop from the env's state "
                  f"(traffic held): {per_step['raw']:.2f} us. The same physics replayed in a tight loop (a fresh "
                  f"episode's first steps, best of 5): {per_step['held']:.2f} us with the traffic held, "
                  f"{per_step['moving']:.2f} us with the traffic moving as in the env (the pose writes' own time "
                  f"taken off): {per_step['moving'] / per_step['held'] - 1:.1%} more for MuJoCo itself."]
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dts", nargs="+", type=positive_float, default=[0.002, 0.003, 0.004, 0.005, 0.008, 0.01])
    parser.add_argument("--sections", nargs="+", default=["vehicle", "collision", "stability", "throughput"],
                        choices=["vehicle", "collision", "stability", "throughput", "profile"])
    parser.add_argument("--profile-steps", type=int_at_least(1), default=3000)
    parser.add_argument("--profile-tasks", nargs="+", default=["roundabout/d210"],
                        help="profile: tasks with traffic, domain/task")
    parser.add_argument("--stability-steps", type=int_at_least(1), default=100_000)
    parser.add_argument("--seconds", type=positive_float, default=10.0, help="throughput: wall seconds per case")
    parser.add_argument("--rounds", type=int_at_least(1), default=5)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    lines = [f"# Physics step: measurements ({platform.machine()}, mujoco {mujoco.__version__})", "",
             "`python -m tools.physics_dt " + " ".join(sys.argv[1:] if argv is None else argv) + "`", ""]
    # the tasks need whole physics steps per traffic chunk (0.02 s) and per control step (0.1 s, 0.2 s)
    task_dts = [dt for dt in args.dts if all(abs(p / dt - round(p / dt)) < 1e-6 for p in (CHUNK, 0.1, 0.2))]
    for section in args.sections:
        if section == "vehicle":
            lines += vehicle_section(args.dts) + [""]
        elif section == "collision":
            lines += collision_section(args.dts) + [""]
        elif section == "stability":
            lines += stability_section(task_dts, args.stability_steps) + [""]
        elif section == "throughput":
            lines += throughput_section(task_dts, args.seconds, args.rounds) + [""]
        elif section == "profile":
            for task_name in args.profile_tasks:
                lines += profile_section(world.PHYSICS_TIMESTEP, args.profile_steps, task_name) + [""]
    lines.append(f"Wall time {time.perf_counter() - start:.0f} s.")
    text = "\n".join(lines) + "\n"
    if args.out:
        Path(args.out).write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
