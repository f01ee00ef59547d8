"""NDI tool definition files (`.rom`): the SROM image a Polaris needs for each passive tool.

A real `.rom` file (made with NDI 6D Architect) is a fixed 752-byte image,
little-endian. NDI does not publish its layout; the fields fw reads and writes are
the ones observed in real files and documented by their public parsers:

| bytes   | field                                                        |
|---------|--------------------------------------------------------------|
| 0-2     | `NDI`                                                        |
| 4-5     | checksum: the sum of bytes 6-751, modulo 2^16 (uint16)       |
| 8       | 1                                                            |
| 12, 15  | tool sub type (2: undefined), main type (0: unknown)         |
| 24      | maximum marker angle (degrees, 90)                           |
| 28      | marker count (3-20)                                          |
| 32      | minimum markers to track (3)                                 |
| 36-39   | maximum 3-D marker error (float32, mm; 2.0)                  |
| 72-311  | marker positions: 20 x (x, y, z) float32, mm                 |
| 312-551 | marker normals: 20 x (x, y, z) float32                       |
| 552-571 | firing sequence (active tools)                               |
| 572-575 | tracking LED, LEDs 1-3 (31: none)                            |
| 576     | tool-in-port diode (9: present)                              |
| 580-591 | manufacturer (ASCII)                                         |
| 592-611 | part number (ASCII): the name the simulated Vicra matches    |
| 612     | 9                                                            |
| 613-652 | face and group of each marker (1)                            |
| 653     | algorithm flags (0x80: unique geometry)                      |
| 655     | marker type (41: passive sphere)                             |
| 656-751 | face normals: 8 x (x, y, z) float32                          |

fw's earlier stand-in format (`FWROM1`, a name and the markers) is still read, so
tool files written before keep working; fw now writes real SROM images.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

SROM_SIZE = 752
SROM_MAGIC = b"NDI"
MAX_MARKERS = 20
STAND_IN_MAGIC = b"FWROM1"

_MARKERS_AT, _NORMALS_AT = 72, 312
_MANUFACTURER_AT, _PART_AT = 580, 592
_COUNT_AT, _MIN_COUNT_AT, _MAX_ERROR_AT = 28, 32, 36
_PASSIVE_SPHERE = 41


@dataclass(frozen=True)
class ToolDefinition:
    """What fw needs from a tool definition: the part number and the marker geometry."""

    part: str
    markers: list[tuple[float, float, float]]
    manufacturer: str = ""


def checksum(image: bytes | bytearray) -> int:
    """The SROM checksum: the sum of every byte after the checksum field, modulo 2^16."""
    return sum(image[6:]) & 0xFFFF


def make_srom(markers_mm: list[list[float]], part: str, manufacturer: str = "fw") -> bytes:
    """An SROM image for a passive tool (markers in the tool frame, mm): the file NDI 6D
    Architect would write, with the fields of the module docstring."""
    if not 3 <= len(markers_mm) <= MAX_MARKERS:
        raise ValueError(f"a tool has 3 to {MAX_MARKERS} markers, not {len(markers_mm)}")
    image = bytearray(SROM_SIZE)
    image[0:3] = SROM_MAGIC
    image[8] = 1
    image[12] = 2
    image[24] = 90
    image[_COUNT_AT] = len(markers_mm)
    image[_MIN_COUNT_AT] = 3
    struct.pack_into("<f", image, _MAX_ERROR_AT, 2.0)
    for i, marker in enumerate(markers_mm):
        struct.pack_into("<3f", image, _MARKERS_AT + 12 * i, *marker)
        struct.pack_into("<3f", image, _NORMALS_AT + 12 * i, 0.0, 0.0, 1.0)
    image[552 : 552 + len(markers_mm)] = bytes(range(len(markers_mm)))
    image[572:576] = bytes([31, 31, 31, 31])
    image[576] = 9
    image[_MANUFACTURER_AT : _MANUFACTURER_AT + 12] = _ascii(manufacturer, 12)
    image[_PART_AT : _PART_AT + 20] = _ascii(part, 20)
    image[612] = 9
    image[613 : 613 + len(markers_mm)] = bytes([1] * len(markers_mm))
    image[633 : 633 + len(markers_mm)] = bytes([1] * len(markers_mm))
    image[653] = 0x80
    image[655] = _PASSIVE_SPHERE
    struct.pack_into("<3f", image, 656, 0.0, 0.0, 1.0)
    struct.pack_into("<H", image, 4, checksum(image))
    return bytes(image)


def read_tool_definition(data: bytes | bytearray) -> ToolDefinition:
    """The part number and markers of a tool definition (an SROM image, or fw's older
    stand-in); ValueError saying what is wrong otherwise. Trailing padding (a device
    receives the image in 64-byte chunks) is ignored."""
    data = bytes(data)
    if data.startswith(STAND_IN_MAGIC):
        return _read_stand_in(data)
    if not data.startswith(SROM_MAGIC):
        raise ValueError("not an NDI tool definition (it does not start with 'NDI')")
    if len(data) < SROM_SIZE:
        raise ValueError(f"truncated tool definition: {len(data)} bytes of {SROM_SIZE}")
    image = data[:SROM_SIZE]
    (stored,) = struct.unpack_from("<H", image, 4)
    if stored != checksum(image):
        raise ValueError(
            f"corrupt tool definition: checksum {stored:#06x}, content sums to "
            f"{checksum(image):#06x}"
        )
    count = image[_COUNT_AT]
    if not 3 <= count <= MAX_MARKERS:
        raise ValueError(f"the definition has {count} markers (a tool has 3 to {MAX_MARKERS})")
    markers = [struct.unpack_from("<3f", image, _MARKERS_AT + 12 * i) for i in range(count)]
    if not all(math.isfinite(v) for marker in markers for v in marker):
        raise ValueError("a marker position is NaN or infinite")
    return ToolDefinition(
        _text(image[_PART_AT : _PART_AT + 20]),
        markers,
        _text(image[_MANUFACTURER_AT : _MANUFACTURER_AT + 12]),
    )


def _read_stand_in(data: bytes) -> ToolDefinition:
    if len(data) < 23:
        raise ValueError("truncated tool definition")
    count = data[22]
    if len(data) < 23 + 12 * count:
        raise ValueError("truncated tool definition")
    markers = [struct.unpack_from("<3f", data, 23 + 12 * i) for i in range(count)]
    return ToolDefinition(_text(data[6:22]), markers)


def _ascii(text: str, size: int) -> bytes:
    return text.encode("ascii", "replace")[:size].ljust(size, b"\0")


def _text(field: bytes) -> str:
    return field.split(b"\0", 1)[0].decode("ascii", "replace").strip()
