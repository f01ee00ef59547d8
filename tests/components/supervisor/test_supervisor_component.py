"""Spec: the Supervisor believes only plausible samples. A distance that is not a number
is taken as contact (the reflex halts), a Sensor Manager decision that cannot be read is
taken as no tracker (e_NOTRACKER and the reflex), other garbage is refused and ignored;
every refusal is said on fw/refused/supervisor, and the Supervisor keeps running. The
navigator's news (who steers, where the goals are, a refused patient motion) becomes
limits and events."""

import math

import pytest

from components.supervisor.supervisor import Supervisor
from framework import keys, messages
from framework.activity import Activity, SteppedExecutor
from framework.clock import SimulatedClock
from framework.container import Container
from framework.messages import EventMessage, Pose, Scalar
from tests.conftest import REPO, wait_until, writer_port

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
            ("motion", EventMessage),
            ("navigation", EventMessage),
            ("robot", EventMessage),
        ]:
            self.writers[port] = writer_port(hub, f"test/{port}", kind)
            self.container.connect("supervisor", port, f"test/{port}")
        self.events, self.halts, self.refused, self.limits = [], [], [], []
        self.probed = set()
        self._subs = [
            peer.subscribe("supervisor/events", self._collect(self.events)),
            peer.subscribe("supervisor/halt", self._collect(self.halts)),
            peer.subscribe(keys.refused("supervisor"), self._collect(self.refused)),
            peer.subscribe("supervisor/limits", self._collect(self.limits)),
        ]
        assert peer.wait_for_peers(1)
        self._routed(
            hub,
            [
                "supervisor/events",
                "supervisor/halt",
                keys.refused("supervisor"),
                "supervisor/limits",
            ],
        )
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

    def steer(self, tracker, target=(0.6, 0.0, 0.12), refused=""):
        """The navigator says `tracker` steers and where the target is now."""
        goals = {"target": [*target, 0.0, 1.0, 0.0, 0.0], "home": [0.54, 0.0, 0.37, 0, 1, 0, 0]}
        payload = {"goals": goals, "tracker": tracker, "refused": refused}
        self.feed("navigation", EventMessage(0.0, "goals", "navigator", payload))

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
    rig.steer("certus")
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", decision))
    assert wait_until(lambda: any(e.name == "e_NOTRACKER" for e in rig.events))
    assert wait_until(lambda: rig.halts), "the reflex halted the interpolator too"
    assert why in refusals(rig, "tracking")[0]
    assert rig.supervisor.call("report")["best"] is None


def test_a_believable_decision_is_taken(rig):
    rig.steer("certus")
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


def emitted(rig, name):
    assert wait_until(lambda: any(e.name == name for e in rig.events), 10), name
    return [e.payload for e in rig.events if e.name == name]


def test_the_tcp_alone_moves_the_area_and_the_report_says_where_things_are(rig):
    target = [0.6, 0.0, 0.12]
    report = rig.supervisor.call("report")
    assert report["area"] is None and report["min_distance"] is None
    assert report["target"] is None, "on the patient: nowhere until the navigator says"
    rig.steer(None)
    report = rig.supervisor.call("report")
    assert report["target"] == target and report["steering"] is None
    rig.feed("tcp", Pose(position=(0.6, 0.0, 0.12 + 0.2), valid=True))
    assert emitted(rig, "e_SAFE_AREA") == [{"distance": 0.2}]
    rig.feed("tcp", Pose(position=(0.6, 0.0, 0.12 + 0.01), valid=True))
    assert emitted(rig, "e_CRITICAL_AREA")[0]["why"] == "near the target"
    rig.feed("min_distance", Scalar(0.0, 1.25))
    report = rig.supervisor.call("report")
    assert report["area"] == "critical" and report["min_distance"] == 1.25
    assert report["in_collision"] is False


def test_a_negative_people_count_however_small_is_not_taken(rig):
    rig.feed("users_near", Scalar(0.0, 2.0))
    rig.feed("users_near", Scalar(0.0, -0.5))
    assert rig.supervisor.call("report")["users_near"] == 2


def test_a_people_count_back_to_zero_is_taken(rig):
    rig.steer(None)  # where the target is
    rig.feed("tcp", Pose(position=(0.6, 0.0, 0.5), valid=True))
    rig.feed("users_near", Scalar(0.0, 3.0))
    assert emitted(rig, "e_CRITICAL_AREA")[0]["why"] == "crowded"
    rig.feed("users_near", Scalar(0.0, 0.0))
    assert emitted(rig, "e_SAFE_AREA")
    assert rig.supervisor.call("report")["users_near"] == 0 and not rig.refused


def test_a_distance_that_is_not_a_number_is_reported_as_contact(rig):
    rig.feed("min_distance", Scalar(0.0, math.nan))
    (stop,) = emitted(rig, "e_STOP")
    assert stop["reason"] == "possible collision: robot 0.0 cm from a person (limit 10 cm)"


def test_motion_changes_reach_the_supervisor_arrival_and_collision(rig):
    rig.steer(None)  # where the target is
    rig.feed("tcp", Pose(position=(0.6, 0.0, 0.12), valid=True))
    rig.feed("motion", EventMessage(0.0, "reached", "interpolator", {"goal": "target"}))
    assert emitted(rig, "e_TARGET") == [{"goal": "target"}]
    rig.feed("min_distance", Scalar(0.0, 0.01))
    assert len(emitted(rig, "e_STOP")) == 1
    rig.feed("motion", EventMessage(0.0, "moving", "interpolator", {"goal": "home"}))
    assert wait_until(lambda: len([e for e in rig.events if e.name == "e_STOP"]) == 2)
    report = rig.supervisor.call("report")
    assert (report["phase"], report["goal"]) == ("moving", "home")


def test_a_latched_robot_stop_reaches_the_chart_and_halts(rig):
    status = {"braked": True, "fault": True, "reason": "monitor tripped"}
    rig.feed("robot", EventMessage(0.0, "status", "robot", status))
    assert emitted(rig, "e_STOP") == [{"reason": "robot braked: monitor tripped"}]
    assert wait_until(lambda: rig.halts)
    assert rig.halts[0].payload == {"reason": "robot braked: monitor tripped"}


def test_all_trackers_lost_halts_the_interpolator_before_the_chart_hears_it(rig):
    rig.steer("certus")
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", {"best": None}))
    assert emitted(rig, "e_NOTRACKER") == [{"why": "the Sensor Manager has not said"}]
    assert wait_until(lambda: rig.halts)
    assert rig.halts[0].payload == {"reason": "no tracker sees the robot"}


def test_the_best_tracker_is_reported_as_an_event_when_asked(rig):
    assert rig.supervisor.call("report_best_tracker") == "e_NOTRACKER"
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", {"best": "vicra"}))
    assert rig.supervisor.call("report_best_tracker") == "e_TOK"
    assert emitted(rig, "e_TOK") == [{"tracker": "vicra"}]


def test_speed_changes_send_the_interpolator_its_limits(rig):
    rig.steer("vicra")
    assert rig.supervisor.call("change_movement_parameters", speed="fast") == {
        "velocity": 0.05,
        "acceleration": 0.25,
    }
    assert wait_until(lambda: rig.limits)
    rig.steer("certus")  # a swap: the new tracker's limits, without the chart asking
    assert wait_until(lambda: len(rig.limits) == 2)
    assert rig.limits[1].payload == {"velocity": 0.075, "acceleration": 0.25}
    rig.steer("certus", target=(0.5, 0.1, 0.123456))
    assert rig.supervisor.call("report")["target"] == [0.5, 0.1, 0.1235]
    rig.steer("vicra")  # the same tracker in new news sent nothing; this swap does
    assert wait_until(lambda: len(rig.limits) >= 3)
    assert [m.payload["velocity"] for m in rig.limits] == [0.05, 0.075, 0.05]


def test_a_refused_patient_motion_halts_the_interpolator_and_reaches_the_chart(rig):
    rig.steer("certus", refused="the patient moved 12.0 mm from where it was registered")
    assert emitted(rig, "e_PATIENT_MOVED") == [
        {"reason": "the patient moved 12.0 mm from where it was registered"}
    ]
    assert wait_until(lambda: rig.halts)
    assert rig.halts[0].payload["reason"].startswith("the patient moved 12.0 mm")
    assert rig.supervisor.call("report")["patient_refused"].startswith("the patient moved")


@pytest.mark.parametrize(
    "payload, why",
    [
        ({"goals": {"target": [0.6, "up", 0.1]}, "tracker": "certus"}, "could not convert"),
        ({"goals": {"target": [0.6, 0.1]}, "tracker": "certus"}, "finite position"),
        ({"goals": {}, "tracker": 7}, "not a name"),
        ({"goals": {}, "tracker": ""}, "not a name"),
        ({"goals": {}, "tracker": "x" * 65}, f"tracker {'x' * 40!r} is not a name"),
        ({"goals": {"y" * 99: [0.6, 0.1]}, "tracker": "certus"}, f"goal {'y' * 40!r} is not"),
        ({"tracker": "certus"}, "goals"),
    ],
)
def test_navigator_news_that_cannot_be_believed_is_refused(rig, payload, why):
    rig.feed("navigation", EventMessage(0.0, "goals", "navigator", payload))
    assert why in refusals(rig, "navigation")[0]
    assert rig.supervisor.core.in_use is None and rig.supervisor.state.value == "Running"


@pytest.mark.parametrize("name", ["v", "x" * 64])
def test_a_tracker_named_with_one_to_64_characters_is_believed(rig, name):
    rig.steer(name)
    assert rig.supervisor.core.in_use == name and not rig.refused


def test_operators_tools_may_only_ask_for_reports():
    from framework.topology import class_info

    info = class_info(Supervisor)
    assert "report" in info.readonly
    assert {"report_best_tracker", "change_movement_parameters"}.isdisjoint(info.readonly)
    assert {"report_best_tracker", "change_movement_parameters", "report"} == set(info.operations)


def test_a_supervisor_without_a_readable_procedure_does_not_configure(hub, tmp_path):
    container = Container("c", hub, SteppedExecutor(SimulatedClock()))
    try:
        missing = container.add(Supervisor("missing"), Activity())
        assert not missing.configure()
        assert "procedure_file" in missing.last_error
        broken = container.add(Supervisor("broken"), Activity())
        bad = tmp_path / "seeg.yaml"
        bad.write_text("procedure: seeg\ntarget: [1, 2\n", encoding="utf-8")
        broken.set_property("procedure_file", str(bad))
        assert not broken.configure()
        assert "seeg.yaml" in broken.last_error
    finally:
        container.shutdown()


def test_the_sensor_managers_limits_for_the_tracker_in_use_cap_the_speeds_sent(rig):
    """The Sensor Manager says how fast its tracker may be followed: the limits the
    interpolator is sent never exceed them, whatever the procedure allows."""
    rig.steer("certus")
    decision = {"best": "certus", "health": {}, "limits": {"max_velocity": 0.01}}
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", decision))
    assert rig.supervisor.call("change_movement_parameters", speed="fast")["velocity"] == 0.01


def test_a_tracker_fault_reaches_the_chart_with_the_sensor_managers_cause(rig):
    rig.steer("certus")
    decision = {"best": "vicra", "health": {"certus": {"cause": "stale"}}}
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", decision))
    assert wait_until(lambda: any(e.name == "e_TFAULT" for e in rig.events))
    (fault,) = [e for e in rig.events if e.name == "e_TFAULT"]
    assert fault.payload == {
        "tracker": "vicra",
        "failed": "certus",
        "fault": "stale",
        "detail": "",
        "numbers": {},
    }


def test_a_decision_without_limits_for_its_tracker_lifts_the_earlier_ones(rig):
    rig.steer("certus")
    capped = {"best": "certus", "health": {}, "limits": {"max_velocity": 0.01}}
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", capped))
    lifted = {"best": "certus", "health": {}, "limits": {}}
    rig.feed("tracking", EventMessage(0.0, "decision", "sensor_manager", lifted))
    assert rig.supervisor.call("change_movement_parameters", speed="fast")["velocity"] == 0.075
