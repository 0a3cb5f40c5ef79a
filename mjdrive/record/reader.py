"""Read episode files back with the `mcap` reader: metadata, per-topic messages (JSON and protobuf decoded),
and the `mjdrive logs` table. Truncated files (a killed writer, a cut copy) are read up to the damage and
flagged `complete=False` with the reason, instead of raising."""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Channel, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from mjdrive.record import proto


class EpisodeFileError(ValueError):
    """A file that is not a readable mjdrive episode (not MCAP, or no mjdrive metadata)."""


@dataclass
class Episode:
    """One episode file: `metadata` (the "mjdrive" record, JSON values decoded), `summary` (None if the
    file ends before it), raw `messages` per topic as (log_time [ns], bytes), and whether it is complete."""

    path: Path
    metadata: dict[str, Any]
    summary: dict[str, Any] | None
    messages: dict[str, list[tuple[int, bytes]]]
    schemas: dict[str, tuple[str, str, bytes]]  # topic -> (schema name, encoding, data)
    complete: bool
    error: str | None = None
    message_encodings: dict[str, str] = field(default_factory=dict)

    @property
    def topics(self) -> set[str]:
        return set(self.messages)

    def json(self, topic: str) -> list[dict]:
        return [json.loads(data) for _, data in self.messages.get(topic, [])]

    def decoded(self, topic: str) -> list:
        """Protobuf messages of `topic`, decoded with the schema stored in the file."""
        name, _, data = self.schemas[topic]
        return [proto.decode(name, data, payload) for _, payload in self.messages.get(topic, [])]

    def physics(self) -> dict[str, np.ndarray]:
        """Stacked /physics states: time (T,1), qpos (T,nq), qvel (T,nv), act, mocap_pos, mocap_quat (T,...);
        T = steps + 1, the reset state first."""
        states = self.decoded("/physics")
        return {"time": np.array([s.time for s in states]).reshape(len(states), 1),
                "qpos": np.array([list(s.qpos) for s in states]).reshape(len(states), -1),
                "qvel": np.array([list(s.qvel) for s in states]).reshape(len(states), -1),
                "act": np.array([list(s.act) for s in states]).reshape(len(states), -1),
                "mocap_pos": np.array([list(s.mocap_pos) for s in states]).reshape(len(states), -1),
                "mocap_quat": np.array([list(s.mocap_quat) for s in states]).reshape(len(states), -1)}

    def actions(self) -> np.ndarray:
        """(steps, 3) applied (throttle, steer, brake); for an env of the decision action set, (steps,) the
        decisions' indices."""
        messages = self.json("/action")
        if messages and "decision" in messages[0]:
            return np.array([a["decision"] for a in messages], dtype=np.int64)
        return np.array([[a["throttle"], a["steer"], a["brake"]] for a in messages]).reshape(-1, 3)

    @property
    def readable_steps(self) -> int:
        """Steps whose action and resulting state are both in the file."""
        return max(0, min(len(self.messages.get("/action", [])), len(self.messages.get("/physics", [])) - 1))

    def describe_damage(self) -> str:
        return (f"{self.path} is incomplete ({self.error}); the writer was probably killed or the file was cut. "
                f"{self.readable_steps} steps are readable.")


def _metadata_values(record: Metadata) -> dict[str, Any]:
    out = {}
    for key, value in record.metadata.items():
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def read_episode(path: str | Path, topics: set[str] | None = None) -> Episode:
    """Read an episode file (all topics, or only `topics`). Raises EpisodeFileError if it is not an mjdrive
    MCAP file; a damaged file gives `complete=False` and what could be read before the damage."""
    path = Path(path)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
    metadata: dict[str, Any] | None = None
    summary = None
    complete, error = False, None
    with open(path, "rb") as f:
        try:
            for record in StreamReader(f, skip_magic=False, validate_crcs=True).records:
                if isinstance(record, Message):
                    channel = channels[record.channel_id]
                    if topics is None or channel.topic in topics:
                        messages[channel.topic].append((record.log_time, record.data))
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Metadata):
                    if record.name == "mjdrive":
                        metadata = _metadata_values(record)
                    elif record.name == "summary":
                        summary = _metadata_values(record)
                elif isinstance(record, (DataEnd, Footer)):
                    complete = isinstance(record, Footer) or complete
        except Exception as exc:  # the mcap reader raises several types on cut or corrupt data
            if metadata is None and not messages:
                raise EpisodeFileError(f"{path} is not a readable MCAP file ({type(exc).__name__}: {exc})") from exc
            error = f"{type(exc).__name__}: {exc}" if str(exc) else f"{type(exc).__name__}: data ends early"
            complete = False
    if metadata is None:
        raise EpisodeFileError(f"{path} has no mjdrive metadata (not an mjdrive episode log?)")
    if complete and summary is None:
        complete, error = False, "no summary record"
    if not complete and error is None:
        error = "the file ends before its footer"
    by_topic = {c.topic: c for c in channels.values()}
    topic_schemas = {t: (schemas[c.schema_id].name, schemas[c.schema_id].encoding, schemas[c.schema_id].data)
                     for t, c in by_topic.items() if c.schema_id in schemas}
    return Episode(path, metadata, summary, dict(messages), topic_schemas, complete, error,
                   {t: c.message_encoding for t, c in by_topic.items()})


# --- mjdrive logs ---------------------------------------------------------------------------------------


def episode_files(folder: str | Path) -> list[Path]:
    """The episode files of a folder: finished `.mcap` and unfinished `.mcap.part`, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} is not a folder")
    return sorted([*folder.glob("*.mcap"), *folder.glob("*.mcap.part")])


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.{digits}f}" if math.isfinite(value) else str(value)
    return str(value)


def _mean(summary: dict, key: str) -> str:
    """A mean of the summary for the table's last row ("-" when no row has the value)."""
    return f"{summary[key]:.2f} (mean)" if key in summary else "-"


def logs_rows(folder: str | Path, progress: bool = False) -> tuple[list[dict], list[str], list[str], list[str]]:
    """(schema rows of the complete episodes in `folder`, their task names, one table row per damaged or
    unreadable file, one line per problem). Rows follow `mjdrive.record.summary.ROW_FIELDS`, as run's and
    eval's do. `progress`: a bar over the files on stderr."""
    from mjdrive.progress import Progress
    from mjdrive.record.summary import COMFORT_FIELDS, episode_row, roundabout_arms

    rows: list[dict] = []
    tasks: list[str] = []
    problems: list[str] = []
    damaged: list[str] = []
    files = episode_files(folder)
    for path in Progress(files, desc="reading logs", unit="file", disable=not progress, delay=1.0):
        try:
            episode = read_episode(path, topics={"/action", "/physics"})
        except EpisodeFileError as error:
            damaged.append(f"| {path.name} | - | - | - | - | - | - | - | - | - | - | - | - | unreadable |")
            problems.append(str(error))
            continue
        meta, summary = episode.metadata, episode.summary
        if summary is None:
            damaged.append(f"| {path.name} | {meta.get('task')} | {_fmt(meta.get('seed'))} | {episode.readable_steps} "
                           "| - | - | - | - | - | - | - | - | - | incomplete |")
            problems.append(episode.describe_damage())
            continue
        steps = int(summary.get("steps", 0))
        arms = roundabout_arms(meta["domain"], meta["task_name"], meta.get("task_kwargs"))
        # the comfort metrics of the summary (the recorder's, mjdrive.comfort); older logs: the task's info
        comfort = {name: summary[key] for name, key in COMFORT_FIELDS.items() if key in summary} or None
        rows.append(episode_row(summary.get("info", {}), episode=len(rows), seed=summary.get("seed"),
                                reward=summary.get("return", 0.0), steps=steps,
                                terminated=bool(summary.get("terminated")), truncated=bool(summary.get("truncated")),
                                interrupted=bool(summary.get("interrupted")), arms=arms, log=path.name, comfort=comfort,
                                control_dt=float(summary.get("sim_time", 0.0)) / max(steps, 1)))
        tasks.append(summary.get("task", meta.get("task")))
    return rows, tasks, damaged, problems


def logs_document(folder: str | Path, rows_of_folder: tuple | None = None) -> dict[str, Any]:
    """`mjdrive logs --out FILE.json`: the folder's episodes in the summary schema of run and eval
    (`rows_of_folder`: `logs_rows(folder)` if already read)."""
    from mjdrive.record.summary import document

    rows, tasks, _, problems = rows_of_folder or logs_rows(folder)
    return document("logs", " + ".join(dict.fromkeys(tasks)), {}, "-", rows, folder=str(folder),
                    problems=problems)


def logs_table(folder: str | Path, rows_of_folder: tuple | None = None) -> str:
    """A markdown table of the episodes in `folder` (one row per complete file, in the summary schema of
    run and eval), their means, and the damaged files (`rows_of_folder`: `logs_rows(folder)` if already read)."""
    from mjdrive.record.summary import summarize

    rows, tasks, damaged, problems = rows_of_folder or logs_rows(folder)
    lines = [
        f"# Episodes in {folder}", "",
        "| file | task | seed | steps | reward | success | collision | time [s] | mean speed [m/s] "
        "| p95 jerk [m/s^3] | max jerk [m/s^3] | p95 accel [m/s^2] | exit | end |",
        "| --- | --- | ---: | ---: | ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for row, task in zip(rows, tasks, strict=True):
        lines.append(f"| {row['log']} | {task} | {_fmt(row['seed'])} | {row['steps']} | {_fmt(row['reward'], 1)} "
                     f"| {_fmt(row['success'])} | {_fmt(row['collision'])} | {_fmt(row['time_s'], 1)} "
                     f"| {_fmt(row['speed_m_s'])} | {_fmt(row['jerk_p95_m_s3'])} | {_fmt(row['jerk_max_m_s3'])} "
                     f"| {_fmt(row['accel_p95_m_s2'])} | {_fmt(row['exit'])} | {row['end']} |")
    lines += damaged
    if rows:
        s = summarize(rows)
        lines.append(f"| **all {len(rows)} complete** | | | {sum(r['steps'] for r in rows)} "
                     f"| {s['avg_reward']:.1f} (mean) | {s['success_pct']:.0f}% | {s['collision_pct']:.0f}% "
                     f"| {s['avg_time_s']:.1f} (mean) | {s['avg_speed_m_s']:.2f} (mean) "
                     f"| {_mean(s, 'avg_jerk_p95_m_s3')} | {_mean(s, 'avg_jerk_max_m_s3')} "
                     f"| {_mean(s, 'avg_accel_p95_m_s2')} | | |")
    if problems:
        lines += ["", "Problems:", *[f"- {p}" for p in problems]]
    return "\n".join(lines)
