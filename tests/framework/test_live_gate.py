"""Specs of the live view's gate (framework/live_gate.py, issue 48): beyond loopback,
Foxglove's live view answers only over TLS and only a URL with the run's token; past
the gate a real WebSocket client speaks Foxglove's protocol as on loopback."""

from __future__ import annotations

import asyncio
import json
import socket
import ssl

import pytest

from framework.console import tls
from framework.live_gate import LiveGate
from framework.live_view import LiveView

PROTOCOL = "foxglove.sdk.v1"
TOKEN = "the-runs-token"


@pytest.fixture
def gated(tmp_path):
    """A live view behind a gate with a certificate made for 127.0.0.1, and a client
    TLS context that trusts that certificate alone."""
    cert, key = tls.self_signed(["127.0.0.1"], tmp_path)
    live = LiveView(0)
    gate = LiveGate("127.0.0.1", 0, live.port, TOKEN, tls.server_context(cert, key), timeout=1.0)
    client = ssl.create_default_context(cafile=str(cert))
    yield gate, client
    gate.close()
    live.close()


def answer(gate, client, path: str) -> bytes:
    """The first bytes the gate answers a WebSocket upgrade request for `path`."""
    raw = socket.create_connection(("127.0.0.1", gate.port), timeout=5)
    with client.wrap_socket(raw, server_hostname="127.0.0.1") as conn:
        conn.sendall(
            f"GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{gate.port}\r\nUpgrade: websocket\r\n"
            "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
            f"Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {PROTOCOL}\r\n\r\n".encode()
        )
        return conn.recv(4096)


@pytest.mark.parametrize("path", ["/", "/?token=wrong", "/?tokens=the-runs-token", "/x?token="])
def test_without_the_runs_token_the_answer_is_401(gated, path):
    gate, client = gated
    assert answer(gate, client, path).startswith(b"HTTP/1.1 401 ")
    assert gate.refused == 1


def test_with_the_token_a_foxglove_client_gets_the_servers_hello(gated):
    gate, client = gated
    assert answer(gate, client, f"/?token={TOKEN}").startswith(b"HTTP/1.1 101 ")

    async def hello() -> dict:
        import websockets

        uri = f"wss://127.0.0.1:{gate.port}/?token={TOKEN}"
        async with websockets.connect(uri, subprotocols=[PROTOCOL], ssl=client) as ws:
            return json.loads(await asyncio.wait_for(ws.recv(), 10))

    assert asyncio.run(hello())["op"] == "serverInfo"
    assert gate.refused == 0


def first_bytes(raw: socket.socket) -> bytes:
    """What the peer sends first; b"" once it has closed (reset, if our bytes were unread)."""
    try:
        return raw.recv(4096)
    except ConnectionResetError:
        return b""


def test_plain_text_and_a_silent_client_are_dropped(gated):
    gate, _ = gated
    with socket.create_connection(("127.0.0.1", gate.port), timeout=5) as raw:
        raw.sendall(f"GET /?token={TOKEN} HTTP/1.1\r\n\r\n".encode())
        assert first_bytes(raw) == b"", "no answer without TLS: the connection is closed"
    with socket.create_connection(("127.0.0.1", gate.port), timeout=5) as raw:
        assert first_bytes(raw) == b"", "closed when no handshake comes within its timeout"
    assert gate.refused == 2
