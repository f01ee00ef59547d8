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
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> BusConfig:
        """Inverse of `to_dict`."""
        return cls(**{**data, "peers": tuple(data.get("peers", ()))})


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


class Bus:
    """One open Zenoh session of a deployment, with the handful of calls fw needs."""

    def __init__(self, config: BusConfig, hub: bool = False, subject: str = ""):
        _route_zenoh_logs()
        self.config = config
        self.hub = hub
        self.subject = subject
        try:
            self.session = zenoh.open(zenoh_config(config, hub, subject))
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
        self._closed = False
        self._lock = threading.Lock()
        self.local_readers: dict[str, dict[int, Any]] = {}
        """Input ports of this session by key: same-session samples skip Zenoh."""
        self.local_writers: dict[str, dict[int, Any]] = {}
        """Output ports of this session by key (their last sample serves local connects)."""

    @property
    def closed(self) -> bool:
        """True once `close()` ran."""
        return self._closed

    def publisher(self, key: str, cache: bool = True, remote_only: bool = False) -> Any:
        """A publisher on `key`; with `cache`, late subscribers get the last sample at once;
        `remote_only` skips this session's own subscribers (they are served directly)."""
        where = zenoh.Locality.REMOTE if remote_only else None
        if cache:
            return zenoh.ext.declare_advanced_publisher(
                self.session,
                key,
                cache=zenoh.ext.CacheConfig(max_samples=1),
                publisher_detection=True,
                allowed_destination=where,
            )
        return self.session.declare_publisher(key, allowed_destination=where)

    def subscribe(
        self,
        key: str,
        callback: Callable[[Any], None] | None,
        history: bool = True,
        remote_only: bool = False,
        capacity: int = 1,
    ) -> Any:
        """Subscribe to `key`; with `history`, the last cached sample arrives at once;
        `remote_only` ignores this session's own publications. With `callback` None,
        the samples go to a ring of `capacity` (the newest; Zenoh drops the oldest) that
        the reader polls with `try_recv`: Zenoh's network thread then never waits for
        the interpreter."""
        where = zenoh.Locality.REMOTE if remote_only else None
        if callback is None:
            handler: Any = zenoh.handlers.RingChannel(capacity)
        else:
            # On Zenoh's network thread: a port's delivery is short (decode, queue,
            # wake), and the default thread per subscriber cost a hand-over per sample.
            handler = zenoh.handlers.Callback(callback, indirect=False)
        if history:
            return zenoh.ext.declare_advanced_subscriber(
                self.session,
                key,
                handler,
                allowed_origin=where,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
            )
        return self.session.declare_subscriber(key, handler, allowed_origin=where)

    def queryable(self, key: str, handler: Callable[[Any], None]) -> Any:
        """Answer queries on `key` (remote operations, introspection)."""
        return self.session.declare_queryable(key, handler)

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

    def token(self, key: str) -> Any:
        """Declare a liveliness token: peers see it vanish when this process dies."""
        return self.session.liveliness().declare_token(key)

    def watch(self, key_expr: str, callback: Callable[[str, bool], None]) -> Any:
        """Call `callback(key, alive)` for liveliness tokens matching `key_expr`, starting
        with the ones alive now."""

        def on_sample(sample: Any) -> None:
            callback(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        return self.session.liveliness().declare_subscriber(key_expr, on_sample, history=True)

    def alive(self, key_expr: str, timeout: float = 2.0) -> list[str]:
        """Keys of the liveliness tokens alive now that match `key_expr`."""
        replies = self.session.liveliness().get(key_expr, timeout=timeout)
        return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

    def peers(self) -> int:
        """How many peers this session is connected to right now."""
        return len(list(self.session.info.peers_zid()))

    def wait_for_peers(self, count: int, timeout: float = 3.0) -> bool:
        """Wait until connected to `count` peers (gossip connects a new session to the
        deployment's processes one by one; queries before that reach only some)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.peers() >= count:
                return True
            time.sleep(0.01)
        return self.peers() >= count

    def close(self) -> None:
        """Close the session (idempotent). An unclosed session can hang process exit."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        with contextlib.suppress(Exception):
            self.session.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
