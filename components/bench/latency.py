"""Reaction latencies of the SEEG deployment (thesis 3.6.3.A-B, Fig. 4.1, 4.3, 4.5).

Every trial runs on the real multi-process deployment in real time. Where each
timestamp is taken (all `time.time()` on this host):

* t_trackerfail: the Sensor Manager's status message whose verdict first marks the
  tracker in use as failed (its stamp: when the Sensor Manager decided);
* t_newtracker: the Supervisor's `sources` record of the first valid sample from
  the new tracker on its rewired `tracked` input (stamped on receipt there);
* t_nosensors -> here t_stop: the interpolator's status message announcing the
  `stopping` phase (stamped in the robot process on the control cycle the motion
  starts braking: later than the thesis's "STOP command sent", never earlier);
* t_collision: the people detector's minimum-distance sample under the procedure's
  collision distance (its stamp: when the detector computed it).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from components.bench.seeg_run import BenchError, Sample, SeegRun

MOVE_TIMEOUT = 60.0


@dataclass
class Trial:
    """One measured reaction: its latency (s) and the stamps it came from."""

    latency: float
    start: float
    end: float
    detail: dict[str, Any] = field(default_factory=dict)


TASK_STATES = (
    "Wait_Start",
    "Moving_Fast",
    "Moving_Slow",
    "Target_Reached",
    "Stopped",
    "No_Tracker",
)


def _first(
    run: SeegRun, key: str, after: float, test: Any, what: str, timeout: float = 10.0
) -> Sample:
    """The first sample of `key` received after `after` that passes `test`."""
    deadline = time.monotonic() + timeout
    while True:
        for sample in run.since(after, key):
            if test(sample.message):
                return sample
        if time.monotonic() > deadline:
            raise BenchError(f"no {what} within {timeout:g} s")
        time.sleep(0.002)


def _failed(tracker: str) -> Any:
    def test(message: Any) -> bool:
        health = message.payload.get("health", {}).get(tracker, {})
        return isinstance(health, dict) and health.get("ok") is False

    return test


def _last_task_state(run: SeegRun) -> str:
    return run.last_entered(TASK_STATES)


def keep_moving(run: SeegRun, goal: list[str]) -> None:
    """Make sure the robot is on its way: START, or Go To the other goal once there
    (`goal` holds the current goal and is flipped)."""
    deadline = time.monotonic() + MOVE_TIMEOUT
    while True:
        state = _last_task_state(run)
        if state in ("Moving_Fast", "Moving_Slow"):
            return
        if time.monotonic() > deadline:
            raise BenchError(f"the robot did not start moving (last state {state})")
        # an event the chart cannot take yet (a configuration still running) is
        # dropped, so ask again until the robot moves
        if state == "Wait_Start":
            run.send("e_START")
        elif state == "Target_Reached":
            goal[0] = "home" if goal[0] == "target" else "target"
            run.send("e_GOTO", {"where": goal[0]})
        elif state in ("Stopped", "No_Tracker"):
            run.send("e_RELEASE")
        for _ in range(100):
            time.sleep(0.01)
            if _last_task_state(run) != state:
                break


def _tracker_in_use(run: SeegRun) -> str:
    state = run.last_entered(("Certus_Up", "Vicra_Up"))
    return {"Certus_Up": "certus", "Vicra_Up": "vicra"}.get(state, "")


def _repeat(
    name: str, trials: int, trial: Callable[[], Trial | None], progress: Any, cleanup: Any
) -> list[Trial]:
    """Run `trial` until `trials` succeeded; a failed one (BenchError) is cleaned up
    and retried, at most 10 times in all."""
    out: list[Trial] = []
    failures: list[str] = []
    while len(out) < trials:
        if len(failures) > 10:
            raise BenchError(f"{name}: {len(failures)} trials failed; last: {failures[-1]}")
        try:
            result = trial()
        except BenchError as exc:
            failures.append(str(exc))
            cleanup()
            continue
        if result is not None:
            out.append(result)
            if progress:
                progress(len(out), trials)
    return out


def sensor_swap(run: SeegRun, trials: int, progress: Any = None) -> list[Trial]:
    """Occlude the Certus while the robot moves; L = t_newtracker - t_trackerfail
    (eq. 3.12). After each trial the Certus is uncovered and the chart swaps back."""
    goal = ["target"]

    def trial() -> Trial:
        keep_moving(run, goal)
        if _tracker_in_use(run) != "certus":
            raise BenchError("the Certus is not in use")
        t0 = time.time()
        run.call("certus.occlude", tool="cto")
        try:
            fail = _first(run, "sensor_manager/status", t0, _failed("certus"), "Certus fault")
            new = _first(
                run,
                "supervisor/sources",
                t0,
                lambda m: m.payload.get("tracker") == "vicra",
                "Vicra sample at the Supervisor",
            )
        finally:
            run.call("certus.occlude", tool="cto", hidden=False)
        t_fail, t_new = fail.message.stamp, new.message.stamp
        _back_to(run, "certus")
        return Trial(
            t_new - t_fail,
            t_fail,
            t_new,
            {
                "sample_age": t_new - new.message.payload.get("sample_stamp", t_new),
                "fault": fail.message.payload["health"]["certus"].get("cause", ""),
            },
        )

    return _repeat("sensor swap", trials, trial, progress, lambda: _recover(run))


def no_sensor_to_stop(run: SeegRun, trials: int, progress: Any = None) -> list[Trial]:
    """With the Vicra occluded, occlude the Certus while the robot moves;
    L = t_stop - t_trackerfail (eq. 3.13). Then uncover it and RELEASE."""
    goal = ["target"]

    def trial() -> Trial:
        keep_moving(run, goal)
        mark = run.mark()
        t0 = time.time()
        run.call("certus.occlude", tool="cto")
        try:
            fail = _first(run, "sensor_manager/status", t0, _failed("certus"), "Certus fault")
            stop = _first(
                run,
                "interpolator/status",
                t0,
                lambda m: m.name in ("stopping", "stopped"),
                "interpolator stop",
            )
            run.wait_state("No_Tracker", 10.0, since=mark)
        finally:
            run.call("certus.occlude", tool="cto", hidden=False)
        _healthy(run, "certus")
        t_fail, t_stop = fail.message.stamp, stop.message.stamp
        return Trial(t_stop - t_fail, t_fail, t_stop, {"phase": stop.message.name})

    run.call("vicra_sim.occlude", tool="cto")
    try:
        return _repeat(
            "no sensor to stop",
            trials,
            trial,
            progress,
            lambda: (_recover(run), run.call("vicra_sim.occlude", tool="cto")),
        )
    finally:
        run.call("vicra_sim.occlude", tool="cto", hidden=False)


def _healthy(run: SeegRun, tracker: str, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while True:
        status = run.call("sensor_manager.current")
        if status.get("health", {}).get(tracker, {}).get("ok"):
            return
        if time.monotonic() > deadline:
            raise BenchError(f"{tracker} did not recover in {timeout:g} s")
        time.sleep(0.02)


def _back_to(run: SeegRun, tracker: str, timeout: float = 10.0) -> None:
    """Wait until the chart navigates with `tracker` again (or left Moving)."""
    deadline = time.monotonic() + timeout
    while _tracker_in_use(run) != tracker:
        if _last_task_state(run) not in ("Moving_Fast", "Moving_Slow"):
            return
        if time.monotonic() > deadline:
            raise BenchError(f"the chart did not return to {tracker}")
        time.sleep(0.01)


def _recover(run: SeegRun) -> None:
    """After a failed trial: everything visible, healthy again, then moving."""
    for ref in ("certus.occlude", "vicra_sim.occlude"):
        run.call(ref, tool="cto", hidden=False)
    _healthy(run, "certus")
