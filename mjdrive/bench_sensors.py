"""`mjdrive bench --sensors TASK ...`: what the extra sensors (depth, segmentation, range ring) cost per env
step, against the same env without them, in interleaved rounds (best of each, as `mjdrive.bench`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from mjdrive.bench import ROUNDS, calls_per_second
from mjdrive.envs.gym_env import SENSORS

CONFIGS: dict[str, tuple[str, ...]] = {"none": (), **{name: (name,) for name in SENSORS}, "all": SENSORS}
SENSOR_PARTS = 1 + ROUNDS * len(CONFIGS)  # progress units per task: set-up, then each timed measurement
ACTION = np.array([0.25, 0.0, 0.0])  # gentle throttle, straight ahead


def bench_sensors(name: str, seconds: float = 3.0, size: int = 64, rays: int = 36,
                  tick: Callable[[str], None] = lambda label: None) -> dict[str, float]:
    """Env steps per second of task `name` with each sensor set of CONFIGS (gymnasium env, features)."""
    from mjdrive.envs import make_env

    domain, task = name.split("/")
    envs = {key: make_env(domain, task, random=0, sensors=sensors, sensor_size=size, range_rays=rays)
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

    rates = {key: 0.0 for key in envs}
    for _ in range(ROUNDS):
        for key, env in envs.items():
            rates[key] = max(rates[key], calls_per_second(stepper(env), seconds / ROUNDS))
            tick(f"{name}: sensors {key}")
    for env in envs.values():
        env.close()
    return rates


def run_sensor_benchmarks(tasks: list[str], seconds: float = 3.0, size: int = 64, rays: int = 36,
                          tick: Callable[[str], None] = lambda label: None) -> str:
    """A markdown table: env steps/s with each sensor set, and each set's cost per step [ms]."""
    lines = [
        "# mjdrive bench, extra sensors",
        "",
        f"Depth and segmentation {size}x{size} px from the front camera, range ring of {rays} rays "
        "(`make_env(..., sensors=...)`); features observation underneath.",
        "",
        "| task | sensors | env [steps/s] | cost [ms/step] | share of the step |",
        "| --- | --- | ---: | ---: | ---: |",
    ]
    for name in tasks:
        rates = bench_sensors(name, seconds, size, rays, tick)
        base_ms = 1e3 / rates["none"]
        for key, rate in rates.items():
            cost = 1e3 / rate - base_ms
            lines.append(f"| {name} | {key} | {rate:,.0f} | {cost:.2f} | {cost / (1e3 / rate):.0%} |")
    lines += ["", f"Best of {ROUNDS} interleaved rounds per figure; cost = step time with the sensors minus "
              "without (on a busy machine its noise is a few tenths of a ms either way)."]
    return "\n".join(lines)
