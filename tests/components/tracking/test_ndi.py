"""Spec: the NDI combined API framing, CRC and replies, byte for byte."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from components.tracking import ndi


def test_crc_matches_the_published_constants():
    assert ndi.crc16(b"INIT:") == 0xE3A5
    assert ndi.crc16(b"OKAY") == 0xA896


def test_commands_with_and_without_crc():
    assert ndi.command("INIT") == b"INIT:E3A5\r"
    assert ndi.command("INIT", with_crc=False) == b"INIT \r"
    assert ndi.command("COMM", "50000", with_crc=False) == b"COMM 50000\r"
    assert ndi.parse_command(b"INIT:E3A5\r") == ("INIT", "", True)
    assert ndi.parse_command(b"INIT:e3a5\r") == ("INIT", "", True), "lower-case hex"
    assert ndi.parse_command(b"PENA 0AD\r") == ("PENA", "0AD", False)
    with pytest.raises(ndi.NdiError, match="invalid CRC"):
        ndi.parse_command(b"INIT:E3A6\r")


def test_replies_are_checked_and_errors_named():
    assert ndi.parse_reply(ndi.reply("OKAY")) == "OKAY"
    with pytest.raises(
        ndi.NdiError, match="ERROR2B: the requested port handle has not been allocated"
    ):
        ndi.parse_reply(ndi.reply("ERROR2B"))
    with pytest.raises(ndi.NdiError, match="bad reply CRC"):
        ndi.parse_reply(b"OKAY0000\r")


finite = st.floats(-1e4, 1e4, allow_nan=False, width=32)
tool_frames = st.builds(
    lambda handle, status, q, t, error, port, frame: ndi.ToolFrame(
        handle,
        status,
        q if status == ndi.VALID else (1.0, 0.0, 0.0, 0.0),
        t if status == ndi.VALID else (0.0, 0.0, 0.0),
        error if status == ndi.VALID else 0.0,
        port if status != ndi.DISABLED else 0,
        frame if status != ndi.DISABLED else 0,
    ),
    st.integers(1, 255),
    st.sampled_from([ndi.VALID, ndi.MISSING, ndi.DISABLED]),
    st.tuples(finite, finite, finite, finite),
    st.tuples(finite, finite, finite),
    finite,
    st.integers(0, 2**32 - 1),
    st.integers(0, 2**32 - 1),
)


@settings(max_examples=200, deadline=None)
@given(tools=st.lists(tool_frames, max_size=6), system=st.integers(0, 0xFFFF))
def test_bx_replies_round_trip(tools, system):
    decoded, status = ndi.decode_bx(ndi.encode_bx(tools, system))
    assert status == system and len(decoded) == len(tools)
    for got, sent in zip(decoded, tools, strict=True):
        assert (got.handle, got.status, got.frame) == (sent.handle, sent.status, sent.frame)
        assert got.translation == pytest.approx(sent.translation, rel=1e-6, abs=1e-3)


@settings(max_examples=300, deadline=None)
@given(tools=st.lists(tool_frames, min_size=1, max_size=3), data=st.data())
def test_corrupt_bx_replies_raise_only_protocol_errors(tools, data):
    frame = bytearray(ndi.encode_bx(tools))
    i = data.draw(st.integers(0, len(frame) - 1))
    frame[i] ^= data.draw(st.integers(1, 255))
    cut = data.draw(st.integers(0, len(frame)))
    with pytest.raises(ndi.NdiError):
        ndi.decode_bx(bytes(frame[:cut]) if cut < len(frame) else bytes(frame))


def test_tx_replies_round_trip_with_missing_and_disabled_tools():
    tools = [
        ndi.ToolFrame(1, ndi.VALID, (1.0, 0.0, 0.0, 0.0), (10.5, -20.25, 1000.0), 0.12, 0x31, 42),
        ndi.ToolFrame(2, ndi.MISSING, port_status=1, frame=42),
        ndi.ToolFrame(3, ndi.DISABLED),
    ]
    decoded, _ = ndi.decode_tx(ndi.encode_tx(tools))
    assert decoded == tools
    with pytest.raises(ndi.NdiError, match="malformed TX"):
        ndi.decode_tx("zz")
