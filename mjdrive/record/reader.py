"""Read episode files back with the `mcap` reader: metadata, per-topic messages (JSON and protobuf decoded),
and the `mjdrive logs` table. Truncated files (a killed writer, a cut copy) are read up to the damage and
flagged `complete=False` with the reason, instead of raising. Every CRC the file has is checked (each
chunk's, the data section's, the summary section's): a damaged file is read as far as it can be and
flagged with `damage`, one line per file from `describe_damage`."""

from __future__ import annotations

import io
import json
import math
import os
import zlib
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, NamedTuple

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE, CRCValidationError, StreamReader, breakup_chunk
from mcap.writer import MCAP0_MAGIC

from mjdrive.record import proto


class EpisodeFileError(ValueError):
    """A file that is not a readable mjdrive episode (not MCAP, or no mjdrive metadata)."""


DATA_DAMAGE = ("chunk", "its data section")  # how the damage items of the data section begin


@dataclass
class Episode:
    """One episode file: `metadata` (the "mjdrive" record, JSON values decoded), `summary` (None if the
    file ends before it), raw `messages` per topic as (log_time [ns], bytes), whether it is complete (read
    to the end of its data section, with its summary record) and what its CRC checks found damaged.
    The messages of every topic are a prefix of the episode's: after a damaged chunk none are kept."""

    path: Path
    metadata: dict[str, Any]
    summary: dict[str, Any] | None
    messages: dict[str, list[tuple[int, bytes]]]
    schemas: dict[str, tuple[str, str, bytes]]  # topic -> (schema name, encoding, data)
    complete: bool
    error: str | None = None  # why it is not complete
    message_encodings: dict[str, str] = field(default_factory=dict)
    damage: list[str] = field(default_factory=list)  # what the CRC checks and the summary section show damaged

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
        if messages and messages[0].get("decision") is not None:
            return np.array([a["decision"] for a in messages], dtype=np.int64)
        return np.array([[a["throttle"], a["steer"], a["brake"]] for a in messages]).reshape(-1, 3)

    @property
    def readable_steps(self) -> int:
        """Steps whose action and resulting state are both in the file."""
        return max(0, min(len(self.messages.get("/action", [])), len(self.messages.get("/physics", [])) - 1))

    @property
    def intact(self) -> bool:
        """Complete, and every CRC it has checks out."""
        return self.complete and not self.damage

    def describe_damage(self) -> str:
        """What is wrong with the file and how it was read, on one line ("" for an intact file)."""
        steps = f"{self.readable_steps} steps are readable"
        if not self.complete:
            cause = ("it is unfinished: its writer stopped or was killed mid-episode" if self.path.suffix == ".part"
                     else "the writer was probably killed or the file was cut or damaged")
            found = f"; also {'; '.join(self.damage)}" if self.damage else ""
            return f"{self.path} is incomplete ({self.error}); {cause}{found}. {steps}."
        if self.damage:
            data_ok = not any(item.startswith(DATA_DAMAGE) for item in self.damage)
            how = "the data section passes its CRC check, " if data_ok else ""
            summary = "its summary record was read" if self.summary is not None else "its summary record is lost"
            return f"{self.path} is damaged: {'; '.join(self.damage)}. Read from the start: {how}{steps}, {summary}."
        return ""


def _metadata_values(record: Metadata) -> dict[str, Any]:
    out = {}
    for key, value in record.metadata.items():
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _crc_text(error: CRCValidationError) -> str:
    return f"stored CRC {error.expected:#010x}, computed {error.actual:#010x}"


FOOTER_BODY = 8 + 8 + 4  # [bytes] summary_start, summary_offset_start, summary_crc
FOOTER_RECORD = 1 + 8 + FOOTER_BODY  # [bytes] opcode, record length, body


def summary_section_damage(file: BinaryIO) -> str | None:
    """What is wrong with the end of an MCAP file (its summary section, footer, closing magic) by the footer's
    CRC of the summary section (MCAP spec: every byte from the summary start through the footer's
    summary_offset_start), or None when it checks out or the file has no such CRC (0)."""
    size = file.seek(0, os.SEEK_END)
    footer_at = size - MAGIC_SIZE - FOOTER_RECORD
    if footer_at < MAGIC_SIZE:
        return "it is too short to hold a footer"
    file.seek(footer_at)
    raw = file.read(FOOTER_RECORD + MAGIC_SIZE)
    if raw[FOOTER_RECORD:] != MCAP0_MAGIC:
        return "its closing magic bytes are damaged"
    if raw[0] != Opcode.FOOTER or int.from_bytes(raw[1:9], "little") != FOOTER_BODY:
        return "its footer is damaged"
    footer = Footer.read(ReadDataStream(io.BytesIO(raw[9:FOOTER_RECORD])))
    start = footer.summary_start or footer_at  # 0: no summary section, the CRC covers the footer's fields
    stored = footer.summary_crc
    if stored == 0:
        return None
    if not MAGIC_SIZE <= start <= footer_at:
        return f"its footer is damaged (it places the summary section at byte {start} of {size})"
    file.seek(start)
    computed = zlib.crc32(file.read(footer_at + 1 + 8 + 8 + 8 - start))
    if computed != stored:
        return (f"its summary section (bytes {start}-{footer_at}: the schemas, channels and indexes a seeking "
                f"reader uses) fails its CRC check (stored CRC {stored:#010x}, computed {computed:#010x})")
    return None


def read_episode(path: str | Path, topics: set[str] | None = None) -> Episode:
    """Read an episode file (all topics, or only `topics`) from the start, checking every CRC it has. Raises
    EpisodeFileError if it is not an mjdrive MCAP file. A file cut short gives `complete=False` and what could
    be read before its end; a chunk that fails its CRC check is left out with every message after it (so each
    topic stays a prefix of the episode) while the records outside chunks (the summary metadata) are still
    read; a damaged data or summary section is reported in `damage`."""
    path = Path(path)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    messages: dict[str, list[tuple[int, bytes]]] = defaultdict(list)
    metadata: dict[str, Any] | None = None
    summary = None
    error, damage = None, []
    unreadable = None  # why the summary section did not parse
    data_end = skipping = False  # read to DataEnd; messages left out after a damaged chunk

    def take(record) -> None:
        nonlocal metadata, summary
        if isinstance(record, Message):
            channel = channels.get(record.channel_id)
            if channel is not None and (topics is None or channel.topic in topics):
                messages[channel.topic].append((record.log_time, record.data))
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Metadata) and record.name == "mjdrive":
            metadata = _metadata_values(record)
        elif isinstance(record, Metadata) and record.name == "summary":
            summary = _metadata_values(record)

    with open(path, "rb") as f:
        chunks = 0
        try:
            for record in StreamReader(f, skip_magic=False, emit_chunks=True, validate_crcs=True).records:
                if isinstance(record, Chunk):
                    chunks += 1
                    if skipping:
                        continue
                    try:
                        inner = breakup_chunk(record, validate_crc=True)
                    except Exception as exc:  # a failed CRC, or data that no longer decompresses or parses
                        crc = isinstance(exc, CRCValidationError)
                        reason = _crc_text(exc) if crc else f"{type(exc).__name__}: {exc}"
                        damage.append(f"chunk {chunks} fails its check ({reason}): its messages and all later "
                                      "ones are left out")
                        skipping = True
                        continue
                    for item in inner:
                        take(item)
                elif isinstance(record, DataEnd):
                    data_end = True
                elif data_end or (skipping and isinstance(record, Message)):
                    continue  # the summary section repeats schemas and channels; after a bad chunk no message is kept
                else:
                    take(record)
        except CRCValidationError as exc:  # raised at DataEnd: a byte outside the chunks changed (or in a chunk)
            data_end = True
            if not skipping:
                damage.append(f"its data section fails its CRC check ({_crc_text(exc)}) though every chunk passes "
                              "its own: a record outside the chunks (metadata, schemas, channels, indexes) changed")
        except Exception as exc:  # the mcap reader raises several types on cut or corrupt data
            if metadata is None and not messages:
                raise EpisodeFileError(f"{path} is not a readable MCAP file ({type(exc).__name__}: {exc})") from exc
            if data_end:
                unreadable = f"{type(exc).__name__}: {exc}"
            else:
                error = f"{type(exc).__name__}: {exc}" if str(exc) else f"{type(exc).__name__}: data ends early"
        if data_end:  # the data section was read: check the rest by the footer's CRC
            problem = summary_section_damage(f)
            if problem is not None:
                damage.append(problem)
            elif unreadable is not None:
                damage.append(f"its summary section does not parse ({unreadable})")
    if metadata is None:
        raise EpisodeFileError(f"{path} has no mjdrive metadata (not an mjdrive episode log?)")
    complete = data_end and summary is not None
    if data_end and summary is None:
        error = "no summary record"
    if not complete and error is None:
        error = "the file ends before its footer"
    by_topic = {c.topic: c for c in channels.values()}
    topic_schemas = {t: (schemas[c.schema_id].name, schemas[c.schema_id].encoding, schemas[c.schema_id].data)
                     for t, c in by_topic.items() if c.schema_id in schemas}
    return Episode(path, metadata, summary, dict(messages), topic_schemas, complete, error,
                   {t: c.message_encoding for t, c in by_topic.items()}, damage)


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


class FolderLogs(NamedTuple):
    """The episode files of a folder as `logs_rows` reads them."""

    rows: list[dict]  # schema rows of the episodes whose summary was read (`mjdrive.record.summary.ROW_FIELDS`)
    tasks: list[str]  # each row's task
    damaged: list[str]  # one table row per unreadable or incomplete file
    problems: list[str]  # one line per file that is not intact: what is wrong and how it was read
    flagged: list[bool]  # each row's file is damaged (its CRC checks failed) though its summary was read


def logs_rows(folder: str | Path, progress: bool = False) -> FolderLogs:
    """The episode files of `folder` read back (`FolderLogs`): rows follow `mjdrive.record.summary.ROW_FIELDS`,
    as run's and eval's do. `progress`: a bar over the files on stderr."""
    from mjdrive.progress import Progress
    from mjdrive.record.summary import COMFORT_FIELDS, episode_row, roundabout_arms

    read = FolderLogs([], [], [], [], [])
    files = episode_files(folder)
    for path in Progress(files, desc="reading logs", unit="file", disable=not progress, delay=1.0):
        try:
            episode = read_episode(path, topics={"/action", "/physics"})
        except EpisodeFileError as error:
            read.damaged.append(f"| {path.name} | - | - | - | - | - | - | - | - | - | - | - | - | unreadable |")
            read.problems.append(str(error))
            continue
        meta, summary = episode.metadata, episode.summary
        if summary is None:
            read.damaged.append(f"| {path.name} | {meta.get('task')} | {_fmt(meta.get('seed'))} "
                                f"| {episode.readable_steps} | - | - | - | - | - | - | - | - | - | incomplete |")
            read.problems.append(episode.describe_damage())
            continue
        if not episode.intact:
            read.problems.append(episode.describe_damage())
        steps = int(summary.get("steps", 0))
        arms = roundabout_arms(meta["domain"], meta["task_name"], meta.get("task_kwargs"))
        # the comfort metrics of the summary (the recorder's, mjdrive.comfort); older logs: the task's info
        comfort = {name: summary[key] for name, key in COMFORT_FIELDS.items() if key in summary} or None
        read.rows.append(episode_row(
            summary.get("info", {}), episode=len(read.rows), seed=summary.get("seed"),
            reward=summary.get("return", 0.0), steps=steps, terminated=bool(summary.get("terminated")),
            truncated=bool(summary.get("truncated")), interrupted=bool(summary.get("interrupted")), arms=arms,
            log=path.name, comfort=comfort, control_dt=float(summary.get("sim_time", 0.0)) / max(steps, 1)))
        read.tasks.append(summary.get("task", meta.get("task")))
        read.flagged.append(not episode.intact)
    return read


def logs_document(folder: str | Path, rows_of_folder: FolderLogs | None = None) -> dict[str, Any]:
    """`mjdrive logs --out FILE.json`: the folder's episodes in the summary schema of run and eval
    (`rows_of_folder`: `logs_rows(folder)` if already read)."""
    from mjdrive.record.summary import document

    rows, tasks, _, problems, _ = rows_of_folder or logs_rows(folder)
    return document("logs", " + ".join(dict.fromkeys(tasks)), {}, "-", rows, folder=str(folder),
                    problems=problems)


def logs_table(folder: str | Path, rows_of_folder: FolderLogs | None = None) -> str:
    """A markdown table of the episodes in `folder` (one row per file whose summary was read, in the summary
    schema of run and eval; a damaged one marked so), their means, the incomplete and unreadable files, and
    one line per file that is not intact (`rows_of_folder`: `logs_rows(folder)` if already read)."""
    from mjdrive.record.summary import summarize

    rows, tasks, damaged, problems, flagged = rows_of_folder or logs_rows(folder)
    lines = [
        f"# Episodes in {folder}", "",
        "| file | task | seed | steps | reward | success | collision | time [s] | mean speed [m/s] "
        "| p95 jerk [m/s^3] | max jerk [m/s^3] | p95 accel [m/s^2] | exit | end |",
        "| --- | --- | ---: | ---: | ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | --- |",
    ]
    for row, task, bad in zip(rows, tasks, flagged, strict=True):
        name = f"{row['log']} (damaged)" if bad else row["log"]
        lines.append(f"| {name} | {task} | {_fmt(row['seed'])} | {row['steps']} | {_fmt(row['reward'], 1)} "
                     f"| {_fmt(row['success'])} | {_fmt(row['collision'])} | {_fmt(row['time_s'], 1)} "
                     f"| {_fmt(row['speed_m_s'])} | {_fmt(row['jerk_p95_m_s3'])} | {_fmt(row['jerk_max_m_s3'])} "
                     f"| {_fmt(row['accel_p95_m_s2'])} | {_fmt(row['exit'])} | {row['end']} |")
    lines += damaged
    if rows:
        s = summarize(rows)
        marked = f" ({sum(flagged)} damaged)" if any(flagged) else ""
        lines.append(f"| **all {len(rows)} complete{marked}** | | | {sum(r['steps'] for r in rows)} "
                     f"| {s['avg_reward']:.1f} (mean) | {s['success_pct']:.0f}% | {s['collision_pct']:.0f}% "
                     f"| {s['avg_time_s']:.1f} (mean) | {s['avg_speed_m_s']:.2f} (mean) "
                     f"| {_mean(s, 'avg_jerk_p95_m_s3')} | {_mean(s, 'avg_jerk_max_m_s3')} "
                     f"| {_mean(s, 'avg_accel_p95_m_s2')} | | |")
    if problems:
        lines += ["", "Problems:", *[f"- {p}" for p in problems]]
    return "\n".join(lines)
