"""Study 002's Fig. 9/10 on `urban/concatenated`: one episode's speed, steering, pedals, acceleration and jerk
over time, the background coloured by the active scenario, as PNG.

    python -m tools.urban_figures --seed 20000 --out results/urban/
    python -m tools.urban_figures --seed 20000 --checkpoint results/checkpoints/hybrid_trpo.pt --name hybrid_trpo

Drives one episode with a built-in policy (default the privileged autopilot, `mjdrive.policies`) or a trained
one (`--checkpoint`, e.g. the hybrid agent, greedy) and writes `<name>_seed<S>.png` (the whole episode) and
`<name>_seed<S>_peak.png` (a few seconds around the episode's max |jerk|). Samples: the chassis at the control
rate (10 Hz), the episode's start and after every control period (with the decision action set, each decision
spans several; the steering shown is then the operative level's commanded angle); acceleration and jerk are
`mjdrive.comfort`'s (Savitzky-Golay derivatives, 0.5 s window, order 2, car frame), so they are the signals
behind the task's comfort metrics. Dashed lines: nuPlan's comfort bounds (the paper gives none). Needs
matplotlib (`pip install -e .[plot]`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, int_at_least, positive_float, run_reporting_errors
from mjdrive.comfort import AccelerationProfile
from mjdrive.envs import make_env
from mjdrive.policies import DECISION_POLICIES, POLICIES, make_policy
from mjdrive.tasks.urban import CONTROL_TIMESTEP, SCENARIOS

SCENARIO_COLOURS = {
    "follow": "white",
    "roundabout": "tab:blue",
    "lane_change": "tab:orange",
    "crossroad": "tab:green",
    "merge": "tab:red",
}  # background by active scenario
# nuPlan's comfort bounds (pdm_comfort_metrics.py), after its own Savitzky-Golay filtering
ACCEL_LON_BOUNDS = (-4.05, 2.40)  # [m/s^2]
ACCEL_LAT_BOUND = 4.89  # [m/s^2] on |a_lat|
JERK_LON_BOUND = 4.13  # [m/s^3] on |jerk_lon|
JERK_BOUND = 8.37  # [m/s^3] on |jerk|
ENDS = ("success", "collision", "off_route", "time_limit")


@dataclass(frozen=True, eq=False)
class Episode:
    """One driven episode: N samples (the start and after each of the N - 1 control steps)."""

    seed: int
    policy: str
    end: str  # one of ENDS
    info: dict  # the task's info at the last step (comfort metrics included)
    profile: AccelerationProfile  # (N,) time, speed, a_lon, a_lat, jerk_lon, jerk_lat
    steering: np.ndarray  # (N,) [rad] bicycle-equivalent front-wheel angle
    scenario: tuple[str, ...]  # (N,) the active scenario at each sample
    commands: np.ndarray  # (N - 1, 3) (throttle, steer, brake) applied from sample i to i + 1

    @property
    def time(self) -> np.ndarray:
        return self.profile.time  # [s]

    @property
    def jerk(self) -> np.ndarray:
        return np.hypot(self.profile.jerk_lon, self.profile.jerk_lat)  # [m/s^3]


def drive(seed: int, policy: str = "autopilot", time_limit: float | None = None,
          checkpoint: str | None = None) -> Episode:
    """Drive one episode of `urban/concatenated` (seed for the task and the episode, as tools.urban_table2) with
    the built-in `policy` or the greedy policy of `checkpoint`."""
    kwargs = {} if time_limit is None else {"time_limit": time_limit}
    if checkpoint is not None:
        from mjdrive.agents.evaluate import load_agent

        agent, payload = load_agent(checkpoint)
        decisions = bool(payload["config"].get("task_kwargs", {}).get("decisions"))

        def act(observation: dict):
            return agent.act({key: value[None] for key, value in observation.items()})[0]
    else:
        decisions = policy in DECISION_POLICIES
    env = make_env("urban", "concatenated", random=seed, decisions=decisions, **kwargs)
    try:
        task, physics = env.unwrapped.task, env.unwrapped.dm_env.physics
        if checkpoint is None:
            act = make_policy(policy, env, seed)
        observation, info = env.reset(seed=seed)
        steering, scenario, commands = [task.vehicle.steering_angle(physics.raw_data)], [info["scenario"]], []
        while True:
            action = act(observation)
            observation, _, terminated, truncated, info = env.step(
                action if decisions else np.asarray(action, dtype=np.float32))
            if decisions:  # every control period of the decision: the operative level's commands
                max_steer = task.operative.params.max_steer  # [rad]
                for tick in task.ticks:
                    commands.append((tick["throttle"], tick["steer"], tick["brake"]))
                    steering.append(tick["steer"] * max_steer)
                    scenario.append(info["scenario"])
            else:
                commands.append(np.asarray(action, dtype=np.float64))
                steering.append(task.vehicle.steering_angle(physics.raw_data))
                scenario.append(info["scenario"])
            if terminated or truncated:
                break
        profile = task.comfort.profile(CONTROL_TIMESTEP)
    finally:
        env.close()
    end = next((e for e in ENDS[:3] if info[e]), "time_limit")  # success, collision, off_route
    return Episode(
        seed,
        policy if checkpoint is None else Path(checkpoint).stem,
        end,
        dict(info),
        profile,
        np.asarray(steering),
        tuple(scenario),
        np.asarray(commands, dtype=np.float64).reshape(-1, 3),
    )


def scenario_spans(time: np.ndarray, scenario: tuple[str, ...]) -> list[tuple[float, float, str]]:
    """Contiguous (start [s], end [s], scenario) runs; each sample holds until the next one."""
    spans, start = [], 0
    for i in range(1, len(scenario) + 1):
        if i == len(scenario) or scenario[i] != scenario[start]:
            end = time[i] if i < len(time) else time[-1] + (time[1] - time[0] if len(time) > 1 else CONTROL_TIMESTEP)
            spans.append((float(time[start]), float(end), scenario[start]))
            start = i
    return spans


def draw(episode: Episode, path: Path, span: tuple[float, float] | None = None):
    """Write the figure to `path` (PNG) and return it: the whole episode, or the time window `span` [s]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Patch

    t, p, c = episode.time, episode.profile, episode.commands
    peak = int(np.nanargmax(episode.jerk)) if np.isfinite(episode.jerk).any() else None
    fig, axes = plt.subplots(5, 1, sharex=True, figsize=(12, 11) if span is None else (8, 11))
    ax_v, ax_s, ax_c, ax_a, ax_j = axes
    ax_v.plot(t, p.speed, color="black", lw=1.0, label="speed")
    ax_v.set_ylabel("speed [m/s]")
    ax_s.plot(t, np.degrees(episode.steering), color="black", lw=1.0, label="steering angle")
    ax_s.set_ylabel("steering [deg]")
    ax_c.step(t[:-1], c[:, 0], where="post", color="tab:green", lw=1.0, label="throttle")
    ax_c.step(t[:-1], c[:, 2], where="post", color="tab:red", lw=1.0, label="brake")
    ax_c.set_ylabel("pedal [0-1]")
    ax_c.set_ylim(-0.05, 1.05)
    ax_a.plot(t, p.a_lon, color="tab:blue", lw=1.0, label="a_lon")
    ax_a.plot(t, p.a_lat, color="tab:purple", lw=1.0, label="a_lat")
    for y in ACCEL_LON_BOUNDS:
        ax_a.axhline(y, color="tab:blue", ls="--", lw=0.8)
    for y in (-ACCEL_LAT_BOUND, ACCEL_LAT_BOUND):
        ax_a.axhline(y, color="tab:purple", ls=":", lw=0.8)
    ax_a.set_ylabel("accel [m/s²]")
    ax_j.plot(t, p.jerk_lon, color="tab:blue", lw=1.0, label="jerk_lon")
    ax_j.plot(t, p.jerk_lat, color="tab:purple", lw=1.0, label="jerk_lat")
    ax_j.plot(t, episode.jerk, color="black", lw=0.6, alpha=0.6, label="|jerk|")
    for y in (-JERK_LON_BOUND, JERK_LON_BOUND):
        ax_j.axhline(y, color="tab:blue", ls="--", lw=0.8)
    ax_j.axhline(JERK_BOUND, color="black", ls="--", lw=0.8)
    ax_j.set_ylabel("jerk [m/s³]")
    ax_j.set_xlabel("time [s]")
    if peak is not None:
        ax_j.plot(
            [t[peak]], [episode.jerk[peak]], "v", color="black", ms=6, label=f"max |jerk| {episode.jerk[peak]:.1f}"
        )
    for ax in axes:
        for start, end, name in scenario_spans(t, episode.scenario):
            if name != "follow":
                ax.axvspan(start, end, color=SCENARIO_COLOURS[name], alpha=0.15, lw=0)
        if peak is not None and span is not None:
            ax.axvline(t[peak], color="black", lw=0.6, ls=":")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=7, ncol=4)
    if span is not None:
        ax_j.set_xlim(*span)
    else:
        ax_j.set_xlim(t[0], t[-1])
    patches = [
        Patch(facecolor=SCENARIO_COLOURS[s], alpha=0.15 if s != "follow" else 1.0, edgecolor="grey", label=s)
        for s in SCENARIOS
    ]
    patches.append(Patch(facecolor="none", edgecolor="grey", ls="--", label="nuPlan comfort bounds (dashed)"))
    fig.legend(
        handles=patches, loc="upper center", bbox_to_anchor=(0.5, 0.97), ncol=len(patches), fontsize=8, frameon=False
    )
    info = episode.info
    title = (
        f"urban/concatenated, {episode.policy}, seed {episode.seed}: {episode.end} after "
        f"{info['elapsed_time']:.1f} s, {info['average_speed']:.2f} m/s"
    )
    if span is not None:
        title += f" (around the max |jerk| at {t[peak]:.1f} s)"
    fig.suptitle(title, y=0.995, fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.945))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return fig


def peak_span(episode: Episode, half: float = 4.0) -> tuple[float, float]:
    """[s] the window of +- `half` s around the episode's max |jerk|, inside the episode."""
    t = episode.time
    k = int(np.nanargmax(episode.jerk)) if np.isfinite(episode.jerk).any() else 0
    return max(float(t[0]), float(t[k]) - half), min(float(t[-1]), float(t[k]) + half)


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int_at_least(0), default=20000, help="task and episode seed")
    parser.add_argument("--policy", default="autopilot", choices=POLICIES)
    parser.add_argument("--time-limit", type=positive_float, default=None, help="[s] shorter episode (default: task's)")
    parser.add_argument("--checkpoint", default=None, help="drive a trained policy (e.g. the hybrid agent) instead")
    parser.add_argument("--name", default=None, help="the PNGs' name (default: the policy's or checkpoint's)")
    parser.add_argument("--out", default="results/urban/", help="folder for the PNGs")
    args = parser.parse_args(argv)
    if args.checkpoint is not None and not Path(args.checkpoint).is_file():
        parser.error(f"--checkpoint {args.checkpoint}: no such file")
    episode = drive(args.seed, args.policy, args.time_limit, args.checkpoint)
    info = episode.info
    print(
        f"seed {args.seed}: {episode.end} after {info['elapsed_time']:.1f} s ({info['steps']} steps), "
        f"{info['distance']:.0f} m, average speed {info['average_speed']:.2f} m/s, last scenario "
        f"{info['scenario']}",
        flush=True,
    )
    for key, value in episode.profile.metrics().as_dict().items():
        print(f"  {key:20s} {value:7.2f}")
    out = Path(args.out)
    name = f"{args.name or episode.policy}_seed{args.seed}"
    for path, span in ((out / f"{name}.png", None), (out / f"{name}_peak.png", peak_span(episode))):
        draw(episode, path, span)
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
