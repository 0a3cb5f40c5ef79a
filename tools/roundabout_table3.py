"""Study 000's Table 3 for trained agents at every roundabout density, beside the paper's figures.

Each checkpoint runs N episodes per density (greedy actions, or sampled with --stochastic); optional training
wall-clock from the run's episodes.csv.

    python -m tools.roundabout_table3 --episodes 50 \\
        --agent SAC results/checkpoints/sac_camera_roundabout.pt results/roundabout/sac_camera_episodes.csv \\
        --agent DQN results/checkpoints/dqn_camera_roundabout.pt --out results/roundabout/table3

Every agent runs the same episodes (seeds --seed..., the task kwargs it was trained with, updated by
--task-kwarg) at each density;
`mjdrive eval` does one density at a time with per-episode rows. Writes OUT.md and OUT.json.
"""

from __future__ import annotations

import argparse
import csv
import json
import platform
import shlex
import sys
import time
from pathlib import Path

from mjdrive.agents.checkpoints import load_checkpoint
from mjdrive.agents.ensemble import describe
from mjdrive.agents.evaluate import evaluate
from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors
from mjdrive.config import parse_task_kwargs
from mjdrive.tasks.roundabout import DENSITIES

# Table 3 of the study (Ben Elallid et al. 2024): density -> (avg reward, time s, speed m/s, distance m,
# steps, success %, collision %)
PAPER = {
    "SAC": {"d120": (93.01, 6.70, 3.77, 31.58, 31.64, 98, 2), "d140": (92.99, 7.48, 3.78, 31.70, 32.91, 98, 2),
            "d160": (91.79, 8.50, 3.64, 31.72, 35.06, 96, 2), "d210": (85.07, 10.36, 3.75, 31.63, 30.80, 94, 6)},
    "PPO": {"d120": (62.1, 7.01, 3.60, 32.51, 36.01, 88, 12), "d140": (60.8, 8.02, 3.68, 32.63, 37.20, 86, 14),
            "d160": (57.2, 8.70, 3.55, 32.72, 38.10, 83, 17), "d210": (50.1, 10.5, 3.70, 32.51, 36.20, 80, 20)},
    "DQN": {"d120": (35.74, 7.89, 3.58, 33.48, 47.13, 70, 30), "d140": (24.98, 9.28, 3.52, 33.35, 47.81, 64, 36),
            "d160": (29.40, 8.63, 3.45, 33.57, 49.0, 66, 34), "d210": (1.86, 10.88, 3.63, 33.54, 47.69, 52, 48)},
}
HEADER = ("| agent | density | avg reward | avg time (s) | avg speed (m/s) | avg distance (m) | avg steps "
          "| success % | collision % | other ends | success, never off road % |")
RULE = "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: |"


def training_wall_clock(episodes_csv: Path, step: int) -> tuple[float, int]:
    """(wall-clock seconds, episodes) of a run's episodes.csv up to env step `step`."""
    wall, episodes = 0.0, 0
    with open(episodes_csv) as f:
        for row in csv.DictReader(f):
            if int(row["env_step"]) > step:
                break
            wall, episodes = float(row["wall_s"]), int(row["episode"])  # episodes are counted from 1
    return wall, episodes


def other_ends(rows: list[dict]) -> str:
    """Counts of the episode ends that are neither arrival nor collision (time limit, off route, ...)."""
    counts: dict[str, int] = {}
    for row in rows:
        if row["end"] not in ("arrived", "collision"):
            counts[row["end"]] = counts.get(row["end"], 0) + 1
    return ", ".join(f"{n} {end}" for end, n in sorted(counts.items())) or "-"


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--agent", nargs="+", action="append", required=True, metavar="NAME CHECKPOINT [CSV]",
                        help="a label, its checkpoint and optionally its run's episodes.csv (repeatable)")
    parser.add_argument("--episodes", type=int_at_least(1), default=50)
    parser.add_argument("--levels", nargs="+", default=list(DENSITIES), choices=list(DENSITIES))
    parser.add_argument("--seed", type=int_at_least(0), default=10_000)
    parser.add_argument("--stochastic", action="store_true",
                        help="sample actions from the policy (torch seeded per episode) instead of greedy ones")
    parser.add_argument("--task-kwarg", action="append", default=[], metavar="KEY=VALUE",
                        help="task keyword argument over the checkpoint's, e.g. collision_penalty=100 to score an "
                             "agent trained with another penalty under eq. 12 (repeatable)")
    parser.add_argument("--workers", type=int_at_least(0), default=0, metavar="N",
                        help="run each density's episodes in N worker processes (same table at any N)")
    parser.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                        help="run the episodes as Ray tasks: a local Ray of --workers CPUs (no ADDRESS), 'auto' "
                             "(the cluster of `ray start` on this machine) or HOST:PORT")
    parser.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    args = parser.parse_args(argv)
    task_kwargs = parse_task_kwargs(args.task_kwarg)
    for spec in args.agent:
        if len(spec) not in (2, 3):
            parser.error(f"--agent takes NAME CHECKPOINT [EPISODES_CSV], got {spec}")
    owns_ray = False
    if args.ray is not None:  # one Ray session for every agent and density
        from mjdrive.envs.vector import ray_connect

        owns_ray = ray_connect(args.ray, num_cpus=args.workers or None)
    try:
        return _tables(args, task_kwargs, argv)
    finally:
        if owns_ray:
            import ray

            ray.shutdown()


def _tables(args: argparse.Namespace, task_kwargs: dict, argv: list[str] | None) -> int:
    start = time.perf_counter()
    results, rows, training = {}, [], []
    for name, checkpoint, *csv_path in args.agent:
        for level in args.levels:
            result = evaluate(checkpoint, episodes=args.episodes, task=f"roundabout/{level}", seed=args.seed,
                              task_kwargs=task_kwargs, deterministic=not args.stochastic, progress=f"{name} {level}",
                              workers=args.workers, ray=args.ray)
            results.setdefault(name, {})[level] = result
            s = result["summary"]
            rows.append(f"| {name} | {level} | {s['avg_reward']:.2f} | {s['avg_time_s']:.2f} | "
                        f"{s['avg_speed_m_s']:.2f} | {s['avg_distance_m']:.2f} | {s['avg_steps']:.1f} | "
                        f"{s['success_pct']:g} | {s['collision_pct']:g} | {other_ends(result['rows'])} | "
                        f"{s['success_on_road_pct']:g} |")
            print(rows[-1], flush=True)
        first = next(iter(results[name].values()))
        trained_kwargs = load_checkpoint(checkpoint)["config"].get("task_kwargs", {})
        line = (f"- {name}: `{checkpoint}`, {first['algo']} trained on {first['trained_on']} "
                f"{trained_kwargs} for {first['train_steps']:,} env steps")
        if first.get("ensemble"):
            line += f" (its longest-trained member's: {describe(first['ensemble'])})"
        if task_kwargs:
            line += f", scored with {task_kwargs}"
        if csv_path:
            wall, episodes = training_wall_clock(Path(csv_path[0]), first["train_steps"])
            line += f", {episodes:,} episodes, {wall / 60:.0f} min wall-clock on this machine"
        training.append(line + ".")
    paper_rows = [f"| {name} (paper) | {level} | " + " | ".join(str(v) for v in values) + " | - | - |"
                  for name, levels in PAPER.items() for level, values in levels.items()]
    command = "python -m tools.roundabout_table3 " + shlex.join(sys.argv[1:] if argv is None else argv)
    policy = "sampled-action (stochastic policy)" if args.stochastic else "greedy"
    lines = [
        "# Roundabout (study 000), Table 3: trained agents at every density",
        "",
        f"`{command}`",
        "",
        f"{args.episodes} {policy} episodes per agent and density (seeds {args.seed}...{args.seed + args.episodes - 1},"
        " the same episodes for every agent). Time, speed, distance and steps are means over all episodes, as in"
        " the paper (whose own figures follow for comparison). The last column counts only arrivals whose"
        " footprint never left the road entirely (eq. 12 charges off-road driving 0.05 per step, so an agent may"
        " cut across the verge).",
        "",
        HEADER, RULE, *rows,
        "",
        "Training:",
        *training,
        "",
        "The paper (CARLA, 2000 episodes per agent):",
        "",
        HEADER, RULE, *paper_rows,
        "",
        f"Evaluation wall time {time.perf_counter() - start:.0f} s on {platform.machine()}.",
    ]
    report = "\n".join(lines)
    print(report)
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".md").write_text(report + "\n")
        summary = {name: {level: {k: r[k] for k in ("checkpoint", "algo", "trained_on", "train_steps",
                                                     "task_kwargs", "summary")} | {"ends": other_ends(r["rows"])}
                          for level, r in levels.items()} for name, levels in results.items()}
        out.with_suffix(".json").write_text(json.dumps(summary, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
