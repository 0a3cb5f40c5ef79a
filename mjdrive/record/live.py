"""Telling the user where a recorder's live stream is."""

from __future__ import annotations

from mjdrive.progress import note
from mjdrive.record import LAYOUT


def announce_live(env) -> None:
    """A note with the live stream's URL and the Foxglove layout, if `env` records with a live server."""
    url = getattr(getattr(env, "recorder", None), "live_url", None)
    if url:
        note(f"live: {url} (Foxglove: Open connection > Foxglove WebSocket; layout {LAYOUT})")
