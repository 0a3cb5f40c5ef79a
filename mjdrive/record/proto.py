"""Protobuf on the hot path without building message objects: wire-format helpers, numpy-encoded
repeated cubes (the road users of a `foxglove.SceneUpdate`) and their text labels, mjdrive's own
`PhysicsState` schema, and a generic decoder for any protobuf channel of an MCAP file (used by the reader
and the tests).

Every double is written explicitly (proto3 readers accept zeros that a proto3 writer would omit), so a
cube has a fixed size and N cubes are one numpy buffer whose doubles sit at fixed offsets.
"""

from __future__ import annotations

import struct

import numpy as np

_DOUBLE = 1  # wire type fixed64
_LEN = 2  # wire type length-delimited


def varint(value: int) -> bytes:
    """Base-128 varint of a non-negative int."""
    out = bytearray()
    while value > 0x7F:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def tag(field: int, wire: int) -> bytes:
    return varint(field << 3 | wire)


def length_delimited(field: int, payload: bytes) -> bytes:
    """Field `field` holding a submessage, string or packed array."""
    return tag(field, _LEN) + varint(len(payload)) + payload


def timestamp(ns: int) -> bytes:
    """A google.protobuf.Timestamp (seconds, nanos) payload for `ns` [ns since the epoch]."""
    seconds, nanos = divmod(ns, 1_000_000_000)
    return tag(1, 0) + varint(seconds) + tag(2, 0) + varint(nanos)


def _fixed_layout(spec: list, offset: int, names: list[str], offsets: list[int]) -> bytes:
    """Encode `spec` (list of (field, name) doubles or (field, sub-spec) submessages) with zero doubles,
    recording each double's byte offset (relative to the start of the returned bytes + `offset`)."""
    out = bytearray()
    for field, item in spec:
        if isinstance(item, str):
            out += tag(field, _DOUBLE)
            names.append(item)
            offsets.append(offset + len(out))
            out += bytes(8)
        else:
            head = tag(field, _LEN)
            # a submessage of doubles only has a size independent of the values: encode it once to learn it
            size = len(_fixed_layout(item, 0, [], []))
            head += varint(size)
            out += head
            out += _fixed_layout(item, offset + len(out), names, offsets)
    return bytes(out)


_VEC3 = [(1, "x"), (2, "y"), (3, "z")]
_CUBE = [  # foxglove.CubePrimitive: pose (position, orientation), size, color
    (1, [(1, [(1, "px"), (2, "py"), (3, "pz")]), (2, [(1, "qx"), (2, "qy"), (3, "qz"), (4, "qw")])]),
    (2, [(1, "sx"), (2, "sy"), (3, "sz")]),
    (3, [(1, "r"), (2, "g"), (3, "b"), (4, "a")]),
]
ENTITY_CUBES_FIELD = 8  # foxglove.SceneEntity.cubes


class CubeListEncoder:
    """Encodes N boxes as the repeated `cubes` field of a foxglove.SceneEntity, into a reused buffer.

    `encode(poses, half_sizes, rgba)` takes poses (N,3) [m, m, rad] of boxes standing on the ground,
    half sizes (N,3) [m] and colours (N,4) [0-1]; returns the bytes of the N `cubes` fields.
    """

    def __init__(self, capacity: int = 64):
        names: list[str] = []
        offsets: list[int] = []
        cube = _fixed_layout(_CUBE, 0, names, offsets)
        head = tag(ENTITY_CUBES_FIELD, _LEN) + varint(len(cube))
        self.template = np.frombuffer(head + cube, np.uint8)
        self.dtype = np.dtype({"names": names, "formats": ["<f8"] * len(names),
                               "offsets": [len(head) + o for o in offsets], "itemsize": len(self.template)})
        self._grow(capacity)

    def _grow(self, capacity: int) -> None:
        self.buffer = np.tile(self.template, capacity)
        self.records = self.buffer.view(self.dtype)
        self.records["qx"] = 0.0
        self.records["qy"] = 0.0

    def encode(self, poses: np.ndarray, half_sizes: np.ndarray, rgba: np.ndarray) -> bytes:
        n = len(poses)
        if n > len(self.records):
            self._grow(max(n, 2 * len(self.records)))
        r = self.records[:n]
        r["px"], r["py"] = poses[:, 0], poses[:, 1]
        r["pz"] = half_sizes[:, 2]  # boxes stand on the ground
        half_yaw = 0.5 * poses[:, 2]
        r["qz"], r["qw"] = np.sin(half_yaw), np.cos(half_yaw)
        r["sx"], r["sy"], r["sz"] = 2.0 * half_sizes[:, 0], 2.0 * half_sizes[:, 1], 2.0 * half_sizes[:, 2]
        r["r"], r["g"], r["b"], r["a"] = rgba[:, 0], rgba[:, 1], rgba[:, 2], rgba[:, 3]
        return self.buffer[: n * len(self.template)].tobytes()


ENTITY_TEXTS_FIELD = 13  # foxglove.SceneEntity.texts


def text_field(text: bytes, rgba: tuple[float, ...], font_size: float = 12.0) -> tuple[bytes, int]:
    """One `texts` field of a foxglove.SceneEntity: a billboard, scale-invariant label (UTF-8 `text`, colour
    `rgba` [0-1], `font_size` [px]) at (0, 0, 0), and the byte offset of its position's x (`place` moves it)."""
    position = struct.pack("<BdBdBd", 0x09, 0.0, 0x11, 0.0, 0x19, 0.0)  # x, y, z: fields 1-3, fixed64
    head = tag(1, _LEN) + varint(len(position))
    pose = head + position + length_delimited(2, tag(4, _DOUBLE) + struct.pack("<d", 1.0))  # orientation w = 1
    style = tag(2, 0) + varint(1) + tag(3, _DOUBLE) + struct.pack("<d", font_size) + tag(4, 0) + varint(1)
    r, g, b, a = rgba
    color = length_delimited(5, struct.pack("<BdBdBdBd", 0x09, r, 0x11, g, 0x19, b, 0x21, a))
    body = length_delimited(1, pose) + style + color + length_delimited(6, text)
    outer = tag(ENTITY_TEXTS_FIELD, _LEN) + varint(len(body))
    return outer + body, len(outer) + len(tag(1, _LEN) + varint(len(pose))) + len(head) + 1


def place(buffer: bytearray, at: int, x: float, y: float, z: float) -> None:
    """Write a position (x, y, z) [m] into a `text_field` copied into `buffer` with its x at byte `at`."""
    struct.pack_into("<dBdBd", buffer, at, x, 0x11, y, 0x19, z)


def text_fields(positions: np.ndarray, texts: list[bytes], rgba: np.ndarray, font_size: float = 12.0) -> bytes:
    """The repeated `texts` fields (`text_field`) of labels `texts` at `positions` (N,3) [m], colours (N,4)."""
    out = bytearray()
    for (x, y, z), text, color in zip(positions.tolist(), texts, rgba.tolist(), strict=True):
        field, at = text_field(text, tuple(color), font_size)
        start = len(out)
        out += field
        place(out, start + at, x, y, z)
    return bytes(out)


def scene_update_bytes(entity_head: bytes, entity_body: bytes) -> bytes:
    """A foxglove.SceneUpdate holding one entity (head: timestamp/frame/id fields, body: primitives)."""
    return length_delimited(2, entity_head + entity_body)


def entity_head(ns: int, frame_id: str, entity_id: str) -> bytes:
    """SceneEntity fields timestamp (1), frame_id (2), id (3)."""
    return (length_delimited(1, timestamp(ns)) + length_delimited(2, frame_id.encode())
            + length_delimited(3, entity_id.encode()))


# --- mjdrive.PhysicsState: the exact simulator state, for replay checks ----------------------------------

PHYSICS_SCHEMA_NAME = "mjdrive.PhysicsState"
_PHYSICS_FIELDS = ("time", "qpos", "qvel", "act", "mocap_pos", "mocap_quat")  # field numbers 1..6


def physics_schema_data() -> bytes:
    """FileDescriptorSet of `mjdrive.PhysicsState {double time; repeated double qpos, qvel, act, mocap_pos,
    mocap_quat}` (packed doubles, MuJoCo units: s, qpos/qvel as in mjData, mocap arrays flattened)."""
    from google.protobuf import descriptor_pb2

    fds = descriptor_pb2.FileDescriptorSet()
    file = fds.file.add(name="mjdrive/PhysicsState.proto", package="mjdrive", syntax="proto3")
    message = file.message_type.add(name="PhysicsState")
    f = descriptor_pb2.FieldDescriptorProto
    for number, name in enumerate(_PHYSICS_FIELDS, start=1):
        label = f.LABEL_OPTIONAL if name == "time" else f.LABEL_REPEATED
        message.field.add(name=name, number=number, type=f.TYPE_DOUBLE, label=label)
    return fds.SerializeToString()


class PhysicsStateEncoder:
    """Encodes (time, qpos, qvel, act, mocap_pos, mocap_quat) of an MjData as `mjdrive.PhysicsState`."""

    def __init__(self, nq: int, nv: int, na: int, nmocap: int):
        sizes = {"qpos": nq, "qvel": nv, "act": na, "mocap_pos": 3 * nmocap, "mocap_quat": 4 * nmocap}
        self._time_tag = tag(1, _DOUBLE)
        self._heads = [(name, tag(number, _LEN) + varint(8 * sizes[name]))
                       for number, name in enumerate(_PHYSICS_FIELDS, start=1) if name != "time" and sizes[name]]

    def encode(self, data) -> bytes:
        parts = [self._time_tag, struct.pack("<d", data.time)]
        for name, head in self._heads:
            parts.append(head)
            parts.append(getattr(data, name).tobytes())
        return b"".join(parts)


# --- decoding -----------------------------------------------------------------------------------------

_CLASSES: dict[tuple[str, bytes], type] = {}


def message_class(schema_name: str, schema_data: bytes) -> type:
    """The protobuf message class of an MCAP protobuf schema (a FileDescriptorSet), cached."""
    key = (schema_name, schema_data)
    if key not in _CLASSES:
        from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

        pool = descriptor_pool.DescriptorPool()
        for file in descriptor_pb2.FileDescriptorSet.FromString(schema_data).file:
            pool.Add(file)
        _CLASSES[key] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))
    return _CLASSES[key]


def decode(schema_name: str, schema_data: bytes, payload: bytes):
    """Decode one protobuf message of an MCAP channel."""
    return message_class(schema_name, schema_data).FromString(payload)
