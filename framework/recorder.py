"""The flight recorder: every chart event, transition, configuration request, ack
and component state change, timestamped, in an MCAP file.

It only listens on the bus (like any other process could), so it records what
really travelled. Messages are JSON with JSON Schemas, so Foxglove and any MCAP
reader can open the file. It survives a crash of the process that records: messages
are written as plain records (no chunks to fill) and flushed to the operating system
at least every `FLUSH_PERIOD`, so a SIGKILL loses at most that much; `read_recording`
reads a file cut anywhere (no summary, a torn last record) up to its last whole
record. (A power loss can still lose what the OS had not written to disk yet.) Port
samples can be recorded too, by key.

Beside fw's own JSON channels it writes Foxglove's well-known messages
(`framework/scene.py`): every record as a `foxglove.Log` line on `/fw/log`, and the
recorded joints, poses and people's envelopes as joint states, transforms and a 3D
scene, so Foxglove shows the run without fw's schemas. `fw log` and `fw replay` read
the JSON channels and skip those.

    fw deploy topologies/demo.yaml --record run.mcap
    fw log run.mcap                   # the timeline
    fw replay run.mcap                # feed the recorded events to the chart again
"""

from __future__ import annotations

import json
import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

from framework import keys, messages
from framework.bus import Bus
from framework.coordinator import ACKS_KEY, REQUESTS_KEY, STATUS_KEY
from framework.errors import FwError
from framework.messages import ConfigAck, ConfigRequest, EventMessage
from framework.ports import ConnPolicy, InputPort, ReadStatus

FLUSH_PERIOD = 0.05
"""Seconds at most between a message and its flush to the operating system."""

_SCHEMAS: dict[str, dict[str, Any]] = {
    "fw.ChartStatus": {
        "type": "object",
        "title": "fw.ChartStatus",
        "properties": {
            "stamp": {"type": "number"},
            "kind": {"type": "string"},
            "payload": {"type": "object"},
        },
    },
    "fw.ComponentState": {
        "type": "object",
        "title": "fw.ComponentState",
        "properties": {
            "stamp": {"type": "number"},
            "component": {"type": "string"},
            "old": {"type": "string"},
            "new": {"type": "string"},
            "reason": {"type": "string"},
        },
    },
    "fw.Refusal": {
        "type": "object",
        "title": "fw.Refusal",
        "description": "A sample a component refused (and how many refusals it stands for)",
        "properties": {
            "stamp": {"type": "number"},
            "component": {"type": "string"},
            "port": {"type": "string"},
            "reason": {"type": "string"},
            "count": {"type": "integer"},
        },
    },
    "fw.ConfigRequest": {
        "type": "object",
        "title": "fw.ConfigRequest",
        "properties": {
            "stamp": {"type": "number"},
            "request_id": {"type": "integer"},
            "tag": {"type": "string"},
            "args": {"type": "object"},
            "deadline": {"type": "number"},
            "alone": {"type": "boolean"},
        },
    },
    "fw.ConfigAck": {
        "type": "object",
        "title": "fw.ConfigAck",
        "properties": {
            "stamp": {"type": "number"},
            "request_id": {"type": "integer"},
            "ok": {"type": "boolean"},
            "tag": {"type": "string"},
            "step": {"type": "string"},
            "reason": {"type": "string"},
            "process": {"type": "string", "description": "who made a local switch"},
        },
    },
    "fw.Sample": {
        "type": "object",
        "title": "fw.Sample",
        "description": "A port sample, as its message's fields.",
    },
}


class RecorderError(FwError):
    """A recording could not be written or read."""


def _plain(value: Any) -> Any:
    if is_dataclass(value):
        return {k: _plain(v) for k, v in asdict(value).items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value


def _hook(path: str) -> Any:
    """The function a topology names, or a `RecorderError` saying why not."""
    from framework.classes import ClassPathError, load_function

    try:
        return load_function(path)
    except ClassPathError as exc:
        raise RecorderError(f"cannot draw a recorded output: {exc}") from None


class _Discard:
    """A file that keeps nothing, only counts: a recorder that only feeds the live view
    (the MCAP writer asks where it is)."""

    def __init__(self) -> None:
        self._at = 0

    def write(self, data: Any) -> int:
        self._at += len(data)
        return len(data)

    def tell(self) -> int:
        return self._at

    def flush(self) -> None:
        return None

    def close(self) -> None:
        return None


class FlightRecorder:
    """Records a deployment's coordination traffic (and chosen port samples) to MCAP."""

    def __init__(
        self,
        path: str | Path | None,
        bus: Bus,
        samples: dict[str, str] | None = None,
        metadata: dict[str, str] | None = None,
        foxglove: bool = True,
        frames: dict[str, str] | None = None,
        names: dict[str, str] | None = None,
        live: Any = None,
        links: dict[str, str] | None = None,
        draws: dict[str, str] | None = None,
    ):
        """`samples` maps extra keys to record to their message type name; `metadata`
        (for example the statechart's path, used by `fw replay`) is stored in the file;
        `foxglove`: also write Foxglove's well-known messages (framework/scene.py), a
        recorded key's in the frame `frames` names for it, named as `names` says (else
        by its key); `live`: a `framework.live_view.LiveView` served the same Foxglove
        messages as they come (`path` None: nothing written, only served); `links`: per
        recorded JointState key, the `module:function` giving the robot's links, drawn
        as transforms; `draws`: per recorded key, the `module:function` turning a
        sample into `framework.scene.Shapes`."""
        from mcap.writer import CompressionType, Writer

        self.path = Path(path) if path is not None else None
        try:
            self._file = self.path.open("wb") if self.path is not None else _Discard()
        except OSError as exc:
            raise RecorderError(f"cannot write {self.path}: {exc}") from None
        self._live = live
        self._writer = Writer(self._file, compression=CompressionType.NONE, use_chunking=False)
        self._writer.start(profile="", library="fw")
        self._writer.add_metadata(name="fw", data={k: str(v) for k, v in (metadata or {}).items()})
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        self._schema_ids = {
            name: self._writer.register_schema(
                name=name, encoding="jsonschema", data=json.dumps(spec).encode()
            )
            for name, spec in _SCHEMAS.items()
        }
        self._ports: list[InputPort[Any]] = []
        self._scene = None
        if foxglove or live is not None:
            from framework import scene

            self._scene = scene
        self._foxglove_schemas: dict[str, int] = {}
        names = dict(names or {})
        self._frames = {names.get(key, key): frame for key, frame in (frames or {}).items()}
        self._links = {names.get(key, key): _hook(path) for key, path in (links or {}).items()}
        self._draws = {names.get(key, key): _hook(path) for key, path in (draws or {}).items()}
        self._undrawable: set[str] = set()
        self.count = 0
        self._closed = False
        self._file.flush()
        self._dirty = False
        self._stop = threading.Event()
        self._flusher = threading.Thread(target=self._flush_loop, name="fw-recorder", daemon=True)
        self._flusher.start()
        self._listen(
            bus,
            STATUS_KEY,
            EventMessage,
            "/fw/chart",
            "fw.ChartStatus",
            lambda m: {"stamp": m.stamp, "kind": m.name, "payload": m.payload},
        )
        self._listen(
            bus, REQUESTS_KEY, ConfigRequest, "/fw/config/request", "fw.ConfigRequest", _plain
        )
        self._listen(bus, ACKS_KEY, ConfigAck, "/fw/config/ack", "fw.ConfigAck", _plain)
        self._subs = [
            bus.subscribe(
                keys.ALL_STATES, self._by_component("/fw/components", "fw.ComponentState")
            ),
            bus.subscribe(keys.ALL_REFUSED, self._by_component("/fw/refused", "fw.Refusal")),
            bus.subscribe(keys.ALL_SWITCHED, self._switched, history=False),
        ]
        for key, type_name in (samples or {}).items():
            kind = messages.resolve_type(type_name)
            name = names.get(key, key)
            self._listen(bus, key, kind, f"/fw/samples/{key}", "fw.Sample", _plain, name)

    @classmethod
    def of_topology(
        cls,
        path: str | Path | None,
        bus: Bus,
        topology: Any,
        extra: dict[str, str] | None = None,
        **options: Any,
    ) -> FlightRecorder:
        """A recorder of what `topology`'s `record:` names (its outputs' keys, frames,
        names, links and drawings), with `extra` keys to record on top
        (`--record-samples`)."""
        records = topology.records
        return cls(
            path,
            bus,
            {**{key: r.kind for key, r in records.items()}, **(extra or {})},
            frames={key: r.frame for key, r in records.items() if r.frame},
            names={key: r.name for key, r in records.items()},
            links={key: r.links for key, r in records.items() if r.links},
            draws={key: r.draw for key, r in records.items() if r.draw},
            **options,
        )

    def _channel(self, topic: str, schema: str) -> int:
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=self._schema_ids[schema]
            )
        return channel

    def write(
        self, topic: str, schema: str, data: dict[str, Any], stamp: float | None = None
    ) -> None:
        """Append one message (thread-safe); with Foxglove's messages on, its timeline
        line too (`/fw/log`), samples excepted (their scene is written by `_sample`)."""
        when = stamp or time.time()
        body = json.dumps(data, default=str).encode()
        log = None
        if self._scene is not None and schema != "fw.Sample":
            from framework.timeline import line

            log = self._scene.log(when, line(topic, data))
        with self._lock:
            if self._closed:
                return
            self._add(self._channel(topic, schema), when, body)
            if log is not None:
                self._add(self._foxglove_channel(self._scene.LOG_TOPIC, log), when, log.data)
        if log is not None and self._live is not None:
            self._live.publish(self._scene.LOG_TOPIC, log, when)

    def _add(self, channel: int, when: float, body: bytes) -> None:
        """One message on `channel` (the lock held)."""
        self._writer.add_message(
            channel, log_time=max(int(when * 1e9), 0), data=body, publish_time=time.time_ns()
        )
        self.count += 1
        self._dirty = True

    def _foxglove_channel(self, topic: str, converted: Any) -> int:
        """The channel of a Foxglove message's topic, its protobuf schema registered once
        (the lock held)."""
        channel = self._channels.get(topic)
        if channel is None:
            schema = self._foxglove_schemas.get(converted.schema_name)
            if schema is None:
                schema = self._foxglove_schemas[converted.schema_name] = (
                    self._writer.register_schema(
                        name=converted.schema_name, encoding="protobuf", data=converted.schema
                    )
                )
            channel = self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="protobuf", schema_id=schema
            )
        return channel

    def _sample(self, key: str, value: Any) -> None:
        """A recorded sample Foxglove can draw, as its well-known messages (its own
        kind's, and what the topology's links and drawing functions make of it)."""
        scene = self._scene
        if scene is None:
            return
        convert = scene.CONVERTERS.get(type(value))
        drawing = self._draws.get(key)
        if convert is None and drawing is None:
            return
        try:
            drawn = []
            if convert is not None:
                drawn.append(
                    (
                        scene.topic_for(type(value), key),
                        convert(value, key, self._frames.get(key, "")),
                    )
                )
            if key in self._links:
                drawn.append(("/tf", scene.link_transforms(value, self._links[key])))
            if drawing is not None:
                drawn += scene.shapes(getattr(value, "stamp", 0.0), key, drawing(value))
        except Exception as exc:  # a sample it cannot draw: said once, the recording goes on
            if key not in self._undrawable:
                self._undrawable.add(key)
                refusal = {"component": "recorder", "port": key, "count": 1}
                self.write("/fw/refused", "fw.Refusal", {**refusal, "reason": f"not drawn: {exc}"})
            return
        when = getattr(value, "stamp", 0.0) or time.time()
        with self._lock:
            if self._closed:
                return
            for topic, message in drawn:
                self._add(self._foxglove_channel(topic, message), when, message.data)
        if self._live is not None:
            for topic, message in drawn:
                self._live.publish(topic, message, when)

    def _flush_loop(self) -> None:
        """Hand what was written to the operating system every `FLUSH_PERIOD`: a killed
        recorder then loses at most that much."""
        while not self._stop.wait(FLUSH_PERIOD):
            with self._lock:
                if self._closed:
                    return
                if self._dirty:
                    self._file.flush()
                    self._dirty = False

    def _listen(
        self,
        bus: Bus,
        key: str,
        kind: type,
        topic: str,
        schema: str,
        convert: Any,
        sample: str = "",
    ) -> None:
        """Record what arrives on `key` (`sample`: the key of a port sample, also drawn
        for Foxglove when it can be)."""
        port: InputPort[Any] = InputPort(topic, kind, policy=ConnPolicy("buffer", 4096))
        port.bus = bus

        def drain(p: InputPort[Any]) -> None:
            while True:
                status, value = p.read()
                if status is not ReadStatus.NEW:
                    return
                self.write(topic, schema, convert(value), getattr(value, "stamp", None))
                if sample:
                    self._sample(sample, value)

        port.on_data = drain
        port.connect(key)
        self._ports.append(port)

    def _by_component(self, topic: str, schema: str) -> Any:
        """A handler for what components say of themselves on `fw/<what>/*` (state
        changes, refusals): recorded on `topic` with the component's name."""

        def record(sample: Any) -> None:
            try:
                message, _, _ = messages.decode(sample.payload.to_bytes(), EventMessage)
            except messages.CodecError:
                return
            data = {"stamp": message.stamp, "component": message.source, **message.payload}
            self.write(topic, schema, data, message.stamp)

        return record

    def _switched(self, sample: Any) -> None:
        """A process's report of a local switch (framework/local_switch.py), with the
        process's name from its key."""
        try:
            report, _, _ = messages.decode(sample.payload.to_bytes(), ConfigAck)
        except messages.CodecError:
            return
        data = {"process": str(sample.key_expr).rsplit("/", 1)[-1], **_plain(report)}
        self.write("/fw/config/switched", "fw.ConfigAck", data, report.stamp)

    def close(self) -> None:
        """Stop listening and finish the file (summary and index); closing again does
        nothing."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        for port in self._ports:
            port.close()
        for sub in self._subs:
            sub.undeclare()
        self._stop.set()
        with self._lock:
            self._writer.finish()
            self._file.close()


MCAP_MAGIC = b"\x89MCAP0\r\n"
"""The first bytes of every MCAP file (the MCAP specification's magic)."""


def _records(path: str | Path) -> Iterator[Any]:
    """Every whole record of an MCAP file, in file order, stopping quietly at a torn
    end (a recorder killed mid-write): what was written before is kept."""
    from mcap.exceptions import McapError
    from mcap.stream_reader import StreamReader

    if not Path(path).is_file():
        raise RecorderError(f"{path}: no such recording")
    with Path(path).open("rb") as handle:
        if handle.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            raise RecorderError(
                f"{path}: not a flight recording: it is no MCAP file "
                "(`fw deploy TOPOLOGY --record run.mcap` writes one)"
            )
        handle.seek(0)
        try:
            yield from StreamReader(handle).records
        except (McapError, EOFError, ValueError, struct.error) as exc:
            if handle.tell() <= 8:
                raise RecorderError(f"{path}: not a readable fw recording ({exc})") from None
            return  # a torn last record: everything before it was read


def read_recording(path: str | Path) -> Iterator[tuple[str, float, dict[str, Any]]]:
    """(topic, time in seconds, message) of every recorded message, in time order; also
    for a recording cut short by a crash (no summary, a torn last record)."""
    from mcap.records import Channel, Message

    topics: dict[int, str] = {}
    found: list[tuple[int, str, bytes]] = []
    for record in _records(path):
        if isinstance(record, Channel):
            if record.message_encoding == "json":  # Foxglove's protobuf ones are not fw's
                topics[record.id] = record.topic
        elif isinstance(record, Message) and record.channel_id in topics:
            found.append((record.log_time, topics[record.channel_id], record.data))
    found.sort(key=lambda item: item[0])
    for log_time, topic, data in found:
        try:
            body = json.loads(data)
        except json.JSONDecodeError:
            continue  # one corrupt message does not hide the rest
        yield topic, log_time / 1e9, body


def recording_metadata(path: str | Path) -> dict[str, str]:
    """The `fw` metadata record of a recording (empty if there is none)."""
    from mcap.records import Metadata

    for record in _records(path):
        if isinstance(record, Metadata) and record.name == "fw":
            return dict(record.metadata)
    return {}
