"""Choose a run's checkpoint on validation episodes (seeds apart from the test table's), and export it.

Success swings by +-10 points between checkpoints 10k steps apart, so the reported checkpoint is chosen on
separate seeds (default 20000..., the Table 3 tool uses 10000...) and then tested on the table's seeds:

    python -m tools.select_checkpoint runs/sac_rb_camera_state --first 200000 --episodes 40 \\
        --export results/checkpoints/sac_camera_state_roundabout.pt \\
        --out results/roundabout/sac_camera_state_selection/summary

Ranks by success %, then fewer collisions, then higher average reward. Writes OUT.md and OUT.json; greedy
actions; the task (and its kwargs) the run trained on unless --task is given. Several tasks (e.g. the four
roundabout densities: `--task roundabout/d120 roundabout/d140 roundabout/d160 roundabout/d210`) run
--episodes each on the same seeds and rank on the pooled figures (the mean of the per-task ones), with each
task's success % in the table. `--time-limit 60` ends episodes of a policy that stands still after 60 s
instead of the roundabout's 220 s (they fail either way; the agents' successful episodes take ~9 s).
"""

from __future__ import annotations

import json
import re
import shlex
import sys
import time
from pathlib import Path

from mjdrive.agents.evaluate import evaluate
from mjdrive.agents.train import export_policy
from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors


def run_checkpoints(run_dir: Path, first: int = 0, last: int | None = None) -> list[tuple[int, Path]]:
    """(env step, path) of the run's periodic checkpoints (checkpoints/step_N.pt) with first <= N <= last."""
    found = []
    for path in (run_dir / "checkpoints").glob("step_*.pt"):
        match = re.fullmatch(r"step_(\d+)\.pt", path.name)
        if match and first <= int(match[1]) <= (last if last is not None else float("inf")):
            found.append((int(match[1]), path))
    if not found:
        raise FileNotFoundError(f"no checkpoints/step_N.pt with {first} <= N <= {last} in {run_dir}")
    return sorted(found)


def rank_key(summary: dict) -> tuple[float, float, float]:
    """Sort key, best first: most successes, then fewest collisions, then the highest average reward."""
    return (-summary["success_pct"], summary["collision_pct"], -summary["avg_reward"])


def pooled(summaries: list[dict]) -> dict:
    """The mean of each numeric figure over per-task summaries of equally many episodes."""
    keys = [k for k, v in summaries[0].items() if isinstance(v, int | float) and not isinstance(v, bool)]
    return {k: sum(s[k] for s in summaries) / len(summaries) for k in keys}


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run_dir", type=Path, help="a `mjdrive train` output folder")
    parser.add_argument("--first", type=int_at_least(0), default=0, help="lowest env step to consider")
    parser.add_argument("--last", type=int_at_least(0), default=None, help="highest env step to consider")
    parser.add_argument("--steps", type=int_at_least(0), nargs="+", default=None,
                        help="only these env steps (e.g. the best few, again on more seeds)")
    parser.add_argument("--episodes", type=int_at_least(1), default=40)
    parser.add_argument("--seed", type=int_at_least(0), default=20_000, help="first validation seed")
    parser.add_argument("--task", nargs="+", default=None,
                        help="DOMAIN/TASK, or several to pool (default: the run's)")
    parser.add_argument("--time-limit", type=positive_float, default=None, metavar="S",
                        help="[s] episode time limit instead of the task's (e.g. 60 against the roundabout's 220): "
                             "an immature policy that stands still fails sooner, not differently; validation only")
    parser.add_argument("--export", type=Path, default=None, help="write the chosen policy (acting network only)")
    parser.add_argument("--out", type=Path, default=None, help="write OUT.md and OUT.json")
    args = parser.parse_args(argv)

    start = time.perf_counter()
    results = []
    checkpoints = run_checkpoints(args.run_dir, args.first, args.last)
    if args.steps:
        missing = sorted(set(args.steps) - {step for step, _ in checkpoints})
        if missing:
            parser.error(f"no checkpoint for steps {missing} in {args.run_dir}/checkpoints; "
                         f"there are {[step for step, _ in checkpoints]}")
        checkpoints = [(step, path) for step, path in checkpoints if step in args.steps]
    task_kwargs = None if args.time_limit is None else {"time_limit": args.time_limit}
    for step, path in checkpoints:
        per_task, failures = {}, {}
        for task in args.task or [None]:
            result = evaluate(path, episodes=args.episodes, task=task, seed=args.seed, task_kwargs=task_kwargs,
                              progress=f"step {step:,}" + (f" {task}" if task else ""))
            per_task[result["task"]] = result["summary"]
            failures[result["task"]] = {row["seed"]: row["end"] for row in result["rows"] if not row["success"]}
        s = pooled(list(per_task.values()))
        results.append({"step": step, "checkpoint": str(path), "summary": s, "task": " + ".join(per_task),
                        "per_task": per_task, "failures": failures})  # seed: end, for tools/collision_report.py
        split = " (" + ", ".join(f"{t} {v['success_pct']:.0f}" for t, v in per_task.items()) + ")" \
            if len(per_task) > 1 else ""
        print(f"step {step:>9,}: success {s['success_pct']:5.1f} %{split}, collision {s['collision_pct']:5.1f} %, "
              f"avg reward {s['avg_reward']:8.2f}", flush=True)
    best = min(results, key=lambda r: rank_key(r["summary"]))
    if args.export:
        export_policy(best["checkpoint"], args.export)

    command = "python -m tools.select_checkpoint " + shlex.join(sys.argv[1:] if argv is None else argv)
    lines = [f"# Checkpoint selection: {args.run_dir}", "", f"`{command}`", "",
             f"{args.episodes} greedy episodes per checkpoint and task on {best['task']}, seeds "
             f"{args.seed}...{args.seed + args.episodes - 1}"
             + (f", time limit {args.time_limit:g} s" if args.time_limit is not None else "")
             + "; ranked by success, then collisions, then reward.",
             "", "| env step | success % | collision % | avg reward | avg time (s) | avg speed (m/s) |"
             + ("" if len(best["per_task"]) == 1 else " success % per task |"),
             "| ---: | ---: | ---: | ---: | ---: | ---: |" + ("" if len(best["per_task"]) == 1 else " --- |")]
    for r in results:
        s, mark = r["summary"], " **(chosen)**" if r is best else ""
        split = "" if len(r["per_task"]) == 1 else \
            " " + " / ".join(f"{v['success_pct']:.0f}" for v in r["per_task"].values()) + " |"
        lines.append(f"| {r['step']:,}{mark} | {s['success_pct']:.1f} | {s['collision_pct']:.1f} | "
                     f"{s['avg_reward']:.2f} | {s['avg_time_s']:.2f} | {s['avg_speed_m_s']:.2f} |{split}")
    lines += ["", f"Chosen: step {best['step']:,}" + (f", exported to `{args.export}`" if args.export else "") + ".",
              f"Evaluation wall time {time.perf_counter() - start:.0f} s."]
    report = "\n".join(lines)
    print(report)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.with_suffix(".md").write_text(report + "\n")
        args.out.with_suffix(".json").write_text(json.dumps({"command": command, "chosen": best["step"],
                                                             "checkpoints": results}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
