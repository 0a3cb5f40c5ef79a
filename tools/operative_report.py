"""Study 002's operative level on the empty concatenated route (`urban/concatenated`, no road users, the decision
action set with "drive" everywhere): the route driven at the speed reference, its comfort and tracking, and the
lateral tracking under an added steering latency with and without the LQR's delay compensation.

    python -m tools.operative_report --out results/urban/operative.md

Lateral error: the car's centre from the route's centre line, every control period (10 Hz; the LQR steers the
rear axle onto a smoothed path within about 0.2 m of the route, `control.speed_profile`). Comfort metrics as in
Table 2 (`mjdrive.comfort`: 10 Hz, 0.5 s Savitzky-Golay). The pure-pursuit driver at the lanes' speed limits
(`--policy always_go`) is the reference row: the low level of the scripted drivers.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from mjdrive.cli import ArgumentParser, run_reporting_errors
from mjdrive.envs import make_env
from mjdrive.policies import make_policy
from tools.report import publish

EMPTY = {"road_users": {"car": 0, "motorcycle": 0}}
LATENCIES = (0.0, 0.1, 0.2)  # [s] added steering latency of the car
GOALS = {"time": 95.0, "jerk_p95": 2.0, "jerk_max": 4.13, "accel_p95": 2.0, "rms": 0.15, "max": 0.5}


def drive_empty(latency: float = 0.0, compensation: bool = True, policy: str | None = None,
                seed: int = 0) -> dict:
    """One episode of the empty route: the decision env driving "drive" (or the scripted `policy` with throttle,
    steer and brake); its end, time, comfort metrics and the centre's lateral error (RMS, max) [m]."""
    if policy is None:
        env = make_env("urban", "concatenated", decisions=True, steering_latency=latency,
                       operative={"delay_compensation": compensation}, **EMPTY)
        act = make_policy("always_drive", env)
    else:
        env = make_env("urban", "concatenated", **EMPTY)
        act = make_policy(policy, env)
    task = env.unwrapped.task
    observation, info = env.reset(seed=seed)
    offsets = []
    while True:
        observation, _, terminated, truncated, info = env.step(act(observation))
        offsets += [t["route_offset"] for t in task.ticks] if policy is None else [task.lane_offset]
        if terminated or truncated:
            break
    env.close()
    offsets = np.abs(np.array(offsets))
    return {"success": info["success"], "time": info["elapsed_time"], "jerk_p95": info["jerk_p95_mps3"],
            "jerk_max": info["jerk_max_mps3"], "accel_p95": info["accel_p95_mps2"],
            "jerk_lon_max": info["jerk_lon_max_mps3"], "jerk_lat_max": info["jerk_lat_max_mps3"],
            "rms": float(np.sqrt(np.mean(offsets**2))), "max": float(offsets.max())}


def _row(name: str, r: dict) -> str:
    return (f"| {name} | {'yes' if r['success'] else 'no'} | {r['time']:.1f} | {r['jerk_p95']:.2f} | "
            f"{r['jerk_max']:.2f} | {r['accel_p95']:.2f} | {r['rms']:.3f} | {r['max']:.3f} |")


def markdown(level: dict, pure_pursuit: dict, latency_rows: dict[tuple[float, bool], dict]) -> str:
    header = ["| driver | arrived | time [s] | p95 jerk [m/s^3] | max jerk [m/s^3] | p95 accel [m/s^2] "
              "| lateral error RMS [m] | max [m] |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    goals = ("| goal (the issue) | yes | <= 95 | <= 2.0 | <= 4.13 | <= 2.0 | <= 0.15 | <= 0.5 |")
    lines = ["# The operative level on the empty concatenated route", "",
             "`python -m tools.operative_report --out results/urban/operative.md`: `urban/concatenated` without "
             "road users, the decision action set with \"drive\" at every decision (0.5 s), the operative level "
             "at 10 Hz underneath (LQR lateral tracking, OSQP longitudinal MPC, the identified pedal model). "
             "Lateral error: the car's centre from the route's centre line, every control period. One episode "
             "each: the empty route is deterministic.", "", *header,
             _row("operative level (drive)", level), _row("pure pursuit at the speed limits (always_go)", pure_pursuit),
             goals, "",
             f"The operative level's maximum jerk is longitudinal {level['jerk_lon_max']:.2f} m/s^3 and lateral "
             f"{level['jerk_lat_max']:.2f} m/s^3 (the magnitude is their vector's).", "",
             "## Steering latency", "",
             "The car applies each steering command `steering_latency` later (task keyword); the LQR predicts its "
             "path errors over the servo's lag (0.04 s, measured by `python -m tools.identify_vehicle`) plus that "
             "latency with the commands already sent (`delay_compensation`), or not.", "",
             "| added latency [s] | compensation | arrived | time [s] | p95 jerk [m/s^3] | max jerk [m/s^3] "
             "| p95 accel [m/s^2] | lateral error RMS [m] | max [m] |",
             "| ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for (latency, compensation), r in latency_rows.items():
        lines.append(f"| {latency:g} | {'on' if compensation else 'off'} " + _row("", r)[3:])
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=None, help="write the markdown report here")
    args = parser.parse_args(argv)
    level = drive_empty()
    pure_pursuit = drive_empty(policy="always_go")
    latency_rows = {(latency, compensation): drive_empty(latency, compensation)
                    for latency in LATENCIES for compensation in (True, False)}
    publish(markdown(level, pure_pursuit, latency_rows), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(run_reporting_errors(Path(sys.argv[0]).name, main))
