"""Routes the bus lost after a partition, found and made again.

After a partition heals, Zenoh (1.10.2, the newest on PyPI) sometimes links two
sessions again without routing between them: in 9 of 24 partitions of the tracking
host (docs/hosts.md) the trackers' samples never reached the Sensor Manager again,
while both processes ran, were linked and answered questions. The robot stayed braked
and latched, as it must, but could not be released until the deployment restarted. A
new session on the side that hears nothing makes its routes again (measured with
`tools/zenoh_partition.py --reopen`); a restarted producer did not.

So each process of a deployment (its container, and `fw deploy`'s own on the control
host) puts a *route probe* on
`fw/process/<name>/routes` once a `PERIOD` (the id of the session it says
everything on, how many probes it put, how many times it reopened) and hears the
others'. A process that heard another's
probes and then hears none for `SILENT` s while that process is evidently there (the
session its probes came from is still linked to this one), or hears its probes but
not its tokens for as long, has lost its routes from it: it reopens its bus
(`Bus.reopen`: what it hears moves to a new session; what it says stays), at most once per
`SPACING` s, and says so on stderr (the process's log) and in its probes. A process
that is cut off, hung or dead is not linked (a hung one's link goes with its lease,
2 s): that is a partition, the safety monitor's business, and nothing is reopened.

What reopening costs the robot: nothing moves by it (motion restarts only by an
operator's RELEASE, through the chart); what the process says (its publishers,
queryables and tokens) stays on its first session, so nobody that hears it misses a
sample or sees a component vanish (when publishers moved too, a reopen of the
supervision process left its heartbeat 151 ms silent at the robot, which braked as it
moved); for 3 s both sessions receive and every poll reads both, so no sample is lost
while the new routes are made. A
component may hold every process's bus (`Component.holds_bus`: the robot interface
while it commands the arm): its process's watch waits and says so in its probes, and
every other process's watch waits while it hears that. A reopen costs its process a
moment of interpreter time: the robot's own once made the KRC brake with a fault 0.25
s into the motion, and the supervision process's made its sensor manager's heartbeat
150 ms late at the robot, which braked (robot partition, 2 of 8 runs, 2026-12-07). A
route the moving robot needs and lacks brakes it anyway (its watches); the reopen then
comes, braked. A probe is
about 80 bytes a second per process to each other process. Only a process may put on
its own probe key (framework/access.py), so a forged probe cannot hide a silence.
Runs on a thread of its own (`fw-routes`), at the process's ordinary priority.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from framework import keys

log = logging.getLogger("fw.routes")

PERIOD = 1.0
"""Seconds between two probes of a process (and two looks at the others')."""
SILENT = 6.0
"""Seconds without a probe from a process that is there before routes count as lost:
well past a heal's reconnection (links are tried again every second, the lease is
2 s) and six probes lost in a row."""
SPACING = 30.0
"""Seconds at least between two reopens of one process."""


@dataclass
class Peer:
    """What this process knows of another from its probes."""

    zid: str
    """Its session's id (a restarted or reopened process has a new one)."""
    heard: float
    """When its last probe arrived (monotonic s)."""
    count: int = 0
    reopened: int = 0
    """How many times it reopened its own bus (from its probes)."""
    tokens: tuple[str, ...] = ()
    """The liveliness tokens it holds (from its probes)."""
    holds: str = ""
    """Why no process of the deployment may reopen now, if it says so (its probes)."""


class RouteWatch:
    """Puts this process's route probes, hears the others', and reopens the bus when
    routes from a process that is there are lost (module docstring)."""

    def __init__(
        self,
        bus: Any,
        process: str,
        period: float = PERIOD,
        silent: float = SILENT,
        spacing: float = SPACING,
        can_reopen: bool = True,
        hold: Callable[[], str] | None = None,
        overlap: float | None = None,
    ):
        """`can_reopen` False (the hub of a deployment on one host): lost routes are
        said, not mended. `hold`: why the bus must not reopen now ('' if it may; the
        container's `holds_bus`): the reopen waits, asked again every round."""
        self.bus = bus
        self.can_reopen = can_reopen
        self.hold = hold
        self.overlap = overlap
        """Seconds both sessions carry the declarations after a reopen (None: the bus's
        default, framework/bus.py `REOPEN_OVERLAP`)."""
        self._held = ""
        self._hold_error = ""
        self.process = process
        self.period = period
        self.silent = silent
        self.spacing = spacing
        self.peers: dict[str, Peer] = {}
        self.refused = 0
        """Probes that were not what a probe is (counted, ignored)."""
        self.reopens: list[dict[str, Any]] = []
        """Every reopen: when (wall s), for whom, why, how long it took."""
        self._sent = 0
        self._last_reopen = -math.inf
        self._waiting: dict[str, float] = {}  # peers silent at the last reopen -> when
        self._unseen: dict[str, float] = {}  # tokens a heard peer claims, unseen -> since
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fw-routes", daemon=True)
        # the latest-value publisher and subscriber fw's ports use, so the probes take
        # the routes the data takes: plain ones were lost after heals where the data's
        # came back, and every reopen they caused was a gap in the data for nothing
        self._publisher = bus.publisher(keys.route_probe(process))
        self._subscriber = bus.subscribe(keys.ALL_ROUTE_PROBES, self._on_probe)

    def start(self) -> RouteWatch:
        """Probe and look once a period from the watch's own thread."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop probing (before the bus closes)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(2.0)
        for declared in (self._subscriber, self._publisher):
            with contextlib.suppress(Exception):  # the session is closing
                declared.undeclare()

    # -- Zenoh's thread -----------------------------------------------------------------
    def _on_probe(self, sample: Any) -> None:
        name = str(sample.key_expr).rsplit("/", 2)[-2]
        if name == self.process:
            return
        try:
            body = json.loads(bytes(sample.payload.to_bytes()))
            zid, count, reopened = str(body["zid"]), int(body["n"]), int(body["reopened"])
            tokens = tuple(str(t) for t in body.get("tokens", ()))
            holds = str(body.get("holds", ""))
        except (ValueError, KeyError, TypeError):
            with self._lock:
                self.refused += 1
            return
        now = time.monotonic()
        with self._lock:
            known = self.peers.get(name)
            if known is not None and known.zid == zid and count <= known.count:
                return  # a cached probe heard again (a reopen, a late publisher found)
            self.peers[name] = Peer(zid, now, count, reopened, tokens, holds)
            since = self._waiting.pop(name, None)
        if since is not None:
            self._say(f"hears {name} again, {now - since:.1f} s after reopening its bus")

    # -- the watch's thread ---------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.wait(self.period):
            try:
                self.step()
            except Exception as exc:  # a closing bus; anything else is said, and probing goes on
                if self._stop.is_set() or getattr(self.bus, "closed", False):
                    return
                self._say(f"route watch round failed: {exc}")

    def step(self) -> list[str]:
        """One round: put this process's probe, and reopen the bus if routes from a
        process that is there are lost; the processes it reopened for (none if it
        did not reopen: nothing lost, or the bus cannot or may not reopen now). Runs in the
        watch's thread (or a test's)."""
        self._sent += 1
        probe = {
            "zid": self.bus.says_zid(),  # the session the probe comes from
            "n": self._sent,
            "reopened": self.bus.reopened,
            "tokens": self.bus.tokens(),
            "holds": self._own_hold(),
        }
        self._publisher.put(json.dumps(probe))
        now = time.monotonic()
        if now - self._last_reopen < self.spacing:
            return []
        with self._lock:
            silent = {n: p for n, p in self.peers.items() if now - p.heard >= self.silent}
            heard = {n: p for n, p in self.peers.items() if n not in silent}
        lost = self._unseen_tokens(heard, now)
        if not silent and not lost:
            return []
        linked = self.bus.linked() if silent else set()
        for name, peer in sorted(silent.items()):
            how = self._there(name, peer, linked)
            if how:
                lost[name] = f"heard nothing from {name} for {now - peer.heard:.1f} s, {how}"
        if not lost:
            return []
        return sorted(lost) if self._reopen(lost) else []

    def _unseen_tokens(self, heard: dict[str, Peer], now: float) -> dict[str, str]:
        """Processes heard whose tokens this bus's watches have not seen alive for
        `silent` s: their liveliness routes are lost (the robot's safety monitor saw a
        tracker "lost" 30 s after a heal while its process's probes came through)."""
        lost: dict[str, str] = {}
        claimed = set()
        for name, peer in sorted(heard.items()):
            for key in peer.tokens:
                claimed.add(key)
                if self.bus.seen_alive(key) is not False:
                    self._unseen.pop(key, None)
                    continue
                since = self._unseen.setdefault(key, now)
                if now - since >= self.silent and name not in lost:
                    lost[name] = (
                        f"its token {key} unseen for {now - since:.1f} s while its probes "
                        f"come through"
                    )
        for key in set(self._unseen) - claimed:
            del self._unseen[key]
        return lost

    def _there(self, name: str, peer: Peer, linked: set[str]) -> str:
        """How this process knows a silent one is there ('' if it does not): the session
        its probes came from is still linked to this one. Not an answer on its clock
        key: a process restarted under the same name answers it before its first
        probe, and every other process reopened for it."""
        if peer.zid in linked:
            return "while its session is linked to this one"
        return ""

    def _own_hold(self) -> str:
        """This process's hold ('' if none): `hold` asked, and a hold that raises is
        said and counts as none (the probes must go on: a process whose probes stop
        makes every other one reopen for it)."""
        if self.hold is None:
            return ""
        try:
            return str(self.hold() or "")
        except Exception as exc:  # a component's own code: said once, the probe still goes
            why = f"asking whether the bus must be kept failed: {type(exc).__name__}: {exc}"
            if why != self._hold_error:  # said once, not every round
                self._say(why)
                self._hold_error = why
            return ""

    def _holding(self) -> str:
        """Why this bus must not reopen now ('' if it may): a component of this process
        says so (`hold`), or another process's latest probe, heard within two periods,
        does. A reopen costs its process a moment of CPU (a new session, its links,
        every subscription made again): the robot interface holds the deployment's
        buses while it commands the arm, as a late heartbeat from any process then
        brakes it (the sensor manager's, 150 ms, as a reopen of the supervision process
        for the control host's silence met the approach after RELEASE, 2026-12-07)."""
        own = self._own_hold()
        if own:
            return own
        now = time.monotonic()
        with self._lock:
            for name, peer in sorted(self.peers.items()):
                if peer.holds and now - peer.heard <= 2 * self.period:
                    return f"{name} says {peer.holds}"
        return ""

    def _reopen(self, lost: dict[str, str]) -> bool:
        """Reopen the bus for `lost` (process -> why); whether it did."""
        why = "; ".join(lost.values())
        if not self.can_reopen:
            self._say(f"routes lost: {why}; this bus cannot reopen (the hub on one host)")
            self._last_reopen = time.monotonic()
            return False
        held = self._holding()
        if held:
            if held != self._held:
                self._say(f"routes lost: {why}; the reopen waits: {held}")
            self._held = held
            return False
        self._held = ""
        self._say(f"routes lost: {why}: reopening the bus (routes Zenoh left unmade)")
        began = time.monotonic()
        self._last_reopen = began  # a reopen that fails is not tried again at once
        took = self.bus.reopen() if self.overlap is None else self.bus.reopen(self.overlap)
        now = time.monotonic()
        self._last_reopen = now
        self._unseen.clear()  # the new session's watches start over
        with self._lock:
            for name in lost:
                self._waiting[name] = began
            for peer in self.peers.values():  # the new session's time to hear them
                peer.heard = max(peer.heard, now)
        self.reopens.append(
            {"stamp": time.time(), "for": sorted(lost), "why": why, "took_s": round(took, 3)}
        )
        self._say(f"bus reopened in {took:.2f} s (it hears on session {self.bus.zid()})")
        return True

    def _say(self, text: str) -> None:
        print(f"fw routes ({self.process}): {text}", file=sys.stderr, flush=True)
        log.info(text)
