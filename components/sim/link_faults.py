"""Faults of the network between the simulated KRC and the PC: answers lost or late, a
silent KRC, datagrams that are no measurement, a foreign sender on the PC's port.

A fake at the physical edge (the cable and switch between a KRC and its PC), injected
by `ArmController.impair` for scenarios and `fw bench chaos`; everything on both sides
of it (the KRC's quality rating and brakes, the interface's refusals and watches) is
the real code. Times are the KRC component's clock: the host's monotonic time when
deployed (a network delays in real time), a stepped test's simulated time.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from components.domain import fri

GARBAGE_KINDS = ("empty", "truncated", "oversized", "wrong id")
"""The datagrams that are no measurement, sent in turn."""
OVERSIZED = 4096
"""bytes: more than any FRI datagram (the PC reads at most 2048: truncated, refused)."""


def garbage(kind: str, measurement: bytes) -> bytes:
    """A datagram of `kind` (`GARBAGE_KINDS`) made from a real `measurement`."""
    if kind == "empty":
        return b""
    if kind == "truncated":
        return measurement[: len(measurement) // 2]
    if kind == "oversized":
        return measurement + bytes(OVERSIZED - len(measurement))
    if kind == "wrong id":
        return measurement[:6] + struct.pack("<H", fri.CMD_ID) + measurement[8:]
    raise ValueError(f"no garbage of kind {kind!r}: one of {', '.join(GARBAGE_KINDS)}")


@dataclass
class LinkFaults:
    """What the link does to the datagrams now (nothing, by default)."""

    drop_every: int = 0
    """Every this many-th answer that arrives is lost (0: none; 1: all)."""
    delay: float = 0.0
    """s: answers arrive this much later than they were sent."""
    until: float = 0.0
    """When the loss and the delay end (the KRC's clock)."""
    silent_until: float = 0.0
    """Until when the KRC's measurements do not reach the PC (the KRC's clock)."""
    garbage: int = 0
    """Datagrams that are no measurement still to send, one per cycle."""
    foreign: int = 0
    """Measurements from another address still to send, one per cycle."""
    arrived: int = 0
    dropped: int = 0
    garbage_sent: int = 0
    foreign_sent: int = 0

    def impair(
        self,
        now: float,
        *,
        drop_every: int = 0,
        delay: float = 0.0,
        silence: float = 0.0,
        garbage: int = 0,
        foreign: int = 0,
        seconds: float = 1.0,
    ) -> None:
        """From `now`: lose every `drop_every`-th answer and delay answers by `delay` s
        for `seconds`; keep the KRC silent for `silence` s; send `garbage` and `foreign`
        datagrams (added to any still to send). Bad values raise ValueError."""
        for name, value in (("drop_every", drop_every), ("garbage", garbage), ("foreign", foreign)):
            if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= 10_000:
                raise ValueError(f"{name} must be a whole number from 0 to 10000, not {value!r}")
        for name, value in (("delay", delay), ("silence", silence), ("seconds", seconds)):
            if not isinstance(value, int | float) or not 0.0 <= value <= 60.0:
                raise ValueError(f"{name} must be 0 to 60 s, not {value!r}")
        self.drop_every, self.delay, self.until = drop_every, float(delay), now + seconds
        self.silent_until = max(self.silent_until, now + silence)
        self.garbage += garbage
        self.foreign += foreign

    def due(self, now: float) -> float:
        """When an answer that arrives `now` reaches the KRC."""
        return now + self.delay if now < self.until else now

    def impairs_answers(self, now: float) -> bool:
        """Whether an answer arriving `now` may be delayed or lost (else it reaches the
        KRC at once, as it arrived)."""
        return now < self.until and (self.delay > 0.0 or self.drop_every > 0)

    def lost(self, now: float) -> bool:
        """Whether the answer that just reached the KRC was lost on the way."""
        if not self.drop_every or now >= self.until:
            return False
        self.arrived += 1
        if self.arrived % self.drop_every:
            return False
        self.dropped += 1
        return True

    def silent(self, now: float) -> bool:
        """Whether the KRC's measurement of this cycle is lost."""
        return now < self.silent_until

    def next_garbage(self, measurement: bytes) -> bytes | None:
        """The garbage datagram to send after this cycle's measurement, if any."""
        if not self.garbage:
            return None
        self.garbage -= 1
        kind = GARBAGE_KINDS[self.garbage_sent % len(GARBAGE_KINDS)]
        self.garbage_sent += 1
        return garbage(kind, measurement)

    def next_foreign(self) -> bool:
        """Whether a measurement from another address goes out this cycle."""
        if not self.foreign:
            return False
        self.foreign -= 1
        self.foreign_sent += 1
        return True

    def report(self) -> dict[str, int]:
        """What the link did so far."""
        return {
            "dropped": self.dropped,
            "garbage_sent": self.garbage_sent,
            "foreign_sent": self.foreign_sent,
        }
