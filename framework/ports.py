"""Typed input and output ports, connection policies and read status (as OROCOS RTT).

An output port publishes each written sample on the Zenoh key(s) it is
connected to; an input port subscribes to one key and keeps what arrives
according to its policy: `data` (the latest sample) or `buffer` (a bounded
FIFO with a declared overflow rule). `read()` returns `(NEW | OLD | NO_DATA,
value)` like RTT.

Rewiring never mixes connections: every (re)connection starts a new
generation, and a sample that arrives for an older generation (Zenoh can
still deliver the old key's samples after the switch) is dropped and
counted. Every sample carries its publisher's id and sequence number, so a
sample seen twice (cache replay racing a live sample) is dropped too.
A newly connected port receives the publisher's cached latest sample at
once instead of waiting for the next period.

An output port may also publish a *thinned* stream on a key of its own
(`connect(key, rate=...)`): at most `rate` samples per second, for a reader that
needs far fewer than the writer makes (a 30 Hz detector reading 1 kHz joints). A
sample that is not sent costs nothing on the wire and nothing to the reader's
process, which is where a 1 kHz stream's cost is (decoding, waking).

Within one process a sample never touches the bus: a reader connected to a key this
process's own output port writes is handed the written object itself (as RTT's
in-process connections), with no encoding and no decoding, when its type holds no
mutable part (every type but those with a JSON payload); so write immutable values
(tuples) and never change a value read from a port. A *stream* port (`Out(...,
stream=True)`, written every cycle of a fast loop) is encoded only when a reader in
another process listens on one of its keys (Zenoh's matching status): a 1 kHz stream
read only in its own process costs no encoding at all. A stream keeps no cached
sample for late readers (its next one comes within a cycle).
"""

from __future__ import annotations

import itertools
import random
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Generic, Protocol, TypeVar

from framework import messages
from framework.errors import FwError

T = TypeVar("T")


class PortError(FwError):
    """A port was used wrongly: bad policy, wrong type, not connected, no bus."""


class ReadStatus(Enum):
    """What `InputPort.read()` found."""

    NEW = "new"
    OLD = "old"
    NO_DATA = "no_data"


@dataclass(frozen=True)
class ConnPolicy:
    """How an input port keeps samples: latest value, or a bounded FIFO."""

    type: str = "data"
    size: int = 1
    overflow: str = "drop_oldest"

    def __post_init__(self) -> None:
        if self.type not in ("data", "buffer"):
            raise PortError(f"connection policy type must be 'data' or 'buffer', not {self.type!r}")
        if not isinstance(self.size, int) or isinstance(self.size, bool) or self.size < 1:
            raise PortError(
                f"connection policy size must be a whole number >= 1, not {self.size!r}"
            )
        if self.overflow not in ("drop_oldest", "drop_newest"):
            raise PortError(
                f"overflow must be 'drop_oldest' or 'drop_newest', not {self.overflow!r}"
            )

    @classmethod
    def from_spec(cls, spec: dict[str, Any] | ConnPolicy | None) -> ConnPolicy:
        """A policy from YAML-like data (`{type: buffer, size: 8, overflow: drop_newest}`)."""
        if spec is None:
            return cls()
        if isinstance(spec, ConnPolicy):
            return spec
        unknown = set(spec) - {"type", "size", "overflow"}
        if unknown:
            raise PortError(f"unknown connection policy key(s): {', '.join(sorted(unknown))}")
        return cls(**spec)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (for remote calls and introspection)."""
        return {"type": self.type, "size": self.size, "overflow": self.overflow}


@dataclass
class PortStats:
    """Counters of what happened to the samples of one port (nothing is dropped silently)."""

    written: int = 0
    received: int = 0
    dropped_stale: int = 0
    dropped_duplicate: int = 0
    dropped_overflow: int = 0
    dropped_invalid: int = 0
    discarded_on_rewire: int = 0
    ring_full: int = 0
    """Polls of a buffer port that found Zenoh's ring full: older samples may have been
    dropped there, before the port could count them (the ring holds twice the port's
    size, so a reader that falls that far behind is the one case)."""
    last_error: str = ""

    def to_dict(self) -> dict[str, Any]:
        """Plain data for introspection."""
        return dict(self.__dict__)


@dataclass(eq=False, repr=False)
class Port(Generic[T]):
    """What input and output ports share: a name, a message type and documentation."""

    name: str
    type: type
    doc: str = ""
    owner: str = ""
    stats: PortStats = field(default_factory=PortStats)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.full_name}: {self.type_name}>"

    @property
    def type_name(self) -> str:
        """The catalog name of the port's message type."""
        return messages.type_name(self.type)

    @property
    def full_name(self) -> str:
        """`component.port`."""
        return f"{self.owner}.{self.name}" if self.owner else self.name


_ids = random.SystemRandom()


class OutputPort(Port[T]):
    """Publishes written samples on the keys it is connected to (latest value cached,
    unless it is a `stream`: see the module docstring)."""

    def __init__(self, name: str, type: type, doc: str = "", stream: bool = False):
        super().__init__(name, type, doc)
        codec = messages.codec_for(type)  # fail at declaration if the type has no codec
        self.shareable = codec.shareable
        self.stream = stream
        self.publisher_id = _ids.getrandbits(63)
        self._seq = itertools.count(1)
        self._publishers: dict[str, Any] = {}
        self._matching: dict[str, list[Any]] = {}  # stream key -> [matching?, listener]
        self._thinned: dict[str, list[float]] = {}  # key -> [period (s), next send due]
        self._lock = threading.Lock()
        self.clock: Callable[[], float] = time.monotonic
        """What thinned keys measure their period by (a test's simulated clock)."""
        self.last: T | None = None
        self.last_data: bytes | None = None  # its encoding, if it was encoded
        self.last_seq = 0
        self.bus: Any = None
        self._deferred: deque[tuple[Any, int, bytes | None, list[Any]]] | None = None
        """Samples for other processes awaiting `flush` (value, number, its encoding if
        made, publishers); None: they are sent inside `write`."""

    @property
    def keys(self) -> list[str]:
        """Keys this port publishes on."""
        return sorted(self._publishers)

    def connect(self, key: str, rate: float = 0.0) -> None:
        """Also publish on `key` (idempotent); with `rate` (Hz), at most that many samples
        per second there (the first write after each period), a thinned stream."""
        if self.bus is None:
            raise PortError(f"output port {self.full_name} is not attached to a bus")
        if not (rate >= 0 and rate < float("inf")):
            raise PortError(f"a rate must be a positive number of Hz, not {rate!r}")
        with self._lock:
            if key not in self._publishers:
                publisher = self.bus.publisher(key, cache=not self.stream, remote_only=True)
                self._publishers[key] = publisher
                if self.stream:
                    # [matching?, listener, when last asked]: the listener's callbacks may
                    # run out of order on Zenoh's threads, so each asks for the status now
                    # rather than trusting the one it carries; and a key found unmatched
                    # is asked again at most every MATCHING_RECHECK s (a reader that came
                    # while a callback was lost is served within that)
                    flag: list[Any] = [publisher.matching_status.matching, None, time.monotonic()]
                    flag[1] = publisher.declare_matching_listener(
                        lambda _status, f=flag, p=publisher: f.__setitem__(
                            0, p.matching_status.matching
                        )
                    )
                    self._matching[key] = flag
                self.bus.local_writers.setdefault(key, {})[id(self)] = self
            if rate:
                self._thinned[key] = [1.0 / rate, -float("inf")]

    def disconnect(self, key: str | None = None) -> None:
        """Stop publishing on `key` (or on every key)."""
        with self._lock:
            keys = [key] if key is not None else list(self._publishers)
            for k in keys:
                publisher = self._publishers.pop(k, None)
                self._thinned.pop(k, None)
                flag = self._matching.pop(k, None)
                if flag is not None and flag[1] is not None:
                    flag[1].undeclare()
                if publisher is not None:
                    self.bus.local_writers.get(k, {}).pop(id(self), None)
                    publisher.undeclare()

    def write(self, value: T) -> None:
        """Publish one sample on every connected key; a wrong type raises `PortError`.
        Readers in this process get the object itself (or, for a type with a JSON
        payload, its encoding); it is encoded for the bus only when needed.

        One thread at a time per port (a component's lock serializes its updates and
        operations): each sample is numbered, and readers drop a number at or below one
        they kept as a repeat, so two threads overtaking each other between numbering
        and sending lose a sample. No lock here: a loop at real-time priority must not
        wait on one another thread may hold (with one, the multi-host run's KRC braked
        by itself in 4 of 9 runs, against 0 of 11 without; the cause was not shown)."""
        if type(value) is not self.type and not (self.type is float and type(value) is int):
            self._refuse_type(value)
        seq = self.last_seq = next(self._seq)
        data: bytes | None = None
        deferred = self._deferred
        if not self.shareable or not (self.stream or deferred is not None):
            data = self._encode(value, seq)  # a payload's error is the writer's, at once
        self.last, self.last_data = value, data
        self.stats.written += 1
        readers = self.bus.local_readers if self.bus is not None else {}
        thinned = self._thinned
        matching = self._matching
        now = self.clock() if thinned else 0.0
        remote: list[Any] | None = None
        for key, publisher in list(self._publishers.items()):
            due = thinned.get(key)
            if due is not None:
                period, next_due = due
                if now < next_due - 0.1 * period:  # 10%: a writer's jitter skips no period
                    continue
                # on schedule, so the average rate holds (a late send does not push the
                # next one back); a writer that paused gets no burst to catch up
                due[1] = (next_due if next_due >= now - period else now) + period
            flag = matching.get(key)
            if flag is not None and not flag[0]:
                _recheck(flag, publisher)
            if flag is None or flag[0]:  # a stream: only when another process listens
                if remote is None:
                    remote = []
                remote.append(publisher)
            local = readers.get(key)
            if local:  # same process: no bus, and no encoding for a shareable type
                for reader in list(local.values()):
                    if self.shareable:
                        reader.deliver_value(value, self.publisher_id, seq)
                    else:
                        if data is None:
                            data = self.last_data = self._encode(value, seq)
                        reader.deliver_local(data)
        if remote is None:
            return
        # after this process's readers: the Supervisor takes a tracker verdict written in
        # its process before the verdict (a JSON payload of kilobytes) is put on the bus
        if deferred is not None:
            deferred.append((value, seq, data, remote))
            return
        if data is None:
            data = self.last_data = self._encode(value, seq)
        for publisher in remote:
            publisher.put(data)

    def defer(self) -> None:
        """From now on send samples to other processes at `flush`, not inside `write`
        (readers in this process still get each one inside `write`): a paced loop's
        ports, whose encoding and puts (10-25 us a sample) then run after the cycle's
        command has gone out, in the time before the next measurement, as ros2_control's
        real-time publishers hand theirs to another thread. A sample whose type has a
        JSON payload is still encoded inside `write`, so its error is the writer's."""
        if self._deferred is None:
            self._deferred = deque()

    def undefer(self) -> int:
        """Send inside `write` again (its loop ended), after the samples still deferred;
        how many those were. A write racing this from another thread could still land in
        the old queue: call it from the loop's thread, once nothing else writes there."""
        sent, failed = 0, None
        while self._deferred:
            try:
                sent += self.flush()
            except PortError as exc:  # that sample is dropped; the ones after it go out
                failed = failed or exc
        self._deferred = None
        if failed is not None:
            raise failed
        return sent

    def flush(self) -> int:
        """Encode and put the samples `write` deferred, oldest first; how many. In the
        thread that writes the port (its paced loop, between cycles). A sample that
        cannot be encoded raises `PortError` (after the ones before it were sent), as
        its `write` would have."""
        deferred = self._deferred
        sent = 0
        while deferred:
            value, seq, data, publishers = deferred.popleft()
            if data is None:
                data = self._encode(value, seq)
            for publisher in publishers:
                publisher.put(data)
            sent += 1
        return sent

    def wanted(self) -> bool:
        """Whether a sample written now would reach anyone: a reader in this process, or
        (for a stream) one in another process listening (a writer may skip making it)."""
        readers = self.bus.local_readers if self.bus is not None else {}
        now = self.clock() if self._thinned else 0.0
        for key in self._publishers:
            due = self._thinned.get(key)
            if due is not None and now < due[1] - 0.1 * due[0]:
                continue  # a thinned key not due yet (as `write` decides)
            flag = self._matching.get(key)
            if flag is not None and not flag[0]:
                _recheck(flag, self._publishers[key])
            if flag is None or flag[0] or readers.get(key):
                return True
        return False

    def _encode(self, value: T, seq: int) -> bytes:
        try:
            return messages.encode(value, self.type, self.publisher_id, seq)
        except messages.CodecError as exc:
            self.stats.last_error = str(exc)
            raise PortError(f"cannot write to {self.full_name} ({self.type_name}): {exc}") from None

    def _refuse_type(self, value: Any) -> None:
        reason = f"expected {self.type_name}, got {type(value).__name__}"
        self.stats.last_error = reason
        raise PortError(f"cannot write to {self.full_name} ({self.type_name}): {reason}")


MATCHING_RECHECK = 0.2
"""s: how often a stream key with no reader elsewhere asks Zenoh again."""


def _recheck(flag: list[Any], publisher: Any) -> None:
    """Ask Zenoh whether a stream key has a reader now (at most every MATCHING_RECHECK)."""
    now = time.monotonic()
    if now - flag[2] >= MATCHING_RECHECK:
        flag[2] = now
        flag[0] = publisher.matching_status.matching


def _drain(ring: Any, limit: int | None) -> Iterator[Any]:
    """The samples waiting in a Zenoh ring, oldest first, at most `limit` (None: all);
    none once it was undeclared (a rewire from another thread)."""
    taken = 0
    while limit is None or taken < limit:
        try:
            sample = ring.try_recv()
        except Exception:  # undeclared meanwhile
            return
        if sample is None:
            return
        taken += 1
        yield sample


class TypeAdapter(Protocol):
    """An input port's own form of its type's samples (as ROS 2's type adaptation, REP
    2007): a reader that computes on arrays is handed them decoded straight from the
    wire, once, instead of the message's tuples and then a conversion of its own, in a
    loop where every microsecond counts. The port's type stays what is wired and
    checked; only what `read` returns changes. Both methods run in the thread that
    takes the sample: the reader's for a polled port, the bus's for one with `on_data`,
    the writer's for a sample written in the same process."""

    def from_bytes(self, data: bytes) -> tuple[Any, int, int]:
        """(the adapted value, publisher id, sequence number) of an encoded sample;
        `messages.CodecError` if it is not one of the port's type."""
        ...

    def from_value(self, value: Any) -> Any:
        """The adapted form of a sample of the port's type written in this process."""
        ...


class InputPort(Port[T]):
    """Receives samples from one key and keeps them according to its `ConnPolicy`;
    with an `adapter`, in the adapter's form (`TypeAdapter`)."""

    def __init__(
        self,
        name: str,
        type: type,
        doc: str = "",
        policy: ConnPolicy | None = None,
        arrivals_only: bool = False,
        adapter: TypeAdapter | None = None,
    ):
        super().__init__(name, type, doc)
        messages.codec_for(type)
        self.policy = policy or ConnPolicy()
        self.adapter = adapter
        """The form `read` returns samples in (None: the port's type itself)."""
        self.arrivals_only = arrivals_only
        """Only that a sample came matters (a safety watch's deadline): it is counted and
        `on_data` called, never decoded or kept (no work for the bus's thread, no GIL
        held against a 1 kHz loop in the same process)."""
        self.key: str | None = None
        self.bus: Any = None
        self.generation = 0
        self._on_data: Callable[[InputPort[T]], None] | None = None
        # a polled subscription: its generation, the ring, its standby key (or None)
        self._ring: tuple[int, Any, str | None] | None = None
        self._came = False  # an arrival nobody was called for, since the last `poll`
        self._lock = threading.Lock()
        self._queue: deque[T] = deque()
        self._latest: T | None = None
        self._fresh = False
        self._ever = False
        self._seen: dict[int, int] = {}
        self._subscriber: Any = None
        self._standby: dict[str, Any] = {}
        self._standby_latest: dict[str, bytes] = {}

    @property
    def on_data(self) -> Callable[[InputPort[T]], None] | None:
        """Called (on the bus's thread) after each sample is kept: an event activity's
        wake, a safety watch's arrival. A port with none is polled instead
        (`connect`)."""
        return self._on_data

    @on_data.setter
    def on_data(self, callback: Callable[[InputPort[T]], None] | None) -> None:
        self._on_data = callback
        if callback is not None:
            polled = self._ring is not None
            for key in [k for k, entry in self._standby.items() if entry[1]]:
                latest = self._standby_latest.get(key)
                self.unprepare(key)  # a polled standby: delivered from now on
                self.prepare(key)
                if latest is not None:
                    self._standby_latest.setdefault(key, latest)
            if polled and self.key is not None:
                self.connect(self.key)  # someone waits on it now: delivered, not polled

    @property
    def polled(self) -> bool:
        """Whether the port's samples wait in Zenoh's ring for `read` to take them."""
        return self._ring is not None

    @property
    def connected(self) -> bool:
        """True if the port listens to a key."""
        return self.key is not None

    def prepare(self, key: str) -> None:
        """Keep a standby subscription to `key` so a later `connect(key)` switches at once.

        The standby keeps only the key's latest sample; nothing reaches the port until it
        is connected. Use it for the alternatives a procedure may switch between (the
        trackers of a tracker swap): switching then costs no network round trip.
        """
        if self.bus is None:
            raise PortError(f"input port {self.full_name} is not attached to a bus")
        if key in self._standby:
            return
        if self._standby_pollable():
            # its newest sample waits in a ring of one, taken when connected to it: no
            # interpreter on Zenoh's thread for the samples of a tracker not in use
            self._standby[key] = (self.bus.subscribe(key, None, remote_only=True), True)
            return

        def on_sample(sample: Any, key: str = key) -> None:
            data = sample.payload.to_bytes()
            generation = self.generation  # read before the key: a switch in between
            self._standby_latest[key] = data  # makes this generation stale
            if self.key == key:
                self._deliver(generation, data)

        self._standby[key] = (self.bus.subscribe(key, on_sample, remote_only=True), False)

    def unprepare(self, key: str) -> None:
        """Drop a standby subscription (unless it is the connected key)."""
        entry = self._standby.pop(key, None)
        self._standby_latest.pop(key, None)
        subscriber = entry[0] if entry is not None else None
        ring = self._ring
        if ring is not None and ring[1] is subscriber:
            self._ring = None  # connected to it: nothing reaches the port any more
        if subscriber is not None:
            subscriber.undeclare()

    @property
    def prepared(self) -> list[str]:
        """Keys with a standby subscription."""
        return sorted(self._standby)

    def standby_ready(self, key: str) -> bool:
        """True once the standby subscription to `key` holds a sample."""
        entry = self._standby.get(key)
        if entry is not None and entry[1] and key not in self._standby_latest:
            ring = self._ring
            if ring is not None and ring[1] is entry[0]:
                self._poll()  # connected to it: taken into the port, and remembered
            else:
                for sample in _drain(entry[0], 1):
                    self._standby_latest[key] = sample.payload.to_bytes()
        return key in self._standby_latest

    def connect(self, key: str, policy: ConnPolicy | dict[str, Any] | None = None) -> None:
        """Listen to `key` (replacing any previous connection) with an optional new policy.

        The port starts empty: samples of the previous connection still queued are
        discarded (and counted), so data of two sources is never mixed. The key's latest
        sample arrives at once: from a local writer, from a standby subscription (see
        `prepare`), or from the publisher's cache over the network. A new subscription is
        declared before the old one is undeclared, so the teardown overlaps that fetch.

        A port nobody waits on (no `on_data`) is *polled*: Zenoh keeps the key's newest
        sample in a ring of one (a `data` port) or the newest twice-its-size samples (a
        `buffer` that drops its oldest), and `read` takes and decodes them, so no sample
        costs this process's interpreter on Zenoh's network thread (each one a hand-over
        of the interpreter lock: 600 a second in SEEG's supervision process), and a
        reader slower than the writer (a starved process) never lets a backlog build on
        the link: the samples it would never read are dropped by Zenoh, not queued
        behind the GIL. A buffer that drops its newest is delivered (the ring cannot).
        """
        if self.bus is None:
            raise PortError(f"input port {self.full_name} is not attached to a bus")
        new_policy = ConnPolicy.from_spec(policy) if policy is not None else self.policy
        self._discard_ring()
        with self._lock:
            self._reset()
            self.policy = new_policy
            generation = self.generation
            old_key, self.key = self.key, key
            old, self._subscriber, self._ring = self._subscriber, None, None
        readers = self.bus.local_readers
        if old_key is not None:
            readers.get(old_key, {}).pop(id(self), None)
        readers.setdefault(key, {})[id(self)] = self
        standby = self._standby.get(key)
        if standby is not None and standby[1] and self._standby_pollable():
            self._ring = (generation, standby[0], key)
            if not self._poll():  # nothing new since: the latest it ever had
                cached = self._standby_latest.get(key)
                if cached is not None:
                    self._deliver(generation, cached)
        elif standby is not None:
            cached = self._standby_latest.get(key)
            if cached is not None:
                self._deliver(generation, cached)
        elif self._pollable():
            self._subscriber = self.bus.subscribe(
                key, None, remote_only=True, capacity=self._ring_capacity()
            )
            self._ring = (generation, self._subscriber, None)
        else:
            self._subscriber = self.bus.subscribe(
                key,
                lambda sample: self._deliver(generation, sample.payload.to_bytes()),
                remote_only=True,
            )
        for writer in list(self.bus.local_writers.get(key, {}).values()):
            if writer.last is None:
                continue
            # a local writer's latest value, at once
            if writer.shareable:
                self.deliver_value(writer.last, writer.publisher_id, writer.last_seq)
            elif writer.last_data is not None:  # a payload's: always encoded in `write`
                self._deliver(generation, writer.last_data)
        if old is not None:
            old.undeclare()

    def disconnect(self) -> None:
        """Stop listening; later samples of the old key are dropped as stale. Standby
        subscriptions stay (see `unprepare`)."""
        self._discard_ring()
        with self._lock:
            self._reset()
            key, self.key = self.key, None
            subscriber, self._subscriber, self._ring = self._subscriber, None, None
        if key is not None and self.bus is not None:
            self.bus.local_readers.get(key, {}).pop(id(self), None)
        if subscriber is not None:
            subscriber.undeclare()

    def close(self) -> None:
        """Disconnect and drop every standby subscription."""
        self.disconnect()
        for key in list(self._standby):
            self.unprepare(key)

    def _reset(self) -> None:
        """New generation, empty queue (discarded samples are counted). Lock held."""
        self.generation += 1
        self.stats.discarded_on_rewire += len(self._queue) + (1 if self._fresh else 0)
        self._queue.clear()
        self._latest = None
        self._fresh = False
        self._ever = False
        self._seen.clear()

    def deliver_local(self, data: bytes) -> None:
        """A sample written by an output port of the same session, encoded."""
        self._deliver(self.generation, data)

    def deliver_value(self, value: T, publisher: int, seq: int) -> None:
        """A sample written by an output port of the same process: the object itself
        (its type holds no mutable part), no decoding."""
        if self.arrivals_only:
            self._arrived()
            return
        if self.adapter is not None:
            value = self.adapter.from_value(value)
        self._accept(self.generation, value, publisher, seq)

    def _deliver(self, generation: int, data: bytes) -> None:
        """Called on Zenoh's thread for every sample of the connected key."""
        if generation != self.generation:
            self.stats.dropped_stale += 1
            return
        if self.arrivals_only:
            self._arrived()
            return
        try:
            if self.adapter is None:
                value, publisher, seq = messages.decode(data, self.type)
            else:
                value, publisher, seq = self.adapter.from_bytes(data)
        except messages.CodecError as exc:
            self.stats.dropped_invalid += 1
            self.stats.last_error = f"{self.full_name}: {exc}"
            return
        self._accept(generation, value, publisher, seq)

    def _accept(self, generation: int, value: T, publisher: int, seq: int) -> None:
        """Keep a sample of connection `generation` unless the port was reconnected
        since or it repeats one already kept; then tell the owner."""
        with self._lock:
            if generation != self.generation:
                self.stats.dropped_stale += 1
                return
            if seq:  # 0 = written outside a port, without a sequence: never a duplicate
                if seq <= self._seen.get(publisher, 0):
                    self.stats.dropped_duplicate += 1
                    return
                self._seen[publisher] = seq
            self.stats.received += 1
            self._store(value)
        callback = self._on_data
        if callback is not None:
            callback(self)

    def _arrived(self) -> None:
        self.stats.received += 1
        callback = self._on_data
        if callback is not None:
            callback(self)
        else:
            self._came = True  # for `poll`: from Zenoh's ring or from this process

    def _store(self, value: T) -> None:
        if self.policy.type == "data":
            self._latest = value
            self._fresh = True
        else:
            queue = self._queue
            if len(queue) >= self.policy.size:
                self.stats.dropped_overflow += 1
                if self.policy.overflow == "drop_newest":
                    return
                queue.popleft()
            queue.append(value)
        self._ever = True

    def _pollable(self) -> bool:
        """Whether samples may wait in Zenoh's ring for the reader (`connect`): nobody
        waits on the port, and it keeps the latest sample or a queue that drops its
        oldest (as the ring does)."""
        return self._on_data is None and (
            self.policy.type == "data" or self.policy.overflow == "drop_oldest"
        )

    def _standby_pollable(self) -> bool:
        """Whether a standby key's samples may wait in a ring of one (`prepare`): a
        polled port keeping the latest sample (a standby keeps only that)."""
        return self._pollable() and self.policy.type == "data"

    def _ring_capacity(self) -> int:
        """One for a data port (the newest); twice the queue for a buffer, so the port's
        own overflow rule and counters apply unless the reader fell that far behind."""
        return 1 if self.policy.type == "data" else 2 * self.policy.size

    def _discard_ring(self) -> None:
        """Count what still waits unread in a polled port's ring as discarded by the
        rewire about to drop it (not decoded: it is not kept)."""
        entry = self._ring
        if entry is None or entry[2] is not None:  # a standby's ring stays for later
            return
        self.stats.discarded_on_rewire += sum(1 for _ in _drain(entry[1], None))

    def _poll(self) -> bool:
        """Take what a polled port's ring holds (the newest sample, or every queued one
        for a buffer), as of the connection it came on (a rewire in between makes it
        stale, never mixed in); True if a sample of this connection came."""
        entry = self._ring
        if entry is None:
            return False
        try:
            first = entry[1].try_recv()  # mostly nothing: asked every cycle of a 1 kHz loop
        except Exception:  # undeclared meanwhile (a rewire from another thread)
            return False
        return first is not None and self._take_ring(entry, first)

    def _take_ring(self, entry: tuple[int, Any, str | None], first: Any) -> bool:
        """`first` and what else waits in the ring of `entry` (see `_poll`)."""
        if self.arrivals_only:
            return self._count_arrivals(entry)
        generation, ring, standby = entry
        limit = self._ring_capacity()
        taken = 0
        for sample in itertools.chain((first,), _drain(ring, limit - 1)):
            taken += 1
            data = sample.payload.to_bytes()
            if standby is not None:
                self._standby_latest[standby] = data  # for a later switch back to it
            self._deliver(generation, data)
        if taken == limit > 1:
            self.stats.ring_full += 1
        return generation == self.generation

    def _count_arrivals(self, entry: tuple[int, Any, str | None]) -> bool:
        """`_take_ring` for an arrivals-only port, its first sample already taken: what
        else waits (the ring is bounded) is counted, never copied out of Zenoh, as nobody
        reads it; the owner hears of one arrival (`_arrived`). A safety monitor's watches
        take a heartbeat or a tracker sample in most cycles of a 1 kHz loop, where copying
        and delivering each cost up to 5 us. One of a connection replaced meanwhile is
        counted stale, not an arrival."""
        generation, ring, _ = entry
        taken = 1 + sum(1 for _ in _drain(ring, None))
        if generation != self.generation:
            self.stats.dropped_stale += taken
            return False
        self.stats.received += taken - 1
        self._arrived()
        return True

    def poll(self) -> bool:
        """Take what waits in Zenoh's ring (as `read` does); True if a sample came since
        the last time. An `arrivals_only` port nobody waits on is watched so: an arrival
        over the bus is seen by the thread that polls, never on Zenoh's; one written in
        this process counts too. (`_poll` inline: a safety monitor asks a dozen ports
        every cycle of a 1 kHz loop.)"""
        taken = False
        entry = self._ring
        if entry is not None:
            try:
                first = entry[1].try_recv()
            except Exception:  # undeclared meanwhile (a rewire from another thread)
                first = None
            if first is not None:
                taken = self._take_ring(entry, first)
        if self._came:
            self._came = False
            return True
        return taken

    def read(self) -> tuple[ReadStatus, T | None]:
        """(NEW, value) for an unread sample, (OLD, last value), or (NO_DATA, None)."""
        if self._ring is not None:
            self._poll()
        if not self._fresh and not self._queue:  # nothing new: no lock to take (1 kHz)
            latest = self._latest
            if self._ever and latest is not None:
                return ReadStatus.OLD, latest
            if not self._ever:
                return ReadStatus.NO_DATA, None
        with self._lock:
            if self.policy.type == "buffer":
                if self._queue:
                    self._latest = self._queue.popleft()
                    return ReadStatus.NEW, self._latest
            elif self._fresh:
                self._fresh = False
                return ReadStatus.NEW, self._latest
            if self._ever and self._latest is not None:
                return ReadStatus.OLD, self._latest
            return ReadStatus.NO_DATA, None

    def latest(self) -> T | None:
        """The newest sample received, without reading it (NEW stays NEW); None before
        any. For an operation that waits on what the component's loop also reads."""
        self._poll()
        with self._lock:
            if self.policy.type == "buffer" and self._queue:
                return self._queue[-1]
            return self._latest if self._ever else None

    def pending(self) -> int:
        """Unread samples (0 or 1 for a data port)."""
        self._poll()
        with self._lock:
            return len(self._queue) if self.policy.type == "buffer" else int(self._fresh)
