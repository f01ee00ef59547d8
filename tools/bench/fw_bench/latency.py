"""Reaction latencies of the SEEG deployment (thesis 3.6.3.A-B, Fig. 4.1, 4.3, 4.5).

Every trial runs on the real multi-process deployment in real time. Where each
timestamp is taken (all `time.time()` on this host):

* t_trackerfail: the Sensor Manager's status message whose verdict first marks the
  tracker in use as failed (its stamp: when the Sensor Manager decided);
* t_newtracker: the navigator's `sources` record of the first valid sample from
  the new tracker on its rewired `cto` input (stamped on receipt there: the tracker
  that steers has changed);
* t_nosensors and t_stop (the thesis' "STOP command sent to the robot"): the
  Supervisor's `halt` message to the interpolator, stamped when it is written;
* t_brake (stricter, not in the thesis): the interpolator's status message
  announcing the `stopping` phase, stamped in the robot process on the 1 kHz control
  cycle the motion starts braking (so it adds up to one cycle of waiting);
* t_collision: the people detector's minimum-distance sample under the procedure's
  collision distance (its stamp: when the detector computed it);
* protective stops (speed and separation monitoring, in the robot interface's own
  cycle): from the arrival here of the envelopes sample that decided it (one hop, as
  for the robot process) to the robot's status announcing it, stamped in the cycle
  that sent the stop's first command; and, inside that cycle, from the start of the
  separation check to that command (the interface's own clock).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from framework import keys
from framework.messages import EventMessage, Pose
from fw_bench.files import seeg_file
from fw_bench.seeg_run import BenchError, Sample, SeegRun

MOVE_TIMEOUT = 60.0


@dataclass
class Trial:
    """One measured reaction: its latency (s) and the stamps it came from."""

    latency: float
    start: float
    end: float
    detail: dict[str, Any] = field(default_factory=dict)


def _first(
    run: SeegRun, key: str, after: float, test: Any, what: str, timeout: float = 10.0
) -> Sample:
    """The first sample of `key` received after `after` that passes `test`."""
    return _first_of(run, after, {key: test}, what, timeout)


def _first_of(
    run: SeegRun, after: float, tests: dict[str, Any], what: str, timeout: float = 10.0
) -> Sample:
    """The first sample received after `after`, of any key of `tests`, that passes that
    key's test."""
    deadline = time.monotonic() + timeout
    while True:
        found = [
            sample
            for key, test in tests.items()
            for sample in run.since(after, key)
            if test(sample.message)
        ]
        if found:
            return min(found, key=lambda s: s.received)
        if time.monotonic() > deadline:
            raise BenchError(f"no {what} within {timeout:g} s")
        time.sleep(0.002)


def _failed(tracker: str) -> Any:
    def test(message: Any) -> bool:
        health = message.payload.get("health", {}).get(tracker, {})
        return isinstance(health, dict) and health.get("ok") is False

    return test


def keep_moving(run: SeegRun, goal: list[str]) -> None:
    """Make sure the robot is on its way: START, or Go To the other goal once there
    (`goal` holds the current goal and is flipped)."""
    deadline = time.monotonic() + MOVE_TIMEOUT
    while True:
        state = run.task_state()
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
            if run.task_state() != state:
                break


def _tracker_in_use(run: SeegRun) -> str:
    tag = run.last_requested(("tracker_1_up", "tracker_2_up"))
    return {"tracker_1_up": "certus", "tracker_2_up": "vicra"}.get(tag, "")


def _repeat(
    name: str,
    trials: int,
    trial: Callable[[], Trial | None],
    progress: Any,
    cleanup: Any,
    give_up: Callable[[], bool] = lambda: False,
) -> list[Trial]:
    """Run `trial` until `trials` succeeded (a trial returning None does not count)
    or `give_up()`; a failed one (BenchError) is cleaned up and retried, at most 10
    times in all."""
    out: list[Trial] = []
    failures: list[str] = []
    while len(out) < trials and not give_up():
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
        _back_to(run, "certus")  # after another experiment the Vicra may still be in use
        if _tracker_in_use(run) != "certus":
            raise BenchError("the Certus is not in use")
        t0 = time.time()
        run.call("certus.occlude", tool="cto")
        try:
            fail = _first(run, "sensor_manager/status", t0, _failed("certus"), "Certus fault")
            new = _first(
                run,
                "navigator/sources",
                t0,
                lambda m: m.payload.get("tracker") == "vicra",
                "Vicra sample at the navigator",
            )
        finally:
            run.call("certus.occlude", tool="cto", hidden=False)
        t_fail, t_new = fail.message.stamp, new.message.stamp
        stages = _stages(
            t_fail,
            [
                ("Supervisor raises e_TFAULT", _event_stamp(run, "e_TFAULT", t0)),
                ("the chart takes it", run.taken_after("e_TFAULT", t_fail)),
                ("tracker_2_up requested", run.requested_after("tracker_2_up", t_fail)),
                (
                    "the navigator's process switched (its report)",
                    _switched(run, "tracker_2_up", t0),
                ),
                ("first Vicra sample at the navigator", t_new),
            ],
        )
        _back_to(run, "certus")
        return Trial(
            t_new - t_fail,
            t_fail,
            t_new,
            {
                "sample_age": t_new - new.message.payload.get("sample_stamp", t_new),
                "fault": fail.message.payload["health"]["certus"].get("cause", ""),
                "stages": stages,
            },
        )

    return _repeat("sensor swap", trials, trial, progress, lambda: _recover(run))


def _switched(run: SeegRun, tag: str, t0: float) -> float | None:
    """The stamp of a process's local switch to `tag` after `t0` (the navigator's
    process: supervision since issue 43; None if the Configurator made it: the request
    was not `alone`)."""
    for sample in run.since(t0, keys.ALL_SWITCHED):
        if sample.message.tag == tag and sample.message.ok:
            return float(sample.message.stamp)
    return None


def no_sensor_to_stop(run: SeegRun, trials: int, progress: Any = None) -> list[Trial]:
    """With the Vicra occluded, occlude the Certus while the robot moves;
    L = t_nosensors - t_trackerfail (eq. 3.13), and the braking cycle's latency in
    `detail["brake"]`. Then uncover it and RELEASE."""
    goal = ["target"]

    def trial() -> Trial:
        keep_moving(run, goal)
        mark = run.mark()
        t0 = time.time()
        run.call("certus.occlude", tool="cto")
        try:
            fail = _first(run, "sensor_manager/status", t0, _failed("certus"), "Certus fault")
            result = _stop_after(run, t0, fail.message.stamp, "no tracker")
            run.wait_state("No_Tracker", 10.0, since=mark)
        finally:
            run.call("certus.occlude", tool="cto", hidden=False)
        _healthy(run, "certus")
        return result

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


def _stop_after(run: SeegRun, t0: float, cause: float, reason: str) -> Trial:
    """The STOP that `cause` (a stamp) led to: the Supervisor's halt whose reason starts
    with `reason`, and the braking cycle, both seen after `t0`. The trial's latency
    is to the halt (the thesis' "STOP command sent"); `detail["brake"]` to the cycle."""
    halt = _first(
        run,
        "supervisor/halt",
        t0,
        # a STOP stamped before its cause is not its effect (a "no tracker" while the
        # recovered tracker was still in the Sensor Manager's hysteresis, say)
        lambda m: m.stamp >= cause and str(m.payload.get("reason", "")).startswith(reason),
        "STOP command",
    )
    brake = _first(
        run,
        "interpolator/status",
        t0,
        lambda m: m.name in ("stopping", "stopped"),
        "interpolator stop",
    )
    t_stop, t_brake = halt.message.stamp, brake.message.stamp
    stages = _stages(
        cause,
        [
            ("Supervisor sends the halt (STOP command)", t_stop),
            ("the braking control cycle", t_brake),
        ],
    )
    return Trial(
        t_stop - cause,
        cause,
        t_stop,
        {"brake": t_brake - cause, "phase": brake.message.name, "stages": stages},
    )


def _event_stamp(run: SeegRun, name: str, after: float) -> float | None:
    """The stamp of the first event `name` published on fw/events after `after`."""
    return next(
        (s.message.stamp for s in run.since(after, "fw/events") if s.message.name == name), None
    )


def _stages(start: float, marks: list[tuple[str, float | None]]) -> dict[str, float]:
    """Time (s) spent in each stage of a reaction chain: from the previous mark to this
    one. A missing mark merges its stage into the next."""
    out: dict[str, float] = {}
    previous = start
    for name, at in marks:
        if at is None:
            continue
        out[name] = at - previous
        previous = at
    return out


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
        if run.task_state() not in ("Moving_Fast", "Moving_Slow"):
            return
        if time.monotonic() > deadline:
            raise BenchError(f"the chart did not return to {tracker}")
        time.sleep(0.01)


def _recover(run: SeegRun) -> None:
    """After a failed trial: everything visible, healthy again, then moving."""
    for ref in ("certus.occlude", "vicra_sim.occlude"):
        run.call(ref, tool="cto", hidden=False)
    _healthy(run, "certus")


COLLIDER = 1
"""The person of `people_world` who touches the robot in the collision trials."""


def collision_reaction(run: SeegRun, trials: int, progress: Any = None) -> list[Trial]:
    """A surgeon standing at the table leans over the moving robot; L = t_stop -
    t_collision (eq. 3.18), and the braking cycle's latency in `detail["brake"]`.
    Then they stand upright, the distance clears and RELEASE resumes the motion.
    Speed and separation monitoring may stop the arm first: before the collision
    distance (more often on a busy host, where the lean is seen later), or on the same
    camera frame as the Supervisor, whose halt then comes after the arm already brakes.
    Such a lean (a protective stop said, or the braking cycle, before the halt) is
    returned with `detail["preempted"]` and leaned again, until `trials` leans timed
    the Supervisor's path or 3x as many were preempted."""
    limit = _collision_distance()
    goal = ["target"]
    preempted: list[Trial] = []

    def trial() -> Trial | None:
        _clear(run, limit)
        keep_moving(run, goal)
        time.sleep(0.3)  # well into the motion
        mark = run.mark()
        t0 = time.time()
        run.call("people_world.lean", person=COLLIDER, reach=0.9)
        try:
            first = _first_of(
                run,
                t0,
                {
                    "people_detector/min_distance": lambda m: m.value < limit,
                    # speed and separation monitoring keeps more room than the Supervisor's
                    # collision distance while the arm moves: it may stop the arm first
                    "robot/status": lambda m: str(m.payload.get("reason", "")).startswith(
                        "protective stop"
                    ),
                },
                "a robot-person distance under the collision distance, or a protective stop",
            )
            result: Trial | None = None
            if first.key != "robot/status":
                timed = _stop_after(run, t0, first.message.stamp, "possible collision")
                timed.detail["distance"] = first.message.value
                # the same camera frame reaches the robot's separation check and the
                # Supervisor: the braking may be the protective stop's (the arm stops,
                # the interpolator sees it lag), not the halt's
                if not _protective_stop_before(run, t0, timed.end) and timed.detail["brake"] >= (
                    timed.latency
                ):
                    result = timed
            if result is None:  # the Supervisor's path was not what stopped it: lean again
                preempted.append(Trial(0.0, first.received, first.received, {"preempted": True}))
            run.wait_state("Stopped", 10.0, since=mark)
        finally:
            run.call("people_world.lean", person=COLLIDER, reach=0.0)
        return result

    run.call("people_world.place", person=COLLIDER, x=1.25, y=0.0, facing_deg=180.0)
    try:
        timed = _repeat(
            "collision reaction",
            trials,
            trial,
            progress,
            lambda: _clear(run, limit),
            give_up=lambda: len(preempted) >= 3 * trials,
        )
        return timed + preempted
    finally:
        run.call("people_world.leave", person=COLLIDER)
        _no_collision(run)


def _protective_stop_before(run: SeegRun, after: float, stamp: float) -> bool:
    """Whether the robot said a protective stop (speed and separation monitoring) stamped
    before `stamp`, among its statuses received since `after`."""
    return any(
        sample.message.stamp < stamp
        and str(sample.message.payload.get("reason", "")).startswith("protective stop")
        for sample in run.since(after, "robot/status")
    )


def _no_collision(run: SeegRun, timeout: float = 10.0) -> None:
    """Wait until the Supervisor no longer sees a possible collision (the next
    experiment must be able to move)."""
    deadline = time.monotonic() + timeout
    while run.call("supervisor.report").get("in_collision"):
        if time.monotonic() > deadline:
            raise BenchError(f"the Supervisor still sees a collision after {timeout:g} s")
        time.sleep(0.05)


def _collision_distance() -> float:
    from components.domain.procedure import load_procedure

    return load_procedure(seeg_file("procedures", "seeg.yaml")).collision_distance


def _clear(run: SeegRun, limit: float, timeout: float = 10.0) -> None:
    """Wait until the closest person is clearly beyond the collision distance."""
    run.call("people_world.lean", person=COLLIDER, reach=0.0)
    deadline = time.monotonic() + timeout
    while True:
        t = time.time()
        time.sleep(0.15)
        recent = run.since(t, "people_detector/min_distance")
        if recent and all(s.message.value > 1.5 * limit for s in recent):
            return
        if time.monotonic() > deadline:
            raise BenchError("the person did not step back from the robot")


def repeated_swaps(
    run: SeegRun, repetitions: int, swaps: int, progress: Any = None
) -> list[list[Trial]]:
    """Fig. 4.3: `repetitions` runs of `swaps` consecutive sensor swaps (the thesis:
    30 x 50), each swap measured as in `sensor_swap`."""
    out = []
    for r in range(repetitions):
        out.append(sensor_swap(run, swaps))
        if progress:
            progress(r + 1, repetitions)
    return out


def swap_during_motion(run: SeegRun, motions: int, progress: Any = None) -> dict[str, Any]:
    """Fig. 4.2: trackers swapped back and forth while the robot approaches at 7.5 cm/s.

    Returns the Sensor Manager's robot pose (master frame, best tracker) through
    the motions and, per swap, the jump of that pose: both sides of the swap are
    fitted with a straight line (the motion is linear) and extrapolated to the swap
    instant; the gap between them is the disagreement of the two trackers'
    calibrations, which is what the robot sees at a swap."""
    subscription = run.watch("sensor_manager/robot_pose", Pose)
    goal = ["target"]
    windows = []
    try:
        for m in range(motions):
            keep_moving(run, goal)
            t_start = time.time()
            for _ in range(2):
                time.sleep(0.5)
                run.call("certus.occlude", tool="cto")
                time.sleep(0.5)
                run.call("certus.occlude", tool="cto", hidden=False)
            time.sleep(0.6)
            windows.append((t_start, time.time()))
            if progress:
                progress(m + 1, motions)
    finally:
        run.unwatch(subscription)
        run.call("certus.occlude", tool="cto", hidden=False)
    trace, swaps = [], []
    for t_start, t_end in windows:
        poses = [
            (s.message.stamp, *s.message.position)
            for s in run.since(t_start, "sensor_manager/robot_pose")
            if s.message.stamp <= t_end
        ]
        trace += poses
        best = None
        for s in run.since(t_start, "sensor_manager/status"):
            if s.message.stamp > t_end:
                break
            now = s.message.payload.get("best")
            if best is not None and now is not None and now != best:
                jump = _jump(poses, s.message.stamp)
                if jump is not None:
                    swaps.append({"t": s.message.stamp, "from": best, "to": now, "jump_m": jump})
            best = now
    origin = windows[0][0] if windows else 0.0  # times relative to the first motion
    return {
        "trace": [(t - origin, *xyz) for t, *xyz in trace],
        "swaps": [{**swap, "t": swap["t"] - origin} for swap in swaps],
    }


def _jump(poses: list[tuple[float, ...]], at: float, span: float = 0.08) -> float | None:
    """The gap at `at` between straight lines fitted to the poses before and after."""
    before = np.array([p for p in poses if at - span <= p[0] < at - 0.001])
    after = np.array([p for p in poses if at - 0.001 <= p[0] <= at + span])
    if len(before) < 5 or len(after) < 5:
        return None
    ends = []
    for side in (before, after):
        t = side[:, 0] - at
        coeffs = np.polyfit(t, side[:, 1:4], 1)  # per axis: slope, intercept
        ends.append(coeffs[1])
    return float(np.linalg.norm(ends[1] - ends[0]))


WALKER = 2
"""The person of `people_world` who walks at the arm in the protective stop trials."""


def _stop_timing(run: SeegRun, since: float, timeout: float = 2.0) -> dict[str, Any] | None:
    """The robot interface's timing of a protective stop stamped at or after `since`
    (its report may lag the status that said the stop), None if none comes."""
    deadline = time.monotonic() + timeout
    while True:
        timing = run.call("robot.report").get("protective_stop") or {}
        if timing.get("stamp", 0.0) >= since and timing.get("envelopes_taken"):
            return timing
        if time.monotonic() > deadline:
            return None
        time.sleep(0.02)


def _published_before(run: SeegRun, since: float, taken: float) -> float | None:
    """When the people detector published the frame whose envelopes the robot's loop
    took at `taken`: the stamp of its `min_distance` of that frame (taken on the
    detector's clock just before it wrote the frame's envelopes, then the distance),
    the newest at or before `taken` (frames come every 33 ms, a frame's envelopes reach
    the loop within a cycle or two); None if the bench heard none."""
    stamps = [s.message.stamp for s in run.since(since - 0.1, "people_detector/min_distance")]
    before = [t for t in stamps if t <= taken]
    return max(before) if before else None


def _nobody_near(run: SeegRun, distance: float = 0.5, timeout: float = 10.0) -> None:
    """Wait until the people detector sees nobody within `distance` of the robot for
    0.3 s (a person who left may live on as a track for a few frames)."""
    deadline = time.monotonic() + timeout
    while True:
        t = time.time()
        time.sleep(0.3)
        recent = run.since(t, "people_detector/min_distance")
        if all(s.message.value > distance for s in recent):
            return
        if time.monotonic() > deadline:
            raise BenchError(f"someone stays within {distance} m of the robot")


def protective_stops(run: SeegRun, trials: int, progress: Any = None) -> list[Trial]:
    """A person appears against the moving arm (steps out of a blind spot: placed
    there in one frame, well inside the protective distance), and the robot interface's
    speed and separation monitoring stops it.
    L = the braking cycle's status stamp - the wall time the robot's loop took the
    envelopes that decided it, both stamped by the robot interface itself (the bench's
    own reception of the envelopes, in another process, may come after the stop on a
    loaded host); `detail`: the separation check's own time, its verdict -> the stop's
    first command, inside that cycle, `published`: from the detector's publishing of the
    frame those envelopes are of to the braking cycle (the bus, the wait for the loop's
    next cycle, the check; None if the bench heard no such frame), and `frame`: from the
    camera frame the envelopes come from (L plus their age when taken: the detection
    too). Then the person leaves and RELEASE resumes
    the motion. (The walk at 1.6 m/s is the `walk_in` scenario: there the stop comes as
    the envelope ages, by design, not on a frame's arrival.)"""
    statuses = run.watch("robot/status", EventMessage)
    goal = ["target"]

    def protective(message: Any) -> bool:
        return str(message.payload.get("reason", "")).startswith("protective stop")

    def trial() -> Trial:
        # the last trial's walker may live on as a track for some frames after leaving:
        # a RELEASE then resumes into a protective stop of the old trial's person
        _nobody_near(run)
        keep_moving(run, goal)
        time.sleep(0.3)
        before = run.call("robot.report")
        if before.get("latched"):  # stopped before anyone appeared: not this trial's stop
            raise BenchError(f"the robot stopped before the person appeared: {before['reason']}")
        t0 = time.time()
        run.call("people_world.place", person=WALKER, x=0.7, y=0.0, facing_deg=180.0)
        try:
            stop = _first(
                run,
                "robot/status",
                t0,
                lambda m: m.stamp >= t0 and protective(m),  # not a repeat of an older one
                "protective stop",
            )
            timing = _stop_timing(run, t0)
            if timing is None:
                raise BenchError(
                    f"a protective stop ({stop.message.payload.get('reason')}) the robot "
                    "interface reports no timing of since the person appeared"
                )
            cause, braked = timing["envelopes_taken"], stop.message.stamp
            published = _published_before(run, t0, cause)
            detail = {
                "check": timing["check_ms"] / 1e3,
                "command": timing["detected_to_command_ms"] / 1e3,
                # their camera frame -> the braking cycle: the age they had when taken
                # (stamped by the cameras' process, judged as the loop judges it) on top
                "frame": braked - cause + float(timing.get("envelopes_age_ms", 0.0)) / 1e3,
                "published": None if published is None else braked - published,
            }
            return Trial(braked - cause, cause, braked, detail)
        finally:
            run.call("people_world.leave", person=WALKER)

    def cleanup() -> None:
        run.call("people_world.leave", person=WALKER)
        _nobody_near(run)

    run.call("people_world.leave", person=WALKER)
    try:
        return _repeat("protective stop", trials, trial, progress, cleanup)
    finally:
        run.unwatch(statuses)
        _no_collision(run)
