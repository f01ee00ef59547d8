"""The operator console's web server: static page, live state, answered commands.

Started by `fw deploy` on 127.0.0.1 (never on other interfaces unless asked; then
over TLS only, see `framework/console/tls.py`). It needs nothing beyond the standard
library and ships its page as static files, so nothing is built or fetched at run time.
Every request needs the run's token; a client has `TIMEOUT` s for the whole head of a
request (TLS handshake, request line, headers, a command's body), however it trickles.

* `GET /` and `/static/<file>`: the page (HTML, JS, CSS from `framework/console/static`);
  `/panels/<name>/<file>`: the scripts of the panels the topology names;
* `GET /api/layout`: what the page builds once (`ConsoleModel.layout`): the operator's
  buttons and forms (payload fields with type, limits, unit), plots and panels;
* `GET /api/state`: the whole picture (`ConsoleModel.snapshot`) as JSON;
* `GET /api/stream`: Server-Sent Events: the whole picture at once, then again at
  every change of the chart or the log (at least `rate` times a second), with each
  new log line; the page marks the view stale when the stream stops;
* `GET /api/chart`: the procedure chart as SVG plus the SVG-id -> state-path map the
  page uses to highlight the active states;
* `POST /api/command` `{"event", "payload", "origin"}`: checked here (only the
  topology's `external_events`, payload fields and types as the chart declares
  them), then offered to the Coordinator, whose answer (accepted, or refused with
  the reason) is returned and logged with its origin.
"""

from __future__ import annotations

import contextlib
import hmac
import json
import math
import mimetypes
import secrets
import socket
import ssl
import threading
import time
import urllib.parse
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from framework.console.model import ConsoleModel
from framework.console.tls import is_loopback, is_wildcard, names_for
from framework.errors import FwError
from framework.remote import RemoteComponent, RemoteError

STATIC = Path(__file__).resolve().parent / "static"
DEFAULT_PORT = 8470
MAX_BODY = 16 * 1024
MAX_DEPTH = 8
"""Nesting a command may have (its payload is one flat object)."""
MAX_PATH = 512
TIMEOUT = 10.0
"""Seconds a connection may take to send a request's head (slow senders are cut)."""
MAX_CONNECTIONS = 256  # threads are cheap; a slow client holds one until its timeout
MAX_STREAMS = 16
COALESCE = 0.02  # s: changes closer than this go out in one picture


class ConsoleError(FwError):
    """The console could not start (port taken, bad address)."""


class CommandError(FwError):
    """A command refused before it reached the chart (bad event or payload)."""


def query_tokens(query: str) -> list[str]:
    """The `token=` values of a URL's query."""
    return urllib.parse.parse_qs(query).get("token", [])


def carries_token(given: list[str], token: str) -> bool:
    """Is the run's `token` among what a request `given`? Compared in constant time (a
    guess cannot learn a prefix from how fast it is refused)."""
    return any(hmac.compare_digest(g.encode(), token.encode()) for g in given)


class ConsoleServer:
    """Serves the console of one deployment (see the module docstring)."""

    def __init__(
        self,
        model: ConsoleModel,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        timeout: float = TIMEOUT,
        tls: ssl.SSLContext | None = None,
        token: str | None = None,
    ):
        self.model, self.host, self.port = model, host, port
        self.tls = tls
        """Served over TLS with this context (None: plain HTTP, for loopback only)."""
        self.token = token or secrets.token_urlsafe(18)
        """The run's login: in the URL fw deploy prints, then in a cookie."""
        self.rate = 5.0
        self._httpd: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None
        self._chart: dict[str, Any] | None = None
        self.stopping = threading.Event()
        self.timeout = timeout
        self.connections = threading.BoundedSemaphore(MAX_CONNECTIONS)
        self.streams = threading.BoundedSemaphore(MAX_STREAMS)
        self._heads: dict[socket.socket, float] = {}
        """Connections still sending a request's head -> when they must be done."""
        self._heads_lock = threading.Lock()
        self._allowed: set[str] = set()

    def allowed_hosts(self) -> set[str]:
        """`Host` headers this server answers (anything else is DNS rebinding); found
        once, at start (a wildcard host's names need a lookup)."""
        return self._allowed

    def _find_allowed_hosts(self) -> set[str]:
        names = set(names_for(self.host))
        if is_loopback(self.host):
            names |= set(LOOPBACK)
        return {f"[{n}]:{self.port}" if ":" in n else f"{n}:{self.port}" for n in names}

    @property
    def base(self) -> str:
        """Where the console is served (without the login)."""
        host = socket.gethostname() if is_wildcard(self.host) else self.host
        host = f"[{host}]" if ":" in host else host
        return f"{'https' if self.tls else 'http'}://{host}:{self.port}/"

    @property
    def url(self) -> str:
        """The URL to open: with the run's token (like a notebook server's)."""
        return f"{self.base}?token={self.token}"

    @property
    def cookie(self) -> str:
        """The cookie that carries the login (per port: two consoles on one host)."""
        return f"fw_console_{self.port}"

    def authorized(self, headers: Any, query: str) -> bool:
        """Does this request carry the run's token (cookie, bearer header or URL)?"""
        given = []
        for part in (headers.get("Cookie") or "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == self.cookie:
                given.append(value)
        bearer = headers.get("Authorization") or ""
        if bearer.startswith("Bearer "):
            given.append(bearer[len("Bearer ") :])
        return carries_token([*given, *query_tokens(query)], self.token)

    def start(self) -> str:
        """Serve in a background thread; returns the URL."""
        handler = type("Handler", (_Handler,), {"console": self, "timeout": self.timeout})
        try:
            self._httpd = _Server((self.host, self.port), handler)
        except OSError as exc:
            raise ConsoleError(
                f"cannot serve the console on {self.host}:{self.port}: {exc.strerror or exc} "
                "(choose another with --console-port, or --no-console)"
            ) from None
        self._httpd.daemon_threads = True
        self.port = self._httpd.server_address[1]
        self._allowed = self._find_allowed_hosts()
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, name="fw-console", daemon=True
        )
        self._thread.start()
        threading.Thread(target=self._cut_slow_heads, name="fw-console-heads", daemon=True).start()
        return self.url

    def head_begins(self, connection: socket.socket) -> None:
        """A request's head starts arriving: it has `timeout` s to be complete (a
        connection's first request keeps the deadline its TLS handshake began)."""
        with self._heads_lock:
            self._heads.setdefault(connection, time.monotonic() + self.timeout)

    def head_done(self, connection: socket.socket) -> None:
        """The head has arrived (or the connection ends): no deadline any more."""
        with self._heads_lock:
            self._heads.pop(connection, None)

    def _cut_slow_heads(self) -> None:
        """Close connections whose head is late: a socket timeout bounds each read, not
        a client that sends one byte just before every timeout."""
        while not self.stopping.wait(min(0.25, self.timeout / 2)):
            now = time.monotonic()
            with self._heads_lock:
                late = [c for c, until in self._heads.items() if until < now]
                for connection in late:
                    del self._heads[connection]
            for connection in late:
                with contextlib.suppress(OSError):  # the plain socket's: no TLS close
                    socket.socket.shutdown(connection, socket.SHUT_RDWR)

    def stop(self) -> None:
        """Stop serving (open streams end)."""
        self.stopping.set()
        if self._httpd is not None:
            self._httpd.shutdown()
            self._httpd.server_close()
            self._httpd = None

    # -- what the handler asks -----------------------------------------------------
    def chart(self) -> dict[str, Any]:
        """The chart drawing and the id map (drawn once)."""
        if self._chart is None:
            chart = self.model.chart
            if chart is None:
                self._chart = {"svg": "", "idents": {}, "error": "this deployment has no chart"}
            else:
                self._chart = _draw(chart)
        return self._chart

    def command(self, body: dict[str, Any], origin: str) -> dict[str, Any]:
        """Check a command, offer it to the chart, return the answer."""
        event = body.get("event")
        payload = body.get("payload") or {}
        who = str(body.get("origin") or "console")[:60] + f"@{origin}"
        try:
            self._check(event, payload)
        except CommandError as exc:
            answer = {"accepted": False, "reason": str(exc)}
            self.model.note("warning", f"command {event!r} from {who}: refused: {exc}")
            return answer
        try:
            return RemoteComponent(self.model.bus, "coordinator", timeout=2.0).call(
                "offer", event=event, payload=payload or None, origin=who
            )
        except RemoteError as exc:
            return {"accepted": False, "reason": f"the coordinator did not answer: {exc}"}

    def _check(self, event: Any, payload: Any) -> None:
        allowed = self.model.external_events
        if not isinstance(event, str) or event not in allowed:
            raise CommandError(f"not an operator event; one of {', '.join(allowed) or 'none'}")
        if not isinstance(payload, dict):
            raise CommandError("payload must be an object")
        chart = self.model.chart
        spec = chart.events.get(event) if chart is not None else None
        if spec is not None:
            problem = spec.problem(payload)
        else:
            problem = f"{event} has no payload field {next(iter(payload))!r}" if payload else ""
        if problem:
            raise CommandError(problem)


def _draw(chart: Any) -> dict[str, Any]:
    import re
    import tempfile

    from framework.statechart.export import ExportError, render

    idents = {
        "s_" + (re.sub(r"\W", "_", s.path) if s.path else "root"): s.path
        for s in chart.states.values()
    }
    try:
        with tempfile.TemporaryDirectory() as tmp:
            svg = render(chart, Path(tmp) / "chart.svg").read_text(encoding="utf-8")
    except ExportError as exc:
        return {"svg": "", "idents": idents, "error": str(exc)}
    return {"svg": svg, "idents": idents}


def _depth(value: Any) -> int:
    """How deeply `value` nests (a flat object is 1)."""
    if isinstance(value, dict):
        return 1 + max((_depth(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return 1 + max((_depth(v) for v in value), default=0)
    return 0


def _finite(value: Any) -> Any:
    """NaN and infinities become null: browsers' JSON.parse refuses them."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _dumps(data: Any) -> str:
    return json.dumps(_finite(data), default=str, allow_nan=False)


LOOPBACK = ("127.0.0.1", "localhost", "::1")
LOGIN = "log in with the URL fw deploy printed (it carries this run's token)"


class _Server(ThreadingHTTPServer):
    """A thread per connection, at most MAX_CONNECTIONS of them; nothing a client
    does ever prints a traceback on the operator's terminal."""

    daemon_threads = True

    def get_request(self) -> tuple[Any, Any]:
        """Accept; over TLS, the handshake is left to the connection's own thread (a
        slow handshake must not hold the accepting one)."""
        connection, address = super().get_request()
        tls = self.RequestHandlerClass.console.tls  # type: ignore[attr-defined]
        if tls is not None:
            connection = tls.wrap_socket(
                connection, server_side=True, do_handshake_on_connect=False
            )
        return connection, address

    def process_request(self, request: Any, client_address: Any) -> None:
        console = self.RequestHandlerClass.console  # type: ignore[attr-defined]
        if not console.connections.acquire(blocking=False):
            if console.tls is None:  # over TLS, plain bytes would only be garbage
                with contextlib.suppress(OSError):
                    request.sendall(
                        b"HTTP/1.1 503 Service Unavailable\r\nContent-Length: 0\r\n\r\n"
                    )
            self.shutdown_request(request)
            return
        super().process_request(request, client_address)

    def process_request_thread(self, request: Any, client_address: Any) -> None:
        try:
            super().process_request_thread(request, client_address)
        finally:
            self.RequestHandlerClass.console.connections.release()  # type: ignore[attr-defined]

    def handle_error(self, request: Any, client_address: Any) -> None:
        """A client that went away or sent garbage: not the operator's concern."""


class _Handler(BaseHTTPRequestHandler):
    console: ConsoleServer
    server_version = "fw-console"
    timeout = TIMEOUT

    def log_message(self, format: str, *args: Any) -> None:
        """Quiet: the console's own log is the event log."""

    def setup(self) -> None:
        """The head deadline covers the TLS handshake too."""
        self.console.head_begins(self.request)
        super().setup()
        if isinstance(self.connection, ssl.SSLSocket):
            try:
                self.connection.do_handshake()
            except (OSError, ValueError):  # not TLS, a bad certificate, too slow
                self.console.head_done(self.request)
                raise ConnectionAbortedError from None

    def handle_one_request(self) -> None:
        self.console.head_begins(self.request)
        try:
            super().handle_one_request()
        finally:  # however it ended, the next request on this connection starts afresh
            self.console.head_done(self.request)

    def parse_request(self) -> bool:
        parsed = super().parse_request()
        if self.command != "POST":  # a POST's head includes its body
            self.console.head_done(self.request)
        return parsed

    def finish(self) -> None:
        with contextlib.suppress(OSError, ValueError):  # a connection cut by the watcher
            super().finish()

    def _send(self, status: int, body: bytes, kind: str) -> None:
        try:
            self.send_response(status)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.send_header("X-Content-Type-Options", "nosniff")
            self.send_header("X-Frame-Options", "DENY")
            self.end_headers()
            self.wfile.write(body)
        except OSError:  # the client went away
            self.close_connection = True

    def _refused(self) -> str:
        """Why this request is refused before anything else ("" if it is not): a
        foreign Host (DNS rebinding), a foreign Origin (another site's page), a path
        longer than any of ours."""
        host = self.headers.get("Host", "")
        if host not in self.console.allowed_hosts():
            return f"this console does not answer for host {host[:80]!r}"
        origin = self.headers.get("Origin")
        if origin is not None and origin.split("//", 1)[-1] not in self.console.allowed_hosts():
            return f"requests from {origin[:80]!r} are refused (another site's page)"
        if len(self.path) > MAX_PATH:
            return "path too long"
        return ""

    def _json(self, data: Any, status: int = HTTPStatus.OK) -> None:
        self._send(status, _dumps(data).encode(), "application/json")

    def do_GET(self) -> None:
        refusal = self._refused()
        if refusal:
            return self._json({"error": refusal}, HTTPStatus.FORBIDDEN)
        path, _, query = self.path.partition("?")
        if not self.console.authorized(self.headers, query):
            return self._json({"error": LOGIN}, HTTPStatus.UNAUTHORIZED)
        if "token=" in query and path in ("/", "/index.html"):
            return self._login(query)
        if path in ("/", "/index.html"):
            return self._file("index.html")
        if path.startswith("/static/"):
            return self._file(path[len("/static/") :])
        if path == "/api/state":
            return self._json(self.console.model.snapshot())
        if path == "/api/chart":
            return self._json(self.console.chart())
        if path == "/api/layout":
            return self._json(self.console.model.layout())
        if path.startswith("/panels/"):
            name, _, file = path[len("/panels/") :].partition("/")
            panel = next((p for p in self.console.model.panels if p.name == name), None)
            return self._file(file, panel.static if panel is not None else None)
        if path == "/api/stream":
            return self._stream()
        self._json({"error": f"no such page: {path}"}, HTTPStatus.NOT_FOUND)

    def do_POST(self) -> None:
        refusal = self._refused()
        if refusal:
            return self._json({"accepted": False, "reason": refusal}, HTTPStatus.FORBIDDEN)
        if not self.console.authorized(self.headers, ""):
            return self._json({"accepted": False, "reason": LOGIN}, HTTPStatus.UNAUTHORIZED)
        if self.path != "/api/command":
            return self._json({"error": f"no such endpoint: {self.path[:80]}"}, 404)
        kind = self.headers.get("Content-Type", "").split(";", 1)[0].strip().lower()
        if kind != "application/json":  # a form or text/plain: what another page can send
            reason = "a command must be sent as application/json"
            return self._json({"accepted": False, "reason": reason}, 415)
        text = self.headers.get("Content-Length", "")
        if not text.isdigit():
            reason = "a command needs a valid Content-Length"
            return self._json({"accepted": False, "reason": reason}, 400)
        length = int(text)
        if length > MAX_BODY:
            return self._json({"accepted": False, "reason": "command too large"}, 413)
        try:
            data = self.rfile.read(length)
            self.console.head_done(self.request)
            body = json.loads(data or b"{}")
            if not isinstance(body, dict):
                raise ValueError("not an object")
            if _depth(body) > MAX_DEPTH:
                raise ValueError(f"nested deeper than {MAX_DEPTH}")
        except (ValueError, RecursionError) as exc:
            reason = f"malformed command: {str(exc)[:120] or type(exc).__name__}"
            return self._json({"accepted": False, "reason": reason}, 400)
        except OSError:  # the client went away or was too slow (TIMEOUT)
            self.close_connection = True
            return
        origin = f"{self.client_address[0]}:{self.client_address[1]}"
        self._json(self.console.command(body, origin))

    def _login(self, query: str) -> None:
        """The token from the URL goes into a cookie only this console's own pages send
        (HttpOnly, SameSite=Strict); the address bar loses it, and keeps the rest of
        the query (`snapshot`)."""
        rest = "&".join(p for p in query.split("&") if p and not p.startswith("token="))
        try:
            self.send_response(HTTPStatus.SEE_OTHER)
            secure = "; Secure" if self.console.tls is not None else ""
            self.send_header(
                "Set-Cookie",
                f"{self.console.cookie}={self.console.token}; HttpOnly; SameSite=Strict; "
                f"Path=/{secure}",
            )
            self.send_header("Location", "/" + (f"?{rest}" if rest else ""))
            self.send_header("Content-Length", "0")
            self.end_headers()
        except OSError:
            self.close_connection = True

    def _file(self, name: str, folder: Path | None = STATIC) -> None:
        """A file of `folder` (the page's, or a panel's), never one outside it."""
        try:
            target = (folder / name).resolve() if folder is not None else None
            found = target is not None and folder.resolve() in target.parents
            found = found and target.is_file()
        except (OSError, ValueError):
            found = False
        if not found:
            return self._json({"error": f"no such file: {name[:80]}"}, HTTPStatus.NOT_FOUND)
        kind = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
        self._send(HTTPStatus.OK, target.read_bytes(), kind)

    def _stream(self) -> None:
        if not self.console.streams.acquire(blocking=False):
            return self._json({"error": f"at most {MAX_STREAMS} live views"}, 503)
        try:
            self._stream_held()
        finally:
            self.console.streams.release()

    def _stream_held(self) -> None:
        self.connection.settimeout(self.console.timeout)  # a reader that stops is dropped
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream")
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        console, model = self.console, self.console.model
        first = True
        seq = 0
        generation = -1
        try:
            while not console.stopping.is_set():
                snapshot = model.snapshot(log=first)
                if first:
                    seq = snapshot["log_seq"]
                    first = False
                self._event("state", snapshot)
                # the next picture: at once when the chart or the log changes, else
                # after 1/rate s (the polled parts refresh at that pace anyway)
                generation = model.wait_change(generation, 1.0 / console.rate)
                console.stopping.wait(COALESCE)  # one picture for a burst of chart steps
                for entry in model.log_since(seq):
                    self._event("log", entry)
                    seq = entry["seq"]
        except OSError:
            return  # the page went away, or stopped reading

    def _event(self, name: str, data: Any) -> None:
        self.wfile.write(f"event: {name}\ndata: {_dumps(data)}\n\n".encode())
        self.wfile.flush()
