"""`mjdrive bench --sensors TASK ...`: what the extra sensors (task keyword `sensors`: depth, segmentation,
range ring) cost per env step, in interleaved rounds (best of each, as `mjdrive.bench`): the sensors' own time
per step, timed directly, and the env's steps per second with them."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mjdrive.bench import ROUNDS, calls_per_second
from mjdrive.sensors import SENSORS

CONFIGS: dict[str, tuple[str, ...]] = {"none": (), **{name: (name,) for name in SENSORS}, "all": SENSORS}
SENSOR_PARTS = 1 + ROUNDS * len(CONFIGS)  # progress units per task: set-up, then each timed measurement
ACTION = np.array([0.25, 0.0, 0.0])  # gentle throttle, straight ahead


def bench_sensors(name: str, seconds: float = 3.0, size: int = 64, rays: int = 36,
                  tick: Callable[[str], None] = lambda label: None) -> dict[str, tuple[float, float]]:
    """Per sensor set of CONFIGS: (env steps per second, the sensors' own time per step [ms]) of task `name`
    (gymnasium env, features observation underneath)."""
    from mjdrive.envs import make_env

    domain, task = name.split("/")
    envs = {key: make_env(domain, task, random=0, sensors=list(sensors), sensor_size=size, range_rays=rays)
            for key, sensors in CONFIGS.items()}
    for env in envs.values():
        env.reset(seed=0)
    tick(f"{name}: envs built")

    def stepper(env) -> Callable[[], None]:
        def step() -> None:
            _, _, terminated, truncated, _ = env.step(ACTION)
            if terminated or truncated:
                env.reset()
        return step

    def sensing(env) -> Callable[[], None]:
        base = env.unwrapped
        return lambda: base.task.sensor_observation(base.dm_env.physics)

    rates = {key: 0.0 for key in envs}
    own = {key: 0.0 for key in envs}  # sensor calls per second
    for _ in range(ROUNDS):
        for key, env in envs.items():
            rates[key] = max(rates[key], calls_per_second(stepper(env), 0.5 * seconds / ROUNDS))
            if key != "none":
                own[key] = max(own[key], calls_per_second(sensing(env), 0.5 * seconds / ROUNDS))
            tick(f"{name}: sensors {key}")
    for env in envs.values():
        env.close()
    return {key: (rates[key], 1e3 / own[key] if own[key] else 0.0) for key in envs}


def run_sensor_benchmarks(tasks: list[str], seconds: float = 3.0, size: int = 64, rays: int = 36,
                          tick: Callable[[str], None] = lambda label: None) -> str:
    """A markdown table: each sensor set's own time per step [ms], its share of the step, and env steps/s."""
    lines = [
        "# mjdrive bench, extra sensors",
        "",
        f"Depth and segmentation {size}x{size} px from the front camera, range ring of {rays} rays "
        "(task keyword `sensors`); features observation underneath.",
        "",
        "| task | sensors | sensors [ms/step] | share of the step | env [steps/s] |",
        "| --- | --- | ---: | ---: | ---: |",
    ]
    for name in tasks:
        results = bench_sensors(name, seconds, size, rays, tick)
        base_ms = 1e3 / results["none"][0]  # [ms] a step without sensors
        for key, (rate, cost) in results.items():
            lines.append(f"| {name} | {key} | {cost:.2f} | {cost / (base_ms + cost):.0%} | {rate:,.0f} |")
    lines += ["", f"Best of {ROUNDS} interleaved rounds per figure. The sensors' time is that of their own calls "
              "(`task.sensor_observation`) on the env's state; its share is of a step without sensors plus it. "
              "Steps/s with sensors include them (on a busy machine those vary by several tenths of a ms)."]
    return "\n".join(lines)
