"""The simulated KUKA LWR 4+ as a machine of its own: MuJoCo physics and its KRC, talking
FRI 1.x over UDP (components/domain/fri.py) to the robot interface.

A real LWR 4+ has its own controller (the KRC), the clock of the robot's loop: every
cycle it sends the robot interface a measurement datagram and expects the answer (a
command) before its next cycle; it rates the answers and brakes by itself when they
stop. `ArmController` is that machine in simulation, hosted in a process of its own
(topology process `arm`), so that killing or hanging the robot interface's process
brakes the arm as pulling the FRI cable would:

* every cycle it reads the answers that came (only from `fri_remote`, the PC's address,
  of the right size and id, answering its latest measurement: anything else is
  refused and counted), rates the cycle (`fri.QualityMeter`: KUKA's thresholds are not
  public, these are the open ubi-agni KRC simulator's, properties here), serves the
  request the answer carries (fw's KRL convention: brake, release, reset, servo mode),
  applies the setpoint in command mode, steps `SimulatedArm` and sends the next
  measurement (encoders, commanded joints, torques, brakes, latch, the request served);
* **command mode only with a perfect link**: a release is taken once the quality is
  PERFECT and the monitor-mode answers echo cmdJntPos + cmdJntPosFriOffset (its KRL
  program waits for that up to `RELEASE_WAIT`, then refuses); in
  command mode a quality at or below BAD (10 cycles without an answer, from PERFECT)
  leaves it: monitor mode, brakes on, **latched**;
* brakes the controller applies by itself (quality, the setpoint guard of
  `SimulatedArm`, a stop) and brakes the interface asks for as a safety stop latch:
  a release is refused until a reset, which the interface sends only on the operator's
  RELEASE;
* while braked (monitor mode) it sends a measurement every `monitor_cycles` of its
  1 ms cycles (the sample time its KRL program opens FRI with then; the datagram says
  it), released every cycle again: what keeps the idle deployment cheap;
* at `truth_rate` the ground-truth `tcp` goes out on the bus for the simulated OR's
  trackers: with `model_errors: lwr4` it differs from the nominal model by a few
  millimetres, as a real arm's does. `measured` mirrors each measurement on the bus
  for instruments (`fw bench`), encoded only while one listens; `status` says the
  link's quality and counters twice a second.

Its cycles count its own time: if the whole host stalls, the arm stalls with it. It
waits up to `lockstep_ms` (2 ms) for an answer still on its way while the interface
keeps up: a simulation allowance, since the simulated KRC shares two cores with the
interface and the whole simulated OR, where a real KRC is a machine of its own and
its PC has cores to itself. On a starved host the simulated arm then slows down
(`fw bench cost` reports its real-time factor) rather than braking. Once an answer is
missed it waits no more until one comes in time again, so a dead or hung interface
costs it one wait and then 10 cycles at full rate: braked within about 12 ms.

Its loop takes a bounded share of each millisecond (`simulated_device`: SCHED_DEADLINE,
0.3 ms of every 1 ms, where the host gives real-time priority): a real KRC is another
computer, so it keeps real time whatever else runs, yet on a host too slow for the whole
simulated OR the simulation slows down instead of starving the system it tests
(docs/safety.md). Where the host gives no
real-time priority at all (no CAP_SYS_NICE: a developer's account, a CI container),
the interface's loop cannot keep a 1 ms deadline either: its answers come a
scheduler slice late now and then, and a KRC that stops waiting after
one miss brakes within seconds of a motion (measured: 3 s on an idle 2-core host).
There the simulated KRC waits up to `lockstep_ms` for every answer (the simulation
slows down instead, as a simulator in lockstep with its controller does; a dead
interface brakes it in about 30 ms), and says so in its report (`real_time`).
`lockstep: always` asks for that on any host: the suite's procedure scenarios, which
test the procedure and not the watches, run so on a shared CI host (tests/conftest.py,
`SHARED_HOST_MARGIN`), where a FIFO loop still waits for the GIL behind a preempted
thread of its own process; the fault scenarios keep `auto`.
Injected link faults (`impair`) are the network's, not the host's: a delayed answer
is held until its time and is never waited for.
"""

from __future__ import annotations

import contextlib
import math
import select
import socket
import time
from collections import deque
from typing import Any

from components.domain import fri
from components.domain.geometry import joint_gap, matrix_to_quat
from components.domain.kernel import _fwkernel
from components.domain.lwr4 import HOME, LWR4_ERRORS, NOMINAL, Kinematics
from components.sim.arm import MODES, SimulatedArm
from components.sim.link_faults import LinkFaults
from framework.clock import MonotonicClock
from framework.component import Component, ConfigureError, OperationError, Out, operation
from framework.messages import ArmState, EventMessage, Pose
from framework.properties import prop

MODEL_ERRORS = {"lwr4": LWR4_ERRORS, "none": NOMINAL}
"""How the simulated arm differs from its model: as a real LWR 4+ (components/domain/lwr4.py),
or not at all."""
ECHO_TOLERANCE = 1e-4
"""rad: how close a monitor-mode answer must be to cmdJntPos + cmdJntPosFriOffset."""
RELEASE_WAIT = 1000
"""Cycles (ms) a release waits for a PERFECT link before it is refused."""
STATUS_PERIOD = 0.5
"""s between link statuses on the bus."""
_REQUESTS = {
    fri.Request.MODE_POSITION: "position",
    fri.Request.MODE_IMPEDANCE: "impedance",
}


def parse_address(text: str) -> tuple[str, int]:
    """`host:port` as a socket address; ValueError naming what is wrong."""
    host, sep, port = str(text).rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"an FRI address is HOST:PORT (e.g. 127.0.0.1:49938), not {text!r}")
    return host, int(port)


class ArmController(Component):
    """The simulated LWR 4+ and its KRC (see the module docstring)."""

    realtime = True  # the KRC is the robot's clock: a device loop of its own...
    simulated_device = True  # ...with a bounded share of the CPU, not the SUT's SCHED_FIFO

    fri_remote = prop(
        str, "127.0.0.1:49938", doc="the robot interface's FRI address (KRL friSetup's)"
    )
    fri_local = prop(
        str,
        "",
        doc="the KRC's own address on the FRI link (default: the robot interface's host, "
        "as on one machine)",
    )
    mode = prop(str, "position", choices=list(MODES), doc="joint servo mode at power on")
    model_errors = prop(
        str,
        "lwr4",
        choices=list(MODEL_ERRORS),
        doc="the arm vs its nominal model: a real LWR 4+'s errors, or none",
    )
    lockstep_ms = prop(
        float,
        2.0,
        unit="ms",
        min=0.0,
        max=100.0,
        doc="wait for a late answer while the interface keeps up, or always on a host without real-time priority (0: never; a real KRC does not)",
    )
    lockstep = prop(
        str,
        "auto",
        choices=["auto", "always"],
        doc="auto: wait while the interface keeps up, for every answer on a host without real-time priority; always: for every answer (a simulator in lockstep with its controller: a shared host slows it down, a dead interface brakes it in about 30 ms)",
    )
    monitor_cycles = prop(
        int,
        10,
        min=1,
        max=40,
        doc="while braked (FRI monitor mode), cycles per measurement sent",
    )
    quality_top = prop(int, 20, min=3, max=1000, doc="FRI quality counter's top")
    quality_bad = prop(
        int, 10, min=1, max=999, doc="at or below: BAD (command mode is left, brakes latched)"
    )
    quality_ok = prop(int, 15, min=2, max=999, doc="above: PERFECT (a release is taken)")
    truth_rate = prop(
        float, 200.0, unit="Hz", min=1.0, max=1000.0, doc="how often the ground-truth tcp goes out"
    )
    tcp = Out(Pose, doc="ground-truth tool pose in the base frame (what trackers see)")
    measured = Out(
        ArmState,
        doc="each FRI measurement mirrored for instruments (encoded only while one listens)",
        stream=True,
    )
    status = Out(EventMessage, doc="FRI state and quality, counters, brakes (2 Hz, on change)")

    def __init__(self, name: str):
        super().__init__(name)
        self.arm: SimulatedArm | None = None
        """The machine, made by `configure`."""
        self._socket: socket.socket | None = None
        self._forger: socket.socket | None = None
        self.faults = LinkFaults()
        """What the network between this KRC and the PC does (`impair`)."""
        self._inbox: deque[tuple[float, bytes, tuple[str, int]]] = deque()

    def configure_hook(self) -> bool:
        try:
            self.remote = parse_address(self.fri_remote)
            self.meter = fri.QualityMeter(self.quality_top, self.quality_bad, self.quality_ok)
        except ValueError as exc:
            raise ConfigureError(str(exc)) from None
        self.arm = SimulatedArm(
            HOME, watchdog_cycles=10**9, mode=self.mode, errors=MODEL_ERRORS[self.model_errors]
        )
        self.kinematics = Kinematics()
        self.latched = ""
        self.releases = 0
        self.braked_at: float | None = None
        """Wall time of the cycle the brakes last engaged (None while released): how a
        run whose watcher was cut off from this host times the braking afterwards."""
        self.refused = ""
        self.cycle = 0
        self.served = 0
        self.send_seq = 0
        self._sent_at = 0.0
        self._on_time = True
        self._dropped = False  # this cycle's answer came and the link lost it
        self._real_time: bool | None = None  # whether the interface's loop keeps real time
        self.counts = {"answered": 0, "missed": 0, "late": 0, "refused": 0, "echo": 0}
        self._last_status = -math.inf
        self._cmd_jnt_pos: tuple[float, ...] = tuple(HOME)
        self._echo_ok = True  # the last monitor-mode answer echoed cmdJntPos + offset
        self._release_asked: int | None = None  # the cycle a pending release was asked at
        self.faults = LinkFaults()
        self._inbox.clear()
        self._close()
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._socket.bind((self.fri_local or self.remote[0], 0))
        self._socket.setblocking(False)
        return True

    def stop_hook(self) -> None:
        self._brake("controller stopped", latch=True)

    def cleanup_hook(self) -> None:
        self._close()

    def _close(self) -> None:
        for sock in (self._socket, self._forger):
            if sock is not None:
                sock.close()
        self._socket = self._forger = None

    def _brake(self, reason: str, latch: bool) -> None:
        self.arm.brake(reason)
        if latch and not self.latched:
            self.latched = reason

    # -- the cycle -----------------------------------------------------------------------
    def update_hook(self) -> None:
        arm = self.arm
        self._dropped = False
        answer = self._answer()
        if self._real_time is None:  # asked once, in the loop's own thread
            self._real_time = self._keeps_real_time()
        # an answer the link lost (`impair`) came and is gone: waiting for it would only
        # make the next cycle late, and its answer missed too (every second answer lost
        # then made every answer count as missed, and the arm brake within 10 ms)
        waits = (self._on_time or not self._real_time) and not self._dropped
        if answer is None and self.lockstep_ms > 0 and waits and self.send_seq:
            answer = self._answer(self.lockstep_ms / 1000.0)
        self._on_time = answer is not None or self._dropped  # a lost one says nothing of the PC
        quality = self.meter.cycle(answer is not None, time.monotonic() - self._sent_at)
        if answer is not None:
            self.counts["answered"] += 1
            self._serve(answer, quality)
            commanded = not arm.braked and answer.flags & fri.CMD_JNTPOS
            if commanded and not arm.command(answer.jnt_pos):
                self.latched = self.latched or f"setpoint: {arm.reason}"  # the guard braked
        else:
            self.counts["missed"] += 1
        self._release(quality)
        if not arm.braked and quality <= fri.Quality.BAD:
            self._brake(f"{fri.REASONS[3]} ({self.meter.counter})", latch=True)
        steps = self.periods_per_update  # the cycles since the last update
        for _ in range(steps):
            arm.step()
        self.cycle += steps
        self.periods_per_update = self.monitor_cycles if arm.braked else 1
        self._send(quality)
        self._publish(steps)

    def _keeps_real_time(self) -> bool:
        """Whether the robot interface's loop keeps the 1 ms deadline (module docstring):
        the host gives real-time priority (it does to the interface's loop; this loop,
        a simulated machine, only asks) and `lockstep` is not `always`, or a stepped
        clock runs it (nothing waits there)."""
        if not isinstance(self.clock, MonotonicClock):
            return True
        if self.lockstep == "always":
            return False
        stats = self.loop_stats
        return bool(stats is not None and stats.host_realtime)

    def _answer(self, wait: float = 0.0) -> fri.Command | None:
        """The answer to the latest measurement, if it came (waiting at most `wait`);
        every other datagram is refused and counted. What arrives reaches the KRC when
        the link (`faults`) lets it: at once, later, or never (on the component's clock:
        the host's, or a stepped test's)."""
        sock = self._socket
        if sock is None:
            return None
        if not self._inbox and not self.faults.impairs_answers(self.clock.now()):
            return self._answer_direct(sock, wait)
        deadline = time.monotonic() + wait
        while True:
            found = self._due()
            if found is not None or self._dropped:  # the link lost this cycle's: no more
                return found
            try:
                data, sender = sock.recvfrom(2048)
            except BlockingIOError:
                left = deadline - time.monotonic()
                if left <= 0 or not select.select([sock], [], [], left)[0]:
                    return None
                continue
            self._inbox.append((self.faults.due(self.clock.now()), data, sender))

    def _answer_direct(self, sock: socket.socket, wait: float) -> fri.Command | None:
        """`_answer` while the link loses and delays nothing: each datagram is judged as
        it is read (what `_due` does with one due at once), no clock asked; with the
        kernel, what is queued is read in one call and what follows the answer waits in
        the inbox for the next cycle, as it would have in the socket."""
        if _fwkernel is None:
            return self._answer_reference(sock, wait)
        expected, remote = self.send_seq & 0xFFFF, self.remote
        counts = self.counts
        fd, left = sock.fileno(), wait
        deadline = time.monotonic() + wait if wait > 0.0 else 0.0
        while True:
            batch = _fwkernel.fri_receive(fd, left)  # waits only if nothing is queued
            for index, (data, _, sender) in enumerate(batch):
                if sender != remote:
                    counts["refused"] += 1
                    continue
                try:
                    command = fri.decode_command(data)
                except fri.DatagramError:
                    counts["refused"] += 1
                    continue
                if command.refl_seq != expected:
                    counts["late"] += 1  # an answer to an older measurement
                    continue
                if index + 1 < len(batch):
                    now = self.clock.now()
                    self._inbox.extend((now, d, who) for d, _, who in batch[index + 1 :])
                return command
            if not batch or wait <= 0.0:
                return None
            left = deadline - time.monotonic()  # only refused or late ones came: wait on
            if left <= 0.0:
                return None

    def _answer_reference(self, sock: socket.socket, wait: float) -> fri.Command | None:
        """`_answer_direct` with Python's socket module."""
        deadline = 0.0
        expected, remote = self.send_seq & 0xFFFF, self.remote
        counts = self.counts
        while True:
            try:
                data, sender = sock.recvfrom(2048)
            except BlockingIOError:
                if wait <= 0.0:
                    return None
                now = time.monotonic()
                if not deadline:
                    deadline = now + wait
                left = deadline - now
                if left <= 0 or not select.select([sock], [], [], left)[0]:
                    return None
                continue
            if sender != remote:
                counts["refused"] += 1
                continue
            try:
                command = fri.decode_command(data)
            except fri.DatagramError:
                counts["refused"] += 1
                continue
            if command.refl_seq != expected:
                counts["late"] += 1  # an answer to an older measurement
                continue
            return command

    def _due(self) -> fri.Command | None:
        """The first datagram due that answers the latest measurement; the others due
        before it are refused or counted late."""
        inbox, now = self._inbox, self.clock.now()
        while inbox and inbox[0][0] <= now:
            _, data, sender = inbox.popleft()
            if sender != self.remote:
                self.counts["refused"] += 1
                continue
            try:
                command = fri.decode_command(data)
            except fri.DatagramError:
                self.counts["refused"] += 1
                continue
            if command.refl_seq != self.send_seq & 0xFFFF:
                self.counts["late"] += 1  # an answer to an older measurement
                continue
            if self.faults.lost(now):
                self._dropped = True
                continue
            return command
        return None

    def _serve(self, command: fri.Command, quality: fri.Quality) -> None:
        """The request the answer carries, once (fw's KRL convention), and the
        monitor-mode echo rule."""
        arm = self.arm
        if arm.braked:
            apart = joint_gap(command.jnt_pos, self._cmd_jnt_pos)
            self._echo_ok = apart <= ECHO_TOLERANCE
            if not self._echo_ok:
                self.counts["echo"] += 1
        number = command.request_number
        if number <= self.served:
            return
        self.served = number
        request = command.request
        if request in (fri.Request.BRAKE, fri.Request.BRAKE_LATCHED):
            latch = request == fri.Request.BRAKE_LATCHED
            self._brake(fri.REASONS[6] if latch else fri.REASONS[2], latch)
        elif request == fri.Request.RELEASE:
            self._release_asked = self.cycle  # its KRL program waits for PERFECT, then friStart
        elif request == fri.Request.RESET:
            self.latched = ""
        elif request in _REQUESTS:
            arm.set_mode(_REQUESTS[request])

    def _release(self, quality: fri.Quality) -> None:
        """A release asked for is taken once the link is PERFECT and the monitor-mode
        answers echo as FRI demands (KRL: WAIT FOR $FriQuality == #PERFECT; friStart()),
        refused if that takes over `RELEASE_WAIT` cycles or the brakes are latched."""
        asked = self._release_asked
        if asked is None:
            return
        arm = self.arm
        if self.latched:
            self.refused = f"release refused: latched ({self.latched}); reset first"
        elif quality == fri.Quality.PERFECT and self._echo_ok:
            if arm.braked:
                arm.release()
                self.releases += 1
            self.refused = ""
        elif self.cycle - asked < RELEASE_WAIT:
            return  # still waiting for the link
        else:
            why = fri.REASONS[5] if not self._echo_ok else f"FRI quality {quality.name}"
            self.refused = f"release refused: {why}, not PERFECT within {RELEASE_WAIT} ms"
        self._release_asked = None

    def _send(self, quality: fri.Quality) -> None:
        arm = self.arm
        if arm.braked != (self.braked_at is not None):
            self.braked_at = time.time() if arm.braked else None
        q = arm.q_values
        braked = arm.braked
        self._cmd_jnt_pos = q if braked else arm.last_setpoint
        self.send_seq += 1
        datagram = fri.encode_measurement(
            self.send_seq,
            0,
            timestamp=arm.time,
            state=fri.State.MON if braked else fri.State.CMD,
            quality=quality,
            stats=self.meter.stats(),
            control=fri.Control.JNT_IMP if arm.mode == "impedance" else fri.Control.POSITION,
            msr_jnt_pos=q,
            cmd_jnt_pos=self._cmd_jnt_pos,
            msr_jnt_trq=arm.torque_values,
            served=self.served,
            reason=fri.reason_code(self.latched or arm.reason) if braked else 0,
            cycle=self.cycle,
            braked=braked,
            latched=bool(self.latched),
            sample_time=0.001 * self.periods_per_update,
        )
        self._sent_at = time.monotonic()
        faults = self.faults
        if self._socket is None or (faults.silent_until and faults.silent(self.clock.now())):
            return
        # nobody may listen yet (ECONNREFUSED on loopback): the next cycle sends again
        with contextlib.suppress(OSError):
            self._socket.sendto(datagram, self.remote)
            if faults.garbage:
                bad = faults.next_garbage(datagram)
                if bad is not None:
                    self._socket.sendto(bad, self.remote)
            if faults.foreign and faults.next_foreign():
                self._foreign_socket().sendto(datagram, self.remote)

    def _foreign_socket(self) -> socket.socket:
        """Another sender on the KRC's host (a forged measurement comes from it)."""
        if self._forger is None:
            self._forger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._forger.bind((self.fri_local or self.remote[0], 0))
        return self._forger

    def _publish(self, steps: int) -> None:
        arm, stamp = self.arm, time.time()
        if self.measured.wanted():
            q = arm.q
            nominal = self.kinematics.tcp(q)
            self.measured.write(
                ArmState(
                    stamp,
                    self.cycle,
                    self.served,
                    arm.q_values,
                    tuple(arm.qd.tolist()),
                    arm.torque_values,
                    (*nominal[:3, 3].tolist(), *matrix_to_quat(nominal[:3, :3])),
                    arm.braked,
                    bool(self.latched),
                    self.latched or arm.reason,
                )
            )
        every = max(1, round(1000.0 / self.truth_rate))
        if self.cycle % every < steps:  # a multiple of `every` was passed: trackers sample slower
            tcp = arm.tcp()
            position = tuple(float(v) for v in tcp[:3, 3])
            quaternion = matrix_to_quat(tcp[:3, :3])
            self.tcp.write(Pose(position, quaternion, stamp, 0.0, self.cycle, True, "base", "tcp"))  # type: ignore[arg-type]
        now = self.clock.now()
        if now - self._last_status >= STATUS_PERIOD:
            self._last_status = now
            self.status.write(EventMessage(stamp, "fri", self.name, self.report()))

    @operation()
    def impair(
        self,
        drop_every: int = 0,
        delay_ms: float = 0.0,
        silence_ms: float = 0.0,
        garbage: int = 0,
        foreign: int = 0,
        seconds: float = 1.0,
    ) -> dict[str, Any]:
        """Make the network between this KRC and the PC fail (a fault at the physical
        edge, for scenarios and `fw bench chaos`): for `seconds`, lose every
        `drop_every`-th answer (1: all) and delay answers by `delay_ms`; send no
        measurement for `silence_ms`; send `garbage` datagrams that are no measurement
        (empty, truncated, oversized, a wrong id, in turn) and `foreign` measurements
        from another address to the PC's port, one per cycle. What the KRC and the
        interface make of it is theirs: quality, brakes, refusals."""
        try:
            self.faults.impair(
                self.clock.now(),
                drop_every=drop_every,
                delay=delay_ms / 1000.0,
                silence=silence_ms / 1000.0,
                garbage=garbage,
                foreign=foreign,
                seconds=seconds,
            )
        except (TypeError, ValueError) as exc:
            raise OperationError(f"{self.name}.impair: {exc}") from None
        return self.faults.report()

    @operation(readonly=True)
    def report(self, loop: bool = False) -> dict[str, Any]:
        """Brakes, latch, why, releases so far, servo mode, simulated time, joints, and the
        FRI link: state, quality, the statistics of the last 100 cycles and counters; with
        `loop` (for `fw bench cost`), its loop's cycle statistics (milliseconds of work
        for this process's interpreter: on request only)."""
        arm = self.arm
        if arm is None:
            return {"braked": True, "latched": False, "reason": "not configured"}
        rate, latency, jitter, miss_rate, misses = self.meter.stats()
        return {
            "braked": arm.braked,
            "latched": bool(self.latched),
            "reason": self.latched or arm.reason,
            "releases": self.releases,
            "braked_at": self.braked_at,
            "refused": self.refused,
            "mode": arm.mode,
            "cycle": self.cycle,
            "time": round(arm.time, 4),
            "q": [round(v, 5) for v in arm.q.tolist()],
            "real_time": self._real_time,
            "loop": (
                None
                if self.loop_stats is None
                else self.loop_stats.report()
                if loop
                else {"scheduling": self.loop_stats.scheduling}
            ),
            "fri": {
                "state": "MON" if arm.braked else "CMD",
                "quality": self.meter.quality.name,
                "counter": self.meter.counter,
                "answer_rate": round(rate, 3),
                "latency_ms": round(latency * 1e3, 3),
                "jitter_ms": round(jitter * 1e3, 3),
                "miss_rate": round(miss_rate, 3),
                "misses": misses,
                **self.counts,
                **self.faults.report(),
            },
        }
