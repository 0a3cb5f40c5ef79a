"""The one ending of the table tools: write the markdown report to `--out` (folders made) or print it."""

from __future__ import annotations

from pathlib import Path


def publish(text: str, out: str | None) -> None:
    """Write `text` to `out` and say so, or print it when `out` is None."""
    if out:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(text)
        print(f"wrote {out}")
    else:
        print(text)
