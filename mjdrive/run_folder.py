"""One folder per run: made fresh, refused when it holds another run, emptied of a run's files on request."""

from __future__ import annotations

from pathlib import Path

RUN_FILES = ("*.mcap", "*.mcap.part", "episode_*.mp4", "summary.json")  # what `mjdrive run` writes


def fresh_folder(path: str | Path, overwrite: bool, patterns: tuple[str, ...] = RUN_FILES,
                 option: str = "--out") -> Path:
    """A folder for one run's outputs: made if missing; an existing non-empty one is refused (so two runs
    never mix), or with `overwrite` emptied of the files a run writes (`patterns`); anything else in it
    is left alone and refused, never deleted."""
    folder = Path(path)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{option} {folder} is a file, not a folder")
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
