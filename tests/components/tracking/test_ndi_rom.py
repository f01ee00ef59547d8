"""Spec: NDI tool definitions (.rom SROM images) are read by the documented byte layout,
written so that a reader of that layout finds the same tool, and refused, with the
reason, when they are not one."""

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from components.tracking.ndi_rom import (
    SROM_SIZE,
    checksum,
    make_srom,
    read_tool_definition,
)

MARKERS = [[0.0, 0.0, 0.0], [0.0, 50.0, 0.0], [40.0, 80.0, 0.0], [-40.0, 95.0, 0.0]]


def architect_image(markers, part=b"8700339", manufacturer=b"NDI"):
    """An image laid out by hand from the documented offsets, as NDI 6D Architect
    writes it (not with the module's writer)."""
    image = bytearray(SROM_SIZE)
    image[0:3] = b"NDI"
    image[28] = len(markers)
    for i, m in enumerate(markers):
        image[72 + 12 * i : 84 + 12 * i] = struct.pack("<3f", *m)
    image[580 : 580 + len(manufacturer)] = manufacturer
    image[592 : 592 + len(part)] = part
    image[4:6] = struct.pack("<H", sum(image[6:]) % 65536)
    return bytes(image)


def test_a_real_layout_gives_its_part_number_and_marker_geometry():
    definition = read_tool_definition(architect_image(MARKERS))
    assert definition.part == "8700339" and definition.manufacturer == "NDI"
    assert [list(m) for m in definition.markers] == MARKERS


def test_written_images_have_the_real_size_magic_checksum_and_fields():
    image = make_srom(MARKERS, "cto")
    assert len(image) == SROM_SIZE and image[:3] == b"NDI"
    assert struct.unpack_from("<H", image, 4)[0] == checksum(image)
    assert image[28] == 4 and image[655] == 41, "four passive spheres"
    assert struct.unpack_from("<3f", image, 72 + 12 * 2) == (40.0, 80.0, 0.0)
    assert image[592:595] == b"cto"


@given(
    st.lists(
        st.lists(st.floats(-500, 500, allow_nan=False, width=32), min_size=3, max_size=3),
        min_size=3,
        max_size=20,
    ),
    st.text(alphabet="abcdefghijklmnopqrstuvwxyz0123456789_", min_size=1, max_size=20),
)
def test_any_tool_round_trips(markers, part):
    definition = read_tool_definition(make_srom(markers, part))
    assert definition.part == part
    assert [list(m) for m in definition.markers] == markers


def test_padding_after_the_image_is_ignored():
    """A device receives the image in 64-byte chunks: its copy ends with zeros."""
    padded = make_srom(MARKERS, "rto") + bytes(16)
    assert read_tool_definition(padded).part == "rto"


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        (lambda b: b[:400], "truncated tool definition: 400 bytes of 752"),
        (lambda b: b"XYZ" + b[3:], "does not start with 'NDI'"),
        (lambda b: b[:100] + bytes([b[100] ^ 0x40]) + b[101:], "corrupt tool definition"),
        (lambda b: b[:28] + bytes([2]) + b[29:], "checksum"),
    ],
    ids=["truncated", "not-ndi", "flipped-bit", "count-changed"],
)
def test_damaged_definitions_are_refused_with_the_reason(damage, reason):
    with pytest.raises(ValueError, match=reason):
        read_tool_definition(damage(make_srom(MARKERS, "cto")))


@pytest.mark.parametrize(
    ("count", "bad_value", "reason"),
    [(2, 0.0, "has 2 markers"), (21, 0.0, "has 21 markers"), (3, float("nan"), "NaN")],
)
def test_impossible_geometry_is_refused(count, bad_value, reason):
    image = bytearray(architect_image([[bad_value, 0.0, 0.0], [1, 0, 0], [0, 1, 0]]))
    image[28] = count
    image[4:6] = struct.pack("<H", checksum(image))
    with pytest.raises(ValueError, match=reason):
        read_tool_definition(bytes(image))


def test_the_earlier_stand_in_format_is_still_read():
    stand_in = b"FWROM1" + b"cto".ljust(16, b"\0") + bytes([3])
    stand_in += b"".join(struct.pack("<3f", *m) for m in MARKERS[:3])
    definition = read_tool_definition(stand_in)
    assert definition.part == "cto" and [list(m) for m in definition.markers] == MARKERS[:3]


def test_writing_refuses_a_tool_that_cannot_be_tracked():
    with pytest.raises(ValueError, match="3 to 20 markers, not 2"):
        make_srom(MARKERS[:2], "cto")
