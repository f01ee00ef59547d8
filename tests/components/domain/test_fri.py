"""Spec: FRI 1.x datagrams byte for byte (KUKA's friComm.h, Rev 1.17), the KRC's rating
of the PC's answers, and fw's KRL convention for requests and reasons."""

import re
import struct

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from components.domain import fri

# friComm.h's declarations, in order: (field, C type, count). The offsets below are
# computed from these with C's rules (every member here is 2- or 4-byte aligned), so a
# wrong entry in fri.OFFSETS or a wrong struct format cannot agree with them by chance.
HEADER = [("sendSeqCount", "u16", 1), ("reflSeqCount", "u16", 1), ("packetSize", "u16", 1),
          ("datagramId", "u16", 1)]  # fmt: skip
KRL = [("krl.realData", "f32", 16), ("krl.intData", "i32", 16), ("krl.boolData", "u16", 1),
       ("krl.fill", "u16", 1)]  # fmt: skip
MEASUREMENT = HEADER + KRL + [
    ("intf.timestamp", "f32", 1), ("intf.state", "u16", 1), ("intf.quality", "u16", 1),
    ("intf.desiredMsrSampleTime", "f32", 1), ("intf.desiredCmdSampleTime", "f32", 1),
    ("intf.safetyLimits", "f32", 1), ("intf.stat.answerRate", "f32", 1),
    ("intf.stat.latency", "f32", 1), ("intf.stat.jitter", "f32", 1),
    ("intf.stat.missRate", "f32", 1), ("intf.stat.missCounter", "u32", 1),
    ("robot.power", "u16", 1), ("robot.control", "u16", 1), ("robot.error", "u16", 1),
    ("robot.warning", "u16", 1), ("robot.temperature", "f32", 7),
    ("data.msrJntPos", "f32", 7), ("data.msrCartPos", "f32", 12),
    ("data.cmdJntPos", "f32", 7), ("data.cmdJntPosFriOffset", "f32", 7),
    ("data.cmdCartPos", "f32", 12), ("data.cmdCartPosFriOffset", "f32", 12),
    ("data.msrJntTrq", "f32", 7), ("data.estExtJntTrq", "f32", 7),
    ("data.estExtTcpFT", "f32", 6), ("data.jacobian", "f32", 42),
    ("data.massMatrix", "f32", 49), ("data.gravity", "f32", 7),
]  # fmt: skip
COMMAND = HEADER + KRL + [
    ("cmd.cmdFlags", "u32", 1), ("cmd.jntPos", "f32", 7), ("cmd.cartPos", "f32", 12),
    ("cmd.addJntTrq", "f32", 7), ("cmd.addTcpFT", "f32", 6),
    ("cmd.jntStiffness", "f32", 7), ("cmd.jntDamping", "f32", 7),
    ("cmd.cartStiffness", "f32", 6), ("cmd.cartDamping", "f32", 6),
]  # fmt: skip
SIZES = {"u16": 2, "i32": 4, "u32": 4, "f32": 4}
FORMATS = {"u16": "H", "i32": "i", "u32": "I", "f32": "f"}


def layout(fields):
    """Each field's offset under C's alignment rules, and the struct's size."""
    offsets, at = {}, 0
    for name, kind, count in fields:
        size = SIZES[kind]
        at += -at % size  # padding up to the member's alignment
        offsets[name] = at
        at += size * count
    return offsets, at + (-at % 4)  # the struct's own alignment


def field(datagram, fields, name):
    """A field read back at its friComm.h offset."""
    offsets, _ = layout(fields)
    kind, count = next((k, c) for n, k, c in fields if n == name)
    values = struct.unpack_from(f"<{count}{FORMATS[kind]}", datagram, offsets[name])
    return values if count > 1 else values[0]


def test_the_offsets_and_sizes_are_friComms():
    msr_offsets, msr_size = layout(MEASUREMENT)
    cmd_offsets, cmd_size = layout(COMMAND)
    assert (msr_size, cmd_size) == (fri.MSR_SIZE, fri.CMD_SIZE) == (916, 376)
    for name, offset in fri.OFFSETS.items():
        expected = cmd_offsets[name] if name.startswith("cmd.") else msr_offsets[name]
        assert offset == expected, name
    # the ones FACTS.md measured in open copies of friComm.h
    assert msr_offsets["data.cmdJntPosFriOffset"] == 320 and cmd_offsets["cmd.jntPos"] == 144


def test_the_enumerations_flags_and_port_carry_friComms_numbers():
    """friComm.h's numbers (FACTS.md): a KRC reads them, so a renumbering is a protocol
    break even where fw's two ends would still agree with each other."""
    assert {s.name: s.value for s in fri.State} == {"OFF": 0, "MON": 1, "CMD": 2}
    assert {q.name: q.value for q in fri.Quality} == {
        "UNACCEPTABLE": 0,
        "BAD": 1,
        "OK": 2,
        "PERFECT": 3,
    }
    assert {c.name: c.value for c in fri.Control} == {"POSITION": 1, "CART_IMP": 2, "JNT_IMP": 3}
    assert (fri.CMD_JNTPOS, fri.CMD_JNTSTIFF, fri.CMD_JNTDAMP) == (0x1, 0x10, 0x20)
    assert (fri.MSR_ID, fri.CMD_ID, fri.PORT) == (0x2006, 0x1005, 49938)


def test_requests_carry_the_numbers_the_krl_convention_documents():
    """The KRL program on a real KRC is written from the convention in fri.py's
    docstring: the numbers there are the ones sent."""
    documented = fri.__doc__.split("intData[1] request:")[1].split("measurement")[0]
    numbers = dict(re.findall(r"([A-Z_]+) (\d+)", documented))
    assert numbers == {r.name: str(r.value) for r in fri.Request if r is not fri.Request.NONE}
    assert fri.Request.NONE == 0, "no request: the KRL program serves nothing"


floats7 = st.tuples(*[st.floats(-3.0, 3.0, width=32)] * 7)


@given(
    seq=st.integers(0, 0xFFFF),
    refl=st.integers(0, 0xFFFF),
    q=floats7,
    cmd=floats7,
    offset=floats7,
    torque=floats7,
    served=st.integers(0, 2**31 - 1),
    reason=st.integers(0, len(fri.REASONS) - 1),
    cycle=st.integers(0, 2**31 - 1),
    braked=st.booleans(),
    latched=st.booleans(),
    quality=st.sampled_from(list(fri.Quality)),
)
def test_a_measurement_says_each_field_where_friComm_puts_it(
    seq, refl, q, cmd, offset, torque, served, reason, cycle, braked, latched, quality
):
    datagram = fri.encode_measurement(
        seq,
        refl,
        timestamp=12.5,
        state=fri.State.MON if braked else fri.State.CMD,
        quality=quality,
        stats=(0.75, 0.002, 0.0005, 0.25, 7),
        msr_jnt_pos=q,
        cmd_jnt_pos=cmd,
        cmd_jnt_pos_fri_offset=offset,
        msr_jnt_trq=torque,
        served=served,
        reason=reason,
        cycle=cycle,
        braked=braked,
        latched=latched,
    )
    assert len(datagram) == 916
    at = lambda name: field(datagram, MEASUREMENT, name)  # noqa: E731
    assert (at("sendSeqCount"), at("reflSeqCount")) == (seq, refl)
    assert (at("packetSize"), at("datagramId")) == (916, 0x2006)
    assert at("data.msrJntPos") == q and at("data.cmdJntPos") == cmd
    assert at("data.cmdJntPosFriOffset") == offset and at("data.msrJntTrq") == torque
    assert at("robot.power") == (0 if braked else 1), "the drives are on while released"
    assert at("intf.quality") == quality and at("intf.stat.missCounter") == 7
    assert at("intf.state") == (1 if braked else 2)
    assert at("krl.intData")[:3] == (served, reason, cycle)
    assert at("krl.boolData") == braked | latched << 1
    assert at("intf.timestamp") == 12.5
    decoded = fri.decode_measurement(datagram)
    assert (decoded.send_seq, decoded.refl_seq, decoded.quality) == (seq, refl, quality)
    assert decoded.timestamp == 12.5
    assert decoded.msr_jnt_pos == q and decoded.cmd_jnt_pos == cmd
    assert decoded.msr_jnt_trq == torque
    assert (decoded.served, decoded.reason, decoded.cycle) == (served, reason, cycle)
    assert (decoded.braked, decoded.latched, decoded.miss_counter) == (braked, latched, 7)
    assert decoded.monitor_answer == tuple(a + b for a, b in zip(cmd, offset, strict=True))


@given(
    seq=st.integers(0, 0xFFFF),
    refl=st.integers(0, 0xFFFF),
    q=floats7,
    number=st.integers(0, 2**31 - 1),
    request=st.sampled_from(list(fri.Request)),
    flags=st.sampled_from([fri.CMD_JNTPOS, fri.CMD_JNTPOS | fri.CMD_JNTSTIFF]),
)
def test_a_command_says_each_field_where_friComm_puts_it(seq, refl, q, number, request, flags):
    datagram = fri.encode_command(seq, refl, q, flags=flags, request_number=number, request=request)
    assert len(datagram) == 376
    at = lambda name: field(datagram, COMMAND, name)  # noqa: E731
    assert (at("sendSeqCount"), at("reflSeqCount"), at("packetSize")) == (seq, refl, 376)
    assert at("datagramId") == 0x1005 and at("cmd.cmdFlags") == flags
    assert at("cmd.jntPos") == q and at("krl.intData")[:2] == (number, request)
    decoded = fri.decode_command(datagram)
    assert (decoded.send_seq, decoded.refl_seq, decoded.flags) == (seq, refl, flags)
    assert decoded.jnt_pos == q and (decoded.request_number, decoded.request) == (number, request)


def test_floats_travel_as_float32():
    datagram = fri.encode_command(1, 1, (0.1,) * 7)
    assert fri.decode_command(datagram).jnt_pos[0] == struct.unpack("f", struct.pack("f", 0.1))[0]
    assert fri.decode_command(datagram).jnt_pos[0] != 0.1


@pytest.mark.parametrize(
    ("datagram", "why"),
    [
        (b"", "a measurement is 916 bytes, not 0"),
        (bytes(915), "a measurement is 916 bytes, not 915"),
        (fri.encode_command(1, 1, (0.0,) * 7) + bytes(540), "datagram id 0x1005 size 376"),
        (bytes(916), "datagram id 0x0000 size 0 is no measurement"),
    ],
)
def test_anything_but_a_measurement_is_refused_with_what_it_is(datagram, why):
    with pytest.raises(fri.DatagramError, match=why):
        fri.decode_measurement(datagram)


@pytest.mark.parametrize(("at", "value"), [(6, 0x1005), (6, 0x2005), (4, 915), (4, 917)])
def test_a_datagram_of_the_right_length_that_says_another_id_or_size_is_refused(at, value):
    forged = bytearray(fri.encode_measurement(1, 0, timestamp=0.0, state=1, quality=3))
    forged[at : at + 2] = struct.pack("<H", value)
    with pytest.raises(fri.DatagramError, match="is no measurement"):
        fri.decode_measurement(bytes(forged))


@pytest.mark.parametrize("decode", [fri.decode_measurement, fri.decode_command])
@pytest.mark.parametrize("datagram", [b"", b"\x00", bytes(7)])
def test_a_datagram_too_short_for_a_header_is_refused_as_one(decode, datagram):
    with pytest.raises(fri.DatagramError, match=f"bytes, not {len(datagram)}"):
        decode(datagram)


def test_latched_is_bit_one_of_the_krl_flags_alone():
    datagram = bytearray(fri.encode_measurement(1, 0, timestamp=0.0, state=1, quality=3))
    datagram[136] = 0b100  # a bit the KRL program may use for something else
    decoded = fri.decode_measurement(bytes(datagram))
    assert (decoded.braked, decoded.latched) == (False, False)


def test_a_command_told_no_request_carries_none():
    command = fri.decode_command(fri.encode_command(1, 1, (0.0,) * 7))
    assert (command.request_number, command.request) == (0, fri.Request.NONE)
    assert command.flags == fri.CMD_JNTPOS


def test_a_measurement_is_no_command():
    datagram = fri.encode_measurement(1, 0, timestamp=0.0, state=1, quality=3)
    with pytest.raises(fri.DatagramError, match="a command is 376 bytes, not 916"):
        fri.decode_command(datagram)
    forged = bytearray(fri.encode_command(1, 1, (0.0,) * 7))
    forged[6:8] = struct.pack("<H", 0x2006)
    with pytest.raises(fri.DatagramError, match="id 0x2006 size 376 is no command"):
        fri.decode_command(bytes(forged))


def test_a_command_says_nothing_but_what_fw_means():
    """Beyond the header, the request in intData[0..1], the flags and jntPos, every byte
    of a command is zero: a KRC that reads stiffness, damping, added torques or the
    Cartesian pose under other flags, or KRL data fw does not use, finds 0, not junk."""
    datagram = fri.encode_command(7, 6, (0.5,) * 7, request_number=3, request=fri.Request.RELEASE)
    meant = {"sendSeqCount", "reflSeqCount", "packetSize", "datagramId", "cmd.cmdFlags",
             "cmd.jntPos"}  # fmt: skip
    for name, _, count in COMMAND:
        value = field(datagram, COMMAND, name)
        if name == "krl.intData":
            assert value[:2] == (3, fri.Request.RELEASE) and not any(value[2:]), name
        elif name not in meant:
            assert not any(value if count > 1 else (value,)), name


def test_a_measurement_told_nothing_is_of_a_braked_arm_at_rest():
    """The KRC's encoder with only its required fields: braked, not latched, nothing
    served and no reason, every joint vector zero, answers perfect, a 1 ms cycle."""
    datagram = fri.encode_measurement(1, 0, timestamp=0.0, state=fri.State.MON, quality=3)
    m = fri.decode_measurement(datagram)
    assert (m.braked, m.latched, m.served, m.reason, m.cycle) == (True, False, 0, 0, 0)
    zeros = (0.0,) * 7
    assert m.msr_jnt_pos == m.cmd_jnt_pos == m.cmd_jnt_pos_fri_offset == zeros
    assert m.msr_jnt_trq == zeros and m.monitor_answer == zeros
    assert (m.answer_rate, m.latency, m.jitter, m.miss_rate, m.miss_counter) == (1, 0, 0, 0, 0)
    assert field(datagram, MEASUREMENT, "intf.desiredMsrSampleTime") == pytest.approx(0.001)
    assert field(datagram, MEASUREMENT, "intf.desiredCmdSampleTime") == pytest.approx(0.001)


def test_a_measurement_says_nothing_but_what_the_simulated_krc_knows():
    """The simulated KRC fills the fields fw reads; every other one is zero (KRL data
    beyond intData[0..2], the fill, the robot's error and warning, the Cartesian pose,
    torques, Jacobian...), but the drives' temperatures, a plausible 30 degrees C."""
    datagram = fri.encode_measurement(
        9, 8, timestamp=1.5, state=fri.State.CMD, quality=3, msr_jnt_pos=(0.1,) * 7,
        cmd_jnt_pos=(0.2,) * 7, served=4, reason=1, cycle=77, braked=False,
    )  # fmt: skip
    filled = {"sendSeqCount", "reflSeqCount", "packetSize", "datagramId", "krl.boolData",
              "intf.timestamp", "intf.state", "intf.quality", "intf.desiredMsrSampleTime",
              "intf.desiredCmdSampleTime", "intf.stat.answerRate", "robot.power",
              "robot.control", "data.msrJntPos", "data.cmdJntPos"}  # fmt: skip
    for name, _, count in MEASUREMENT:
        value = field(datagram, MEASUREMENT, name)
        if name == "krl.intData":
            assert value[:3] == (4, 1, 77) and not any(value[3:]), name
        elif name == "robot.temperature":
            assert value == (30.0,) * 7
        elif name not in filled:
            assert not any(value if count > 1 else (value,)), name


@pytest.mark.parametrize("seq", [0xFFFF, 0x10000, 0x1FFFE])
def test_counters_past_sixteen_bits_travel_wrapped(seq):
    measurement = fri.encode_measurement(seq, seq, timestamp=0.0, state=1, quality=3)
    command = fri.encode_command(seq, seq, (0.0,) * 7)
    for datagram in (measurement, command):
        assert struct.unpack_from("<HH", datagram, 0) == (seq & 0xFFFF, seq & 0xFFFF)


@pytest.mark.parametrize(("cycle", "sent"), [(2**31 - 1, 2**31 - 1), (2**31, 0), (2**31 + 5, 5)])
def test_the_krcs_cycle_counter_wraps_within_a_signed_32_bit_int(cycle, sent):
    datagram = fri.encode_measurement(1, 0, timestamp=0.0, state=1, quality=3, cycle=cycle)
    assert fri.decode_measurement(datagram).cycle == sent


def test_a_decoded_datagram_cannot_be_changed_by_whoever_reads_it():
    """The loop hands the decoded measurement and command to in-process readers as they
    are (no copy): none of them can change what the others read."""
    measurement = fri.decode_measurement(
        fri.encode_measurement(1, 0, timestamp=0.0, state=1, quality=3, braked=True)
    )
    command = fri.decode_command(fri.encode_command(1, 1, (0.0,) * 7))
    with pytest.raises(AttributeError):
        measurement.braked = False
    with pytest.raises(AttributeError):
        command.request = fri.Request.RELEASE


@pytest.mark.parametrize(
    ("a", "b", "after"),
    [(1, 0, True), (0, 1, False), (5, 5, False), (0, 0xFFFF, True), (0x7FFF, 0, True),
     (0x8000, 0, False), (3, 0xFFF0, True)],
)  # fmt: skip
def test_sequence_counters_wrap(a, b, after):
    assert fri.seq_after(a, b) is after


def test_quality_rises_one_step_per_answered_cycle_and_falls_one_per_miss():
    meter = fri.QualityMeter()
    assert meter.quality is fri.Quality.UNACCEPTABLE
    seen = [meter.cycle(True) for _ in range(16)]
    assert seen[:10] == [fri.Quality.BAD] * 10, "1..10: BAD"
    assert seen[10:15] == [fri.Quality.OK] * 5, "11..15: OK"
    assert seen[15] is fri.Quality.PERFECT, "16 answered cycles: PERFECT"
    for _ in range(10):
        meter.cycle(True)
    assert meter.counter == 20, "it saturates at 20"
    fallen = [meter.cycle(False) for _ in range(10)]
    assert fallen[:4] == [fri.Quality.PERFECT] * 4 and fallen[4] is fri.Quality.OK
    assert fallen[-1] is fri.Quality.BAD, "from PERFECT, 10 silent cycles: BAD"
    back = [meter.cycle(True) for _ in range(6)]
    assert back[:5] == [fri.Quality.OK] * 5 and back[5] is fri.Quality.PERFECT, "one step each"
    for _ in range(6):
        meter.cycle(False)
    for _ in range(20):
        meter.cycle(False)
    assert meter.counter == 0 and meter.quality is fri.Quality.UNACCEPTABLE


def test_the_statistics_cover_the_last_hundred_cycles():
    meter = fri.QualityMeter()
    for _ in range(100):
        meter.cycle(False)
    for i in range(100):
        meter.cycle(True, latency=0.001 + (i % 2) * 0.0004)
    rate, latency, jitter, miss_rate, misses = meter.stats()
    assert (rate, miss_rate, misses) == (1.0, 0.0, 100), "misses in all: 100"
    assert latency == pytest.approx(0.0012) and jitter == pytest.approx(0.0004)
    meter.reset()
    assert meter.counter == 0 and meter.stats()[:4] == (0.0, 0.0, 0.0, 0.0)


def test_thresholds_are_parameters_but_must_be_ordered():
    meter = fri.QualityMeter(top=8, bad=2, ok=5)
    assert [meter.cycle(True) for _ in range(6)][-1] is fri.Quality.PERFECT
    assert fri.QualityMeter(top=3, bad=1, ok=2).bad == 1, "the tightest order allowed"
    for top, bad, ok in [
        (10, 12, 15),
        (10, 0, 5),
        (10, -1, 5),
        (10, 5, 5),
        (10, 3, 10),
        (10, 6, 5),
    ]:
        with pytest.raises(ValueError, match="0 < bad < ok < top"):
            fri.QualityMeter(top=top, bad=bad, ok=ok)


def test_a_cycle_answered_without_a_latency_counts_as_answered_at_once():
    meter = fri.QualityMeter()
    meter.cycle(True)
    meter.cycle(True, 0.004)
    assert meter.stats()[1] == pytest.approx(0.002) and meter.stats()[2] == pytest.approx(0.004)


def test_a_new_connection_forgets_every_answer_but_keeps_counting_misses():
    meter = fri.QualityMeter(window=10)
    for answered in (True, False, True, True):
        meter.cycle(answered, 0.003)
    meter.reset()
    assert meter.quality is fri.Quality.UNACCEPTABLE
    assert meter.stats() == (0.0, 0.0, 0.0, 0.0, 1)
    meter.cycle(True, 0.001)
    meter.cycle(False)
    assert meter.stats() == (pytest.approx(0.5), pytest.approx(0.001), 0.0, pytest.approx(0.5), 2)
    meter.reset()
    meter.cycle(True, 0.005)  # above every latency before: the old lowest must be gone too
    assert meter.stats()[1:3] == (pytest.approx(0.005), 0.0)


def test_reasons_travel_as_codes_and_unknown_words_as_the_interfaces():
    for code, text in enumerate(fri.REASONS):
        assert fri.reason_code(text) == code
    assert fri.reason_code(fri.REASONS[3] + " (10)") == 3, "details after the words"
    assert fri.reason_code("at goal") == 2, "a procedure's own words: the PC asked"


@given(
    cycles=st.lists(
        st.tuples(st.booleans(), st.floats(0.0, 0.01, allow_nan=False)), min_size=1, max_size=400
    ),
    window=st.one_of(st.integers(1, 8), st.integers(1, 120)),  # small: samples leave it
)
@example([(True, 0.005), (True, 0.001), (True, 0.003)], 2)  # the highest leaves first
@example([(True, 0.001), (True, 0.005), (True, 0.003)], 2)  # the lowest leaves first
@example([(True, 0.003), (True, 0.003), (True, 0.001), (True, 0.002)], 2)  # a tie
@example([(True, (2 - k % 3) * 0.001) for k in range(299)], 2)  # past Python's small ints
@example([(True, (k % 3) * 0.001) for k in range(299)], 2)
def test_the_statistics_are_those_of_the_window_whatever_came_before(cycles, window):
    """The meter keeps running sums and sliding extremes (a cycle costs the same for any
    window): they agree with the statistics computed afresh over the last cycles."""
    meter = fri.QualityMeter(window=window)
    for answered, latency in cycles:
        meter.cycle(answered, latency)
    verdicts = [a for a, _ in cycles][-window:]
    latencies = [lat for a, lat in cycles if a][-window:]
    rate, mean, jitter, miss_rate, misses = meter.stats()
    assert rate == pytest.approx(sum(verdicts) / len(verdicts))
    assert miss_rate == pytest.approx(1.0 - sum(verdicts) / len(verdicts))
    assert misses == sum(1 for a, _ in cycles if not a)
    if latencies:
        assert mean == pytest.approx(sum(latencies) / len(latencies), abs=1e-12)
        assert jitter == max(latencies) - min(latencies)
    else:
        assert (mean, jitter) == (0.0, 0.0)


@settings(max_examples=50, deadline=None)
@given(
    st.integers(0, 2**16 - 1),
    st.integers(0, 2**16 - 1),
    st.tuples(*[st.floats(-3.0, 3.0, width=32)] * 7),
    st.tuples(*[st.floats(-100.0, 100.0, width=32)] * 7),
    st.integers(0, 2**31 - 4),  # the cycle counter (served + 3) is 31 bits: it wraps
    st.integers(0, 8),
    st.booleans(),
    st.sampled_from([0.001, 0.01]),
)
def test_without_the_kernel_every_field_travels_both_ways(
    send, refl, joints, torques, served, reason, braked, sample_time
):
    """Where the kernel was not built, the references encode and decode every field fw
    uses, measurement and command alike (the kernel spec holds the two paths equal)."""
    module = fri

    kernel, module._fwkernel = module._fwkernel, None
    try:
        datagram = fri.encode_measurement(
            send, refl, timestamp=1.5, state=fri.State.CMD, quality=fri.Quality.OK,
            stats=(0.5, 0.25, 0.125, 0.5, 7), control=fri.Control.JNT_IMP,
            msr_jnt_pos=joints, cmd_jnt_pos=joints[::-1], cmd_jnt_pos_fri_offset=torques,
            msr_jnt_trq=torques[::-1], served=served, reason=reason, cycle=served + 3,
            braked=braked, latched=not braked, sample_time=sample_time,
        )  # fmt: skip
        m = fri.decode_measurement(datagram)
        command = fri.decode_command(
            fri.encode_command(
                send, refl, joints, flags=0x31, request_number=served, request=reason
            )
        )
    finally:
        module._fwkernel = kernel
    assert (m.send_seq, m.refl_seq, m.timestamp, m.state, m.quality) == (send, refl, 1.5, 2, 2)
    assert (m.answer_rate, m.latency, m.jitter, m.miss_rate, m.miss_counter) == (
        0.5,
        0.25,
        0.125,
        0.5,
        7,
    )
    assert (m.control, m.msr_jnt_pos, m.cmd_jnt_pos) == (fri.Control.JNT_IMP, joints, joints[::-1])
    assert (m.cmd_jnt_pos_fri_offset, m.msr_jnt_trq) == (torques, torques[::-1])
    assert (m.served, m.reason, m.cycle, m.braked, m.latched) == (
        served,
        reason,
        served + 3,
        braked,
        not braked,
    )
    assert datagram[148:156] == struct.pack("<ff", sample_time, sample_time)
    assert tuple(command) == (send, refl, 0x31, joints, served, reason)
