"""Scripted baselines on the roundabout densities: a naive "just drive" policy (pure pursuit along the
route, traffic ignored) and a careful privileged autopilot (traffic's own rules applied to the ego from
ground truth: IDM, yielding with gap acceptance, crosswalks). Writes the study's Table 3 columns.

    python -m tools.roundabout_baselines --episodes 50 --out results/roundabout_baselines.md
"""

from __future__ import annotations

import platform
import sys
import time
from pathlib import Path

import numpy as np

from mjdrive import suite
from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from mjdrive.control.autopilot import Autopilot
from mjdrive.tasks.roundabout import DENSITIES
from mjdrive.world import PHYSICS_TIMESTEP

COLUMNS = ("episode_reward", "elapsed_time", "average_speed", "distance", "steps")


def evaluate(level: str, careful: bool, episodes: int, seed: int = 0) -> dict[str, float]:
    """Means over `episodes` of the Table 3 metrics for one density and policy (features observation)."""
    env = suite.load("roundabout", level, {"random": seed})
    driver = Autopilot(env.task, env.control_timestep(), careful=careful)
    rows = []
    for _ in range(episodes):
        timestep = env.reset()
        driver.reset()
        while not timestep.last():
            timestep = env.step(driver(env.physics))
        info = env.task.info
        rows.append([info[c] for c in COLUMNS] + [info["success"], info["collision"]])
    r = np.array(rows, dtype=float)
    out = dict(zip(COLUMNS, r[:, : len(COLUMNS)].mean(axis=0), strict=True))
    out["success"], out["collision"] = 100 * r[:, -2].mean(), 100 * r[:, -1].mean()
    out["timeout"] = 100 * np.mean((r[:, -2] == 0) & (r[:, -1] == 0))  # neither: the 1100-step limit
    return out


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int_at_least(1), default=50)
    parser.add_argument("--levels", nargs="+", default=list(DENSITIES))
    parser.add_argument("--seed", type=int_at_least(0), default=0)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    lines = [
        "# Roundabout baselines (scripted, privileged)",
        "",
        f"`python -m tools.roundabout_baselines --episodes {args.episodes} --seed {args.seed}"
        + (f" --out {args.out}`" if args.out else "`"),
        "",
        f"{args.episodes} episodes per density and policy (task seed {args.seed}; the same episodes for both "
        f"policies), features observation, sedan, 5 Hz control, {1e3 * PHYSICS_TIMESTEP:g} ms physics step (the "
        "default). Columns as the study's Table 3; time, speed and "
        "distance are means over all episodes.",
        "",
        "| policy | density | avg reward | avg time [s] | avg speed [m/s] | avg distance [m] | avg steps "
        "| success [%] | collision [%] | timeout [%] |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for careful, name in ((False, "just drive"), (True, "careful autopilot")):
        for level in args.levels:
            r = evaluate(level, careful, args.episodes, args.seed)
            lines.append(
                f"| {name} | {level} | {r['episode_reward']:.1f} | {r['elapsed_time']:.1f} "
                f"| {r['average_speed']:.2f} | {r['distance']:.1f} | {r['steps']:.1f} | {r['success']:.0f} "
                f"| {r['collision']:.0f} | {r['timeout']:.0f} |"
            )
            print(lines[-1], flush=True)
    lines += [
        "",
        "just drive: pure pursuit along the route at 6 m/s (slower in curves), traffic ignored.",
        "careful autopilot: the same steering; speed from `Traffic.advise` (IDM behind leaders and anything "
        "in its corridor, stops for pedestrians on its crosswalks, enters only when no circulating vehicle "
        "reaches the merge point within 4.5 s).",
        f"Wall time {time.perf_counter() - start:.0f} s on {platform.machine()} ({platform.processor() or '?'}), "
        f"Python {sys.version.split()[0]}.",
    ]
    report = "\n".join(lines)
    print(report)
    if args.out:
        Path(args.out).write_text(report + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
