"""Spec: the robot's envelopes port reads each sample as capsule arrays
(components/robot/envelopes.py). The compiled decoding judges every sample as the Python
reference does (the capsules as sent, or the same reason to refuse them), refuses what
is not a whole sample with the codec's own words, and hands out arrays nobody can
change and that keep nothing of the sample's memory."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from components.domain.kernel import COMPILED
from components.robot.envelopes import EnvelopeCapsules, PeopleCapsules
from framework import messages
from framework.messages import Envelopes, Pose

pytestmark = pytest.mark.skipif(
    not COMPILED, reason="the compiled kernel was not built (pip install -e .)"
)
KERNEL, REFERENCE = EnvelopeCapsules(), EnvelopeCapsules(compiled=False)
ODD = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -0.15])


def sample(capsules: int, extra: tuple[int, int, int], values, spoil, stamp: float) -> Envelopes:
    """An envelopes sample of `capsules` capsules whose arrays have `extra` values more
    (a sample that does not add up), its values drawn from `values`, one of them
    replaced by `spoil` (index, value) if given."""
    counts = (3 * capsules + extra[0], 3 * capsules + extra[1], capsules + extra[2])
    fields = [list(values[: counts[0]]), list(values[counts[0] : counts[0] + counts[1]])]
    fields.append([abs(v) for v in values[counts[0] + counts[1] : sum(counts)]])
    if spoil is not None and sum(counts):
        index = spoil[0] % sum(counts)
        for field in fields:
            if index < len(field):
                field[index] = spoil[1]
                break
            index -= len(field)
    return Envelopes(stamp, *(tuple(field) for field in fields))


envelopes = st.builds(
    sample,
    st.integers(0, 12),
    st.sampled_from([(0, 0, 0)] * 6 + [(1, 0, 0), (0, 1, 0), (0, 0, 1)]),
    st.lists(st.floats(-3.0, 3.0), min_size=200, max_size=200),
    st.none() | st.tuples(st.integers(0, 199), ODD),
    st.floats(0.0, 1e9) | ODD,
)


def same(got: PeopleCapsules, want: PeopleCapsules) -> None:
    assert got.wrong == want.wrong
    assert got.stamp == want.stamp or (math.isnan(got.stamp) and math.isnan(want.stamp))
    for mine, theirs in zip(got.capsules, want.capsules, strict=True):
        assert mine.shape == theirs.shape and mine.dtype == theirs.dtype == np.float64
        assert np.array_equal(mine, theirs)


@given(message=envelopes, publisher=st.integers(0, 2**64 - 1), seq=st.integers(0, 2**64 - 1))
def test_the_kernel_reads_every_sample_as_the_reference_does(message, publisher, seq):
    """Capsules as sent, or the same refusal: lengths that do not add up, a value that
    is not finite (or a sum too large to be metres), a negative radius, a stamp that is
    not a number; and the publisher and sequence number the port drops repeats by."""
    data = messages.encode(message, Envelopes, publisher, seq)
    got, got_publisher, got_seq = KERNEL.from_bytes(data)
    want, want_publisher, want_seq = REFERENCE.from_bytes(data)
    assert (got_publisher, got_seq) == (want_publisher, want_seq) == (publisher, seq)
    same(got, want)
    same(KERNEL.from_value(message), want)


def test_capsules_come_as_sent():
    message = Envelopes(5.0, (0.1, 0.2, 0.3, 1.0, 1.0, 1.0), (0.4, 0.5, 0.6, 2, 2, 2), (0.1, 0.2))
    got, _, _ = KERNEL.from_bytes(messages.encode(message, Envelopes, 3, 4))
    assert got.wrong == "" and got.stamp == 5.0
    assert got.a.tolist() == [[0.1, 0.2, 0.3], [1.0, 1.0, 1.0]]
    assert got.b.tolist() == [[0.4, 0.5, 0.6], [2.0, 2.0, 2.0]]
    assert got.radius.tolist() == [0.1, 0.2]


@pytest.mark.parametrize(
    "spoil",
    [
        lambda data: data[:-1],
        lambda data: data + b"\x00",
        lambda data: data[:30],
        lambda data: b"\x00garbage",
        lambda data: messages.encode(Pose(), Pose),
        lambda data: data[:32] + b"\xff\xff\xff\xff" + data[36:],
    ],
    ids=["truncated", "trailing", "headless", "garbage", "another type", "a count too large"],
)
def test_what_is_not_a_whole_sample_is_refused_as_the_codec_says(spoil):
    data = spoil(messages.encode(Envelopes(1.0, (0.0,) * 3, (1.0,) * 3, (0.1,)), Envelopes, 1, 1))
    with pytest.raises(messages.CodecError) as reference:
        messages.decode(data, Envelopes)
    with pytest.raises(messages.CodecError) as kernel:
        KERNEL.from_bytes(data)
    assert str(kernel.value) == str(reference.value)


def test_the_arrays_cannot_be_changed_and_keep_nothing_of_the_sample():
    data = bytearray(messages.encode(Envelopes(1.0, (0.0,) * 3, (1.0,) * 3, (0.1,)), Envelopes))
    for adapter in (KERNEL, REFERENCE):
        got, _, _ = adapter.from_bytes(bytes(data))
        for values in got.capsules:
            with pytest.raises(ValueError):
                values[0] = 7.0
    got, _, _ = KERNEL.from_bytes(data)
    data[36:44] = b"\xff" * 8  # the sample's memory reused by whoever owned it
    assert got.a[0].tolist() == [0.0, 0.0, 0.0]


def test_numbers_whose_sum_is_not_finite_are_not_metres():
    """Each finite, together beyond any float: refused as not finite, both ways."""
    message = Envelopes(1.0, (1e308, 1e308, 0.0), (1.0, 1.0, 1.0), (0.1,))
    for adapter in (KERNEL, REFERENCE):
        got, _, _ = adapter.from_bytes(messages.encode(message, Envelopes))
        assert got.wrong == "a coordinate or radius that is not finite"


@pytest.mark.parametrize(
    ("message", "wrong"),
    [
        (Envelopes(1.0, (0.0,) * 6, (1.0,) * 6, (0.1, -0.1)), "a negative radius or a stamp"),
        (Envelopes(1.0, (0.0,) * 6, (1.0,) * 3, (0.1,)), "6/3 coordinates for 1 capsules"),
        (Envelopes(1.0, (0.0,) * 3, (1.0,) * 3, (0.1, 0.2)), "3/3 coordinates for 2 capsules"),
    ],
    ids=["one radius negative", "more a than b", "more radii"],
)
def test_a_sample_that_is_not_capsules_is_refused_with_what_is_wrong(message, wrong):
    for adapter in (KERNEL, REFERENCE):
        got, _, _ = adapter.from_bytes(messages.encode(message, Envelopes))
        assert got.wrong.startswith(wrong) and len(got.a) == len(got.radius) == 0
        assert KERNEL.from_value(message).wrong == got.wrong


def test_the_reference_decodes_without_the_kernel(monkeypatch):
    """What the kernel is held to must not be the kernel."""
    from components.robot import envelopes

    class Broken:
        def envelopes_decode(self, *args):
            raise AssertionError("the reference called the kernel")

    monkeypatch.setattr(envelopes, "_fwkernel", Broken())
    message = Envelopes(2.0, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.1,))
    got, _, _ = REFERENCE.from_bytes(messages.encode(message, Envelopes))
    assert got.wrong == "" and got.radius.tolist() == [0.1]
