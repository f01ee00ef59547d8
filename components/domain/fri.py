"""KUKA's Fast Research Interface 1.x (LWR 4+): the datagrams, byte for byte.

The KRC and the robot's PC exchange UDP datagrams laid out as KUKA's `friComm.h`
(Rev 1.17) declares them: little-endian, IEEE float32, uint16 sequence counters that
wrap. The KRC is the clock: every cycle it sends a **measurement** (`tFriMsrData`,
916 bytes, datagram id 0x2006) and the PC answers it at once with a **command**
(`tFriCmdData`, 376 bytes, id 0x1005) that echoes the measurement's send counter in
its `reflSeqCount`. Offsets (bytes from the datagram's start):

    header            0   sendSeqCount u16, reflSeqCount u16, packetSize u16, datagramId u16
    krl               8   realData f32[16], intData i32[16], boolData u16, fill u16
    measurement:
      intf          140   timestamp f32, state u16 (OFF 0 / MON 1 / CMD 2),
                          quality u16 (UNACCEPTABLE 0 / BAD 1 / OK 2 / PERFECT 3),
                          desiredMsrSampleTime f32, desiredCmdSampleTime f32,
                          safetyLimits f32, stat: answerRate, latency, jitter,
                          missRate f32, missCounter u32
      robot         180   power u16, control u16 (POSITION 1 / CART_IMP 2 / JNT_IMP 3),
                          error u16, warning u16, temperature f32[7]
      data          216   msrJntPos[7] 216, msrCartPos[12] 244, cmdJntPos[7] 292,
                          cmdJntPosFriOffset[7] 320, cmdCartPos[12] 348,
                          cmdCartPosFriOffset[12] 396, msrJntTrq[7] 444,
                          estExtJntTrq[7] 472, estExtTcpFT[6] 500, jacobian[42] 524,
                          massMatrix[49] 692, gravity[7] 888 (all f32)
    command:
      cmdFlags      140   u32 (JNTPOS 0x1, JNTTRQ 0x4, JNTSTIFF 0x10, JNTDAMP 0x20,
                          CARTPOS 0x100, TCPFT 0x400, CARTSTIFF 0x1000, CARTDAMP 0x2000)
      jntPos[7]     144, cartPos[12] 172, addJntTrq[7] 220, addTcpFT[6] 248,
      jntStiffness[7] 272, jntDamping[7] 300, cartStiffness[6] 328, cartDamping[6] 352

In monitor mode (or with the drives off) the PC must answer with jntPos =
cmdJntPos + cmdJntPosFriOffset, else the KRC reports an interpolation error.

**fw's KRL convention** (what the KRL program on a real KRC implements, and the
simulated KRC does): the PC's requests travel in the command's KRL data, the KRC's
answers in the measurement's:

    command      intData[0] request number (rising; the KRC serves each once, and
                            the PC repeats it in every command until the measurement
                            says it was served: UDP may lose the one that carried it)
                 intData[1] request: BRAKE 1, BRAKE_LATCHED 2, RELEASE 3, RESET 4,
                            MODE_POSITION 5, MODE_IMPEDANCE 6
    measurement  intData[0] the last request number served
                 intData[1] why the brakes are on: a `REASONS` code
                 intData[2] the KRC's cycle counter (its 1 ms ticks)
                 boolData   bit 0 braked, bit 1 latched (only a RESET clears it)
"""

from __future__ import annotations

import struct
from collections import deque
from enum import IntEnum
from typing import NamedTuple

from components.domain.kernel import _fwkernel

MSR_ID = 0x2006
CMD_ID = 0x1005
MSR_SIZE = 916
CMD_SIZE = 376
PORT = 49938
"""The client's default port in KUKA's examples (KRL `friSetup` sets the real one)."""

_MSR = struct.Struct("<4H 16f16iHH fHHfff ffffI 4H7f 175f")
_CMD = struct.Struct("<4H 16f16iHH I 58f")
assert _MSR.size == MSR_SIZE and _CMD.size == CMD_SIZE

OFFSETS: dict[str, int] = {
    "sendSeqCount": 0,
    "reflSeqCount": 2,
    "packetSize": 4,
    "datagramId": 6,
    "krl.realData": 8,
    "krl.intData": 72,
    "krl.boolData": 136,
    "intf.timestamp": 140,
    "intf.state": 144,
    "intf.quality": 146,
    "intf.desiredMsrSampleTime": 148,
    "intf.desiredCmdSampleTime": 152,
    "intf.safetyLimits": 156,
    "intf.stat.answerRate": 160,
    "intf.stat.latency": 164,
    "intf.stat.jitter": 168,
    "intf.stat.missRate": 172,
    "intf.stat.missCounter": 176,
    "robot.power": 180,
    "robot.control": 182,
    "robot.error": 184,
    "robot.warning": 186,
    "robot.temperature": 188,
    "data.msrJntPos": 216,
    "data.msrCartPos": 244,
    "data.cmdJntPos": 292,
    "data.cmdJntPosFriOffset": 320,
    "data.cmdCartPos": 348,
    "data.cmdCartPosFriOffset": 396,
    "data.msrJntTrq": 444,
    "data.estExtJntTrq": 472,
    "data.estExtTcpFT": 500,
    "data.jacobian": 524,
    "data.massMatrix": 692,
    "data.gravity": 888,
    "cmd.cmdFlags": 140,
    "cmd.jntPos": 144,
    "cmd.cartPos": 172,
    "cmd.addJntTrq": 220,
    "cmd.addTcpFT": 248,
    "cmd.jntStiffness": 272,
    "cmd.jntDamping": 300,
    "cmd.cartStiffness": 328,
    "cmd.cartDamping": 352,
}
"""Where each field begins (bytes), as friComm.h lays them out; a spec packs a datagram
and reads every field back at its offset."""


class State(IntEnum):
    """The FRI interface state."""

    OFF = 0
    MON = 1
    CMD = 2


class Quality(IntEnum):
    """FRI's communication quality; only UNACCEPTABLE forbids commanding."""

    UNACCEPTABLE = 0
    BAD = 1
    OK = 2
    PERFECT = 3


class Control(IntEnum):
    """The LWR's control strategy."""

    POSITION = 1
    CART_IMP = 2
    JNT_IMP = 3


class Request(IntEnum):
    """fw's requests in the command's KRL data (module docstring)."""

    NONE = 0
    BRAKE = 1
    BRAKE_LATCHED = 2
    RELEASE = 3
    RESET = 4
    MODE_POSITION = 5
    MODE_IMPEDANCE = 6


CMD_JNTPOS = 0x1
CMD_JNTSTIFF = 0x10
CMD_JNTDAMP = 0x20

REASONS: tuple[str, ...] = (
    "",  # 0: not braked
    "power on",
    "interface",  # 2: the PC asked (a procedure's brake)
    "FRI quality too low: the answers stopped or came late",
    "setpoint: a step no arm can follow",
    "interpolation error: monitor mode needs cmdJntPos + cmdJntPosFriOffset",
    "safety stop asked by the robot interface",
    "controller stopped",
    "KRC reset",
)
"""Why the brakes are on, by the code the measurement carries (intData[1])."""


def reason_code(reason: str) -> int:
    """The `REASONS` code of a reason (the first that begins it; 2 for any other)."""
    for code, text in enumerate(REASONS):
        if code and reason.startswith(text):
            return code
    return 2 if reason else 0


class Measurement(NamedTuple):
    """A KRC measurement, decoded: what fw uses of `tFriMsrData` (a tuple: immutable,
    and made at once from the kernel's fields)."""

    send_seq: int
    refl_seq: int
    timestamp: float
    state: int
    quality: int
    answer_rate: float
    latency: float
    jitter: float
    miss_rate: float
    miss_counter: int
    control: int
    msr_jnt_pos: tuple[float, ...]
    cmd_jnt_pos: tuple[float, ...]
    cmd_jnt_pos_fri_offset: tuple[float, ...]
    msr_jnt_trq: tuple[float, ...]
    served: int
    reason: int
    cycle: int
    braked: bool
    latched: bool

    @property
    def monitor_answer(self) -> tuple[float, ...]:
        """What the PC must answer in monitor mode: cmdJntPos + cmdJntPosFriOffset."""
        return tuple(
            a + b for a, b in zip(self.cmd_jnt_pos, self.cmd_jnt_pos_fri_offset, strict=True)
        )


class Command(NamedTuple):
    """A PC command, decoded: what fw uses of `tFriCmdData` (a tuple, as `Measurement`)."""

    send_seq: int
    refl_seq: int
    flags: int
    jnt_pos: tuple[float, ...]
    request_number: int
    request: int


class DatagramError(ValueError):
    """A datagram that is not what it claims: size, id or declared length wrong."""


_U16x2 = struct.Struct("<HH")
_F7 = struct.Struct("<7f")
_MSR_KRL = struct.Struct("<iii")  # intData[0..2]: served, reason, cycle
_MSR_FLAGS = struct.Struct("<H")  # boolData
_MSR_INTF = struct.Struct("<fHHfff ffffI HH")  # 140..184: interface state, stats, power, control
_MSR_HEAD = struct.Struct("<4H")
_MSR_TEMPLATE = _MSR.pack(0, 0, MSR_SIZE, MSR_ID, *([0.0] * 16), *([0] * 16), 0, 0,
                          0.0, 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0,
                          *([30.0] * 7), *([0.0] * 175))  # fmt: skip
"""A measurement of the constant fields (size, id, temperatures): each one sent is this
with its own fields packed in place (a cycle packs 50 numbers, not 254)."""
_CMD_TEMPLATE = _CMD.pack(
    0, 0, CMD_SIZE, CMD_ID, *([0.0] * 16), *([0] * 16), 0, 0, 0, *([0.0] * 58)
)
_CMD_KRL = struct.Struct("<ii")  # intData[0..1]: request number, request
_CMD_FLAGS = struct.Struct("<I")
_ZERO7 = (0.0,) * 7


def encode_measurement(
    send_seq: int,
    refl_seq: int,
    *,
    timestamp: float,
    state: int,
    quality: int,
    stats: tuple[float, float, float, float, int] = (1.0, 0.0, 0.0, 0.0, 0),
    control: int = Control.POSITION,
    msr_jnt_pos: tuple[float, ...] = _ZERO7,
    cmd_jnt_pos: tuple[float, ...] = _ZERO7,
    cmd_jnt_pos_fri_offset: tuple[float, ...] = _ZERO7,
    msr_jnt_trq: tuple[float, ...] = _ZERO7,
    served: int = 0,
    reason: int = 0,
    cycle: int = 0,
    braked: bool = True,
    latched: bool = False,
    sample_time: float = 0.001,
) -> bytes:
    """A measurement datagram (the KRC's side). `stats`: answerRate, latency, jitter,
    missRate, missCounter over the last 100 packets. In the kernel where it was built
    (`encode_measurement_reference` is what a spec holds it to)."""
    if _fwkernel is not None:
        return _fwkernel.fri_encode_measurement(
            send_seq, refl_seq, timestamp, state, quality, stats, control, msr_jnt_pos,
            cmd_jnt_pos,
            None if cmd_jnt_pos_fri_offset is _ZERO7 else cmd_jnt_pos_fri_offset,
            None if msr_jnt_trq is _ZERO7 else msr_jnt_trq,
            served, reason, cycle, braked, latched, sample_time,
        )  # fmt: skip
    return encode_measurement_reference(
        send_seq, refl_seq, timestamp=timestamp, state=state, quality=quality, stats=stats,
        control=control, msr_jnt_pos=msr_jnt_pos, cmd_jnt_pos=cmd_jnt_pos,
        cmd_jnt_pos_fri_offset=cmd_jnt_pos_fri_offset, msr_jnt_trq=msr_jnt_trq,
        served=served, reason=reason, cycle=cycle, braked=braked, latched=latched,
        sample_time=sample_time,
    )  # fmt: skip


def encode_measurement_reference(
    send_seq: int,
    refl_seq: int,
    *,
    timestamp: float,
    state: int,
    quality: int,
    stats: tuple[float, float, float, float, int] = (1.0, 0.0, 0.0, 0.0, 0),
    control: int = Control.POSITION,
    msr_jnt_pos: tuple[float, ...] = _ZERO7,
    cmd_jnt_pos: tuple[float, ...] = _ZERO7,
    cmd_jnt_pos_fri_offset: tuple[float, ...] = _ZERO7,
    msr_jnt_trq: tuple[float, ...] = _ZERO7,
    served: int = 0,
    reason: int = 0,
    cycle: int = 0,
    braked: bool = True,
    latched: bool = False,
    sample_time: float = 0.001,
) -> bytes:
    """`encode_measurement` with Python's struct."""
    out = bytearray(_MSR_TEMPLATE)
    _U16x2.pack_into(out, 0, send_seq & 0xFFFF, refl_seq & 0xFFFF)
    _MSR_KRL.pack_into(out, 72, served, reason, cycle & 0x7FFFFFFF)
    _MSR_FLAGS.pack_into(out, 136, (1 if braked else 0) | (2 if latched else 0))
    rate, latency, jitter, miss_rate, misses = stats
    _MSR_INTF.pack_into(
        out, 140, timestamp, state, quality, sample_time, sample_time, 0.0,
        rate, latency, jitter, miss_rate, misses,
        1 if not braked else 0,  # power: the drives are on while released
        control,
    )  # fmt: skip
    _F7.pack_into(out, 216, *msr_jnt_pos)
    _F7.pack_into(out, 292, *cmd_jnt_pos)
    if cmd_jnt_pos_fri_offset is not _ZERO7:
        _F7.pack_into(out, 320, *cmd_jnt_pos_fri_offset)
    if msr_jnt_trq is not _ZERO7:
        _F7.pack_into(out, 444, *msr_jnt_trq)
    return bytes(out)


def _check(datagram: bytes, size: int, datagram_id: int, what: str) -> None:
    """`DatagramError` unless the datagram's length, its declared size and its id are
    those of a `what`."""
    if len(datagram) != size:
        raise DatagramError(f"a {what} is {size} bytes, not {len(datagram)}")
    declared, found = _U16x2.unpack_from(datagram, 4)
    if found != datagram_id or declared != size:
        raise DatagramError(f"datagram id 0x{found:04x} size {declared} is no {what}")


def decode_measurement(datagram: bytes) -> Measurement:
    """A measurement datagram, decoded; `DatagramError` if it is not one. The kernel
    decodes where it was built (`decode_measurement_reference` is what a spec holds it
    to, and says why a datagram is none)."""
    if _fwkernel is not None:
        fields = _fwkernel.fri_measurement(datagram)
        if fields is not None:
            return tuple.__new__(Measurement, fields)
    return decode_measurement_reference(datagram)


def decode_measurement_reference(datagram: bytes) -> Measurement:
    """`decode_measurement` with Python's struct."""
    _check(datagram, MSR_SIZE, MSR_ID, "measurement")
    send_seq, refl_seq = _U16x2.unpack_from(datagram, 0)
    served, reason, cycle = _MSR_KRL.unpack_from(datagram, 72)
    flags = datagram[136]
    timestamp, state, quality, _, _, _, rate, latency, jitter, miss_rate, misses, _, control = (
        _MSR_INTF.unpack_from(datagram, 140)
    )
    return Measurement(
        send_seq,
        refl_seq,
        timestamp,
        state,
        quality,
        rate,
        latency,
        jitter,
        miss_rate,
        misses,
        control,
        _F7.unpack_from(datagram, 216),
        _F7.unpack_from(datagram, 292),
        _F7.unpack_from(datagram, 320),
        _F7.unpack_from(datagram, 444),
        served,
        reason,
        cycle,
        bool(flags & 1),
        bool(flags & 2),
    )


def encode_command(
    send_seq: int,
    refl_seq: int,
    jnt_pos: tuple[float, ...],
    *,
    flags: int = CMD_JNTPOS,
    request_number: int = 0,
    request: int = Request.NONE,
) -> bytes:
    """A command datagram (the PC's side) answering measurement `refl_seq` (in the
    kernel where it was built; `encode_command_reference` is what a spec holds it to)."""
    if _fwkernel is not None:
        return _fwkernel.fri_encode_command(
            send_seq, refl_seq, jnt_pos, request_number, request, flags
        )
    return encode_command_reference(
        send_seq, refl_seq, jnt_pos, flags=flags, request_number=request_number, request=request
    )


def encode_command_reference(
    send_seq: int,
    refl_seq: int,
    jnt_pos: tuple[float, ...],
    *,
    flags: int = CMD_JNTPOS,
    request_number: int = 0,
    request: int = Request.NONE,
) -> bytes:
    """`encode_command` with Python's struct."""
    out = bytearray(_CMD_TEMPLATE)
    _U16x2.pack_into(out, 0, send_seq & 0xFFFF, refl_seq & 0xFFFF)
    _CMD_KRL.pack_into(out, 72, request_number, request)
    _CMD_FLAGS.pack_into(out, 140, flags)
    _F7.pack_into(out, 144, *jnt_pos)
    return bytes(out)


def decode_command(datagram: bytes) -> Command:
    """A command datagram, decoded; `DatagramError` if it is not one (in the kernel where
    it was built; `decode_command_reference` is what a spec holds it to)."""
    if _fwkernel is not None:
        fields = _fwkernel.fri_command(datagram)
        if fields is not None:
            return tuple.__new__(Command, fields)
    return decode_command_reference(datagram)


def decode_command_reference(datagram: bytes) -> Command:
    """`decode_command` with Python's struct."""
    _check(datagram, CMD_SIZE, CMD_ID, "command")
    send_seq, refl_seq = _U16x2.unpack_from(datagram, 0)
    number, request = _CMD_KRL.unpack_from(datagram, 72)
    (flags,) = _CMD_FLAGS.unpack_from(datagram, 140)
    return Command(send_seq, refl_seq, flags, _F7.unpack_from(datagram, 144), number, request)


def seq_after(a: int, b: int) -> bool:
    """True if uint16 counter `a` comes after `b` (within half the wrap)."""
    return 0 < (a - b) & 0xFFFF < 0x8000


class QualityMeter:
    """How the KRC rates the PC's answers, one verdict per cycle.

    KUKA's own thresholds are not public; this follows the open KRC simulator of
    ubi-agni/lwr_robot (`lwr_controller.cpp`): a counter from 0 to `top` (20) rises by
    one for each cycle answered in time and falls by one for each cycle without an
    answer; at or below `bad` (10) the quality is BAD, above `ok` (15) PERFECT, OK
    between; UNACCEPTABLE at 0. Starting at 0, 11 answered cycles make it OK and 16
    PERFECT; from PERFECT, 10 cycles without an answer (10 ms at 1 kHz) make it BAD.
    Also the statistics of the last 100 cycles (answer rate, latency, jitter, miss
    rate, misses in all) that the measurement carries."""

    def __init__(self, top: int = 20, bad: int = 10, ok: int = 15, window: int = 100):
        if not 0 < bad < ok < top:
            raise ValueError("need 0 < bad < ok < top")
        self.top, self.bad, self.ok = top, bad, ok
        self.counter = 0
        self.window = window
        # the last `window` verdicts and answered cycles' latencies, with their running
        # sums and, for the jitter, the latencies' sliding maximum and minimum (monotonic
        # queues of (index, latency)): a cycle costs the same whatever the window
        self._answered: deque[bool] = deque()
        self._answered_sum = 0
        self._latencies: deque[float] = deque()
        self._latency_sum = 0.0
        self._latency_index = 0
        self._highs: deque[tuple[int, float]] = deque()
        self._lows: deque[tuple[int, float]] = deque()
        self.misses = 0

    def cycle(self, answered: bool, latency: float = 0.0) -> Quality:
        """Rate one cycle (answered in time, or not) and return the quality now."""
        self.counter = min(self.top, self.counter + 1) if answered else max(0, self.counter - 1)
        window = self.window
        verdicts = self._answered
        verdicts.append(answered)
        self._answered_sum += answered
        if len(verdicts) > window:
            self._answered_sum -= verdicts.popleft()
        if answered:
            self._add_latency(latency)
        else:
            self.misses += 1
        return self.quality

    def _add_latency(self, latency: float) -> None:
        latencies, index = self._latencies, self._latency_index
        self._latency_index = index + 1
        latencies.append(latency)
        self._latency_sum += latency
        highs, lows = self._highs, self._lows
        while highs and highs[-1][1] <= latency:
            highs.pop()
        highs.append((index, latency))
        while lows and lows[-1][1] >= latency:
            lows.pop()
        lows.append((index, latency))
        if len(latencies) > self.window:
            self._latency_sum -= latencies.popleft()
            oldest = index - self.window  # the index that just left the window
            if highs[0][0] <= oldest:
                highs.popleft()
            if lows[0][0] <= oldest:
                lows.popleft()

    @property
    def quality(self) -> Quality:
        """The quality the counter stands for."""
        if self.counter == 0:
            return Quality.UNACCEPTABLE
        if self.counter <= self.bad:
            return Quality.BAD
        return Quality.PERFECT if self.counter > self.ok else Quality.OK

    def stats(self) -> tuple[float, float, float, float, int]:
        """answerRate, latency (s, mean), jitter (s, max - min), missRate, missCounter."""
        n = len(self._answered)
        rate = self._answered_sum / n if n else 0.0
        m = len(self._latencies)
        mean = self._latency_sum / m if m else 0.0
        jitter = self._highs[0][1] - self._lows[0][1] if m else 0.0
        return rate, mean, jitter, 1.0 - rate if n else 0.0, self.misses

    def reset(self) -> None:
        """Forget every answer (a new connection)."""
        self.counter = 0
        self._answered.clear()
        self._answered_sum = 0
        self._latencies.clear()
        self._latency_sum = 0.0
        self._highs.clear()
        self._lows.clear()
