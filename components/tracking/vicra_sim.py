"""A simulated NDI Polaris Vicra on a pseudo-terminal, speaking the combined API.

The device listens on a pty behind a stable symlink (like `/dev/serial/by-id/...`),
so a driver opens it with pyserial exactly as it would open the USB adapter, and
a cable loss removes the device node and a re-plug creates it again. It answers
INIT, COMM, VER, BEEP, PHSR, PHRQ, PVWR, PINIT, PENA, PDIS, PHF, TSTART, TSTOP, BX
and TX, with and without CRC (upper- or lower-case hex), at 20 Hz with 0.25 mm
RMS noise, inside the Vicra's pyramid field of view; tools can be occluded, and
faults injected: `silent` (stops answering), `bad_crc` (replies with a wrong
CRC), `garbage` (random bytes before each reply), and values a broken device marks
valid: `nan`, `inf`, `huge` (3e35 mm) positions; and the line can hold its replies
(`delay_replies`), as a busy host holds a serial device's bytes.

The field of view is an approximation of the Vicra pyramid (557-1336 mm from the
sensor, +-26 deg horizontally, +-23 deg vertically), enough to put a tool in or out.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import math
import os
import queue
import random
import select
import threading
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from components.domain.geometry import pose_matrix
from components.tracking import ndi
from components.tracking.ndi_rom import read_tool_definition
from framework.component import Component, In, operation
from framework.messages import Pose
from framework.ports import ReadStatus
from framework.properties import prop

VERSION = (
    "Polaris Vicra Control Firmware\n"
    "NDI S/N: P6-SIM00\n"
    "Characterization Date: 01/01/26\n"
    "Freeze Tag: Polaris Vicra Rev 007.000\n"
    "Freeze Date: 01/01/26\n"
    "(C) Northern Digital Inc.\n"
)
"""The VER reply, laid out as a Vicra's: clients read the firmware from its Freeze Tag."""
CORRUPT_VALUES = {"nan": math.nan, "inf": math.inf, "huge": 3e35}
"""Value faults: the device marks the frame valid but sends this as a position (mm)."""


def in_field_of_view(translation_mm: tuple[float, float, float]) -> bool:
    """True if a point (sensor frame, mm, z along the optical axis) is in the pyramid."""
    return ndi.in_vicra_volume(translation_mm)


@dataclass
class SimTool:
    """A tool as the device knows it."""

    handle: int
    rom: bytearray = field(default_factory=bytearray)
    name: str = ""
    markers: list[tuple[float, float, float]] = field(default_factory=list)
    initialized: bool = False
    enabled: bool = False

    def port_status(self) -> int:
        """The port status bits PHSR and BX/TX report for this tool."""
        return (
            ndi.PORT_OCCUPIED
            | (ndi.PORT_INITIALIZED if self.initialized else 0)
            | (ndi.PORT_ENABLED if self.enabled else 0)
        )


@dataclass
class ScenePose:
    """Where a named tool is (sensor frame) and whether something hides it."""

    translation: tuple[float, float, float] = (0.0, 0.0, 900.0)
    quaternion: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    occluded: bool = False


class VicraDevice:
    """The device itself: a thread answering on the pty master."""

    def __init__(self, link: str | Path, rate: float = 20.0, noise_mm: float = 0.25, seed: int = 0):
        self.link = Path(link)
        self.rate, self.noise_mm = rate, noise_mm
        self.random = random.Random(seed)
        self.scene: dict[str, ScenePose] = {}  # by the part name in the tool definition
        self.world: Any = None
        """Optional `callable(tool, seconds) -> (translation_mm, quaternion) | None` that
        moves the tools (the simulated OR); the scene's occlusion flags still apply.
        `seconds` is the frame's time since TSTART: a frame shows the world when the
        device captured it, at its frame rate, not when a request happened to read it."""
        self.frame_time = 0.0
        """Wall-clock time of the frame being made (for a world that follows stamped
        streams, such as the robot's measured TCP)."""
        self.fault = ""
        self.reply_delay = 0.0
        """Seconds the line holds each reply (a busy host's serial input), in order."""
        self.stream_requests = 0  # BX and TX received
        self.commands: list[str] = []
        self._lock = threading.Lock()
        self._master: int | None = None
        self._slave: int | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._reset_state()

    def _reset_state(self) -> None:
        self.initialized = False
        self.tracking = False
        self.baud = 9600
        self.tools: dict[int, SimTool] = {}
        self._next_handle = 0x0A
        self._t0 = time.monotonic()
        self._noise_frame = -1
        self._noise: dict[int, tuple[float, float, float]] = {}

    # -- the cable ---------------------------------------------------------------------
    def plug(self) -> str:
        """Create the device node (a new pty behind the stable link); returns the link."""
        master, slave = os.openpty()
        tty.setraw(slave)
        self._master, self._slave = master, slave
        self.link.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        self.link.symlink_to(os.ttyname(slave))
        self._reset_state()
        self._stop.clear()
        self._held: queue.Queue = queue.Queue()
        threading.Thread(target=self._deliver_held, name="vicra-line", daemon=True).start()
        self._thread = threading.Thread(target=self._serve, name="vicra-sim", daemon=True)
        self._thread.start()
        return str(self.link)

    def unplug(self) -> None:
        """Pull the cable: the device node disappears and the open port breaks."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(1.0)
            self._held.put((0.0, None, b""))
        with contextlib.suppress(FileNotFoundError):
            self.link.unlink()
        for fd in (self._master, self._slave):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = None

    # -- serving -------------------------------------------------------------------
    def _serve(self) -> None:
        buffer = b""
        master = self._master
        while not self._stop.is_set() and master is not None:
            ready, _, _ = select.select([master], [], [], 0.05)
            if not ready:
                continue
            try:
                chunk = os.read(master, 4096)
            except OSError:
                return
            buffer += chunk
            while b"\r" in buffer:
                line, _, buffer = buffer.partition(b"\r")
                response = self._answer(line)
                if response is None:
                    continue
                if self.fault == "garbage":
                    response = bytes(self.random.randrange(256) for _ in range(7)) + response
                if self.reply_delay > 0:
                    self._held.put((time.monotonic() + self.reply_delay, master, response))
                    continue
                with contextlib.suppress(OSError):
                    os.write(master, response)

    def _deliver_held(self) -> None:
        """Write the replies the line holds, each when its delay is over, in order."""
        while True:
            due, master, response = self._held.get()
            if master is None:
                return
            time.sleep(max(0.0, due - time.monotonic()))
            with contextlib.suppress(OSError):
                os.write(master, response)

    def _answer(self, line: bytes) -> bytes | None:
        if self.fault == "silent" or not line.strip():
            return None
        try:
            name, params, _ = ndi.parse_command(line)
        except ndi.NdiError:
            return self._error(ndi.BAD_CRC)
        if name not in ("BX", "TX"):  # the setup, not the stream
            self.commands.append(name)
        else:
            self.stream_requests += 1
        handler = getattr(self, f"_cmd_{name.lower()}", None)
        if handler is None:
            return self._error(ndi.INVALID_COMMAND)
        if not self.initialized and name not in ("INIT", "COMM", "VER", "BEEP"):
            return self._error(ndi.NOT_INITIALIZED)
        with self._lock:
            return handler(params)

    def _error(self, code: str) -> bytes:
        return self._reply(f"ERROR{code}")

    def _reply(self, text: str) -> bytes:
        frame = ndi.reply(text)
        if self.fault == "bad_crc":
            frame = frame[:-5] + (b"0000" if frame[-5:-1] != b"0000" else b"FFFF") + b"\r"
        return frame

    # -- commands ------------------------------------------------------------------
    def _cmd_init(self, params: str) -> bytes:
        self._reset_state()
        self.initialized = True
        return self._reply("OKAY")

    def _cmd_comm(self, params: str) -> bytes:
        if not params:
            return self._error(ndi.BAD_PARAMETERS)
        if params[0] not in ndi.BAUD_CODES:
            return self._error(ndi.OUT_OF_RANGE)
        self.baud = ndi.BAUD_CODES[params[0]]  # answered at the old rate, then switched
        return self._reply("OKAY")

    def _cmd_ver(self, params: str) -> bytes:
        return self._reply(VERSION)

    def _cmd_beep(self, params: str) -> bytes:
        return self._reply("1")

    def _cmd_phsr(self, params: str) -> bytes:
        kind = params[:2] or "00"
        picked = [
            t
            for t in self.tools.values()
            if kind == "00"
            or (kind == "01" and not t.enabled)
            or (kind == "02" and not t.initialized)
            or (kind == "03" and t.initialized and not t.enabled)
            or (kind == "04" and t.enabled)
        ]
        text = f"{len(picked):02X}" + "".join(
            f"{t.handle:02X}{t.port_status():03X}" for t in picked
        )
        return self._reply(text)

    def _cmd_phrq(self, params: str) -> bytes:
        if len(self.tools) >= 6:  # the Vicra tracks at most 6 rigid bodies
            return self._error(ndi.NO_HANDLE_AVAILABLE)
        handle = self._next_handle
        self._next_handle += 1
        self.tools[handle] = SimTool(handle)
        return self._reply(f"{handle:02X}")

    def _tool(self, params: str) -> SimTool | None:
        try:
            return self.tools.get(int(params[:2], 16))
        except ValueError:
            return None

    def _cmd_pvwr(self, params: str) -> bytes:
        tool = self._tool(params)
        if tool is None:
            return self._error(ndi.UNKNOWN_HANDLE)
        try:
            address = int(params[2:6], 16)
            data = bytes.fromhex(params[6:])
        except ValueError:
            return self._error(ndi.BAD_PARAMETERS)
        if len(data) != 64:
            return self._error(ndi.BAD_PARAMETERS)
        end = address + 64
        if len(tool.rom) < end:
            tool.rom.extend(bytes(end - len(tool.rom)))
        tool.rom[address:end] = data
        return self._reply("OKAY")

    def _cmd_pinit(self, params: str) -> bytes:
        tool = self._tool(params)
        if tool is None:
            return self._error(ndi.UNKNOWN_HANDLE)
        try:
            definition = read_tool_definition(tool.rom)
        except ValueError:
            return self._error(ndi.TOOL_INIT_FAILED)
        tool.name, tool.markers = definition.part, definition.markers
        tool.initialized = True
        return self._reply("OKAY")

    def _cmd_pena(self, params: str) -> bytes:
        tool = self._tool(params)
        if tool is None:
            return self._error(ndi.UNKNOWN_HANDLE)
        if not tool.initialized:
            return self._error(ndi.HANDLE_NOT_INITIALIZED)
        tool.enabled = True
        return self._reply("OKAY")

    def _cmd_pdis(self, params: str) -> bytes:
        tool = self._tool(params)
        if tool is None:
            return self._error(ndi.UNKNOWN_HANDLE)
        tool.enabled = False
        return self._reply("OKAY")

    def _cmd_phf(self, params: str) -> bytes:
        tool = self._tool(params)
        if tool is None:
            return self._error(ndi.UNKNOWN_HANDLE)
        del self.tools[tool.handle]
        return self._reply("OKAY")

    def _cmd_tstart(self, params: str) -> bytes:
        self.tracking = True
        self._t0 = time.monotonic()
        return self._reply("OKAY")

    def _cmd_tstop(self, params: str) -> bytes:
        self.tracking = False
        return self._reply("OKAY")

    def _frames(self) -> list[ndi.ToolFrame]:
        now = time.monotonic()
        frame = int((now - self._t0) * self.rate)
        captured = frame / self.rate  # the newest frame's capture, since TSTART
        self.frame_time = time.time() - (now - self._t0 - captured)
        if frame != self._noise_frame:  # one noise sample per device frame
            self._noise_frame = frame
            sigma = self.noise_mm / math.sqrt(3.0)  # per axis, so the 3-D RMS is noise_mm
            self._noise = {
                h: (
                    self.random.gauss(0, sigma),
                    self.random.gauss(0, sigma),
                    self.random.gauss(0, sigma),
                )
                for h in self.tools
            }
        out = []
        for handle, tool in sorted(self.tools.items()):
            if not tool.enabled:
                out.append(ndi.ToolFrame(handle, ndi.DISABLED))
                continue
            pose = self.scene.get(tool.name)
            if self.world is not None:
                seen = self.world(tool.name, captured)
                hidden = pose.occluded if pose is not None else False
                pose = None if seen is None else ScenePose(seen[0], seen[1], hidden)
            outside = pose is not None and not in_field_of_view(pose.translation)
            if pose is None or pose.occluded or outside:
                status = tool.port_status() | (ndi.PORT_OUT_OF_VOLUME if outside else 0)
                out.append(ndi.ToolFrame(handle, ndi.MISSING, port_status=status, frame=frame))
                continue
            noise = self._noise.get(handle, (0.0, 0.0, 0.0))
            position = tuple(p + n for p, n in zip(pose.translation, noise, strict=True))
            if self.fault in CORRUPT_VALUES:  # a broken device, marking garbage valid
                position = (CORRUPT_VALUES[self.fault], position[1], position[2])
            out.append(
                ndi.ToolFrame(
                    handle,
                    ndi.VALID,
                    pose.quaternion,
                    position,
                    self.noise_mm,
                    tool.port_status(),
                    frame,
                )
            )
        return out

    def _cmd_bx(self, params: str) -> bytes:
        if not self.tracking:
            return self._error(ndi.INVALID_MODE)
        frame = ndi.encode_bx(self._frames())
        if self.fault == "bad_crc":
            frame = frame[:-2] + bytes([frame[-2] ^ 0xFF, frame[-1]])
        return frame

    def _cmd_tx(self, params: str) -> bytes:
        if not self.tracking:
            return self._error(ndi.INVALID_MODE)
        return self._reply(ndi.encode_tx(self._frames()))


def synthetic_world(rig_name: str, robot: Any = None, head: Any = None) -> Any:
    """A world callable for `VicraDevice.world`: the robot seen by one of the synthetic
    trackers (noise-free: the device adds its own). `robot()` gives the end-effector in
    the base frame (4x4) or None, in which case the synthetic path is used; `head()`
    the reference tool in the base frame (4x4) or None (where the rig was set up)."""
    import dataclasses

    import numpy as np

    from components.domain.rigs import ee_path, standard_rigs

    rig = dataclasses.replace(next(r for r in standard_rigs() if r.name == rig_name), noise=0.0)
    rng = np.random.default_rng(0)

    def see(tool: str, seconds: float) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
        ee = robot() if robot is not None else None
        base_from_rto = head() if head is not None else None
        cto, rto = rig.observe(
            ee if ee is not None else ee_path(seconds), rng, base_from_rto=base_from_rto
        )
        pose = {"cto": cto, "rto": rto}.get(tool)
        if pose is None:
            return None
        return tuple(v * 1000.0 for v in pose.position), pose.orientation

    return see


class VicraSimulator(Component):
    """Hosts a `VicraDevice` in a component, so it runs in its own process and the
    simulated OR (or a test) can move, hide and break it by operations."""

    needs_configuration = True
    link = prop(str, "", doc="device path to create (default: a temp folder)")
    rate = prop(float, 20.0, unit="Hz", min=1.0, max=60.0, doc="frame rate")
    noise = prop(float, 0.25, unit="mm", min=0.0, max=10.0, doc="3-D RMS position noise")
    seed = prop(int, 0, doc="noise seed (repeatable runs)")
    follow_world = prop(bool, False, doc="move the tools with the synthetic tracking world")
    ee_pose = In(
        Pose,
        doc="the robot's TCP in its base frame (with follow_world; else a path); every "
        "sample is kept for a moment, so a frame shows the TCP of its capture time",
        policy={"type": "buffer", "size": 256},
    )
    head = In(Pose, doc="the reference tool in the robot base frame (with follow_world)")

    def configure_hook(self) -> bool:
        import tempfile

        path = self.link or str(Path(tempfile.mkdtemp(prefix="fw-vicra-")) / "ttyVICRA")
        self.device = VicraDevice(path, self.rate, self.noise, self.seed)
        self._tcp: collections.deque = collections.deque(maxlen=512)  # ~1 s at 500 Hz
        if self.follow_world:
            self.device.world = synthetic_world("vicra", self._robot, self._head)
        self.device.plug()
        return True

    def _robot(self) -> Any:
        """The robot's TCP (4x4) nearest the frame's capture time, or None before any."""
        while True:
            status, pose = self.ee_pose.read()
            if status is not ReadStatus.NEW or pose is None:
                break
            # on this host's clock, as the frame's time is (the robot's host may differ)
            stamp = self.local_stamp("ee_pose", pose.stamp)
            if stamp is not None:
                self._tcp.append(dataclasses.replace(pose, stamp=stamp))
        at, nearest, gap = self.device.frame_time, None, math.inf
        for pose in reversed(self._tcp):  # stamps rise: the frame's is near the newest
            if abs(pose.stamp - at) > gap:
                break
            nearest, gap = pose, abs(pose.stamp - at)
        return None if nearest is None else pose_matrix(nearest)

    def _head(self) -> Any:
        """The latest pose of the reference tool on the head clamp (4x4), or None."""
        status, pose = self.head.read()
        return None if status is ReadStatus.NO_DATA or pose is None else pose_matrix(pose)

    def cleanup_hook(self) -> None:
        self.device.unplug()

    @operation(readonly=True)
    def device_path(self) -> str:
        """Where the driver should open the port."""
        return str(self.device.link)

    @operation
    def place(
        self, tool: str, translation: list[float], quaternion: list[float] | None = None
    ) -> None:
        """Put a tool (by the name in its definition) at a pose (sensor frame, mm)."""
        pose = self.device.scene.setdefault(tool, ScenePose())
        pose.translation = tuple(float(v) for v in translation)  # type: ignore[assignment]
        if quaternion is not None:
            pose.quaternion = tuple(float(v) for v in quaternion)  # type: ignore[assignment]

    @operation
    def occlude(self, tool: str, hidden: bool = True) -> None:
        """Hide (or show again) a tool."""
        self.device.scene.setdefault(tool, ScenePose()).occluded = hidden

    @operation
    def inject(self, fault: str = "") -> None:
        """'' (none), 'silent', 'bad_crc', 'garbage', or a value marked valid: 'nan',
        'inf', 'huge' (3e35 mm)."""
        known = ("", "silent", "bad_crc", "garbage", *CORRUPT_VALUES)
        if fault not in known:
            raise ValueError(f"unknown fault {fault!r} ({', '.join(known[1:])})")
        self.device.fault = fault

    @operation
    def delay_replies(self, seconds: float = 0.0) -> None:
        """Hold every reply this long on the line, in order (0: none): what a busy host
        does to a serial device's bytes, measured up to seconds (docs/tracking.md)."""
        if not (math.isfinite(seconds) and 0.0 <= seconds <= 10.0):
            raise ValueError(f"delay {seconds!r} s: give 0 to 10 s")
        self.device.reply_delay = float(seconds)

    @operation
    def unplug(self) -> None:
        """Pull the cable."""
        self.device.unplug()

    @operation
    def replug(self) -> str:
        """Plug the cable back (the device restarts, uninitialised)."""
        return self.device.plug()

    @operation(readonly=True)
    def device_state(self) -> dict[str, Any]:
        """What the device believes: initialised, tracking, baud, tools, the commands
        it received since it was made (the first 100; BX and TX are not listed, only
        counted as `stream_requests`)."""
        return {
            "initialized": self.device.initialized,
            "tracking": self.device.tracking,
            "baud": self.device.baud,
            "tools": len(self.device.tools),
            "commands": self.device.commands[:100],
            "stream_requests": self.device.stream_requests,
        }
