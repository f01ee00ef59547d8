"""Real-time priority for a paced loop's thread, and what it got.

A device loop that must answer every millisecond (the robot interface answering the
KRC) runs as OROCOS lwr_fri, lbr_fri_ros2_stack and ros2_control run theirs: its
thread at `SCHED_FIFO` (priority `PRIORITY`, 80: above the kernel's threaded
interrupts at 50 and below its watchdogs at 99), the process's memory locked
(`mlockall`: no page fault in a cycle), and Python's garbage collector kept out of the
cycles: the objects that exist once the loop starts are frozen out of collection, the
automatic collector is off in that process, and the loop collects the young
generation itself between cycles (`between_cycles`), timing each collection.

Where the host does not allow it (no CAP_SYS_NICE, an rtprio limit of 0, a container
without the capability), the loop says so in one line and keeps the process's nice
value (the deployer's -15 for safety processes). Either way `LoopStats.scheduling`
says what the loop got, for `fw deploy`'s screen and `fw bench cost`.

A simulated device's loop (the simulated OR's KRC) is not the system under test: where
the host gives real-time priority it runs SCHED_DEADLINE with `SIMULATED_SHARE` of each
period (sched_setattr(2)), its CPU on time whatever else runs and never more, so it
cannot starve fw on a slow host as SCHED_FIFO did; elsewhere SCHED_OTHER.

Only the loop's thread runs at real-time priority, never its process's other threads
(the bus's; its process beats from the loop, below): with all of them at SCHED_FIFO 70 (tried, to spare the
loop a priority inversion through the GIL) the bus threads of the robot and KRC
processes starved the rest of the deployment, and the Sensor Manager's heartbeat
missed its 100 ms deadline on a quiet 2-core host. The GIL: a thread of the same
process holding it makes the loop wait up to the interpreter's switch interval (5 ms
by default); `enter` lowers that interval to `SWITCH_INTERVAL` so any other thread
yields it within 0.2 ms, and the loop measures its wake-up (the `wake` stage: from
the datagram's arrival in the kernel to the loop holding it).

What that leaves is a priority inversion through the GIL: a thread of the loop's
process (a bus callback, an operation's caller encoding its answer) that holds the
interpreter when the host preempts it makes the loop wait until it runs again, a
scheduler slice (milliseconds) later on a busy host. Measured on the SEEG deployment:
a report whose loop statistics (percentiles over 2000 cycles of 12 stages) were computed
in the caller's thread, polled at 2 Hz, cost enough missed answers for the KRC to brake
within seconds; computed on request only (`fw bench cost`), the approach reached its
target with the same polling. So the other threads of a loop's process must do little
Python: decode, store, return; and that process has no heartbeat thread: its loop beats
for it between cycles (`ProcessHeartbeat.poll`, framework/safety.py), so the 40 beats a
second are no longer 40 chances a second for that inversion, and a hung loop leaves its
process silent.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import os
import platform
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger("fw.realtime")

PRIORITY = 80
"""SCHED_FIFO priority of a device loop (OROCOS lwr_fri and lbr_fri_ros2_stack use 80-90)."""
SIMULATED_SHARE = 0.3
"""The share of each period a simulated device's loop gets at SCHED_DEADLINE: 0.3 ms of
every 1 ms for the simulated KRC, whose cycle (MuJoCo's step, FRI) takes ~0.1 ms here
(p50; p99 0.2-0.28 ms moving): guaranteed on time whatever else the host runs, and
never more, so a host too slow for the whole simulation slows the simulation down
instead of starving what it tests (0.98x real time on a slow hour). Not larger: with
0.5 ms it preempted the robot interface's loop on their shared CPU for longer, and
FRI answers came late (6 a run against 0, docs/bench.md)."""
SWITCH_INTERVAL = 0.0002
"""s: how soon another thread of the loop's process must yield the GIL."""
GC_YOUNG = 700
"""Allocations beyond which the loop collects the young generation between cycles."""
_MCL_CURRENT, _MCL_FUTURE = 1, 2


KEEP = 2000
"""How many recent cycles the statistics are over."""


def _percentile(values: list[float], q: float) -> float | None:
    """The q-quantile of `values` (us, rounded), None for none."""
    if not values:
        return None
    return round(float(np.quantile(values, q, method="lower")) * 1e6, 1)


def _keep(samples: list[float], value: float) -> None:
    samples.append(value)
    if len(samples) > 2 * KEEP:
        del samples[:KEEP]


@dataclass
class LoopStats:
    """A paced loop's scheduling and what its cycles, their stages and the collections
    took (the last `KEEP` cycles)."""

    scheduling: str
    cycles: int = 0
    durations: list[float] = field(default_factory=list)  # s: read done to write sent
    afters: list[float] = field(default_factory=list)  # s: after the write, before the next
    stages: dict[str, list[float]] = field(default_factory=dict)  # s, by stage
    longest: float = 0.0
    collections: int = 0
    longest_collection: float = 0.0
    host_realtime: bool | None = None
    """Whether the host gives real-time priority (a simulated device's loop asks without
    taking it); None where nobody said."""

    def cycle(self, seconds: float) -> None:
        """One cycle's work (read done to write sent) took `seconds`."""
        self.cycles += 1
        self.longest = max(self.longest, seconds)
        _keep(self.durations, seconds)

    def after_cycle(self, seconds: float) -> None:
        """The work after a cycle's write (the components' `after_cycle`: deferred puts,
        news) took `seconds`: it delays no answer, only the next cycle if it overran."""
        _keep(self.afters, seconds)

    def stage(self, name: str, seconds: float) -> None:
        """A stage of this cycle (receive, safety, interpolation, IK, separation,
        send...) took `seconds`; called by the loop and the components it runs (a dozen
        times a cycle: `_keep` written out here)."""
        samples = self.stages.get(name)
        if samples is None:
            samples = self.stages[name] = []
        samples.append(seconds)
        if len(samples) > 2 * KEEP:
            del samples[:KEEP]

    def report(self) -> dict[str, object]:
        """Scheduling, cycles, the cycle work's and each stage's p50/p99 (us), the
        longest cycle, the collections. Safe from any thread while the loop runs (it
        reads copies): a report's percentiles are never computed in a cycle's time."""
        recent = self.durations[-KEEP:]
        return {
            "scheduling": self.scheduling,
            "cycles": self.cycles,
            "work_p50_us": _percentile(recent, 0.5),
            "work_p99_us": _percentile(recent, 0.99),
            "work_max_us": round(self.longest * 1e6, 1),
            "after_cycle_p50_us": _percentile(self.afters[-KEEP:], 0.5),
            "after_cycle_p99_us": _percentile(self.afters[-KEEP:], 0.99),
            "stages_us": {
                name: {
                    "p50": _percentile(values[-KEEP:], 0.5),
                    "p99": _percentile(values[-KEEP:], 0.99),
                }
                for name, values in list(self.stages.items())
            },
            "collections": self.collections,
            "longest_collection_us": round(self.longest_collection * 1e6, 1),
        }


class RealTimePolicy:
    """How a paced loop's thread asks for real-time priority (module docstring)."""

    def __init__(self, enabled: bool = True, priority: int = PRIORITY, manage_gc: bool = True):
        self.enabled = enabled
        self.priority = priority
        self.manage_gc = manage_gc
        self.granted: bool | None = None
        """Whether the host gives real-time priority (None: no loop asked yet)."""
        self._collecting = 0  # the loops that took the collector over and still run
        self._lock = threading.Lock()

    def enter(
        self,
        name: str,
        priority: int | None = None,
        fifo: bool = True,
        period: float | None = None,
    ) -> str:
        """In the loop's own thread, before its first cycle: ask for SCHED_FIFO (at
        `priority`, the policy's own unless given), lock memory, take the collector
        over; what the thread got, in words. With `fifo` False (a simulated device's
        loop, paced every `period` seconds): find out whether the host would give
        SCHED_FIFO and, where it would, take SCHED_DEADLINE with `SIMULATED_SHARE` of
        each period instead (without a period, or refused: SCHED_OTHER). `granted`
        says afterwards whether the host gives real-time priority."""
        priority = self.priority if priority is None else priority
        sys.setswitchinterval(SWITCH_INTERVAL)
        if self.manage_gc:
            with self._lock:
                self._collecting += 1
            gc.collect()
            gc.freeze()  # what exists now is never scanned again
            gc.disable()  # the loop collects between its cycles
        if not self.enabled:
            self.granted = False
            return f"SCHED_OTHER, nice {os.nice(0)} (real-time not asked for)"
        thread = threading.get_native_id()
        if not fifo:
            self.granted = _fifo_allowed(thread, priority)
            if self.granted and period is not None:
                runtime = SIMULATED_SHARE * period
                if _deadline(thread, runtime, period):
                    return (
                        f"SCHED_DEADLINE, {runtime * 1e3:g} ms of every {period * 1e3:g} ms "
                        "(a simulated device: its share guaranteed, never more)"
                    )
            allowed = "the host allows it" if self.granted else "the host does not allow it"
            return (
                f"SCHED_OTHER, nice {os.nice(0)} (a simulated device: real-time priority is "
                f"left to the system under test; {allowed})"
            )
        try:
            os.sched_setscheduler(thread, os.SCHED_FIFO, os.sched_param(priority))
        except (PermissionError, OSError) as exc:
            self.granted = False
            why = exc.strerror or str(exc)
            got = f"SCHED_OTHER, nice {os.nice(0)} (SCHED_FIFO refused: {why})"
            log.warning("%s: no real-time priority for its loop: %s", name, got)
            print(
                f"fw: {name}: no real-time priority for its loop ({why}): "
                f"it runs at nice {os.nice(0)}; see docs/safety.md",
                file=sys.stderr,
            )
            return got
        self.granted = True
        locked = _lock_memory()
        return f"SCHED_FIFO {priority}" + ("" if locked else " (memory not locked)")

    def leave(self) -> None:
        """In the loop's thread, after its last cycle: once no loop of the process runs,
        the collector is Python's again and what was frozen may be collected (at exit, a
        frozen extension object is never freed: nanobind's modules, ruckig's, then report
        it as a leak in the process's log)."""
        with self._lock:
            if self._collecting == 0:  # no loop took the collector (or none is left)
                return
            self._collecting -= 1
            if self._collecting:
                return
        gc.unfreeze()
        gc.enable()

    def between_cycles(self, stats: LoopStats, slack: bool = False) -> None:
        """After a cycle's write, in the loop's thread: collect the young generations
        when due (tens of microseconds), timed; the whole heap (milliseconds: three
        missed answers at 1 kHz) only with `slack`, when the device left time (a
        braked arm's KRC sends every 10 ms)."""
        if not self.manage_gc:
            return
        young, middle, old = gc.get_count()
        if young < GC_YOUNG and not (slack and old > 10):
            return
        generation = 2 if slack and old > 10 else (1 if middle > 10 else 0)
        began = time.perf_counter()
        gc.collect(generation)
        took = time.perf_counter() - began
        stats.collections += 1
        stats.longest_collection = max(stats.longest_collection, took)


def _libc() -> ctypes.CDLL | None:
    """The C library, once per process (None where there is none to find)."""
    global _LIBC_LOADED
    if _LIBC_LOADED is None:
        name = ctypes.util.find_library("c") if sys.platform.startswith("linux") else None
        _LIBC_LOADED = (ctypes.CDLL(name, use_errno=True),) if name else (None,)
    return _LIBC_LOADED[0]


_LIBC_LOADED: tuple[ctypes.CDLL | None] | None = None
_PR_SET_NAME = 15


def name_os_thread(name: str) -> None:
    """Give the calling thread `name` (15 bytes at most) where the host's tools (top -H,
    ps -L, /proc, py-spy) see it; nothing where the platform has no such call."""
    libc = _libc()
    if libc is not None:
        libc.prctl(_PR_SET_NAME, name.encode()[:15], 0, 0, 0)


def _fifo_allowed(thread: int, priority: int) -> bool:
    """Whether the host would run `thread` at SCHED_FIFO `priority`: asked, then given
    back (the thread keeps its own policy and nice level)."""
    policy, param = os.sched_getscheduler(thread), os.sched_getparam(thread)
    try:
        os.sched_setscheduler(thread, os.SCHED_FIFO, os.sched_param(priority))
    except (PermissionError, OSError):
        return False
    os.sched_setscheduler(thread, policy, param)
    return True


class _SchedAttr(ctypes.Structure):
    """Linux's struct sched_attr, version 0 (48 bytes): what sched_setattr(2) takes."""

    _fields_ = [
        ("size", ctypes.c_uint32),
        ("sched_policy", ctypes.c_uint32),
        ("sched_flags", ctypes.c_uint64),
        ("sched_nice", ctypes.c_int32),
        ("sched_priority", ctypes.c_uint32),
        ("sched_runtime", ctypes.c_uint64),
        ("sched_deadline", ctypes.c_uint64),
        ("sched_period", ctypes.c_uint64),
    ]


_SCHED_DEADLINE = 6
_SCHED_FLAG_RESET_ON_FORK = 0x01
_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}


def _deadline(thread: int, runtime: float, period: float) -> bool:
    """Run `thread` at SCHED_DEADLINE: `runtime` seconds of CPU guaranteed in every
    `period`, never more (the kernel throttles it to the next period): False where the
    host refuses it or the architecture's syscall number is not known here."""
    number = _SYS_SCHED_SETATTR.get(platform.machine())
    libc = _libc()
    if number is None or libc is None:
        return False
    attr = _SchedAttr(
        size=ctypes.sizeof(_SchedAttr),
        sched_policy=_SCHED_DEADLINE,
        sched_runtime=int(runtime * 1e9),
        sched_deadline=int(period * 1e9),
        sched_period=int(period * 1e9),
        sched_flags=_SCHED_FLAG_RESET_ON_FORK,  # a child it starts gets SCHED_OTHER
    )
    return libc.syscall(number, thread, ctypes.byref(attr), 0) == 0


def _lock_memory() -> bool:
    """mlockall(MCL_CURRENT | MCL_FUTURE); False if the host refuses."""
    libc = _libc()
    return libc is not None and libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0
