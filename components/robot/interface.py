"""The robot interface (the FRI role): the only component that commands the arm, and
where the robot-side safety monitor runs.

It is the PC side of KUKA's FRI 1.x (components/domain/fri.py): the KRC (a real one
given its address, or the simulated one, `components/sim/arm_controller.py`) sends a
measurement datagram every cycle over UDP and this component answers each at once,
in one loop at real-time priority (`activity: {paced: ...}`): **read** the
measurement (only from the KRC, of the right size, id and sequence; anything else is
refused and counted, never a crash) -> **update** (the safety monitor, speed and
separation monitoring, the state every other component reads) -> the components that
run after it in the same thread (the interpolator: the setpoint of this very
measurement) -> **write** the command (the setpoint, the protective stop's next step,
the hold position, or in monitor mode cmdJntPos + cmdJntPosFriOffset as FRI demands,
with the next request to the KRC in its KRL data). Nothing on that path goes over the
bus or is encoded, and no operation takes this component's lock mid-cycle (they run
between cycles, framework/engine.py). Joints and TCP go out to everyone, stamped with
the measurement's arrival in the kernel (not when this process got to it).

Safety, fastest first (docs/safety.md):

* every cycle the **safety monitor** (framework/safety.py) checks the deadlines of
  the inputs the topology declares safety-relevant and the liveliness of every
  component. A trip, a silent interpolator (`setpoint_cycles`) or the controller
  braking by itself **latches**: the interface stops the arm itself at full
  deceleration along its path (`SafeStop`), then asks the controller for its brakes,
  latched;
* the latch opens only through `acknowledge` (the operator's RELEASE, applied by the
  chart's `release` configuration) with every watched input healthy; `release` and
  every setpoint are refused while latched, so nothing but RELEASE restarts motion;
* if this process dies or hangs, the KRC's answers stop and it brakes by itself (FRI
  quality, within 10 of its cycles); if the KRC falls silent for `krc_timeout`, that
  is a trip too (the chart hears of a dead KRC process through its liveliness);
* with people's `envelopes` wired, **speed and separation monitoring** runs every
  cycle the arm is released (`separation.py`, ISO/TS 15066's protective separation
  distance): a separation under it is a protective stop, latched like a trip, taken
  in the cycle that measured it; before that, `speed_cap` slows the motion as people
  approach (the interpolator takes it). The cap is for the envelopes' age when the
  next are due, so it holds for their whole life (about one cap per envelope, not one
  every few cycles as they age) and is never above the cap of their true age.

`brake` and `release` are the procedure's brakes (waiting for START, holding at a
goal): they do not latch.
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import struct
import time
from collections import deque
from typing import Any

import numpy as np

from components.domain import fri
from components.domain.geometry import matrix_to_quat
from components.domain.ik import _fwkernel
from components.domain.lwr4 import POSITION_LIMIT, VELOCITY_LIMIT, Kinematics
from components.domain.separation import CLEAR, SeparationMonitor, SsmParams, Verdict
from components.robot.envelopes import EnvelopeCapsules
from components.robot.safe_stop import SafeStop
from framework.clock_offset import UNMEASURED
from framework.component import Component, ConfigureError, In, Out, operation
from framework.errors import FwError
from framework.messages import ArmState, Envelopes, EventMessage, JointState, Pose, Scalar
from framework.ports import ReadStatus
from framework.properties import prop

_NO_LOCK = contextlib.nullcontext()
FRI_BATCH = 64
"""Datagrams the kernel's `fri_receive` reads per call at most (then it is asked again)."""

CYCLE = 0.001  # s: the controller's cycle
POSITION_LIMIT_RAD = np.array(POSITION_LIMIT)
MAX_STEP_RAD = np.array(VELOCITY_LIMIT) * CYCLE  # the rated velocity, per cycle
MAX_STEP = tuple(MAX_STEP_RAD.tolist())
STEP_MARGIN = 1.5  # a setpoint step may be 1.5x the rated joint velocity, no more
FIRST_STEP_CYCLES = 10  # the first setpoint of a motion: this many cycles from the arm
STILL_RAD_S = 2e-3  # rad/s: every joint slower than this...
STILL_CYCLES = 50  # ...for this many cycles: the arm stands still (brake when still)
STILL_TIMEOUT_CYCLES = 2000  # brake when still brakes anyway after 2 s
STATUS_PERIOD = 0.5  # s between statuses when nothing changes (a change: at once)
CAP_CHANGE = 0.02  # a speed cap that moved by less than this share is not sent again
CAP_LOOKAHEAD = 0.1
"""s: the cap is for the envelopes' age when the next are due, expected after the last
interval between two, at most this (one late sample does not slow every later one)."""
REQUESTS = {
    ("brake", False): fri.Request.BRAKE,
    ("brake", True): fri.Request.BRAKE_LATCHED,
    ("release", False): fri.Request.RELEASE,
    ("reset", False): fri.Request.RESET,
    ("mode", "position"): fri.Request.MODE_POSITION,
    ("mode", "impedance"): fri.Request.MODE_IMPEDANCE,
}
_ASKED = fri.reason_code(fri.REASONS[2])
_SAFETY_STOP = fri.reason_code(fri.REASONS[6])
_STILL = (0.0,) * 7
_TIMESTAMP = struct.Struct("ll")  # SO_TIMESTAMPNS: seconds, nanoseconds
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
"""Linux's option (asm-generic/socket.h: 35) for the kernel's receive time of a datagram
(Python's socket module does not name it)."""


def parse_address(text: str) -> tuple[str, int]:
    """`host:port` as a socket address; ValueError naming what is wrong."""
    host, sep, port = str(text).rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"an FRI address is HOST:PORT (e.g. 127.0.0.1:49938), not {text!r}")
    return host, int(port)


def tcp_message(tcp: np.ndarray, stamp: float, frame: str = "base") -> Pose:
    """A TCP pose (4x4) as a `Pose` message."""
    return Pose(
        tuple(float(v) for v in tcp[:3, 3]),  # type: ignore[arg-type]
        matrix_to_quat(tcp[:3, :3]),
        stamp,
        0.0,
        0,
        True,
        frame,
        "tcp",
    )


class RobotInterface(Component):
    """Commands the arm's controller, hosts the safety monitor (module docstring)."""

    hosts_safety_monitor = True
    setpoint_cycles = prop(
        int, 5, min=1, max=1000, doc="cycles without a setpoint, while commanding, that trip"
    )
    stop_deceleration = prop(
        float,
        8.0,
        unit="rad/s^2",
        min=0.5,
        max=100.0,
        doc="joint deceleration of a protective stop",
    )
    person_speed = prop(
        float, 1.6, unit="m/s", min=0.1, max=5.0, doc="v_h of the protective distance (ISO 13855)"
    )
    detection_uncertainty = prop(
        float, 0.02, unit="m", min=0.0, max=1.0, doc="Z_d: the envelopes' registration error"
    )
    robot_uncertainty = prop(
        float, 0.005, unit="m", min=0.0, max=1.0, doc="Z_r: the arm's model error"
    )
    slow_band = prop(
        float, 0.4, unit="m", min=0.0, max=5.0, doc="beyond S_p(0): the speed cap falls in it"
    )
    max_speed = prop(
        float, 0.075, unit="m/s", min=0.001, max=0.25, doc="the cap far from everyone's band"
    )
    fri_listen = prop(
        str, "127.0.0.1:49938", doc="where this PC listens for the KRC's FRI datagrams"
    )
    krc = prop(
        str, "", doc="the KRC's FRI address (HOST:PORT; '': learned from its first datagram)"
    )
    krc_timeout = prop(
        float, 0.05, unit="s", min=0.005, max=5.0, doc="no measurement for this long: a trip"
    )
    envelopes = In(
        Envelopes,
        doc="people's envelopes (speed and separation monitoring)",
        adapter=EnvelopeCapsules(),
    )
    speed_cap = Out(Scalar, doc="the TCP speed people allow (m/s; inf: none), on change")
    setpoint = In(JointState, doc="joint position setpoints (rad) from the interpolator")
    joints = Out(JointState, doc="measured joints, every cycle", stream=True)
    tcp = Out(Pose, doc="measured TCP in the robot base frame, every cycle", stream=True)
    status = Out(EventMessage, doc="brakes, latch and reason, mode (on change and at 2 Hz)")

    def __init__(self, name: str):
        super().__init__(name)
        self._arm: ArmState | None = None
        """The arm's last measured state."""
        self._socket: socket.socket | None = None
        self._commanding = False
        """Whether the arm is under command (`holds_bus` is asked from the start)."""

    def configure_hook(self) -> bool:
        try:
            listen = parse_address(self.fri_listen)
            self._krc_fixed = parse_address(self.krc) if self.krc else None
        except ValueError as exc:
            raise ConfigureError(str(exc)) from None
        self._close()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            # the kernel turns arrival stamps on in deferred work: a datagram that comes
            # before it has run is stamped when read (only the first, long before motion)
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            sock.bind(listen)
        except OSError as exc:
            sock.close()
            raise ConfigureError(
                f"cannot listen for FRI on {self.fri_listen}: {exc.strerror or exc}"
            ) from None
        sock.setblocking(False)
        self._socket = sock
        self._krc_address = self._krc_fixed
        self._measurement: fri.Measurement | None = None  # the cycle's, until answered
        self._last_seen: fri.Measurement | None = None
        self._received = 0.0  # its arrival in the kernel (wall clock)
        self._last_seq: int | None = None
        self._last_measured = -math.inf  # this component's clock
        self._previous: tuple[int, tuple[float, ...]] | None = None  # (cycle, joints) before
        self._pending: deque[fri.Request] = deque()  # requests for the KRC, in order
        self._answer = np.zeros(7)  # what the next command carries
        # the number of the last request sent to the KRC; None until its first
        # measurement says which it served last (a KRC outlives this process: numbering
        # from 0 again, each request would be taken for one already served)
        self._requests_sent: int | None = None
        self._in_flight = fri.Request.NONE  # that request, until the KRC has served it
        self._brake_reason = ""  # why this side last asked for the brakes (not latched)
        self.link = {"measurements": 0, "answered": 0, "skipped": 0, "refused": 0}
        self.latched = ""
        self.latched_at: float | None = None  # wall time of the trip (None: not latched)
        self.mode = "position"
        self._arm = None
        self._stop: SafeStop | None = None
        self._sent: deque[np.ndarray] = deque(maxlen=2)
        self._commanding = False
        self._since_setpoint = 0
        self._requests = 0
        self._brake_when_still: tuple[str, int] | None = None
        self._still_cycles = 0
        self._reported: tuple[Any, ...] | None = None
        self._last_status = -math.inf
        self._published_cycle = 0
        self._news: ArmState | None = None  # published this cycle, its TCP and status not yet
        self.peak_step = 0.0  # the largest setpoint step seen, in rated joint velocities
        params = SsmParams(
            person_speed=self.person_speed,
            detection_uncertainty=self.detection_uncertainty,
            robot_uncertainty=self.robot_uncertainty,
            slow_band=self.slow_band,
        )
        self._ssm = SeparationMonitor(params, self.max_speed)
        # built here (~50 ms with Pinocchio's model), never in a cycle
        self._kinematics = Kinematics()
        self._capsules = self._kinematics.capsules_buffer()  # the separation check's, reused
        self._people: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._age_at_arrival = 0.0  # the envelopes' age when they arrived (wall clock, s)
        self._arrived = 0.0  # ...and when, on this component's clock
        self._taken = 0.0  # ...and when, on the wall clock (`fw bench ssm`)
        self._interval = 0.0  # between the last two arrivals (this clock, s; 0: one yet)
        self.verdict: Verdict = CLEAR
        self.closest = math.inf  # the least separation while released (m)
        self._cap_sent = math.inf
        self._quiet = 0  # cycles the separation need not be checked
        self._check_started = 0.0  # perf_counter of the check that decided a stop
        self._detected = 0.0  # ...and of its verdict
        self._deciding = 0.0  # wall time the envelopes that decided it were taken
        self._deciding_age = 0.0  # ...and their age then (since their camera frame)
        self.protective_stop: dict[str, float] = {}  # the last one's timing (bench)
        return True

    def stop_hook(self) -> None:
        # its answers stop: the KRC brakes by itself within 10 of its cycles (FRI quality)
        self._request("brake", reason="robot interface stopped", latch=True)

    def cleanup_hook(self) -> None:
        self._close()

    def _close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    # -- the cycle: read, update, (the interpolator), write --------------------------------
    def read_hook(self, timeout: float) -> bool:
        """Wait (at most `timeout` s) for the KRC's next measurement and take it: the
        newest valid one if several queued up (the ones skipped are counted, only the
        newest is answered). A datagram from another sender, of the wrong size or id,
        or out of sequence is refused and counted, and the wait goes on to its end: a
        flood of them neither ends a cycle's wait nor lengthens it. Runs in the loop's
        thread."""
        sock = self._socket
        if sock is None:
            return False
        if _fwkernel is None:
            return self._read_reference(sock, timeout)
        taken = None
        deadline = time.monotonic() + timeout
        try:
            fd = sock.fileno()
            batch = _fwkernel.fri_receive(fd, timeout)  # waits only if nothing is queued
            while batch:
                for data, received, sender in batch:
                    began = time.perf_counter()
                    found = self._judge(data, received, sender)
                    self.stage("receive", time.perf_counter() - began)
                    if found is not None:
                        if taken is not None:
                            self.link["skipped"] += 1
                        taken = found
                if len(batch) == FRI_BATCH:
                    batch = _fwkernel.fri_receive(fd, 0.0)  # more may be queued
                elif taken is None and timeout > 0.0:  # only refused ones: wait on
                    left = deadline - time.monotonic()
                    batch = _fwkernel.fri_receive(fd, left) if left > 0.0 else []
                else:
                    batch = []
        except OSError:  # the socket was closed (stopping)
            return False
        return self._took(taken)

    def _read_reference(self, sock: socket.socket, timeout: float) -> bool:
        """`read_hook` with Python's socket module (where the kernel was not built)."""
        taken = None
        deadline = time.monotonic() + timeout
        try:
            while True:
                try:
                    data, ancillary, _, sender = sock.recvmsg(2048, 64)
                except BlockingIOError:
                    left = deadline - time.monotonic()
                    if taken is not None or left <= 0.0:
                        break
                    if not select.select([sock], [], [], left)[0]:
                        break
                    continue
                began = time.perf_counter()
                found = self._take(data, ancillary, sender)
                self.stage("receive", time.perf_counter() - began)
                if found is not None:
                    if taken is not None:
                        self.link["skipped"] += 1
                    taken = found
        except OSError:  # the socket was closed (stopping)
            return False
        return self._took(taken)

    def _took(self, taken: tuple[fri.Measurement, float] | None) -> bool:
        """The cycle's measurement, if one was taken."""
        if taken is None:
            return False
        measurement, self._received = taken
        self._measurement = self._last_seen = measurement
        self.link["measurements"] += 1
        # from the datagram's arrival in the kernel to now: waking, and the GIL
        self.stage("wake", max(0.0, time.time() - self._received))
        return True

    def _take(
        self, data: bytes, ancillary: list[Any], sender: tuple[str, int]
    ) -> tuple[fri.Measurement, float] | None:
        """`_judge` of a datagram as Python's socket module reads it."""
        received = time.time()
        for level, kind, value in ancillary:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                seconds, nanoseconds = _TIMESTAMP.unpack(value[: _TIMESTAMP.size])
                received = seconds + nanoseconds * 1e-9
        return self._judge(data, received, sender)

    def _judge(
        self, data: bytes, received: float, sender: tuple[str, int]
    ) -> tuple[fri.Measurement, float] | None:
        """One datagram: a measurement of the KRC's, newer than the last, with its
        arrival time in the kernel; None (refused and counted) for anything else."""
        expected = self._krc_address
        if expected is not None and sender != expected:
            return self._refused(f"a datagram from {sender[0]}:{sender[1]}, not the KRC")
        try:
            measurement = fri.decode_measurement(data)
        except fri.DatagramError as exc:
            return self._refused(str(exc))
        last = self._last_seq
        if last is not None and not fri.seq_after(measurement.send_seq, last):
            return self._refused(
                f"measurement {measurement.send_seq} out of sequence (after {last})"
            )
        self._last_seq = measurement.send_seq
        self._krc_address = expected or sender  # the first valid datagram's sender
        return measurement, received

    def _refused(self, reason: str) -> None:
        self.link["refused"] += 1
        self.refuse("fri", reason)
        return None

    def update_hook(self) -> None:
        measurement = self._measurement
        if measurement is None:
            return
        began = time.perf_counter()
        state = self._state_of(measurement)
        self._arm = state
        self._last_measured = self.clock.now()
        if state.braked:
            self._commanding = False
            self._sent.clear()
        latched = self.latched
        self._guard(state)
        guarded = time.perf_counter()
        self._separation(state)
        separated = time.perf_counter()
        if self.latched and not latched:
            # a stop decided in this cycle: its first command answers the measurement
            # now, before the publishing and the components that run after this one
            self.write_hook()
        if self._brake_when_still is not None:
            self._brake_once_still(state)
        self._publish(state)
        self.stage("safety", guarded - began)
        self.stage("separation", separated - guarded)
        self.stage("publish", time.perf_counter() - separated)

    def write_hook(self) -> None:
        """Answer the cycle's measurement: the protective stop's next step, the
        interpolator's setpoint of this very cycle (once found plausible), the hold
        position, or in monitor mode what FRI demands; with the next request. Runs in
        the loop's thread at the end of its cycle, or from `update_hook` already in a
        cycle that decided a stop (its first command must not wait); once per
        measurement either way."""
        measurement, state = self._measurement, self._arm
        if measurement is None or state is None:
            return
        self._measurement = None
        if self._stop is not None:
            self._send(self._stop.step())
            if self._stop.done:
                self._stop = None
                self._request("brake", reason=self.latched, latch=True)
        elif not self.latched and not state.braked:
            status, setpoint = self.setpoint.read()
            if status is ReadStatus.NEW and setpoint is not None:
                q = np.asarray(setpoint.position, dtype=float)
                wrong = self._implausible(q, state)
                if wrong:
                    self.refuse("setpoint", wrong)
                    self._trip(f"setpoint refused: {wrong}", state)
                    if self._stop is not None:  # its first command goes out now
                        self._send(self._stop.step())
                else:
                    self._send(q)
                    self._since_setpoint = 0
            elif self._commanding:
                self._since_setpoint += 1
        if state.braked or not self._commanding:  # hold: the measurement's own answer
            self._answer = np.asarray(measurement.monitor_answer)
        self._answer_krc(measurement)
        if self._check_started:  # a protective stop's first command is on its way
            self._reacted()

    def _answer_krc(self, measurement: fri.Measurement) -> None:
        """Send the command answering `measurement`, with the request in flight: each
        answer carries it until the KRC reports it served (a datagram lost on the way
        must not lose a brake; the KRC takes each request number once), then the next
        queued one."""
        if self._requests_sent is None:
            self._requests_sent = measurement.served
        if measurement.served >= self._requests_sent:
            self._in_flight = fri.Request.NONE
            if self._pending:
                self._in_flight = self._pending.popleft()
                self._requests_sent += 1
        number, request = self._requests_sent, self._in_flight
        datagram = fri.encode_command(
            self.link["answered"] + 1,
            measurement.send_seq,
            self._answer.tolist(),
            request_number=number,
            request=request,
        )
        sock, address = self._socket, self._krc_address
        if sock is None or address is None:
            return
        try:
            sock.sendto(datagram, address)
            self.link["answered"] += 1
        except OSError as exc:
            self.refuse("fri", f"cannot answer the KRC: {exc.strerror or exc}")

    def _state_of(self, m: fri.Measurement) -> ArmState:
        """The measurement as the arm's state: joints and (by finite difference over the
        KRC's cycles) their velocities, torques, brakes, latch and why, stamped with its
        arrival in the kernel."""
        q = m.msr_jnt_pos
        previous = self._previous
        if previous is not None and m.cycle > previous[0]:
            rate = 1.0 / ((m.cycle - previous[0]) * CYCLE)
            velocity = tuple([(a - b) * rate for a, b in zip(q, previous[1], strict=True)])
        else:
            velocity = _STILL
        self._previous = (m.cycle, q)
        reason = fri.REASONS[m.reason] if 0 <= m.reason < len(fri.REASONS) else "unknown"
        if m.reason == _ASKED:  # asked for: by this side, and why
            reason = self._brake_reason or reason
        elif m.reason == _SAFETY_STOP:
            reason = self.latched or reason
        return ArmState(
            self._received,
            m.cycle,
            m.served,
            m.msr_jnt_pos,
            velocity,
            m.msr_jnt_trq,
            (),  # the TCP: computed only for a cycle whose pose someone reads (_publish)
            m.braked,
            m.latched,
            reason if m.braked else "",
        )

    def holds_bus(self) -> str:
        """While the arm is commanded (released, moving or holding under command), no
        process reopens its bus: a reopen's interpreter time would make FRI's answers
        late (the KRC brakes), or a heartbeat this loop watches (it brakes itself);
        framework/routes.py waits, in every process, until the arm is braked."""
        return "the robot interface commands the arm" if self._commanding else ""

    def idle_hook(self) -> None:
        """No measurement for the activity's `idle` period (the KRC is silent or slow):
        the monitor still checks every input, the KRC's silence beyond `krc_timeout` is a
        trip of its own, and a protective stop still under way cannot go on (it has no
        cycles to decelerate with: the KRC brakes when its answers stop). Runs in the
        loop's thread."""
        state = self._arm
        if state is None:
            return
        silent = self.clock.now() - self._last_measured
        if silent > self.krc_timeout and not self.latched:
            self._trip(
                f"the KRC is silent: no measurement for {silent * 1e3:.0f} ms "
                f"(timeout {self.krc_timeout * 1e3:.0f} ms)",
                state,
            )
        self._guard(state)
        if self._stop is not None:  # no cycles to decelerate with: brake at once
            self._stop = None
            self._request("brake", reason=self.latched, latch=True)
        self._publish_status(state)

    def _guard(self, state: ArmState) -> None:
        """Latch on a monitor trip, on the controller's own brake, on a silent planner."""
        if self.latched:
            return
        released = not state.braked or self._commanding
        reason = self.safety.check(released) if self.safety is not None else ""
        if not reason and state.latched and state.served >= self._requests:
            reason = f"the arm braked by itself: {state.reason}"
        if not reason and self._commanding and self._since_setpoint >= self.setpoint_cycles:
            reason = f"no setpoint for {self._since_setpoint} cycles (the interpolator stopped)"
        if reason:
            self._trip(reason, state)

    def _separation(self, state: ArmState) -> None:
        """Speed and separation monitoring, every cycle the arm is released: the stop
        in this very cycle, the speed cap on change (module docstring)."""
        status, sample = self.envelopes.read()
        if status is ReadStatus.NEW:
            wrong = sample.wrong
            if wrong:  # where people are is unknown: stop, as for a lost input
                self.refuse("envelopes", wrong)
                if not self.latched:
                    self._trip(f"envelopes refused: {wrong}", state)
                return
            # their age is the camera frame's on arrival, then this cycle's own clock:
            # a wall clock step after arrival cannot make them younger, and on a
            # simulated clock they age with the simulation
            taken = time.time()
            age = self._age_on_arrival(sample.stamp, taken)
            if age is None:  # stamped by a host whose clock is not measured yet
                self.refuse("envelopes", UNMEASURED)
                if not state.braked and not self.latched:
                    self._trip(f"envelopes of unknown age: {UNMEASURED}", state)
                return  # braked: nothing to judge until that host's clock is measured
            arrived = self.clock.now()
            if self._people is not None:
                self._interval = min(max(0.0, arrived - self._arrived), CAP_LOOKAHEAD)
            self._people = sample.capsules
            self._taken, self._age_at_arrival = taken, age
            self._arrived = arrived
            self._quiet = 0  # news: check now
        if self._people is None or (state.braked and not self._commanding):
            return
        if len(self._people[2]) == 0:  # nobody in the room
            self.verdict = CLEAR
            self._send_cap(math.inf)
            return
        if self._quiet > 0:  # everyone far: nothing can change before the next check
            self._quiet -= 1
            return
        started = time.perf_counter()
        capsules = self._kinematics.capsules_into(state.position, self._capsules)
        now = state.cycle * CYCLE
        age = self._age_at_arrival + max(0.0, self.clock.now() - self._arrived)
        due = self._age_at_arrival + self._interval  # their age when the next are due
        verdict, self._quiet = self._ssm.check_cycle(
            (capsules.a, capsules.b, capsules.radius), self._people, age, now, due, CYCLE
        )
        self.verdict = verdict
        self.closest = min(self.closest, verdict.separation)
        if verdict.stop and not self.latched:
            self._check_started, self._detected = started, time.perf_counter()
            self._deciding, self._deciding_age = self._taken, self._age_at_arrival
            self._trip(
                f"protective stop: a person {verdict.separation * 100:.1f} cm away, under "
                f"the protective distance {verdict.protective * 100:.1f} cm at "
                f"{verdict.robot_speed * 100:.1f} cm/s (envelope {age * 1000:.0f} ms old)",
                state,
            )
            return  # the stop's first command goes out before anything else
        self._send_cap(verdict.tcp_cap)

    def _reacted(self) -> None:
        """Once the first answer of a protective stop is sent (its first stop command,
        or the brake request when the arm was not commanded): how long the separation
        check that decided it took, and from its verdict to that datagram (`fw bench
        ssm`)."""
        started, self._check_started = self._check_started, 0.0
        if started:
            now = time.perf_counter()
            self.protective_stop = {
                "stamp": time.time(),
                "envelopes_taken": self._deciding,  # the cycle that took the envelopes
                "envelopes_age_ms": round(self._deciding_age * 1e3, 4),  # ...their age then
                "check_ms": round((self._detected - started) * 1e3, 4),
                "detected_to_command_ms": round((now - self._detected) * 1e3, 4),
            }

    def _send_cap(self, cap: float) -> None:
        """Say a new cap; one within `CAP_CHANGE` of the last said is not news (0 and
        no cap always are)."""
        sent = self._cap_sent
        if cap == sent or (
            0.0 < cap < math.inf and 0.0 < sent < math.inf and abs(cap - sent) <= CAP_CHANGE * sent
        ):
            return
        self._cap_sent = cap
        self.speed_cap.write(Scalar(time.time(), cap))

    def _age_on_arrival(self, stamp: float, taken: float) -> float | None:
        """The envelopes' age when taken at wall time `taken`: by this host's clock if
        this host stamped them, else the most it can be given the measured offset of
        the host that did (framework/clock_offset.py: an offset may make them look
        older, never fresher); None while that host's clock is not measured."""
        clock = self.stamp_clock("envelopes")
        if clock is None:
            return max(0.0, taken - stamp)
        age = clock.age(stamp, taken)
        return None if age is None else max(0.0, age)

    def _trip(self, reason: str, state: ArmState) -> None:
        self.latched, self.latched_at = reason, time.time()
        if self.safety is not None:
            self.safety.trip(reason)
        self._brake_when_still = None
        if self._commanding and not state.braked and self._sent:
            last = self._sent[-1]
            velocity = (
                (last - self._sent[0]) / CYCLE
                if len(self._sent) == 2
                else np.asarray(state.velocity, dtype=float)
            )
            self._stop = SafeStop(last, velocity, np.full(7, self.stop_deceleration), CYCLE)
        else:
            self._request("brake", reason=reason, latch=True)

    def _implausible(self, q: np.ndarray, state: ArmState) -> str:
        """Why a setpoint must not reach the arm ("" if it may): not 7 finite joints,
        beyond a joint's limit, or a step from the last command faster than the joint's
        rated velocity (with the cycles since then, and a margin). The first setpoint of
        a motion is measured from where the arm stands. The arithmetic runs in the
        compiled kernel where it was built (`setpoint_check`); `_implausible_reference`
        is the same in Python, which a spec holds it to."""
        if _fwkernel is None or q.shape != (7,):
            return self._implausible_reference(q, state)
        if self._commanding and self._sent:
            reference, cycles = self._sent[-1], self._since_setpoint + 1
        else:
            reference, cycles = state.position, FIRST_STEP_CYCLES
        code, j, worst = _fwkernel.setpoint_check(q, POSITION_LIMIT, reference, MAX_STEP, cycles)
        if code == 1:
            return f"not 7 finite joint positions: {q.tolist()!r:.80}"
        if code == 2:
            return f"A{j + 1} at {math.degrees(q[j]):.1f} deg is beyond its limit"
        self.peak_step = max(self.peak_step, worst)
        if worst > STEP_MARGIN:
            return (
                f"A{j + 1} would move {math.degrees(abs(q[j] - reference[j])):.2f} deg in "
                f"{cycles} cycle(s), {worst:.1f}x its rated velocity"
            )
        return ""

    def _implausible_reference(self, q: np.ndarray, state: ArmState) -> str:
        """`_implausible` in plain Python floats."""
        values = q.tolist() if q.ndim == 1 else []
        if len(values) != 7 or not all(math.isfinite(v) for v in values):
            return f"not 7 finite joint positions: {q.tolist()!r:.80}"
        # plain floats: seven numbers cost less than numpy's calls at 1 kHz
        for j, (v, limit) in enumerate(zip(values, POSITION_LIMIT, strict=True)):
            if abs(v) > limit:
                return f"A{j + 1} at {math.degrees(v):.1f} deg is beyond its limit"
        if self._commanding and self._sent:
            reference, cycles = self._sent[-1].tolist(), self._since_setpoint + 1
        else:
            reference, cycles = list(state.position), FIRST_STEP_CYCLES
        worst, j = -1.0, 0
        for k, (v, r, step) in enumerate(zip(values, reference, MAX_STEP, strict=True)):
            ratio = abs(v - r) / (step * cycles)
            if ratio >= worst:  # of equal ratios, the last joint
                worst, j = ratio, k
        self.peak_step = max(self.peak_step, worst)
        if worst > STEP_MARGIN:
            return (
                f"A{j + 1} would move {math.degrees(abs(values[j] - reference[j])):.2f} deg in "
                f"{cycles} cycle(s), {worst:.1f}x its rated velocity"
            )
        return ""

    def _send(self, q: np.ndarray) -> None:
        """The joints the command of this cycle carries."""
        self._answer = q
        self._sent.append(q)
        self._commanding = True

    def _request(self, name: str, **payload: Any) -> None:
        """Queue a request for the KRC (fw's KRL convention: one per command, in order):
        brake {reason, latch}, release, reset, mode {mode}."""
        key = payload.get("mode") if name == "mode" else bool(payload.get("latch", False))
        self._requests += 1
        if name == "brake" and not key:  # FRI carries a code: this side keeps the words
            self._brake_reason = str(payload.get("reason", ""))
        self._pending.append(REQUESTS[(name, key)])

    def _brake_once_still(self, state: ArmState) -> None:
        assert self._brake_when_still is not None
        reason, deadline = self._brake_when_still
        still = max((abs(v) for v in state.velocity), default=0.0) < STILL_RAD_S
        self._still_cycles = self._still_cycles + 1 if still else 0
        if state.braked:
            self._brake_when_still = None
        elif self._still_cycles >= STILL_CYCLES or state.cycle >= deadline:
            self._brake_when_still = None
            self._request("brake", reason=reason, latch=False)

    def _publish(self, state: ArmState) -> None:
        # the controller's measurement time, not when this process got to the state: the
        # trackers' samples carry the time they saw the robot, and a starved process
        # would otherwise pair them with where the robot was some cycles before
        stamp = state.stamp if math.isfinite(state.stamp) else time.time()
        previous = self._published_cycle
        # braked, the arm reports every few cycles (monitor mode): the state covers them;
        # released, it reports every cycle, and a state this loop skipped (a busy host)
        # was a cycle without a new command: the motion must not catch up in one jump
        covered = state.cycle - previous if 0 < previous < state.cycle else 1
        cycles = covered if state.braked else 1
        self._published_cycle = state.cycle
        self.joints.write(JointState(stamp, state.position, state.velocity, state.effort, cycles))
        if self.after_cycles:  # the rest after the command (`after_cycle_hook`)
            self._news = state
        else:
            self._publish_news(state)

    def after_cycle_hook(self) -> None:
        """In the paced loop, after the cycle's command went out: the TCP and the status
        of the state this cycle published (nobody in this cycle reads them; the joints
        went out within it, for the interpolator that runs after this component)."""
        state, self._news = self._news, None
        if state is not None:
            self._publish_news(state)
        if self.safety is not None:  # the watches' arrivals, for the next cycle's check
            self.safety.poll_after_cycle()

    def _publish_news(self, state: ArmState) -> None:
        """The TCP, for its readers at 200 Hz (no forward kinematics on the other
        cycles), and the status."""
        if self.tcp.wanted():
            stamp = state.stamp if math.isfinite(state.stamp) else time.time()
            tcp = self._kinematics.tcp(np.asarray(state.position))
            self.tcp.write(tcp_message(tcp, stamp))
        self._publish_status(state)

    def _publish_status(self, state: ArmState) -> None:
        """On every change of brakes, latch or mode, and at 2 Hz."""
        seen = (state.braked, self.latched, state.reason, self.mode)
        now = self.clock.now()
        if seen != self._reported or now - self._last_status >= STATUS_PERIOD:
            self._reported, self._last_status = seen, now
            payload = self._state_report()  # the loop's statistics: on demand only
            self.status.write(EventMessage(time.time(), "robot", self.name, payload))

    # -- operations ------------------------------------------------------------------------
    @operation
    def brake(self, reason: str = "operator", when_still: bool = False) -> dict[str, Any]:
        """Engage the brakes now, or once the arm stands still (every joint under 2 mrad/s
        for 50 ms; at most 2 s later): the interpolator's own STOP brakes along the path
        first."""
        state = self._arm
        if when_still and state is not None and not state.braked:
            self._brake_when_still = (reason, state.cycle + STILL_TIMEOUT_CYCLES)
            self._still_cycles = 0
        else:
            self._request("brake", reason=reason, latch=False)
        return self._state_report()

    @operation
    def release(self) -> dict[str, Any]:
        """Release the brakes (the arm holds its pose until setpoints arrive); refused
        while a safety stop is latched or a watched input is not healthy."""
        if self.latched:
            raise FwError(
                f"safety stop latched ({self.latched}): only the operator's RELEASE clears it"
            )
        if self.safety is not None:
            why = self.safety.ready()
            if why:
                raise FwError(why)
        self._brake_when_still = None
        self._request("release")
        return self._state_report()

    @operation
    def acknowledge(self) -> dict[str, Any]:
        """The operator's RELEASE: clear the latched safety stop, here and in the arm's
        controller, if every watched input is healthy now (the brakes stay on)."""
        if self._stop is not None:
            raise FwError("the protective stop is still under way")
        if self.safety is not None:
            why = self.safety.acknowledge()
            if why:
                raise FwError(why)
        self.latched, self.latched_at = "", None
        self._request("reset")
        return self._state_report()

    @operation(exclusive=False)
    def await_ready(self, timeout: float = 5.0) -> dict[str, Any]:
        """Wait (at most `timeout` s) until every watched safety input is healthy and
        the arm's controller answers, so the procedure starts only once the robot side
        sees everything it depends on; an error naming what is missing otherwise."""
        end = time.monotonic() + timeout
        while True:
            why = "no state from the arm's controller yet" if self._arm is None else ""
            if not why and self.safety is not None:
                why = self.safety.ready()
            if not why:
                return self._state_report()
            if time.monotonic() >= end:
                raise FwError(f"not ready after {timeout:g} s: {why}")
            time.sleep(0.01)

    @operation
    def set_mode(self, mode: str) -> dict[str, Any]:
        """Switch the joint servos to 'position' or 'impedance'."""
        if mode not in ("position", "impedance"):
            raise FwError(f"unknown mode {mode!r}: position or impedance")
        self.mode = mode
        self._request("mode", mode=mode)
        return self._state_report()

    def _link_report(self) -> dict[str, Any]:
        """The FRI link as this side sees it: the KRC's address, the last measurement's
        state and quality, and the counters (measurements, answered, skipped as too
        late, refused)."""
        m = self._last_seen
        out: dict[str, Any] = dict(self.link)
        address = self._krc_address
        out["krc"] = f"{address[0]}:{address[1]}" if address else None
        if m is not None:
            out.update(
                state=("OFF", "MON", "CMD")[m.state] if 0 <= m.state <= 2 else m.state,
                quality=_quality(m.quality),
                answer_rate=round(m.answer_rate, 3),
                misses=m.miss_counter,
            )
        return out

    @operation(readonly=True, exclusive=False)
    def report(self, loop: bool = False) -> dict[str, Any]:
        """Brakes, latch and why, servo mode, the controller's time, joints, the monitor,
        the FRI link, and (with `loop`, for `fw bench cost`: percentiles over thousands of
        cycles cost milliseconds of this process's interpreter, which its loop shares)
        the loop's scheduling and per-stage times.
        Runs in the caller's thread: the state is taken by the loop between cycles
        (a copy, in microseconds), the loop's statistics (percentiles over thousands of
        cycles, milliseconds) are computed here, never in a cycle's time."""
        engine = self.engine
        if engine is not None and engine.running and not engine.in_loop():
            out = engine.call(self._state_report)
        else:
            with self._lifecycle_lock if engine is None or not engine.running else _NO_LOCK:
                out = self._state_report()
        if engine is not None and "fri" in out:
            stats = engine.report() if loop else {"scheduling": engine.scheduling()}
            out["loop"] = stats
        elif loop and self.loop_stats is not None and "fri" in out:  # a stepped loop's
            out["loop"] = self.loop_stats.report()
        return out

    def _state_report(self) -> dict[str, Any]:
        """`report` without the loop's statistics: what an operation returns, and the
        status says at 2 Hz (in the loop's thread, or under the component's lock)."""
        state = self._arm
        if state is None:
            return {"braked": True, "latched": False, "fault": False, "reason": "no arm state"}
        problems = self.safety.problems() if self.safety is not None else []
        out = {
            "braked": state.braked,
            "latched": bool(self.latched),
            "latched_at": self.latched_at,  # when the stop began (wall clock)
            "fault": bool(self.latched),
            "reason": self.latched or state.reason,
            "ready": not problems,  # every safety input healthy: RELEASE would be taken
            "problems": problems,
            "stopping": self._stop is not None,
            "mode": self.mode,
            "time": round(state.cycle * CYCLE, 4),
            "q": [round(v, 5) for v in state.position],
            "peak_step": round(self.peak_step, 3),
            "separation": _cm(self.verdict.separation),
            "protective_distance": _cm(self.verdict.protective),
            "link_speed": _cm(self.verdict.robot_speed),
            "closest": _cm(self.closest),
            "speed_cap": _cm(self._cap_sent),
            "protective_stop": self.protective_stop,
            "fri": self._link_report(),
            "refused_datagrams": self.link["refused"],  # flat, for scenarios' checks
            "loop": None,
        }
        if self.safety is not None:
            out["safety"] = self.safety.report()
        return out


def _quality(code: int) -> str:
    return fri.Quality(code).name if 0 <= code <= 3 else str(code)


def _cm(metres: float) -> float | None:
    """A distance or speed for a report, to the millimetre (None: unbounded)."""
    return round(metres, 3) if math.isfinite(metres) else None
