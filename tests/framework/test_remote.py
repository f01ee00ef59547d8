"""Specs of `RemoteComponent.request` on a real bus: what a caller sees when nobody
hosts the component, and when its process is alive but the bus has no route to its
requests yet (as just after a partition heals: Zenoh declares liveliness tokens before
queryables on a new link, eclipse-zenoh/zenoh#588, and a peer's link closing can leave
other routes unmade for seconds, #2517)."""

from __future__ import annotations

import json
import threading
import time

import pytest

from framework import keys
from framework.remote import RemoteComponent, RemoteError


def answer(peer, component: str):
    """Declare `component`'s `state` request on `peer`, as its container would."""

    def reply(query):
        query.reply(query.key_expr, json.dumps({"result": {"state": "Running"}}).encode())

    return peer.queryable(keys.control_request(component, "state"), reply)


def seen_alive(hub, component: str, timeout: float = 10.0) -> bool:
    """Wait until `hub` sees `component`'s liveliness token (tokens travel asynchronously)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if hub.alive(keys.alive(component), timeout=1.0):
            return True
        time.sleep(0.01)
    return False


def test_a_component_nobody_hosts_is_said_so_without_waiting_out_the_timeout(hub):
    with pytest.raises(RemoteError, match="nothing on the bus takes it"):
        RemoteComponent(hub, "nobody").request("state", timeout=30.0)


def test_a_component_alive_whose_requests_have_no_route_yet_is_asked_again(hub, peer):
    """Its liveliness token is on the bus first, its queryable 0.3 s later: the request
    (5 s to answer) gets the answer instead of "nothing on the bus takes it"."""
    token = peer.token(keys.alive("late"))
    assert seen_alive(hub, "late"), "the hub never saw the token (the spec's premise)"
    declared = []
    timer = threading.Timer(0.3, lambda: declared.append(answer(peer, "late")))
    timer.start()
    try:
        assert RemoteComponent(hub, "late").request("state", timeout=5.0) == {"state": "Running"}
    finally:
        timer.join()
        for queryable in declared:
            queryable.undeclare()
        token.undeclare()


def test_a_component_alive_that_never_takes_requests_fails_by_its_deadline(hub, peer):
    """Alive but never answering (a route that never comes): the caller learns it by
    the request's deadline, with the same words as for a component nobody hosts."""
    token = peer.token(keys.alive("mute"))
    try:
        with pytest.raises(RemoteError, match="nothing on the bus takes it"):
            RemoteComponent(hub, "mute").request("state", timeout=0.5)
    finally:
        token.undeclare()
