"""The door to Foxglove's live view from other machines (`fw deploy --foxglove PORT
--foxglove-host ADDR`): TLS and the run's token in front of the SDK's server.

Foxglove's WebSocket server has no authentication, so fw keeps it on loopback (an
ephemeral port) and serves this gate on ADDR instead: TLS with the console's
certificate (the hospital's, or one made for the run whose fingerprint `fw deploy`
prints), and every connection must carry the run's token, the console's, in its URL
(`wss://HOST:PORT/?token=...`: a browser's WebSocket cannot set a header, so the URL
is where Foxglove can put it). A connection without it is answered 401 and closed;
one that does not send its request's head within `TIMEOUT` s is closed. Past the
check, bytes are copied both ways unchanged. Runs in the control process, with the
live view, never in a safety process.
"""

from __future__ import annotations

import contextlib
import socket
import ssl
import threading
import urllib.parse

from framework.console.server import carries_token, query_tokens
from framework.errors import FwError

TIMEOUT = 5.0
"""Seconds a connection has to finish its TLS handshake and its request's head."""
MAX_HEAD = 8192
MAX_CONNECTIONS = 8
"""Viewers at once (each costs two threads here and a client of the SDK's server)."""


class GateError(FwError):
    """The gate cannot serve (the address or port is not ours to take)."""


class LiveGate:
    """TLS + token in front of a loopback-only WebSocket server (see the module)."""

    def __init__(
        self,
        host: str,
        port: int,
        behind: int,
        token: str,
        tls: ssl.SSLContext | None,
        timeout: float = TIMEOUT,
    ):
        """Listen on `host`:`port` (0: any free port) for the server on 127.0.0.1:`behind`;
        `tls` None only for the specs on loopback (`fw deploy` always gives one)."""
        self.token, self.tls, self.behind, self.timeout = token, tls, behind, timeout
        self.refused = 0
        """Connections refused so far (no token, a wrong one, a head too slow or big)."""
        self._slots = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self._closing = threading.Event()
        try:
            self._listener = socket.create_server((host, port), reuse_port=False)
        except OSError as exc:
            raise GateError(f"cannot serve the live view's gate on {host}:{port}: {exc}") from None
        self.port = int(self._listener.getsockname()[1])
        self._thread = threading.Thread(target=self._accept, name="fw-live-gate", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._closing.is_set():
            try:
                conn, _ = self._listener.accept()
            except OSError:
                return  # closed
            if not self._slots.acquire(blocking=False):
                conn.close()
                self.refused += 1
                continue
            threading.Thread(target=self._serve, args=(conn,), daemon=True).start()

    def _serve(self, conn: socket.socket) -> None:
        try:
            conn.settimeout(self.timeout)
            if self.tls is not None:
                # The handshake runs here, not in wrap_socket: wrap_socket closes the
                # connection before its error reaches us, so the peer could see the
                # close before the refusal was counted.
                conn = self.tls.wrap_socket(conn, server_side=True, do_handshake_on_connect=False)
                conn.do_handshake()
            head = self._head(conn)
            if head is None or not self._authorized(head):
                self.refused += 1
                with contextlib.suppress(OSError):
                    conn.sendall(
                        b"HTTP/1.1 401 Unauthorized\r\nContent-Length: 0\r\n"
                        b"Connection: close\r\n\r\n"
                    )
                return
            conn.settimeout(None)
            upstream = socket.create_connection(("127.0.0.1", self.behind), timeout=self.timeout)
            upstream.settimeout(None)
            upstream.sendall(head)
            back = threading.Thread(target=_copy, args=(upstream, conn), daemon=True)
            back.start()
            _copy(conn, upstream)
            back.join()
        except (OSError, ssl.SSLError):
            self.refused += 1
        finally:
            with contextlib.suppress(OSError):
                conn.close()
            self._slots.release()

    def _head(self, conn: socket.socket) -> bytes | None:
        """The request's head (up to the blank line), None if it is too big or late."""
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = conn.recv(1024)
            if not chunk or len(head) + len(chunk) > MAX_HEAD:
                return None
            head += chunk
        return head

    def _authorized(self, head: bytes) -> bool:
        line = head.split(b"\r\n", 1)[0].decode("latin-1")
        parts = line.split(" ")
        if len(parts) != 3 or parts[0] != "GET":
            return False
        return carries_token(query_tokens(urllib.parse.urlsplit(parts[1]).query), self.token)

    def close(self) -> None:
        """Stop accepting (connections being served end with their viewer)."""
        self._closing.set()
        with contextlib.suppress(OSError):
            self._listener.close()


def _copy(source: socket.socket, sink: socket.socket) -> None:
    """Copy bytes until `source` ends, then end `sink`'s sending side."""
    try:
        while data := source.recv(65536):
            sink.sendall(data)
    except OSError:
        pass
    finally:
        with contextlib.suppress(OSError):
            sink.shutdown(socket.SHUT_WR)
