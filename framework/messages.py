"""The message catalog and its one binary codec.

Every port carries one message type. Messages are frozen dataclasses whose
`LAYOUT` names each field's wire kind; from it the codec builds, once per
type, a `struct`-based encoder and decoder. Why this codec: `struct` is in
the standard library, packs a Pose in about a microsecond (JSON needs ~10),
and the layout doubles as the schema: every sample starts with a type id
(CRC-32 of the layout), so a port refuses a sample of another type, or of an
older layout of the same type, instead of misreading it.

Wire kinds: `f64`, `i64`, `bool`, `str`, `f64[N]` (fixed array), `f64[]`
(variable array), `json` (free-form payload), `msg[]:Name` (list of nested
messages).
"""

from __future__ import annotations

import json
import math
import operator
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

from framework.errors import FwError


class CodecError(FwError):
    """Bytes that are not a valid sample of the expected message type."""


@dataclass(frozen=True, slots=True)
class Pose:
    """A tracked rigid body: position (m), unit quaternion (w, x, y, z), quality."""

    LAYOUT: ClassVar[str] = (
        "position:f64[3] orientation:f64[4] stamp:f64 rms:f64 frame_number:i64 valid:bool "
        "frame:str tool:str"
    )
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    stamp: float = 0.0
    rms: float = 0.0
    frame_number: int = 0
    valid: bool = False
    frame: str = ""
    tool: str = ""

    def is_finite(self) -> bool:
        """True if every number is finite (a NaN pose must never move the robot)."""
        return all(math.isfinite(v) for v in (*self.position, *self.orientation, self.rms))


@dataclass(frozen=True, slots=True)
class JointState:
    """Joint positions (rad), velocities (rad/s) and torques (N·m) of the arm, and how
    many of the controller's cycles passed since the previous state (1 in command mode,
    more in monitor mode; 0: not said): a follower keeps the arm's time by it."""

    LAYOUT: ClassVar[str] = "stamp:f64 position:f64[] velocity:f64[] effort:f64[] cycles:i64"
    stamp: float = 0.0
    position: tuple[float, ...] = ()
    velocity: tuple[float, ...] = ()
    effort: tuple[float, ...] = ()
    cycles: int = 0


@dataclass(frozen=True, slots=True)
class ArmState:
    """What an arm's own controller reports every cycle (as FRI's measured state does):
    joints, the flange-tool pose (x y z, qw qx qy qz), brakes, the controller's latch, and
    how many requests (brake, release, reset, mode) it has served so far."""

    LAYOUT: ClassVar[str] = (
        "stamp:f64 cycle:i64 served:i64 position:f64[] velocity:f64[] effort:f64[] tcp:f64[7] "
        "braked:bool latched:bool reason:str"
    )
    stamp: float = 0.0
    cycle: int = 0
    served: int = 0
    position: tuple[float, ...] = ()
    velocity: tuple[float, ...] = ()
    effort: tuple[float, ...] = ()
    tcp: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)
    braked: bool = True
    latched: bool = False
    reason: str = ""


@dataclass(frozen=True, slots=True)
class Skeleton:
    """One user's skeleton as seen by one camera: joints as flat x, y, z triples (m)."""

    LAYOUT: ClassVar[str] = "user_id:i64 joints:f64[] confidence:f64[]"
    user_id: int = 0
    joints: tuple[float, ...] = ()
    confidence: tuple[float, ...] = ()


@dataclass(frozen=True, slots=True)
class Skeletons:
    """All skeletons of one camera frame."""

    LAYOUT: ClassVar[str] = "stamp:f64 sensor:str users:msg[]:Skeleton"
    stamp: float = 0.0
    sensor: str = ""
    users: tuple[Skeleton, ...] = ()


@dataclass(frozen=True, slots=True)
class EventMessage:
    """A named event with a JSON payload (to and from the Coordinator)."""

    LAYOUT: ClassVar[str] = "stamp:f64 name:str source:str payload:json"
    stamp: float = 0.0
    name: str = ""
    source: str = ""
    payload: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class ConfigRequest:
    """The Coordinator asks the Configurator to apply a named configuration."""

    LAYOUT: ClassVar[str] = "stamp:f64 request_id:i64 tag:str args:json deadline:f64 alone:bool"
    stamp: float = 0.0
    request_id: int = 0
    tag: str = ""
    args: dict[str, Any] = field(default_factory=dict)
    deadline: float = 0.0
    """Wall-clock time (s) after which it must not start (0: none): a request the
    requester has given up on is refused, never applied late."""
    alone: bool = False
    """Nothing else the requester asked for is still being applied: the process that
    hosts the configuration's first ports may switch them at once (a local switch,
    framework/configurator.py), as no earlier configuration can come after it."""


@dataclass(frozen=True, slots=True)
class ConfigAck:
    """The Configurator's answer: done, or failed at a step for a reason."""

    LAYOUT: ClassVar[str] = "stamp:f64 request_id:i64 ok:bool tag:str step:str reason:str"
    stamp: float = 0.0
    request_id: int = 0
    ok: bool = False
    tag: str = ""
    step: str = ""
    reason: str = ""


@dataclass(frozen=True, slots=True)
class Envelopes:
    """Capsules around people (segments a-b as flat xyz triples, radii, base frame, m),
    stamped with the oldest camera frame they come from: the robot keeps its distance
    from them, and pays their age in distance."""

    LAYOUT: ClassVar[str] = "stamp:f64 a:f64[] b:f64[] radius:f64[]"
    stamp: float = 0.0
    a: tuple[float, ...] = ()
    b: tuple[float, ...] = ()
    radius: tuple[float, ...] = ()


@dataclass(frozen=True, slots=True)
class Scalar:
    """One number with a time stamp (speeds, distances, counts)."""

    LAYOUT: ClassVar[str] = "stamp:f64 value:f64"
    stamp: float = 0.0
    value: float = 0.0


CATALOG: dict[str, type] = {
    cls.__name__: cls
    for cls in (
        Pose,
        JointState,
        ArmState,
        Skeleton,
        Skeletons,
        EventMessage,
        ConfigRequest,
        ConfigAck,
        Scalar,
        Envelopes,
    )
}
BUILTINS: dict[str, type] = {"float": float, "int": int, "bool": bool, "str": str}

# envelope: magic, version, type id, publisher id, sequence number
_ENVELOPE = struct.Struct("<2sBxIQQ")
_MAGIC, _VERSION = b"fw", 1
_U32 = struct.Struct("<I")


def type_name(kind: type) -> str:
    """The catalog name of a message type or builtin."""
    return kind.__name__


def resolve_type(name: str) -> type:
    """A message type or builtin by name; `CodecError` naming the known ones otherwise."""
    kind = CATALOG.get(name) or BUILTINS.get(name)
    if kind is None:
        known = ", ".join(sorted([*CATALOG, *BUILTINS]))
        raise CodecError(f"unknown message type {name!r} (known: {known})")
    return kind


class _Codec:
    """Encoder/decoder of one type's body, compiled from its layout."""

    def __init__(self, kind: type):
        self.kind = kind
        if kind in BUILTINS.values():
            self.layout = f"value:{_BUILTIN_KIND[kind]}"
            self.builtin = True
        else:
            self.layout = kind.LAYOUT
            self.builtin = False
        self.fields = [tuple(item.split(":", 1)) for item in self.layout.split()]
        if not self.builtin:
            names = [f.name for f in fields(kind)]
            if names != [name for name, _ in self.fields]:
                raise CodecError(f"{kind.__name__}.LAYOUT does not list its fields in order")
        signature = f"{type_name(kind)}|{self.layout}"
        self.type_id = zlib.crc32(signature.encode())
        self.shareable = not any(wire.startswith("json") for _, wire in self.fields)
        """Its values hold no mutable part (no JSON payload): a reader in the writer's
        process may be handed the writer's own object (ports), never a copy."""
        fixed = "<"
        self.fixed_names: list[str] = []
        self.fixed_sizes: list[int] = []
        self.variable: list[tuple[str, str]] = []
        for name, wire in self.fields:
            if wire in ("f64", "i64", "bool"):
                fixed += {"f64": "d", "i64": "q", "bool": "?"}[wire]
                self.fixed_names.append(name)
                self.fixed_sizes.append(0)
            elif wire.startswith("f64[") and wire != "f64[]":
                n = int(wire[4:-1])
                fixed += "d" * n
                self.fixed_names.append(name)
                self.fixed_sizes.append(n)
            else:
                self.variable.append((name, wire))
        self.fixed = struct.Struct(fixed)
        # top-level samples: envelope and fixed fields packed by one struct call
        self.head = struct.Struct(_ENVELOPE.format + fixed[1:])
        self.flat = all(size == 0 for size in self.fixed_sizes) and not self.variable
        self.getter = operator.attrgetter(*self.fixed_names) if self.fixed_names else None
        self.plan: list[tuple[str, int, int, str]] = []
        position = 0
        for name, wire in self.fields:
            if (name, wire) in self.variable:
                self.plan.append(("var", 0, 0, wire))
            else:
                size = self.fixed_sizes[self.fixed_names.index(name)]
                self.plan.append(("fixed", position, size, ""))
                position += size or 1

    def pack(self, value: Any, publisher: int, seq: int) -> bytes:
        """A whole sample: envelope, fixed fields, then variable fields."""
        if self.builtin or not self.flat:
            out = bytearray(_ENVELOPE.pack(_MAGIC, _VERSION, self.type_id, publisher, seq))
            self.encode(value, out)
            return bytes(out)
        if type(value) is not self.kind:
            raise CodecError(f"expected {type_name(self.kind)}, got {type(value).__name__}")
        fixed = self.getter(value)  # type: ignore[misc]
        if len(self.fixed_names) == 1:
            fixed = (fixed,)
        try:
            return self.head.pack(_MAGIC, _VERSION, self.type_id, publisher, seq, *fixed)
        except struct.error as exc:
            raise CodecError(f"{type_name(self.kind)}: {exc}") from None

    def unpack(self, view: memoryview) -> tuple[Any, int, int]:
        """(value, publisher, seq) of a whole sample whose envelope was checked."""
        if self.builtin or not self.flat:
            _, _, _, publisher, seq = _ENVELOPE.unpack_from(view, 0)
            value, end = self.decode(view, _ENVELOPE.size)
            if end != len(view):
                raise CodecError(
                    f"{len(view) - end} trailing bytes after a {type_name(self.kind)} sample"
                )
            return value, publisher, seq
        if len(view) != self.head.size:
            raise CodecError(
                f"a {type_name(self.kind)} sample has {self.head.size} bytes, got {len(view)}"
            )
        values = self.head.unpack_from(view, 0)
        return self.kind(*values[5:]), values[3], values[4]

    def encode(self, value: Any, out: bytearray) -> None:
        if self.builtin:
            if type(value) is not self.kind and not (self.kind is float and type(value) is int):
                raise CodecError(f"expected {self.kind.__name__}, got {type(value).__name__}")
            wire = self.fields[0][1]
            if wire == "str":
                _put_str(out, value)
            else:
                out += self.fixed.pack(value)
            return
        if type(value) is not self.kind:
            raise CodecError(f"expected {type_name(self.kind)}, got {type(value).__name__}")
        args: list[Any] = []
        for name, size in zip(self.fixed_names, self.fixed_sizes, strict=True):
            item = getattr(value, name)
            if size:
                if len(item) != size:
                    raise CodecError(
                        f"{type_name(self.kind)}.{name} needs {size} numbers, got {len(item)}"
                    )
                args.extend(item)
            else:
                args.append(item)
        try:
            out += self.fixed.pack(*args)
        except struct.error as exc:
            raise CodecError(f"{type_name(self.kind)}: {exc}") from None
        for name, wire in self.variable:
            _ENCODERS[wire.split(":")[0]](out, getattr(value, name), wire)

    def decode(self, data: memoryview, offset: int) -> tuple[Any, int]:
        if self.builtin:
            if self.fields[0][1] == "str":
                return _get_str(data, offset)
            (value,) = self.fixed.unpack_from(data, offset)
            return value, offset + self.fixed.size
        raw = self.fixed.unpack_from(data, offset)
        offset += self.fixed.size
        args: list[Any] = []
        for kind, start, size, wire in self.plan:
            if kind == "fixed":
                args.append(tuple(raw[start : start + size]) if size else raw[start])
            else:
                value, offset = _DECODERS[wire.split(":")[0]](data, offset, wire)
                args.append(value)
        return self.kind(*args), offset


_BUILTIN_KIND = {float: "f64", int: "i64", bool: "bool", str: "str"}


def _put_str(out: bytearray, text: str) -> None:
    raw = text.encode("utf-8")
    out += _U32.pack(len(raw))
    out += raw


def _get_str(data: memoryview, offset: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(data, offset)
    offset += 4
    if offset + n > len(data):
        raise CodecError("truncated text field")
    return bytes(data[offset : offset + n]).decode("utf-8"), offset + n


def _put_array(out: bytearray, values: Any, wire: str) -> None:
    out += _U32.pack(len(values))
    out += struct.pack(f"<{len(values)}d", *values)


def _get_array(data: memoryview, offset: int, wire: str) -> tuple[tuple[float, ...], int]:
    (n,) = _U32.unpack_from(data, offset)
    offset += 4
    if offset + 8 * n > len(data):
        raise CodecError("truncated array field")
    return struct.unpack_from(f"<{n}d", data, offset), offset + 8 * n


def _put_json(out: bytearray, value: Any, wire: str) -> None:
    try:
        _put_str(out, json.dumps(value, separators=(",", ":"), allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise CodecError(f"payload is not plain JSON data: {exc}") from None


def _get_json(data: memoryview, offset: int, wire: str) -> tuple[Any, int]:
    text, offset = _get_str(data, offset)
    try:
        return json.loads(text), offset
    except json.JSONDecodeError as exc:
        raise CodecError(f"corrupt JSON payload: {exc.msg}") from None


def _put_msgs(out: bytearray, items: Any, wire: str) -> None:
    codec = codec_for(resolve_type(wire.split(":", 1)[1]))
    out += _U32.pack(len(items))
    for item in items:
        codec.encode(item, out)


def _get_msgs(data: memoryview, offset: int, wire: str) -> tuple[tuple[Any, ...], int]:
    codec = codec_for(resolve_type(wire.split(":", 1)[1]))
    (n,) = _U32.unpack_from(data, offset)
    offset += 4
    items = []
    for _ in range(n):
        item, offset = codec.decode(data, offset)
        items.append(item)
    return tuple(items), offset


_ENCODERS: dict[str, Callable[..., None]] = {
    "str": lambda out, v, w: _put_str(out, v),
    "f64[]": _put_array,
    "json": _put_json,
    "msg[]": _put_msgs,
}
_DECODERS: dict[str, Callable[..., tuple[Any, int]]] = {
    "str": lambda d, o, w: _get_str(d, o),
    "f64[]": _get_array,
    "json": _get_json,
    "msg[]": _get_msgs,
}
_CODECS: dict[type, _Codec] = {}


def codec_for(kind: type) -> _Codec:
    """The compiled codec of a message type (built once)."""
    codec = _CODECS.get(kind)
    if codec is None:
        codec = _CODECS[kind] = _Codec(kind)
    return codec


def type_id(kind: type) -> int:
    """The 32-bit id every sample of this type starts with."""
    return codec_for(kind).type_id


def encode(value: Any, kind: type, publisher: int = 0, seq: int = 0) -> bytes:
    """One sample: envelope (type id, publisher id, sequence number) plus the body."""
    return codec_for(kind).pack(value, publisher, seq)


def decode(data: bytes | bytearray | memoryview, kind: type) -> tuple[Any, int, int]:
    """(value, publisher id, sequence number) of a sample; `CodecError` if it is not one."""
    view = memoryview(data)
    if len(view) < _ENVELOPE.size:
        raise CodecError(f"sample of {len(view)} bytes is shorter than its envelope")
    magic, version, tid, _, _ = _ENVELOPE.unpack_from(view, 0)
    if magic != _MAGIC or version != _VERSION:
        raise CodecError("not an fw sample (bad magic or version)")
    codec = codec_for(kind)
    if tid != codec.type_id:
        raise CodecError(
            f"sample is of another type (id {tid:#010x}), expected "
            f"{type_name(kind)} ({codec.type_id:#010x})"
        )
    try:
        return codec.unpack(view)
    except (struct.error, UnicodeDecodeError) as exc:
        raise CodecError(f"corrupt {type_name(kind)} sample: {exc}") from None
