"""Learning curves from runs' episodes.csv: episode return (and route completion) vs episodes, as PNG.

    python -m tools.plot_curves runs/ppo_straight runs/sac_straight --labels PPO SAC --out results/curves.png

Needs matplotlib (`pip install -e .[plot]`). The line is a moving average over `--window` episodes; the
faint band behind it is the raw per-episode value.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, run_reporting_errors


def read_episodes(run: Path) -> dict[str, np.ndarray]:
    """Columns of a run folder's episodes.csv (or of the CSV file itself) as float arrays."""
    with open(run if run.suffix == ".csv" else run / "episodes.csv") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{run}/episodes.csv has no episodes")

    def column(key: str) -> np.ndarray:
        values = [row.get(key, "") for row in rows]
        return np.array([float(v == "True") if v in ("True", "False") else float(v or "nan") for v in values])

    return {key: column(key) for key in ("episode", "env_step", "wall_s", "return", "route_completion", "success")}


def moving_average(x: np.ndarray, window: int) -> np.ndarray:
    window = max(1, min(window, len(x)))
    kernel = np.ones(window) / window
    head = np.cumsum(x[: window - 1]) / np.arange(1, window)  # growing window at the start
    return np.concatenate([head, np.convolve(x, kernel, mode="valid")])


def plot(runs: list[Path], labels: list[str], out: Path, window: int, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = [read_episodes(run) for run in runs]
    # second panel: route completion (waypoints), else the success rate (roundabout), if every run has it
    second = next((key for key in ("route_completion", "success")
                   if all(np.isfinite(d[key]).any() for d in data)), None)
    fig, axes = plt.subplots(1, 2 if second else 1, figsize=(11 if second else 6, 4), squeeze=False)
    for d, label in zip(data, labels, strict=True):
        for ax, key in zip(axes[0], ("return", second), strict=False):
            line = ax.plot(d["episode"], moving_average(d[key], window), label=label)[0]
            ax.plot(d["episode"], d[key], color=line.get_color(), alpha=0.15, linewidth=0.5)
    axes[0, 0].set(xlabel="episode", ylabel=f"episode reward (moving average of {window})", title=title)
    if second:
        name = second.replace("_", " ")
        axes[0, 1].set(xlabel="episode", ylabel=f"{name} (moving average of {window})", ylim=(0, 1.05), title=name)
    for ax in axes[0]:
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="run folders (with episodes.csv) or episodes CSV files")
    parser.add_argument("--labels", nargs="+", default=None)
    parser.add_argument("--window", type=int_at_least(1), default=50, help="moving-average window [episodes]")
    parser.add_argument("--title", default="average reward vs episodes")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    labels = args.labels or [run.name for run in args.runs]
    if len(labels) != len(args.runs):
        raise SystemExit("--labels needs one label per run")
    plot(args.runs, labels, args.out, args.window, args.title)
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
