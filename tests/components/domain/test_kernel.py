"""The compiled kernel (components/domain/_fwkernel.c) computes what the numpy, Pinocchio
and struct references compute: the TCP pose with its Jacobian, one IK step, the path's
pose, the steering step, the arm's joint origins, the least capsule distance, the speed
and separation verdict and FRI's datagrams. The robot's 1 kHz cycle runs the kernel; the
references are what the rest of fw (and these specs) trust."""

from __future__ import annotations

import math
import socket
import struct
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.domain import distance, fri, geometry, ik, lwr4
from components.domain.separation import SeparationMonitor, SsmParams
from components.robot.interpolator import InterpolatorCore

pytestmark = pytest.mark.skipif(
    ik._fwkernel is None, reason="the compiled kernel was not built (pip install -e .)"
)
kernel = ik._fwkernel

KIN = lwr4.Kinematics()
IK = ik.DifferentialIK(KIN)
joints = st.tuples(*[st.floats(-limit, limit) for limit in lwr4.POSITION_LIMIT]).map(np.array)
small = st.floats(-0.05, 0.05)
coordinate = st.floats(-2.0, 2.0)
point = st.tuples(coordinate, coordinate, coordinate)


def _pose(rotation_vector: np.ndarray, position: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    out = np.eye(4)
    out[:3, :3] = pin.exp3(np.asarray(rotation_vector, dtype=float))
    out[:3, 3] = position
    return out


@settings(max_examples=100, deadline=None)
@given(joints)
def test_the_kernels_tcp_pose_and_jacobian_are_pinocchios(q):
    """The pose and the Jacobian in the base-aligned TCP frame, as Pinocchio has them."""
    pose, jac = np.empty((4, 4)), np.empty((6, 7))
    kernel.jacobian(KIN.placements, KIN.tool, np.ascontiguousarray(q), pose, jac)
    want_pose, want_jac = KIN.jacobian(q)
    assert np.allclose(pose, want_pose, atol=1e-12)
    assert np.allclose(jac, want_jac, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(joints)
def test_the_kernels_joint_origins_and_so_the_arms_capsules_are_pinocchios(q):
    """Base, joint origins, flange and TCP (the capsules' ends), as Pinocchio has them."""
    got = KIN.joint_origins(q)
    want = KIN.joint_origins_reference(q)
    assert got.shape == want.shape == (10, 3)
    assert np.allclose(got, want, atol=1e-12)
    capsules = KIN.capsules(q)
    pairs, radii = KIN._capsule_spec
    assert np.array_equal(capsules.a, np.array([got[i] for i, _ in pairs]))
    assert np.array_equal(capsules.b, np.array([got[j] for _, j in pairs]))
    assert np.array_equal(capsules.radius, radii)


@settings(max_examples=100, deadline=None)
@given(joints, st.tuples(small, small, small), st.tuples(small, small, small))
def test_one_ik_step_is_the_reference_step(q, move, turn):
    q = np.clip(q, IK.lower, IK.upper)
    here = KIN.tcp(q)
    target = _pose(turn, here[:3, 3] + np.array(move))
    target[:3, :3] = target[:3, :3] @ here[:3, :3]
    stepped = IK.step(q, target)
    assert np.allclose(stepped, IK.step_reference(q, target), atol=1e-9)
    assert np.all(np.abs(stepped - q) <= IK.max_step + 1e-12)  # no joint faster than its limit


def test_a_step_toward_a_target_it_cannot_solve_falls_back_to_the_reference():
    q = np.array(lwr4.HOME)
    target = KIN.tcp(q)
    target[0, 3] = math.nan
    out = IK.step(q, target)
    reference = IK.step_reference(q, target)
    assert np.array_equal(np.isnan(out), np.isnan(reference))


@settings(max_examples=100, deadline=None)
@given(
    st.floats(0.0, 1.0),
    st.tuples(small, small, small),
    st.tuples(st.floats(-0.3, 0.3), st.floats(-0.3, 0.3), st.floats(-0.3, 0.3)),
    st.tuples(small, small, small, small, small, small),
)
def test_the_path_pose_is_the_reference_pose_with_the_steering_offset(u, move, turn, offset):
    core = InterpolatorCore(
        np.array(lwr4.HOME), velocity=0.05, acceleration=0.25, brake_acceleration=2.0, ik=IK
    )
    start = KIN.tcp(np.array(lwr4.HOME))
    goal = np.eye(4)
    goal[:3, 3] = start[:3, 3] + np.array(move)
    goal[:3, :3] = start[:3, :3] @ _pose(turn, np.zeros(3))[:3, :3]
    core._start_path(start, goal)
    core.offset = np.array(offset)
    s = u * core.length
    assert np.allclose(core._path_pose(s), core._offset_pose(core._pose_at(s)), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(
    st.tuples(*[st.floats(-0.02, 0.02)] * 6),
    st.tuples(*[st.floats(-0.02, 0.02)] * 6),
    st.floats(0.0, 2e-4),
    st.booleans(),
)
def test_the_steering_step_is_the_references(wanted, offset, budget, reached):
    """The kernel's step of the steering correction moves the offset as numpy does, by
    the budget toward the wanted correction or all the way, and sees the same size."""
    cores = [
        InterpolatorCore(
            np.array(lwr4.HOME), velocity=0.05, acceleration=0.25, brake_acceleration=2.0, ik=IK
        )
        for _ in range(2)
    ]
    for core in cores:
        core._wanted = np.array(wanted)
        core.offset = np.array(wanted if reached else offset)
    size = kernel.steer_step(cores[0]._wanted, cores[0].offset, budget, core.ROTATION_RADIUS)
    assert size == pytest.approx(cores[1]._correct_reference(budget), rel=1e-15, abs=1e-18)
    assert np.allclose(cores[0].offset, cores[1].offset, rtol=1e-15, atol=1e-18)
    if reached:
        assert size == 0.0 and np.array_equal(cores[0].offset, np.array(wanted))


capsules = st.integers(0, 6).flatmap(
    lambda n: st.tuples(
        st.lists(point, min_size=n, max_size=n),
        st.lists(point, min_size=n, max_size=n),
        st.lists(st.floats(0.0, 0.3), min_size=n, max_size=n),
    )
)


def _arrays(c):
    a, b = (np.array(x, dtype=float).reshape(-1, 3) for x in c[:2])
    return a, b, np.array(c[2], dtype=float)


def _reference(a, b) -> float:
    matrix = distance.capsule_distances(*a, *b)
    return float(np.min(matrix)) if matrix.size else math.inf


@settings(max_examples=300, deadline=None)
@given(capsules, capsules)
def test_the_least_capsule_distance_is_the_references_minimum(first, second):
    a, b = _arrays(first), _arrays(second)
    got = distance.least_capsule_distance(*a, *b)
    want = _reference(a, b)
    assert got == pytest.approx(want, abs=1e-9) or (math.isinf(got) and math.isinf(want))
    assert got <= want + 1e-9  # never a larger separation than there is


@settings(max_examples=100, deadline=None)
@given(capsules.filter(lambda c: len(c[2]) > 0), st.integers(0, 2))
def test_a_nan_anywhere_makes_the_least_distance_nan_never_a_clear_verdict(first, which):
    a = _arrays(first)
    arm = KIN.capsules(np.array(lwr4.HOME))
    poisoned = [x.copy() for x in a]
    poisoned[which].flat[0] = math.nan
    assert math.isnan(distance.least_capsule_distance(arm.a, arm.b, arm.radius, *poisoned))


def test_the_kernel_refuses_arrays_of_the_wrong_shape_with_a_message():
    arm = KIN.capsules(np.array(lwr4.HOME))
    with pytest.raises(ValueError, match="capsules"):
        kernel.capsule_min(arm.a, arm.b, arm.radius[:2], arm.a, arm.b, arm.radius)


def _same(a, b) -> bool:
    """Equal field for field, NaN equal to NaN (a datagram may carry any bits)."""
    if isinstance(a, tuple):
        return isinstance(b, tuple) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, float) and math.isnan(a):
        return isinstance(b, float) and math.isnan(b)
    return type(a) is type(b) and a == b


@settings(max_examples=300, deadline=None)
@given(
    st.binary(min_size=fri.MSR_SIZE, max_size=fri.MSR_SIZE), st.sampled_from(["ok", "id", "size"])
)
def test_the_kernel_decodes_any_measurement_as_the_reference(raw, header):
    """Any 916 bytes with a measurement's header (every bit pattern of every field: NaNs,
    negative counters, wrapped ints) decode to the reference's fields; a wrong id or
    declared size is no measurement for either."""
    size, datagram_id = fri.MSR_SIZE, fri.MSR_ID
    if header == "id":
        datagram_id = fri.CMD_ID
    if header == "size":
        size = fri.CMD_SIZE
    datagram = raw[:4] + struct.pack("<HH", size, datagram_id) + raw[8:]
    fields = kernel.fri_measurement(datagram)
    if header != "ok":
        assert fields is None
        with pytest.raises(fri.DatagramError):
            fri.decode_measurement(datagram)
        return
    assert _same(fields, tuple(fri.decode_measurement_reference(datagram)))
    assert _same(tuple(fri.decode_measurement(datagram)), fields)


@settings(max_examples=300, deadline=None)
@given(st.binary(min_size=fri.CMD_SIZE, max_size=fri.CMD_SIZE), st.integers(0, 2048))
def test_the_kernel_decodes_any_command_as_the_reference_and_refuses_other_sizes(raw, length):
    datagram = raw[:4] + struct.pack("<HH", fri.CMD_SIZE, fri.CMD_ID) + raw[8:]
    assert _same(kernel.fri_command(datagram), tuple(fri.decode_command_reference(datagram)))
    other = (datagram * 6)[:length]
    if length != fri.CMD_SIZE:
        assert kernel.fri_command(other) is None
        with pytest.raises(fri.DatagramError):
            fri.decode_command(other)


floats32 = st.floats(allow_nan=False, width=32) | st.floats(-1e6, 1e6)


@settings(max_examples=300, deadline=None)
@given(
    st.integers(-(2**20), 2**20),
    st.integers(-(2**20), 2**20),
    st.tuples(*[floats32] * 7),
    st.integers(-(2**31), 2**31 - 1),
    st.integers(-(2**31), 2**31 - 1),
    st.sampled_from([fri.CMD_JNTPOS, 0, 0x31, 2**32 - 1]),
)
def test_the_kernel_encodes_a_command_byte_for_byte_as_the_reference(
    send, refl, jnt_pos, number, request, flags
):
    args = (send, refl, jnt_pos)
    options = {"flags": flags, "request_number": number, "request": request}
    assert fri.encode_command(*args, **options) == fri.encode_command_reference(*args, **options)


@pytest.mark.parametrize(
    "bad", [{"request_number": 2**31}, {"request": -(2**31) - 1}, {"flags": 2**32}]
)
def test_a_command_field_beyond_its_width_is_refused_by_both(bad):
    options = {"request_number": 1, "request": 0, "flags": fri.CMD_JNTPOS, **bad}
    with pytest.raises((OverflowError, struct.error)):
        fri.encode_command(1, 1, (0.0,) * 7, **options)
    with pytest.raises((OverflowError, struct.error)):
        fri.encode_command_reference(1, 1, (0.0,) * 7, **options)


def test_a_joint_beyond_a_float32_is_refused_by_both():
    with pytest.raises(OverflowError):
        fri.encode_command(1, 1, (1e39,) + (0.0,) * 6)
    with pytest.raises((OverflowError, struct.error)):
        fri.encode_command_reference(1, 1, (1e39,) + (0.0,) * 6)


@st.composite
def measurement_fields(draw):
    seven = st.tuples(*[floats32] * 7)
    return {
        "send_seq": draw(st.integers(0, 2**20)),
        "refl_seq": draw(st.integers(0, 2**20)),
        "timestamp": draw(floats32),
        "state": draw(st.integers(0, 2)),
        "quality": draw(st.integers(0, 3)),
        "stats": draw(st.tuples(floats32, floats32, floats32, floats32, st.integers(0, 2**32 - 1))),
        "control": draw(st.sampled_from(list(fri.Control))),
        "msr_jnt_pos": draw(seven),
        "cmd_jnt_pos": draw(seven),
        "cmd_jnt_pos_fri_offset": draw(st.none() | seven) or fri._ZERO7,
        "msr_jnt_trq": draw(st.none() | seven) or fri._ZERO7,
        "served": draw(st.integers(-(2**31), 2**31 - 1)),
        "reason": draw(st.integers(0, len(fri.REASONS))),
        "cycle": draw(st.integers(0, 2**40)),
        "braked": draw(st.booleans()),
        "latched": draw(st.booleans()),
        "sample_time": draw(st.sampled_from([0.001, 0.01, 0.04])),
    }


@settings(max_examples=300, deadline=None)
@given(measurement_fields())
def test_the_kernel_encodes_a_measurement_byte_for_byte_as_the_reference(fields):
    send, refl = fields.pop("send_seq"), fields.pop("refl_seq")
    assert fri.encode_measurement(send, refl, **fields) == fri.encode_measurement_reference(
        send, refl, **fields
    )


@pytest.mark.parametrize(
    "bad",
    [{"state": 2**16}, {"quality": -1}, {"served": 2**31}, {"stats": (1.0, 0.0, 0.0, 0.0, -1)}],
)
def test_a_measurement_field_beyond_its_width_is_refused_by_both(bad):
    fields = {"timestamp": 0.0, "state": 1, "quality": 3, **bad}
    with pytest.raises((OverflowError, struct.error)):
        fri.encode_measurement(1, 0, **fields)
    with pytest.raises((OverflowError, struct.error)):
        fri.encode_measurement_reference(1, 0, **fields)


gap_value = st.floats(-4.0, 4.0) | st.sampled_from([math.nan, math.inf, -math.inf])


@settings(max_examples=300, deadline=None)
@given(st.tuples(*[gap_value] * 7), st.tuples(*[gap_value] * 7), st.booleans())
def test_the_largest_joint_gap_is_pythons_max_nans_included(a, b, as_array):
    """The kernel's largest |a_i - b_i| is what Python's max() takes over the joints, a
    NaN first kept and a later one skipped, from tuples or float64 arrays alike."""
    first = np.array(a) if as_array else a
    assert _same(geometry.joint_gap(first, b), geometry.joint_gap_reference(a, b))


def test_a_joint_gap_of_other_lengths_is_refused_by_both():
    for ask in (geometry.joint_gap, geometry.joint_gap_reference):
        with pytest.raises(ValueError):
            ask((0.0,) * 6, (0.0,) * 7)


def _udp_pair():
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sender.bind(("127.0.0.1", 0))
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.setsockopt(socket.SOL_SOCKET, 35, 1)  # SO_TIMESTAMPNS
    receiver.setblocking(False)
    return sender, receiver


def test_the_kernels_fri_read_takes_what_pythons_recvmsg_takes():
    """Every queued datagram, oldest first, as Python's recvmsg(2048) reads it (an
    oversized one truncated to 2048 bytes), with its sender and the kernel's arrival
    time; nothing queued and no wait: an empty list."""
    sender, receiver = _udp_pair()
    try:
        datagrams = [b"", b"x" * 916, b"y" * 4096, bytes(range(256))]
        assert kernel.fri_receive(receiver.fileno(), 0.0) == []
        for round_ in ("kernel", "python"):
            before = time.time()
            for d in datagrams:
                sender.sendto(d, receiver.getsockname())
            time.sleep(0.05)
            if round_ == "kernel":
                read = kernel.fri_receive(receiver.fileno(), 0.0)
            else:
                read = []
                for _ in datagrams:
                    data, ancillary, _, who = receiver.recvmsg(2048, 64)
                    seconds, nanoseconds = struct.unpack("ll", ancillary[0][2][:16])
                    read.append((data, seconds + nanoseconds * 1e-9, who))
            assert [r[0] for r in read] == [d[:2048] for d in datagrams]
            assert all(r[2] == sender.getsockname() for r in read)
            assert all(before - 0.01 <= r[1] <= time.time() for r in read)
    finally:
        sender.close()
        receiver.close()


def test_the_kernels_fri_read_waits_for_a_datagram_only_when_none_is_queued():
    sender, receiver = _udp_pair()
    try:
        began = time.monotonic()
        assert kernel.fri_receive(receiver.fileno(), 0.05) == []
        assert time.monotonic() - began >= 0.045  # it waited (about) the timeout, not more
        sender.sendto(b"late", receiver.getsockname())
        assert [r[0] for r in kernel.fri_receive(receiver.fileno(), 5.0)] == [b"late"]
        with pytest.raises(OSError):
            kernel.fri_receive(-1, 0.0)
    finally:
        sender.close()
        receiver.close()


def _array_calls() -> dict[str, tuple[object, list[object]]]:
    """Each kernel call that takes float64 arrays, with valid arguments (numbers as
    floats): the arrays' sizes are those its C signature names."""
    a = np.zeros
    return {
        "jacobian": (kernel.jacobian, [a(7 * 16), a(16), a(7), a(16), a(42)]),
        "joint_points": (kernel.joint_points, [a(7 * 16), a(16), a(16), a(7), a(30)]),
        "ik_step": (
            kernel.ik_step,
            [a(7 * 16), a(16), a(7), a(16), a(7), a(7), a(7), a(7), a(7), 0.01, 0.0],
        ),
        "path_pose": (kernel.path_pose, [a(16), a(3), a(3), 0.5, a(6), a(16)]),
        "steer_step": (kernel.steer_step, [a(6), a(6), 0.001, 0.1]),
    }


@pytest.mark.parametrize("call", sorted(_array_calls()))
def test_a_kernel_call_refuses_a_wrong_array_by_name_and_keeps_none_of_the_others(call):
    """Every array argument of the wrong size, or of another dtype, is a ValueError that
    names it, never a crash or a write out of bounds; and the arrays taken before it are
    let go (a buffer kept would pin the array for good: each call of a 1 kHz loop)."""
    fn, valid = _array_calls()[call]
    fn(*valid)  # the valid call works
    for index, argument in enumerate(valid):
        if not isinstance(argument, np.ndarray):
            continue
        for wrong in (np.zeros(argument.size + 1), argument.astype(np.float32)):
            args = list(valid)
            args[index] = wrong
            held = [sys.getrefcount(x) for x in args if isinstance(x, np.ndarray)]
            with pytest.raises(ValueError, match=r"expected \d+ float64 values"):
                fn(*args)
            after = [sys.getrefcount(x) for x in args if isinstance(x, np.ndarray)]
            assert after == held, f"{call}: argument {index} refused, another kept"


# -- speed and separation monitoring ---------------------------------------------------------
coordinates = st.floats(-2.0, 2.0)


def capsule_sets(count):
    """(a, b, radius) of `count` capsules."""
    return st.tuples(
        st.lists(st.tuples(coordinates, coordinates, coordinates), min_size=count, max_size=count),
        st.lists(st.tuples(coordinates, coordinates, coordinates), min_size=count, max_size=count),
        st.lists(st.floats(0.0, 0.3), min_size=count, max_size=count),
    ).map(lambda t: (_points(t[0]), _points(t[1]), np.array(t[2])))


def _points(coordinates):
    return np.array(coordinates, dtype=float).reshape(-1, 3)


cycles = st.tuples(
    st.floats(-0.004, 0.03),  # the clock's step: mostly forward, sometimes back
    st.floats(-0.05, 0.5),  # the envelopes' age (negative: stamped in this host's future)
    st.floats(0.0, 0.6),  # their age when the next are due
    st.floats(0.0, 0.004),  # how far the arm moved
    st.one_of(st.none(), st.integers(0, 6).flatmap(capsule_sets)),
)


@settings(max_examples=300, deadline=None)
@given(
    arm_capsules=st.integers(1, 5).flatmap(capsule_sets),
    run=st.lists(cycles, min_size=1, max_size=40),
    max_speed=st.floats(0.0, 0.3),
    slow_band=st.sampled_from([0.0, 0.4]),
    seed=st.integers(0, 2**16),
    dt=st.sampled_from([0.001, 0.004, 1e-5]),
)
def test_the_kernels_verdicts_are_the_references_cycle_by_cycle(
    arm_capsules, run, max_speed, slow_band, seed, dt
):
    """Over a run of checks (the arm moving, people or nobody, envelopes of any age, a
    clock that may step back), the compiled monitor says what the Python one says:
    separation, speed, protective distance, cap, stop, the tool's speed and how many
    cycles may pass unchecked."""
    params = SsmParams(slow_band=slow_band)
    kernel = SeparationMonitor(params, max_speed, compiled=True)
    reference = SeparationMonitor(params, max_speed, compiled=False)
    a, b, radius = arm_capsules
    rng = np.random.default_rng(seed)
    now = 0.0
    for step, age, due, moved, people in run:
        now += step
        a = a + rng.normal(size=a.shape) * moved
        b = b + rng.normal(size=b.shape) * moved
        got, got_quiet = kernel.check_cycle((a, b, radius), people, age, now, due, dt)
        want, want_quiet = reference.check_cycle((a, b, radius), people, age, now, due, dt)
        assert got_quiet == want_quiet
        for field in ("separation", "robot_speed", "protective", "cap", "tcp_speed"):
            g, w = getattr(got, field), getattr(want, field)
            assert g == pytest.approx(w, rel=1e-12, abs=1e-12, nan_ok=True), field
        assert got.stop is want.stop
        assert kernel.tcp_speed == pytest.approx(reference.tcp_speed, rel=1e-12, abs=1e-12)


@settings(max_examples=100, deadline=None)
@given(joints)
def test_the_kernels_capsules_into_a_buffer_are_the_arms_capsules(q):
    """The separation check's capsules, written into one buffer from the joints' tuple
    as a measurement has them, are `capsules(q)`; nothing else of the buffer changes."""
    buffer = KIN.capsules_buffer()
    radius = buffer.radius.copy()
    got = KIN.capsules_into(tuple(float(v) for v in q), buffer)
    want = KIN.capsules(q)
    assert got is buffer
    assert np.allclose(got.a, want.a, atol=1e-12) and np.allclose(got.b, want.b, atol=1e-12)
    assert np.array_equal(got.radius, radius) and np.array_equal(radius, want.radius)


@pytest.mark.parametrize("q", [(0.0,) * 6, (0.0,) * 6 + (math.nan,), "seven"])
def test_joints_that_are_not_seven_numbers_are_refused(q):
    with pytest.raises((ValueError, TypeError)):
        KIN.capsules_into(q, KIN.capsules_buffer())
