"""The Zenoh bus: the only place that builds Zenoh configurations and opens sessions.

Defaults keep a deployment private to one machine and one namespace: peer
mode, no multicast scouting, listening on loopback only, every process
connecting to one hub endpoint per deployment, gossip with the
`greater-zid` strategy so peers also connect to each other directly (a peer
never forwards between two others). Two deployments, or two tests, that use
different namespaces and hub ports never see each other.

Liveliness: the transport lease (default 2 s, keep-alive 4 per lease) is
how long a *hung* peer goes unnoticed (seen at ~0.8 x lease); a killed
process is seen in milliseconds because its socket closes. Leases under
500 ms gave false alarms under CPU load on the project's 2-core machines.

Security: with `keys` (a keystore, `framework/keystore.py`) every link is mutual TLS
against the deployment's own CA, and each session presents its subject's
certificate; `access` adds the deployment's access rules (`framework/access.py`).
`fw deploy` always sets both. Other Zenoh settings can be passed through
`BusConfig.extra`, a mapping of Zenoh config paths to JSON values.

Reopening: every declaration a `Bus` makes is kept (`Declared`), so `Bus.reopen` can
open a new session and make each of them again on it, then close the old one. It is
the way out of routes Zenoh leaves unmade after a partition heals (framework/routes.py
finds them; docs/hosts.md has the measurements). The holders of the declarations keep
the same objects throughout.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh
import zenoh.ext

from framework.errors import FwError

log = logging.getLogger("fw.bus")
_zenoh_logging_once = threading.Lock()
_zenoh_logging_done = False


class BusError(FwError):
    """The bus could not be opened or used (bad endpoint, closed session...)."""


@dataclass(frozen=True)
class BusConfig:
    """Where a deployment's processes meet. Same config in every process of it."""

    namespace: str = "fw"
    hub_port: int = 7447
    host: str = "127.0.0.1"
    lease_ms: int = 2000
    keep_alive: int = 4
    extra: dict[str, Any] = field(default_factory=dict)
    secure: bool = False
    """Links must be mutual TLS (a keystore is required to open a session)."""
    keys: str = ""
    """The deployment's keystore directory: mutual TLS on every link (empty: plain TCP)."""
    access: dict[str, Any] = field(default_factory=dict)
    """Zenoh `access_control` settings every session enforces on its links."""
    listen: str = ""
    """The address a process other than the hub listens on (empty: `host`, the control
    host's: right for every process on that machine)."""
    listen_port: int = 0
    """The port a process other than the hub listens on (0: any free one)."""
    peers: tuple[str, ...] = ()
    """Endpoints of other processes this one connects to itself, besides the hub, and
    connects to again whenever the link is lost (a deployment on several hosts: gossip
    alone left a link cut by a partition unmade, docs/hosts.md)."""
    others: tuple[str, ...] = ()
    """Endpoints of every other process of the mesh, those that connect to this one
    included: a reopened session (`Bus.reopen`) listens on a port of its own, as the
    fixed one stays with the first session (what this process says), so it makes every link
    itself."""

    @property
    def protocol(self) -> str:
        """`tls` with a keystore, else `tcp`."""
        return "tls" if self.keys else "tcp"

    @property
    def hub_endpoint(self) -> str:
        """The endpoint every process connects to (the hub listens on it)."""
        return f"{self.protocol}/{self.host}:{self.hub_port}"

    def to_dict(self) -> dict[str, Any]:
        """Plain data, to pass to a spawned process."""
        return {
            "namespace": self.namespace,
            "hub_port": self.hub_port,
            "host": self.host,
            "lease_ms": self.lease_ms,
            "keep_alive": self.keep_alive,
            "extra": dict(self.extra),
            "secure": self.secure,
            "keys": self.keys,
            "access": dict(self.access),
            "listen": self.listen,
            "listen_port": self.listen_port,
            "peers": list(self.peers),
            "others": list(self.others),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BusConfig:
        """Inverse of `to_dict`."""
        return cls(
            **{
                **data,
                "peers": tuple(data.get("peers", ())),
                "others": tuple(data.get("others", ())),
            }
        )


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free right now (for tests and ad-hoc deployments)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port that is free right now (a test's or a benchmark's FRI link)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((host, 0))
        return int(sock.getsockname()[1])


def zenoh_config(bus: BusConfig, hub: bool = False, subject: str = "") -> zenoh.Config:
    """The Zenoh configuration of one process of the deployment (`hub` listens on the
    deployment's fixed port; everyone else listens on an ephemeral port of its host;
    `subject`: whose certificate it presents when the bus has a keystore)."""
    settings: dict[str, Any] = {
        "mode": "peer",
        "scouting/multicast/enabled": False,
        "listen/endpoints": [
            bus.hub_endpoint
            if hub
            else f"{bus.protocol}/{bus.listen or bus.host}:{bus.listen_port}"
        ],
        "connect/endpoints": [*bus.peers] if hub else [bus.hub_endpoint, *bus.peers],
        "scouting/gossip/enabled": True,
        "scouting/gossip/autoconnect_strategy": {
            "peer": {"to_router": "always", "to_peer": "greater-zid"}
        },
        "namespace": bus.namespace,
        "timestamping/enabled": True,  # needed by the latest-value cache of output ports
        # a link lost to a partition is tried again at least every second (Zenoh's
        # default backs off to 4 s: a 5 s cut came back 6-11 s after the heal)
        "connect/retry": {
            "period_init_ms": 250,
            "period_max_ms": 1000,
            "period_increase_factor": 2,
        },
        "transport/link/tx/lease": bus.lease_ms,
        "transport/link/tx/keep_alive": bus.keep_alive,
    }
    if bus.secure and not bus.keys:
        raise BusError(
            f"deployment {bus.namespace!r} admits only sessions with its credentials, "
            "and none were given (fw deploy creates them; see docs/security.md)"
        )
    if bus.keys:
        settings.update(_tls_settings(bus, subject))
    if bus.access:
        settings["access_control"] = bus.access
    settings.update(bus.extra)
    config = zenoh.Config()
    for key, value in settings.items():
        try:
            config.insert_json5(key, json.dumps(value))
        except Exception as exc:  # zenoh raises its own error type
            raise BusError(f"invalid Zenoh setting {key}={value!r}: {exc}") from None
    return config


def client_config(bus: BusConfig, keys: str | Path | None = None) -> BusConfig:
    """`bus` with the keystore a client of the running deployment uses (`keys`, else the
    deployment's default place); unchanged for a bus that is not secured."""
    from framework.keystore import OPERATOR, Keystore, keystore_for

    if not bus.secure or bus.keys:
        return bus
    store = Keystore(Path(keys)) if keys else keystore_for(bus.namespace)
    store.check(OPERATOR)
    return dataclasses.replace(bus, keys=str(store.root))


def _tls_settings(bus: BusConfig, subject: str) -> dict[str, Any]:
    """Mutual TLS with `subject`'s certificate, trusting only the deployment's CA."""
    from framework.keystore import Keystore

    store = Keystore(Path(bus.keys))
    if not subject:
        raise BusError("a bus with a keystore needs the subject whose certificate to use")
    store.check(subject)
    cert, key = str(store.certificate(subject)), str(store.private_key(subject))
    return {
        "transport/link/tls/root_ca_certificate": str(store.ca),
        "transport/link/tls/enable_mtls": True,
        "transport/link/tls/listen_certificate": cert,
        "transport/link/tls/listen_private_key": key,
        "transport/link/tls/connect_certificate": cert,
        "transport/link/tls/connect_private_key": key,
    }


def _route_zenoh_logs() -> None:
    """Errors inside Python callbacks go to the `zenoh.handlers` logger; make them visible."""
    global _zenoh_logging_done
    with _zenoh_logging_once:
        if not _zenoh_logging_done:
            logging.getLogger("zenoh.handlers").setLevel(logging.ERROR)
            _zenoh_logging_done = True


class Declared:
    """One declaration of a `Bus`: a publisher, a subscriber, a queryable, a liveliness
    token or watch, or a publisher's matching listener. Its holder uses it as the Zenoh
    object it stands for (`put`, `try_recv`, `undeclare`, any other attribute is the
    object's); `Bus.reopen` makes it again on the new session underneath, so the holder
    never sees the change. `put` and `try_recv` are the object's own bound methods, not
    a call through this one: a 1 kHz loop pays nothing for the indirection."""

    def __init__(
        self,
        bus: Bus,
        make: Callable[[Any], Any],
        parent: Declared | None = None,
        stays: bool = False,
    ):
        self._bus = bus
        self.stays = stays
        """What this process says (a publisher, a queryable, a liveliness token): it stays
        on the first session; only what it hears moves (`Bus.reopen`)."""
        self.token = False
        """A liveliness token."""
        self._make = make
        self._parent = parent
        self.children: list[Declared] = []
        self.undeclared = False
        self.obj: Any = None
        self.liveliness: _LivelinessWatch | None = None
        """For a liveliness watch: the keys it reported alive."""
        self.key_expr = ""
        """For a liveliness watch: what it watches; for a token: its key."""

    def made(self, session: Any) -> Any:
        """Make the declaration on `session` (the parent's object for a child)."""
        return self._make(session if self._parent is None else self._parent.obj)

    def bind(self, obj: Any) -> None:
        """Stand for `obj` from now on."""
        self.obj = obj
        for name in ("put", "try_recv"):
            method = getattr(obj, name, None)
            if method is not None:
                setattr(self, name, method)

    def overlap(self, new: Any, old: Any) -> None:
        """Stand for `new`, while `old` still receives beside it (`Bus.reopen`): a poll
        takes from the old ring first, then from the new, so what the old session
        still carries comes in the order it was sent (a newer sample first would make
        the older ones look like repeats to a port, which drops them)."""
        self.obj = new
        if hasattr(new, "try_recv"):

            def try_recv() -> Any:
                with contextlib.suppress(Exception):  # the old session is going
                    sample = old.try_recv()
                    if sample is not None:
                        return sample
                return new.try_recv()

            self.try_recv = try_recv

    def __getattr__(self, name: str) -> Any:
        return getattr(self.obj, name)

    def declare_matching_listener(self, callback: Callable[[Any], None]) -> Declared:
        """A publisher's matching listener (it stays with its publisher, which never
        moves: `Bus.reopen`)."""
        child = Declared(
            self._bus, lambda publisher: publisher.declare_matching_listener(callback), self
        )
        child.bind(child.made(None))
        self.children.append(child)
        return child

    def undeclare(self) -> None:
        """Undeclare it (it is not made again on a reopened session)."""
        self.undeclared = True
        self._bus._forget(self)
        if self._parent is not None:
            with contextlib.suppress(ValueError):
                self._parent.children.remove(self)
        self.obj.undeclare()


class _LivelinessWatch:
    """The keys a liveliness watch has reported alive, so a reopen can report the ones
    that went while no session of this bus was listening."""

    def __init__(self, callback: Callable[[str, bool], None]):
        self.callback = callback
        self.alive: set[str] = set()
        self._lock = threading.Lock()

    def on_sample(self, sample: Any) -> None:
        key, alive = str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            (self.alive.add if alive else self.alive.discard)(key)
        self.callback(key, alive)

    def reconcile(self, now_alive: set[str]) -> None:
        """Report gone every key reported alive that is not alive now."""
        with self._lock:
            gone = sorted(self.alive - now_alive)
            self.alive -= set(gone)
        for key in gone:
            self.callback(key, False)


REOPEN_LINK_WAIT = 3.0
"""How long a reopened session may take to link with as many peers as the old one had
before the declarations move to it (gossip links a new session one peer at a time)."""
REOPEN_OVERLAP = 3.0
"""Seconds both sessions receive after a reopen and each poll reads both, so a reader
whose routes to the new session are still being made (0.4-2.5 s measured after a
heal) misses nothing meanwhile."""


class Bus:
    """One open Zenoh session of a deployment, with the handful of calls fw needs."""

    def __init__(self, config: BusConfig, hub: bool = False, subject: str = ""):
        _route_zenoh_logs()
        self.config = config
        self.hub = hub
        self.subject = subject
        self.session = self._open(config)
        self._first = self.session
        """The session the liveliness tokens live on (`reopen` keeps it open for them)."""
        self._leaving: Any = None
        """The session a reopen is leaving, while both receive."""
        self._closed = False
        self._lock = threading.Lock()
        self._declared: list[Declared] = []
        self.reopened = 0
        """How many times `reopen` made a new session."""
        self.local_readers: dict[str, dict[int, Any]] = {}
        """Input ports of this session by key: same-session samples skip Zenoh."""
        self.local_writers: dict[str, dict[int, Any]] = {}
        """Output ports of this session by key (their last sample serves local connects)."""

    def _open(self, config: BusConfig, hub: bool | None = None) -> Any:
        hub = self.hub if hub is None else hub
        try:
            return zenoh.open(zenoh_config(config, hub, self.subject))
        except FwError:
            raise
        except Exception as exc:  # zenoh raises its own ZError (and others): said as a BusError
            where = config.hub_endpoint
            if hub and "Address already in use" in str(exc):
                raise BusError(
                    f"cannot open the bus: port {config.hub_port} on {config.host} is in use. "
                    f"Is this topology already running (`fw status --topology TOPOLOGY`)? "
                    f"Stop it first, or give this run another `bus: {{hub_port: N}}`"
                ) from None
            raise BusError(
                f"cannot open the bus ({'listen on' if hub else 'join'} {where}): {exc}"
            ) from None

    @property
    def closed(self) -> bool:
        """True once `close()` ran."""
        return self._closed

    def _declare(self, make: Callable[[Any], Any], stays: bool = False) -> Declared:
        """Make a declaration on the current session (what this process says, `stays`:
        on the first session) and keep it for `reopen`."""
        declared = Declared(self, make, stays=stays)
        with self._lock:
            declared.bind(make(self._first if stays else self.session))
            self._declared.append(declared)
        return declared

    def _forget(self, declared: Declared) -> None:
        with self._lock, contextlib.suppress(ValueError):
            self._declared.remove(declared)

    def publisher(self, key: str, cache: bool = True, remote_only: bool = False) -> Declared:
        """A publisher on `key`; with `cache`, late subscribers get the last sample at once;
        `remote_only` skips this session's own subscribers (they are served directly)."""
        where = zenoh.Locality.REMOTE if remote_only else None
        if cache:
            return self._declare(
                lambda session: zenoh.ext.declare_advanced_publisher(
                    session,
                    key,
                    cache=zenoh.ext.CacheConfig(max_samples=1),
                    publisher_detection=True,
                    allowed_destination=where,
                ),
                stays=True,
            )
        return self._declare(
            lambda session: session.declare_publisher(key, allowed_destination=where),
            stays=True,
        )

    def subscribe(
        self,
        key: str,
        callback: Callable[[Any], None] | None,
        history: bool = True,
        remote_only: bool = False,
        capacity: int = 1,
    ) -> Declared:
        """Subscribe to `key`; with `history`, the last cached sample arrives at once;
        `remote_only` ignores this session's own publications. With `callback` None,
        the samples go to a ring of `capacity` (the newest; Zenoh drops the oldest) that
        the reader polls with `try_recv`: Zenoh's network thread then never waits for
        the interpreter."""
        where = zenoh.Locality.REMOTE if remote_only else None

        def make(session: Any) -> Any:
            if callback is None:
                handler: Any = zenoh.handlers.RingChannel(capacity)
            else:
                # A plain subscriber's callback runs on Zenoh's network thread: a port's
                # delivery is short (decode, queue, wake), and a thread per subscriber
                # costs a hand-over per sample. An advanced one's cannot: zenoh-ext calls
                # it holding the subscriber's lock, so waiting there for the interpreter
                # deadlocks against any thread that holds the interpreter and reaches that
                # lock (declaring or undeclaring a cached publisher on a matching key, in
                # the same session). Its samples go through zenoh-python's own thread.
                handler = zenoh.handlers.Callback(callback, indirect=history)
            if history:
                return zenoh.ext.declare_advanced_subscriber(
                    session,
                    key,
                    handler,
                    allowed_origin=where,
                    history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
                )
            return session.declare_subscriber(key, handler, allowed_origin=where)

        return self._declare(make)

    def queryable(self, key: str, handler: Callable[[Any], None]) -> Declared:
        """Answer queries on `key` (remote operations, introspection)."""
        return self._declare(lambda session: session.declare_queryable(key, handler), stays=True)

    def query(self, key: str, payload: bytes = b"", timeout: float = 2.0) -> list[bytes]:
        """Ask `key` and return every reply's bytes; error replies raise `BusError`."""
        replies = self.session.get(key, payload=payload, timeout=timeout)
        out = []
        for reply in replies:
            if reply.ok is not None:
                out.append(bytes(reply.ok.payload.to_bytes()))
            else:
                raise BusError(bytes(reply.err.payload.to_bytes()).decode("utf-8", "replace"))
        return out

    def token(self, key: str) -> Declared:
        """Declare a liveliness token: peers see it vanish when this process dies."""
        declared = self._declare(
            lambda session: session.liveliness().declare_token(key), stays=True
        )
        declared.key_expr = key
        declared.token = True
        return declared

    def watch(self, key_expr: str, callback: Callable[[str, bool], None]) -> Declared:
        """Call `callback(key, alive)` for liveliness tokens matching `key_expr`, starting
        with the ones alive now. After a `reopen`, a token that went meanwhile is
        reported gone."""
        watch = _LivelinessWatch(callback)
        declared = self._declare(
            lambda session: session.liveliness().declare_subscriber(
                key_expr, watch.on_sample, history=True
            )
        )
        declared.liveliness = watch
        declared.key_expr = key_expr
        return declared

    def tokens(self) -> list[str]:
        """The keys of the liveliness tokens this bus holds now."""
        with self._lock:
            return sorted(d.key_expr for d in self._declared if d.token)

    def seen_alive(self, key: str) -> bool | None:
        """Whether this bus's liveliness watches see the token `key` alive now; None if
        none of them watches it."""
        wanted = zenoh.KeyExpr(key)
        with self._lock:
            watches = [d for d in self._declared if d.liveliness is not None]
        matching = [d for d in watches if zenoh.KeyExpr(d.key_expr).intersects(wanted)]
        if not matching:
            return None
        return all(key in d.liveliness.alive for d in matching)

    def alive(self, key_expr: str, timeout: float = 2.0) -> list[str]:
        """Keys of the liveliness tokens alive now that match `key_expr`."""
        replies = self.session.liveliness().get(key_expr, timeout=timeout)
        return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

    def peers(self) -> int:
        """How many peers this session is connected to right now."""
        return len(list(self.session.info.peers_zid()))

    def linked(self) -> set[str]:
        """The session ids of the peers this session is linked to right now."""
        return {str(z) for z in self.session.info.peers_zid()}

    def zid(self) -> str:
        """The id of the session this process hears on (a reopened bus has a new one)."""
        return str(self.session.info.zid())

    def says_zid(self) -> str:
        """The id of the session this process says everything on (its publishers,
        queryables and tokens): the first one, whatever `reopen` did."""
        return str(self._first.info.zid())

    def wait_for_peers(self, count: int, timeout: float = 3.0) -> bool:
        """Wait until connected to `count` peers (gossip connects a new session to the
        deployment's processes one by one; queries before that reach only some)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.peers() >= count:
                return True
            time.sleep(0.01)
        return self.peers() >= count

    def reopen(self, overlap: float = REOPEN_OVERLAP) -> float:
        """Open a new session and move everything this process hears to it (its
        subscribers and liveliness watches); the seconds it took. For routes Zenoh left
        unmade (framework/routes.py): each process mends its own ears.

        What this process says (publishers, queryables, liveliness tokens) stays on the
        first session and never moves, so nobody that hears it loses a sample by a
        reopen: moved, a reopen of the supervision process left its heartbeat 151 ms
        silent at the robot, which braked; and a robot that moved its publishers along
        with its deaf subscribers went unheard by the supervision process on its own
        host, whose routes to the old session were fine (2026-12-07). A peer that hears
        nothing from this process mends its own ears the same way. A token moved was
        also seen to blink (gone and back at once, 6 of 40 reopens).

        The new session listens on a port of its own (the first holds the fixed port,
        the hub's among them) and, in a mesh, connects to every other process itself
        (`BusConfig.others`); a hub without them (one host) cannot reopen. The
        subscriptions move once it is linked with as many peers as the old one was (at
        most `REOPEN_LINK_WAIT` s), so a watch finds the tokens alive and a ring its
        writers. For `overlap` s both sessions receive and every poll reads the old ring,
        then the new: none is lost while the new session's routes are made, for a
        reader that polls meanwhile (a sample may arrive twice: ports drop repeats by
        sequence number). A token reported alive that is gone
        after the move is reported gone; queries go out on the new session."""
        began = time.monotonic()
        config, hub = self.config, self.hub
        if hub and not config.others:
            raise BusError("the hub of a deployment on one host cannot reopen (no endpoints)")
        if hub or config.listen_port:
            config = dataclasses.replace(config, listen_port=0, peers=config.others or config.peers)
        new = self._open(config, hub=False)
        before = self.peers()
        end = time.monotonic() + REOPEN_LINK_WAIT
        while time.monotonic() < end and len(list(new.info.peers_zid())) < before:
            time.sleep(0.01)
        with self._lock:
            if self._closed:
                with contextlib.suppress(Exception):
                    new.close()
                raise BusError("the bus was closed while it reopened")
            made = []
            for declared in self._declared:
                if not declared.stays:
                    made.append((declared, declared.obj, declared.made(new)))
            old, self.session = self.session, new
            self._leaving = old
            for declared, previous, obj in made:
                declared.overlap(obj, previous)
            watches = [(d.key_expr, d.liveliness) for d in self._declared if d.liveliness]
            self.reopened += 1
        time.sleep(overlap)
        with self._lock:
            for declared, _, obj in made:
                if not declared.undeclared:
                    declared.bind(obj)
            self._leaving = None
        if old is self._first:  # it keeps what this process says, and only that
            for _, previous, _ in made:
                with contextlib.suppress(Exception):
                    previous.undeclare()
        else:
            with contextlib.suppress(Exception):
                old.close()
        for key_expr, watch in watches:
            with contextlib.suppress(Exception):
                watch.reconcile(set(self.alive(key_expr, timeout=1.0)))
        return time.monotonic() - began

    def close(self) -> None:
        """Close the session (idempotent). An unclosed session can hang process exit."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        sessions = (self.session, self._first, self._leaving)
        for session in {id(s): s for s in sessions if s is not None}.values():
            with contextlib.suppress(Exception):
                session.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
