"""Spec: a process that stops hearing another one that is there reopens its bus, and
only then (framework/routes.py), on real Zenoh sessions.

Zenoh's own failure (routes left unmade after a partition heals) cannot be caused at
will; here the receiving side's probe subscription is undeclared behind the watch's
back, which leaves the two sessions linked and the probes unheard: what the watch
sees in that failure.
"""

from __future__ import annotations

import json
import time

import pytest

from framework import keys
from framework.bus import Bus
from framework.peer_clocks import answer_clock
from framework.routes import Peer, RouteWatch
from tests.conftest import wait_until

SILENT = 0.3


@pytest.fixture
def pair(bus_config, hub):
    """Two processes' buses, `a` and `b`, each with its route watch (stepped by the test)
    and its clock queryable, linked and hearing each other."""
    buses = [Bus(bus_config) for _ in range(2)]
    watches = [
        RouteWatch(bus, name, silent=SILENT, spacing=0.0, overlap=0.2)
        for bus, name in zip(buses, "ab", strict=True)
    ]
    clocks = [answer_clock(bus, name) for bus, name in zip(buses, "ab", strict=True)]

    def both_hear() -> bool:
        for w in watches:
            w.step()
        return all(set(w.peers) == {"ab".replace(w.process, "")} for w in watches)

    assert wait_until(both_hear, 10.0), "the two processes never heard each other's probes"
    yield watches
    for w in watches:
        w.stop()
    for clock in clocks:
        clock.undeclare()
    for bus in buses:
        bus.close()


def _step_until(watch: RouteWatch, timeout: float = 10.0) -> list[str]:
    """Step `watch` until a round reopens its bus (or `timeout`); whom it reopened for."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        reopened = watch.step()
        if reopened:
            return reopened
        time.sleep(0.02)
    return []


def test_probes_of_a_process_that_is_there_unheard_reopen_the_bus_and_it_hears_again(pair):
    a, b = pair
    b.silent = 5.0  # longer than a's reopen, in which a puts no probe (6 s against 1 deployed)
    a._subscriber.obj.undeclare()  # a hears b no more; their sessions stay linked
    assert _step_until(a) == ["b"]
    assert a.bus.reopened == 1
    assert "while its session is linked to this one" in a.reopens[0]["why"]
    reopened_at = time.monotonic()

    def hears_b_again() -> bool:
        b.step()
        a.step()  # a's probes go on, so b has nothing to mend
        return a.peers["b"].heard > reopened_at

    assert wait_until(hears_b_again, 10.0), "the reopened bus never heard b's probes"
    assert b.bus.reopened == 0, "the side that heard everything reopened too"


def test_a_process_that_is_cut_off_or_dead_reopens_nothing(pair):
    a, b = pair
    b.stop()
    b.bus.close()  # dead: neither linked nor answering
    assert wait_until(lambda: a.peers["b"].zid not in a.bus.linked(), 10.0)
    time.sleep(SILENT)
    for _ in range(5):
        assert a.step() == []
    assert a.bus.reopened == 0


def test_a_silent_process_whose_session_is_not_linked_is_not_there(pair):
    """Not linked: cut off, hung past its lease, dead, or restarted under a new session
    id (its clock answers under the same name before its first probe: no evidence)."""
    a, _ = pair
    peer = a.peers["b"]
    restarted = Peer("a-session-that-is-gone", peer.heard, peer.count)
    assert a._there("b", restarted, a.bus.linked()) == ""
    assert a._there("b", peer, a.bus.linked()) == "while its session is linked to this one"


def test_reopens_are_spaced(pair):
    a, _ = pair
    a.spacing = 60.0
    a._subscriber.obj.undeclare()
    assert _step_until(a) == ["b"]
    a._subscriber.obj.undeclare()  # lost again at once
    time.sleep(SILENT * 2)
    for _ in range(5):
        assert a.step() == []
    assert a.bus.reopened == 1


def test_a_probe_that_is_not_one_is_counted_and_ignored(pair, hub):
    a, _ = pair
    publisher = hub.publisher(keys.route_probe("intruder"), cache=False)
    for payload in (b"\xff\x00", b"{}", json.dumps({"zid": "x", "n": "many", "reopened": 0})):
        publisher.put(payload)
    assert wait_until(lambda: a.refused >= 3, 10.0)
    assert "intruder" not in a.peers
    a.step()  # and the watch goes on


def test_a_process_does_not_count_its_own_probes(pair):
    a, _ = pair
    for _ in range(3):
        a.step()
    assert a.process not in a.peers
    assert a._hold_error == "", "a watch without a hold found it failing"


def test_a_bus_that_cannot_reopen_says_the_routes_are_lost_and_keeps_its_session(pair, capsys):
    a, _ = pair
    a.can_reopen = False
    zid = a.bus.zid()
    a._subscriber.obj.undeclare()
    time.sleep(SILENT)
    for _ in range(3):
        assert a.step() == []
    assert a.bus.reopened == 0 and a.bus.zid() == zid
    assert "cannot reopen" in capsys.readouterr().err


def test_the_hub_of_a_deployment_on_one_host_cannot_reopen(hub):
    from framework.bus import BusError

    with pytest.raises(BusError, match="cannot reopen"):
        hub.reopen()


def test_a_heard_process_whose_token_this_bus_never_sees_makes_it_reopen(pair):
    a, b = pair
    seen: list[tuple[str, bool]] = []
    watch = a.bus.watch(keys.ALL_ALIVE, lambda key, alive: seen.append((key, alive)))
    watch.obj.undeclare()  # a's liveliness routes lost; its probes still flow
    b.bus.token(keys.alive("tracker"))
    end = time.monotonic() + 10.0
    reopened: list[str] = []
    while not reopened and time.monotonic() < end:
        b.step()  # b's probes say it holds the token
        reopened = a.step()
        time.sleep(0.05)
    assert reopened == ["b"]
    assert "its token fw/alive/tracker unseen" in a.reopens[0]["why"]
    assert wait_until(lambda: ("fw/alive/tracker", True) in seen, 10.0)
    assert a.bus.seen_alive(keys.alive("tracker")) is True


def test_a_token_of_a_process_nobody_here_watches_is_no_evidence(pair):
    a, b = pair
    b.bus.token(keys.alive("tracker"))  # a watches no liveliness at all
    for _ in range(int(SILENT / 0.05) * 2):
        b.step()
        assert a.step() == []
        time.sleep(0.05)


def test_a_process_that_must_keep_its_bus_reopens_only_once_it_may(pair, capsys):
    a, _ = pair
    holding = ["robot: the robot interface commands the arm"]
    a.hold = lambda: holding[0]
    a._subscriber.obj.undeclare()
    time.sleep(SILENT)
    for _ in range(5):
        assert a.step() == []
    assert a.bus.reopened == 0
    assert capsys.readouterr().err.count("the reopen waits: robot:") == 1, "said once"
    holding[0] = ""  # the arm is braked
    assert _step_until(a) == ["b"]
    assert a.bus.reopened == 1


def test_no_process_reopens_while_another_says_it_holds_the_deployments_buses(
    pair, bus_config, capsys
):
    """The robot interface holds every process's bus while it commands the arm (its
    probes say so): a reopen elsewhere, for a peer that fell silent, waits for the arm
    to be braked, as its interpreter time can make a watched heartbeat late."""
    a, b = pair
    c = RouteWatch(Bus(bus_config), "c", silent=SILENT, spacing=0.0, overlap=0.2)
    try:

        def all_hear_c() -> bool:
            for w in (a, b, c):
                w.step()
            return "c" in a.peers

        assert wait_until(all_hear_c, 10.0)
        a.silent = 1.0  # a hiccup of b's probes on a busy host is not what this is about
        b.hold = lambda: "the robot interface commands the arm"
        assert wait_until(lambda: (b.step(), a.step(), a.peers["b"].holds)[2], 10.0)
        c._publisher.undeclare()  # c falls silent while its session is still linked
        for _ in range(int(a.silent / 0.05) * 2):
            b.step()
            assert a.step() == [], "a reopened while b held the buses"
            time.sleep(0.05)
        assert "the reopen waits: b says the robot interface commands the arm" in (
            capsys.readouterr().err
        )
        b.hold = lambda: ""  # the arm is braked

        def a_reopens() -> list[str]:
            b.step()  # b keeps putting probes (now without its hold)
            return a.step()

        reopened: list[list[str]] = []
        assert wait_until(lambda: reopened.append(a_reopens()) or reopened[-1], 10.0)
        assert reopened[-1] == ["c"]
    finally:
        c.stop()
        c.bus.close()


def test_a_hold_that_fails_is_said_and_the_probes_go_on(pair, capsys):
    a, b = pair
    a.hold = lambda: 1 / 0  # a component's own code, before it is configured

    def heard_from_a() -> int:
        b.step()
        return b.peers["a"].count

    before = heard_from_a()
    for _ in range(3):
        a.step()
    assert wait_until(lambda: heard_from_a() >= before + 3, 10.0), "a's probes stopped"
    assert b.peers["a"].holds == "", "a hold that failed counts as one"
    assert capsys.readouterr().err.count("ZeroDivisionError") == 1, "said once"
