"""The NDI combined API (Polaris/Vicra) on a byte level: framing, CRC, replies.

Shared by the driver and the simulator so both speak exactly the protocol and
nothing else. Commands are `CMD:params` + CRC-16 (4 upper-case hex) + CR, or
`CMD params` + CR without CRC; replies are text + CRC + CR (`OKAY`, `ERRORxx`,
data), or binary for `BX` (start sequence 0xA5C4 little-endian, length,
header CRC, body, body CRC). The CRC is CRC-16/ARC: polynomial 0x8005
reflected (0xA001), initial value 0, no final xor (`INIT:` -> E3A5, `OKAY` -> A896).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from framework.errors import FwError

CR = b"\r"
BX_START = 0xA5C4
VALID, MISSING, DISABLED = 0x01, 0x02, 0x04
BAUD_CODES = {
    "0": 9600,
    "1": 14400,
    "2": 19200,
    "3": 38400,
    "4": 57600,
    "5": 115200,
    "6": 921600,
    "7": 1228739,
    "A": 230400,
}
ERRORS = {
    "01": "invalid command",
    "02": "command too long",
    "03": "command too short",
    "04": "invalid CRC calculated for command",
    "05": "command timed out",
    "06": "bad COMM settings",
    "07": "incorrect number of parameters",
    "08": "invalid port handle selected",
    "0C": "command invalid in the current mode",
    "0D": "no tool is assigned to the selected port handle",
    "0E": "selected port handle not initialized",
    "0F": "selected port handle not enabled",
    "10": "system not initialized",
    "11": "unable to stop tracking",
    "12": "unable to start tracking",
    "13": "tool or SROM fault: unable to initialize",
    "23": "command parameter out of range",
    "28": "too many tools are enabled",
    "2A": "no memory available for dynamic allocation",
    "2B": "the requested port handle has not been allocated",
    "2C": "the requested port handle is unoccupied",
    "2D": "no more port handles available",
    "2F": "invalid port description",
    "30": "requested port is already assigned a port handle",
    "32": "invalid operation on the requested port handle",
}
"""The device's error codes (`ERRORxx`) that the Polaris Vicra and the simulator use,
numbered and named as in NDI's combined API (the same table as NDI's own CAPI sample
and ndicapi)."""
(
    INVALID_COMMAND,
    BAD_CRC,
    BAD_PARAMETERS,
    INVALID_MODE,
    HANDLE_NOT_INITIALIZED,
    NOT_INITIALIZED,
    TOOL_INIT_FAILED,
    OUT_OF_RANGE,
    UNKNOWN_HANDLE,
    NO_HANDLE_AVAILABLE,
) = ("01", "04", "07", "0C", "0E", "10", "13", "23", "2B", "2D")

PORT_OCCUPIED, PORT_INITIALIZED, PORT_ENABLED = 0x01, 0x10, 0x20
PORT_OUT_OF_VOLUME, PORT_PARTLY_IN_VOLUME = 0x40, 0x80
"""Port status bits, the same in PHSR (3 hex digits) and in BX/TX (32 bits)."""


class NdiError(FwError):
    """A protocol error: bad CRC, an ERRORxx reply, a malformed frame."""


def crc16(data: bytes) -> int:
    """CRC-16/ARC as the NDI API computes it."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def command(name: str, params: str = "", with_crc: bool = True) -> bytes:
    """A command frame: `NAME:params` + CRC + CR, or `NAME params` + CR."""
    if with_crc:
        body = f"{name}:{params}".encode("ascii")
        return body + f"{crc16(body):04X}".encode() + CR
    return f"{name} {params}".rstrip().encode("ascii") + CR if params else f"{name} ".encode() + CR


def parse_command(frame: bytes) -> tuple[str, str, bool]:
    """(name, params, had_crc) of a received command (CR stripped); `NdiError` if the
    CRC is wrong. Lower-case hex in the CRC is accepted."""
    text = frame.rstrip(b"\r").decode("ascii", "replace")
    if ":" in text:
        name, _, rest = text.partition(":")
        if len(rest) < 4:
            raise NdiError("command too short for its CRC")
        params, crc_text = rest[:-4], rest[-4:]
        try:
            sent = int(crc_text, 16)
        except ValueError:
            raise NdiError(f"CRC {crc_text!r} is not hex") from None
        if sent != crc16(f"{name}:{params}".encode("ascii", "replace")):
            raise NdiError("invalid CRC calculated for command")
        return name.upper(), params, True
    name, _, params = text.partition(" ")
    return name.upper(), params.strip(), False


def reply(text: str) -> bytes:
    """A text reply frame: text + CRC + CR."""
    body = text.encode("ascii")
    return body + f"{crc16(body):04X}".encode() + CR


def parse_reply(frame: bytes) -> str:
    """The text of a reply frame after checking its CRC; `NdiError` for ERRORxx."""
    body = frame.rstrip(b"\r")
    if len(body) < 4:
        raise NdiError(f"reply too short: {body!r}")
    text, crc_text = body[:-4], body[-4:]
    try:
        sent = int(crc_text, 16)
    except ValueError:
        raise NdiError(f"reply CRC {crc_text!r} is not hex") from None
    if sent != crc16(text):
        raise NdiError(f"bad reply CRC: {body!r}")
    decoded = text.decode("ascii", "replace")
    if decoded.startswith("ERROR"):
        code = decoded[5:7].upper()
        raise NdiError(f"device answered ERROR{code}: {ERRORS.get(code, 'unknown error')}")
    return decoded


def freeze_tag(version: str) -> str:
    """The firmware's Freeze Tag from a VER reply ('' if the reply has none): the line
    NDI's tools read to know which firmware answers."""
    for line in version.splitlines():
        key, _, value = line.partition(":")
        if key.strip().lower() == "freeze tag":
            return value.strip()
    return ""


@dataclass(frozen=True)
class ToolFrame:
    """One tool's data in a BX/TX reply: status, pose (q0 qx qy qz, mm), RMS error."""

    handle: int
    status: int
    quaternion: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    error: float = 0.0
    port_status: int = 0
    frame: int = 0


_HEADER = struct.Struct("<HH")
_U16 = struct.Struct("<H")
_POSE = struct.Struct("<8f")
_TAIL = struct.Struct("<II")


def encode_bx(tools: list[ToolFrame], system_status: int = 0) -> bytes:
    """A BX reply (what the device sends)."""
    body = bytearray([len(tools)])
    for tool in tools:
        body += bytes([tool.handle, tool.status])
        if tool.status == VALID:
            body += _POSE.pack(*tool.quaternion, *tool.translation, tool.error)
        if tool.status != DISABLED:
            body += _TAIL.pack(tool.port_status, tool.frame)
    body += _U16.pack(system_status)
    header = _HEADER.pack(BX_START, len(body))
    return header + _U16.pack(crc16(header)) + bytes(body) + _U16.pack(crc16(bytes(body)))


def bx_length(header: bytes) -> int:
    """Total length of a BX reply from its first 6 bytes (checking start and CRC)."""
    if len(header) < 6:
        raise NdiError(f"BX header of {len(header)} bytes (needs 6)")
    start, length = _HEADER.unpack_from(header, 0)
    if start != BX_START:
        raise NdiError(f"not a BX reply (start {start:#06x})")
    (crc,) = _U16.unpack_from(header, 4)
    if crc != crc16(header[:4]):
        raise NdiError("bad BX header CRC")
    return 6 + length + 2


def decode_bx(frame: bytes) -> tuple[list[ToolFrame], int]:
    """(tools, system status) of a whole BX reply; `NdiError` if anything is off."""
    total = bx_length(frame[:6])
    if len(frame) != total:
        raise NdiError(f"BX reply of {len(frame)} bytes, header says {total}")
    body = frame[6:-2]
    (crc,) = _U16.unpack_from(frame, total - 2)
    if crc != crc16(body):
        raise NdiError("bad BX body CRC")
    try:
        count, offset, tools = body[0], 1, []
        for _ in range(count):
            handle, status = body[offset], body[offset + 1]
            offset += 2
            values = None
            if status == VALID:
                values = _POSE.unpack_from(body, offset)
                offset += _POSE.size
            port_status, number = (0, 0)
            if status != DISABLED:
                port_status, number = _TAIL.unpack_from(body, offset)
                offset += _TAIL.size
            if values is not None:
                tools.append(
                    ToolFrame(
                        handle,
                        status,
                        tuple(values[:4]),
                        tuple(values[4:7]),
                        values[7],
                        port_status,
                        number,
                    )
                )
            else:
                tools.append(ToolFrame(handle, status, port_status=port_status, frame=number))
        (system,) = _U16.unpack_from(body, offset)
    except (IndexError, struct.error) as exc:
        raise NdiError(f"truncated BX body: {exc}") from None
    return tools, system


def _signed(value: float, digits: int, decimals: int) -> str:
    scaled = round(value * 10**decimals)
    limit = 10**digits - 1
    scaled = max(-limit, min(limit, scaled))
    return f"{'+' if scaled >= 0 else '-'}{abs(scaled):0{digits}d}"


def encode_tx(tools: list[ToolFrame], system_status: int = 0) -> str:
    """The text of a TX reply (before CRC)."""
    lines = [f"{len(tools):02X}"]
    for tool in tools:
        head = f"{tool.handle:02X}"
        if tool.status == DISABLED:
            lines.append(head + "DISABLED")
            continue
        if tool.status == MISSING:
            lines.append(f"{head}MISSING{tool.port_status:08X}{tool.frame:08X}")
            continue
        q = "".join(_signed(v, 5, 4) for v in tool.quaternion)
        t = "".join(_signed(v, 6, 2) for v in tool.translation)
        lines.append(
            f"{head}{q}{t}{_signed(tool.error, 5, 4)}{tool.port_status:08X}{tool.frame:08X}"
        )
    return lines[0] + "\n".join(lines[1:]) + f"\n{system_status:04X}"


def decode_tx(text: str) -> tuple[list[ToolFrame], int]:
    """(tools, system status) of a TX reply's text (CRC already checked)."""
    try:
        count = int(text[:2], 16)
        records = text[2:].split("\n")
        tools = []
        for record in records[:count]:
            handle = int(record[:2], 16)
            rest = record[2:]
            if rest.startswith("DISABLED"):
                tools.append(ToolFrame(handle, DISABLED))
            elif rest.startswith("MISSING"):
                tools.append(
                    ToolFrame(
                        handle, MISSING, port_status=int(rest[7:15], 16), frame=int(rest[15:23], 16)
                    )
                )
            else:
                q = tuple(int(rest[i : i + 6]) / 1e4 for i in range(0, 24, 6))
                t = tuple(int(rest[24 + i : 31 + i]) / 1e2 for i in range(0, 21, 7))
                error = int(rest[45:51]) / 1e4
                tools.append(
                    ToolFrame(
                        handle, VALID, q, t, error, int(rest[51:59], 16), int(rest[59:67], 16)
                    )
                )
        system = int(records[count], 16)
    except (ValueError, IndexError) as exc:
        raise NdiError(f"malformed TX reply: {exc}") from None
    return tools, system


VICRA_NEAR_MM, VICRA_FAR_MM = 557.0, 1336.0
VICRA_HALF_X, VICRA_HALF_Y = math.radians(26.0), math.radians(23.0)


def in_vicra_volume(translation_mm: tuple[float, ...], margin_mm: float = 0.0) -> bool:
    """True if a point (sensor frame, mm, z along the optical axis) is inside the Polaris
    Vicra's pyramid measurement volume (557-1336 mm, +-26 deg by +-23 deg), grown by
    `margin_mm`: a pose outside it cannot be a real measurement."""
    x, y, z = translation_mm
    if not all(math.isfinite(v) for v in (x, y, z)):
        return False
    near, far = VICRA_NEAR_MM - margin_mm, VICRA_FAR_MM + margin_mm
    return (
        near <= z <= far
        and abs(x) <= z * math.tan(VICRA_HALF_X) + margin_mm
        and abs(y) <= z * math.tan(VICRA_HALF_Y) + margin_mm
    )


def frame_problem(tool: ToolFrame, margin_mm: float | None = 50.0) -> str:
    """'' if a frame the device marks valid is a plausible measurement, else why not:
    a value that is NaN or infinite, a non-unit rotation, a position outside the
    Vicra's measurement volume (grown by `margin_mm`; None: no volume check), a
    negative error."""
    values = (*tool.translation, *tool.quaternion, tool.error)
    if not all(math.isfinite(v) for v in values):
        return "a value is NaN or infinite"
    if not quaternion_is_unit(tool.quaternion):
        return "the rotation is not a unit quaternion"
    if margin_mm is not None and not in_vicra_volume(tool.translation, margin_mm):
        where = ", ".join(f"{v:.6g}" for v in tool.translation)
        return f"the position ({where}) mm is outside the measurement volume"
    if tool.error < 0:
        return "the RMS error is negative"
    return ""


def quaternion_is_unit(q: tuple[float, ...], tolerance: float = 1e-3) -> bool:
    """True for a finite unit quaternion (a corrupt frame often is not)."""
    norm = math.sqrt(sum(v * v for v in q))
    return all(math.isfinite(v) for v in q) and abs(norm - 1.0) < tolerance
