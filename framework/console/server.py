"""The operator console's web server: static page, live state, answered commands.

Started by `fw deploy` on 127.0.0.1 (never on other interfaces unless asked). It
needs nothing beyond the standard library and ships its page as static files, so
nothing is built or fetched at run time.

* `GET /` and `/static/<file>`: the page (HTML, JS, CSS from `framework/console/static`);
* `GET /api/state`: the whole picture (`ConsoleModel.snapshot`) as JSON;
* `GET /api/stream`: Server-Sent Events: the whole picture at once, then again at
  every change of the chart or the log (at least `rate` times a second), with each
  new log line; the page marks the view stale when the stream stops;
* `GET /api/chart`: the procedure chart as SVG plus the SVG-id -> state-path map the
  page uses to highlight the active states, and the operator commands with their
  payload fields (type, limits, unit) the page builds its forms from;
* `POST /api/command` `{"event", "payload", "origin"}`: checked here (only the
  topology's `external_events`, payload fields and types as the chart declares
  them), then offered to the Coordinator, whose answer (accepted, or refused with
  the reason) is returned and logged with its origin.
"""

from __future__ import annotations

import json
import math
import mimetypes
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from framework.console.model import ConsoleModel
from framework.errors import FwError
from framework.remote import RemoteComponent, RemoteError

STATIC = Path(__file__).resolve().parent / "static"
DEFAULT_PORT = 8470
MAX_BODY = 16 * 1024
COALESCE = 0.02  # s: changes closer than this go out in one picture


class ConsoleError(FwError):
    """The console could not start (port taken, bad address)."""


class CommandError(FwError):
    """A command refused before it reached the chart (bad event or payload)."""


class ConsoleServer:
    """Serves the console of one deployment (see the module docstring)."""

    def __init__(self, model: ConsoleModel, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        self.model, self.host, self.port = model, host, port
        self.rate = 5.0
        self._httpd: ThreadingHTTPServer | None = None
        self._thread: threading.Thread | None = None
        self._chart: dict[str, Any] | None = None
        self.stopping = threading.Event()

    @property
    def url(self) -> str:
        """Where the console is served."""
        return f"http://{self.host}:{self.port}/"

    def start(self) -> str:
        """Serve in a background thread; returns the URL."""
        handler = type("Handler", (_Handler,), {"console": self})
        try:
            self._httpd = ThreadingHTTPServer((self.host, self.port), handler)
        except OSError as exc:
            raise ConsoleError(
                f"cannot serve the console on {self.host}:{self.port}: {exc.strerror or exc} "
                "(choose another with --console-port, or --no-console)"
            ) from None
        self._httpd.daemon_threads = True
        self.port = self._httpd.server_address[1]
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, name="fw-console", daemon=True
        )
        self._thread.start()
        return self.url

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
                self._chart["commands"] = {
                    name: {
                        "doc": chart.events[name].doc,
                        "payload": {
                            field: {"type": kind, **chart.events[name].fields.get(field, {})}
                            for field, kind in chart.events[name].payload.items()
                        },
                    }
                    for name in self.model.external_events
                    if name in chart.events
                }
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


class _Handler(BaseHTTPRequestHandler):
    console: ConsoleServer
    server_version = "fw-console"

    def log_message(self, format: str, *args: Any) -> None:
        """Quiet: the console's own log is the event log."""

    def _send(self, status: int, body: bytes, kind: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.end_headers()
        self.wfile.write(body)

    def _json(self, data: Any, status: int = HTTPStatus.OK) -> None:
        self._send(status, _dumps(data).encode(), "application/json")

    def do_GET(self) -> None:
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            return self._file("index.html")
        if path.startswith("/static/"):
            return self._file(path[len("/static/") :])
        if path == "/api/state":
            return self._json(self.console.model.snapshot())
        if path == "/api/chart":
            return self._json(self.console.chart())
        if path == "/api/stream":
            return self._stream()
        self._json({"error": f"no such page: {path}"}, HTTPStatus.NOT_FOUND)

    def do_POST(self) -> None:
        if self.path != "/api/command":
            return self._json({"error": f"no such endpoint: {self.path}"}, HTTPStatus.NOT_FOUND)
        length = int(self.headers.get("Content-Length") or 0)
        if length > MAX_BODY:
            return self._json({"accepted": False, "reason": "command too large"}, 413)
        try:
            body = json.loads(self.rfile.read(length) or b"{}")
            if not isinstance(body, dict):
                raise ValueError("not an object")
        except ValueError as exc:
            return self._json({"accepted": False, "reason": f"malformed command: {exc}"}, 400)
        origin = f"{self.client_address[0]}:{self.client_address[1]}"
        self._json(self.console.command(body, origin))

    def _file(self, name: str) -> None:
        target = (STATIC / name).resolve()
        if STATIC not in target.parents or not target.is_file():
            return self._json({"error": f"no such file: {name}"}, HTTPStatus.NOT_FOUND)
        kind = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
        self._send(HTTPStatus.OK, target.read_bytes(), kind)

    def _stream(self) -> None:
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
        except (BrokenPipeError, ConnectionResetError):
            return  # the page went away

    def _event(self, name: str, data: Any) -> None:
        self.wfile.write(f"event: {name}\ndata: {_dumps(data)}\n\n".encode())
        self.wfile.flush()
