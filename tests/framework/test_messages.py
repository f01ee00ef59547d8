"""Spec: every catalog message survives the codec, and bad bytes are refused, never misread."""

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from framework import messages
from framework.messages import (
    CATALOG,
    CodecError,
    ConfigAck,
    EventMessage,
    JointState,
    Pose,
    Scalar,
    Skeleton,
    Skeletons,
    decode,
    encode,
)

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
text = st.text(max_size=20)
i64 = st.integers(-(2**63), 2**63 - 1)
json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-1000, 1000)
    | text
    | st.floats(allow_nan=False, allow_infinity=False),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(text, inner, max_size=3),
    max_leaves=8,
)
skeleton = st.builds(
    Skeleton,
    i64,
    st.lists(finite, max_size=45).map(tuple),
    st.lists(finite, max_size=15).map(tuple),
)
SAMPLES = st.one_of(
    st.builds(
        Pose,
        st.tuples(finite, finite, finite),
        st.tuples(finite, finite, finite, finite),
        finite,
        finite,
        i64,
        st.booleans(),
        text,
        text,
    ),
    st.builds(JointState, finite, *[st.lists(finite, max_size=7).map(tuple)] * 3),
    st.builds(Skeletons, finite, text, st.lists(skeleton, max_size=3).map(tuple)),
    st.builds(EventMessage, finite, text, text, st.dictionaries(text, json_values, max_size=4)),
    st.builds(ConfigAck, finite, i64, st.booleans(), text, text, text),
    st.builds(Scalar, finite, finite),
)


@settings(max_examples=300, deadline=None)
@given(sample=SAMPLES, publisher=st.integers(0, 2**63), seq=st.integers(0, 2**63))
def test_every_message_round_trips(sample, publisher, seq):
    kind = type(sample)
    assert decode(encode(sample, kind, publisher, seq), kind) == (sample, publisher, seq)


@pytest.mark.parametrize(("value", "kind"), [(1.5, float), (-3, int), (True, bool), ("é", str)])
def test_builtin_scalars_round_trip(value, kind):
    assert decode(encode(value, kind), kind)[0] == value


@settings(max_examples=300, deadline=None)
@given(sample=SAMPLES, data=st.data())
def test_corrupt_bytes_raise_codec_errors_only(sample, data):
    raw = bytearray(encode(sample, type(sample)))
    action = data.draw(st.sampled_from(["truncate", "flip", "append"]))
    if action == "truncate":
        raw = raw[: data.draw(st.integers(0, len(raw) - 1))]
    elif action == "flip":
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] ^= data.draw(st.integers(1, 255))
    else:
        raw += data.draw(st.binary(min_size=1, max_size=8))
    try:
        value, _, _ = decode(bytes(raw), type(sample))
    except CodecError:
        return
    assert type(value) is type(sample)  # a flip inside a number is still a valid sample


def test_a_sample_of_another_type_is_refused_naming_the_expected_type():
    raw = encode(Scalar(1.0, 2.0), Scalar)
    with pytest.raises(CodecError, match="expected Pose"):
        decode(raw, Pose)


def test_writing_the_wrong_type_is_refused():
    with pytest.raises(CodecError, match="expected Pose, got Scalar"):
        encode(Scalar(), Pose)
    with pytest.raises(CodecError, match="needs 3 numbers"):
        encode(Pose(position=(1.0, 2.0)), Pose)
    with pytest.raises(CodecError, match="plain JSON"):
        encode(EventMessage(payload={"x": object()}), EventMessage)
    with pytest.raises(CodecError, match="plain JSON"):
        encode(EventMessage(payload={"x": math.nan}), EventMessage)


def test_type_ids_differ_per_type_and_unknown_names_are_listed():
    ids = {messages.type_id(k) for k in CATALOG.values()}
    assert len(ids) == len(CATALOG)
    with pytest.raises(CodecError, match=r"known: .*Pose"):
        messages.resolve_type("Posture")


def test_nan_poses_are_recognisable():
    assert not Pose(position=(math.nan, 0.0, 0.0)).is_finite()
    assert Pose().is_finite()
