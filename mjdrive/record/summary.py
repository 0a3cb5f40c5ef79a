"""One summary schema for `mjdrive run` and `drive` (summary.json), `mjdrive eval` (OUT.json) and `mjdrive logs`
(its table, and `--out FILE.json`): a header naming the command, task, policy and seeds, one row per
episode with units in the field names, and the means over the rows. docs/summary.md describes it."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import fields
from typing import Any

import numpy as np

from mjdrive.comfort import ComfortMetrics

SCHEMA = "mjdrive.summary/1"

# ComfortMetrics field -> its row field (units: _m_s2 metres per second squared, _m_s3 per second cubed)
COMFORT_FIELDS: dict[str, str] = {
    f.name: f"{f.name}_{'m_s3' if f.name.startswith('jerk') else 'm_s2'}" for f in fields(ComfortMetrics)}
_COMFORT_MEANING = {
    "jerk_lon_p95": "95th percentile of the longitudinal jerk's size [m/s^3]",
    "jerk_lon_max": "largest size of the longitudinal jerk [m/s^3]",
    "jerk_lat_p95": "95th percentile of the lateral jerk's size [m/s^3]",
    "jerk_lat_max": "largest size of the lateral jerk [m/s^3]",
    "jerk_p95": "95th percentile of the jerk's magnitude, hypot(longitudinal, lateral) [m/s^3]",
    "jerk_max": "largest magnitude of the jerk [m/s^3]",
    "accel_lon_p95": "95th percentile of the longitudinal acceleration's size [m/s^2]",
    "accel_lat_p95": "95th percentile of the lateral acceleration's size [m/s^2]",
    "accel_p95": "95th percentile of the acceleration's magnitude, hypot(longitudinal, lateral) [m/s^2]",
}
# the summary's comfort means: (summary field, row field)
COMFORT_MEANS = (("avg_jerk_p95_m_s3", "jerk_p95_m_s3"), ("avg_jerk_max_m_s3", "jerk_max_m_s3"),
                 ("avg_accel_p95_m_s2", "accel_p95_m_s2"))

# row field -> what it holds (units in the names: _s seconds, _m metres, _m_s metres per second)
ROW_FIELDS: dict[str, str] = {
    "episode": "index of the episode in the run, from 0",
    "seed": "the seed its reset was given (null: none)",
    "steps": "control steps",
    "reward": "episode return: the sum of the rewards (the task's units)",
    "time_s": "simulated time [s]",
    "distance_m": "distance driven by the ego [m]",
    "speed_m_s": "mean speed = distance_m / time_s [m/s]",
    "route_completion": "share of the route's waypoints reached, 0..1 (waypoints tasks; else null)",
    "success": "the episode reached its goal",
    "collision": "the ego touched something other than the road",
    "off_road": "the ego's whole footprint left the road at some step",
    "end": "why it ended: arrived, collision, physics_error, red_light or stop_sign (urban junction control), "
           "time_limit, lane_invasion, off_route, off_road, terminated (another task rule), interrupted (stopped "
           "before the env ended it)",
    "exit": "roundabout: the exit taken, counted from the entry (1 first = right turn, 2 second = straight on, "
            "3 third = left turn); else null",
    **{row: f"{_COMFORT_MEANING[name]} (comfort, see above; null: unknown)" for name, row in COMFORT_FIELDS.items()},
    "log": "the episode's MCAP file name (null: not recorded)",
}

# summary field -> what it holds (means over the rows)
SUMMARY_FIELDS: dict[str, str] = {
    "avg_reward": "mean episode return",
    "avg_time_s": "mean simulated time [s]",
    "avg_speed_m_s": "mean of the rows' speed_m_s [m/s]",
    "avg_distance_m": "mean distance [m]",
    "avg_steps": "mean control steps",
    "success_pct": "episodes with success [%]",
    "collision_pct": "episodes with a collision [%]",
    "success_on_road_pct": "successes whose footprint never left the road entirely [%]",
    "route_completion_mean": "mean route_completion, 0..1 (waypoints tasks only)",
    "route_completion_min": "lowest route_completion (waypoints tasks only)",
    "route_completion_max": "highest route_completion (waypoints tasks only)",
    "avg_jerk_p95_m_s3": "mean of the rows' jerk_p95_m_s3 [m/s^3] (rows with a value)",
    "avg_jerk_max_m_s3": "mean of the rows' jerk_max_m_s3 [m/s^3] (rows with a value)",
    "avg_accel_p95_m_s2": "mean of the rows' accel_p95_m_s2 [m/s^2] (rows with a value)",
}


def end_reason(info: dict, terminated: bool, truncated: bool, interrupted: bool = False) -> str:
    """Why the episode ended, from the task's info flags."""
    if info.get("collision"):
        return "collision"
    if info.get("physics_error"):
        return "physics_error"
    if info.get("violation"):  # urban tasks' junction control: "red_light" or "stop_sign"
        return str(info["violation"])
    if info.get("success"):
        return "arrived"
    if interrupted:
        return "interrupted"
    if truncated:
        return "time_limit"
    for key in ("lane_invasion", "off_route", "off_road"):
        if info.get(key):
            return key
    return "terminated" if terminated else "running"


def roundabout_arms(domain: str, task: str, task_kwargs: dict | None = None) -> int | None:
    """Arms of a task's roundabout (to count exits from the entry), or None for a task without one."""
    from mjdrive import suite

    config_class, defaults = suite.task_config(domain, task)
    try:
        config = config_class.from_dict(task_kwargs or {}, defaults)
    except ValueError:
        return None
    return getattr(config, "arms", None)


def relative_exit(info: dict, arms: int | None) -> int | None:
    """The exit counted from the entry (1: the first exit): the roundabout task's `exit_number`, or (in logs older
    than it) from the absolute arm indices in `info`."""
    if info.get("exit_number") is not None:
        return int(info["exit_number"])
    if arms is None or info.get("entry") is None or info.get("exit") is None:
        return None
    return (int(info["exit"]) - int(info["entry"]) - 1) % arms + 1


def _finite(value: Any) -> float | None:
    """A finite float, or None (for None, NaN and inf)."""
    return None if value is None or not math.isfinite(float(value)) else float(value)


def _number(value: Any, digits: int) -> float | None:
    if value is None:
        return None
    value = float(value)
    return round(value, digits) if math.isfinite(value) else None


def comfort_fields(metrics: Mapping[str, Any]) -> dict[str, float | None]:
    """The row fields (COMFORT_FIELDS) of comfort metrics keyed by `ComfortMetrics` field name (None where
    missing or NaN), at full precision."""
    return {row: _finite(metrics.get(name)) for name, row in COMFORT_FIELDS.items()}


def info_comfort(info: Mapping[str, Any]) -> dict[str, Any]:
    """The comfort metrics of a task's `info` (keys of `ComfortMetrics.as_dict()`) by field name."""
    units = ComfortMetrics.nan().as_dict()
    return {key.rsplit("_", 1)[0]: info[key] for key in units if key in info}


def episode_row(info: dict, *, episode: int, seed: int | None, reward: float, steps: int, terminated: bool,
                truncated: bool, control_dt: float, interrupted: bool = False, arms: int | None = None,
                log: str | None = None, comfort: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One row of the schema from an episode's last `info` (the task's metrics), its return and steps;
    `control_dt` [s] gives the time of a task whose info lacks `elapsed_time`. `comfort`: the comfort metrics
    by `ComfortMetrics` field name (default: those in `info`, which a task has at its episode's end)."""
    comfort = info_comfort(info) if comfort is None else comfort
    time_s = float(info.get("elapsed_time", steps * control_dt))
    distance = info.get("distance")
    completion = info.get("route_completion")
    row = {
        "episode": int(episode), "seed": seed, "steps": int(steps), "reward": _number(reward, 2),
        "time_s": _number(time_s, 2), "distance_m": _number(distance, 2),
        "speed_m_s": _number(float(distance) / time_s, 3) if distance is not None and time_s > 0 else None,
        "route_completion": _number(completion, 4),
        "success": bool(info.get("success", False)), "collision": bool(info.get("collision", False)),
        "off_road": bool(info.get("off_road", False)),
        "end": end_reason(info, terminated, truncated, interrupted),
        "exit": relative_exit(info, arms),
        **{row: _number(value, 3) for row, value in comfort_fields(comfort).items()},
        "log": log,
    }
    return row


def summarize(rows: list[dict]) -> dict[str, float]:
    """The means over the rows (SUMMARY_FIELDS); route completion only where the rows have it."""

    def mean(key: str) -> float:
        values = [row[key] for row in rows if row[key] is not None]
        return float(np.mean(values)) if values else float("nan")

    completion = [row["route_completion"] for row in rows if row["route_completion"] is not None]
    out = {
        "avg_reward": round(mean("reward"), 2), "avg_time_s": round(mean("time_s"), 2),
        "avg_speed_m_s": round(mean("speed_m_s"), 3), "avg_distance_m": round(mean("distance_m"), 2),
        "avg_steps": round(mean("steps"), 1), "success_pct": round(100 * mean("success"), 1),
        "collision_pct": round(100 * mean("collision"), 1),
        # arrivals that never left the road entirely (eq. 12 charges off-road driving only 0.05 per step)
        "success_on_road_pct": round(100 * float(np.mean([r["success"] and not r.get("off_road", False)
                                                          for r in rows])), 1),
    }
    if completion:
        out.update({"route_completion_mean": round(float(np.mean(completion)), 4),
                    "route_completion_min": round(float(np.min(completion)), 4),
                    "route_completion_max": round(float(np.max(completion)), 4)})
    for name, key in COMFORT_MEANS:
        if any(row.get(key) is not None for row in rows):
            out[name] = round(float(np.mean([row[key] for row in rows if row.get(key) is not None])), 3)
    return out


COMFORT_COLUMNS = "| p95 jerk (m/s^3) | max jerk (m/s^3) | p95 accel (m/s^2) "  # markdown headers of comfort_cells


def comfort_cells(row: dict) -> str:
    """A row's p95 jerk, max jerk and p95 acceleration as markdown cells (COMFORT_COLUMNS; "-": unknown)."""
    values = (row.get(key) for key in ("jerk_p95_m_s3", "jerk_max_m_s3", "accel_p95_m_s2"))
    return "".join(f"| {'-' if value is None else f'{value:.2f}'} " for value in values)


def comfort_line(summary: dict) -> str:
    """The summary's comfort means as a markdown sentence ("" when no episode has them)."""
    if not all(name in summary for name, _ in COMFORT_MEANS):
        return ""
    return (f"Comfort (`mjdrive.comfort`, means over the episodes): p95 jerk {summary['avg_jerk_p95_m_s3']:.2f} "
            f"m/s^3, max jerk {summary['avg_jerk_max_m_s3']:.2f} m/s^3, p95 acceleration "
            f"{summary['avg_accel_p95_m_s2']:.2f} m/s^2.")


def document(command: str, task: str, task_kwargs: dict, policy: str, rows: list[dict],
             **header: Any) -> dict[str, Any]:
    """The whole summary: schema, command, task, its kwargs, policy, first seed, episodes, `header` extras,
    the means (`summary`) and the rows."""
    seeds = [row["seed"] for row in rows if row["seed"] is not None]
    return {"schema": SCHEMA, "command": command, "task": task, "task_kwargs": task_kwargs, "policy": policy,
            "seed": min(seeds) if seeds else None, "episodes": len(rows), **header,
            "summary": summarize(rows) if rows else {}, "rows": rows}


def markdown_reference() -> str:
    """The schema's fields as markdown (docs/summary.md's tables)."""
    lines = ["| row field | meaning |", "| --- | --- |"]
    lines += [f"| `{name}` | {meaning} |" for name, meaning in ROW_FIELDS.items()]
    lines += ["", "| summary field | meaning |", "| --- | --- |"]
    lines += [f"| `{name}` | {meaning} |" for name, meaning in SUMMARY_FIELDS.items()]
    return "\n".join(lines)
