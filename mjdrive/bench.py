"""`mjdrive bench`: env throughput against raw `mj_step` of the same model, measured in the same run.

Figures are ratios within one process on one machine, so they compare across machines better than the
absolute numbers. Simulated seconds per wall second = steps/s x step duration.
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable

import mujoco
import numpy as np

from mjdrive import suite
from mjdrive.sensors import CameraRenderer

CRUISE_ACTION = np.array([0.25, 0.0, 0.0])  # gentle throttle, straight ahead


def _rate(step: Callable[[], None], seconds: float) -> float:
    """Calls of `step` per wall second, over about `seconds`."""
    step()  # warm-up
    calls, start = 0, time.perf_counter()
    while True:
        for _ in range(10):
            step()
        calls += 10
        elapsed = time.perf_counter() - start
        if elapsed >= seconds:
            return calls / elapsed


def bench_task(name: str, seconds: float = 3.0, image_size: int = 128) -> dict[str, float]:
    """Raw physics, env (features) and env (camera) throughput of one task, in one process."""
    domain, task = name.split("/")
    env = suite.load(domain, task, {"random": 0})
    model, dt = env.physics.model.ptr, env.physics.timestep()
    n_sub = env._n_sub_steps
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

    result = {"dt": dt, "n_sub": n_sub, "nbody": model.nbody, "ngeom": model.ngeom}
    result["raw_steps_per_s"] = _rate(raw, seconds) * n_sub
    env.reset()
    result["env_steps_per_s"] = _rate(env_step(env), seconds)
    camera_env = suite.load(domain, task, {"random": 0, "observation": "camera", "image_size": image_size})
    camera_env.reset()
    result["camera_env_steps_per_s"] = _rate(env_step(camera_env), seconds)
    renderer = CameraRenderer(model, "ego/front", image_size, image_size)
    result["render_per_s"] = _rate(lambda: renderer.render(env.physics.data.ptr), seconds)
    renderer.close()
    for task_env in (camera_env,):
        for camera in task_env.task.cameras.values():
            camera.close()
    return result


def run_benchmarks(tasks: list[str], seconds: float = 3.0, image_size: int = 128) -> str:
    """A markdown report for `tasks`."""
    lines = [
        f"# mjdrive bench ({platform.processor() or platform.machine()}, {mujoco.__version__=}, one thread)",
        "",
        "| task | raw mj_step [steps/s] | raw [sim-s/wall-s] | env features [steps/s] | env [sim-s/wall-s] "
        "| env/raw | env camera [steps/s] | camera step [ms] | features step + render [ms] |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for name in tasks:
        r = bench_task(name, seconds, image_size)
        control_dt = r["dt"] * r["n_sub"]
        raw_sim = r["raw_steps_per_s"] * r["dt"]
        env_sim = r["env_steps_per_s"] * control_dt
        camera_ms = 1e3 / r["camera_env_steps_per_s"]
        parts_ms = 1e3 / r["env_steps_per_s"] + 1e3 / r["render_per_s"]
        lines.append(
            f"| {name} | {r['raw_steps_per_s']:,.0f} | {raw_sim:.1f} | {r['env_steps_per_s']:,.0f} "
            f"| {env_sim:.1f} | {env_sim / raw_sim:.0%} | {r['camera_env_steps_per_s']:,.0f} "
            f"| {camera_ms:.2f} | {parts_ms:.2f} |"
        )
    lines += [
        "",
        f"Control period = physics dt x substeps; camera {image_size}x{image_size} RGB, shadows off.",
        "env/raw: simulated seconds per wall second of the env (features observation) over raw `mj_step`.",
        "camera step vs features step + render: the camera observation should cost no more than its render.",
    ]
    return "\n".join(lines)
