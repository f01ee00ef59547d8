"""Spec: the robot interface, cycle by cycle. The test plays the arm's controller (a
measured state per cycle) and the interpolator (setpoints), and reads what the interface
commands and asks of the arm: a setpoint no arm could follow, a silent interpolator or
the controller's own brake trip a protective stop that latches; only acknowledge (the
operator's RELEASE) opens it."""

import math
import socket
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain import fri
from components.domain.lwr4 import Kinematics
from components.robot.interface import (
    FIRST_STEP_CYCLES,
    MAX_STEP_RAD,
    POSITION_LIMIT_RAD,
    STEP_MARGIN,
    RobotInterface,
    parse_address,
    tcp_message,
)
from framework.activity import Activity, SteppedExecutor
from framework.bus import free_udp_port
from framework.clock import SimulatedClock
from framework.container import Container
from framework.errors import FwError
from framework.messages import ArmState, EventMessage, JointState, Pose
from framework.ports import ReadStatus
from tests.conftest import drained, kernel_stamps_arrivals, reader_port, writer_port

HOME = np.array([0.0, 0.5, 0.0, -1.2, 0.0, 0.6, 0.0])


@dataclass
class Request:
    """A request the interface sent the KRC in a command's KRL data (fw's convention)."""

    name: str
    payload: dict


REQUESTS = {
    fri.Request.BRAKE: ("brake", {"latch": False}),
    fri.Request.BRAKE_LATCHED: ("brake", {"latch": True}),
    fri.Request.RELEASE: ("release", {}),
    fri.Request.RESET: ("reset", {}),
    fri.Request.MODE_POSITION: ("mode", {"mode": "position"}),
    fri.Request.MODE_IMPEDANCE: ("mode", {"mode": "impedance"}),
}


class Arm:
    """The interface in a stepped container, paced by the test playing the KRC over real
    UDP (FRI datagrams on loopback are there to read at once); the interpolator's
    setpoints on a port of the same session, so every sample is delivered before
    `cycle` returns."""

    def __init__(self, hub, safety=None):
        self.clock = SimulatedClock()
        self.container = Container("c", hub, SteppedExecutor(self.clock))
        self.krc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.krc.bind(("127.0.0.1", 0))
        self.krc.setblocking(False)
        self.port = free_udp_port()
        krc = f"127.0.0.1:{self.krc.getsockname()[1]}"
        self.robot = self.container.add(
            RobotInterface("robot"),
            Activity.paced(0.02),
            properties={"fri_listen": f"127.0.0.1:{self.port}", "krc": krc},
            safety=safety,
        )
        self.container.connect("robot", "setpoint", "interpolator/setpoint")
        self.writers = {"setpoint": writer_port(hub, "interpolator/setpoint", JointState)}
        self.readers = {
            name: reader_port(hub, f"robot/{name}", kind)
            for name, kind in [
                ("joints", JointState),
                ("tcp", Pose),
                ("status", EventMessage),
            ]
        }
        self.container.start()
        assert self.robot.configure() and self.robot.start()
        self.cycle_no = 0
        self.served = 0
        self.q = HOME.copy()
        self.v = np.zeros(7)  # the arm drifts at this speed (rad/s) from cycle to cycle
        self.braked = True
        self.latched = False
        self.reason = ""
        self.commanded = HOME.copy()  # the KRC's commanded position (cmdJntPos)
        self.serving = True  # the KRC serves each request at once (a test may hold them)
        self.taken = 0  # the number of the last request the KRC took
        self.commands: list[np.ndarray] = []
        """New commanded positions the interface sent while the arm was released."""
        self.answers: list[fri.Command] = []
        self._requests: list[Request] = []
        self.refusals: list = []
        self.robot.add_refusal_listener(self.refusals.append)

    @property
    def requests(self) -> list[Request]:
        """What the interface asked of the arm so far (brake, release, reset, mode)."""
        return self._requests

    def measure(self, **state):
        """Send the KRC's measurement of this cycle (its fields from `state` or the arm)."""
        self.cycle_no += 1
        braked = state.get("braked", self.braked)
        reason = state.get("reason", self.reason)
        datagram = fri.encode_measurement(
            self.cycle_no,
            0,
            timestamp=self.cycle_no * 0.001,
            state=fri.State.MON if braked else fri.State.CMD,
            quality=fri.Quality.PERFECT,
            msr_jnt_pos=tuple(self.q),
            cmd_jnt_pos=tuple(self.q if braked else self.commanded),
            served=state.get("served", self.served),
            reason=fri.reason_code(reason) if braked else 0,
            cycle=self.cycle_no,
            braked=braked,
            latched=state.get("latched", self.latched),
        )
        self.krc.sendto(datagram, ("127.0.0.1", self.port))
        return braked

    def cycle(self, setpoint=None, **state):
        """One KRC cycle: maybe a setpoint from the interpolator, then the KRC's
        measurement; the loop runs it (read, update, write) and its answer is taken."""
        if setpoint is not None:
            self.writers["setpoint"].write(JointState(0.0, tuple(float(v) for v in setpoint)))
        self.q = self.q + self.v * 0.001
        braked = self.measure(**state)
        self.container.executor.run_pending()
        self._collect(braked)

    def _collect(self, braked):
        while True:
            try:
                data = self.krc.recv(2048)
            except BlockingIOError:
                return
            answer = fri.decode_command(data)
            self.answers.append(answer)
            q = np.array(answer.jnt_pos)
            if not braked and not np.allclose(q, self.commanded, atol=1e-6):
                self.commands.append(q)
                self.commanded = q
            if answer.request_number > self.taken and answer.request != fri.Request.NONE:
                self.taken = answer.request_number  # the KRC takes each number once
                name, payload = REQUESTS[fri.Request(answer.request)]
                self._requests.append(Request(name, payload))
                if self.serving:
                    self.served = answer.request_number  # the KRC serves it at once

    def released(self):
        """The brakes are off, as the controller reports after a release."""
        self.braked = False
        self.served = self.taken
        self.commanded = self.q.copy()

    def follow(self, q):
        """The arm follows a command exactly (what the measurement says next)."""
        self.q = np.asarray(q, dtype=float)
        self.v = np.zeros(7)

    def names(self):
        return [r.name for r in self.requests]

    def report(self):
        return self.robot.call("report")

    def close(self):
        self.container.shutdown()
        self.krc.close()


@pytest.fixture(params=["kernel", "python"])
def arm(hub, request, monkeypatch):
    """The interface with fw's compiled kernel, and again with its Python references
    (where the kernel is not built): every spec holds for both paths."""
    if request.param == "python":
        from components.robot import interface

        monkeypatch.setattr(interface, "_fwkernel", None)
    arm = Arm(hub)
    yield arm
    arm.close()


STILL_CYCLES = 50  # 50 ms under 2 mrad/s on every joint: the arm stands still
STILL_TIMEOUT_CYCLES = 2000  # brake when still gives up waiting after 2 s


def step(fraction, joint=2, cycles=1):
    """A setpoint `fraction` of the rated velocity away on `joint` over `cycles`."""
    out = np.zeros(7)
    out[joint] = fraction * MAX_STEP_RAD[joint] * cycles
    return out


def moving(arm, cycles=3):
    """Released, commanding: a few small steps the arm follows."""
    arm.cycle()
    arm.released()
    for _ in range(cycles):
        target = arm.q + step(0.5)
        arm.cycle(target)
        arm.follow(target)
    return arm.q.copy()


def test_every_measured_state_is_answered_with_the_latest_setpoint(arm):
    arm.cycle(HOME + step(1.0))
    assert arm.commands == [], "braked: nothing reaches the arm"
    arm.released()
    target = HOME + step(0.5)
    arm.cycle(target)
    assert len(arm.commands) == 1 and np.allclose(arm.commands[0], target)
    status, joints = arm.readers["joints"].read()
    assert status is ReadStatus.NEW and np.allclose(joints.position, HOME)
    status, tcp = arm.readers["tcp"].read()
    expected = tcp_message(Kinematics().tcp(HOME), 0.0)
    assert status is ReadStatus.NEW
    assert tcp.position == pytest.approx(expected.position, abs=1e-6)  # FRI sends float32
    assert tcp.orientation == pytest.approx(expected.orientation, abs=1e-6)
    assert (tcp.rms, tcp.frame_number, tcp.valid, tcp.frame, tcp.tool) == (
        0.0,
        0,
        True,
        "base",
        "tcp",
    )


def test_each_answer_counts_on_by_one_and_reflects_the_measurement_it_answers(arm):
    """FRI's sequence counters: the PC's own rises by one per command from 1, and each
    command reflects the counter of the measurement it answers (the KRC rates late
    answers by it)."""
    for _ in range(5):
        arm.cycle()
    assert [a.send_seq for a in arm.answers] == [1, 2, 3, 4, 5]
    assert [a.refl_seq for a in arm.answers] == [1, 2, 3, 4, 5]


def test_a_request_is_carried_by_every_answer_until_the_measurement_says_it_is_served(arm):
    """UDP may lose the answer that carried it: the KRC takes each number once."""
    arm.serving = False
    arm.robot.call("brake", reason="operator")
    for _ in range(3):
        arm.cycle()
    brake = fri.Request.BRAKE
    assert [(a.request_number, a.request) for a in arm.answers] == [(1, brake)] * 3
    arm.cycle(served=1)
    arm.cycle(served=1)
    assert [(a.request_number, a.request) for a in arm.answers[3:]] == [(1, fri.Request.NONE)] * 2


def test_an_interface_beside_a_krc_that_served_requests_numbers_on_from_them(arm):
    """A KRC outlives the PC's process (a restart, `on_loss: restart`): a new interface
    numbering from 1 again would have each request taken for one already served."""
    arm.cycle(served=7)
    arm.robot.call("brake", reason="operator")
    arm.cycle(served=7)
    assert (arm.answers[-1].request_number, arm.answers[-1].request) == (8, fri.Request.BRAKE)


def test_the_first_setpoint_of_a_motion_may_be_ten_cycles_of_rated_velocity_away(arm):
    arm.cycle()
    arm.released()
    arm.cycle(HOME + step(STEP_MARGIN * 0.99, cycles=FIRST_STEP_CYCLES))
    assert arm.commands and not arm.report()["latched"]
    assert arm.report()["peak_step"] == pytest.approx(STEP_MARGIN * 0.99, abs=1e-3)


def test_a_first_setpoint_further_away_trips(arm):
    arm.cycle()
    arm.released()
    arm.cycle(HOME + step(STEP_MARGIN * 1.02, joint=4, cycles=FIRST_STEP_CYCLES))
    report = arm.report()
    assert report["latched"] and not arm.commands
    assert report["reason"] == (
        "setpoint refused: A5 would move "
        f"{math.degrees(STEP_MARGIN * 1.02 * MAX_STEP_RAD[4] * 10):.2f} deg in 10 cycle(s), "
        "1.5x its rated velocity"
    )
    assert arm.requests[-1].name == "brake" and arm.requests[-1].payload["latch"] is True
    assert report["peak_step"] == pytest.approx(STEP_MARGIN * 1.02, abs=1e-3), "seen, refused"


@pytest.mark.parametrize(("fraction", "trips"), [(1.45, False), (1.55, True)])
def test_each_later_step_may_be_one_and_a_half_rated_velocities(arm, fraction, trips):
    last = moving(arm)
    assert arm.report()["peak_step"] == 0.5, "so far half the rated velocity at most"
    arm.cycle(last + step(fraction, joint=0))
    assert arm.report()["latched"] == trips


def test_a_cycle_without_a_setpoint_allows_a_longer_next_step(arm):
    last = moving(arm)
    arm.cycle()  # the interpolator missed one cycle
    arm.cycle(last + step(1.4, joint=1, cycles=2))
    assert not arm.report()["latched"], "2.8 rated steps over 2 cycles"
    arm.follow(arm.commands[-1])
    arm.cycle(arm.q + step(1.6, joint=1))
    assert "in 1 cycle(s), 1.6x" in arm.report()["reason"]


@pytest.mark.parametrize(
    ("setpoint", "why"),
    [
        (HOME[:6], "not 7 finite joint positions: [0.0, 0.5, 0.0, -1.2, 0.0, 0.6]"),
        (np.append(HOME, 0.0), "not 7 finite joint positions"),
        (np.where(np.arange(7) == 3, np.nan, HOME), "not 7 finite joint positions"),
        (np.where(np.arange(7) == 1, POSITION_LIMIT_RAD[1] + 0.01, HOME), "A2 at 120.6 deg"),
        (np.where(np.arange(7) == 6, -POSITION_LIMIT_RAD[6] - 0.01, HOME), "A7 at -170.6 deg"),
    ],
)
def test_a_setpoint_no_arm_has_trips_and_is_never_sent(arm, setpoint, why):
    arm.cycle()
    arm.released()
    arm.cycle(setpoint)
    assert not arm.commands
    assert arm.report()["reason"].startswith(f"setpoint refused: {why}")


def test_a_joint_exactly_at_its_limit_is_allowed(arm):
    arm.q = np.where(np.arange(7) == 1, POSITION_LIMIT_RAD[1], HOME)
    arm.cycle()
    arm.released()
    arm.cycle(arm.q + step(0.1, joint=2))
    assert arm.commands and not arm.report()["latched"]


def test_a_silent_interpolator_trips_after_its_cycles_and_the_arm_stops_on_its_path(arm):
    last = moving(arm)
    for _ in range(5):
        arm.cycle()
    assert not arm.report()["latched"], "5 silent cycles are tolerated"
    arm.cycle()
    report = arm.report()
    assert report["reason"] == "no setpoint for 5 cycles (the interpolator stopped)"
    assert report["stopping"], "the interface decelerates the arm itself"
    sent = len(arm.commands)
    for _ in range(200):
        arm.follow(arm.commands[-1])
        arm.cycle()
    stop = arm.commands[sent - 1 :]
    assert len(stop) > 2, "commanded to a stop over several cycles"
    deltas = np.diff(np.array(stop)[:, 2])
    assert np.all(deltas >= -1e-12) and deltas[-1] < deltas[0] / 100
    assert np.all(np.diff(deltas) <= 1e-12), "slowing down, never speeding up"
    assert arm.commands[-1][2] > last[2], "carried on the way it went"
    assert arm.names()[-1] == "brake" and arm.requests[-1].payload == {"latch": True}


def test_the_controllers_own_brake_latches_the_interface_once_it_is_not_ours(arm):
    moving(arm)
    arm.serving = False  # the KRC has not served the brake it is asked for yet
    arm.robot.call("brake", reason="holding")
    arm.cycle(arm.q, braked=True, latched=True, reason=fri.REASONS[3], served=arm.served)
    assert not arm.report()["latched"], "our own request, not yet served: not a fault"
    arm.cycle(arm.q, braked=True, latched=True, reason=fri.REASONS[3], served=len(arm.requests))
    assert arm.report()["reason"] == f"the arm braked by itself: {fri.REASONS[3]}"


def test_a_krc_latched_by_an_earlier_interfaces_safety_stop_says_so(arm):
    """The KRC outlived the PC's process: latched by the safety stop a former interface
    asked for (code 6), with nothing latched here, the trip says that reason."""
    arm.cycle(braked=True, latched=True, reason=fri.REASONS[6])
    assert arm.report()["reason"] == f"the arm braked by itself: {fri.REASONS[6]}"


def test_the_brake_this_side_asked_for_says_its_reason_and_the_krcs_own_says_its(arm):
    """Braked on this side's request (code 2): the reason given with the request; braked
    by the KRC for its own reason afterwards (power on, code 1): that reason, not the
    last request's."""
    arm.robot.call("brake", reason="operator")
    arm.cycle(braked=True, reason=fri.REASONS[2])
    assert arm.report()["reason"] == "operator"
    arm.cycle(braked=True, reason=fri.REASONS[1])
    assert arm.report()["reason"] == fri.REASONS[1]


def test_a_latched_stop_opens_only_with_acknowledge(arm):
    last = moving(arm)
    arm.cycle(last + step(5.0))
    assert arm.report()["latched"]
    with pytest.raises(FwError, match="safety stop latched"):
        arm.robot.call("release")
    for _ in range(300):
        arm.follow(arm.commands[-1])
        arm.cycle()
    arm.braked = True
    arm.cycle()
    arm.cycle(arm.q)
    assert arm.report()["latched"]
    assert arm.robot.call("acknowledge")["latched"] is False
    arm.cycle(arm.q)  # the reset goes out with the next answer
    assert arm.names()[-1] == "reset" and not arm.report()["latched"]
    assert arm.robot.call("release")["braked"] is True, "answers with the report"
    arm.cycle(arm.q)
    assert arm.names()[-1] == "release"


def test_acknowledge_waits_for_the_protective_stop_to_end(arm):
    last = moving(arm)
    arm.cycle(last + step(5.0))
    with pytest.raises(FwError, match="still under way"):
        arm.robot.call("acknowledge")


def test_a_trip_while_not_commanding_brakes_at_once(arm):
    arm.cycle()
    arm.released()
    arm.cycle(HOME + step(50.0))
    assert arm.names() == ["brake"] and not arm.report()["stopping"]


def test_brake_when_still_waits_until_the_arm_stands_still(arm):
    moving(arm)
    arm.v = np.full(7, 0.01)
    arm.robot.call("brake", reason="at goal", when_still=True)
    requests = len(arm.requests)
    for _ in range(10):
        arm.cycle(arm.q)
    assert len(arm.requests) == requests, "still moving"
    arm.v = np.full(7, 0.0019)
    for _ in range(STILL_CYCLES - 1):
        arm.cycle(arm.q)
    assert len(arm.requests) == requests, "not yet still long enough"
    arm.cycle(arm.q)
    assert arm.requests[-1].name == "brake"
    assert arm.requests[-1].payload == {"latch": False}
    arm.braked = True
    arm.cycle(arm.q, reason=fri.REASONS[2])  # the KRC: braked, as the interface asked
    assert arm.report()["reason"] == "at goal", "the words stay on this side"


def test_brake_when_still_gives_up_waiting_after_two_seconds(arm):
    moving(arm, cycles=15)  # asked at cycle 16: a deadline that shares bits with 2000
    arm.v = np.full(7, 0.05)
    arm.robot.call("brake", reason="at goal", when_still=True)
    requests = len(arm.requests)
    for _ in range(STILL_TIMEOUT_CYCLES - 1):
        arm.cycle(arm.q)
    assert len(arm.requests) == requests
    arm.cycle(arm.q)
    assert arm.names()[-1] == "brake" and len(arm.requests) == requests + 1


def test_brake_when_still_is_dropped_once_the_arm_is_braked(arm):
    moving(arm)
    arm.v = np.full(7, 0.05)
    arm.robot.call("brake", reason="at goal", when_still=True)
    requests = len(arm.requests)
    arm.braked = True
    arm.cycle(arm.q)
    arm.v = np.zeros(7)
    for _ in range(STILL_CYCLES + 5):
        arm.cycle(arm.q)
    assert len(arm.requests) == requests


def test_brake_and_release_without_a_latch_and_the_servo_mode(arm):
    """Requests travel in the answers' KRL data, one per answer, each once the one
    before was served; the KRC says a code, the words stay on this side."""
    arm.robot.call("brake", reason="waiting")
    answer = arm.robot.call("set_mode", mode="impedance")
    assert answer == arm.report()  # the caller reads where the robot stands in the answer
    arm.cycle()
    assert arm.requests[-1].payload == {"latch": False}
    arm.cycle(reason=fri.REASONS[2])
    assert arm.requests[-1].name == "mode" and arm.requests[-1].payload == {"mode": "impedance"}
    assert arm.report()["reason"] == "waiting"
    with pytest.raises(FwError, match="unknown mode 'torque'"):
        arm.robot.call("set_mode", mode="torque")
    arm.cycle()
    assert arm.report()["mode"] == "impedance"


def test_the_report_before_and_after_the_first_state(arm):
    assert arm.report() == {
        "braked": True,
        "latched": False,
        "fault": False,
        "reason": "no arm state",
    }
    with pytest.raises(FwError, match=r"not ready after 0\.05 s: no state from the arm"):
        arm.robot.call("await_ready", timeout=0.05)
    arm.q = HOME + 1e-7
    arm.cycle(reason=fri.REASONS[1])
    report = arm.report()
    assert report["q"] == [round(v, 5) for v in arm.q] and report["time"] == 0.001
    assert report["reason"] == "power on" and report["ready"] and not report["stopping"]
    assert report["fri"]["state"] == "MON" and report["fri"]["quality"] == "PERFECT"
    assert arm.robot.call("await_ready", timeout=0.05)["braked"]


def test_a_stopped_interface_answers_no_measurement(arm):
    """Stopped (or dead, or hung), the interface answers nothing: the KRC's quality falls
    and it brakes by itself within ten of its cycles, latched (FRI)."""
    moving(arm)
    answered = len(arm.answers)
    arm.robot.stop()
    for _ in range(3):
        arm.cycle()
    assert len(arm.answers) == answered


def test_a_monitor_trip_while_the_controller_is_silent_brakes_at_once(hub):
    """The arm's controller stops sending states mid-motion (no cycles left to stop on the
    path) and a watched input falls silent: the idle check trips and brakes, latched."""
    from framework.messages import Scalar
    from framework.safety import SafetySpec, Watch

    token = hub.token("fw/alive/tester")
    spec = SafetySpec("robot", (Watch("tester", "test/beat", 0.02, "tester"),), ("tester",))
    arm = Arm(hub, safety=spec)
    beat = writer_port(hub, "test/beat", Scalar, owner="tester")
    try:
        arm.cycle()
        arm.released()
        for i in range(20):  # moving, every input on time
            arm.clock.set(arm.clock.now() + 0.001)
            beat.write(Scalar(0.0, float(i)))
            target = arm.q + step(0.5)
            arm.cycle(target)
            arm.follow(target)
        assert arm.report()["safety"]["armed"] and not arm.report()["latched"]
        for _ in range(10):  # the controller and the heartbeat fall silent
            arm.clock.set(arm.clock.now() + 0.005)
            arm.robot.idle_hook()
        report = arm.report()
        assert report["latched"] and report["reason"].startswith("tester: no data for")
        assert not report["stopping"], "no cycles to stop on: the brakes at once"
        said = [s.payload for s in drained(arm.readers["status"])]
        assert said[-1]["latched"] and said[-1]["reason"] == report["reason"], "said at once"
        arm.cycle(arm.q)  # the KRC speaks again: the brake goes out with the answer
        assert arm.requests[-1].name == "brake" and arm.requests[-1].payload["latch"] is True
        with pytest.raises(FwError, match="safety stop latched"):
            arm.robot.call("release")
    finally:
        arm.close()
        token.undeclare()


def test_release_and_acknowledge_wait_for_every_watched_input(hub):
    from framework.safety import SafetySpec, Watch

    token = hub.token("fw/alive/tester")
    spec = SafetySpec("robot", (Watch("tester", "test/beat", 0.02, "tester"),), ("tester",))
    arm = Arm(hub, safety=spec)
    try:
        arm.cycle()
        with pytest.raises(FwError, match="tester: no data yet"):
            arm.robot.call("release")
        with pytest.raises(FwError, match="tester: no data yet"):
            arm.robot.call("acknowledge")
        with pytest.raises(FwError, match=r"not ready after 0\.05 s: .*tester: no data yet"):
            arm.robot.call("await_ready", timeout=0.05)
        assert arm.report()["problems"] == ["tester: no data yet"]
        assert arm.report()["safety"]["watches"]["tester"]["age_ms"] is None
    finally:
        arm.close()
        token.undeclare()


def test_updates_without_a_new_measured_state_are_not_cycles(arm):
    moving(arm)
    sent = len(arm.commands)
    for _ in range(20):  # woken with nothing new from the arm (another port, a spurious wake)
        arm.robot.update_hook()
    assert not arm.report()["latched"], "the interpolator is silent for 0 cycles, not 20"
    assert len(arm.commands) == sent, "nothing is sent without a state to answer"


class Watched:
    """An `Arm` whose safety monitor watches one heartbeat (20 ms), played by the test."""

    def __init__(self, hub):
        from framework.messages import Scalar
        from framework.safety import SafetySpec, Watch

        self.token = hub.token("fw/alive/tester")
        spec = SafetySpec("robot", (Watch("tester", "test/beat", 0.02, "tester"),), ("tester",))
        self.arm = Arm(hub, safety=spec)
        self.beat = writer_port(hub, "test/beat", Scalar, owner="tester")
        self.beats = 0

    def cycle(self, setpoint=None, beat=True, **state):
        """One millisecond: maybe a heartbeat, then a controller cycle."""
        from framework.messages import Scalar

        self.arm.clock.set(self.arm.clock.now() + 0.001)
        if beat:
            self.beats += 1
            self.beat.write(Scalar(0.0, float(self.beats)))
        self.arm.cycle(setpoint, **state)

    def close(self):
        self.arm.close()
        self.token.undeclare()


@pytest.fixture
def watched(hub):
    rig = Watched(hub)
    yield rig
    rig.close()


def watched_moving(watched):
    """Released with the heartbeat on time, five small steps the arm follows: the arm."""
    arm = watched.arm
    watched.cycle()
    arm.released()
    for _ in range(5):
        target = arm.q + step(0.5)
        watched.cycle(target)
        arm.follow(target)
    return arm


def test_a_late_input_only_holds_a_braked_arm(watched):
    for _ in range(5):
        watched.cycle()
    for _ in range(100):  # 100 ms without a heartbeat, the arm braked
        watched.cycle(beat=False)
    report = watched.arm.report()
    assert not report["latched"] and report["problems"][0].startswith("tester: no data for")
    with pytest.raises(FwError, match="tester: no data for"):
        watched.arm.robot.call("release")


def test_a_late_input_trips_a_released_arm_even_before_its_first_setpoint(watched):
    watched.cycle()
    watched.arm.released()
    for _ in range(5):
        watched.cycle()
    for _ in range(100):
        watched.cycle(beat=False)
    assert watched.arm.report()["reason"].startswith("tester: no data for")


def test_an_arm_braked_again_after_a_motion_is_held_not_tripped_by_a_late_input(watched):
    arm = watched_moving(watched)
    arm.robot.call("brake", reason="at goal")
    arm.braked, arm.served = True, arm.taken
    watched.cycle()
    for _ in range(100):
        watched.cycle(beat=False)
    assert not arm.report()["latched"]


def test_a_protective_stop_under_way_when_the_controller_falls_silent_brakes_at_once(arm):
    last = moving(arm)
    arm.cycle(last + step(5.0))  # trips: the interface starts decelerating the arm
    assert arm.report()["stopping"]
    requests = len(arm.requests)
    arm.robot.idle_hook()  # then no state from the controller for an idle period
    assert not arm.report()["stopping"]
    arm.cycle(arm.q)  # the request travels in the next answer (the KRC brakes anyway)
    assert arm.names()[requests:] == ["brake"] and arm.requests[-1].payload["latch"] is True


def test_a_protective_stop_under_way_when_the_controller_brakes_by_itself_answers_its_echo(arm):
    """Braked by the KRC in the middle of the interface's stop, the arm is in monitor
    mode: FRI demands the echo of its commanded position, not the stop's next step."""
    last = moving(arm)
    arm.cycle(last + step(5.0))  # trips: the interface starts decelerating the arm
    assert arm.report()["stopping"]
    stepping = np.array(arm.answers[-1].jnt_pos)
    arm.braked = True
    arm.cycle()
    assert not np.allclose(stepping, arm.q), "the stop's steps are not the echo"
    assert np.allclose(arm.answers[-1].jnt_pos, arm.q)


def test_an_interface_that_starts_beside_an_arm_its_controller_latched_latches_too(arm):
    arm.cycle(latched=True, reason=fri.REASONS[3], served=7)  # requests of a previous run
    assert arm.report()["reason"] == f"the arm braked by itself: {fri.REASONS[3]}"


def test_fewer_setpoint_cycles_set_while_the_interpolator_is_silent_trip_at_once(arm):
    moving(arm)
    for _ in range(3):
        arm.cycle()
    arm.robot.set_property("setpoint_cycles", 2)
    arm.cycle()
    assert arm.report()["reason"] == "no setpoint for 3 cycles (the interpolator stopped)"


def test_the_status_is_said_at_once_on_every_change_and_every_half_second(arm):
    def statuses():
        return drained(arm.readers["status"])

    arm.cycle()
    assert len(statuses()) == 1, "the first state is said at once"

    def ticks_to_next_status(step):
        for ticks in range(1, 1000):
            arm.clock.set(arm.clock.now() + step)
            arm.cycle()
            if statuses():
                return ticks
        return None

    for _ in range(4):
        assert ticks_to_next_status(1 / 256) == 128, "nothing changed: every half second"
    for _ in range(3):  # steps that never land on the half second: the first past it
        assert ticks_to_next_status(3 / 256) == 43, "43 x 3/256 s is the first >= 0.5 s"
    arm.robot.call("brake", reason="waiting")
    arm.reason = "waiting"
    arm.cycle()
    assert [s.payload["reason"] for s in statuses()] == ["waiting"], "a change: at once"


def test_a_tcp_pose_is_a_valid_message_in_its_frame():
    tcp = np.eye(4)
    tcp[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # 90 deg about z
    tcp[:3, 3] = [0.5, 0.1, 0.4]
    pose = tcp_message(tcp, 12.5, "patient")
    assert pose.position == (0.5, 0.1, 0.4) and pose.stamp == 12.5
    assert pose.orientation == pytest.approx((math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)))
    assert (pose.rms, pose.frame_number, pose.valid, pose.frame, pose.tool) == (
        0.0,
        0,
        True,
        "patient",
        "tcp",
    )
    assert tcp_message(tcp, 0.0).frame == "base"


def test_a_protective_stop_carries_on_at_the_commanded_velocity_whatever_the_arm_measures(arm):
    last = moving(arm)  # steps of half the rated velocity on A3, the arm following
    arm.v = np.zeros(7)  # the arm's own velocity estimate lags: it says still
    for _ in range(6):  # the interpolator falls silent: the sixth cycle trips
        arm.cycle()
    assert arm.report()["stopping"]
    first_step = arm.commands[-1][2] - last[2]
    assert first_step == pytest.approx(0.5 * MAX_STEP_RAD[2], rel=0.05), "no jump, no halt"


def test_a_refused_setpoint_is_said_with_its_reason(arm):
    refusals = []
    arm.robot.add_refusal_listener(refusals.append)
    arm.cycle()
    arm.released()
    arm.cycle(HOME + step(50.0))
    assert [(r.port, r.reason.split(" would ")[0]) for r in refusals] == [("setpoint", "A3")]


def test_a_trip_latches_the_safety_monitor_too(watched):
    arm = watched.arm
    watched.cycle()
    arm.released()
    watched.cycle(HOME + step(50.0))  # a setpoint no arm can follow
    assert arm.report()["safety"]["latched"] == arm.report()["reason"]


def test_a_protective_stop_asks_for_the_brakes_once_latched_whatever_was_pending(arm):
    moving(arm)
    arm.v = np.full(7, 0.05)
    arm.robot.call("brake", reason="at goal", when_still=True)  # pending, still moving
    requests = len(arm.requests)
    for _ in range(6):  # the interpolator falls silent: a protective stop
        arm.cycle()
    for _ in range(300):
        arm.follow(arm.commands[-1])
        arm.cycle()
    asked = arm.requests[requests:]
    assert [(r.name, r.payload["latch"]) for r in asked] == [("brake", True)]


def test_a_stop_just_after_a_new_motions_first_setpoint_ignores_the_last_motions_commands(arm):
    moving(arm)
    arm.robot.call("brake", reason="at goal")
    arm.braked, arm.served = True, arm.taken
    arm.cycle()
    arm.q = arm.q + step(8.0, joint=2, cycles=10)  # moved while braked (hand guided)
    arm.v = np.zeros(7)
    arm.cycle()
    arm.robot.call("release")
    arm.released()
    arm.cycle(arm.q.copy())  # the new motion's first setpoint: where the arm stands
    sent = len(arm.commands)
    for _ in range(20):  # then silence: a stop from the arm's own state, at rest
        arm.cycle()
        arm.follow(arm.commands[-1])
    assert arm.report()["reason"].startswith("no setpoint for 5 cycles")
    leaps = [abs(q[2] - arm.q[2]) for q in arm.commands[sent - 1 :]]
    assert max(leaps) < MAX_STEP_RAD[2], "no leap along the last motion's velocity"


def test_an_interface_that_starts_beside_a_released_arm_answers_it(arm):
    arm.braked = False  # restarted while the arm was released (its brakes are the arm's)
    for _ in range(10):
        arm.cycle()
    assert not arm.report()["latched"], "it commanded nothing yet: no setpoint is missing"
    arm.cycle(HOME + step(0.5))
    report = arm.report()
    assert not report["latched"] and not report["braked"]
    assert len(arm.commands) == 1, "its first setpoint goes through"


def still_brake_pending(arm):
    """Moving, then asked to brake once still (the arm still moving: pending)."""
    moving(arm)
    arm.v = np.full(7, 0.05)
    answer = arm.robot.call("brake", reason="at goal", when_still=True)
    assert answer["braked"] is False, "the operation answers with the report"
    arm.cycle(arm.q)  # a cycle of that motion: the arm is seen moving
    return len(arm.requests)


def test_brake_when_still_asks_once(arm):
    requests = still_brake_pending(arm)
    arm.v = np.zeros(7)
    for _ in range(STILL_CYCLES + 20):
        arm.cycle(arm.q)
    assert arm.names()[requests:] == ["brake"]


def test_a_brake_when_still_dropped_by_the_brakes_stays_dropped_after_a_release(arm):
    requests = still_brake_pending(arm)
    arm.braked = True  # braked by someone else meanwhile
    arm.cycle(arm.q)
    arm.braked, arm.v = False, np.zeros(7)  # released again, standing still
    for _ in range(STILL_CYCLES + 20):
        arm.cycle(arm.q)
    assert arm.names()[requests:] == []


def test_a_release_drops_a_pending_brake_when_still(arm):
    requests = still_brake_pending(arm)
    arm.robot.call("release")
    arm.v = np.zeros(7)
    for _ in range(STILL_CYCLES + 20):
        arm.cycle(arm.q)
    assert arm.names()[requests:] == ["release"]


def test_each_brake_when_still_waits_its_own_still_time(arm):
    requests = still_brake_pending(arm)
    arm.v = np.zeros(7)
    for _ in range(STILL_CYCLES):
        arm.cycle(arm.q)
    assert arm.names()[requests:] == ["brake"]
    arm.robot.call("brake", reason="again", when_still=True)  # the arm has not braked yet
    for _ in range(STILL_CYCLES - 1):
        arm.cycle(arm.q)
    assert arm.names()[requests:] == ["brake"], "not still long enough since asked"
    arm.cycle(arm.q)
    assert arm.names()[requests:] == ["brake", "brake"]


def test_brake_when_still_gives_up_even_if_the_deadlines_cycle_was_never_seen(arm):
    moving(arm)
    arm.v = np.full(7, 0.05)
    arm.robot.call("brake", reason="at goal", when_still=True)
    requests = len(arm.requests)
    arm.cycle_no += STILL_TIMEOUT_CYCLES + 5  # states lost: the counter jumps past it
    arm.cycle(arm.q)
    assert arm.names()[requests:] == ["brake"]


def test_a_refused_step_names_the_joint_and_how_far_it_would_move(arm):
    arm.cycle()
    arm.released()
    arm.cycle(HOME + step(STEP_MARGIN * 1.02, joint=3, cycles=FIRST_STEP_CYCLES))
    moved = math.degrees(STEP_MARGIN * 1.02 * MAX_STEP_RAD[3] * 10)
    assert arm.report()["reason"] == (
        f"setpoint refused: A4 would move {moved:.2f} deg in 10 cycle(s), 1.5x its rated velocity"
    )


def test_joints_and_tcp_carry_the_time_the_measurement_arrived(arm):
    """Not the time this process got to it: trackers stamp their samples with the time
    they saw the robot, and the Sensor Manager and the navigator pair each sample with
    the robot's pose at that stamp, so a starved robot process must not shift them. The
    kernel stamps the datagram's arrival (SO_TIMESTAMPNS)."""
    if not kernel_stamps_arrivals():
        pytest.skip("this kernel does not stamp UDP datagrams on arrival")
    before = time.time()
    arm.measure()
    sent = time.time()
    time.sleep(0.25)  # the state waits a quarter second for this process
    arm.container.executor.run_pending()
    (joints,), (tcp,) = drained(arm.readers["joints"]), drained(arm.readers["tcp"])
    assert joints.stamp == tcp.stamp
    assert before <= joints.stamp < sent + 0.2 < time.time(), "when it arrived, not later"


def test_await_ready_waits_for_the_arm_to_answer(arm):
    import threading

    answer = {}

    def wait():
        try:
            answer["report"] = arm.robot.call("await_ready", timeout=5.0)
        except FwError as exc:
            answer["error"] = str(exc)

    waiter = threading.Thread(target=wait)
    waiter.start()
    time.sleep(0.1)  # the arm's first state comes while it waits
    arm.cycle()
    waiter.join(10)
    assert "error" not in answer and answer["report"]["braked"]


def test_after_three_missed_cycles_the_next_step_may_span_four(arm):
    last = moving(arm)
    for _ in range(3):
        arm.cycle()
    arm.cycle(last + step(1.4, joint=1, cycles=4))
    assert not arm.report()["latched"], "5.6 rated steps over 4 cycles"
    assert arm.report()["peak_step"] == 1.4, "the step's velocity, not the cycles missed"
    arm.cycle(last + step(1.4, joint=1, cycles=4))  # the same setpoint: standing
    assert arm.report()["peak_step"] == 1.4, "the largest so far"


def test_every_answer_reflects_the_measurement_it_answers(arm):
    """FRI: the PC answers each measurement at once, with its sequence number reflected;
    the command of cycle k is computed from the measurement of cycle k."""
    moving(arm)
    for _ in range(5):
        target = arm.q + step(0.5)
        arm.cycle(target)
        arm.follow(target)
    assert [a.refl_seq for a in arm.answers] == list(range(1, arm.cycle_no + 1))
    assert np.allclose(arm.answers[-1].jnt_pos, arm.q, atol=1e-6)  # this cycle's setpoint


def said(arm):
    """The reasons of the FRI refusals the interface said (every one: a new fixture's
    first refusal is always said)."""
    return " | ".join(r.reason for r in arm.refusals if r.port == "fri")


def _send(arm, data, sock=None):
    (sock or arm.krc).sendto(data, ("127.0.0.1", arm.port))
    arm.container.executor.run_pending()
    arm._collect(arm.braked)


@pytest.mark.parametrize(
    "garbage, why",
    [
        (b"", "916 bytes, not 0"),
        (b"\x00" * 17, "916 bytes, not 17"),
        (b"\xff" * fri.MSR_SIZE, "id"),
    ],
)
def test_a_datagram_that_is_no_measurement_is_refused_counted_and_not_answered(arm, garbage, why):
    arm.cycle()
    answered = len(arm.answers)
    _send(arm, garbage)
    link = arm.report()["fri"]
    assert link["refused"] == 1 and link["measurements"] == 1
    assert len(arm.answers) == answered
    assert why in said(arm)
    arm.cycle()  # the next real measurement is answered as ever
    assert len(arm.answers) == answered + 1
    assert arm.robot.state.value == "Running"


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.2"])
def test_a_measurement_from_another_sender_is_refused(arm, host):
    """Any other sender, its address ordered before or after the KRC's, is refused and
    named."""
    arm.cycle()
    forger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    forger.bind((host, 0))
    sender = forger.getsockname()
    try:
        datagram = fri.encode_measurement(
            arm.cycle_no + 1,
            0,
            timestamp=0.0,
            state=fri.State.CMD,
            quality=fri.Quality.PERFECT,
            msr_jnt_pos=tuple(arm.q),
            cmd_jnt_pos=tuple(arm.q),
            served=0,
            reason=0,
            cycle=arm.cycle_no + 1,
            braked=False,
            latched=False,
        )
        _send(arm, datagram, forger)
    finally:
        forger.close()
    assert arm.report()["fri"]["refused"] == 1
    assert said(arm) == f"a datagram from {sender[0]}:{sender[1]}, not the KRC"
    assert arm.report()["braked"] is True  # the forged "released" changed nothing


def test_a_replayed_or_older_measurement_is_refused(arm):
    arm.cycle()
    arm.cycle()
    arm.cycle_no -= 1  # the same sequence number again
    arm.cycle()
    assert arm.report()["fri"]["refused"] == 1
    assert "out of sequence" in said(arm)
    assert [a.refl_seq for a in arm.answers] == [1, 2]


@pytest.mark.parametrize(
    "address",
    [":49938", "127.0.0.1", "127.0.0.1:", "127.0.0.1:0", "127.0.0.1:65536", "127.0.0.1:fri"],
)
@pytest.mark.parametrize("prop", ["fri_listen", "krc"])
def test_an_fri_address_that_is_not_host_and_port_is_refused_by_configure(hub, prop, address):
    """Where this PC listens and where the KRC is are HOST:PORT, both parts written: an
    empty host would listen on every interface of the robot's PC, port 0 on a port
    nobody knows."""
    container = Container("c", hub, SteppedExecutor(SimulatedClock()))
    try:
        properties = {"fri_listen": f"127.0.0.1:{free_udp_port()}", prop: address}
        robot = container.add(RobotInterface("robot"), Activity.paced(0.02), properties=properties)
        container.start()
        assert not robot.configure()
        assert robot.last_error == (
            f"an FRI address is HOST:PORT (e.g. 127.0.0.1:49938), not {address!r}"
        )
    finally:
        container.shutdown()


def _bindable(port: int) -> bool:
    """Whether this machine's UDP `port` on loopback is free to listen on."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind(("127.0.0.1", port))
        return True
    except OSError:
        return False
    finally:
        probe.close()


def test_an_interface_configured_again_listens_on_its_new_address_and_frees_the_old(arm):
    """Configured again it starts afresh: the old port is free, no arm state is known
    until the KRC's next measurement, and the words of the last run's brake request
    are not given to a brake the KRC reports now."""
    old = arm.port
    assert not _bindable(old), "configured: it listens there"
    arm.robot.call("brake", reason="at goal")
    arm.cycle()
    arm.port = free_udp_port()
    assert arm.robot.stop()
    arm.robot.set_property("fri_listen", f"127.0.0.1:{arm.port}")
    assert arm.robot.configure(), arm.robot.last_error
    assert _bindable(old)
    assert arm.report()["reason"] == "no arm state"
    assert arm.robot.start()
    arm.reason = fri.REASONS[2]  # braked as asked (by the last run)
    arm.cycle()
    assert arm.answers and arm.answers[-1].refl_seq == arm.cycle_no
    assert arm.report()["reason"] == fri.REASONS[2]
    assert arm.robot.stop() and arm.robot.cleanup()
    assert _bindable(arm.port), "cleaned up, it listens nowhere"


def test_an_interface_stopped_and_started_again_first_asks_for_the_brakes_latched(arm):
    """Stopping the interface stops its answers, and the KRC brakes by itself; started
    again, its first answer asks for the brakes latched (the words: 'robot interface
    stopped'), so a motion never resumes without the operator's RELEASE."""
    moving(arm)
    assert arm.robot.stop() and arm.robot.start()
    arm.cycle()
    assert arm.requests[-1] == Request("brake", {"latch": True})


def test_the_loop_report_times_each_stage_of_every_cycle(arm):
    """`fw bench cost` splits a cycle into its stages: taking the datagram, waking for
    it, the safety monitor, the separation check and the publishing: each a duration
    (some work, within the cycles measured; not a clock's reading, not the difference
    of one instant with itself)."""
    began = time.perf_counter()
    moving(arm, cycles=5)
    elapsed_us = (time.perf_counter() - began) * 1e6
    stages = arm.robot.report(loop=True)["loop"]["stages_us"]
    assert {"receive", "wake", "safety", "separation", "publish"} <= set(stages)
    for name, times in stages.items():
        assert 0.0 < times["p50"] <= times["p99"] <= elapsed_us, name


def test_every_replayed_older_measurement_is_refused_not_only_the_first(arm):
    """A refused datagram moves nothing: after a replay of measurement 1, a replay of
    measurement 2 is as old as ever."""
    for _ in range(4):
        arm.cycle()
    for replayed in (1, 2):
        arm.cycle_no = replayed - 1
        arm.cycle()
    assert arm.report()["fri"]["refused"] == 2
    assert [a.refl_seq for a in arm.answers] == [1, 2, 3, 4]


def test_a_replay_right_after_the_sequence_wrapped_to_zero_is_refused(arm):
    """FRI's sequence counter is 16 bits: measurement 0 comes after 65535, and 65535
    again after it is a replay like any other."""
    arm.cycle_no = 65533
    arm.cycle()
    arm.cycle()
    arm.cycle_no = -1
    arm.cycle()  # 0
    arm.cycle_no = 65534
    arm.cycle()  # 65535 again
    assert arm.report()["fri"]["refused"] == 1 and "out of sequence" in said(arm)
    assert [a.refl_seq for a in arm.answers] == [65534, 65535, 0]


def test_an_arm_that_brakes_in_the_cycle_an_input_falls_late_is_held_not_tripped(watched):
    """The cycle's decision is taken on the cycle's measurement: an arm that comes back
    braked (at its goal) is held by an input late since the last cycle, as any braked
    arm is; RELEASE is refused until the input is back."""
    arm = watched_moving(watched)
    arm.robot.call("brake", reason="at goal")
    watched.cycle(arm.q)  # the request goes out with this cycle's answer
    # the heartbeat stops; the arm goes on released until the input is one cycle from
    # late (deadline 20 ms), then comes back braked as the KRC serves the brake
    while arm.report()["safety"]["watches"]["tester"]["age_ms"] + 1.0 < 20.0:
        watched.cycle(arm.q, beat=False)  # holding its goal
    assert not arm.report()["latched"]
    arm.braked, arm.served = True, arm.taken
    watched.cycle(beat=False)
    report = arm.report()
    assert not report["latched"] and report["problems"][0].startswith("tester: no data for")


def test_brake_when_still_waits_while_the_measured_joints_still_move(arm):
    """'Still' is the arm's measured motion from cycle to cycle (under 2 mrad/s on
    every joint for 50 ms), not what was commanded: an arm that drifts on is not
    braked until it stands."""
    requests = still_brake_pending(arm)
    for _ in range(STILL_CYCLES + 20):  # 0.05 rad/s: moving
        arm.cycle(arm.q)
    assert arm.names()[requests:] == []
    arm.v = np.zeros(7)
    for _ in range(STILL_CYCLES + 1):
        arm.cycle(arm.q)
    assert arm.names()[requests:] == ["brake"]


def test_a_silent_krc_trips_with_its_silence_and_timeout(arm):
    """No measurement for longer than `krc_timeout` (50 ms) is a trip of its own, said
    with the silence and the timeout; shorter, nothing happens."""
    moving(arm)
    arm.clock.set(arm.clock.now() + 0.04)
    arm.robot.idle_hook()
    assert not arm.report()["latched"]
    arm.clock.set(arm.clock.now() + 0.02)
    arm.robot.idle_hook()
    assert arm.report()["reason"] == "the KRC is silent: no measurement for 60 ms (timeout 50 ms)"


def test_a_long_silence_is_said_to_the_millisecond(hub):
    """Seconds of silence with a timeout of seconds: both said in whole milliseconds."""
    arm = Arm(hub)
    try:
        assert arm.robot.stop() and arm.robot.set_property("krc_timeout", 2.0)
        assert arm.robot.configure() and arm.robot.start()
        moving(arm)
        arm.clock.set(arm.clock.now() + 3.0)
        arm.robot.idle_hook()
        assert arm.report()["reason"] == (
            "the KRC is silent: no measurement for 3000 ms (timeout 2000 ms)"
        )
    finally:
        arm.close()


def test_the_cycle_that_refuses_a_setpoint_already_carries_the_stops_first_command(arm):
    """A refused setpoint is not answered by holding the last command (a halt from full
    speed): that very cycle's answer is the protective stop's first step, on at the
    commanded velocity."""
    last = moving(arm)
    sent = len(arm.commands)
    arm.cycle(last + step(50.0))
    assert arm.report()["stopping"]
    assert len(arm.commands) == sent + 1
    assert arm.commands[-1][2] - last[2] == pytest.approx(0.5 * MAX_STEP_RAD[2], rel=0.05)


def test_measurements_queued_while_the_interface_was_busy_are_counted_and_only_the_newest_answered(
    arm,
):
    """A busy host finds several measurements waiting: answering the old ones would put
    each answer a cycle later; only the newest is answered, the others are counted as
    skipped (the link's report) and nothing is refused."""
    arm.cycle()
    for _ in range(3):
        arm.measure()
    arm.container.executor.run_pending()
    arm._collect(arm.braked)
    link = arm.report()["fri"]
    assert (link["measurements"], link["skipped"], link["refused"]) == (2, 2, 0)
    assert link["krc"] == f"127.0.0.1:{arm.krc.getsockname()[1]}"
    assert [a.refl_seq for a in arm.answers] == [1, 4]


def test_an_fri_port_already_taken_is_a_configure_error_naming_it(hub):
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    taken.bind(("127.0.0.1", 0))
    container = Container("c", hub, SteppedExecutor(SimulatedClock()))
    try:
        address = f"127.0.0.1:{taken.getsockname()[1]}"
        robot = container.add(
            RobotInterface("robot"), Activity.paced(0.02), properties={"fri_listen": address}
        )
        container.start()
        assert not robot.configure()
        assert robot.last_error == f"cannot listen for FRI on {address}: Address already in use"
    finally:
        container.shutdown()
        taken.close()


def test_a_threaded_loop_answers_each_measurement_as_it_comes_and_reports_its_loop(hub):
    """In its own thread (as deployed) the loop waits in the kernel for each datagram
    and answers it; its report says how the host scheduled it and what each stage took;
    stopped while it waits, the loop ends without an error."""
    from framework.activity import RealTimeExecutor
    from framework.realtime import RealTimePolicy

    krc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    krc.bind(("127.0.0.1", 0))
    krc.settimeout(5.0)
    port = free_udp_port()
    container = Container("c", hub, RealTimeExecutor(RealTimePolicy(enabled=False)))
    try:
        robot = container.add(
            RobotInterface("robot"),
            Activity.paced(0.02),
            properties={
                "fri_listen": f"127.0.0.1:{port}",
                "krc": f"127.0.0.1:{krc.getsockname()[1]}",
            },
        )
        container.start()
        assert robot.configure() and robot.start(), robot.last_error
        answered = []
        for n in range(1, 21):
            datagram = fri.encode_measurement(
                n,
                0,
                timestamp=n * 0.001,
                state=fri.State.MON,
                quality=fri.Quality.PERFECT,
                msr_jnt_pos=tuple(HOME),
                cmd_jnt_pos=tuple(HOME),
                served=0,
                reason=fri.reason_code(fri.REASONS[1]),
                cycle=n,
                braked=True,
                latched=False,
            )
            krc.sendto(datagram, ("127.0.0.1", port))
            answered.append(fri.decode_command(krc.recv(2048)).refl_seq)
        assert answered == list(range(1, 21))
        assert robot.report()["loop"]["scheduling"]
        stages = robot.report(loop=True)["loop"]["stages_us"]
        assert {"receive", "wake", "safety", "separation", "publish"} <= set(stages)
        assert robot.stop() and robot.state.value == "Stopped"
    finally:
        container.shutdown()
        krc.close()


def test_an_acknowledge_refused_for_an_unhealthy_input_leaves_the_stop_latched(watched):
    arm = watched.arm
    watched.cycle()
    arm.released()
    watched.cycle(HOME + step(50.0))  # a setpoint no arm can follow: latched
    for _ in range(60):
        watched.cycle(beat=False)  # and the watched input falls silent
    with pytest.raises(FwError, match="tester: no data for"):
        arm.robot.call("acknowledge")
    assert arm.report()["latched"] and arm.report()["reason"].startswith("setpoint refused")


def test_an_interface_not_configured_yet_reports_no_arm_state(hub):
    container = Container("c", hub, SteppedExecutor(SimulatedClock()))
    try:
        robot = container.add(RobotInterface("robot"), Activity.paced(0.02))
        container.start()
        report = robot.call("report")
        assert report["braked"] is True and report["reason"] == "no arm state"
    finally:
        container.shutdown()


def test_an_acknowledge_while_the_stop_is_under_way_is_refused_and_acknowledges_nothing(watched):
    """RELEASE during a protective stop's deceleration is refused, and the safety
    monitor stays latched with the interface: nothing of the stop is cleared."""
    arm = watched_moving(watched)
    watched.cycle(arm.q + step(50.0))  # refused mid-motion: the stop decelerates
    assert arm.report()["stopping"]
    with pytest.raises(FwError, match="still under way"):
        arm.robot.call("acknowledge")
    report = arm.report()
    assert report["latched"] and report["safety"]["latched"] == report["reason"]


@pytest.mark.parametrize(
    ("text", "address"),
    [("127.0.0.1:1", ("127.0.0.1", 1)), ("10.0.0.2:65535", ("10.0.0.2", 65535))],
)
def test_an_fri_address_takes_every_port_there_is(text, address):
    assert parse_address(text) == address


@pytest.mark.parametrize("text", ["127.0.0.1:0", "127.0.0.1:65536", "127.0.0.1:70000", ":49938"])
def test_an_fri_address_beyond_the_ports_there_are_is_refused(text):
    with pytest.raises(ValueError, match="an FRI address is HOST:PORT"):
        parse_address(text)


def test_the_first_measurement_says_the_joints_at_rest_and_no_step_seen(arm):
    """One measurement gives no velocity (it takes two cycles): the joints' velocities
    are seven zeros, and no setpoint step has been seen yet."""
    arm.v = np.full(7, 0.5)
    arm.cycle()
    joints = drained(arm.readers["joints"])
    assert joints and joints[-1].velocity == (0.0,) * 7
    assert arm.report()["peak_step"] == 0.0
    arm.cycle()
    assert drained(arm.readers["joints"])[-1].velocity == pytest.approx((0.5,) * 7, rel=3e-4)


def _measure_later(arm, seconds):
    import threading

    sender = threading.Timer(seconds, arm.measure)
    sender.start()
    return sender


def test_the_loop_waits_for_the_krcs_next_measurement_and_takes_it_when_it_comes(arm):
    """The KRC is the clock: with nothing queued, the loop's read waits (up to its
    timeout) for the next measurement and takes it as it arrives, instead of giving up
    at once (the loop would spin) or waiting for more."""
    arm.cycle()
    before = dict(arm.robot.link)
    sender = _measure_later(arm, 0.1)
    try:
        assert arm.robot.read_hook(0.9), "the measurement sent while it waited is taken"
    finally:
        sender.join()
    assert arm.robot.link["measurements"] == before["measurements"] + 1
    assert arm.robot.link["skipped"] == before["skipped"]


def test_a_measurement_already_queued_is_taken_without_waiting_for_another(arm):
    """One measurement in the kernel's queue: the read takes it and returns; it does not
    wait out its timeout for a second one (that cycle would be answered late)."""
    arm.cycle()
    arm.measure()
    time.sleep(0.05)  # in the kernel's queue before the read begins
    sender = _measure_later(arm, 0.5)
    try:
        assert arm.robot.read_hook(2.0)
        taken = arm.robot._measurement.cycle
    finally:
        sender.join()
    assert taken == arm.cycle_no - 1, "the queued one, not the one sent 0.5 s later"
    assert arm.robot.link["skipped"] == 0


def test_a_read_on_a_socket_closed_under_it_ends_with_no_measurement(arm):
    """Stopping closes the socket while the loop may be reading: the read ends with no
    measurement (False), not an exception in the loop's thread."""
    arm.cycle()
    arm.robot._socket.close()
    assert arm.robot.read_hook(0.0) is False


def test_requests_numbered_past_the_small_ints_are_served_and_followed_by_the_next(arm):
    """Beside a KRC that served 300 requests: the next is 301, and once served the one
    after goes out as 302 (numbers compared by value, not by identity)."""
    arm.cycle(served=300)
    arm.taken = 300
    arm.robot.call("brake", reason="operator")
    arm.cycle(served=300)
    arm.cycle()  # served at once
    arm.robot.call("release")
    arm.cycle()
    numbers = [(a.request_number, a.request) for a in arm.answers if a.request]
    assert numbers[0] == (301, fri.Request.BRAKE) and numbers[-1] == (302, fri.Request.RELEASE)


def test_a_measurement_repeating_the_last_cycle_number_gives_no_velocity_and_no_crash(arm):
    """A KRC's cycle counter that does not move on (a new datagram, the same cycle): no
    velocity can be derived from it (no division by a zero interval); the joints read as
    still and the interface runs on."""
    arm.cycle()
    arm.cycle()
    datagram = fri.encode_measurement(
        arm.cycle_no + 1,
        0,
        timestamp=arm.cycle_no * 0.001,
        state=fri.State.MON,
        quality=fri.Quality.PERFECT,
        msr_jnt_pos=tuple(arm.q),
        cmd_jnt_pos=tuple(arm.q),
        served=arm.served,
        reason=0,
        cycle=arm.cycle_no,  # the cycle of the last measurement again
        braked=True,
        latched=False,
    )
    arm.cycle_no += 1
    _send(arm, datagram)
    assert drained(arm.readers["joints"])[-1].velocity == (0.0,) * 7
    assert arm.robot.state.value == "Running"


class _Unreachable:
    """The interface's own socket, whose sends the network refuses (a KRC's link down)."""

    def __init__(self, sock):
        self._sock = sock

    def sendto(self, *_):
        import errno

        raise OSError(errno.ENETUNREACH, "Network is unreachable")

    def __getattr__(self, name):
        return getattr(self._sock, name)


def test_an_answer_the_network_refuses_is_said_and_the_loop_goes_on(arm):
    arm.cycle()
    real = arm.robot._socket
    arm.robot._socket = _Unreachable(real)
    try:
        arm.cycle()
    finally:
        arm.robot._socket = real
    assert "cannot answer the KRC: Network is unreachable" in said(arm)
    assert arm.robot.state.value == "Running"
    answered = len(arm.answers)
    arm.cycle()
    assert len(arm.answers) == answered + 1, "answered again once the network takes it"


def _measured(arm, cycle, **fields):
    """The KRC's next measurement, numbered on, of the arm at rest and braked, with
    `cycle` and any field given."""
    arm.cycle_no += 1
    values = {
        "timestamp": arm.cycle_no * 0.001,
        "state": fri.State.MON,
        "quality": fri.Quality.PERFECT,
        "msr_jnt_pos": tuple(arm.q),
        "cmd_jnt_pos": tuple(arm.q),
        "served": arm.served,
        "reason": 0,
        "cycle": cycle,
        "braked": True,
        "latched": False,
    }
    values.update(fields)
    _send(arm, fri.encode_measurement(arm.cycle_no, 0, **values))


def test_the_velocity_spans_the_krcs_cycles_between_two_measurements(arm):
    """A cycle the KRC did not report (its counter moved on by 2): the joints' motion is
    spread over both cycles, not taken as one cycle's."""
    arm.cycle()
    start = arm.cycle_no
    arm.q = arm.q + 0.001
    _measured(arm, start + 2)
    assert drained(arm.readers["joints"])[-1].velocity == pytest.approx((0.5,) * 7, rel=3e-4)


@pytest.mark.parametrize(
    ("code", "said"), [(0, ""), (-1, "unknown"), (9, "unknown"), (10, "unknown")]
)
def test_a_brake_reason_code_outside_the_table_reads_unknown(arm, code, said):
    """Code 0 is no reason; a code FRI's table does not have (a negative one included:
    never Python's index from the end) reads 'unknown'."""
    arm.cycle()
    _measured(arm, arm.cycle_no + 1, reason=code)
    assert arm.report()["reason"] == said


def test_a_trip_after_a_single_command_stops_from_the_arms_measured_motion(arm):
    """One command sent, then a trip: no second command to take a velocity from, so the
    stop decelerates from the measured velocity (the arm still carries that motion),
    and does not fail for want of a command before the last."""
    arm.cycle()
    arm.released()
    arm.v = np.zeros(7)
    arm.v[2] = 0.2  # A3 moving at 0.2 rad/s, measured
    target = arm.q + step(0.5)
    arm.cycle(target)  # the one command of this motion
    arm.commands.clear()
    arm.cycle(arm.q + 1.0)  # refused: a trip, the protective stop begins
    assert arm.report()["latched"] and arm.robot.state.value == "Running"
    for _ in range(5):
        arm.cycle()
    a3 = [c[2] for c in arm.commands]
    assert len(a3) >= 3 and a3[-1] > a3[0], "the stop runs on from the measured motion"


def test_the_words_of_this_sides_last_brake_stay_until_it_asks_again(arm):
    """A release is no brake: the reason of this side's last (unlatched) brake is what a
    brake the KRC reports as asked for says, until this side asks again with others."""
    arm.robot.call("brake", reason="operator")
    arm.cycle(braked=True, reason=fri.REASONS[2])
    arm.robot.call("release")
    arm.cycle(braked=True, reason=fri.REASONS[2])
    assert arm.report()["reason"] == "operator"
    arm.robot.call("brake", reason="tool change")
    arm.cycle(braked=True, reason=fri.REASONS[2])
    assert arm.report()["reason"] == "tool change"


@pytest.mark.parametrize(
    ("state", "said"),
    [(fri.State.OFF, "OFF"), (fri.State.MON, "MON"), (fri.State.CMD, "CMD"), (3, 3)],
)
def test_the_link_report_names_each_state_of_the_krcs_interface(arm, state, said):
    arm.cycle()
    _measured(arm, arm.cycle_no + 1, state=state)
    assert arm.report()["fri"]["state"] == said


def test_await_ready_waits_for_the_arm_within_its_timeout(arm):
    """Not ready yet (no measurement), ready a moment later: await_ready returns ready,
    it does not give up before its timeout."""
    import threading

    def first_state():
        arm.measure()
        arm.container.executor.run_pending()  # the loop takes it

    sender = threading.Timer(0.05, first_state)
    sender.start()
    try:
        report = arm.robot.call("await_ready", timeout=0.95)  # under 1 s, on purpose
    finally:
        sender.join()
    assert report["braked"] and not report["latched"]


@pytest.mark.parametrize(
    ("code", "said"),
    [(0, "UNACCEPTABLE"), (1, "BAD"), (2, "OK"), (3, "PERFECT"), (4, "4")],
)
def test_the_link_report_names_each_fri_quality_and_a_code_beyond_by_its_number(arm, code, said):
    arm.cycle()
    _measured(arm, arm.cycle_no + 1, quality=code)
    assert arm.report()["fri"]["quality"] == said


def test_the_report_gives_the_krcs_time_and_the_joints_to_their_precision(arm):
    """The KRC's time from its cycle (ms), the joints to 1e-5 rad of what the datagram
    carried (float32)."""
    arm.q = HOME + 0.0012345
    arm.cycle()
    _measured(arm, 1234)
    report = arm.report()
    assert report["time"] == 1.234
    assert report["q"] == [round(float(np.float32(v)), 5) for v in arm.q]


joint_value = st.floats(-3.2, 3.2) | st.sampled_from([math.nan, math.inf, -math.inf])


@settings(max_examples=300, deadline=None)
@given(
    st.lists(joint_value, min_size=0, max_size=9),
    st.tuples(*[st.floats(-2.0, 2.0)] * 7),
    st.tuples(*[st.floats(-0.01, 0.01)] * 7),
    st.booleans(),
    st.integers(0, 30),
)
def test_the_kernels_setpoint_plausibility_is_the_pythons(
    values, position, nudge, commanding, idle
):
    """The compiled check refuses what the Python one refuses, with the same words, and
    sees the same largest step (a setpoint near, far, beyond a limit, not finite, or of
    another length; measured from the last command or, first of a motion, the arm)."""
    interfaces = [RobotInterface("robot") for _ in range(2)]
    last = np.asarray(position) + np.asarray(nudge)
    q = np.asarray(values, dtype=float)
    if len(values) == 7 and all(map(math.isfinite, values)):
        q = last + (q - last) * 0.002  # mostly plausible steps, some past the margin
    for robot in interfaces:
        robot._commanding, robot._since_setpoint, robot.peak_step = commanding, idle, 0.0
        robot._sent = deque([last.copy()], maxlen=2) if commanding else deque(maxlen=2)
    state = ArmState(0.0, 1, 0, position, (0.0,) * 7, (0.0,) * 7)
    said = interfaces[0]._implausible(q, state)
    assert said == interfaces[1]._implausible_reference(q, state)
    assert interfaces[0].peak_step == interfaces[1].peak_step


def test_a_refused_datagram_neither_ends_nor_lengthens_the_wait_for_a_measurement(arm):
    """A datagram the interface refuses (garbage, a forger's) does not end the cycle's
    wait: the KRC's measurement that follows within it is taken; with only refused
    ones, the wait ends at its end and nothing is taken."""
    import threading

    arm.cycle()
    arm.krc.sendto(b"\x00" * 17, ("127.0.0.1", arm.port))
    later = threading.Timer(0.2, arm.measure)
    later.start()
    try:
        took = arm.robot.read_hook(10.0)
    finally:
        later.join()
    link = arm.robot.link
    assert took and link["refused"] == 1 and link["measurements"] == 2
    arm.krc.sendto(b"\x00" * 17, ("127.0.0.1", arm.port))
    assert not arm.robot.read_hook(0.2)
    assert link["refused"] == 2 and link["measurements"] == 2


class _UnsentSocket(socket.socket):
    """The interface's own socket whose every send fails, as one to a network gone
    unreachable does (ENETUNREACH): the network's fault, injected at the edge."""

    def sendto(self, *args):
        import errno

        raise OSError(errno.ENETUNREACH, "Network is unreachable")


def test_an_answer_that_could_not_be_sent_is_said_and_not_counted_as_answered(arm):
    import os

    arm.cycle()
    answered = arm.robot.link["answered"]
    own = arm.robot._socket
    failing = _UnsentSocket(fileno=os.dup(own.fileno()))
    arm.robot._socket = failing
    try:
        arm.cycle()
    finally:
        arm.robot._socket = own
        failing.close()
    assert arm.robot.link["answered"] == answered
    assert "cannot answer the KRC: Network is unreachable" in said(arm)
    arm.cycle()  # the network back: answered as ever
    assert arm.robot.link["answered"] == answered + 1


def test_the_robots_process_keeps_its_bus_while_the_arm_is_commanded(arm):
    """framework/routes.py waits to reopen the bus of a process that must keep it: the
    robot interface's while it commands the arm (a reopen would make its answers late),
    not while the arm stands braked."""
    arm.cycle()
    assert arm.robot.holds_bus() == "" and arm.container.holds_bus() == ""
    moving(arm)
    assert arm.robot.holds_bus() == "the robot interface commands the arm"
    assert arm.container.holds_bus().startswith(f"{arm.robot.name}: ")
