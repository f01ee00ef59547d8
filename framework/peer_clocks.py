"""Measuring other hosts' clocks over the bus: each process answers its wall time on
`fw/clock/<process>`; a process whose inputs come from other hosts asks one process of
each such host once a second and keeps an `OffsetEstimate` per host
(framework/clock_offset.py says what the interval means and why it is safe).

Only a host's own process may answer on its clock key (framework/access.py), so a
forged answer cannot move the estimate; an answer that is not one finite number is
refused and counted. A peer that stops answering (cut off, hung) leaves its last
interval in place, widening by the drift bound: ages judged with it only grow.
"""

from __future__ import annotations

import math
import struct
import threading
import time
from typing import Any

from framework import keys
from framework.clock_offset import Exchange, OffsetEstimate

PERIOD = 1.0
"""Seconds between two questions to each peer."""

ANSWER_TIMEOUT = 0.5
"""How long a question may wait for its answer (a late answer is a wide interval, still
true, but there is no use waiting longer than a period)."""

WIRE = struct.Struct("<d")


def answer_clock(bus: Any, process: str) -> Any:
    """Declare `process`'s clock queryable; each query is answered with the wall time
    (8 bytes, little-endian double) read at the moment of answering. Runs in Zenoh's
    thread. Returns the queryable (undeclare it on shutdown)."""
    key = keys.clock(process)

    def answer(query: Any) -> None:
        query.reply(key, WIRE.pack(time.time()))

    return bus.queryable(key, answer)


class PeerClocks:
    """The offsets of other hosts' clocks, one `OffsetEstimate` per host, measured on a
    thread of its own (`fw-clocks`) by asking one process of each."""

    def __init__(self, bus: Any, peers: dict[str, str], period: float = PERIOD):
        """`peers`: host -> the process of that host to ask."""
        self.bus = bus
        self.peers = dict(peers)
        self.period = period
        self.estimates = {host: OffsetEstimate() for host in self.peers}
        self.unanswered = dict.fromkeys(self.peers, 0)
        self._stop = threading.Event()
        self._soon = threading.Event()
        self._thread: threading.Thread | None = None

    def of(self, host: str) -> OffsetEstimate | None:
        """The estimate for `host` (None: not a peer this process measures). One not
        measured yet (the host came up after this process) is asked at once, not at
        the next period."""
        estimate = self.estimates.get(host)
        if estimate is not None and not estimate.measured:
            self._soon.set()
        return estimate

    def wait_measured(self, host: str, timeout: float = ANSWER_TIMEOUT) -> bool:
        """Wait up to `timeout` for `host`'s first answer (asked at once); whether it
        came. For a reader that cannot go on without it; the measuring thread asks."""
        estimate = self.of(host)
        end = time.monotonic() + timeout
        while estimate is not None and not estimate.measured and time.monotonic() < end:
            self._soon.set()
            time.sleep(0.005)
        return estimate is not None and estimate.measured

    def start(self) -> None:
        """Measure every peer at once, then once per period."""
        if self._thread is None and self.peers:
            self._thread = threading.Thread(target=self._run, name="fw-clocks", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop measuring (the estimates stay readable)."""
        self._stop.set()
        self._soon.set()
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None

    def measure(self, host: str) -> bool:
        """Ask `host` once; True if its answer was taken."""
        asked = time.time()
        try:
            replies = self.bus.query(keys.clock(self.peers[host]), timeout=ANSWER_TIMEOUT)
        except Exception:  # unreachable, refused: the estimate keeps widening, safely
            replies = []
        answered = time.time()
        if len(replies) != 1 or len(replies[0]) != WIRE.size:
            self.unanswered[host] += 1
            return False
        (answer,) = WIRE.unpack(replies[0])
        if not math.isfinite(answer):
            self.unanswered[host] += 1
            return False
        return self.estimates[host].add(Exchange(asked, answer, answered))

    def _run(self) -> None:
        while not self._stop.is_set():
            self._soon.clear()
            for host in self.peers:
                self.measure(host)
            self._soon.wait(self.period)
