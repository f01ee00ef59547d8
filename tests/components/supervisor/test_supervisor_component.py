"""Spec: the Supervisor believes only plausible samples. A distance that is not a number
is taken as contact (the reflex halts), a Sensor Manager decision that cannot be read is
taken as no tracker (e_NOTRACKER and the reflex), other garbage is refused and ignored;
every refusal is said on fw/refused/supervisor, and the Supervisor keeps running."""

import math

import pytest

from components.supervisor.supervisor import Supervisor
from framework import keys, messages
from framework.activity import Activity, SteppedExecutor
from framework.clock import SimulatedClock
from framework.container import Container
from framework.messages import EventMessage, Pose, Scalar
from framework.ports import OutputPort
from tests.conftest import REPO, wait_until

PROCEDURE = REPO / "procedures" / "seeg.yaml"


class Rig:
    """A Supervisor in a container on the test's bus, fed by the test's output ports;
    what it emits, halts and refuses is collected by another session (`peer`), as the
    Coordinator and the interpolator would receive it."""

    def __init__(self, hub, peer):
        self.hub = hub
        self.container = Container("c", hub, SteppedExecutor(SimulatedClock()))
        self.supervisor = self.container.add(Supervisor("supervisor"), Activity())
        self.supervisor.set_property("procedure_file", str(PROCEDURE))
        self.writers = {}
        for port, kind in [
            ("tracking", EventMessage),
            ("tcp", Pose),
            ("users_near", Scalar),
            ("min_distance", Scalar),
        ]:
            writer = OutputPort(port, kind)
            writer.owner, writer.bus = "test", hub
            writer.connect(f"test/{port}")
            self.container.connect("supervisor", port, f"test/{port}")
            self.writers[port] = writer
        self.events, self.halts, self.refused = [], [], []
        self.probed = set()
        self._subs = [
            peer.subscribe("supervisor/events", self._collect(self.events)),
            peer.subscribe("supervisor/halt", self._collect(self.halts)),
            peer.subscribe(keys.refused("supervisor"), self._collect(self.refused)),
        ]
        assert peer.wait_for_peers(1)
        self._routed(hub, ["supervisor/events", "supervisor/halt", keys.refused("supervisor")])
        assert self.supervisor.configure() and self.supervisor.start()

    def _routed(self, hub, keys_):
        """Wait until a probe put on each key reaches the collecting session (a
        subscription is routed a little after it is declared); probes are not collected."""
        probe = messages.encode(EventMessage(0.0, "probe", "test", {}), EventMessage)
        for key in keys_:
            publisher = hub.publisher(key, cache=False)
            assert wait_until(lambda p=publisher, k=key: p.put(probe) or k in self.probed, 10)
            publisher.undeclare()

    def _collect(self, into):
        def on(sample):
            message, _, _ = messages.decode(sample.payload.to_bytes(), EventMessage)
            if message.name == "probe":
                self.probed.add(str(sample.key_expr))
            else:
                into.append(message)

        return on

    def feed(self, port, value):
        """Write one sample and let the Supervisor take it (its update, once it arrived)."""
        port_in = self.supervisor.inputs[port]
        before = port_in.stats.received
        self.writers[port].write(value)
        assert wait_until(lambda: port_in.stats.received > before)
        self.supervisor.update_hook()

    def close(self):
        for sub in self._subs:
            sub.undeclare()
        self.container.shutdown()


@pytest.fixture
def rig(hub, peer):
    rig = Rig(hub, peer)
    yield rig
    rig.close()


def refusals(rig, port):
    assert wait_until(lambda: any(r.payload["port"] == port for r in rig.refused), 10), port
    return [r.payload["reason"] for r in rig.refused if r.payload["port"] == port]


def test_a_distance_that_is_not_a_number_is_taken_as_contact(rig):
    rig.feed("min_distance", Scalar(0.0, 2.0))
    assert not rig.halts
    rig.feed("min_distance", Scalar(0.0, math.nan))
    assert wait_until(lambda: rig.halts), "the reflex halted the interpolator"
    assert rig.halts[0].payload["reason"].startswith("possible collision")
    assert wait_until(lambda: any(e.name == "e_STOP" for e in rig.events))
    assert "taken as contact" in refusals(rig, "min_distance")[0]


@pytest.mark.parametrize(
    "decision, why",
    [
        ({"best": 42, "health": {}}, "not a sensor name"),
        ({"best": "certus", "health": ["ok"]}, "not a table of sensors"),
        ({"best": "certus", "health": {}, "limits": {"velocity": "fast"}}, "positive number"),
        ({"best": "certus", "health": {}, "limits": {"velocity": -1.0}}, "positive number"),
    ],
)
def test_a_decision_that_cannot_be_believed_is_taken_as_no_tracker(rig, decision, why):
    rig.supervisor.call("use_tracker", tracker="certus")
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", decision))
    assert wait_until(lambda: any(e.name == "e_NOTRACKER" for e in rig.events))
    assert wait_until(lambda: rig.halts), "the reflex halted the interpolator too"
    assert why in refusals(rig, "tracking")[0]
    assert rig.supervisor.call("report")["best"] is None


def test_a_believable_decision_is_taken(rig):
    rig.supervisor.call("use_tracker", tracker="certus")
    decision = {"best": "vicra", "health": {"certus": {"cause": "stale"}}, "limits": {"v": 0.1}}
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", decision))
    assert wait_until(lambda: any(e.name == "e_TFAULT" for e in rig.events))
    assert not rig.refused


def test_an_impossible_people_count_or_tcp_is_refused_and_the_supervisor_runs_on(rig):
    rig.feed("users_near", Scalar(0.0, math.nan))
    rig.feed("users_near", Scalar(0.0, -3.0))
    rig.feed("tcp", Pose(position=(math.nan, 0.0, 0.5), valid=True))
    assert "people count of nan" in refusals(rig, "users_near")[0]
    assert "not finite" in refusals(rig, "tcp")[0]
    assert rig.supervisor.state.value == "Running"
    assert rig.supervisor.call("report")["users_near"] == 0
    assert rig.supervisor.core.tcp is None
