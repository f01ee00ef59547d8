"""The Cartesian interpolator (thesis 3.6.1): straight-line TCP motion with live limits.

The TCP moves along the straight path from where it is to the goal: position by
linear interpolation, orientation by the geodesic (slerp), both driven by one
path parameter `s` in metres. `s` follows a trapezoidal velocity profile from
ruckig (online trajectory generation, infinite jerk = constant-acceleration
ramps): because ruckig replans from the current state every cycle, the maximum
velocity and acceleration may change while moving (the speed ramps to the new
limit at constant acceleration) and a new goal may arrive at any time.

* **STOP** brakes at `brake_acceleration` (velocity control to zero: the exact
  v^2/2a stop), then returns along the path to where the STOP was asserted and
  holds there.
* **A new goal while moving** brakes on the current path, then starts the new one
  (a path cannot turn a corner at speed).
* Rotation-dominated paths: `s` runs over max(translation, angle x
  `ROTATION_RADIUS` (0.1 m)), so a pure reorientation still has a finite duration.
* **Until the Supervisor sends limits**, the component moves at the procedure's
  slowest speed (no tracker said to be in use).
* **Steering** (`steer`): while moving to a goal or holding it, the goal may
  move (navigation: the tracked patient, the arm's model errors). The path is
  kept; the difference between the goal now and the goal the path was planned
  to is added to it as an offset that moves at most as fast as the speed left
  over by the path this cycle (the commanded TCP never exceeds the velocity
  limit; a step in the goal never gives a step in the command). While a
  correction is pending the path cruises at `1 - STEER_SHARE` of the limit, so
  the correction always has a share. A STOP freezes the offset. The correction is
  cut at `max_correction` from the planned goal (the component sets the
  procedure's `max_patient_motion + max_model_error`, 15 mm, and says the refusal):
  a steering source gone wrong cannot pull the arm farther than the patient may move
  plus what the arm's model may be off by.

Each cycle the Cartesian setpoint goes through differential IK (`ik.py`) to the
joint setpoint the robot interface receives. `InterpolatorCore` is the logic
(no I/O, time advances one `dt` per `step`); the component wraps it.
"""

from __future__ import annotations

import math
import threading
import time
from enum import Enum
from typing import Any

import numpy as np
import pinocchio as pin
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig

from components.domain.geometry import joint_gap, norm, pose_from_list
from components.domain.ik import DifferentialIK, _fwkernel
from components.robot.interface import tcp_message
from framework.component import Component, In, Out, operation
from framework.errors import FwError
from framework.messages import EventMessage, JointState, Pose, Scalar
from framework.ports import ReadStatus
from framework.properties import prop

IDENTITY = np.eye(4)
"""Copied, not made, for each pose of the cycle (np.eye costs more than the copy)."""


MAX_STEPS_PER_STATE = 40
"""At most this many 1 ms steps for one measured state (the arm's monitor mode reports
every 10 cycles; a longer gap is a stall, not time to catch up on)."""


class Phase(Enum):
    """What the interpolator is doing."""

    IDLE = "idle"
    MOVING = "moving"
    REACHED = "reached"
    STOPPING = "stopping"
    RETURNING = "returning"
    STOPPED = "stopped"


class LimitError(ValueError):
    """A velocity or acceleration limit that is not a positive finite number."""


def _check_limit(name: str, value: float, ceiling: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and 0.0 < value <= ceiling):
        raise LimitError(f"{name} must be in (0, {ceiling:g}], got {value!r}")
    return value


class InterpolatorCore:
    """Straight-line Cartesian motion with live limits, STOP and return (module docstring)."""

    MAX_VELOCITY = 0.25  # m/s: far above any surgical approach speed, a sanity ceiling
    MAX_ACCELERATION = 5.0  # m/s^2

    ROTATION_RADIUS = 0.1  # m: a rotation of 1 rad counts as 0.1 m of path
    STEER_SHARE = 0.5  # of the velocity limit kept for a pending correction
    STEER_DEADBAND = 1e-6  # m: a smaller pending correction does not slow the path
    STEER_RESOLUTION = 1e-12  # m: a smaller difference is float noise, not a correction

    def __init__(
        self,
        q0: np.ndarray,
        *,
        velocity: float,
        acceleration: float,
        brake_acceleration: float,
        ik: DifferentialIK | None = None,
    ):
        """Start at rest at the joints `q0`; the limits (m/s, m/s^2) are the procedure's,
        so every caller states them (no second set of defaults to drift from it)."""
        self.ik = ik or DifferentialIK()
        self.dt = self.ik.dt
        self.velocity = _check_limit("velocity", velocity, self.MAX_VELOCITY)
        self.acceleration = _check_limit("acceleration", acceleration, self.MAX_ACCELERATION)
        self.brake_acceleration = _check_limit(
            "brake_acceleration", brake_acceleration, self.MAX_ACCELERATION
        )
        self._otg = Ruckig(1, self.dt)
        self._in = InputParameter(1)
        self._out = OutputParameter(1)
        self.phase = Phase.IDLE
        self.goal: np.ndarray | None = None
        self._pending: np.ndarray | None = None
        self.stop_s = 0.0
        self.stop_pose: np.ndarray | None = None
        self._return_after_stop = True
        self.offset = np.zeros(6)  # applied correction: translation (m), rotation vector (rad)
        self._wanted = np.zeros(6)  # the correction the goal asks for
        self.ik_seconds = 0.0
        """s the IK of the steps since the component last set it to 0 took."""
        self._slowed = False
        self.cap = math.inf
        """The speed people nearby allow (m/s; speed and separation monitoring)."""
        self._held = False  # moving, but standing on a cap of 0 until it rises
        self.max_correction = math.inf
        """How far (m; a rotation counts at `ROTATION_RADIUS`) a steered goal may lie
        from the goal the motion was planned to: farther, the correction stops there."""
        self.sync(q0)

    # --- state -------------------------------------------------------------------------
    @property
    def s(self) -> float:
        """Distance travelled along the current path (m)."""
        return float(self._in.current_position[0])

    @property
    def speed(self) -> float:
        """Current path speed (m/s)."""
        return float(self._in.current_velocity[0])

    @property
    def moving(self) -> bool:
        """True while the commanded TCP is in motion (or about to be)."""
        return self.phase in (Phase.MOVING, Phase.STOPPING, Phase.RETURNING)

    def sync(self, q: np.ndarray) -> None:
        """Take the measured joints as the commanded ones, at rest (after brakes)."""
        self.q = np.asarray(q, dtype=float).copy()
        self._settled = False
        self.pose = self.ik.kin.tcp(self.q)
        self.offset = np.zeros(6)
        self._wanted = np.zeros(6)
        self._steered = False  # no goal was steered since: no correction to make
        self._start_path(self.pose, self.pose)
        self.phase = Phase.IDLE
        self._pending = None

    # --- commands ----------------------------------------------------------------------
    def go_to(self, goal: np.ndarray) -> None:
        """Move the TCP to `goal` (4x4, base frame) along a straight line."""
        goal = np.asarray(goal, dtype=float)
        if goal.shape != (4, 4) or not np.all(np.isfinite(goal)):
            raise ValueError("a goal is a finite 4x4 pose")
        if self.phase in (Phase.MOVING, Phase.STOPPING, Phase.RETURNING) and self.speed > 1e-9:
            self._pending = goal  # brake on this path first, then turn
            self._brake(Phase.STOPPING)
            self._return_after_stop = False
            return
        self._begin(goal)

    def steer(self, goal: np.ndarray) -> float:
        """Where the goal of the current motion is now (4x4, base frame): the command
        converges on it at the speed the path leaves over (module docstring). Ignored
        unless moving to a goal or holding one. Returns how far (m) the goal lies from
        the planned one beyond `max_correction` (0: within it); the correction is cut
        there, so a steering source gone wrong cannot pull the arm far."""
        goal = np.asarray(goal, dtype=float)
        if goal.shape != (4, 4) or not np.all(np.isfinite(goal)):
            raise ValueError("a goal is a finite 4x4 pose")
        if self.phase not in (Phase.MOVING, Phase.REACHED) or self.goal is None:
            return 0.0
        planned = self.goal
        wanted = np.concatenate(
            [goal[:3, 3] - planned[:3, 3], pin.log3(goal[:3, :3] @ planned[:3, :3].T)]
        )
        size = self._correction_size(wanted)
        beyond = size - self.max_correction
        if beyond > 0.0:
            wanted = wanted * (self.max_correction / size)
        self._wanted = wanted
        self._steered = True
        return max(0.0, beyond)

    def set_limits(self, velocity: float, acceleration: float | None = None) -> None:
        """New maximum path velocity (m/s) and acceleration (m/s^2), effective at once;
        both are checked before either is taken (a refused pair changes neither)."""
        velocity = _check_limit("velocity", velocity, self.MAX_VELOCITY)
        if acceleration is not None:
            acceleration = _check_limit("acceleration", acceleration, self.MAX_ACCELERATION)
        self.velocity = velocity
        self.acceleration = self.acceleration if acceleration is None else acceleration
        if self.phase is Phase.MOVING:
            self._pace()

    def set_cap(self, cap: float) -> None:
        """The speed people nearby allow (m/s; inf: no cap; NaN counts as 0), effective
        at once within the acceleration limit: under the Supervisor's limit it slows the
        motion, at 0 the motion stands (unbraked) until the cap rises again."""
        self.cap = max(0.0, cap) if not math.isnan(cap) else 0.0
        if self.phase is Phase.MOVING:
            self._pace()

    def _allowed(self) -> float:
        """The path's speed limit: the Supervisor's, or less where people are near."""
        return min(self.velocity, self.cap)

    def _pace(self) -> None:
        """Apply the allowed speed to the motion under way: to 0 at the acceleration
        limit and stand, or head on for the goal at that speed."""
        if self._allowed() <= 0.0:
            if not self._held:
                self._held = True
                self._in.control_interface = ControlInterface.Velocity
                self._in.target_velocity = [0.0]
                self._in.target_acceleration = [0.0]
                self._in.max_acceleration = [self.acceleration]
            return
        if self._held:  # a pending correction slows the path again in this very step
            self._held = False
            self._position_control(self.length, self._allowed(), self.acceleration)
        self._in.max_velocity = [self._cruise()]
        self._in.max_acceleration = [self.acceleration]

    def stop(self) -> None:
        """Brake at full deceleration, then return to where the STOP was asserted.
        A STOP while one is already being carried out keeps the first stop point."""
        if self._return_after_stop and self.phase in (
            Phase.STOPPING,
            Phase.RETURNING,
            Phase.STOPPED,
        ):
            return
        self._pending = None
        self.stop_s = self.s
        self.stop_pose = self.pose.copy()
        self._return_after_stop = True
        if self.speed > 1e-12 or self.phase is Phase.MOVING:
            self._brake(Phase.STOPPING)
        else:
            self.phase = Phase.STOPPED

    # --- the cycle ---------------------------------------------------------------------
    def step(self) -> np.ndarray:
        """Advance one cycle; the joint setpoint for the robot."""
        steering = self.phase in (Phase.MOVING, Phase.REACHED)
        if self.moving:
            before = self.s
            result = self._otg.update(self._in, self._out)
            self._out.pass_to_input(self._in)
            if result == Result.Finished:
                self._finished()
            elif result not in (Result.Working,):
                raise RuntimeError(f"ruckig failed: {result}")
            if steering and self._steered:  # the straight path's translation this cycle
                share = abs(self.s - before) / self.length  # a path moved on is >= 1 nm
                self._correct(share * self._delta_length)
            self.pose = self._path_pose(self.s)
        elif steering and self._steered and self._pending_correction():
            self._correct(0.0)
            self.pose = self._path_pose(self.s)
            self._settled = False
        elif self._settled:  # at rest and converged: the same setpoint, no IK to solve
            return self.q
        began = time.perf_counter()
        q = self.ik.step(self.q, self.pose)
        self.ik_seconds += time.perf_counter() - began
        self._settled = not self.moving and float(np.max(np.abs(q - self.q))) < 1e-10
        self.q = q
        return self.q

    # --- internals ---------------------------------------------------------------------
    def _cruise(self) -> float:
        """The path's velocity limit: less while a correction is pending."""
        allowed = self._allowed()
        return allowed * (1.0 - self.STEER_SHARE) if self._slowed else allowed

    def _correction_size(self, error: np.ndarray) -> float:
        return max(
            norm(error[:3]),
            norm(error[3:]) * self.ROTATION_RADIUS,
        )

    def _pending_correction(self) -> bool:
        return self._correction_size(self._wanted - self.offset) > self.STEER_RESOLUTION

    def _correct(self, path_step: float) -> None:
        """Move the offset toward the wanted correction with the speed left this cycle
        (in the compiled kernel where it was built: `steer_step`, the arithmetic of
        `_correct_reference`, which a spec holds it to)."""
        budget = max(0.0, self._allowed() * self.dt - path_step)
        if _fwkernel is None:
            size = self._correct_reference(budget)
        else:
            size = _fwkernel.steer_step(self._wanted, self.offset, budget, self.ROTATION_RADIUS)
        slowed = size > self.STEER_DEADBAND and self.phase is Phase.MOVING
        if slowed != self._slowed:
            self._slowed = slowed
            if self.phase is Phase.MOVING and not self._held:
                self._in.max_velocity = [self._cruise()]

    def _correct_reference(self, budget: float) -> float:
        """The offset's step toward the wanted correction within `budget` (m) in numpy;
        the correction's size before it."""
        error = self._wanted - self.offset
        size = self._correction_size(error)
        if size > 0.0:
            self.offset = self.offset + error * min(1.0, budget / size)
        return size

    def _offset_pose(self, path: np.ndarray) -> np.ndarray:
        if not self.offset.any():
            return path
        out = IDENTITY.copy()
        out[:3, 3] = path[:3, 3] + self.offset[:3]
        out[:3, :3] = pin.exp3(self.offset[3:]) @ path[:3, :3]
        return out

    def _start_path(self, start: np.ndarray, goal: np.ndarray) -> None:
        self._start = np.ascontiguousarray(start, dtype=float)
        self._delta_p = np.ascontiguousarray(goal[:3, 3] - start[:3, 3])
        self._delta_length = norm(self._delta_p)
        # in the start frame
        self._delta_r = np.ascontiguousarray(pin.log3(start[:3, :3].T @ goal[:3, :3]))
        self.length = max(
            norm(self._delta_p),
            norm(self._delta_r) * self.ROTATION_RADIUS,
        )
        self._in.current_position = [0.0]
        self._in.current_velocity = [0.0]
        self._in.current_acceleration = [0.0]

    def _begin(self, goal: np.ndarray) -> None:
        self.goal = goal.copy()
        self.offset = np.zeros(6)  # the new path starts where the command is, offset included
        self._wanted = np.zeros(6)
        self._steered = False
        self._slowed = False
        self._start_path(self.pose, goal)
        if self.length < 1e-9:
            self.phase = Phase.REACHED
            return
        self._held = False
        self._position_control(self.length, max(self._allowed(), 1e-9), self.acceleration)
        self.phase = Phase.MOVING
        if self._allowed() <= 0.0:
            self._pace()

    def _position_control(self, target: float, velocity: float, acceleration: float) -> None:
        self._in.control_interface = ControlInterface.Position
        self._in.target_position = [target]
        self._in.target_velocity = [0.0]
        self._in.target_acceleration = [0.0]
        self._in.max_velocity = [velocity]
        self._in.max_acceleration = [acceleration]
        self._in.max_jerk = [math.inf]
        self._slowed = False

    def _brake(self, phase: Phase) -> None:
        self._held = False
        self._in.control_interface = ControlInterface.Velocity
        self._in.target_velocity = [0.0]
        self._in.target_acceleration = [0.0]
        self._in.max_acceleration = [self.brake_acceleration]
        self._in.max_jerk = [math.inf]
        self.phase = phase

    def _finished(self) -> None:
        if self.phase is Phase.MOVING and self._held:
            return  # standing on a cap of 0, not at the goal
        if self.phase is Phase.MOVING:
            self.phase = Phase.REACHED
        elif self.phase is Phase.STOPPING:
            self._in.current_velocity = [0.0]
            self._in.current_acceleration = [0.0]
            if self._pending is not None:
                goal, self._pending = self._pending, None
                self.pose = self._offset_pose(self._pose_at(self.s))
                self._begin(goal)
            elif (
                self._return_after_stop
                and abs(self.s - self.stop_s) > 1e-9
                and self._allowed() > 0.0
            ):
                self._position_control(self.stop_s, self._allowed(), self.acceleration)
                self.phase = Phase.RETURNING
            else:
                self.phase = Phase.STOPPED
        elif self.phase is Phase.RETURNING:
            self.phase = Phase.STOPPED

    def _path_pose(self, s: float) -> np.ndarray:
        """The commanded pose at path position `s`, the steering offset added: in the
        compiled kernel where it was built, else in numpy (`_offset_pose(_pose_at(s))`,
        which a spec holds it to)."""
        if _fwkernel is None:
            return self._offset_pose(self._pose_at(s))
        out = np.empty((4, 4))
        u = 0.0 if self.length < 1e-12 else s / self.length
        _fwkernel.path_pose(self._start, self._delta_p, self._delta_r, u, self.offset, out)
        return out

    def _pose_at(self, s: float) -> np.ndarray:
        u = 0.0 if self.length < 1e-12 else s / self.length
        out = IDENTITY.copy()
        out[:3, 3] = self._start[:3, 3] + u * self._delta_p
        out[:3, :3] = self._start[:3, :3] @ pin.exp3(u * self._delta_r)
        return out


class CartesianInterpolator(Component):
    """Feeds `InterpolatorCore` at 1 kHz: goals by name, limits by port, joint setpoints out.

    It starts from the measured joints (it waits for the first `joints` sample) and
    writes a setpoint every cycle once started, so the robot's watchdog only fires if
    this component dies. `sync` re-reads the measured joints (after the brakes)."""

    procedure_file = prop(
        str, "", doc="procedure YAML (goals, accelerations)", required=True, file="procedure"
    )
    max_lag = prop(
        float, 0.05, unit="rad", min=0.001, max=1.0, doc="command-to-arm gap that stops a motion"
    )
    joints = In(JointState, doc="measured joints (from the robot interface)")
    limits = In(EventMessage, doc="new limits: payload {velocity, acceleration} (m/s, m/s^2)")
    halt = In(EventMessage, doc="STOP now (the Supervisor's reflex): any sample brakes")
    speed_cap = In(Scalar, doc="the TCP speed people nearby allow (m/s; inf: none), robot side")
    goals = In(
        EventMessage,
        doc="where the goals are now (the navigator): the motion steers toward its goal; "
        "a refusal stops it",
    )
    setpoint = Out(
        JointState, doc="joint setpoints for the robot interface, every cycle", stream=True
    )
    command = Out(
        Pose, doc="commanded TCP in the robot base frame (every cycle unless idle)", stream=True
    )
    status = Out(EventMessage, doc="phase (idle, moving, reached, stopping, returning, stopped)")

    def __init__(self, name: str):
        super().__init__(name)
        self.core: InterpolatorCore | None = None
        """The interpolation, made from the first joint state after `configure`."""

    def configure_hook(self) -> bool:
        from components.domain.procedure import load_procedure

        self.procedure = load_procedure(self.procedure_file)
        self.core = None
        self._goal_name = ""
        self._phase: Phase | None = None
        self._core_lock = threading.Lock()
        self.halted = ""  # the reason of the last halt
        self._goals: dict[str, np.ndarray] = {}  # the navigator's latest, base frame
        self._revisions: dict[str, int] = {}
        self._revision = 0  # of the goal the current motion heads for
        self._refused = ""
        return True

    def update_hook(self) -> None:
        status, measured = self.joints.read()
        if status is ReadStatus.NO_DATA:
            return
        with self._core_lock:
            if self.core is None:
                p = self.procedure
                self.core = InterpolatorCore(
                    np.asarray(measured.position),
                    velocity=p.slowest,  # until the Supervisor's limits come
                    acceleration=p.acceleration,
                    brake_acceleration=p.brake_acceleration,
                )
                n = p.navigation  # what the patient may move plus what the model may be off
                self.core.max_correction = n.max_patient_motion + n.max_model_error
            core = self.core
            status, limits = self.limits.read()
            if status is ReadStatus.NEW:
                self._take_limits(core, limits.payload)
            status, cap = self.speed_cap.read()
            if status is ReadStatus.NEW:
                core.set_cap(float(cap.value))
            status, halt = self.halt.read()
            if status is ReadStatus.NEW:
                core.stop()
                self._goal_name = ""
                self.halted = str(halt.payload.get("reason", ""))
            if not self.after_cycles:  # else taken after the cycle's command (below)
                self._take_goals(core)
            lag = joint_gap(core.q, measured.position)
            if core.moving and core.phase is not Phase.STOPPING and lag > self.max_lag:
                # the arm does not follow (brakes, contact): stop commanding a motion
                # nobody executes; the STOP returns the command to where the arm stands
                self.last_error = f"the arm lags the command by {np.degrees(lag):.1f} deg"
                core.sync(np.asarray(measured.position))
                core.stop()
            # one step per cycle of the arm: braked, its controller reports every few
            # cycles (monitor mode) and a motion nobody executes still lags at once
            began, core.ik_seconds = time.perf_counter(), 0.0
            for _ in range(min(max(1, measured.cycles), MAX_STEPS_PER_STATE)):
                q = core.step()
            self.stage("IK", core.ik_seconds)
            self.stage("interpolation", time.perf_counter() - began - core.ik_seconds)
            phase = core.phase
        stamp = time.time()
        self.setpoint.write(JointState(stamp, tuple(q.tolist())))
        moved = phase is not Phase.IDLE or self._phase is not phase  # not 1 kHz of one pose
        if moved and self.command.wanted():
            self.command.write(tcp_message(core.pose, stamp))
        if phase is not self._phase:
            self._phase = phase
            self.status.write(EventMessage(stamp, phase.value, self.name, self.report()))

    def after_cycle_hook(self) -> None:
        """In a paced loop, after the cycle's command went out: the navigator's goals.
        Steering at the tracker's rate needs no answer within the cycle they came in
        (taken there, the next cycle steers), and taking one (decoding its JSON, the
        rotation's logarithm) cost 150-250 us in the deployment: the largest share of
        the cycles they came in."""
        with self._core_lock:
            if self.core is not None:
                self._take_goals(self.core)

    def _take_goals(self, core: InterpolatorCore) -> None:
        status, goals = self.goals.read()
        if status is ReadStatus.NEW:
            self._navigate(core, goals.payload)

    def _navigate(self, core: InterpolatorCore, payload: Any) -> None:
        """The navigator's goals: steer the motion toward its goal where it is now; a
        refusal (the patient moved too far or too fast) stops it at once, as a halt."""
        try:
            goals = {str(k): pose_from_list(v) for k, v in payload["goals"].items()}
            revisions = {str(k): int(v) for k, v in (payload.get("revisions") or {}).items()}
            refused = str(payload.get("refused") or "")
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            self.refuse("goals", f"malformed goals: {exc!r}")
            return
        self._goals, self._revisions = goals, revisions
        if refused and not self._refused:
            core.stop()
            self._goal_name = ""
            self.halted = refused
        self._refused = refused
        goal = goals.get(self._goal_name)
        same = revisions.get(self._goal_name, 0) == self._revision  # not defined anew
        if goal is not None and same and not refused:
            beyond = core.steer(goal)
            if beyond > 0.0:
                self.refuse(
                    "goals",
                    f"the navigator's {self._goal_name} is "
                    f"{(beyond + core.max_correction) * 1e3:.1f} mm from where the motion "
                    f"was planned to go; corrected {core.max_correction * 1e3:.0f} mm at most "
                    "(the patient's motion plus the arm's model error): is the navigator wrong?",
                )

    def _take_limits(self, core: InterpolatorCore, payload: Any) -> None:
        """Apply limits from the port unless they exceed what the procedure allows (its
        fastest tracker speed, its acceleration): a producer gone wrong cannot speed the
        arm up; the refusal is said (flight recording) and the previous limits stay."""
        try:
            velocity = float(payload["velocity"])
            acceleration = payload.get("acceleration")
            acceleration = None if acceleration is None else float(acceleration)
            self._within_procedure(velocity, acceleration)
            core.set_limits(velocity, acceleration)
        except (KeyError, TypeError, ValueError, AttributeError, LimitError) as exc:
            reason = str(exc) if isinstance(exc, LimitError) else f"malformed limits: {exc!r}"
            self.last_error = f"limits refused: {reason}"
            self.refuse("limits", reason)

    def _within_procedure(self, velocity: float, acceleration: float | None) -> None:
        """`LimitError` for limits beyond the procedure's fastest tracker speed or its
        acceleration (the core's own ceilings are sanity bounds for any procedure)."""
        p = self.procedure
        ceiling = max(s.fast for s in p.speeds.values())
        if not velocity <= ceiling:
            raise LimitError(f"velocity {velocity:g} m/s is over the procedure's {ceiling:g}")
        if acceleration is not None and not acceleration <= p.acceleration:
            raise LimitError(
                f"acceleration {acceleration:g} m/s^2 is over the procedure's {p.acceleration:g}"
            )

    def _core(self) -> InterpolatorCore:
        if self.core is None:
            raise FwError("no joint state received yet: is the robot interface running?")
        return self.core

    @operation
    def go_to(self, goal: str) -> dict[str, Any]:
        """Move to a named goal of the procedure (target, home); the same goal while
        moving there is a no-op, so a tracker swap does not interrupt the motion."""
        if goal not in self.procedure.goals:
            raise FwError(f"unknown goal {goal!r}: one of {', '.join(self.procedure.goals)}")
        with self._core_lock:
            core = self._core()
            if self._refused:
                raise FwError(f"navigation refuses: {self._refused}")
            pose = self._goals.get(goal)
            if pose is None and self.procedure.frame(goal) == "patient":
                raise FwError(
                    f"goal {goal!r} is on the patient and no navigator said where the "
                    "patient is: is the navigator running and connected to `goals`?"
                )
            if not (goal == self._goal_name and core.phase in (Phase.MOVING, Phase.REACHED)):
                core.go_to(self.procedure.goals[goal] if pose is None else pose)
                self._revision = self._revisions.get(goal, 0)
            self._goal_name = goal
            return self.report()

    @operation
    def go_to_pose(self, position: list[float], rpy_deg: list[float]) -> dict[str, Any]:
        """Move to a pose given in the robot base frame (m, deg)."""
        from components.domain.procedure import pose_from

        pose = pose_from(position, rpy_deg)
        with self._core_lock:
            self._core().go_to(pose)
            self._goal_name = "pose"
            return self.report()

    @operation
    def set_limits(self, velocity: float, acceleration: float | None = None) -> dict[str, Any]:
        """Maximum path velocity (m/s) and acceleration (m/s^2), effective at once."""
        self._within_procedure(float(velocity), acceleration)
        with self._core_lock:
            self._core().set_limits(velocity, acceleration)
            return self.report()

    @operation
    def stop_motion(self) -> dict[str, Any]:
        """Brake at full deceleration, then return to where the STOP was asserted."""
        with self._core_lock:
            self._core().stop()
            self._goal_name = ""
            return self.report()

    @operation
    def sync(self, force: bool = False) -> dict[str, Any]:
        """Restart from the measured joints, at rest. While moving this does nothing (a
        tracker swap re-applies the goto configuration: it must not cut the motion
        short) unless `force`: after a stop the robot side imposed, whatever motion the
        interpolator was still playing is void, and its next setpoint must be where the
        arm stands, or the arm's setpoint guard brakes again at once. That setpoint goes
        out now, not at the next update: the release that follows may reach the arm
        first, and the robot interface must then find this one, not the void motion's."""
        with self._core_lock:
            core = self._core()
            if force or not core.moving:
                status, measured = self.joints.read()
                if status is not ReadStatus.NO_DATA:
                    core.sync(np.asarray(measured.position))
                    self._goal_name = ""
                    self.setpoint.write(JointState(time.time(), tuple(core.q.tolist())))
            return self.report()

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """Phase, goal, path progress and speed, limits."""
        core = self.core
        if core is None:
            return {"phase": "waiting for joints"}
        return {
            "phase": core.phase.value,
            "goal": self._goal_name,
            "s": round(core.s, 6),
            "length": round(core.length, 6),
            "speed": round(core.speed, 6),
            "velocity": core.velocity,
            "acceleration": core.acceleration,
            "halted": self.halted,
            "tcp": [round(v, 6) for v in core.pose[:3, 3].tolist()],
        }
