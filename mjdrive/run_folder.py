"""One folder per run: made fresh, refused when it holds another run, emptied of a run's files on request.
An unfinished episode log (`*.mcap.part`) whose writer is gone (an interrupted or killed run) never blocks
the next run: it is removed, with a note; one a live process still writes is a run in progress."""

from __future__ import annotations

import fcntl
import os
import sys
from pathlib import Path

RUN_FILES = ("*.mcap", "*.mcap.part", "episode_*.mp4", "summary.json")  # what `mjdrive run` writes
UNFINISHED = "*.mcap.part"  # an episode log being written (mjdrive.record.recorder)


def lock_part(descriptor: int) -> int:
    """Take the writer's lock on an unfinished log's open `descriptor` (an exclusive flock, released when the
    descriptor closes or its process ends, however it ends); returns the descriptor."""
    fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return descriptor


def part_is_live(path: Path) -> bool:
    """A process holds the writer's lock on the unfinished log `path` (it is being written now)."""
    try:
        descriptor = os.open(path, os.O_RDONLY)
    except FileNotFoundError:
        return False
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(descriptor)  # also releases the lock taken just now
    return False


def remove_abandoned_parts(folder: Path, option: str) -> None:
    """Remove the unfinished logs in `folder` whose writer is gone (saying so on stderr); ValueError if a live
    process is writing one (a run in progress there)."""
    parts = sorted(folder.glob(UNFINISHED))
    live = [part.name for part in parts if part_is_live(part)]
    if live:
        raise ValueError(f"{option} {folder} is in use: a running process is writing {live[0]} there; choose "
                         "another folder or wait for that run to end")
    for part in parts:
        part.unlink(missing_ok=True)
    if parts:
        print(f"note: removed {len(parts)} unfinished log{'s' if len(parts) > 1 else ''} ({parts[0].name}"
              f"{', ...' if len(parts) > 1 else ''}) left in {folder} by an interrupted run", file=sys.stderr)


def fresh_folder(path: str | Path, overwrite: bool, patterns: tuple[str, ...] = RUN_FILES,
                 option: str = "--out") -> Path:
    """A folder for one run's outputs: made if missing; unfinished logs of an interrupted run removed (never a
    live one's); an existing non-empty one is then refused (so two runs never mix), or with `overwrite`
    emptied of the files a run writes (`patterns`); anything else in it is left alone and refused, never
    deleted."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{option} {folder} is a file, not a folder")
    if folder.is_dir():
        remove_abandoned_parts(folder, option)
    if folder.is_dir() and any(folder.iterdir()):
        if not overwrite:
            raise ValueError(f"{option} {folder} is not empty (a folder holds one run): choose a new folder, "
                             "or pass --overwrite to replace its run")
        for pattern in patterns:
            for file in folder.glob(pattern):
                file.unlink()
        others = sorted(p.name for p in folder.iterdir())
        if others:
            raise ValueError(f"{option} {folder} holds files that are not a run's ({', '.join(others[:3])}"
                             f"{', ...' if len(others) > 3 else ''}); --overwrite only replaces a run's files")
    folder.mkdir(parents=True, exist_ok=True)
    return folder
