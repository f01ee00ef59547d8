"""A slow link where the kernel has no netem: a wire of two TAP devices and a process
that carries each frame across after its delay.

`framework/netns.py` delays a host's link with `tc netem` where the kernel has
`sch_netem`. Some VMs' kernels have neither it nor nftables' `queue` (no NFQUEUE),
so there the host's link is swapped, for the time of the fault, for this wire:

    host's namespace                    this machine's namespace
    `dly0` (a TAP, the host's address)  `<prefix>d<n>` (a TAP in the bridge)
           \\                                 /
            this process: frames the host sends wait `delay` (+- `jitter`)

A TAP opened without IFF_VNET_HDR offers no checksum or segmentation offload, so
every frame is whole (an Ethernet frame of at most the MTU) and can be carried by
`os.read`/`os.write`, which a veth end read with a packet socket cannot promise.

What it does, stated as netem's terms: `delay` on what the host sends, `jitter` drawn
uniformly in [-jitter, +jitter] per frame but never reordering (a frame leaves no
earlier than the one before it: netem reorders unless told otherwise), `loss` a random
drop of each frame either way. What the host receives is not delayed.

Run by `Hosts.impair` as `python -m framework.netns_delay HOSTTAP BRIDGETAP DELAY
JITTER LOSS`: it creates both TAPs, prints `ready` and carries frames until killed
(`Hosts.heal`). It runs at SCHED_FIFO `PRIORITY` where the host allows it (netem
delays in the kernel's softirq, ahead of every program): as an ordinary process on a
busy 2-core machine it waits for a core behind the deployment, and a LAN's 0.2 ms
would come out as milliseconds. Where the host does not allow it, it says so on
stderr and carries frames at its ordinary priority. Its death takes both TAPs with
it: the host is then cut off, which is a partition, and the robot side brakes on what
it stops hearing.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import heapq
import os
import random
import select
import signal
import struct
import sys
import time

_TUNSETIFF = 0x400454CA
_IFF_TAP, _IFF_NO_PI = 0x0002, 0x1000
FRAME = 65536
"""Bytes read at most per frame (a TAP gives one frame per read)."""
DOWN_WAIT = 0.001
"""s to wait after a TAP gave an error instead of a frame (its device down)."""
GONE = (errno.EBADFD, errno.ENODEV, errno.ENXIO)
"""What a TAP's read says once its device is gone: the wire has nothing left to carry."""
PRIORITY = 70
"""SCHED_FIFO priority of the wire: above the bus's threads and the heartbeats (1),
below the device loops (framework/realtime.py, 80), whose cycles a network does not
take on a real machine."""


def open_tap(name: str) -> int:
    """A new TAP device `name` (gone when its descriptor closes), as a non-blocking fd."""
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    fcntl.ioctl(fd, _TUNSETIFF, struct.pack("16sH", name.encode(), _IFF_TAP | _IFF_NO_PI))
    return fd


class Wire:
    """Carries frames between the host's TAP and the bridge's (see the module docstring).
    `now` is the clock (seconds); `draw` gives a uniform number in [0, 1)."""

    def __init__(
        self,
        delay: float,
        jitter: float = 0.0,
        loss: float = 0.0,
        now=time.monotonic,
        draw=random.random,
    ):
        self.delay, self.jitter, self.loss = delay, jitter, loss
        self.now, self.draw = now, draw
        self._queue: list[tuple[float, int, bytes]] = []
        self._last = -float("inf")
        self._count = 0
        self.dropped = 0

    def lost(self) -> bool:
        """Whether the next frame (either way) is lost."""
        if self.loss and self.draw() < self.loss:
            self.dropped += 1
            return True
        return False

    def send(self, frame: bytes) -> None:
        """A frame the host sent: it leaves after its delay, never before the previous."""
        if self.lost():
            return
        wait = self.delay + (2.0 * self.draw() - 1.0) * self.jitter
        due = max(self.now() + max(wait, 0.0), self._last)
        self._last = due
        self._count += 1
        heapq.heappush(self._queue, (due, self._count, frame))

    def due(self) -> list[bytes]:
        """The frames whose time has come, in the order sent."""
        out = []
        now = self.now()
        while self._queue and self._queue[0][0] <= now:
            out.append(heapq.heappop(self._queue)[2])
        return out

    def next_in(self) -> float | None:
        """Seconds until the next frame is due (None: none waiting)."""
        return max(self._queue[0][0] - self.now(), 0.0) if self._queue else None


def carry(host: int, bridge: int, wire: Wire) -> None:
    """Carry frames until killed or a TAP is gone: host -> (delayed) -> bridge,
    bridge -> host."""
    while True:
        wait = wire.next_in()
        ready, _, _ = select.select([host, bridge], [], [], wait)
        failed = False
        if host in ready:
            frames, failed = _drain(host)
            for frame in frames:
                wire.send(frame)
        if bridge in ready:
            frames, bridge_failed = _drain(bridge)
            failed |= bridge_failed
            for frame in frames:
                if not wire.lost():
                    _write(host, frame)
        for frame in wire.due():
            _write(bridge, frame)
        if failed:
            # a TAP that is readable yet gives an error would make this loop spin, at
            # real-time priority a core taken from every program: wait a little
            time.sleep(DOWN_WAIT)


def _drain(fd: int) -> tuple[list[bytes], bool]:
    """The frames queued on `fd`, and whether reading it failed (other than finding
    none). A TAP whose device is gone (its namespace deleted) ends the wire."""
    frames = []
    while True:
        try:
            frames.append(os.read(fd, FRAME))
        except BlockingIOError:
            return frames, False
        except OSError as exc:  # the device went down for a moment (a link set down)
            if exc.errno in GONE:
                raise SystemExit(0) from None
            return frames, True


def _write(fd: int, frame: bytes) -> None:
    with contextlib.suppress(OSError):  # the other end is down (a partition on top): dropped
        os.write(fd, frame)


def main(argv: list[str]) -> int:
    """`HOSTTAP BRIDGETAP DELAY JITTER LOSS` (seconds, seconds, share 0-1)."""
    if len(argv) != 5:
        print(__doc__, file=sys.stderr)
        return 2
    host_name, bridge_name = argv[0], argv[1]
    delay, jitter, loss = (float(v) for v in argv[2:])
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
    except OSError as exc:  # PermissionError among them
        print(
            f"netns_delay: no SCHED_FIFO {PRIORITY} ({exc.strerror}): the delay will be "
            "longer on a busy machine",
            file=sys.stderr,
        )
    host, bridge = open_tap(host_name), open_tap(bridge_name)
    print("ready", flush=True)
    with contextlib.suppress(KeyboardInterrupt):
        carry(host, bridge, Wire(delay, jitter, loss))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
