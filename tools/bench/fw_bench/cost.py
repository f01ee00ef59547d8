"""What the simulated OR costs (issue 18): CPU per process, and whether the 1 kHz loop
keeps real time.

On the running SEEG deployment (`SeegRun`), over a window each: the robot braked and
waiting for START (idle), then moving toward the target with the people of the
scene in the room (only while the chart is in a motion state: a window that ran on
past the target would average the motion with the hold). For every process of the
deployment, for a process that holds nothing but a Zenoh session (the floor any
process of fw stands on), and for this one (the
Coordinator and Configurator, with the bench's own listener), the CPU it used
(user + system, from /proc/<pid>/stat) divided by the window: the cores it took.
The arm's loop: how many 1 ms cycles it ran per millisecond of wall time (its
real-time factor, from `arm.report` at both ends of the window), and the intervals
between the stamps its cycles put on `arm/measured`, per cycle they cover (the
stamps are taken in the arm's own process, so delivery does not blur them; braked,
the arm reports every 10 cycles). The robot loop's own account at the window's end:
its scheduling class, its cycle's work and each stage's p50/p99 (receive, wake,
safety, separation, interpolation, IK, publish, send), the FRI link's quality and its
missed, late and refused datagrams. `load` busy loops run on the host meanwhile, as
other jobs of a shared machine would.
"""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from framework.messages import ArmState
from fw_bench.latency import keep_moving
from fw_bench.seeg_run import BenchError, SeegRun

TICK = os.sysconf("SC_CLK_TCK")
BUSY_LOOP = "while True: pass"


def cpu_seconds(pid: int) -> float:
    """User + system CPU time a process (all its threads) has used so far (s)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()  # after the command's name
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime (fields 14, 15)


def switches(pid: int) -> int:
    """Context switches of all a process's threads so far (voluntary: it slept and was
    woken; involuntary: preempted): how often the host had to schedule it, a count no
    host's speed changes (its cost per switch does: `fw_bench.baseline.wake_round_trip`)."""
    total = 0
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return 0
    for task in tasks:
        try:
            with open(f"/proc/{pid}/task/{task}/status", encoding="ascii") as status:
                for line in status:  # voluntary_ and nonvoluntary_ctxt_switches
                    if "ctxt_switches:" in line:
                        total += int(line.split(":", 1)[1])
        except OSError:  # a thread that ended meanwhile
            continue
    return total


@dataclass
class Window:
    """One measured window."""

    seconds: float
    cores: dict[str, float]  # process -> cores used
    realtime: float  # arm cycles per millisecond of wall time
    cycle_ms: list[float] = field(default_factory=list)  # wall ms per arm cycle, per state
    loop: dict[str, Any] = field(default_factory=dict)  # the robot loop's report
    krc_loop: dict[str, Any] = field(default_factory=dict)  # the simulated KRC's
    fri: dict[str, Any] = field(default_factory=dict)  # link quality and counters
    zenoh_idle: float = 0.0  # cores a process holding only a Zenoh session took
    wakeups: dict[str, float] = field(default_factory=dict)  # process -> switches per s
    interrupted: list[str] = field(default_factory=list)  # motions a stop cut short first
    safety: dict[str, Any] = field(default_factory=dict)  # the monitor's report at the end
    people: int = 0  # people the detector confirmed at the window's end

    @property
    def total(self) -> float:
        """Cores used by the whole deployment (this process included)."""
        return sum(self.cores.values())


def processes(run: SeegRun) -> dict[str, int]:
    """Process name -> pid of every running process of the deployment, and `control`
    (this process: the Coordinator and the Configurator)."""
    assert run.deployment is not None
    out = {p.name: p.popen.pid for p in run.deployment.processes if p.popen is not None}
    out["control"] = os.getpid()
    return out


ROOM = ((11, 2.0, 0.8, 200.0), (12, 1.4, 1.5, 240.0))
"""(person, x, y, facing in degrees) of the people in the room while cost measures: a
surgeon and a nurse 1.3-1.6 m from the arm, away from the table (the robot keeps its
speed), both seen by a camera, so the detector tracks two people and the robot's
speed and separation monitoring checks their envelopes, as in an operating room (the
SEEG topology starts with the room empty). Person ids no other experiment places."""
ROOM_SEEN = 10.0
"""s: how long the detector may take to confirm them before the bench says it did not."""
MOTION_STATES = ("Moving_Fast", "Moving_Slow")
"""The chart's states in which the robot moves toward a goal."""
ZENOH_IDLE = (
    "import sys, time, zenoh\n"
    "config = zenoh.Config()\n"
    "config.insert_json5('mode', '\"peer\"')\n"
    "config.insert_json5('scouting/multicast/enabled', 'false')\n"
    "session = zenoh.open(config)\n"
    "print('ready', flush=True)\n"
    "time.sleep(3600)\n"
)
"""A process that only holds a Zenoh session: the floor any fw process stands on."""


class ShortWindow(BenchError):
    """A window the chart left too soon (a stop) to count cores over."""


MOVING_TRIES = 3
"""Motions the moving window may be tried on: one a stop interrupted (a busy host's
late input, as fw must stop on) is said and the next one measured."""
MIN_WINDOW = 1.0
"""s: the shortest window whose CPU figures mean anything (a motion that ended sooner
is an error of the bench, never a number of cores)."""


def measure(
    run: SeegRun,
    seconds: float,
    jitter_seconds: float,
    while_in: tuple[str, ...] = (),
    resume: Callable[[], None] | None = None,
) -> Window:
    """CPU per process and the arm's real-time factor over `seconds`, or less if the
    chart leaves the states `while_in` (the moving window covers only motion); then
    the arm's cycle intervals over `jitter_seconds` (a subscriber of its 1 kHz output
    costs something, so it comes after the CPU is counted), only those taken while
    still in `while_in` (`resume` sets the robot moving again first if the motion the
    CPU window counted is over: the approach lasts ~9 s). Also what the robot's loop and
    the FRI link report at the CPU window's end: the loop's per-stage cycle times (its last 2000 cycles), scheduling
    class, the link's quality and counters."""
    pids = processes(run)
    pids["zenoh_idle"] = _zenoh_idle(run)
    before = {name: cpu_seconds(pid) for name, pid in pids.items()}
    switched = {name: switches(pid) for name, pid in pids.items()}
    first = run.call("arm.report")
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        if while_in and run.task_state() not in while_in:
            break
        time.sleep(0.05)
    elapsed = time.monotonic() - t0
    after = {name: cpu_seconds(pid) for name, pid in pids.items()}
    wakeups = {name: (switches(pid) - switched[name]) / elapsed for name, pid in pids.items()}
    robot = run.call("robot.report", loop=True)
    last = run.call("arm.report", loop=True)
    if elapsed < MIN_WINDOW:
        state = run.task_state()
        why = run.last_payload("e_STOP") if state == "Stopped" else None
        raise ShortWindow(
            f"the window lasted {elapsed:.2f} s (the chart left {', '.join(while_in)} for "
            f"{state}{f': {why}' if why else ''}): too short to count cores"
        )
    cores = {name: (after[name] - before[name]) / elapsed for name in pids}
    reference = cores.pop("zenoh_idle")
    realtime = (last["cycle"] - first["cycle"]) / (elapsed * 1000.0)
    states = []
    if while_in and resume is not None and run.task_state() not in while_in:
        resume()
    if not while_in or run.task_state() in while_in:
        subscription = run.watch("arm/measured", ArmState)
        start = time.time()
        time.sleep(jitter_seconds)
        run.unwatch(subscription)
        left = run.left_after(while_in, start) if while_in else None
        states = [
            s.message for s in run.since(start, "arm/measured") if left is None or s.received < left
        ]
    window = Window(elapsed, cores, realtime, cycle_intervals(states))
    window.loop = robot.get("loop") or {}
    window.krc_loop = last.get("loop") or {}
    window.fri = {
        "quality_end": last["fri"]["quality"],
        **{k: last["fri"][k] - first["fri"][k] for k in ("missed", "late", "refused")},
        "interface_refused": robot["fri"]["refused"],
        "interface_skipped": robot["fri"]["skipped"],
    }
    window.safety = robot.get("safety") or {}
    window.people = len(run.call("people_detector.current").get("people") or [])
    window.zenoh_idle = reference
    wakeups.pop("zenoh_idle", None)
    window.wakeups = wakeups
    return window


_ZENOH: list[subprocess.Popen[bytes]] = []


def _zenoh_idle(run: SeegRun) -> int:
    """The pid of a process holding only a Zenoh session (started once per bench run)."""
    if not _ZENOH or _ZENOH[0].poll() is not None:
        _ZENOH[:] = [
            subprocess.Popen(
                [sys.executable, "-c", ZENOH_IDLE],
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
            )
        ]
        assert _ZENOH[0].stdout is not None
        _ZENOH[0].stdout.readline()  # ready: its session is open
    return _ZENOH[0].pid


def tightest_watch(safety: dict[str, Any]) -> tuple[str, float, float] | None:
    """The watch whose longest silence since the monitor armed came nearest its
    deadline: (name, longest silence ms, deadline ms), from the robot's `report`
    ("safety"); None without watches. A healthy deployment's margin: a silence past
    the deadline is a false trip."""
    watches = [
        (name, float(w["worst_ms"]), float(w["deadline_ms"]))
        for name, w in (safety.get("watches") or {}).items()
        if w.get("deadline_ms")
    ]
    if not watches:
        return None
    return max(watches, key=lambda w: w[1] / w[2])


def cycle_intervals(states: list[ArmState]) -> list[float]:
    """The wall time (ms) per arm cycle between consecutive states: braked, the arm
    reports once per `monitor_cycles` cycles (FRI's monitor mode), so an interval
    counts for the cycles it covers; a state repeated or out of order is skipped."""
    out = []
    for before, after in itertools.pairwise(states):
        cycles = after.cycle - before.cycle
        if cycles > 0:
            out.append((after.stamp - before.stamp) * 1e3 / cycles)
    return out


def busy_loops(count: int) -> list[subprocess.Popen[bytes]]:
    """`count` processes that each keep a core busy (at the host's normal priority)."""
    return [subprocess.Popen([sys.executable, "-c", BUSY_LOOP]) for _ in range(count)]


def stop(loops: list[subprocess.Popen[bytes]]) -> None:
    """End the busy loops."""
    for loop in loops:
        loop.kill()
    for loop in loops:
        loop.wait()


def idle_and_moving(
    run: SeegRun, seconds: float, jitter_seconds: float, load: int = 0
) -> dict[str, Window]:
    """The deployment braked and waiting for START, measured over `seconds`; then moving
    toward the target, measured while the chart is in a motion state (at most
    `seconds`), with `load` busy loops on the host."""
    run.wait_state("Wait_Start", 60.0)
    state = run.task_state()
    if state != "Wait_Start":
        raise BenchError(f"cost measures the robot waiting for START first; it is in {state}")
    enter_room(run)
    loops = busy_loops(load)
    try:
        idle = measure(run, seconds, jitter_seconds)
        mark = run.mark()
        run.send("e_START")
        run.wait_state("Moving_Fast", 30.0, since=mark)
        goal = ["target"]
        interrupted: list[str] = []
        while True:
            try:
                moving = measure(
                    run,
                    seconds,
                    jitter_seconds,
                    while_in=MOTION_STATES,
                    resume=lambda: keep_moving(run, goal),
                )
                break
            except ShortWindow as exc:
                interrupted.append(str(exc))
                if len(interrupted) >= MOVING_TRIES:
                    raise BenchError(
                        f"{len(interrupted)} motions stopped before a window: "
                        + "; ".join(interrupted)
                    ) from None
                keep_moving(run, goal)  # RELEASE, as the operator would, and measure that
        moving.interrupted = interrupted
    finally:
        stop(loops)
        for person, *_ in ROOM:
            run.call("people_world.leave", person=person)
        for process in _ZENOH:
            process.kill()
            process.wait()
        _ZENOH.clear()
    return {"idle": idle, "moving": moving}


def enter_room(run: SeegRun) -> None:
    """Place the people of `ROOM` and wait until the detector confirms every one of
    them: a window with fewer would measure an emptier room than it says."""
    for person, x, y, facing in ROOM:
        run.call("people_world.place", person=person, x=x, y=y, facing_deg=facing)
    deadline = time.monotonic() + ROOM_SEEN
    while True:
        seen = len(run.call("people_detector.current").get("people") or [])
        if seen >= len(ROOM):
            return
        if time.monotonic() > deadline:
            raise BenchError(
                f"the detector confirmed {seen} of the {len(ROOM)} people placed in the room "
                f"within {ROOM_SEEN:g} s: cost measures with them"
            )
        time.sleep(0.1)


def summary(window: Window) -> dict[str, Any]:
    """A window as plain data (for the JSON summary)."""
    cycles = np.array(window.cycle_ms) if window.cycle_ms else np.array([0.0])
    return {
        "seconds": round(window.seconds, 3),
        "cores": {k: round(v, 4) for k, v in sorted(window.cores.items())},
        "total_cores": round(window.total, 4),
        "realtime": round(window.realtime, 4),
        "zenoh_idle_cores": round(window.zenoh_idle, 4),
        "wakeups_per_s": {k: round(v) for k, v in sorted(window.wakeups.items())},
        "loop": window.loop,
        "krc_loop": window.krc_loop,
        "fri": window.fri,
        "interrupted": window.interrupted,
        "people": window.people,
        "safety": {
            "trips": window.safety.get("trips"),
            "watches": window.safety.get("watches", {}),
        },
        "cycle_ms": {
            "p50": round(float(np.percentile(cycles, 50)), 4),
            "p99": round(float(np.percentile(cycles, 99)), 4),
            "max": round(float(cycles.max()), 4),
            "n": len(window.cycle_ms),
        },
    }
