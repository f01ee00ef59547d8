"""NDI Polaris/Vicra driver: the combined API over pyserial, publishing tool poses.

configure: open the port, INIT, COMM (the device answers OKAY at the old rate,
then both switch), and for each tool PHRQ, PVWR (tool definition in 64-byte
chunks), PINIT, PENA. start: TSTART. Each update: BX (or TX), one Pose per
tool on its output port (`cto`, `rto`; metres, quaternion w-x-y-z, RMS error,
frame number, validity). MISSING and DISABLED tools are published as invalid
poses, and so is a frame the device marks valid whose values cannot be a
measurement (NaN, infinite, a non-unit rotation, outside the measurement volume):
a broken device never moves the robot. Every pose is stamped with its capture time,
from the frame number (`FrameClock`): a reply the line held is as old as it is, and
one held on the way to the device is not made older. Garbage bytes
and CRC errors are counted and skipped; a late reply is taken when it comes (the
request is not repeated behind it); after `reconnect_after` failed cycles in a row
(a timeout each) the driver reopens the port and initialises the device again (a
cable loss and re-plug). The driver says
itself what is wrong: `health` carries its fault state (link lost, no replies,
corrupt replies, impossible values) on every change, not only through silence.
"""

from __future__ import annotations

import contextlib
import select
import termios
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import serial

from components.tracking import ndi
from components.tracking.frame_clock import FrameClock
from components.tracking.ndi_rom import make_srom, read_tool_definition
from framework import schema
from framework.component import Component, Out, operation
from framework.errors import FwError, LocatedError
from framework.filekinds import FileKind, schema_then
from framework.files import UnreadableFile, read_file
from framework.messages import EventMessage, Pose
from framework.properties import prop
from framework.yamlio import load_yaml

_LINK_ERRORS = (OSError, serial.SerialException, termios.error)
BAUD_TO_CODE = {v: k for k, v in ndi.BAUD_CODES.items()}


class DriverError(FwError):
    """The device or its configuration cannot be used (the reason says why)."""


class ToolsFileError(DriverError, LocatedError):
    """A tools file is wrong (file:line:column and the field)."""


TOOLS_SCHEMA = "components.tracking:tools.schema.json"


@dataclass
class ToolSpec:
    """A tool to track: its name (output port), markers (mm) and definition bytes."""

    name: str
    markers: list[list[float]]
    rom: bytes


ROM_MAX_BYTES = 64 * 1024
"""A tool definition larger than this is not one (an NDI SROM image is under 1 kB)."""

MARKER_AGREEMENT_MM = 0.01
"""How far a tools file's marker may be from the same marker in its `.rom` (float32)."""


def load_tools(path: str | Path) -> list[ToolSpec]:
    """Tools from YAML (`tools: {cto: {markers: [[x,y,z], ...], rom: file}}`), checked.

    A tool names its markers, its NDI tool definition (`rom`, geometry read from the
    file), or both (they must agree). Without a `rom`, fw writes the SROM image."""
    doc = load_yaml(path)
    schema.require(doc, TOOLS_SCHEMA, ToolsFileError)
    out = []
    for name, spec in doc.data["tools"].items():
        markers, rom_path = spec.get("markers"), spec.get("rom")
        if rom_path:
            where = doc.location(("tools", name, "rom"))
            try:
                rom = read_file(Path(doc.file).parent / rom_path, ROM_MAX_BYTES)
            except UnreadableFile as exc:
                raise ToolsFileError(
                    f"cannot read tool definition {rom_path!r}: {exc.reason}", where
                ) from None
            try:
                definition = read_tool_definition(rom)
            except ValueError as exc:
                raise ToolsFileError(f"tool definition {rom_path!r}: {exc}", where) from None
            from_rom = [list(m) for m in definition.markers]
            if markers is not None and not _same_markers(markers, from_rom):
                raise ToolsFileError(
                    f"the markers of tool {name!r} differ from its definition {rom_path!r} "
                    f"({_marker_list(from_rom)}); correct one or leave the markers out",
                    doc.location(("tools", name, "markers")),
                )
            markers = from_rom
        elif markers is None:
            raise ToolsFileError(
                f"tool {name!r} needs its markers or its tool definition (rom: file.rom)",
                doc.location(("tools", name)),
            )
        else:
            rom = make_srom(markers, name)
        out.append(ToolSpec(name, markers, rom))
    return out


def _same_markers(a: list[list[float]], b: list[list[float]]) -> bool:
    return len(a) == len(b) and all(
        abs(x - y) <= MARKER_AGREEMENT_MM
        for p, q in zip(a, b, strict=True)
        for x, y in zip(p, q, strict=True)
    )


def _marker_list(markers: list[list[float]]) -> str:
    return ", ".join("[" + ", ".join(f"{v:g}" for v in m) + "]" for m in markers)


TOOLS_FILE = FileKind(
    "tools",
    "tools",
    "optical tools an NDI tracker follows (markers, .rom files)",
    schema_then(TOOLS_SCHEMA, load_tools, "tools"),
)


class NdiTracker(Component):
    """The Polaris Vicra (or any NDI combined-API tracker) as a component."""

    emits = ()
    device = prop(str, "", doc="serial device (e.g. /dev/ttyUSB0)")
    baud = prop(int, 115200, choices=sorted(BAUD_TO_CODE), doc="baud rate after COMM")
    tools_file = prop(str, "", doc="tools YAML (markers, tool definition files)", file="tools")
    binary = prop(bool, True, doc="stream with BX (binary) instead of TX (text)")
    timeout = prop(float, 0.25, unit="s", min=0.01, max=5.0, doc="reply timeout")
    frame_rate = prop(
        float, 20.0, unit="Hz", min=1.0, max=1000.0, doc="how fast the device numbers its frames"
    )
    reconnect_after = prop(int, 3, min=1, max=100, doc="failed cycles before reconnecting")
    frame = prop(str, "vicra", doc="frame name written in every pose")
    volume = prop(
        str, "vicra", choices=["vicra", "none"], doc="measurement volume poses must lie in"
    )
    cto = Out(Pose, doc="calibration tool optical (on the end-effector)")
    rto = Out(Pose, doc="reference tool optical (on the table)")
    health = Out(EventMessage, doc="the driver's own fault state {ok, fault} on every change")

    def __init__(self, name: str):
        super().__init__(name)
        self.serial: Any = None
        self.handles: dict[int, str] = {}
        self.counters = {
            "frames": 0,
            "crc_errors": 0,
            "timeouts": 0,
            "device_errors": 0,
            "reconnects": 0,
            "failed_cycles": 0,
            "invalid_values": 0,
        }
        self.fault = "not connected"
        self.firmware = ""  # the device's Freeze Tag (VER), once connected
        self._reported_fault: str | None = None
        self.tools: list[ToolSpec] = []
        self._rx = b""  # bytes from the device not taken yet (a late reply waits here)
        self._asked: tuple[float, float] | None = None  # the pending request (mono, wall)
        self._overdue = 0  # timeouts the pending request has run over
        self._clock = FrameClock(20.0)

    # -- lifecycle -------------------------------------------------------------------
    def configure_hook(self) -> bool:
        if not self.tools_file:
            raise DriverError("property tools_file is empty: name the tools YAML")
        self.tools = load_tools(self.tools_file)  # a problem refuses: stays PreOperational
        self._connect()
        return True

    def start_hook(self) -> bool:
        self._command("TSTART")
        return True

    def stop_hook(self) -> None:
        with contextlib.suppress(Exception):
            self._command("TSTOP")

    def cleanup_hook(self) -> None:
        self._close()

    def update_hook(self) -> None:
        if self.serial is None:
            self._try_reconnect()
            return
        try:
            tools, stamp = self._poll()
        except ndi.NdiError as exc:
            key = "crc_errors" if "CRC" in str(exc) else "device_errors"
            self.counters[key] += 1
            self._failed(str(exc))
            return
        except TimeoutError as exc:
            self.counters["timeouts"] += 1
            self._failed(str(exc))
            return
        except _LINK_ERRORS as exc:  # the device node went away (cable loss)
            self._failed(f"serial link lost: {exc}")
            self._close()
            return
        self.counters["failed_cycles"] = 0
        self.counters["frames"] += 1
        numbers = [tool.frame for tool in tools if tool.status != ndi.DISABLED]
        if numbers:  # when the device captured it; else when it was asked for
            stamp = self._clock.stamp(max(numbers), stamp, time.time())
        impossible = []
        margin = 50.0 if self.volume == "vicra" else None
        for tool in tools:
            name = self.handles.get(tool.handle)
            if name is None:
                continue
            valid = tool.status == ndi.VALID
            if valid:
                problem = ndi.frame_problem(tool, margin)
                if problem:
                    valid = False
                    impossible.append(f"{name}: {problem}")
                    self.counters["invalid_values"] += 1
            position = tuple(v / 1000.0 for v in tool.translation) if valid else (0.0, 0.0, 0.0)
            pose = Pose(
                position,
                tuple(tool.quaternion) if valid else (1.0, 0.0, 0.0, 0.0),
                stamp,
                tool.error / 1000.0 if valid else 0.0,
                tool.frame,
                valid,
                self.frame,
                name,
            )
            self.outputs[name].write(pose)
        self._report_fault(f"impossible values ({'; '.join(impossible)})" if impossible else "")

    def _report_fault(self, fault: str) -> None:
        """Publish the driver's fault state when it changes ('' when healthy)."""
        self.fault = fault
        if fault != self._reported_fault:
            self._reported_fault = fault
            message = {"ok": not fault, "fault": fault, "firmware": self.firmware, **self.counters}
            self.health.write(EventMessage(time.time(), "health", self.name, message))

    # -- the device ------------------------------------------------------------------
    def _open(self, baud: int) -> None:
        path = Path(self.device)
        if not self.device:
            raise DriverError("property device is empty: name the serial device")
        if not path.exists():
            raise DriverError(
                f"serial device {self.device!r} does not exist (is the tracker plugged in?)"
            )
        try:
            self.serial = serial.Serial(
                self.device, baudrate=baud, timeout=self.timeout, write_timeout=self.timeout
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise DriverError(f"cannot open {self.device!r} as a serial port: {exc}") from None

    def _close(self) -> None:
        self._rx, self._asked = b"", None
        if self.serial is not None:
            with contextlib.suppress(Exception):
                self.serial.close()
        self.serial = None

    def _connect(self) -> None:
        """Open at 9600 baud, INIT, switch baud, set up every tool."""
        self._close()
        self._clock = FrameClock(self.frame_rate)  # INIT restarts the frame counter
        self._open(9600)
        self.serial.reset_input_buffer()
        try:
            self._command("INIT")
        except (TimeoutError, ndi.NdiError) as exc:
            self._close()
            raise DriverError(f"no NDI device answers on {self.device!r}: {exc}") from None
        code = BAUD_TO_CODE[self.baud]
        self._command("COMM", f"{code}0000")  # OKAY comes at the old rate
        self.serial.baudrate = self.baud
        self.firmware = ndi.freeze_tag(self._command("VER", "4"))
        self._free_stale_handles()
        self.handles = {}
        for tool in self.tools:
            handle = int(self._command("PHRQ", "*********1****"), 16)
            for address in range(0, len(tool.rom), 64):
                chunk = tool.rom[address : address + 64].ljust(64, b"\0")
                self._command("PVWR", f"{handle:02X}{address:04X}{chunk.hex().upper()}")
            try:
                self._command("PINIT", f"{handle:02X}")
            except ndi.NdiError as exc:
                raise DriverError(f"the device refused tool {tool.name!r}: {exc}") from None
            self._command("PENA", f"{handle:02X}D")
            self.handles[handle] = tool.name

    def _free_stale_handles(self) -> None:
        """PHSR:01 lists handles left from an earlier session; PHF frees each."""
        reply = self._command("PHSR", "01")
        for i in range(int(reply[:2], 16)):
            handle = reply[2 + 5 * i : 4 + 5 * i]
            self._command("PHF", handle)

    def _command(self, name: str, params: str = "") -> str:
        if self._asked is not None:  # a stream reply still pending is dropped with the rest
            self._discard_input()
        self.serial.write(ndi.command(name, params))
        deadline = time.monotonic() + self.timeout
        while (line := self._take_line()) is None:
            chunk = self._read_some(deadline)
            if not chunk:
                raise TimeoutError(f"no reply within {self.timeout:g} s")
            self._rx += chunk
        return ndi.parse_reply(line)

    def _discard_input(self) -> None:
        """Forget what the device sent and any pending request (what waits is junk)."""
        self._rx, self._asked = b"", None
        self.serial.reset_input_buffer()

    def _take_line(self) -> bytes | None:
        """The first text reply (up to its CR) in the receive buffer, if complete."""
        line, cr, rest = self._rx.partition(b"\r")
        if not cr:
            return None
        self._rx = rest
        return line + cr

    def _poll(self) -> tuple[list[ndi.ToolFrame], float]:
        """One BX/TX round: every tool's frame, and when it was asked for (wall clock).

        A reply later than `timeout` is late, not lost: the request is not sent again
        while it is pending, and its reply is taken when it comes (a busy host can hold
        a serial line's bytes for a second; sending again would only queue more
        requests behind them). Until then each cycle fails with `TimeoutError`, one per
        `timeout` the reply is overdue, so a silent device is still reconnected after
        `reconnect_after` timeouts."""
        if self._asked is None:
            self._discard_input()
            self.serial.write(ndi.command("BX" if self.binary else "TX", "0801"))
            self._asked = (time.monotonic(), time.time())
            self._overdue = 0
        asked, stamp = self._asked
        deadline = asked + self.timeout * (self._overdue + 1)
        while True:
            try:
                reply = self._take_reply()
            except ndi.NdiError:
                self._asked = None  # answered, badly: ask again
                raise
            if reply is not None:
                self._asked = None
                return reply, stamp
            chunk = self._read_some(deadline)
            if not chunk:
                break
            self._rx += chunk
        self._overdue += 1
        raise TimeoutError(
            f"no {'BX' if self.binary else 'TX'} reply within {self.timeout * self._overdue:g} s"
        )

    def _take_reply(self) -> list[ndi.ToolFrame] | None:
        """The tools of the reply in the receive buffer, if it is complete (garbage
        before it is skipped; a text ERROR raises `NdiError`)."""
        if not self.binary:
            line = self._take_line()
            return None if line is None else ndi.decode_tx(ndi.parse_reply(line))[0]
        buffer = self._rx
        start = buffer.find(b"\xc4\xa5")
        if start < 0:
            if b"\r" in buffer and b"ERROR" in buffer:  # a text error instead of BX
                error = buffer[buffer.index(b"ERROR") :]
                self._rx = b""
                ndi.parse_reply(error[: error.index(b"\r") + 1])  # raises NdiError
            self._rx = buffer[-1:]  # a header may start with the last byte
            return None
        if len(buffer) - start < 6:
            return None
        total = ndi.bx_length(buffer[start : start + 6])
        if len(buffer) - start < total:
            return None
        self._rx = buffer[start + total :]
        tools, _ = ndi.decode_bx(buffer[start : start + total])
        return tools

    def _read_some(self, until: float) -> bytes:
        """What the device sent, waiting for a first byte until `until` (monotonic).
        Waits on the descriptor: changing the port's timeout would reconfigure the tty
        (tcsetattr) twice a read."""
        if not self.serial.in_waiting:
            remaining = until - time.monotonic()
            if remaining <= 0:
                return b""
            ready, _, _ = select.select([self.serial.fileno()], [], [], remaining)
            if not ready:
                return b""
        # readable with nothing waiting is a device that went away: read() says so
        return self.serial.read(max(1, self.serial.in_waiting))

    def _failed(self, reason: str) -> None:
        self.counters["failed_cycles"] += 1
        self.last_error = reason
        self._report_fault(reason)
        if self.counters["failed_cycles"] >= self.reconnect_after:
            self._close()

    def _try_reconnect(self) -> None:
        try:
            self._connect()
            self._command("TSTART")
        except (DriverError, TimeoutError, ndi.NdiError, *_LINK_ERRORS) as exc:
            self.last_error = f"reconnecting: {exc}"
            self._report_fault(f"device lost, reconnecting: {exc}")
            self._close()
            return
        self.counters["reconnects"] += 1
        self.counters["failed_cycles"] = 0
        self.last_error = ""

    @operation(readonly=True)
    def status(self) -> dict[str, Any]:
        """Connected or not, the firmware's Freeze Tag, counters, tool handles, last error."""
        return {
            "connected": self.serial is not None,
            "firmware": self.firmware,
            "ok": not self.fault,
            "fault": self.fault,
            **self.counters,
            "handles": {f"{h:02X}": n for h, n in self.handles.items()},
            "last_error": self.last_error,
        }
