"""Checkpoint files: written as tensors and plain data, read without running code, validated;
loading saved network and optimizer state."""

from __future__ import annotations

import collections
import contextlib
import copy
import pickle
import re
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn as nn

CHECKPOINT_FORMAT = "mjdrive.agents.checkpoint"
CHECKPOINT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint that cannot be used: missing, corrupt, unsafe, of another format, algorithm or network shape.
    A ValueError, so the command line prints it as one line and exits with status 2."""


# The globals a checkpoint may name beyond torch's weights_only defaults (tensors, storages, OrderedDict, the
# builtin containers): the whole allow-list while a checkpoint loads, replacing those other libraries register
# on import (tensordict, torch.distributed). mjdrive's checkpoints hold only tensors and plain data, so it is
# empty; a type listed here must be data only, never a callable that runs code when unpickled.
CHECKPOINT_SAFE_GLOBALS: tuple = ()
TORCH_ZIP_MAGIC = b"PK\x03\x04"  # torch.save's format: a zip archive
PICKLE_PROTO = b"\x80"  # the first byte of a pickle of protocol 2 or later (torch's legacy format)
PLAIN_TYPES = (str, int, float, bool, type(None))


def plain_data(value: Any, where: str = "checkpoint") -> Any:
    """`value` as tensors and plain data only (dicts with str/int keys, lists, tuples, str, numbers, None),
    as `torch.load(weights_only=True)` reads it back: numpy scalars become Python numbers, numpy arrays
    tensors, paths strings; TypeError names anything else (`where` is its place in the payload)."""
    if type(value) in (torch.Tensor, nn.Parameter) or type(value) in PLAIN_TYPES:
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        if value.dtype == object:
            raise TypeError(f"{where} is a numpy object array; a checkpoint holds only tensors and plain data")
        return torch.from_numpy(np.ascontiguousarray(value))
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, dict):
        if type(value) not in (dict, collections.OrderedDict):
            raise TypeError(f"{where} is a {type(value).__qualname__}; a checkpoint holds plain dicts")
        converted = {}
        for key, item in value.items():
            if not isinstance(key, str | int):
                raise TypeError(f"{where} has the key {key!r} ({type(key).__name__}); keys must be str or int")
            converted[key] = plain_data(item, f"{where}[{key!r}]")
        if all(converted[key] is item for key, item in value.items()):
            return value  # unchanged: a module's state_dict keeps its OrderedDict and _metadata
        copied = copy.copy(value)
        copied.update(converted)
        return copied
    if isinstance(value, list | tuple):
        items = [plain_data(item, f"{where}[{i}]") for i, item in enumerate(value)]
        if type(value) not in (list, tuple):
            raise TypeError(f"{where} is a {type(value).__qualname__}; a checkpoint holds plain lists and tuples")
        return type(value)(items)
    raise TypeError(f"{where} is a {type(value).__module__}.{type(value).__qualname__}; a checkpoint holds only "
                    "tensors and plain data")


def save_checkpoint(path: str | Path, algo: str, config: dict, state: dict, step: int,
                    extra: dict | None = None) -> Path:
    """Write {format, version, algo, config, step, state, extra} atomically (tmp file + rename); the payload is
    converted to tensors and plain data first (TypeError otherwise), so `load_checkpoint` reads it without
    running code."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "algo": algo, "config": config,
               "step": int(step), "state": state, "extra": extra or {}, "saved_at": time.time()}
    payload = plain_data(payload)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def _one_line(text: str, limit: int = 200) -> str:
    """`text` on one line (whitespace runs become one space), cut to `limit` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _unsafe_reason(message: str) -> str | None:
    """Why torch's weights_only unpickler refused a file (from its error `message`), or None if it did not."""
    match = re.search(r"GLOBAL ([\w.]+)", message)
    if match:
        return f"it would call or build the Python object {match.group(1)}"
    match = re.search(r"WeightsUnpickler error: (.+?)(?:\n\n|Check the documentation|$)", message, re.S)
    if match:
        return f"it is a pickle the safe unpickler cannot read ({_one_line(match.group(1), 120)})"
    return None


@contextlib.contextmanager
def _only_safe_globals(allowed: tuple) -> Iterator[None]:
    """While inside, torch's weights_only allow-list beyond its defaults is exactly `allowed`."""
    registered = torch.serialization.get_safe_globals()
    torch.serialization.clear_safe_globals()
    torch.serialization.add_safe_globals(list(allowed))
    try:
        yield
    finally:
        torch.serialization.clear_safe_globals()
        torch.serialization.add_safe_globals(registered)


def read_checkpoint_file(path: str | Path) -> Any:
    """The object in the torch file at `path`, read with `torch.load(weights_only=True)`: tensors and plain
    data only, so a file that would run code or build other objects is refused before any of it runs.
    CheckpointError (one line) for a missing path, a directory, an empty, corrupt or unsafe file."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist")
    if path.is_dir():
        raise CheckpointError(f"checkpoint {path} is a directory, not a checkpoint file")
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} is not a regular file")
    if path.stat().st_size == 0:
        raise CheckpointError(f"checkpoint {path} is empty (0 bytes)")
    try:
        with open(path, "rb") as file:
            head = file.read(len(TORCH_ZIP_MAGIC))
    except OSError as error:
        raise CheckpointError(f"checkpoint {path} cannot be read ({type(error).__name__}: {error.strerror})") from None
    if head != TORCH_ZIP_MAGIC and head[:1] != PICKLE_PROTO:
        raise CheckpointError(f"checkpoint {path} is not a torch file (it starts with {head!r}, neither a zip "
                              "archive nor a pickle)")
    try:
        with warnings.catch_warnings(), _only_safe_globals(CHECKPOINT_SAFE_GLOBALS):
            warnings.simplefilter("ignore")  # e.g. torch's pickle-protocol notice: the error below says it all
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        reason = _unsafe_reason(str(error))
        if reason is not None:
            raise CheckpointError(f"checkpoint {path} is refused: {reason}; a checkpoint holds only tensors "
                                  "and plain data, and nothing in this one was run") from None
        raise CheckpointError(f"checkpoint {path} is corrupt or not a torch file "
                              f"(UnpicklingError: {_one_line(error)})") from None
    except Exception as error:  # truncated file, not a torch file, unreadable, ...
        detail = _one_line(str(error).split(". ")[0]) or "no detail"  # torch's first sentence says what broke
        raise CheckpointError(f"checkpoint {path} is corrupt or not a torch file ({type(error).__name__}: "
                              f"{detail})") from None


CHECKPOINT_FIELDS = {"algo": str, "config": dict, "state": dict, "step": int}


def load_checkpoint(path: str | Path, algo: str | None = None) -> dict:
    """Read and validate a checkpoint (`read_checkpoint_file`: never runs code from it); raises CheckpointError
    with the reason."""
    path = Path(path)
    payload = read_checkpoint_file(path)
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path} is not an mjdrive agent checkpoint (no '{CHECKPOINT_FORMAT}' header)")
    if payload.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"{path} has checkpoint version {payload.get('version')!r}, "
                              f"this code reads version {CHECKPOINT_VERSION}")
    for key, kind in CHECKPOINT_FIELDS.items():
        if key not in payload:
            raise CheckpointError(f"{path} lacks '{key}'")
        if not isinstance(payload[key], kind) or isinstance(payload[key], bool):
            raise CheckpointError(f"{path}: '{key}' is a {type(payload[key]).__name__}, expected a {kind.__name__}")
    payload.setdefault("extra", {})
    if not isinstance(payload["extra"], dict):
        raise CheckpointError(f"{path}: 'extra' is a {type(payload['extra']).__name__}, expected a dict")
    if not isinstance(payload["config"].get("task"), str):
        raise CheckpointError(f"{path}: its config names no task (config 'task' is "
                              f"{payload['config'].get('task')!r})")
    if algo is not None and payload["algo"] != algo:
        raise CheckpointError(f"{path} holds a {payload['algo']!r} agent, expected {algo!r}")
    return payload


def load_optimizer_state(optimizer: torch.optim.Optimizer, state: dict, lr: float) -> None:
    """Load an optimizer's saved state, then set its learning rate to `lr` (the config's: a resumed run may
    lower it to fine-tune)."""
    optimizer.load_state_dict(state)
    for group in optimizer.param_groups:
        group["lr"] = float(lr)


def load_module_state(module: nn.Module, state: dict, name: str) -> None:
    """load_state_dict with a CheckpointError naming the mismatched parameters."""
    own = module.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = [f"{k}: checkpoint {tuple(state[k].shape)} vs network {tuple(own[k].shape)}"
              for k in own if k in state and hasattr(state[k], "shape") and state[k].shape != own[k].shape]
    if missing or unexpected or shapes:
        raise CheckpointError(f"{name} does not match the checkpoint: missing {missing[:5]}, unexpected "
                              f"{unexpected[:5]}, shape mismatches {shapes[:5]} (was it trained with another "
                              f"observation, action set or network config?)")
    module.load_state_dict(state)
