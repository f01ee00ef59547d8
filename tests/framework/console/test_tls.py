"""Spec: a console opened beyond this machine is served over TLS only, with the
hospital's certificate or one made for the run whose fingerprint fw deploy prints;
certificate mistakes are clear errors before anything starts."""

import http.client
import re
import socket
import ssl

import pytest

from framework.console import tls
from tests.conftest import REPO, interrupt
from tests.framework.console.conftest import served
from tests.framework.test_cli_deploy import deploy_in_background, fw


def https(host, port, path, cafile=None, token=None):
    """GET over TLS; verifies the server against `cafile` if given."""
    context = (
        ssl.create_default_context(cafile=cafile) if cafile else ssl._create_unverified_context()
    )
    connection = http.client.HTTPSConnection(host, port, context=context, timeout=10)
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    connection.connect()
    peer = connection.sock.getpeercert(binary_form=True)
    connection.request("GET", path, headers=headers)
    reply = connection.getresponse()
    body = reply.read()
    connection.close()
    return reply, body, peer


def test_with_a_given_certificate_the_console_speaks_tls_only(toy, tmp_path):
    cert, key = tls.self_signed(["127.0.0.1"], tmp_path / "pki")
    with served(toy, tmp_path, tls=tls.server_context(cert, key)) as (server, _):
        assert server.url.startswith("https://127.0.0.1:")
        reply, body, _ = https("127.0.0.1", server.port, "/api/state", str(cert), server.token)
        assert reply.status == 200 and b'"chart"' in body
        reply, _, _ = https("127.0.0.1", server.port, "/?token=" + server.token, str(cert))
        assert "Secure" in reply.getheader("Set-Cookie")
        with socket.create_connection(("127.0.0.1", server.port), timeout=10) as sock:
            sock.sendall(b"GET /api/state HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            answer = sock.recv(4096)
        assert not answer.startswith(b"HTTP/"), "plain HTTP was answered"
        assert https("127.0.0.1", server.port, "/", str(cert))[0].status == 401


def test_a_client_that_never_finishes_its_handshake_is_cut_off(toy, tmp_path):
    cert, key = tls.self_signed(["127.0.0.1"], tmp_path / "pki")
    with served(toy, tmp_path, tls=tls.server_context(cert, key), timeout=0.3) as (server, _):
        with socket.create_connection(("127.0.0.1", server.port), timeout=20) as sock:
            sock.sendall(b"\x16\x03\x01")  # the first bytes of a ClientHello, no more
            assert sock.recv(1024) == b"", "the server closed the connection"
        assert https("127.0.0.1", server.port, "/", str(cert), server.token)[0].status == 200


def test_beyond_loopback_fw_deploy_serves_tls_with_a_run_certificate_and_its_fingerprint(
    tmp_path, bus_config
):
    topology = tmp_path / "toy.yaml"
    text = (REPO / "tests/data/toy/toy.yaml").read_text()
    topology.write_text(
        text.replace(
            "topology: toy\n",
            f"topology: toy\nbus: {{namespace: {bus_config.namespace}, "
            f"hub_port: {bus_config.hub_port}}}\n",
        )
    )
    (tmp_path / "toy_chart.yaml").write_text((REPO / "tests/data/toy/toy_chart.yaml").read_text())
    run = deploy_in_background(topology, "--console-host", "0.0.0.0", "--console-port", "0")
    try:
        lines = []
        while not any("SHA-256" in line for line in lines):
            line = run.stderr.readline()
            assert line, "fw deploy ended: " + "".join(lines)
            lines.append(line)
        text = "".join(lines)
        url = re.search(r"(https://\S+):(\d+)/\?token=(\S+)", text)
        assert url, text
        port, token = int(url.group(2)), url.group(3)
        printed = re.search(r"SHA-256 ([0-9A-F:]{95})", text).group(1)
        reply, _, peer = https("127.0.0.1", port, "/api/state", token=token)
        assert reply.status == 200
        assert tls.fingerprint_der(peer) == printed
    finally:
        interrupt(run)


@pytest.mark.parametrize(
    "options, message",
    [
        (["--console-cert", "missing.pem"], "--console-cert and --console-key go together"),
        (["--console-cert", "missing.pem", "--console-key", "missing.key"], "no such file"),
        (["--console-cert", "{other}", "--console-key", "{key}"], "cannot serve TLS"),
    ],
)
def test_certificate_mistakes_are_clear_errors_before_anything_starts(tmp_path, options, message):
    _, key = tls.self_signed(["127.0.0.1"], tmp_path / "a")
    other, _ = tls.self_signed(["127.0.0.1"], tmp_path / "b")
    options = [o.format(other=other, key=key) for o in options]
    done = fw("deploy", str(REPO / "tests/data/toy/toy.yaml"), "--console-port", "0", *options)
    assert done.returncode != 0
    assert message in done.stderr and "Traceback" not in done.stderr
    assert "starting" not in done.stderr
