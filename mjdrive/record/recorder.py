"""`EpisodeRecorder`: one MCAP file per episode, fed by (task, physics, action, reward, done) after every
env step. It knows no env class, so the gymnasium and dm_control wrappers (and a batched env, one recorder
per copy) all drive it the same way.

File naming: `{domain}-{task}_{seed}_{episode:05d}.mcap` in the output folder (`seed` is the reset seed,
or `noseed`; `episode` counts this recorder's episodes from `first_episode`). A name already taken (by
another recorder, process or an older run) gets a suffix `-1`, `-2`, ... Each file is written as
`NAME.mcap.part` and renamed (hard link + unlink: never overwrites) once closed, so a `.mcap` file is
always complete; a killed process leaves at most one `.part` per recorder, readable up to its last chunk.

Topics (log times: the episode's wall-clock start + simulated time, so plots start at 0 s):

| topic | schema | when |
| --- | --- | --- |
| /tf | foxglove.FrameTransforms | world -> ego (chassis, 3D) and ego -> camera_front (optical frame), every step |
| /scene/road | foxglove.SceneUpdate | once: lane surfaces, paved areas, markings, crosswalks (frame world) |
| /scene/route | foxglove.SceneUpdate | once: route centre line, waypoints; urban: scenario segments, labelled |
| /scene/ego | foxglove.SceneUpdate | once: the ego box, locked to frame ego |
| /scene/road_users | foxglove.SceneUpdate | every step while there are road users: boxes by kind (+ intentions) |
| /camera/front | foxglove.CompressedImage | every `camera_every`-th step (optional), JPEG or PNG |
| /camera/front/calibration | foxglove.CameraCalibration | with every image |
| /ego/state | JSON mjdrive.EgoState | every step: pose, speed, accel, jerk, steering, commands, lane errors, scenario |
| /action | JSON mjdrive.Action | every step: the (throttle, steer, brake) applied, exact float64 |
| /reward | JSON mjdrive.Reward | every step: reward, return, `task.reward_terms` |
| /physics | protobuf mjdrive.PhysicsState | every step: time, qpos, qvel, act, mocap (exact, for replay) |
| /episode | JSON mjdrive.EpisodeSummary | once at the end: `task.info` + steps, return, mean speed, comfort |
| /sensors/depth | foxglove.RawImage 32FC1 | every step of an env with the `depth` sensor (`sensors=`): [m] |
| /sensors/segmentation | foxglove.RawImage mono8 | every step with `segmentation`: class index x SEGMENT_SCALE |
| /sensors/range | foxglove.LaserScan | every step with `range`: the ring's ranges [m], frame ego, first ray ahead |
| /operative | JSON mjdrive.OperativeStep | `decisions`: every control period (10 Hz): the operative level's state |
| /operative/plan | JSON mjdrive.OperativePlan | `decisions`: every step: the MPC's planned s, v, a |
| /scene/plan | foxglove.SceneUpdate | `decisions`: every step: the path tracked ahead, the stop point |
| /decision | JSON mjdrive.Decision | when the policy says who decided (`decided`, e.g. the hybrid agent under `eval`) |
| /junction | JSON mjdrive.JunctionControl | urban stop signs or lights: what each junction entry shows, every step |
| /scene/signals | foxglove.SceneUpdate | ... and a lamp per entry, coloured by it, in the 3D scene |

/tf, /ego/state, /physics and /scene/road_users also carry the state right after reset (step 0), so they hold steps
+ 1 messages; /action and /reward hold one per step (with `decisions`, /action holds the decision's index and name,
and the last control period's commands). /operative: the decision applied, the MPC's mode and solver status, the
commands, the planned acceleration, speed reference, stop point, lane offset and the LQR's errors. /ego/state's
accelerations are the IMU's at that instant (`Vehicle.acceleration`) and its jerks their finite differences over the
control step: raw signals to plot. The episode's comfort metrics in /episode (`jerk_p95_m_s3`, ... as in the summary
schema, docs/summary.md) are `mjdrive.comfort`'s, from the samples the task's own metrics use (the chassis' planar
velocity and yaw, `DrivingTask.comfort_sample`, every control step), so they equal those of `task.info`.
/ego/state's `scenario` is the urban tasks' active scenario (null on other tasks); urban road users carry a
label with their intentions (`mjdrive.traffic.intentions`), coloured by the one in the active scenario. MCAP
metadata "mjdrive" (written first) holds what replay needs: task, task and environment kwargs (the task kwargs
always name the physics step, `physics_dt` [s]), seed, the task's RNG state at reset, package versions;
metadata "summary" (written last) repeats /episode. Metadata values are JSON strings.

Live: with `RecordOptions(live_port=...)` the recorder also serves its channels on a Foxglove WebSocket
server (foxglove-sdk, bound to `live_host`, 127.0.0.1 by default) while it writes the files; a client that
subscribes to a scene topic mid-episode gets the static scene again at the next step.
"""

from __future__ import annotations

import base64
import dataclasses
import functools
import io
import json
import math
import os
import platform
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import foxglove
import mujoco
import numpy as np
from foxglove import messages as fm
from foxglove.mcap import MCAPCompression, MCAPWriteOptions

from mjdrive.comfort import ComfortMeter
from mjdrive.record import proto, scene
from mjdrive.record.summary import COMFORT_FIELDS, comfort_fields
from mjdrive.run_folder import lock_part
from mjdrive.sensors import SENSORS

FORMAT_VERSION = 1
CAMERA_FRAME = "camera_front"


@dataclass(frozen=True)
class EnvSpec:
    """What `suite.load` needs to rebuild the env of a recording."""

    domain: str
    task: str
    task_kwargs: dict[str, Any] = field(default_factory=dict)
    environment_kwargs: dict[str, Any] | None = None

    @property
    def name(self) -> str:
        return f"{self.domain}/{self.task}"


@dataclass(frozen=True)
class RecordOptions:
    """Recorder settings; the defaults cost the least (no camera images)."""

    camera_every: int = 0  # log the front camera every k-th step (0: never)
    camera: str = "ego/front"
    camera_size: tuple[int, int] = (240, 320)  # (height, width) [px]
    image_format: str = "jpeg"  # "jpeg" or "png"
    jpeg_quality: int = 85
    chunk_size: int = 256 * 1024  # [bytes] uncompressed MCAP chunk: the most a killed process can lose
    compression: str | None = "zstd"  # "zstd", "lz4" or None
    live_port: int | None = None  # also stream every channel to Foxglove's WebSocket on this port (0: any free)
    live_host: str = "127.0.0.1"  # the address the live server binds (0.0.0.0: reachable from other machines)

    def __post_init__(self):
        if self.image_format not in ("jpeg", "png"):
            raise ValueError(f"image_format must be 'jpeg' or 'png', got {self.image_format!r}")
        if self.compression not in ("zstd", "lz4", None):
            raise ValueError(f"compression must be 'zstd', 'lz4' or None, got {self.compression!r}")
        if self.camera_every < 0:
            raise ValueError(f"camera_every must be >= 0, got {self.camera_every}")
        if self.live_port is not None and not 0 <= self.live_port <= 65535:
            raise ValueError(f"live_port must be in 0..65535, got {self.live_port}")


def sensor_readings(observation: Any) -> dict[str, np.ndarray]:
    """The extra sensors' readings (`mjdrive.sensors.SENSORS`: depth, segmentation, range) in an observation:
    the entries of a mapping (gymnasium Dict observation, dm_env observation) by those names; {} for any
    other observation (a flattened one, or an env without the `sensors` task keyword)."""
    if not hasattr(observation, "keys"):
        return {}
    return {name: observation[name] for name in SENSORS if name in observation}


def episode_filename(spec: EnvSpec, seed: int | None, episode: int, suffix: int = 0) -> str:
    """`{domain}-{task}_{seed}_{episode:05d}[-{suffix}].mcap`."""
    extra = f"-{suffix}" if suffix else ""
    return f"{spec.domain}-{spec.task}_{'noseed' if seed is None else seed}_{episode:05d}{extra}.mcap"


def encode_rng_state(state: tuple) -> str:
    """A numpy RandomState state (MT19937) as JSON."""
    name, keys, pos, has_gauss, cached = state
    return json.dumps({"bit_generator": name, "keys": base64.b64encode(np.asarray(keys, "<u4").tobytes()).decode(),
                       "pos": int(pos), "has_gauss": int(has_gauss), "cached_gaussian": float(cached)})


def decode_rng_state(state: str | dict) -> tuple:
    """The RandomState state tuple of `encode_rng_state`'s JSON (text or parsed)."""
    d = json.loads(state) if isinstance(state, str) else state
    keys = np.frombuffer(base64.b64decode(d["keys"]), "<u4").astype(np.uint32)
    return d["bit_generator"], keys, d["pos"], d["has_gauss"], d["cached_gaussian"]


@functools.lru_cache(maxsize=1)
def package_versions() -> dict[str, str]:
    """Versions of the packages that decide an episode's numbers (looked up once per process)."""
    from importlib import metadata

    from mjdrive.version import __version__

    versions = {"mjdrive": __version__, "mujoco": mujoco.__version__, "numpy": np.__version__,
                "python": platform.python_version()}
    for dist in ("dm-control", "foxglove-sdk"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = "unknown"
    return versions


JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"


def _json_schema(title: str, properties: dict[str, str | tuple[str, ...] | dict], description: str = "") -> dict:
    """The JSON schema of a JSON channel's messages: an object with exactly `properties`, every one required.
    A property is a JSON type name ("number"), a tuple of them (("number", "null"): nullable) or a whole
    property schema (a dict, e.g. with a description giving its unit). A key sent but not declared here, or a
    value of another type, fails tests/test_record_schemas.py, which validates every JSON message of an
    episode of every task."""
    def prop(spec: str | tuple[str, ...] | dict) -> dict:
        if isinstance(spec, dict):
            return spec
        return {"type": list(spec) if isinstance(spec, tuple) else spec}

    schema = {"$schema": JSON_SCHEMA_DIALECT, "title": title, "type": "object",
              "properties": {key: prop(spec) for key, spec in properties.items()},
              "required": list(properties), "additionalProperties": False}
    if description:
        schema["description"] = description
    return schema


def _number(unit: str, description: str = "", nullable: bool = False) -> dict:
    """A number property with its unit (and what it is)."""
    return {"type": ["number", "null"] if nullable else "number",
            "description": " ".join(part for part in (description, f"[{unit}]" if unit else "") if part)}


def _jsonable(value: Any) -> Any:
    """Plain JSON values of an info dict entry (numpy scalars and arrays converted), else its repr."""
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None  # JSON has no NaN or inf
    if isinstance(value, (bool, int, str)) or value is None:
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray) and value.size <= 64:
        return value.tolist()
    if isinstance(value, (list, tuple)) and len(value) <= 64:
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    return repr(value)


_EGO_STATE = _json_schema("mjdrive.EgoState", {
    "t": _number("s", "simulated time"), "x": _number("m", "chassis position, world frame"), "y": _number("m"),
    "yaw": _number("rad", "heading, world frame"), "speed": _number("m/s", "signed forward speed"),
    "yaw_rate": _number("rad/s"),
    "accel_long": _number("m/s^2", "IMU acceleration, forward (instantaneous)"),
    "accel_lat": _number("m/s^2", "IMU acceleration, leftward (instantaneous)"),
    "jerk_long": _number("m/s^3", "finite difference of accel_long over the control step"),
    "jerk_lat": _number("m/s^3", "finite difference of accel_lat over the control step"),
    "jerk": _number("m/s^3", "hypot(jerk_long, jerk_lat)"),
    "steering_angle": _number("rad", "front wheels' steering angle"),
    "throttle": _number("", "command applied, 0..1"), "steer": _number("", "command applied, -1..1 (+ = left)"),
    "brake": _number("", "command applied, 0..1"),
    "lane_offset": _number("m", "lateral offset from the lane's or route's centre line (+ = left)"),
    "heading_error": _number("rad", "heading minus the lane's or route's heading"),
    "scenario": {"type": ["string", "null"], "description": "urban tasks: the active scenario; null on others"},
}, "The ego's state after every step (and after the reset).")
_ACTION = _json_schema("mjdrive.Action", {
    "throttle": _number("", "0..1"), "steer": _number("", "-1..1 (+ = left)"), "brake": _number("", "0..1"),
    "decision": {"type": ["integer", "null"], "description": "urban tasks with `decisions`: the decision's index "
                 "(the env's action; replay uses it); the commands are then the step's last control period's. "
                 "null: a continuous action"},
    "name": {"type": ["string", "null"], "description": "the decision's name (null: a continuous action)"},
}, "The (throttle, steer, brake) command the task applied at a step, exact float64; the decision for the "
   "decision action set.")
_REWARD = _json_schema("mjdrive.Reward", {
    "reward": _number("", "the step's reward (the task's units)"), "return": _number("", "the sum so far"),
    "terms": {"type": "object", "additionalProperties": {"type": "number"},
              "description": "the reward's terms by name (`task.reward_terms`; they vary by task)"},
}, "The reward of every step with its terms.")
_SUMMARY = _json_schema("mjdrive.EpisodeSummary", {
    "task": {"type": "string", "description": "DOMAIN/TASK"},
    "episode": {"type": "integer", "description": "the recorder's episode index"},
    "seed": {"type": ["integer", "null"], "description": "the reset seed (null: none)"},
    "steps": {"type": "integer", "description": "control steps"},
    "return": _number("", "the sum of the rewards"),
    "terminated": {"type": "boolean"}, "truncated": {"type": "boolean"},
    "interrupted": {"type": "boolean", "description": "stopped before the env ended the episode"},
    "sim_time": _number("s", "simulated time of the last step"),
    "mean_speed_m_s": _number("m/s", "distance / time where the task says them, else the mean logged speed"),
    **{row: _number("m/s^3" if row.endswith("m_s3") else "m/s^2", "comfort metric (docs/summary.md); null: too "
                    "short to filter", nullable=True) for row in COMFORT_FIELDS.values()},
    "info": {"type": "object", "description": "the task's `info` at the episode's end (its keys per task: "
             "docs/waypoints.md, roundabout.md, urban.md); NaN and inf as null, arrays as lists",
             "additionalProperties": {"type": ["number", "integer", "boolean", "string", "null", "array", "object"]}},
}, "The episode's summary, once at its end; also the MCAP metadata record `summary`.")


class _Channels:
    """The channels of one recorder, in its own foxglove Context (so recorders never share a sink).
    Channels logged with encoded bytes are kept as their `BaseChannel` (`log(bytes, log_time)`): the
    Python `Channel.log` wrapper costs as much again per call."""

    def __init__(self, context: foxglove.Context):
        self._keep: list[foxglove.Channel] = []

        def raw(topic: str, schema: foxglove.Schema | dict, encoding: str = "json"):
            channel = foxglove.Channel(topic, schema=schema, message_encoding=encoding, context=context)
            self._keep.append(channel)
            return channel.base

        def protobuf(topic: str, schema: foxglove.Schema):
            return raw(topic, schema, "protobuf")

        ch = foxglove.channels
        self.tf = ch.FrameTransformsChannel("/tf", context=context)
        self.road = protobuf("/scene/road", fm.SceneUpdate.get_schema())
        self.route = ch.SceneUpdateChannel("/scene/route", context=context)
        self.ego = ch.SceneUpdateChannel("/scene/ego", context=context)
        self.users = protobuf("/scene/road_users", fm.SceneUpdate.get_schema())
        self.image = ch.CompressedImageChannel("/camera/front", context=context)
        self.calibration = ch.CameraCalibrationChannel("/camera/front/calibration", context=context)
        self.state = raw("/ego/state", _EGO_STATE)
        self.action = raw("/action", _ACTION)
        self.reward = raw("/reward", _REWARD)
        self.physics = protobuf("/physics", foxglove.Schema(
            name=proto.PHYSICS_SCHEMA_NAME, encoding="protobuf", data=proto.physics_schema_data()))
        self.episode = raw("/episode", _SUMMARY)


STATIC_TOPICS = ("/scene/road", "/scene/route", "/scene/ego")  # logged once per episode


class _ResendSceneOnSubscribe(foxglove.ServerListener):
    """A live client that subscribes to a scene topic mid-episode gets the scene again at the next step."""

    def __init__(self, due: threading.Event):
        self.due = due

    def on_subscribe(self, client, channel) -> None:
        if channel.topic in STATIC_TOPICS:
            self.due.set()


SEGMENT_SCALE = 20  # segmentation pixels are logged as class index x SEGMENT_SCALE (visible in an Image panel)


class _SensorChannels:
    """Channels of the extra sensors, made on first use (a log without them has none)."""

    def __init__(self, context: foxglove.Context):
        ch = foxglove.channels
        self.depth = ch.RawImageChannel("/sensors/depth", context=context)
        self.segmentation = ch.RawImageChannel("/sensors/segmentation", context=context)
        self.range = ch.LaserScanChannel("/sensors/range", context=context)


_OPERATIVE = _json_schema("mjdrive.OperativeStep", {
    "t": _number("s", "simulated time"), "route_s": _number("m", "the ego's distance along the route"),
    "route_offset": _number("m", "lateral offset from the route's centre line (+ = left)"),
    "decision": {"type": "string", "description": "the decision applied (tasks/decisions.py ACTIONS)"},
    "mode": {"type": "string", "description": "the MPC's binding constraint: cruise, follow, stop"},
    "solver": {"type": "string", "description": "the bounds the plan was solved within (solved: comfort, "
                                                 "firm, emergency) or fallback"},
    "throttle": _number("", "command, 0..1"), "steer": _number("", "command, -1..1 (+ = left)"),
    "brake": _number("", "command, 0..1"),
    "accel_command": _number("m/s^2", "the MPC's first acceleration"),
    "v_ref": _number("m/s", "the speed reference (route profile, decision)"),
    "stop": _number("m", "distance to the stop point ahead", nullable=True),
    "offset": _number("m", "the lateral reference offset now (+ = left)"),
    "target_offset": _number("m", "the lane offset the reference is heading for"),
    "lateral_error": _number("m", "rear axle from the reference path"),
    "heading_error": _number("rad", "heading minus the reference path's"),
    "leaders": {"type": "integer", "description": "road users the MPC follows"},
    "solve_ms": _number("ms", "the MPC's solve time (wall clock)"),
    "step_ms": _number("ms", "the whole control period's computation (wall clock)"),
}, "The operative level's state every control period (10 Hz) of an urban task with `decisions`.")
_FLOATS = {"type": "array", "items": {"type": "number"}}
_PLAN = _json_schema("mjdrive.OperativePlan", {
    "t": {**_FLOATS, "description": "the horizon's times from now [s]"},
    "s": {**_FLOATS, "description": "planned distance travelled [m]"},
    "v": {**_FLOATS, "description": "planned speed [m/s]"},
    "a": {**_FLOATS, "description": "planned acceleration [m/s^2]"},
    "stop": _number("m", "distance to the stop point ahead", nullable=True),
    "mode": {"type": "string", "description": "the MPC's binding constraint"},
}, "The MPC's last plan at every env step of an urban task with `decisions`.")
_DECISION = _json_schema("mjdrive.Decision", {
    "t": _number("s", "simulated time the decision acts from"),
    "scenario": {"type": "string", "description": "the active scenario the policy saw"},
    "agent": {"type": "string", "description": "who decided: a member agent's scenario, or 'follow path'"},
    "action": {"type": "string", "description": "the decision's name (tasks/decisions.py ACTIONS)"},
    "observation": {"type": "object", "description": "the observation the policy decided on, by entry (arrays as "
                    "nested lists)", "additionalProperties": {"type": "array"}},
}, "Who decided each step's action and on what (the hybrid agent's scenario selector), at the action's time.")
_JUNCTION = _json_schema("mjdrive.JunctionControl", {
    "t": _number("s", "simulated time"),
    "control": {"type": "string", "description": "the junctions' control this episode: give_way, stop or lights"},
    "entries": {"type": "array", "description": "every junction entry: its lane, its group (main or minor road) and "
                "what it shows (green, amber, red or stop)",
                "items": {"type": "object", "properties": {"lane": {"type": "string"}, "group": {"type": "string"},
                                                           "state": {"type": "string"}},
                          "required": ["lane", "group", "state"], "additionalProperties": False}},
}, "Urban tasks with junction control (stop signs, traffic lights): what every entry shows, every step.")
PLAN_RGBA = (0.2, 0.9, 0.4, 0.9)  # the lateral path the operative level tracks, in the 3D scene
STOP_RGBA = (0.95, 0.2, 0.2, 1.0)  # the MPC's stop point


class _OperativeChannels:
    """Channels of the urban tasks' operative level (decision action set), made on first use: every control
    period's commands and state, the MPC's plan and the path ahead in the 3D scene at every env step."""

    def __init__(self, context: foxglove.Context):
        def json_channel(topic: str, schema: dict):
            channel = foxglove.Channel(topic, schema=schema, message_encoding="json", context=context)
            self._keep.append(channel)
            return channel.base

        self._keep: list[foxglove.Channel] = []
        self.step = json_channel("/operative", _OPERATIVE)
        self.plan = json_channel("/operative/plan", _PLAN)
        self.scene = foxglove.channels.SceneUpdateChannel("/scene/plan", context=context)
        self._context = context
        self._decision = None

    @property
    def decision(self):
        """/decision, made on first use (only policies that say who decided have it)."""
        if self._decision is None:
            channel = foxglove.Channel("/decision", schema=_DECISION, message_encoding="json", context=self._context)
            self._keep.append(channel)
            self._decision = channel.base
        return self._decision


def _ns(seconds: float) -> int:
    return int(round(seconds * 1e9))


def _timestamp(ns: int) -> fm.Timestamp:
    return fm.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


class EpisodeRecorder:
    """Writes one MCAP file per episode into `out_dir` (see the module doc for names and topics).

    begin(task, physics, seed=..., rng_state=...) after a reset, step(task, physics, action, reward,
    terminated=..., truncated=...) after every env step (ends the episode when either is True), end() to
    close an episode early (marked interrupted), close() when done. `paths` lists the finished files.
    """

    def __init__(self, out_dir: str | Path, spec: EnvSpec, options: RecordOptions | None = None,
                 first_episode: int = 0):
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.spec = spec
        self.options = options or RecordOptions()
        self.episode = first_episode - 1
        self.paths: list[Path] = []
        self._context = foxglove.Context()
        self._channels = _Channels(self._context)
        self._writer = None
        self._part: Path | None = None
        self._part_lock: int | None = None  # an open descriptor of the .part holding its lock (`run_folder`)
        self._road_cache: tuple[Any, bytes] | None = None  # (road map, encoded /scene/road)
        self._model_cache: tuple[Any, dict] | None = None  # (model, per-model constants)
        self._cubes = proto.CubeListEncoder()
        self._renderer = None  # (model, CameraRenderer) for camera images
        self._last_task_info: dict | None = None
        self._kind_colors = scene.KindColors()
        self._intention_labels = scene.IntentionLabels()
        self._task_kwargs_json, self.replayable = self._kwargs_json(spec.task_kwargs)
        env_json, env_ok = self._kwargs_json(spec.environment_kwargs)
        self._environment_kwargs_json, self.replayable = env_json, self.replayable and env_ok
        compression = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4, None: None}[self.options.compression]
        self._write_options = MCAPWriteOptions(compression=compression, chunk_size=self.options.chunk_size,
                                               profile="", compression_threads=0)
        self._sensor_channels: _SensorChannels | None = None
        self._operative_channels: _OperativeChannels | None = None
        self._junction_channels: tuple | None = None  # /junction, /scene/signals (urban junction control)
        self._comfort = ComfortMeter()  # the episode's comfort samples, as the task's (`task.comfort_sample`)
        self._control_dt: float | None = None  # [s] the task's control period (`task.control_dt`)
        self.server = None  # Foxglove WebSocket server streaming this recorder's channels (options.live_port)
        self._scene_due = threading.Event()
        if self.options.live_port is not None:
            self.server = foxglove.start_server(
                name=f"mjdrive {spec.name}", host=self.options.live_host, port=self.options.live_port,
                context=self._context, server_listener=_ResendSceneOnSubscribe(self._scene_due))

    @property
    def live_url(self) -> str | None:
        """ws://HOST:PORT of the live stream (Foxglove: Open connection > Foxglove WebSocket), or None."""
        return None if self.server is None else f"ws://{self.options.live_host}:{self.server.port}"

    @staticmethod
    def _kwargs_json(kwargs: dict | None) -> tuple[str, bool]:
        try:
            return json.dumps(kwargs), True
        except TypeError:
            return json.dumps(_jsonable(kwargs)), False

    def _task_kwargs_with_step(self, physics_dt: float) -> str:
        """The task kwargs' JSON with the physics step [s] the episode ran at (`physics_dt`), so that the log
        replays at that step whatever the default is when it is replayed."""
        kwargs = json.loads(self._task_kwargs_json) or {}
        kwargs.setdefault("physics_dt", physics_dt)
        return json.dumps(kwargs)

    @property
    def recording(self) -> bool:
        """An episode file is open."""
        return self._writer is not None

    # --- files --------------------------------------------------------------------------------------------
    def _claim(self, seed: int | None) -> Path:
        """Create `NAME.mcap.part` exclusively, for the first NAME not taken; returns the part path."""
        for suffix in range(10_000):
            name = episode_filename(self.spec, seed, self.episode, suffix)
            final, part = self.out_dir / name, self.out_dir / (name + ".part")
            if final.exists():
                continue
            try:
                descriptor = os.open(part, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                continue
            # held until the file is published: while it is, the .part belongs to a live writer; once this
            # process ends (even killed) the lock is gone and the next run may remove the file
            self._part_lock = lock_part(descriptor)
            return part
        raise RuntimeError(f"no free file name for episode {self.episode} in {self.out_dir}")

    def _publish(self, part: Path) -> Path:
        """Rename a closed `.part` to its final name without overwriting anything; returns the final path."""
        base = part.name[: -len(".mcap.part")]
        for suffix in range(10_000):
            final = part.with_name(f"{base}{f'-{suffix}' if suffix else ''}.mcap")
            try:
                os.link(part, final)
            except FileExistsError:
                continue
            except OSError:  # no hard links on this file system: rename (may replace a file raced in)
                if final.exists():
                    continue
                os.replace(part, final)
                return final
            os.unlink(part)
            return final
        raise RuntimeError(f"could not publish {part}")

    # --- episode ------------------------------------------------------------------------------------------
    def begin(self, task, physics, *, seed: int | None = None, rng_state: tuple | None = None,
              extra: dict[str, Any] | None = None) -> Path:
        """Open the next episode's file (right after the env's reset) and log the static scene and the
        initial state. `rng_state`: `task.random.get_state()` taken just before that reset (for replay)."""
        if self._writer is not None:
            self.end(interrupted=True)
        self.episode += 1
        self._part = self._claim(seed)
        self._writer = foxglove.open_mcap(self._part, allow_overwrite=True, context=self._context,
                                          writer_options=self._write_options)
        data, model = physics.data.ptr, physics.model.ptr
        self._t0 = time.time_ns()
        self._seed, self._steps, self._return = seed, 0, 0.0
        self._speed_sum = 0.0
        self._prev_accel: tuple[float, float] | None = None
        self._prev_time = self._start_time = float(data.time)
        self._comfort.reset()
        self._control_dt = getattr(task, "control_dt", None)
        self._users_shown = False
        c = self._model_constants(task, model)
        meta = {
            "format_version": FORMAT_VERSION, "task": self.spec.name, "domain": self.spec.domain,
            "task_name": self.spec.task, "episode": self.episode, "seed": seed,
            "rng_state": None if rng_state is None else json.loads(encode_rng_state(rng_state)),
            "replayable": self.replayable and (seed is not None or rng_state is not None),
            "start_time_ns": self._t0, "physics_timestep": float(model.opt.timestep),
            "nq": model.nq, "nv": model.nv, "na": model.na, "nmocap": model.nmocap,
            "vehicle": task.params.name, "camera_every": self.options.camera_every,
            "versions": dict(package_versions()), "host": platform.node(), "pid": os.getpid(), **(extra or {}),
        }
        metadata = {key: json.dumps(value) for key, value in meta.items()}
        metadata["task_kwargs"] = self._task_kwargs_with_step(float(model.opt.timestep))
        metadata["environment_kwargs"] = self._environment_kwargs_json
        self._writer.write_metadata("mjdrive", metadata)
        ns = self._t0 + _ns(data.time)
        self._scene_due.clear()
        self._log_scene(task, ns)
        self._log_state(task, data, c, None, ns)
        return self._part

    def _log_scene(self, task, ns: int) -> None:
        """The static scene: road, route, ego box (at begin, and again when a live client subscribes)."""
        self._channels.road.log(self._road_bytes(task.road_map), ns)
        stamp = _timestamp(ns)
        self._channels.route.log(fm.SceneUpdate(entities=scene.route_entities(task, stamp)), log_time=ns)
        p = task.params
        ego = scene.ego_entity(p.length, p.width, p.height, stamp)
        self._channels.ego.log(fm.SceneUpdate(entities=[ego]), log_time=ns)

    def step(self, task, physics, action, reward: float, *, terminated: bool = False,
             truncated: bool = False, observation: Any = None) -> Path | None:
        """Log one env step (the action applied, its reward, the state after it, and the extra sensors'
        readings found in `observation`: its `depth`, `segmentation` and `range` entries when it is a mapping
        that has them, see `sensor_readings`). Ends the episode when `terminated` or `truncated`, returning the
        finished file's path; else None."""
        if self._writer is None:
            raise RuntimeError("EpisodeRecorder.step before begin()")
        data = physics.data.ptr
        c = self._model_cache[1]
        action_ns = self._t0 + _ns(self._prev_time)
        ns = self._t0 + _ns(data.time)
        self._steps += 1
        reward = float(reward)
        self._return += reward
        ch = self._channels
        decisions = getattr(task, "decisions", None)
        if decisions is None:
            a0, a1, a2 = float(action[0]), float(action[1]), float(action[2])
            ch.action.log(json.dumps({"throttle": a0, "steer": a1, "brake": a2, "decision": None,
                                      "name": None}).encode(), action_ns)
        else:  # the decision, for replay, and the last control period's commands
            last = task.ticks[-1] if task.ticks else {"throttle": 0.0, "steer": 0.0, "brake": 0.0}
            a0, a1, a2 = float(last["throttle"]), float(last["steer"]), float(last["brake"])
            ch.action.log(json.dumps({"decision": int(action), "name": decisions[int(action)], "throttle": a0,
                                      "steer": a1, "brake": a2}).encode(), action_ns)
            self._log_operative(task, ns)
        terms = {k: float(v) for k, v in task.reward_terms.items()}
        ch.reward.log(json.dumps({"reward": reward, "return": self._return, "terms": terms}).encode(), ns)
        if self._scene_due.is_set():  # a live client subscribed to the scene since the last step
            self._scene_due.clear()
            self._log_scene(task, ns)
        self._log_state(task, data, c, (a0, a1, a2), ns)
        sensors = sensor_readings(observation)
        if sensors:
            self._log_sensors(sensors, ns)
        if terminated or truncated:
            return self.end(terminated=terminated, truncated=truncated, task=task)
        return None

    def end(self, *, terminated: bool = False, truncated: bool = False, interrupted: bool = False,
            task=None) -> Path | None:
        """Write the summary, close the file and give it its final name; returns that path (None if no
        episode was open). `interrupted`: the episode stopped before the env ended it."""
        if self._writer is None:
            return None
        info = getattr(task, "info", None) if task is not None else self._last_task_info
        # mean speed as in the summary schema (mjdrive.record.summary): distance / time when the task says them
        distance, elapsed = (info or {}).get("distance"), (info or {}).get("elapsed_time")
        mean_speed = (float(distance) / float(elapsed) if distance is not None and elapsed
                      else self._speed_sum / max(self._steps, 1))
        summary = {
            "task": self.spec.name, "episode": self.episode, "seed": self._seed, "steps": self._steps,
            "return": self._return, "terminated": bool(terminated), "truncated": bool(truncated),
            "interrupted": bool(interrupted), "sim_time": self._prev_time,  # [s]
            "mean_speed_m_s": mean_speed, **self._comfort_summary(),
            "info": {str(k): _jsonable(v) for k, v in (info or {}).items()},
        }
        ns = self._t0 + _ns(self._prev_time)
        self._channels.episode.log(json.dumps(summary).encode(), ns)
        self._writer.write_metadata("summary", {k: json.dumps(v) for k, v in summary.items()})
        self._writer.close()
        self._writer = None
        final = self._publish(self._part)
        self._part = None
        if self._part_lock is not None:
            os.close(self._part_lock)
            self._part_lock = None
        self.paths.append(final)
        return final

    def _comfort_summary(self) -> dict[str, float | None]:
        """The episode's comfort metrics under the summary schema's row names (None: too short to filter):
        sampled every control period, the task's `control_dt` [s] (else the mean step of the log)."""
        dt = self._control_dt or (self._prev_time - self._start_time) / max(self._steps, 1)
        metrics = self._comfort.metrics(dt) if dt > 0 else None
        return comfort_fields({} if metrics is None else dataclasses.asdict(metrics))

    def abandon(self) -> Path | None:
        """Stop writing the open episode without finishing it (after an error mid-episode): its `.part` stays,
        readable up to its last chunk, unlocked, so the next run in the folder removes it; returns its path."""
        part = self._part
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        if self._part_lock is not None:
            os.close(self._part_lock)
            self._part_lock = None
        self._part = None
        return part

    def close(self) -> None:
        """End an open episode (interrupted) and free the camera renderer."""
        self.end(interrupted=True)
        self._close_renderer()
        if self.server is not None:
            self.server.stop()
            self.server = None

    def _close_renderer(self) -> None:
        if self._renderer is not None:
            self._renderer[1].close()
            self._renderer = None

    # --- per step -----------------------------------------------------------------------------------------
    def _model_constants(self, task, model) -> dict:
        """Addresses and encoders of a model (cached), and the camera pose in the chassis frame."""
        if self._model_cache is None or self._model_cache[0] is not model:
            root = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, task.vehicle.prefix + "root")
            camera = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, self.options.camera)
            c = {"model": model, "q": int(model.jnt_qposadr[root]), "camera": camera,
                 "physics": proto.PhysicsStateEncoder(model.nq, model.nv, model.na, model.nmocap)}
            if camera >= 0:
                c["camera_tf"] = _camera_in_chassis(model, task.vehicle.body_id, camera)
                h, w = self.options.camera_size
                f = 0.5 * h / math.tan(math.radians(float(model.cam_fovy[camera])) / 2)
                c["K"] = [f, 0.0, w / 2, 0.0, f, h / 2, 0.0, 0.0, 1.0]
                c["P"] = [f, 0.0, w / 2, 0.0, 0.0, f, h / 2, 0.0, 0.0, 0.0, 1.0, 0.0]
            self._model_cache = (model, c)
        return self._model_cache[1]

    def decided(self, scenario: str, agent: str, action: str, observation: dict[str, np.ndarray]) -> None:
        """Log who decides the coming step's action (`agent`, in the active `scenario`) and the observation it saw,
        at the simulated time the action acts from (/decision); call before that step."""
        if self._writer is None:
            raise RuntimeError("EpisodeRecorder.decided before begin()")
        if self._operative_channels is None:
            self._operative_channels = _OperativeChannels(self._context)
        seen = {str(key): np.asarray(value).tolist() for key, value in observation.items()}
        message = {"t": self._prev_time, "scenario": scenario, "agent": agent, "action": action, "observation": seen}
        self._operative_channels.decision.log(json.dumps(message).encode(), self._t0 + _ns(self._prev_time))

    def _log_operative(self, task, ns: int) -> None:
        """The operative level's control periods of this env step (their comfort samples join the episode's), its
        last MPC plan and the path it tracks ahead (3D)."""
        if self._operative_channels is None:
            self._operative_channels = _OperativeChannels(self._context)
        ch = self._operative_channels
        for tick in task.ticks:
            comfort = tick.get("comfort")
            if comfort is not None and not task.info.get("physics_error"):
                self._comfort.append(*comfort)
            record = {key: value for key, value in tick.items() if key != "comfort"}
            ch.step.log(json.dumps(record).encode(), self._t0 + _ns(tick["t"]))
        plan = task.operative.status.plan
        if plan is None:
            return
        stop = task.operative.status.stop
        ch.plan.log(json.dumps({"t": task.operative.mpc.times.tolist(), "s": plan.s.tolist(), "v": plan.v.tolist(),
                                "a": plan.a.tolist(), "stop": stop, "mode": plan.mode}).encode(), ns)
        path, stop_line = task.operative_path()
        ch.scene.log(fm.SceneUpdate(entities=[scene.plan_entity(path, stop_line, PLAN_RGBA, STOP_RGBA,
                                                                _timestamp(ns))]), log_time=ns)

    def _log_junction(self, signals: dict, t: float, ns: int) -> None:
        """What every junction entry shows (/junction) and its lamp in the 3D scene (/scene/signals)."""
        if self._junction_channels is None:
            self._junction_channels = (
                foxglove.Channel("/junction", schema=_JUNCTION, message_encoding="json", context=self._context),
                foxglove.channels.SceneUpdateChannel("/scene/signals", context=self._context))
        table, lamps = self._junction_channels
        entries = signals["entries"]
        table.base.log(json.dumps({"t": float(t), "control": signals["control"], "entries": entries}).encode(), ns)
        entity = scene.signals_entity(signals["xy"], [e["state"] for e in entries], _timestamp(ns))
        lamps.log(fm.SceneUpdate(entities=[entity]), log_time=ns)

    def _log_sensors(self, sensors: dict[str, np.ndarray], ns: int) -> None:
        if self._sensor_channels is None:
            self._sensor_channels = _SensorChannels(self._context)
        ch, stamp = self._sensor_channels, _timestamp(ns)
        if "depth" in sensors:
            depth = np.ascontiguousarray(sensors["depth"], np.float32)
            ch.depth.log(fm.RawImage(timestamp=stamp, frame_id=CAMERA_FRAME, width=depth.shape[1],
                                     height=depth.shape[0], encoding="32FC1", step=4 * depth.shape[1],
                                     data=depth.tobytes()), log_time=ns)
        if "segmentation" in sensors:
            labels = (np.asarray(sensors["segmentation"], np.uint8) * SEGMENT_SCALE).astype(np.uint8)
            ch.segmentation.log(fm.RawImage(timestamp=stamp, frame_id=CAMERA_FRAME, width=labels.shape[1],
                                            height=labels.shape[0], encoding="mono8", step=labels.shape[1],
                                            data=labels.tobytes()), log_time=ns)
        if "range" in sensors:
            ranges = np.asarray(sensors["range"], np.float64)
            ch.range.log(fm.LaserScan(timestamp=stamp, frame_id=scene.EGO, start_angle=0.0,
                                      end_angle=float(2 * np.pi * (len(ranges) - 1) / len(ranges)),
                                      ranges=ranges.tolist()), log_time=ns)

    def _road_bytes(self, road_map) -> bytes:
        if self._road_cache is None or self._road_cache[0] is not road_map:
            self._road_cache = (road_map, fm.SceneUpdate(entities=scene.road_entities(road_map)).encode())
        return self._road_cache[1]

    def _log_state(self, task, data, c: dict, action: tuple[float, float, float] | None, ns: int) -> None:
        ch = self._channels
        t = float(data.time)
        vehicle = task.vehicle
        q = data.qpos
        a = c["q"]
        stamp = _timestamp(ns)
        transforms = [fm.FrameTransform(
            timestamp=stamp, parent_frame_id=scene.WORLD, child_frame_id=scene.EGO,
            translation=fm.Vector3(x=float(q[a]), y=float(q[a + 1]), z=float(q[a + 2])),
            rotation=fm.Quaternion(w=float(q[a + 3]), x=float(q[a + 4]), y=float(q[a + 5]), z=float(q[a + 6])))]
        if c["camera"] >= 0:
            (px, py, pz), (qw, qx, qy, qz) = c["camera_tf"]
            transforms.append(fm.FrameTransform(
                timestamp=stamp, parent_frame_id=scene.EGO, child_frame_id=CAMERA_FRAME,
                translation=fm.Vector3(x=px, y=py, z=pz), rotation=fm.Quaternion(w=qw, x=qx, y=qy, z=qz)))
        ch.tf.log(fm.FrameTransforms(transforms=transforms), log_time=ns)

        x, y, yaw = vehicle.pose(data)
        speed = vehicle.speed(data)
        accel_long, accel_lat = vehicle.acceleration(data)
        dt = t - self._prev_time
        if self._prev_accel is None or dt <= 0.0:
            jerk_long = jerk_lat = 0.0
        else:
            jerk_long, jerk_lat = (accel_long - self._prev_accel[0]) / dt, (accel_lat - self._prev_accel[1]) / dt
        jerk = math.hypot(jerk_long, jerk_lat)
        self._prev_accel, self._prev_time = (accel_long, accel_lat), t
        if action is not None:
            self._speed_sum += speed
        if not task.info.get("physics_error"):  # the task's samples (those of its info's comfort metrics)
            task.sample_comfort(data, self._comfort)
        lane_offset = getattr(task, "lane_offset", None)
        heading_error = getattr(task, "heading_error", None)
        if lane_offset is None or heading_error is None:  # a task without its own lane frame: ask the map
            query = task.road_map.locate((x, y), yaw)
            lane_offset, heading_error = query.d, query.heading_error
        throttle, steer, brake = action if action is not None else (0.0, 0.0, 0.0)
        active_scenario = getattr(task, "active_scenario", None)  # urban tasks
        scenario = active_scenario() if active_scenario is not None else None
        state = {"t": t, "x": x, "y": y, "yaw": yaw, "speed": speed, "yaw_rate": vehicle.yaw_rate(data),
                 "accel_long": accel_long, "accel_lat": accel_lat, "jerk_long": jerk_long, "jerk_lat": jerk_lat,
                 "jerk": jerk, "steering_angle": vehicle.steering_angle(data), "throttle": throttle,
                 "steer": steer, "brake": brake, "lane_offset": float(lane_offset),
                 "heading_error": float(heading_error), "scenario": scenario}
        ch.state.log(json.dumps(state).encode(), ns)
        ch.physics.log(c["physics"].encode(data), ns)

        users = task.road_users()
        if len(users.kinds) or self._users_shown:
            body = self._cubes.encode(users.poses, users.half_sizes, self._kind_colors(users.kinds))
            if users.intentions is not None:
                body += self._intention_labels(users, scenario)
            head = proto.entity_head(ns, scene.WORLD, "road_users")
            ch.users.log(proto.scene_update_bytes(head, body), ns)
            self._users_shown = len(users.kinds) > 0
        signals = getattr(task, "junction_signals", None)
        signals = signals() if signals is not None else None
        if signals is not None:
            self._log_junction(signals, data.time, ns)
        every = self.options.camera_every
        if every and c["camera"] >= 0 and self._steps % every == 0:
            self._log_image(task, c, data, stamp, ns)
        self._last_task_info = task.info

    def _log_image(self, task, c: dict, data, stamp: fm.Timestamp, ns: int) -> None:
        from PIL import Image

        h, w = self.options.camera_size
        if self._renderer is None or self._renderer[0] is not c["model"]:
            from mjdrive.sensors import CameraRenderer

            self._close_renderer()
            self._renderer = (c["model"], CameraRenderer(c["model"], self.options.camera, h, w))
        pixels = self._renderer[1].render(data)
        buffer = io.BytesIO()
        if self.options.image_format == "jpeg":
            Image.fromarray(pixels).save(buffer, format="JPEG", quality=self.options.jpeg_quality)
        else:
            Image.fromarray(pixels).save(buffer, format="PNG", compress_level=1)
        self._channels.image.log(fm.CompressedImage(timestamp=stamp, frame_id=CAMERA_FRAME, data=buffer.getvalue(),
                                                    format=self.options.image_format), log_time=ns)
        self._channels.calibration.log(fm.CameraCalibration(
            timestamp=stamp, frame_id=CAMERA_FRAME, width=w, height=h, distortion_model="plumb_bob",
            D=[0.0] * 5, K=c["K"], R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], P=c["P"]), log_time=ns)


def _camera_in_chassis(model: mujoco.MjModel, body: int, camera: int) -> tuple[tuple, tuple]:
    """(position [m], quaternion wxyz) of a camera's optical frame (z forward, x right, y down: Foxglove's
    convention; MuJoCo cameras look along -z with y up) in the chassis frame, from the model's qpos0 pose."""
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    rb, pb = data.xmat[body].reshape(3, 3), data.xpos[body]
    rc, pc = data.cam_xmat[camera].reshape(3, 3), data.cam_xpos[camera]
    position = rb.T @ (pc - pb)
    rotation = rb.T @ rc @ np.diag([1.0, -1.0, -1.0])
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, rotation.ravel())
    return tuple(float(v) for v in position), tuple(float(v) for v in quat)

