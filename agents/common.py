"""What every learner shares: configs, seeding, envs from a config, encoders, replay buffer, checkpoints,
and the run bookkeeping (progress bar, TensorBoard, episode log, periodic checkpoints, resume)."""

from __future__ import annotations

import collections
import contextlib
import copy
import csv
import json
import pickle
import random
import re
import shutil
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn

from mjdrive.envs.batched import BatchedEnv, ObservationLayout

CONFIG_DIR = Path(__file__).resolve().parent / "configs"
CHECKPOINT_FORMAT = "mjdrive.agents.checkpoint"
CHECKPOINT_VERSION = 1


# --- configs ------------------------------------------------------------------------------------------

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


def parse_yaml(text: str) -> Any:
    """yaml.safe_load, except that 1e-4 is a float (YAML 1.1 reads it as a string; Adam then fails on it)."""
    import yaml

    class Loader(yaml.SafeLoader):
        pass

    Loader.add_implicit_resolver("tag:yaml.org,2002:float", SCIENTIFIC, list("-+0123456789."))
    return yaml.load(text, Loader=Loader)  # a SafeLoader subclass: safe


SCIENTIFIC = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+$")


def apply_overrides(config: dict, pairs: list[str]) -> dict:
    """`a.b=value` pairs (value parsed as YAML: numbers, booleans, lists) applied to a copy of `config`."""
    config = copy.deepcopy(config)
    for pair in pairs:
        if "=" not in pair:
            raise ValueError(f"override must be KEY=VALUE (dots for nesting), got {pair!r}")
        key, value = pair.split("=", 1)
        node = config
        *parents, leaf = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = parse_yaml(value)
    return config


def set_seed(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


# --- environments -------------------------------------------------------------------------------------

def split_task(name: str) -> tuple[str, str]:
    if "/" not in name:
        raise ValueError(f"task must be DOMAIN/TASK (e.g. waypoints/straight), got {name!r}")
    domain, task = name.split("/", 1)
    return domain, task


def training_tasks(config: dict) -> tuple[str, list[str]]:
    """(domain, task names) the copies of a config's batched env run: `task`, then the optional `mix_tasks`
    (same domain) in turn, copy i running the i-th modulo their count. Evaluation defaults to `task` alone."""
    domain, task = split_task(config["task"])
    names = [task]
    for other in config.get("mix_tasks") or []:
        other_domain, other_task = split_task(other)
        if other_domain != domain:
            raise ValueError(f"mix_tasks must be tasks of {domain} (the domain of task), got {other!r}")
        names.append(other_task)
    return domain, names


def make_batched_env(config: dict, num_envs: int | None = None, **overrides) -> BatchedEnv:
    """The BatchedEnv a config describes (`task`, `mix_tasks`, `task_kwargs`, `actions`, `num_envs`, `nthread`,
    `backend`)."""
    domain, tasks = training_tasks(config)
    task_kwargs = {**config.get("task_kwargs", {}), **overrides}
    return BatchedEnv(domain, tasks, num_envs=num_envs or config.get("num_envs", 1),
                      actions=config.get("actions", "continuous"), nthread=config.get("nthread", 1),
                      backend=config.get("backend", "threads"), record_dir=config.get("record_dir"),
                      **task_kwargs)


def bounded_action_map(space: gym.spaces.Box) -> tuple[torch.Tensor, torch.Tensor]:
    """(scale, bias) with env_action = bias + scale * a for a in [-1, 1] (tanh-squashed policies)."""
    low, high = torch.as_tensor(space.low, dtype=torch.float32), torch.as_tensor(space.high, dtype=torch.float32)
    return (high - low) / 2.0, (high + low) / 2.0


# --- networks -----------------------------------------------------------------------------------------

def mlp(in_dim: int, hidden: list[int], out_dim: int | None, activation: type[nn.Module] = nn.ReLU) -> nn.Sequential:
    """Linear-activation stack; `out_dim=None` ends on the last hidden layer's activation."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), activation()]
        in_dim = width
    if out_dim is not None:
        layers.append(nn.Linear(in_dim, out_dim))
    return nn.Sequential(*layers)


class StudyCNN(nn.Module):
    """The CNN of study 000 (§4.2, eq 10): 3 conv layers 5x5 stride 2, then average pooling to 1x1, flatten.

    The paper is inconsistent: its text gives 16, 16 and 64 kernels, its figure 40x40x16, 18x18x64 and
    7x7x256 feature maps (hence h_t in R^256 and hd_t in R^258, eq 11). The spatial sizes of both agree
    (84 -> 40 -> 18 -> 7 with 5x5 stride 2, no padding); only the channel counts differ. We follow the text,
    channels (16, 16, 64), so h_t has 64 entries and [h_t, dest_t] 66; pass channels=(16, 64, 256) for the
    figure's version. `pool="none"` flattens the last feature map instead (keeps where things are in the
    image, which a waypoint-following camera agent needs) and projects it to `out_dim`.
    """

    def __init__(self, in_shape: tuple[int, int, int], channels: tuple[int, ...] = (16, 16, 64),
                 kernel: int = 5, stride: int = 2, pool: str = "avg", out_dim: int = 256):
        super().__init__()
        layers: list[nn.Module] = []
        c = in_shape[0]
        for width in channels:
            layers += [nn.Conv2d(c, width, kernel, stride), nn.ReLU()]
            c = width
        if pool == "avg":
            layers += [nn.AdaptiveAvgPool2d(1), nn.Flatten()]
        elif pool == "none":
            layers.append(nn.Flatten())
        else:
            raise ValueError(f"pool must be 'avg' or 'none', got {pool!r}")
        self.net = nn.Sequential(*layers)
        with torch.no_grad():
            n = self.net(torch.zeros(1, *in_shape)).shape[1]
        if pool == "none":
            self.net.append(nn.Linear(n, out_dim))
            self.net.append(nn.ReLU())
            n = out_dim
        self.out_dim = n
        # channels-last convolutions: 1.5-1.9x faster forward+backward on this CPU (batch 64, 4x84x84)
        self.net.to(memory_format=torch.channels_last)

    def forward(self, image: torch.Tensor) -> torch.Tensor:
        """image: (B, C, H, W) uint8 or float in [0, 255]."""
        return self.net((image.float() / 255.0).contiguous(memory_format=torch.channels_last))


class Encoder(nn.Module):
    """Observation -> latent: [CNN(image), features] when there is an image (the studies concatenate the
    CNN output with d, θ, v or the destination vector), else the (scaled) features alone."""

    def __init__(self, layout: ObservationLayout, cnn: dict | None = None):
        super().__init__()
        self.cnn = StudyCNN(layout.image_shape, **(cnn or {})) if layout.image_key else None
        self.out_dim = layout.feature_dim + (self.cnn.out_dim if self.cnn else 0)

    def forward(self, features: torch.Tensor, image: torch.Tensor | None = None) -> torch.Tensor:
        if self.cnn is None:
            return features
        return torch.cat([self.cnn(image), features], dim=-1)


def random_shift(image: torch.Tensor, pad: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """DrQ's augmentation (Kostrikov et al. 2021): shift each (C, H, W) frame stack of a batch by its own random
    offset in [-pad, pad] px on both axes, repeating the edge pixels (= pad with the edge, then crop)."""
    if pad <= 0:
        return image
    b, c, h, w = image.shape
    shift = torch.randint(-pad, pad + 1, (b, 2), generator=generator, device=image.device)
    rows = (shift[:, 0:1] + torch.arange(h, device=image.device)).clamp_(0, h - 1)  # (B, H) source rows
    cols = (shift[:, 1:2] + torch.arange(w, device=image.device)).clamp_(0, w - 1)  # (B, W) source columns
    image = image.gather(2, rows[:, None, :, None].expand(b, c, h, w))
    return image.gather(3, cols[:, None, None, :].expand(b, c, h, w))


class ObsBatch:
    """Batched observations as torch tensors: `features` (B, F) float32 and `image` (B, C, H, W) uint8|None."""

    def __init__(self, features: torch.Tensor, image: torch.Tensor | None):
        self.features, self.image = features, image

    def shifted(self, pad: int) -> ObsBatch:
        """The same batch with `random_shift`ed images (features unchanged)."""
        return self if self.image is None or pad <= 0 else ObsBatch(self.features, random_shift(self.image, pad))

    @classmethod
    def from_numpy(cls, layout: ObservationLayout, obs: dict[str, np.ndarray], device: str = "cpu") -> ObsBatch:
        image = layout.image(obs)
        return cls(torch.as_tensor(layout.features(obs), device=device),
                   None if image is None else torch.as_tensor(image, device=device))


# --- replay buffer ------------------------------------------------------------------------------------

class ReplayBuffer:
    """Uniform replay of (obs, action, reward, next_obs, terminated); images kept as uint8.

    Only `terminated` stops bootstrapping: a time-limit truncation keeps its true final observation
    (BatchedEnv's `info["final_observation"]`) as next_obs and is bootstrapped like any other step.
    Memory: 2 x capacity x image bytes (84x84x4: 56 kB per transition; 128x128x3: 98 kB).
    """

    def __init__(self, capacity: int, layout: ObservationLayout, action_shape: tuple[int, ...],
                 action_dtype=np.float32, device: str = "cpu"):
        self.capacity, self.layout, self.device = int(capacity), layout, device
        self.features = np.zeros((self.capacity, layout.feature_dim), np.float32)
        self.next_features = np.zeros_like(self.features)
        shape = layout.image_shape
        self.images = np.zeros((self.capacity, *shape), np.uint8) if shape else None
        self.next_images = np.zeros_like(self.images) if shape else None
        self.actions = np.zeros((self.capacity, *action_shape), action_dtype)
        self.rewards = np.zeros(self.capacity, np.float32)
        self.terminated = np.zeros(self.capacity, np.float32)
        self.position, self.size = 0, 0

    def add(self, obs: dict, actions: np.ndarray, rewards: np.ndarray, next_obs: dict,
            terminated: np.ndarray) -> None:
        """Add a batch of transitions (one per env copy)."""
        features, next_features = self.layout.features(obs), self.layout.features(next_obs)
        images, next_images = self.layout.image(obs), self.layout.image(next_obs)
        for i in range(len(rewards)):
            k = self.position
            self.features[k], self.next_features[k] = features[i], next_features[i]
            if self.images is not None:
                self.images[k], self.next_images[k] = images[i], next_images[i]
            self.actions[k], self.rewards[k], self.terminated[k] = actions[i], rewards[i], terminated[i]
            self.position = (k + 1) % self.capacity
            self.size = min(self.size + 1, self.capacity)

    def sample(self, batch_size: int) -> dict[str, Any]:
        idx = np.random.randint(0, self.size, size=batch_size)

        def t(array):
            return None if array is None else torch.as_tensor(array[idx], device=self.device)

        return {"obs": ObsBatch(t(self.features), t(self.images)),
                "next_obs": ObsBatch(t(self.next_features), t(self.next_images)),
                "actions": t(self.actions), "rewards": t(self.rewards), "terminated": t(self.terminated)}

    ARRAYS = ("features", "next_features", "images", "next_images", "actions", "rewards", "terminated")

    def save(self, directory: str | Path, step: int) -> Path:
        """Write the filled part to `directory` (one .npy per array + meta.json; uncompressed, so 100k camera
        transitions take ~5.6 GB and a few seconds) as of env step `step`; replaces an earlier save only once
        the new one is complete."""
        directory = Path(directory)
        tmp = directory.with_name(directory.name + ".tmp")
        if tmp.exists():
            shutil.rmtree(tmp)
        tmp.mkdir(parents=True)
        for name in self.ARRAYS:
            array = getattr(self, name)
            if array is not None:
                np.save(tmp / f"{name}.npy", array[:self.size])
        meta = {"step": int(step), "size": self.size, "position": self.position, "capacity": self.capacity}
        (tmp / "meta.json").write_text(json.dumps(meta) + "\n")
        if directory.exists():
            shutil.rmtree(directory)
        tmp.rename(directory)
        return directory

    def load(self, directory: str | Path, step: int) -> None:
        """Fill this (empty) buffer from `save`'s `directory`, keeping the newest transitions if it holds fewer
        than were saved; ValueError if it was saved at another env step than `step` or for other observation
        or action shapes."""
        directory = Path(directory)
        meta = json.loads((directory / "meta.json").read_text())
        if meta["step"] != step:
            raise ValueError(f"replay buffer {directory} was saved at env step {meta['step']:,}, "
                             f"the checkpoint is at {step:,}")
        size, position = int(meta["size"]), int(meta["position"])
        arrays = {}
        for name in self.ARRAYS:
            own = getattr(self, name)
            if own is None:
                continue
            saved = np.load(directory / f"{name}.npy", mmap_mode="r", allow_pickle=False)
            if saved.shape != (size, *own.shape[1:]) or saved.dtype != own.dtype:
                raise ValueError(f"replay buffer {directory}: {name} is {saved.dtype}{list(saved.shape)}, this "
                                 f"run stores {own.dtype}{[size, *own.shape[1:]]}")
            arrays[name] = saved
        # the saved rows oldest first (a wrapped buffer's oldest row is at `position`), then the newest n of them
        segments = [(position, size), (0, position)] if size == meta["capacity"] else [(0, size)]
        n = min(size, self.capacity)
        skip, row = size - n, 0
        for first, last in segments:
            dropped = min(skip, last - first)  # older than the newest n
            first, skip = first + dropped, skip - dropped
            for name, saved in arrays.items():
                getattr(self, name)[row:row + last - first] = saved[first:last]
            row += last - first
        self.size, self.position = n, n % self.capacity


# --- checkpoints --------------------------------------------------------------------------------------

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


# --- run bookkeeping ----------------------------------------------------------------------------------

EPISODE_FIELDS = ("episode", "env_step", "wall_s", "return", "length", "route_completion", "success",
                  "collision", "lane_invasion", "off_road", "off_route", "time_limit", "task")


class Run:
    """One training run's outputs in `out/`: config.yaml, episodes.csv (one row per ended episode, flushed as
    it ends; a resumed run keeps the rows up to its checkpoint),
    TensorBoard scalars (tb/), checkpoints (checkpoint.pt = latest, checkpoints/step_N.pt), a tqdm bar."""

    def __init__(self, out: str | Path, config: dict, total_steps: int, start_step: int = 0,
                 start_episode: int = 0, progress: bool = True, tensorboard: bool = True):
        import yaml

        from mjdrive.progress import Progress

        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
        self.config, self.total_steps = config, int(total_steps)
        self.step, self.episode = int(start_step), int(start_episode)
        self.checkpoint_every = int(config.get("checkpoint_every", 0) or 0)
        self._next_checkpoint = (self.step // self.checkpoint_every + 1) * self.checkpoint_every \
            if self.checkpoint_every else None
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.out / "tb"))
        csv_path = self.out / "episodes.csv"
        new_file = not csv_path.exists() or start_step == 0
        if not new_file:  # a resumed run: drop the rows logged after the checkpoint it resumes from
            with open(csv_path, newline="") as f:
                kept = [row for row in csv.DictReader(f) if int(row["episode"]) <= start_episode]
        self._csv_file = open(csv_path, "w", newline="")  # noqa: SIM115
        self._csv = csv.DictWriter(self._csv_file, EPISODE_FIELDS, extrasaction="ignore")
        self._csv.writeheader()
        self.wall_offset = 0.0  # [s] of training before a resume: wall_s in episodes.csv is cumulative
        if not new_file:
            self._csv.writerows(kept)
            self.wall_offset = float(kept[-1]["wall_s"]) if kept else 0.0
        self._csv_file.flush()
        self.recent: list[float] = []
        self.latest: dict[str, float] = {}  # last value of every scalar (written to scalars.json at close)
        self.start_time = time.perf_counter()
        self.bar = Progress(total=self.total_steps, initial=self.step, unit="step", disable=not progress,
                            desc=f"{config.get('algo', 'train')} (env steps)")

    def add_steps(self, n: int, final_infos: list[dict | None] | None = None) -> None:
        """Count `n` env steps and log the episodes that ended (BatchedEnv's `info["final_info"]`)."""
        self.step += n
        self.bar.update(n)
        for final in final_infos or []:
            if final is None:
                continue
            self.episode += 1
            row = {"episode": self.episode, "env_step": self.step,
                   "wall_s": round(self.wall_offset + time.perf_counter() - self.start_time, 2),
                   "return": round(final["episode_return"], 3), "length": final["episode_length"],
                   **{k: final[k] for k in EPISODE_FIELDS[5:] if k in final}}
            self._csv.writerow(row)
            self.recent = (self.recent + [final["episode_return"]])[-20:]
            self.scalar("episode/return", final["episode_return"])
            self.scalar("episode/length", final["episode_length"])
            for key in ("route_completion", "success", "collision"):
                if key in final:
                    self.scalar(f"episode/{key}", float(final[key]))
        if any(final is not None for final in final_infos or []):
            self._csv_file.flush()  # a killed run keeps every ended episode
        if self.recent:
            self.bar.set_postfix(episodes=self.episode, mean_return_last_20=f"{np.mean(self.recent):.0f}",
                                 refresh=False)

    def scalar(self, name: str, value: float) -> None:
        self.latest[name] = float(value)
        if self.writer is not None:
            self.writer.add_scalar(name, float(value), self.step)

    def scalars(self, values: dict[str, float], prefix: str = "train/") -> None:
        for name, value in values.items():
            self.scalar(prefix + name, value)

    def checkpoint_due(self) -> bool:
        return self._next_checkpoint is not None and self.step >= self._next_checkpoint

    def save(self, algo: str, state: dict, extra: dict | None = None, periodic: bool = True) -> Path:
        """Write checkpoint.pt (and checkpoints/step_N.pt when periodic)."""
        extra = {"episode": self.episode, **(extra or {})}
        path = save_checkpoint(self.out / "checkpoint.pt", algo, self.config, state, self.step, extra)
        if periodic:
            save_checkpoint(self.out / "checkpoints" / f"step_{self.step}.pt", algo, self.config, state,
                            self.step, extra)
        if self.checkpoint_every:
            self._next_checkpoint = (self.step // self.checkpoint_every + 1) * self.checkpoint_every
        self._csv_file.flush()
        return path

    def close(self) -> None:
        summary = {"env_steps": self.step, "episodes": self.episode,
                   "wall_s": round(self.wall_offset + time.perf_counter() - self.start_time, 1),
                   "latest": self.latest}
        (self.out / "scalars.json").write_text(json.dumps(summary, indent=2) + "\n")
        self.bar.close()
        self._csv_file.close()
        if self.writer is not None:
            self.writer.close()

    @property
    def done(self) -> bool:
        return self.step >= self.total_steps
