"""Learner configs: YAML/JSON files, configs/ by name, and `a.b=value` overrides."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from mjdrive.config import parse_value, parse_yaml

CONFIG_DIR = Path(__file__).resolve().parent / "configs"


def load_config(name_or_path: str | Path) -> dict[str, Any]:
    """A config from a .yaml/.json file, or by name from agents/configs/ (e.g. "sac_camera84")."""
    path = Path(name_or_path)
    if not path.exists():
        for suffix in (".yaml", ".json"):
            if (CONFIG_DIR / f"{name_or_path}{suffix}").exists():
                path = CONFIG_DIR / f"{name_or_path}{suffix}"
                break
        else:
            names = sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))
            raise ValueError(f"no config {str(name_or_path)!r}; give a file or one of: {', '.join(names)}")
    text = path.read_text()
    if path.suffix == ".json":
        return json.loads(text)
    return parse_yaml(text)


def apply_overrides(config: dict, pairs: list[str]) -> dict:
    """`a.b=value` pairs (value read by `mjdrive.config.parse_value`, like `--task-kwarg`'s) applied to a copy
    of `config`."""
    config = copy.deepcopy(config)
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"override must be KEY=VALUE (dots for nesting), got {pair!r}")
        key, value = pair.split("=", 1)
        node = config
        *parents, leaf = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = parse_value(value)
    return config
