"""Speed and separation monitoring (SSM) in the spirit of ISO/TS 15066, for the robot's
own control loop.

The people detector publishes everyone's envelope (capsules around the limbs, their
3-sigma position noise already in the radii) with the camera frame's stamp. Every
cycle the robot side measures the separation S between those capsules and its own
link capsules at the current joints, and the speed v_r of its fastest link point (a
point on a rigid link moves no faster than the faster end of its segment). It must
keep, while it moves, the protective separation distance

    S_p(v_r) = v_h (T_r + T_s) + v_r T_r + S_s + C + Z_d + Z_r

* v_h: the person's speed toward the robot, 1.6 m/s (ISO 13855's walking speed), for
  every capsule, hands included;
* T_r: the reaction time: the envelope's age (camera frame to now, measured on every
  sample, so a late or stalled detector is paid for in distance) plus the robot's own
  `reaction` (the cycle that decides and the cycle that engages the brakes);
* T_s, S_s: the time and distance to stand still from v_r: `engage` (the brakes'
  engagement) then a deceleration of at least `deceleration`;
* C: the intrusion distance, 0 here: the cameras track the arms and hands, which are
  capsules of the envelope (ISO 13855's reach allowance is for sensors that do not);
* Z_d: what the envelope may be off beyond its noise margin (the cameras' registration
  to the robot base); Z_r: the robot's position uncertainty (its model errors).

Two answers per cycle: `stop` when S < S_p(v_r) (the robot side brakes in that very
cycle), and a speed `cap` for the motion, which slows the arm down in a band of
`slow_band` beyond S_p(0) and is 0 (stand still, unbraked) at S_p(0): as a person
approaches, the arm slows and stands before the protective stop is needed; the stop
is the backstop for a person faster than the slowing.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from components.domain.distance import least_capsule_distance
from components.domain.kernel import _fwkernel


@dataclass(frozen=True)
class SsmParams:
    """The terms of the protective separation distance (module docstring), SI units."""

    person_speed: float = 1.6
    """v_h (m/s), ISO 13855's walking speed."""
    reaction: float = 0.002
    """The robot's part of T_r (s): the cycle that decides and the cycle that brakes."""
    engage: float = 0.010
    """Time from the brake request until the arm decelerates (s)."""
    deceleration: float = 2.0
    """The least deceleration of a protective stop (m/s^2): the procedure's STOP."""
    intrusion: float = 0.0
    """C (m): 0, the envelope holds the tracked arms and hands."""
    detection_uncertainty: float = 0.02
    """Z_d (m): the cameras' registration to the robot base, beyond the noise margin."""
    robot_uncertainty: float = 0.005
    """Z_r (m): the arm's model errors (docs/seeg.md: a few millimetres)."""
    slow_band: float = 0.4
    """Beyond S_p(0) by this much (m) the cap is the full speed; it falls linearly to 0."""

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not value >= 0.0:  # NaN too
                raise ValueError(f"SSM term {name} must be >= 0, not {value}")
        if not self.deceleration > 0.0:
            raise ValueError(f"SSM term deceleration must be > 0, not {self.deceleration}")

    def stopping_time(self, v_r: float) -> float:
        """T_s (s) from speed v_r."""
        return self.engage + v_r / self.deceleration

    def stopping_distance(self, v_r: float) -> float:
        """S_s (m) from speed v_r."""
        return v_r * self.engage + v_r * v_r / (2.0 * self.deceleration)

    def protective_distance(self, v_r: float, age: float) -> float:
        """S_p (m) for a robot at speed v_r (m/s) and an envelope `age` seconds old."""
        t_r = max(age, 0.0) + self.reaction
        return (
            self.person_speed * (t_r + self.stopping_time(v_r))
            + v_r * t_r
            + self.stopping_distance(v_r)
            + self.intrusion
            + self.detection_uncertainty
            + self.robot_uncertainty
        )

    def allowed_speed(self, separation: float, age: float) -> float:
        """The largest v_r with S_p(v_r) <= separation (0 if even standing is too close):
        S_p is a quadratic in v_r with positive coefficients."""
        a = 1.0 / (2.0 * self.deceleration)
        t_r = max(age, 0.0) + self.reaction
        b = self.person_speed / self.deceleration + t_r + self.engage
        c = self.protective_distance(0.0, age) - separation
        if c >= 0.0:
            return 0.0
        return (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)


class Verdict(NamedTuple):
    """One cycle's answer: the separation (m; inf without anyone), the robot's fastest
    link point (m/s), the protective distance at that speed, the speed cap for the
    motion (m/s; inf: none), whether to stop now, and the tool's speed over the same
    window (the end of the last capsule: what the interpolator paces). A named tuple:
    made once per check of the 1 kHz loop, where a frozen dataclass costs microseconds."""

    separation: float
    robot_speed: float
    protective: float
    cap: float
    stop: bool
    tcp_speed: float = 0.0

    @property
    def tcp_cap(self) -> float:
        """The cap as a TCP speed: the link point it is for may move faster than the
        TCP (an elbow swinging), so it shrinks by their ratio."""
        if not math.isfinite(self.cap) or self.tcp_speed < 1e-4:
            return self.cap
        return self.cap * min(1.0, self.tcp_speed / self.robot_speed)


CLEAR = Verdict(math.inf, 0.0, 0.0, math.inf, False)


FASTEST_LINK = 0.25
"""m/s: a bound on any link point's speed in a surgical approach (the interpolator's
sanity ceiling), for how long a far person may go unchecked."""
SPEED_WINDOW = 0.01
"""s: the robot's speed is its link points' displacement over this long."""
MAX_QUIET = 100
"""Cycles a far person may go unchecked, at most (new envelopes are checked at once)."""


def link_speed(
    before: tuple[np.ndarray, np.ndarray], after: tuple[np.ndarray, np.ndarray], dt: float
) -> float:
    """The fastest capsule end (m/s) between two sets of link capsule ends `dt` apart:
    a point of a rigid link moves no faster than its faster end."""
    return _fastest(np.concatenate(after) - np.concatenate(before), dt)


_NOBODY = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))


def _f64(values: np.ndarray) -> np.ndarray:
    """`values` as the kernel takes them: C-contiguous float64 (no copy if they are)."""
    return np.ascontiguousarray(values, dtype=float)


def _fastest(moved: np.ndarray, dt: float) -> float:
    """The largest of the (n, 3) displacements `moved`, as a speed over `dt`."""
    return math.sqrt(float(np.einsum("ij,ij->i", moved, moved).max())) / dt


class SeparationMonitor:
    """Separation, robot speed and S_p cycle by cycle (module docstring). Stateful only
    in the link capsules of the last `SPEED_WINDOW`, for the robot's speed.

    Where the compiled kernel was built, `check` and `robot_speed` are one call of it
    each (`_fwkernel.ssm_check`, `ssm_speed`: the robot's loop checks every new envelope,
    30 times a second, and code run that seldom meets cold caches, where each of the
    ~40 numpy and Python steps costs several times its warm figure); `compiled=False`
    runs the Python below, which is the reference a spec holds the kernel to."""

    COMPILED = True
    """Whether a monitor built without saying runs the kernel (where it was built): the
    specs run every case both ways by flipping this."""

    RING_ROWS = 64
    """Link capsule ends the compiled speed window keeps at most (a check per 1 ms cycle
    needs 12); on more the oldest goes, as `SPEED_WINDOW` would drop it soon."""

    def __init__(self, params: SsmParams, max_speed: float, compiled: bool | None = None):
        """`max_speed`: the fastest the motion may go (m/s), the cap far from everyone;
        `compiled`: the kernel's check where it was built, else the Python one (None:
        `COMPILED`)."""
        self.params = params
        wanted = self.COMPILED if compiled is None else compiled
        self.compiled = wanted and _fwkernel is not None
        self._history: deque[tuple[np.ndarray, float]] = deque()  # (every capsule end, t)
        self._terms = np.array(
            [
                params.person_speed,
                params.reaction,
                params.engage,
                params.deceleration,
                params.intrusion,
                params.detection_uncertainty,
                params.robot_uncertainty,
                params.slow_band,
                max_speed,
                SPEED_WINDOW,
                FASTEST_LINK,
                MAX_QUIET,
            ]
        )
        self._ring = np.zeros((0, 1))  # the compiled window: rows of (t, every end)
        self._ring_meta = np.zeros(2)  # (count, first row)
        self.tcp_speed = 0.0
        """The tool's speed over the window of the last `robot_speed`."""

    @property
    def max_speed(self) -> float:
        """The fastest the motion may go (m/s): the cap far from everyone."""
        return float(self._terms[8])

    def _ring_for(self, a: np.ndarray) -> np.ndarray:
        """The compiled window's rows for `len(a)` link capsules (emptied if it was for
        another count: a speed between different arms is none)."""
        width = 1 + 6 * len(a)
        if self._ring.shape[1] != width:
            self._ring = np.zeros((self.RING_ROWS, width))
            self._ring_meta[:] = 0.0
        return self._ring

    def robot_speed(self, a: np.ndarray, b: np.ndarray, now: float) -> float:
        """The fastest link capsule end over the last `SPEED_WINDOW` (m/s; 0 on the
        first call): a release's settling jolt of a fraction of a millimetre in one
        cycle is not a speed the arm has to stop from. (`link_speed` of both ends at
        once: a check of the 1 kHz loop.)"""
        if self.compiled:
            speed, self.tcp_speed = _fwkernel.ssm_speed(
                _f64(a), _f64(b), self._ring_for(a), self._ring_meta, now, SPEED_WINDOW
            )
            return speed
        history = self._history
        ends = np.concatenate((a, b))  # a copy: the history keeps its own
        if history and history[0][0].shape != ends.shape:
            history.clear()  # another arm's capsules: no speed between them
        while len(history) > 1 and now - history[1][1] >= SPEED_WINDOW:
            history.popleft()
        speed = self.tcp_speed = 0.0
        if history and now > history[0][1]:
            before, then = history[0]
            moved = ends - before
            dt = now - then
            speed = _fastest(moved, dt)
            tip = moved[-1]  # the last link's far end: the tool
            self.tcp_speed = math.sqrt(float(tip @ tip)) / dt
        history.append((ends, now))
        return speed

    def check(
        self,
        robot: tuple[np.ndarray, np.ndarray, np.ndarray],
        people: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
        age: float,
        now: float,
        cap_age: float = 0.0,
    ) -> Verdict:
        """The verdict for the robot's capsules (a, b, radius) at time `now` and the
        people's envelope capsules, `age` seconds old (None or empty: nobody). The stop
        is judged at `age`; the cap is for the envelopes at `cap_age` if that is older
        (the age they will have when the next are due): a cap that holds for their
        whole life, never above the one of their true age, since a person may close
        in all that while, instead of one that falls every cycle as they age. A
        separation that is not a number is a stop (no clear verdict)."""
        a, b, radius = robot
        if self.compiled:
            return self.check_cycle(robot, people, age, now, cap_age, 1.0)[0]
        speed = self.robot_speed(a, b, now)
        if people is None or len(people[0]) == 0:
            return Verdict(math.inf, speed, 0.0, math.inf, False, self.tcp_speed)
        separation = least_capsule_distance(a, b, radius, *people)
        p = self.params
        protective = p.protective_distance(speed, age)
        cap_age = max(age, cap_age)
        standing = p.protective_distance(0.0, cap_age)
        share = (separation - standing) / p.slow_band if p.slow_band > 0 else 1.0
        cap = min(self.max_speed * min(max(share, 0.0), 1.0), p.allowed_speed(separation, cap_age))
        if share >= 1.0 and cap >= self.max_speed:
            cap = math.inf
        stop = not separation >= protective
        return Verdict(separation, speed, protective, cap, stop, self.tcp_speed)

    def check_cycle(
        self,
        robot: tuple[np.ndarray, np.ndarray, np.ndarray],
        people: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
        age: float,
        now: float,
        cap_age: float,
        dt: float,
    ) -> tuple[Verdict, int]:
        """`check`, then `quiet_cycles` of its verdict for cycles of `dt`: what the
        robot's loop asks of each check (one call of the kernel where it was built)."""
        if not self.compiled:
            verdict = self.check(robot, people, age, now, cap_age)
            return verdict, self.quiet_cycles(verdict, age, dt)
        a, b, radius = robot
        pa, pb, pr = _NOBODY if people is None else people
        ring, meta, terms = self._ring_for(a), self._ring_meta, self._terms
        try:  # float64 arrays, as the loop has them, pass as they are
            got = _fwkernel.ssm_check(
                a, b, radius, pa, pb, pr, ring, meta, terms, age, now, cap_age, dt
            )
        except (TypeError, ValueError, BufferError):  # anything else: as the kernel takes them
            got = _fwkernel.ssm_check(
                _f64(a), _f64(b), _f64(radius), _f64(pa), _f64(pb), _f64(pr),
                ring, meta, terms, age, now, cap_age, dt,
            )  # fmt: skip
        separation, speed, protective, cap, stop, tcp, quiet = got
        self.tcp_speed = tcp
        return Verdict(separation, speed, protective, cap, stop, tcp), quiet

    def quiet_cycles(self, verdict: Verdict, age: float, dt: float) -> int:
        """How many cycles of `dt` may pass before the next check changes anything: none
        inside the slowing band or near S_p at the fastest link speed; beyond them, as
        many as it takes the person (toward the robot, and by the envelope's ageing) and
        the robot (at `FASTEST_LINK`) to close the margin, at most `MAX_QUIET`."""
        if not math.isfinite(verdict.separation):
            return 0
        p = self.params
        guard = max(
            p.protective_distance(FASTEST_LINK, age),
            p.protective_distance(0.0, age) + p.slow_band,
        )
        margin = verdict.separation - guard
        if margin <= 0.0:
            return 0
        closing = 2.0 * p.person_speed + FASTEST_LINK
        return min(MAX_QUIET, int(margin / (closing * dt)))
