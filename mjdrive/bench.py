"""`mjdrive bench`: env throughput against raw `mj_step` of the same model, measured in the same run.

Figures are ratios within one process on one machine, so they compare across machines better than the
absolute numbers. Simulated seconds per wall second = steps/s x step duration.

Every env runs at the default physics step (`world.PHYSICS_TIMESTEP`) and, interleaved with it, at 2 ms (the
step before the default was chosen by measurement, results/physics_dt.md): the ratio is the speed-up of the step.

The roundabout section runs every density level with the ego waiting at its yield line (brake) while the
traffic flows, and highway-env's roundabout-v0 in the same process when it is installed (extra `bench`), side by
side with an mjdrive roundabout holding as many cars (the ego and four others, as in roundabout-v0).
"""

from __future__ import annotations

import importlib.util
import platform
import time
from collections.abc import Callable

import mujoco
import numpy as np

from mjdrive import suite
from mjdrive.comfort import load_filter
from mjdrive.world import PHYSICS_TIMESTEP

CRUISE_ACTION = np.array([0.25, 0.0, 0.0])  # gentle throttle, straight ahead
HOLD_ACTION = np.array([0.0, 0.0, 1.0])  # brake: the ego waits at its yield line, traffic flows around it
ROUNDABOUT_LEVELS = ("d120", "d140", "d160", "d210")
URBAN_TASKS = ("concatenated",)
ROUNDS = 5  # interleaved measurement rounds per task (the best of each is kept)
COMPARE_DT = 0.002  # [s] the physics step the default is compared with
HIGHWAY_CARS = {"car": 4}  # road users of the roundabout run beside highway-env's roundabout-v0 (ego + 4 cars)
# progress units per benchmark: the envs' set-up, then each timed measurement
TASK_PARTS = 1 + 4 * ROUNDS
ROUNDABOUT_PARTS = 1 + 3 * ROUNDS + 1
HIGHWAY_PARTS = 1 + 2 * ROUNDS


def _no_tick(label: str) -> None:
    """A `tick` that shows nothing."""


def bench_parts(tasks: list[str], levels: list[str], highway: bool, urban: list[str] = ()) -> int:
    """Progress units of a `mjdrive bench` run (for the bar's total)."""
    highway = highway and bool(levels) and importlib.util.find_spec("highway_env") is not None
    return (len(tasks) * TASK_PARTS + (len(levels) + len(urban)) * ROUNDABOUT_PARTS
            + (HIGHWAY_PARTS if highway else 0))


def calls_per_second(step: Callable[[], None], seconds: float) -> float:
    """Calls of `step` per wall second, over about `seconds` (after one call to warm up, and with scipy.signal,
    which an env imports at its first episode end, already imported: a one-off, not a step's cost)."""
    return _timed_rate(step, seconds, _no_counter)[0]


def _no_counter() -> float:
    return 0.0


def bench_task(name: str, seconds: float = 3.0, image_size: int = 128,
               tick: Callable[[str], None] = _no_tick) -> dict[str, float]:
    """Raw physics, env (features) and env (camera) throughput of one task, in one process. `tick(label)`
    is called after each of its `TASK_PARTS` parts (progress)."""
    domain, task = name.split("/")
    env = suite.load(domain, task, {"random": 0})
    model, dt = env.physics.model.ptr, env.physics.timestep()
    n_sub = env.n_sub_steps
    data = mujoco.MjData(model)
    env.reset()
    data.qpos[:], data.qvel[:], data.ctrl[:] = env.physics.data.qpos, env.physics.data.qvel, env.physics.data.ctrl

    def raw():
        mujoco.mj_step(model, data, n_sub)
        if data.time > 15.0:  # stay in the regime the env sees
            mujoco.mj_resetData(model, data)
            data.qpos[:] = env.physics.data.qpos

    def env_step(environment):
        def step():
            if environment.step(CRUISE_ACTION).last():
                environment.reset()
        return step

    camera_env = suite.load(domain, task, {"random": 0, "observation": "camera", "image_size": image_size})
    camera_env.reset()
    # Time the renders inside the camera env's steps (same views as it drives, not one fixed view).
    render_time = [0.0, 0]  # [s], count
    render_camera = camera_env.task.render_camera

    def timed_render(*args, **kwargs):
        start = time.perf_counter()
        image = render_camera(*args, **kwargs)
        render_time[0] += time.perf_counter() - start
        render_time[1] += 1
        return image

    camera_env.task.render_camera = timed_render
    env_2ms = suite.load(domain, task, {"random": 0, "physics_dt": COMPARE_DT})
    env_2ms.reset()
    tick(f"{name}: envs built")
    measurements = {
        "raw_steps_per_s": (raw, n_sub),
        "env_steps_per_s": (env_step(env), 1),
        "env_2ms_steps_per_s": (env_step(env_2ms), 1),
        "camera_env_steps_per_s": (env_step(camera_env), 1),
    }
    # Interleaved short rounds, best of each: robust to other processes sharing the machine.
    result = {"dt": dt, "n_sub": n_sub, "nbody": model.nbody, "ngeom": model.ngeom,
              "control_dt_2ms": env_2ms.control_timestep()}
    result.update({key: 0.0 for key in measurements})
    for _ in range(ROUNDS):
        for key, (step, scale) in measurements.items():
            render_time[:] = [0.0, 0]
            rate = calls_per_second(step, seconds / ROUNDS) * scale
            tick(f"{name}: {key}")
            if rate > result[key]:
                result[key] = rate
                if key == "camera_env_steps_per_s":  # the render time of the round kept
                    result["render_ms"] = 1e3 * render_time[0] / max(render_time[1], 1)
    for camera in camera_env.task.cameras.values():
        camera.close()
    return result


def run_benchmarks(tasks: list[str], seconds: float = 3.0, image_size: int = 128,
                   tick: Callable[[str], None] = _no_tick) -> str:
    """A markdown report for `tasks` (`tick`: progress, see `bench_task`)."""
    lines = [
        f"# mjdrive bench ({platform.processor() or platform.machine()}, {mujoco.__version__=}, one thread)",
        "",
        f"Physics step {PHYSICS_TIMESTEP * 1e3:g} ms (the default); env at {COMPARE_DT * 1e3:g} ms: the same env at "
        f"physics_dt={COMPARE_DT:g}.",
        "",
        "| task | raw mj_step [steps/s] | raw [sim-s/wall-s] | env features [steps/s] | env [sim-s/wall-s] "
        f"| env/raw | env at {COMPARE_DT * 1e3:g} ms [sim-s/wall-s] | default / {COMPARE_DT * 1e3:g} ms "
        "| env camera [steps/s] | camera step [ms] | its render [ms] | camera step - render [ms] "
        "| features step [ms] |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name in tasks:
        r = bench_task(name, seconds, image_size, tick)
        control_dt = r["dt"] * r["n_sub"]
        raw_sim = r["raw_steps_per_s"] * r["dt"]
        env_sim = r["env_steps_per_s"] * control_dt
        env_2ms_sim = r["env_2ms_steps_per_s"] * r["control_dt_2ms"]
        camera_ms = 1e3 / r["camera_env_steps_per_s"]
        lines.append(
            f"| {name} | {r['raw_steps_per_s']:,.0f} | {raw_sim:.1f} | {r['env_steps_per_s']:,.0f} "
            f"| {env_sim:.1f} | {env_sim / raw_sim:.0%} | {env_2ms_sim:.1f} | {env_sim / env_2ms_sim:.2f}x "
            f"| {r['camera_env_steps_per_s']:,.0f} "
            f"| {camera_ms:.2f} | {r['render_ms']:.2f} | {camera_ms - r['render_ms']:.2f} "
            f"| {1e3 / r['env_steps_per_s']:.2f} |"
        )
    lines += [
        "",
        f"Control period = physics dt x substeps; camera {image_size}x{image_size} RGB, shadows off.",
        "env/raw: simulated seconds per wall second of the env (features observation) over raw `mj_step`.",
        "camera step - render vs features step: beyond its render, the camera observation should cost nothing"
        " (its render is timed inside the camera env's own steps).",
    ]
    return "\n".join(lines)


def _timed_rate(step: Callable[[], None], seconds: float, counter: Callable[[], float]) -> tuple[float, float]:
    """(calls of `step` per wall second, share of that wall time that `counter` [s] grew by), over about `seconds`,
    warmed up as `calls_per_second` says."""
    load_filter()
    step()  # warm-up
    before, calls, start = counter(), 0, time.perf_counter()
    while True:
        for _ in range(10):
            step()
        calls += 10
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            return calls / elapsed, (counter() - before) / elapsed


def bench_roundabout(level: str, seconds: float = 3.0, image_size: int = 84,
                     tick: Callable[[str], None] = _no_tick) -> dict[str, float]:
    """Raw physics, env features (with the traffic update's share of the time) and env camera throughput
    of one roundabout density, the ego braking at its yield line (`tick` after each of `ROUNDABOUT_PARTS`)."""
    return bench_traffic_task("roundabout", level, seconds, image_size, tick)


def bench_traffic_task(domain: str, task: str, seconds: float = 3.0, image_size: int = 84,
                       tick: Callable[[str], None] = _no_tick) -> dict[str, float]:
    """`bench_roundabout` for any task with traffic: the ego brakes at its start while the traffic flows."""
    level, name = task, f"{domain}/{task}"
    env = suite.load(domain, level, {"random": 0})
    env.reset()
    model, dt, n_sub = env.physics.model.ptr, env.physics.timestep(), env.n_sub_steps
    data = mujoco.MjData(model)
    src = env.physics.data
    for field in ("qpos", "qvel", "ctrl", "mocap_pos", "mocap_quat"):  # not `name`: the ticks' task name
        getattr(data, field)[:] = getattr(src, field)
    mujoco.mj_forward(model, data)
    traffic = env.task.traffic

    def step(environment):
        def go():
            if environment.step(HOLD_ACTION).last():
                environment.reset()
        return go

    env_2ms = suite.load(domain, level, {"random": 0, "physics_dt": COMPARE_DT})
    env_2ms.reset()
    tick(f"{name}: envs built")
    result = {"dt": dt, "n_sub": n_sub, "users": traffic.n, "decision": traffic.config.decision_period}
    # Interleaved short rounds, best of each: robust to other processes sharing the machine.
    raw, envs, envs_2ms = [], [], []
    for _ in range(ROUNDS):
        raw.append(calls_per_second(lambda: mujoco.mj_step(model, data, n_sub), seconds / ROUNDS) * n_sub)
        tick(f"{name}: raw")
        envs.append(_timed_rate(step(env), seconds / ROUNDS, lambda: traffic.cpu_time))
        tick(f"{name}: env")
        envs_2ms.append(calls_per_second(step(env_2ms), seconds / ROUNDS))
        tick(f"{name}: env at {COMPARE_DT * 1e3:g} ms")
    result["raw_steps_per_s"] = max(raw)
    result["env_steps_per_s"], result["traffic_share"] = max(envs)
    result["env_2ms_steps_per_s"] = max(envs_2ms)
    camera_env = suite.load(domain, level, {"random": 0, "observation": "camera", "image_size": image_size})
    camera_env.reset()
    result["camera_env_steps_per_s"] = calls_per_second(step(camera_env), seconds)
    tick(f"{name}: camera env")
    for camera in camera_env.task.cameras.values():
        camera.close()
    return result


def bench_highway_env(seconds: float = 3.0, tick: Callable[[str], None] = _no_tick) -> dict[str, float] | None:
    """highway-env's roundabout-v0 (kinematic cars, no rendering, IDLE action) if installed, else None, in
    interleaved rounds with an mjdrive roundabout holding as many cars (`HIGHWAY_CARS` and the ego; features,
    default physics step, the ego braking at its yield line)."""
    try:
        import gymnasium as gym
        import highway_env  # noqa: F401  (registers the ids)
    except ImportError:
        return None
    env = gym.make("roundabout-v0")
    env.reset(seed=0)

    def go():
        _, _, terminated, truncated, _ = env.step(1)  # IDLE
        if terminated or truncated:
            env.reset()

    ours = suite.load("roundabout", "d120", {"random": 0, "road_users": HIGHWAY_CARS})
    ours.reset()
    tick("highway-env: envs built")

    def ours_go():
        if ours.step(HOLD_ACTION).last():
            ours.reset()

    rates, ours_rates = [], []
    for _ in range(ROUNDS):
        rates.append(calls_per_second(go, seconds / ROUNDS))
        tick("highway-env roundabout-v0")
        ours_rates.append(calls_per_second(ours_go, seconds / ROUNDS))
        tick("mjdrive roundabout beside it")
    config = env.unwrapped.config
    result = {"steps_per_s": max(rates), "policy_dt": 1.0 / config["policy_frequency"],
              "sim_dt": 1.0 / config["simulation_frequency"], "vehicles": len(env.unwrapped.road.vehicles),
              "version": getattr(highway_env, "__version__", "?"), "ours_steps_per_s": max(ours_rates),
              "ours_control_dt": ours.control_timestep(), "ours_cars": 1 + ours.task.traffic.n}
    env.close()
    return result


TRAFFIC_HEADER = (
    "| task | road users | raw mj_step [steps/s] | raw [sim-s/wall-s] | env features [steps/s] "
    f"| env [sim-s/wall-s] | env/raw | env at {COMPARE_DT * 1e3:g} ms [sim-s/wall-s] "
    f"| default / {COMPARE_DT * 1e3:g} ms | traffic share of step | traffic [ms/step] | env camera [steps/s] "
    "| camera [sim-s/wall-s] |",
    "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
)


def _traffic_row(name: str, r: dict[str, float]) -> str:
    """One row of TRAFFIC_HEADER's table from `bench_traffic_task`'s result."""
    control_dt = r["dt"] * r["n_sub"]
    raw_sim = r["raw_steps_per_s"] * r["dt"]
    env_sim = r["env_steps_per_s"] * control_dt
    env_2ms_sim = r["env_2ms_steps_per_s"] * control_dt
    return (f"| {name} | {r['users']} | {r['raw_steps_per_s']:,.0f} | {raw_sim:.1f} "
            f"| {r['env_steps_per_s']:,.0f} | {env_sim:.1f} | {env_sim / raw_sim:.0%} | {env_2ms_sim:.1f} "
            f"| {env_sim / env_2ms_sim:.2f}x | {r['traffic_share']:.0%} "
            f"| {1e3 * r['traffic_share'] / r['env_steps_per_s']:.2f} | {r['camera_env_steps_per_s']:,.0f} "
            f"| {r['camera_env_steps_per_s'] * control_dt:.1f} |")


def run_urban_benchmarks(tasks=URBAN_TASKS, seconds: float = 3.0, image_size: int = 84,
                         tick: Callable[[str], None] = _no_tick) -> str:
    """A markdown report: the urban tasks (study 002) at their default traffic, the ego braking at its start
    while the traffic flows (`tick` after each of `ROUNDABOUT_PARTS` per task)."""
    lines = [f"# mjdrive bench, urban ({platform.processor() or platform.machine()}, {mujoco.__version__=}, "
             "one thread)", "", *TRAFFIC_HEADER]
    r = {}
    for task in tasks:
        r = bench_traffic_task("urban", task, seconds, image_size, tick)
        lines.append(_traffic_row(f"urban/{task}", r))
    if r:
        lines += ["", f"Urban: control 10 Hz ({r['n_sub']} physics steps of {r['dt'] * 1e3:g} ms), traffic poses "
                  f"written every 0.02 s, traffic decisions every {r['decision']:.1f} s; the ego brakes at its start "
                  f"while the traffic flows; camera = one {image_size}x{image_size} colour frame. Columns as in the "
                  "roundabout table."]
    return "\n".join(lines)


def run_roundabout_benchmarks(levels=ROUNDABOUT_LEVELS, seconds: float = 3.0, image_size: int = 84,
                              highway: bool = True, tick: Callable[[str], None] = _no_tick) -> str:
    """A markdown report: every roundabout density, and highway-env's roundabout-v0 if installed (`tick`:
    progress, see `bench_roundabout`)."""
    lines = [f"# mjdrive bench, roundabout ({platform.processor() or platform.machine()}, {mujoco.__version__=}, "
             "one thread)", "", *TRAFFIC_HEADER]
    for level in levels:
        r = bench_roundabout(level, seconds, image_size, tick)
        lines.append(_traffic_row(f"roundabout/{level}", r))
    hw = bench_highway_env(seconds, tick) if highway else None
    if hw is not None:
        ours_sim = hw["ours_steps_per_s"] * hw["ours_control_dt"]
        hw_sim = hw["steps_per_s"] * hw["policy_dt"]
        lines += [
            "",
            "| side by side, equal cars | cars (ego included) | env [steps/s] | env [sim-s/wall-s] "
            "| mjdrive / highway-env |",
            "| --- | ---: | ---: | ---: | ---: |",
            f"| mjdrive roundabout (road_users={HIGHWAY_CARS}, features, {PHYSICS_TIMESTEP * 1e3:g} ms) "
            f"| {hw['ours_cars']} | {hw['ours_steps_per_s']:,.0f} | {ours_sim:.1f} | {ours_sim / hw_sim:.2f}x |",
            f"| highway-env {hw['version']} roundabout-v0 | {hw['vehicles']} | {hw['steps_per_s']:,.0f} "
            f"| {hw_sim:.1f} | - |",
        ]
    lines += [
        "",
        f"Roundabout: control 5 Hz ({r['n_sub']} physics steps of {r['dt'] * 1e3:g} ms), traffic poses written every "
        f"0.02 s, traffic decisions every {r['decision']:.1f} s; the ego brakes at its yield line while the "
        f"traffic flows; camera = 4 stacked {image_size}x{image_size} gray frames.",
        "raw: `mj_step` of the same model from the same state (traffic boxes still). env/raw: simulated "
        "seconds per wall second of the env (features observation) over raw physics. traffic share: wall "
        "time inside `Traffic.advance` over the env's wall time: its decisions and the substeps handed back to it "
        "(the other substeps' pose writes run inside the substep loop's kernel, `tasks.stepping`). Raw, env and "
        f"env at {COMPARE_DT * 1e3:g} ms are measured in {ROUNDS} interleaved rounds; each figure is the best round "
        "(robust to other processes on the machine).",
    ]
    if hw is not None:
        lines.append(f"highway-env: {1 / hw['policy_dt']:.0f} Hz policy, {1 / hw['sim_dt']:.0f} Hz kinematic "
                     "simulation, no rendering, IDLE action, in the same process, in interleaved rounds with the "
                     "mjdrive roundabout beside it (best round of each).")
    elif highway:
        lines.append("highway-env is not installed (`pip install mjdrive[bench]` adds it).")
    return "\n".join(lines)
