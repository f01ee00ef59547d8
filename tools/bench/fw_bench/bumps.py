"""Head bumps on the deployed SEEG system (issue 42): bus, trackers, Sensor Manager,
Supervisor, navigator and the MuJoCo arm as `fw deploy` runs them, not the simulated
clock of `navigation.head_bump`.

The robot holds at the target, steered by one tracker (the Certus; for the Vicra, the
Certus's robot tool is occluded first). The head is bumped by 5 mm along a cosine
ramp of 50 ms, in one of 26 directions (the faces, edges and corners of a cube) in
turn, and bumped back 1.5 s later (each is a bump: the head stays within the
navigator's 10 mm of where it was registered, and two bumps are never within the
second over which the patient's speed is measured). For each bump:

* the error before: the median over 0.5 s of the real TCP's distance to the target on
  the head (`patient.report`, the referee), sampled at 50 Hz;
* `back_s`: the time from the bump's start until the error is within 0.5 mm of that
  and stays there for 0.2 s (None: never, within the 1.5 s window);
* `worst_after_1s_mm`: the largest error from 1 s after the bump's start to the end of
  its window (the target: no more than the error before + 0.5 mm);
* `faults`: every calibration verdict the Sensor Manager said in the window, with its
  numbers, and `swaps`: every e_TFAULT the chart took. A bump must cause neither.

A bump whose procedure stopped on a late input (a watched input past its deadline, the
KRC braking on late answers: the host fell behind, and fw stopped the robot as it
must) measures nothing of the navigation: it is reported (`rerun_after_late_input`,
a row of its own), the head is bumped back, the procedure released and the bump run
again, at most `RERUNS` times a series. Any other stop ends the series.

At the end, a real calibration fault: the Certus's reference tool slips 6 mm on its
mount (`certus.bump_reference`), and `detected_s` is the time until the Sensor
Manager says so; then it is slipped back and trusted again.
"""

from __future__ import annotations

import itertools
import math
import statistics
import time
from typing import Any

from fw_bench.seeg_run import BenchError, SeegRun

BUMP_MM = 5.0
RAMP_MS = 50.0
WINDOW = 1.5  # s after each bump before the next (the patient's speed is over 1 s)
SAMPLE = 0.02  # s between referee samples
DIRECTIONS = [
    tuple(v / math.sqrt(sum(c * c for c in (x, y, z))) for v in (x, y, z))
    for x, y, z in itertools.product((-1, 0, 1), repeat=3)
    if (x, y, z) != (0, 0, 0)
]
"""The 26 unit directions to a cube's faces, edges and corners."""


def _error(run: SeegRun) -> float | None:
    value = run.call("patient.report").get("target_error_mm")
    return None if value is None else float(value)


def _errors(run: SeegRun, seconds: float) -> list[tuple[float, float | None]]:
    """(time since the start, the referee's error in mm) every `SAMPLE` for `seconds`."""
    start = time.monotonic()
    out = []
    while (elapsed := time.monotonic() - start) < seconds:
        out.append((elapsed, _error(run)))
        time.sleep(max(0.0, SAMPLE - (time.monotonic() - start - elapsed)))
    return out


STOPS: list[dict[str, Any]] = []
"""Stops of the procedure while the bench waited for a tracker to steer (each then
RELEASEd): what the chart stopped on, reported beside the bumps, never hidden."""


def _settle(run: SeegRun, tracker: str, timeout: float = 30.0) -> None:
    """Hold at the target with `tracker` steering (a procedure that stops meanwhile is
    recorded in `STOPS` and brought back to the target)."""
    if tracker == "vicra":
        run.call("certus.occlude", tool="cto")
    deadline = time.monotonic() + timeout
    while (report := run.call("supervisor.report")).get("steering") != tracker:
        if run.task_state() in ("Stopped", "No_Tracker") and len(STOPS) < 10:
            STOPS.append(
                {
                    "waiting_for": tracker,
                    "state": run.task_state(),
                    "e_STOP": run.last_payload("e_STOP"),
                    "e_NOTRACKER": run.last_payload("e_NOTRACKER"),
                }
            )
            hold_at_target(run)
            continue
        if time.monotonic() > deadline:
            health = run.call("sensor_manager.current").get("health", {})
            why = "; ".join(
                f"{name}: {'ok' if h.get('ok') else h.get('cause')} {h.get('detail') or ''}".strip()
                for name, h in health.items()
            )
            raise BenchError(
                f"{tracker} does not steer after {timeout:g} s (steering: "
                f"{report.get('steering')}, chart: {run.task_state()}; trackers: {why}; "
                f"last e_STOP: {run.last_payload('e_STOP')}, "
                f"e_NOTRACKER: {run.last_payload('e_NOTRACKER')})"
            )
        time.sleep(0.1)
    time.sleep(3.0)  # the swap's carry and the filter settle


def _faults(run: SeegRun, since: float, until: float) -> list[dict[str, Any]]:
    """Calibration verdicts the Sensor Manager said between `since` and `until`."""
    out = []
    for sample in run.since(since, "sensor_manager/status"):
        if sample.received > until:
            break
        for name, health in sample.message.payload.get("health", {}).items():
            if isinstance(health, dict) and health.get("cause") == "calibration":
                out.append({"tracker": name, "detail": health.get("detail"), **health})
    return out


def bump_once(run: SeegRun, offset_mm: tuple[float, float, float]) -> dict[str, Any]:
    """One bump and what it did (module docstring)."""
    before = [e for _, e in _errors(run, 0.5) if e is not None]
    base = statistics.median(before) if before else math.nan
    started = time.time()
    dx, dy, dz = offset_mm
    run.call("patient.bump", dx=dx, dy=dy, dz=dz, duration_ms=RAMP_MS)
    trace = _errors(run, WINDOW)
    ended = time.time()
    back = None
    for k, (t, e) in enumerate(trace):
        hold = [x for s, x in trace[k:] if s - t <= 0.2]
        if e is not None and all(x is not None and x <= base + 0.5 for x in hold):
            back = t
            break
    late = [e for t, e in trace if t >= 1.0 and e is not None]
    return {
        "offset_mm": [round(v, 3) for v in offset_mm],
        "before_mm": round(base, 3),
        "back_s": None if back is None else round(back, 3),
        "worst_after_1s_mm": round(max(late), 3) if late else None,
        "faults": _faults(run, started, ended),
        "swaps": run.taken_after("e_TFAULT", started) is not None
        and run.taken_after("e_TFAULT", started) <= ended,
        "state": run.task_state(),
        # why the procedure stopped, if it did (the chart's last e_STOP / e_NOTRACKER)
        "stopped_on": None
        if run.task_state() == "Target_Reached"
        else {
            "e_STOP": run.last_payload("e_STOP"),
            "e_NOTRACKER": run.last_payload("e_NOTRACKER"),
            "e_PATIENT_MOVED": run.last_payload("e_PATIENT_MOVED"),
        },
    }


LATE_INPUT = ("no data for", "FRI quality too low")
"""What a stop on the host falling behind says: a watched input past its deadline, or
the KRC braking on late answers (fail-safe, and nothing a bump measures)."""
RERUNS = 6
"""Bumps of one series re-run after such a stop, at most (each one reported)."""
HOST_STOPS: list[dict[str, Any]] = []
"""Bumps whose procedure stopped on a late input, re-run from a RELEASE: reported beside
the bumps, never hidden (the quick bench on a loaded 2-core CI host meets them)."""


def _host_fell_behind(result: dict[str, Any]) -> bool:
    """Whether a bump's procedure stopped on a late input, not on anything it measures."""
    stop = (result.get("stopped_on") or {}).get("e_STOP") or {}
    return any(words in str(stop.get("reason", "")) for words in LATE_INPUT)


def bumps(run: SeegRun, tracker: str, count: int, progress: Any = None) -> list[dict[str, Any]]:
    """`count` bumps (out and back in turn) with `tracker` steering at the target. A bump
    whose procedure stopped on a late input (`LATE_INPUT`) is put in `HOST_STOPS`, the
    head bumped back to where it was, the procedure released and the bump run again (at
    most `RERUNS` per series); any other stop ends the series, as the bench reports."""
    _settle(run, tracker)
    out: list[dict[str, Any]] = []
    reruns = 0
    k = 0
    while k < count:
        direction = DIRECTIONS[(k // 2) % len(DIRECTIONS)]
        sign = 1.0 if k % 2 == 0 else -1.0  # out, then back
        offset = tuple(sign * BUMP_MM * v for v in direction)
        result = bump_once(run, offset)  # type: ignore[arg-type]
        result["tracker"] = tracker
        if result["state"] != "Target_Reached" and _host_fell_behind(result) and reruns < RERUNS:
            reruns += 1
            HOST_STOPS.append({"tracker": tracker, "bump": k, **result})
            dx, dy, dz = offset
            run.call("patient.bump", dx=-dx, dy=-dy, dz=-dz, duration_ms=RAMP_MS)
            hold_at_target(run)
            _settle(run, tracker)
            continue
        out.append(result)
        k += 1
        if progress:
            progress(k, count)
        if result["state"] != "Target_Reached":
            break  # the procedure stopped: what the bench reports
    return out


def real_fault(run: SeegRun, slip_m: float = 0.006) -> dict[str, Any]:
    """The Certus's reference tool slips `slip_m` on its mount (the head stays): how long
    until the Sensor Manager says the Certus's calibration is wrong. The slip is undone
    and the Certus trusted again afterwards."""
    run.call("certus.occlude", tool="cto", hidden=False)
    _settle(run, "certus")
    started = time.time()
    run.call("certus.bump_reference", dx=slip_m)
    detected, detail = None, ""
    deadline = time.monotonic() + 5.0
    while detected is None and time.monotonic() < deadline:
        for sample in run.since(started, "sensor_manager/status"):
            health = sample.message.payload.get("health", {}).get("certus", {})
            if isinstance(health, dict) and health.get("cause") == "calibration":
                detected, detail = sample.received, str(health.get("detail"))
                break
        time.sleep(0.01)
    time.sleep(0.5)
    latched = not run.call("sensor_manager.current")["health"]["certus"]["ok"]
    run.call("certus.bump_reference", dx=-slip_m)
    time.sleep(0.5)
    if latched:
        run.call("sensor_manager.trust", sensor="certus")
    return {
        "slip_mm": slip_m * 1e3,
        "detected_s": None if detected is None else round(detected - started, 4),
        "detail": detail,
        "latched": latched,
    }


def hold_at_target(run: SeegRun, timeout: float = 120.0) -> None:
    """Bring the deployment (in whatever state other experiments left it) to holding
    at the target: START, RELEASE or Go To as the chart needs."""
    deadline = time.monotonic() + timeout
    while True:
        state = run.task_state()
        goal = run.call("interpolator.report").get("goal")
        if state == "Target_Reached" and goal == "target":
            return
        if time.monotonic() > deadline:
            raise BenchError(f"not holding at the target after {timeout:g} s ({state})")
        if state == "Wait_Start":
            run.send("e_START")
        elif state == "Target_Reached":
            run.send("e_GOTO", {"where": "target"})
        elif state in ("Stopped", "No_Tracker"):
            run.send("e_RELEASE")
        time.sleep(0.5)


def deployed(run: SeegRun, count: int, progress: Any = None) -> dict[str, Any]:
    """`count` bumps with each tracker steering, then a real calibration fault; the
    Certus is seen again at the end, as it was."""
    results = {}
    STOPS.clear()
    HOST_STOPS.clear()
    try:
        for tracker in ("certus", "vicra"):
            hold_at_target(run)  # a bump that stopped the procedure is in its result
            results[tracker] = bumps(run, tracker, count, progress)
        run.call("certus.occlude", tool="cto", hidden=False)
        hold_at_target(run)
        fault = real_fault(run)
    finally:
        run.call("certus.occlude", tool="cto", hidden=False)
    return {
        "bumps": results,
        "real_fault": fault,
        "stops_while_settling": list(STOPS),
        "rerun_after_late_input": list(HOST_STOPS),
    }
