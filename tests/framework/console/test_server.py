"""Spec: the console server shows a running deployment and answers every command:
accepted, or refused with a reason (bad input is refused before it reaches the
chart); it serves only its own files, on the address it was given."""

import contextlib
import json
import time
import urllib.error
import urllib.request

import pytest

from tests.conftest import wait_until
from tests.framework.console.conftest import served


@pytest.fixture
def console(toy, tmp_path):
    with served(toy, tmp_path) as running:
        yield running


def login(server):
    return {"Authorization": f"Bearer {server.token}"}


def get(server, path, headers=None):
    request = urllib.request.Request(
        server.base.rstrip("/") + path, headers=login(server) if headers is None else headers
    )
    with urllib.request.urlopen(request, timeout=5) as reply:
        return reply.status, reply.headers.get("Content-Type"), reply.read()


def post(server, body, headers=None):
    data = body if isinstance(body, bytes) else json.dumps(body).encode()
    request = urllib.request.Request(
        server.base + "api/command",
        data,
        {"Content-Type": "application/json", **(login(server) if headers is None else headers)},
    )
    try:
        with urllib.request.urlopen(request, timeout=5) as reply:
            return reply.status, json.loads(reply.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def state(server):
    return json.loads(get(server, "/api/state")[2])


def leaves(server):
    return ((state(server).get("chart") or {}).get("data") or {}).get("active", [])


def test_the_page_and_the_whole_state_are_served_at_once(console):
    server, _ = console
    assert server.host == "127.0.0.1"
    status, kind, body = get(server, "/")
    assert status == 200 and kind.startswith("text/html") and b"console.js" in body
    assert wait_until(lambda: leaves(server) == ["Use_T1"], timeout=10)
    snapshot = state(server)
    assert snapshot["topology"] == "toy" and snapshot["external_events"] == ["e_SWAP", "e_BREAK"]
    assert wait_until(lambda: (state(server).get("takeable") or {}).get("data") == ["e_SWAP"])
    assert wait_until(lambda: (state(server).get("health") or {}).get("data"), timeout=5)
    health = state(server)["health"]["data"]
    assert all(h["alive"] for h in health.values()), health


def test_a_command_is_offered_to_the_chart_and_its_answer_returned_and_logged(console):
    server, _ = console
    assert wait_until(lambda: leaves(server) == ["Use_T1"], timeout=10)
    status, answer = post(server, {"event": "e_SWAP", "origin": "test"})
    assert status == 200 and answer == {"accepted": True, "reason": ""}
    assert wait_until(lambda: leaves(server) == ["Use_T2"], timeout=10)
    assert wait_until(
        lambda: any(
            "command e_SWAP from test@127.0.0.1" in line["text"] and "accepted" in line["text"]
            for line in state(server)["log"]
        )
    )


def test_bad_commands_are_refused_with_reasons_before_the_chart(console):
    server, _ = console
    assert wait_until(lambda: leaves(server) == ["Use_T1"], timeout=10)
    assert post(server, {"event": "config.done"})[1] == {
        "accepted": False,
        "reason": "not an operator event; one of e_SWAP, e_BREAK",
    }
    assert post(server, {"event": "e_BREAK"})[1] == {
        "accepted": False,
        "reason": "e_BREAK is not taken in Use_T1",
    }, "the chart's own answer"
    assert post(server, {"event": "e_SWAP", "payload": {"x": 1}})[1]["reason"] == (
        "e_SWAP has no payload field 'x'"
    )
    status, answer = post(server, b"{not json")
    assert status == 400 and answer["reason"].startswith("malformed command")
    status, answer = post(server, b"[1, 2]")
    assert status == 400 and not answer["accepted"]


def test_only_the_consoles_own_files_are_served(console):
    server, _ = console
    for path in ("/static/../server.py", "/static/%2e%2e/model.py", "/nothing"):
        with pytest.raises(urllib.error.HTTPError) as caught:
            get(server, path)
        assert caught.value.code == 404


def test_the_stream_starts_with_the_whole_state(console):
    server, _ = console
    request = urllib.request.Request(server.base + "api/stream", headers=login(server))
    with urllib.request.urlopen(request, timeout=5) as stream:
        assert stream.headers.get("Content-Type") == "text/event-stream"
        assert stream.readline() == b"event: state\n"
        first = json.loads(stream.readline()[len(b"data: ") :])
    assert first["topology"] == "toy" and "tiles" in first and "log" in first


def test_the_chart_drawing_comes_with_the_map_from_svg_ids_to_states(console):
    server, _ = console
    chart = json.loads(get(server, "/api/chart")[2])
    assert chart["idents"]["s_Use_T1"] == "Use_T1"
    if chart.get("error"):
        pytest.skip(chart["error"])  # no Graphviz here
    assert "<svg" in chart["svg"] and "s_Use_T1" in chart["svg"]


def test_non_finite_numbers_reach_the_page_as_null():
    from framework.console.server import _dumps

    assert json.loads(_dumps({"a": float("nan"), "b": [1.5, float("inf")]})) == {
        "a": None,
        "b": [1.5, None],
    }


def test_nothing_is_served_or_taken_without_this_runs_token(console):
    """The console's login is the token in the URL fw deploy prints (then a cookie)."""
    server, _ = console
    assert wait_until(lambda: leaves(server) == ["Use_T1"], timeout=10)
    for path in ("/", "/api/state", "/api/stream", "/static/console.js"):
        with pytest.raises(urllib.error.HTTPError) as caught:
            get(server, path, headers={})
        assert caught.value.code == 401
    with pytest.raises(urllib.error.HTTPError) as caught:
        get(server, "/api/state", headers={"Authorization": "Bearer wrong"})
    assert caught.value.code == 401
    status, answer = post(server, {"event": "e_SWAP"}, headers={})
    assert status == 401 and not answer["accepted"]
    assert leaves(server) == ["Use_T1"], "the command never reached the chart"


def test_the_printed_url_logs_in_with_a_cookie_only_this_console_sends(console):
    import http.client

    server, _ = console
    connection = http.client.HTTPConnection(server.host, server.port, timeout=5)
    connection.request("GET", "/?token=" + server.token)
    reply = connection.getresponse()
    reply.read()
    assert reply.status == 303 and reply.getheader("Location") == "/"
    cookie = reply.getheader("Set-Cookie")
    assert cookie.startswith(f"{server.cookie}={server.token};")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    status, kind, _ = get(server, "/", headers={"Cookie": cookie.split(";", 1)[0]})
    assert status == 200 and kind.startswith("text/html")
    connection.request("GET", f"/?snapshot&token={server.token}")
    reply = connection.getresponse()
    reply.read()
    assert reply.getheader("Location") == "/?snapshot", "the rest of the query is kept"


def raw(server, request: bytes) -> bytes:
    """Send bytes as the operator's logged-in browser would (with the login cookie:
    another site's page in that browser gets it too, 127.0.0.1 ports are one "site"),
    return the whole reply."""
    import socket

    head, _, rest = request.partition(b"\r\n")
    cookie = f"Cookie: {server.cookie}={server.token}\r\n".encode()
    with socket.create_connection((server.host, server.port), timeout=10) as sock:
        sock.sendall(head + b"\r\n" + cookie + rest)
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def status_of(reply: bytes) -> int:
    return int(reply.split(b" ", 2)[1])


def test_other_sites_and_rebinding_hosts_are_refused(console):
    """A page of another site (Origin) or a rebinding name (Host) can neither command
    nor read; a form or text/plain post (a "simple request") is not a command."""
    server, _ = console
    assert wait_until(lambda: leaves(server) == ["Use_T1"], timeout=10), (
        "settled, where e_SWAP is taken"
    )
    host = f"{server.host}:{server.port}"
    body = b'{"event": "e_SWAP"}'
    evil = raw(
        server,
        b"POST /api/command HTTP/1.1\r\nHost: " + host.encode() + b"\r\nOrigin: http://evil.example"
        b"\r\nContent-Type: application/json\r\nContent-Length: 19\r\nConnection: close\r\n\r\n"
        + body,
    )
    assert status_of(evil) == 403 and b"another site" in evil
    rebound = raw(
        server, b"GET /api/state HTTP/1.1\r\nHost: evil.example:80\r\nConnection: close\r\n\r\n"
    )
    assert status_of(rebound) == 403 and b"does not answer for host" in rebound
    plain = raw(
        server,
        b"POST /api/command HTTP/1.1\r\nHost: " + host.encode() + b"\r\nContent-Type: text/plain"
        b"\r\nContent-Length: 19\r\nConnection: close\r\n\r\n" + body,
    )
    assert status_of(plain) == 415
    time.sleep(0.2)  # a command that got through would have swapped by now
    assert leaves(server) == ["Use_T1"], "nothing reached the chart"


@pytest.mark.parametrize(
    "length, body, code, reason",
    [
        ("-1", b"{}", 400, b"valid Content-Length"),
        ("abc", b"{}", 400, b"valid Content-Length"),
        (str(10**6), b"{}", 413, b"too large"),
        (None, b"[" * 5000 + b"]" * 5000, 400, b"malformed command"),
        (None, b'{"a":' * 20 + b"1" + b"}" * 20, 400, b"nested deeper"),
    ],
)
def test_malformed_requests_get_a_clean_answer(console, length, body, code, reason):
    server, _ = console
    host = f"{server.host}:{server.port}".encode()
    size = (length or str(len(body))).encode()
    reply = raw(
        server,
        b"POST /api/command HTTP/1.1\r\nHost: " + host + b"\r\nContent-Type: application/json"
        b"\r\nContent-Length: " + size + b"\r\nConnection: close\r\n\r\n" + body,
    )
    assert status_of(reply) == code and reason in reply


def test_a_long_path_is_refused_and_the_server_goes_on(console):
    server, _ = console
    host = f"{server.host}:{server.port}".encode()
    reply = raw(server, b"GET /" + b"a" * 5000 + b" HTTP/1.1\r\nHost: " + host + b"\r\n\r\n")
    assert status_of(reply) in (403, 414)
    assert get(server, "/")[0] == 200


def test_a_slow_sender_is_cut_off(toy, tmp_path):
    """Slowloris: a connection that never finishes its request is closed."""
    import socket

    with served(toy, tmp_path, timeout=0.3) as (server, _):
        sock = socket.create_connection((server.host, server.port), timeout=20)
        try:
            sock.sendall(b"GET / HTTP/1.1\r\n")  # and nothing more
            assert sock.recv(1024) == b"", "the server closed the connection"
        finally:
            sock.close()


def test_a_sender_that_trickles_its_request_is_cut_off_too(toy, tmp_path):
    """A client that sends one byte just before every read timeout would hold its
    connection forever if only reads were timed: the whole head has a deadline."""
    import socket
    import time

    with served(toy, tmp_path, timeout=0.3) as (server, _):
        line = b"GET / HTTP/1.1\r\nX-Slow: " + b"a" * 200
        sock = socket.create_connection((server.host, server.port), timeout=20)
        sent = 0
        try:
            with contextlib.suppress(OSError):
                for byte in line:
                    sock.sendall(bytes([byte]))
                    sent += 1
                    time.sleep(0.05)  # each byte well within the 0.3 s read timeout
            cut = sent < len(line) or sock.recv(1024) == b""
        finally:
            sock.close()
        assert cut, "the server was still listening after the whole trickle"
        assert sent < len(line), f"the server waited for all {len(line)} bytes"
        assert get(server, "/")[0] == 200
