"""`fw bench chaos`: every process of the SEEG deployment crashed or hung, and the FRI
link between the robot interface and the KRC failed, while the arm approaches the
target at 7.5 cm/s, on a fresh deployment each time.

For each case (a process, a fault: KILL, STOP 2 s, STOP 0.3 s) the run keeps every
state the arm's controller published (`arm/measured`, 1 kHz) and every status of the
robot interface (`robot/status`), stamped in the publishing process (all processes run
on this host, so their clocks compare). From them:

* **to braking**: from the fault to the first control cycle that brakes: the robot
  interface's protective stop begins (its status turns latched) or the arm's
  controller engages its brakes, whichever comes first;
* **to standstill**: from the fault to the brakes being on (the simulated brake holds
  the joints where they are);
* **moved without RELEASE**: after the brakes were on, any state of the arm released
  or moving faster than 1 mrad/s, until the end of the observation (2 s after the
  process resumed, for a hang); no RELEASE is sent during a case.

The FRI link's faults (`LINK_FAULTS`, injected by `arm.impair` at the time the case
calls "the fault") are timed the same way; the garbage case must *not* brake: refused
datagrams change no decision.

The arm's own process is the machine: killed, it is a power loss (the brakes hold by
construction, there is no state to read); hung, its physics stands still. Its rows
say so rather than invent a braking time.
"""

from __future__ import annotations

import functools
import os
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from framework.messages import ArmState, EventMessage
from fw_bench.seeg_run import BenchError

PROCESSES = ("vicra_device", "trackers", "cameras", "arm", "robot", "supervision")
FAULTS = (("KILL", 0.0), ("STOP", 2.0), ("STOP", 0.3))
LINK_FAULTS = (
    ("answers lost 50ms", {"drop_every": 1, "seconds": 0.05}, True),
    ("answers late 5ms", {"delay_ms": 5.0, "seconds": 0.5}, True),
    ("KRC silent 60ms", {"silence_ms": 60.0}, True),
    ("garbage+foreign", {"garbage": 40, "foreign": 10}, False),
)
"""The FRI link's faults: name, `arm.impair` arguments, whether the arm must brake."""
STILL = 1e-3  # rad/s
AFTER = 2.0  # s of observation after the fault (after the resume, for a hang)


@dataclass
class Case:
    """One injected fault and what came of it."""

    process: str
    signal: str
    hold: float
    to_braking_ms: float | None = None
    to_standstill_ms: float | None = None
    moved_without_release: bool = False
    ended_braked: bool = False
    chart: str = ""
    detail: str = ""
    notes: list[str] = field(default_factory=list)
    link: str = ""
    """An FRI link fault's name (`LINK_FAULTS`; process `fri`, signal `LINK`)."""
    must_brake: bool = True
    may_go_on: bool = False
    """A fault that may or may not stop the robot (a link's delay: whether the inputs it
    slows pass their deadlines depends on the traffic): never stopped is fine too."""
    recording_gaps: dict[str, int] = field(default_factory=dict)
    """chaos --hosts: per channel of the control host's flight recording, how many of the
    chart's records, requests and answers written are missing from it."""

    @property
    def name(self) -> str:
        """KILL, STOP 2s, STOP 0.3s, or the link fault's name."""
        if self.link:
            return self.link
        return "KILL" if self.signal == "KILL" else f"STOP {self.hold:g}s"

    @property
    def ok(self) -> bool:
        """Braked at the end, and no motion after the brakes without a RELEASE; for a
        fault that must not brake (garbage), never braked nor latched; for one that may
        go on (`may_go_on`), either of those."""
        if not self.must_brake:
            return self.to_braking_ms is None and not self.ended_braked
        if self.may_go_on and self.to_braking_ms is None and not self.ended_braked:
            return not self.moved_without_release  # never stopped: it carried on
        return self.ended_braked and not self.moved_without_release

    def line(self) -> str:
        """One line for the terminal."""

        def ms(v: float | None) -> str:
            return "   n/a" if v is None else f"{v:6.1f}"

        verdict = "ok  " if self.ok else "FAIL"
        return (
            f"{verdict} {self.process:<13} {self.name:<9} braking {ms(self.to_braking_ms)} ms  "
            f"standstill {ms(self.to_standstill_ms)} ms  "
            f"moved w/o RELEASE: {'YES' if self.moved_without_release else 'no '}  "
            f"chart {self.chart:<12} {self.detail}"
        )


class SetupFailed(BenchError):
    """A case's fresh deployment never began its approach: no fault was injected, so
    no result of the case; tried again (`SETUP_TRIES`) and counted apart."""


SETUP_TRIES = 3
"""Fresh deployments a case may take to begin its approach."""


def setup_failed(run: Any, exc: BenchError) -> SetupFailed:
    """A case's setup that ended in `exc` before any fault, with the chart's e_NOTRACKER
    (what each tracker lacked) if it went to No_Tracker instead of moving."""
    tracking = run.last_payload("e_NOTRACKER")
    return SetupFailed(f"{exc}{f'; e_NOTRACKER: {tracking}' if tracking else ''}")


def set_up_and_run(label: str, attempt: Callable[[], Case], setups: list[str]) -> Case:
    """`attempt()` (one case on a fresh deployment) until its setup succeeds, at most
    `SETUP_TRIES` times; why each failed setup failed is appended to `setups` (as
    "label: why") and said on stderr. The last failure is raised: a case that never
    sets up ends the run with its reason. `chaos` and `chaos --hosts` both run their
    cases through this."""
    for tried in range(1, SETUP_TRIES + 1):
        try:
            return attempt()
        except SetupFailed as exc:
            setups.append(f"{label}: {exc}")
            print(f"setup failed ({tried} of {SETUP_TRIES}): {exc}", file=sys.stderr)
            if tried == SETUP_TRIES:
                raise
    raise AssertionError("unreachable: SETUP_TRIES >= 1")


def run_case(process: str, signal_name: str, hold: float, link: tuple | None = None) -> Case:
    """Deploy, start the approach, inject the fault (a signal to `process`, or the FRI
    link fault `link` of `LINK_FAULTS`), watch, shut down."""
    from fw_bench.seeg_run import SeegRun

    case = Case(process, signal_name, hold)
    if link is not None:
        case.link, case.must_brake = link[0], link[2]
    run = SeegRun()
    try:
        try:
            run.start()
            run.watch("arm/measured", ArmState)
            run.watch("robot/status", EventMessage)
            run.send("e_START")
            run.wait_state("Moving_Fast", 30.0)
        except BenchError as exc:
            raise setup_failed(run, exc) from exc
        time.sleep(0.6)  # well into the approach: at speed
        deployment = run.deployment
        assert deployment is not None
        if link is not None:
            fault = time.time()
            run.call("arm.impair", **link[1])
            time.sleep(AFTER)
            _judge(case, run, fault)
            case.chart = run.last_entered(
                ("Fault", "Stopped", "Moving_Fast", "Moving_Slow", "Target_Reached")
            )
            return case
        popen = next(p.popen for p in deployment.processes if p.name == process)
        assert popen is not None
        fault = time.time()
        os.kill(popen.pid, getattr(signal, f"SIG{signal_name}"))
        if signal_name == "STOP":
            time.sleep(hold)
            if popen.poll() is None:
                os.kill(popen.pid, signal.SIGCONT)
            else:  # a hung process does not exit by itself: said, and judged as it is
                case.detail = f"{process} gone before SIGCONT"
                case.notes.append(
                    f"{process} was gone before SIGCONT (exit {popen.returncode}): "
                    f"{', '.join(deployment.watch.incidents[-3:]) if deployment.watch else ''}"
                )
        time.sleep(AFTER)
        _judge(case, run, fault)
        case.chart = run.last_entered(
            ("Fault", "Stopped", "No_Tracker", "Moving_Fast", "Moving_Slow", "Target_Reached")
        )
    finally:
        run.stop()
    return case


def _judge(case: Case, run: Any, fault: float) -> None:
    states = [s.message for s in run.since(fault - 0.5, "arm/measured")]
    after = [m for m in states if m.stamp >= fault]
    trips = [
        s.message.stamp
        for s in run.since(fault - 0.5, "robot/status")
        if s.message.stamp >= fault and s.message.payload.get("latched")
    ]
    brakes = [m.stamp for m in after if m.braked]
    starts = [*trips[:1], *brakes[:1]]
    if starts:
        case.to_braking_ms = (min(starts) - fault) * 1e3
    if brakes:
        case.to_standstill_ms = (brakes[0] - fault) * 1e3
        since = [m for m in after if m.stamp >= brakes[0]]
        moving = [
            m for m in since if not m.braked or max((abs(v) for v in m.velocity), default=0) > STILL
        ]
        case.moved_without_release = bool(moving)
        case.ended_braked = bool(since) and since[-1].braked
        if moving:
            case.detail = f"moving {(moving[0].stamp - fault) * 1e3:.0f} ms after the fault"
    if case.process == "arm":  # the machine itself
        if case.signal == "KILL":
            case.ended_braked = True  # a power loss: the brakes hold by construction
            case.to_standstill_ms = None
            case.notes.append("the arm's process is the machine: killed, it is a power loss")
            case.detail = case.detail or "power loss: brakes by construction"
        else:
            frozen = [m for m in states if fault <= m.stamp]
            case.detail = case.detail or "physics stood still while hung"
            case.ended_braked = bool(frozen) and frozen[-1].braked
    if not after and case.process != "arm":
        case.detail = "no arm state after the fault"


def chaos(repetitions: int, progress: Any = None) -> tuple[list[Case], list[str]]:
    """Every process x fault kind and every FRI link fault, `repetitions` times each,
    one line per case printed; and why each setup that never began its approach
    failed (the case was run again on a fresh deployment, at most `SETUP_TRIES`)."""
    cases: list[Case] = []
    setups: list[str] = []
    plan: list[tuple[str, str, float, tuple | None]] = [
        (process, signal_name, hold, None) for process in PROCESSES for signal_name, hold in FAULTS
    ]
    plan += [("fri", "LINK", 0.0, link) for link in LINK_FAULTS]
    total = repetitions * len(plan)
    for _ in range(repetitions):
        for process, signal_name, hold, link in plan:
            case = set_up_and_run(
                f"{process} {signal_name}",
                functools.partial(run_case, process, signal_name, hold, link),
                setups,
            )
            cases.append(case)
            print(case.line(), file=sys.stderr, flush=True)
            if progress is not None:
                progress(len(cases), total)
    return cases, setups
