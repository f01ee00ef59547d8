"""Foxglove's live view of a running deployment (`fw deploy --foxglove [PORT]`, issue 48):
the same messages a flight recording holds for Foxglove (framework/scene.py), served by
Foxglove's SDK over its WebSocket protocol while the deployment runs.

The SDK's server is served on loopback only: it has no authentication, and nothing of
fw listens beyond this machine without it (docs/security.md). Open it from Foxglove on
the same machine (Open connection, `ws://127.0.0.1:PORT`); from another machine,
`--foxglove-host` puts framework/live_gate.py in front of it (TLS and the run's token).
Runs in the control process, never in a safety process.
"""

from __future__ import annotations

import ipaddress
import threading
from typing import Any

from framework.errors import FwError

DEFAULT_PORT = 8765
"""Foxglove's own default port for a live connection."""


class LiveViewError(FwError):
    """The live view could not be served."""


class LiveView:
    """A Foxglove WebSocket server fed with `scene.Converted` messages, one channel per
    topic, its protobuf schema advertised with it."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = "127.0.0.1"):
        """Start serving on `host`:`port` (0: any free port; `port` says which)."""
        try:
            loopback = ipaddress.ip_address(host).is_loopback
        except ValueError:
            loopback = host == "localhost"
        if not loopback:
            raise LiveViewError(
                f"the Foxglove live view is served on loopback only, not {host!r}: its "
                "server has no authentication (reach it from another machine through an "
                "SSH tunnel: ssh -L 8765:127.0.0.1:8765 HOST)"
            )
        import foxglove

        self._foxglove = foxglove
        self._context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name="fw", host=host, port=port, context=self._context
            )
        except Exception as exc:  # the SDK raises its own error types
            raise LiveViewError(
                f"cannot serve the Foxglove live view on {host}:{port}: {exc}"
            ) from None
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()
        self.gate: Any = None
        """The `LiveGate` that serves it beyond loopback, if any (closed with it)."""

    @property
    def port(self) -> int:
        """The port it serves on."""
        return int(self._server.port)

    def publish(self, topic: str, converted: Any, stamp: float) -> None:
        """Send one message to every connected client subscribed to `topic` (any thread)."""
        with self._lock:
            channel = self._channels.get(topic)
            if channel is None:
                schema = self._foxglove.Schema(
                    name=converted.schema_name, encoding="protobuf", data=converted.schema
                )
                channel = self._channels[topic] = self._foxglove.Channel(
                    topic, message_encoding="protobuf", schema=schema, context=self._context
                )
        channel.log(converted.data, log_time=max(int(stamp * 1e9), 0))

    def close(self) -> None:
        """Stop serving (clients are disconnected)."""
        if self.gate is not None:
            self.gate.close()
        self._server.stop()
