"""Spec: hosts as network namespaces of one machine (framework/netns.py): each host
reaches the others over the bridge, the KRC only over its own link; a cut host is
unreachable until healed; loss and delay need the kernel's netem, and say so."""

import subprocess
import sys

import pytest

from framework import netns

WHY = netns.available()
pytestmark = pytest.mark.skipif(bool(WHY), reason=f"no hosts as namespaces here: {WHY}")

SERVE = (
    "import socket, sys\n"
    "s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)\n"
    "s.bind((sys.argv[1], 7999)); s.listen(); print('up', flush=True)\n"
    "while True:\n    c, _ = s.accept(); c.sendall(b'hi'); c.close()\n"
)
ASK = (
    "import socket, sys\n"
    "try:\n    print(socket.create_connection((sys.argv[1], 7999), timeout=1).recv(2).decode())\n"
    "except OSError as exc:\n    print('unreachable')\n"
)


@pytest.fixture(scope="module")
def hosts():
    built = netns.Hosts(names=("control", "robot"), prefix="fwn-", bridge="fwnbr0").up()
    yield built
    built.down()


def ask(hosts, host, address):
    return subprocess.run(
        hosts.command(host, sys.executable, "-c", ASK, address), capture_output=True, text=True
    ).stdout.strip()


@pytest.fixture(scope="module")
def served(hosts):
    servers = [
        subprocess.Popen(
            hosts.command(host, sys.executable, "-c", SERVE, hosts.address(host)),
            stdout=subprocess.PIPE,
            text=True,
        )
        for host in ("robot", netns.KRC)
    ]
    for server in servers:
        assert server.stdout.readline().strip() == "up"
    yield
    for server in servers:
        server.kill()
        server.wait()


def test_hosts_reach_each_other_and_the_krc_only_through_the_robots_host(hosts, served):
    assert ask(hosts, "control", hosts.address("robot")) == "hi"
    assert ask(hosts, "robot", hosts.address(netns.KRC)) == "hi", "the KRC's own link"
    assert ask(hosts, "control", hosts.address(netns.KRC)) == "hi", "routed by the robot"


def test_a_cut_host_is_unreachable_until_healed(hosts, served):
    hosts.cut("robot")
    try:
        assert ask(hosts, "control", hosts.address("robot")) == "unreachable"
    finally:
        hosts.heal("robot")
    assert ask(hosts, "control", hosts.address("robot")) == "hi"


@pytest.mark.parametrize("host", ["control", netns.KRC])
def test_a_healed_host_reaches_the_krc_again(hosts, served, host):
    """Its route to the KRC (through the robot's host) goes with its link: a heal
    makes it again (before, a cut of the control host left the KRC unreachable from
    the operator's machine for good)."""
    hosts.cut(host)
    hosts.heal(host)
    assert ask(hosts, "control", hosts.address(netns.KRC)) == "hi"


def test_loss_and_delay_need_the_kernels_netem_and_say_so(hosts):
    if netns.netem_available():
        hosts.impair("robot", delay=0.01)
        hosts.heal("robot")
        return
    with pytest.raises(netns.NetnsError, match="sch_netem"):
        hosts.impair("robot", loss=0.3)
