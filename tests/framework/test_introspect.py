"""Spec: the introspection API lists containers, components, states, ports and connections."""

from components.demo import Counter, Doubler, Sink
from framework.activity import Activity
from framework.container import Container
from framework.introspect import containers, snapshot
from tests.conftest import wait_until


def test_snapshot_lists_everything_and_derives_connections(hub, peer):
    left, right = Container("left", hub), Container("right", peer)
    left.add(Counter("cnt"), Activity.periodic(50))
    right.add(Doubler("dbl"), Activity.event("inp"))
    right.add(Sink("snk"))
    right.connect("dbl", "inp", "cnt/out")
    # the other session's declarations reach the hub's session a moment later (a busy
    # host: after the first query): introspection sees what has arrived
    expected = {"left": ["cnt"], "right": ["dbl", "snk"]}
    assert wait_until(lambda: containers(hub) == expected, timeout=10), containers(hub)
    snap = snapshot(hub)
    assert snap.components["dbl"]["state"] == "PreOperational"
    assert snap.components["snk"]["inputs"][0]["policy"]["type"] == "buffer"
    wired = {c.key: (c.writers, c.readers) for c in snap.connections}
    assert wired["cnt/out"] == (["cnt.out"], ["dbl.inp"])
    assert wired["dbl/out"] == (["dbl.out"], [])
    assert snap.unreachable == []
    right.shutdown()
    left.shutdown()
