"""The Supervisor (thesis 3.5.3): turns measurements into the procedure's events.

It watches the Sensor Manager, the people detector, the robot and the
interpolator, and raises the events the SEEG chart reacts to:

* `e_CRITICAL_AREA` / `e_SAFE_AREA`: the TCP entered or left the sphere of
  `critical_radius` around the target (eq. 3.11), or more than `max_near`
  confirmed people stand near the table;
* `e_STOP {reason}`: a possible collision (robot-envelope distance under
  `collision_distance`), on the rising edge and again whenever motion starts while
  it persists;
* `e_TOK {tracker}` / `e_NOTRACKER {why}`: answers to `report_best_tracker`;
* `e_TFAULT {tracker, failed, fault, detail, numbers}`: the tracker in use (`failed`)
  is no longer the best one (its fault, with the Sensor Manager's words and numbers:
  the poses compared, their times, the tolerance; or a better one recovered); `tracker` is the one to use now (as
  in `e_TOK`), so the chart swaps without asking; `e_NOTRACKER` if none is left. The
  tracker in use is the one whose samples steer the navigator (its `navigation`
  news), not a name handed back by the chart; until the tracker `e_TFAULT` named
  steers, it is watched all the same (a fault of it in between is reported at once,
  not at the Sensor Manager's next status), while the limits stay the slowest;
* `e_PATIENT_MOVED {reason}`: the navigator refuses the patient's motion (moved too
  far or too fast from where it was registered);
* `e_TARGET {goal}`: the interpolator reached the goal and the measured TCP is
  within `target_tolerance` of it;
* `e_STOP {reason}` also when the robot side latched a safety stop by itself (its
  safety monitor tripped, the arm's controller braked): the chart must know the robot
  no longer follows.

Every `e_STOP`, `e_NOTRACKER` and `e_PATIENT_MOVED` is preceded by a message on `halt`, wired straight
to the interpolator: braking starts one hop after the verdict instead of after the
chart and the Configurator (three more hops). The chart still enters its stop state
and applies the stop configuration; the reflex only starts the braking earlier.

`change_movement_parameters(speed)` sends the interpolator the limits of the
tracker in use for the area ("fast" or "slow"), from the procedure file, and again
by itself whenever another tracker starts steering (a swap needs no re-application).
Goals on the patient are where the navigator says they are now (the critical area
and the arrival follow the head).
`SupervisorCore` is the logic (plain values in, events out); the component feeds it.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from components.domain.procedure import Procedure, load_procedure
from framework.component import Component, In, Out, operation
from framework.errors import FwError
from framework.messages import EventMessage, Pose, Scalar
from framework.ports import ReadStatus
from framework.properties import prop

Event = tuple[str, dict[str, Any]]
HALTING = ("e_STOP", "e_NOTRACKER", "e_PATIENT_MOVED")
"""Events that also halt the interpolator directly (the chart's stop follows)."""


def untracked(health: dict[str, Any]) -> str:
    """Why no tracker can be used, from the Sensor Manager's health of each: what the
    operator reads with "no tracker" (and the flight recording keeps)."""
    causes = []
    for name, verdict in sorted(health.items()):
        verdict = verdict or {}
        if verdict.get("ok"):
            causes.append(f"{name}: healthy, not trusted again yet")
            continue
        detail = verdict.get("detail")
        cause = verdict.get("cause") or "unknown"
        causes.append(f"{name}: {cause}, {detail}" if detail else f"{name}: {cause}")
    return "; ".join(causes) or "the Sensor Manager has not said"


@dataclass
class SupervisorCore:
    """The Supervisor's decisions (see the module docstring)."""

    procedure: Procedure
    in_use: str | None = None
    best: str | None = None
    health: dict[str, Any] = field(default_factory=dict)
    area: str | None = None
    in_collision: bool = False
    phase: str = ""
    goal: str = ""
    tcp: tuple[float, float, float] | None = None
    users_near: int = 0
    min_distance: float = math.inf
    arriving: str = ""  # the goal the interpolator reached, until the TCP is there too
    sensor_limits: dict[str, dict[str, float]] = field(default_factory=dict)
    robot_fault: str = ""
    steering: str | None = None  # whose samples steer the navigator (None: they stopped)
    swapping_to: str | None = None  # named by the last e_TFAULT or e_TOK, until it steers
    speed: str = ""  # the speed the chart last asked for (fast, slow)
    goal_positions: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    patient_refused: str = ""

    # --- inputs ----------------------------------------------------------------------
    def tracking(
        self, best: str | None, health: dict[str, Any], limits: dict[str, float] | None = None
    ) -> list[Event]:
        """A Sensor Manager decision (best sensor, every sensor's health, the best's limits)."""
        self.best, self.health = best, health
        if best is not None and limits is not None:
            self.sensor_limits[best] = dict(limits)
        # A tracker the chart is swapping to is watched before its first sample steers:
        # one that fails in between is not lost until the next status (0.5 s later).
        current = self.in_use or self.swapping_to
        if current is None or best == current:
            return []
        self.in_use, self.swapping_to = None, best
        if best is None:
            return [("e_NOTRACKER", {"why": untracked(health)})]
        verdict = health.get(current) or {}
        cause = verdict.get("cause") or f"{best} is better"
        numbers = verdict.get("numbers")
        return [
            (
                "e_TFAULT",
                {
                    "tracker": best,
                    "failed": current,
                    "fault": cause,
                    "detail": str(verdict.get("detail") or ""),
                    "numbers": numbers if isinstance(numbers, dict) else {},
                },
            )
        ]

    def observe(
        self,
        tcp: tuple[float, float, float] | None = None,
        users_near: int | None = None,
        min_distance: float | None = None,
    ) -> list[Event]:
        """New robot TCP (base frame), people count near the table, robot-person distance."""
        if tcp is not None:
            self.tcp = tcp
        if users_near is not None:
            self.users_near = users_near
        if min_distance is not None:
            self.min_distance = min_distance
        events = self._area() + self._arrival()
        collision = self.min_distance < self.procedure.collision_distance
        if collision and not self.in_collision:
            events.append(("e_STOP", {"reason": self._collision_reason()}))
        self.in_collision = collision
        return events

    def motion(self, phase: str, goal: str) -> list[Event]:
        """The interpolator changed phase."""
        started = phase == "moving" and self.phase != "moving"
        self.phase, self.goal = phase, goal
        if started and self.in_collision:
            return [("e_STOP", {"reason": self._collision_reason()})]
        self.arriving = goal if phase == "reached" and goal in self.procedure.goals else ""
        return self._arrival()

    def navigation(
        self,
        tracker: str | None,
        goals: dict[str, tuple[float, float, float]],
        refused: str = "",
    ) -> tuple[list[Event], bool]:
        """The navigator's news: the tracker whose samples steer (None: they stopped),
        where the goals are now (base frame), its refusal of the patient's motion. The
        events, and whether the limits must be sent again (another tracker steers, at its
        own speeds)."""
        self.goal_positions = dict(goals)
        resend = False
        if tracker != self.steering or (tracker is not None and tracker == self.swapping_to):
            self.steering = tracker
            if tracker is not None:
                self.in_use, self.swapping_to = tracker, None
                resend = bool(self.speed)
        events = []
        if refused and not self.patient_refused:
            events.append(("e_PATIENT_MOVED", {"reason": refused}))
        self.patient_refused = refused
        return events + self._area() + self._arrival(), resend

    def robot(self, braked: bool, fault: bool, reason: str) -> list[Event]:
        """The robot interface's status: a safety stop the robot side latched by itself
        (monitor trip, the arm's own brakes) stops the task, once per fault, whether the
        brakes are on yet or the protective stop is still decelerating."""
        if not fault:
            self.robot_fault = ""
            return []
        if reason == self.robot_fault:
            return []
        self.robot_fault = reason
        return [("e_STOP", {"reason": f"robot braked: {reason}"})]

    # --- answers and commands --------------------------------------------------------
    def report_best_tracker(self) -> Event:
        """e_TOK with the best tracker, or e_NOTRACKER. The tracker e_TOK names is the
        one the chart connects: it is watched from now on, before its first sample
        steers (one that fails in between is no tracker, not silence)."""
        if self.best is None:
            return ("e_NOTRACKER", {"why": untracked(self.health)})
        if self.in_use != self.best:
            self.swapping_to = self.best
        return ("e_TOK", {"tracker": self.best})

    def limits(self, speed: str) -> dict[str, float]:
        """Interpolator limits for the tracker in use at `speed` (fast, slow): the
        procedure's speed, capped by what the Sensor Manager allows for that tracker."""
        if speed not in ("fast", "slow"):
            raise FwError(f"speed is 'fast' or 'slow', not {speed!r}")
        self.speed = speed
        speeds = self.procedure.speeds.get(self.in_use or "")
        if speeds is None:  # no tracker in use: the slowest speed of any tracker
            velocity = self.procedure.slowest
        else:
            velocity = speeds.fast if speed == "fast" else speeds.slow
        acceleration = self.procedure.acceleration
        caps = self.sensor_limits.get(self.in_use or "", {})
        velocity = min(velocity, caps.get("max_velocity", velocity))
        acceleration = min(acceleration, caps.get("max_acceleration", acceleration))
        return {"velocity": velocity, "acceleration": acceleration}

    # --- internals -------------------------------------------------------------------
    def goal_position(self, name: str) -> tuple[float, float, float] | None:
        """Where a goal is now in the base frame (None: on the patient, and the navigator
        has not said where the patient is)."""
        if name in self.goal_positions:
            return self.goal_positions[name]
        if self.procedure.frame(name) == "patient":
            return None
        return tuple(float(v) for v in self.procedure.goals[name][:3, 3])  # type: ignore[return-value]

    def _arrival(self) -> list[Event]:
        if not self.arriving or self.tcp is None:
            return []
        goal = self.goal_position(self.arriving)
        if goal is None or math.dist(self.tcp, goal) > self.procedure.target_tolerance:
            return []
        goal_name, self.arriving = self.arriving, ""
        return [("e_TARGET", {"goal": goal_name})]

    def _area(self) -> list[Event]:
        target = self.goal_position("target")
        if self.tcp is None or target is None:
            return []
        distance = math.dist(self.tcp, target)
        crowded = self.users_near > self.procedure.max_near
        critical = distance < self.procedure.critical_radius or crowded
        area = "critical" if critical else "safe"
        if area == self.area:
            return []
        self.area = area
        if not critical:
            return [("e_SAFE_AREA", {"distance": round(distance, 4)})]
        why = "crowded" if crowded else "near the target"
        return [
            (
                "e_CRITICAL_AREA",
                {"distance": round(distance, 4), "users_near": self.users_near, "why": why},
            )
        ]

    def _collision_reason(self) -> str:
        return (
            f"possible collision: robot {self.min_distance * 100:.1f} cm from a person "
            f"(limit {self.procedure.collision_distance * 100:.0f} cm)"
        )


class Supervisor(Component):
    """Feeds `SupervisorCore` from its inputs and publishes its events on `events`."""

    emits = (
        "e_CRITICAL_AREA",
        "e_SAFE_AREA",
        "e_STOP",
        "e_TOK",
        "e_NOTRACKER",
        "e_TFAULT",
        "e_TARGET",
        "e_PATIENT_MOVED",
    )
    procedure_file = prop(
        str, "", doc="procedure YAML (target, areas, speeds)", required=True, file="procedure"
    )
    tracking = In(EventMessage, doc="Sensor Manager decisions (best tracker, health)")
    tcp = In(Pose, doc="robot TCP in the base frame")
    users_near = In(Scalar, doc="confirmed people near the table")
    min_distance = In(Scalar, doc="closest robot-person distance (m)")
    motion = In(EventMessage, doc="interpolator phase changes")
    navigation = In(
        EventMessage,
        doc="the navigator's goals (base frame), the tracker that steers, its refusal",
    )
    robot = In(EventMessage, doc="robot interface status (brakes, reason, fault)")
    events = Out(EventMessage, doc="events for the Coordinator (fw/events)")
    limits = Out(EventMessage, doc="interpolator limits {velocity, acceleration}")
    halt = Out(
        EventMessage,
        doc="the safety reflex: written with every e_STOP and e_NOTRACKER, before the event, "
        "so the interpolator brakes without waiting for the chart {reason}",
    )

    def configure_hook(self) -> bool:
        self.core = SupervisorCore(load_procedure(self.procedure_file))
        self._core_lock = threading.Lock()
        return True

    def idle_hook(self) -> None:
        """No event for the activity's `idle` period: the TCP (read, not waited for: it
        comes at 1 kHz) still moves the area and arrival checks along."""
        self.update_hook()

    def update_hook(self) -> None:
        events: list[Event] = []
        with self._core_lock:
            core = self.core
            status, decision = self.tracking.read()
            if status is ReadStatus.NEW:
                best, health, limits = decision.payload.get("best"), {}, None
                problem = _decision_problem(decision.payload)
                if problem:  # no trustworthy tracker: as if none were left
                    self.refuse("tracking", f"{problem}: taken as no tracker")
                    best = None
                else:
                    health = decision.payload.get("health", {})
                    limits = decision.payload.get("limits")
                events += core.tracking(best, health, limits)
            tcp = self._new(self.tcp)
            if tcp is not None and not all(map(math.isfinite, tcp.position)):
                self.refuse("tcp", f"a TCP position that is not finite: {tcp.position}")
                tcp = None
            near = self._new(self.users_near)
            if near is not None and not (math.isfinite(near.value) and near.value >= 0):
                self.refuse("users_near", f"a people count of {near.value}")
                near = None
            distance = self._new(self.min_distance)
            measured = distance.value if distance is not None else None
            if measured is not None and math.isnan(measured):  # unknown: assume contact
                self.refuse("min_distance", "a distance that is not a number: taken as contact")
                measured = 0.0
            if tcp is not None or near is not None or measured is not None:
                events += core.observe(
                    tcp.position if tcp is not None else None,
                    int(near.value) if near is not None else None,
                    measured,
                )
            while True:
                status, change = self.motion.read()
                if status is not ReadStatus.NEW:
                    break
                events += core.motion(change.name, str(change.payload.get("goal", "")))
            news = self._new(self.navigation)
            if news is not None:
                navigated = self._navigation(news.payload)
                if navigated is not None:
                    more, resend = core.navigation(*navigated)
                    events += more
                    if resend:
                        self._send_limits(core.limits(core.speed))
            robot = self._new(self.robot)
            if robot is not None:
                p = robot.payload
                events += core.robot(
                    bool(p.get("braked")), bool(p.get("fault")), str(p.get("reason", ""))
                )
        for name, payload in events:
            if name in HALTING:
                reason = payload.get("reason", "no tracker sees the robot")
                self.halt.write(EventMessage(time.time(), "halt", self.name, {"reason": reason}))
            self._emit(name, payload)

    def _navigation(
        self, payload: Any
    ) -> tuple[str | None, dict[str, tuple[float, float, float]], str] | None:
        """The navigator's message as (tracker, goal positions, refusal), or None (and
        a refusal said) if it cannot be believed."""
        try:
            tracker = payload.get("tracker")
            if tracker is not None and not (isinstance(tracker, str) and 0 < len(tracker) <= 64):
                raise ValueError(f"tracker {str(tracker)[:40]!r} is not a name")
            goals = {}
            for name, pose in payload["goals"].items():
                position = tuple(float(v) for v in pose[:3])
                if len(position) != 3 or not all(map(math.isfinite, position)):
                    raise ValueError(f"goal {str(name)[:40]!r} is not a finite position")
                goals[str(name)] = position
            return tracker, goals, str(payload.get("refused") or "")
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            self.refuse("navigation", f"navigator news that cannot be believed: {exc}")
            return None

    def _send_limits(self, limits: dict[str, float]) -> None:
        self.limits.write(EventMessage(time.time(), "limits", self.name, limits))

    @staticmethod
    def _new(port: Any) -> Any:
        status, sample = port.read()
        return sample if status is ReadStatus.NEW else None

    def _emit(self, name: str, payload: dict[str, Any]) -> None:
        self.events.write(EventMessage(time.time(), name, self.name, payload))

    @operation
    def report_best_tracker(self) -> str:
        """Raise e_TOK (with the best tracker) or e_NOTRACKER."""
        with self._core_lock:
            name, payload = self.core.report_best_tracker()
        self._emit(name, payload)
        return name

    @operation
    def change_movement_parameters(self, speed: str) -> dict[str, float]:
        """Send the interpolator the limits for the tracker in use at `speed` (fast, slow)."""
        with self._core_lock:
            limits = self.core.limits(speed)
        self._send_limits(limits)
        return limits

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """Tracker in use (and the one steering now), best tracker, area, people,
        distance, motion, where the target is now, the navigator's refusal."""
        core = self.core
        target = core.goal_position("target")
        return {
            "tracker": core.in_use,
            "steering": core.steering,
            "patient_refused": core.patient_refused,
            "best": core.best,
            "area": core.area,
            "users_near": core.users_near,
            "min_distance": None if math.isinf(core.min_distance) else core.min_distance,
            "in_collision": core.in_collision,
            "phase": core.phase,
            "goal": core.goal,
            "target": None if target is None else [round(float(v), 4) for v in target],
            "critical_radius": core.procedure.critical_radius,
        }


def _decision_problem(payload: dict[str, Any]) -> str:
    """Why a Sensor Manager decision cannot be believed ("" if it can): a best sensor
    that is not a name, health that is not a table, limits that are not positive
    finite numbers."""
    best = payload.get("best")
    if best is not None and not (isinstance(best, str) and 0 < len(best) <= 64):
        return f"best sensor {str(best)[:40]!r} is not a sensor name"
    if not isinstance(payload.get("health", {}), dict):
        return "health is not a table of sensors"
    limits = payload.get("limits")
    if limits is None:
        return ""
    if not isinstance(limits, dict):
        return "limits are not a table"
    for name, value in limits.items():
        if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            return f"limit {str(name)[:40]!r} = {str(value)[:40]} is not a positive number"
    return ""
