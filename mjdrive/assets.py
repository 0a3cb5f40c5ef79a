"""Where the package's data files are."""

from __future__ import annotations

from pathlib import Path

XML_DIR = Path(__file__).resolve().parent / "xml"  # MJCF assets: vehicles/, scenes/
MAPS_DIR = Path(__file__).resolve().parent / "maps"  # OpenDRIVE maps shipped by name (urban/opendrive's `opendrive`)
