"""The people of the simulated OR: one ground truth that every simulated camera sees.

People walk along scripted waypoints (walk to the table, stand, lean over the
robot, leave) at walking speed; `PeopleWorld` publishes their true skeletons
(robot base frame, z up, floor at `floor`) on `sim/people`, and each `KinectSim`
observes that truth through its own noise model. Scenarios move people with the
`walk`, `lean`, `place` and `leave` operations.

It is also the **referee** of speed and separation monitoring: from the truth (the
people's true limbs, the arm's link capsules at its measured joints) it keeps, while
the arm moves, how far the true separation ever fell short of the room the arm needs
to stand still before a person walking at 1.6 m/s reaches it (the monitor's own
stopping model: 10 ms, then 2 m/s^2). `report` says it; a scenario's invariant
`max: {shortfall: 0}` checks it independently of the monitor that keeps it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from components.domain.distance import capsule_distances
from components.domain.geometry import norm
from components.domain.separation import SsmParams, link_speed
from components.domain.skeleton import JOINTS, Build, envelopes, standing
from framework.component import Component, In, Out, operation
from framework.errors import FwError
from framework.messages import JointState, Skeleton, Skeletons
from framework.ports import ReadStatus
from framework.properties import prop

WALK_SPEED = 1.0  # m/s, a calm walk in an OR
_HANDS = [JOINTS.index(name) for name in ("left_hand", "right_hand")]
_ELBOWS = [JOINTS.index(name) for name in ("left_elbow", "right_elbow")]


@dataclass
class Person:
    """One person: where they stand, face, are heading, and how far they lean."""

    position: np.ndarray
    facing: float = 0.0
    waypoints: list[np.ndarray] = field(default_factory=list)
    speed: float = WALK_SPEED
    lean: float = 0.0  # how far the hands reach forward (m)
    turn_to: float | None = None  # the facing (rad) on arrival at the last waypoint
    build: Build = field(default_factory=Build)

    def advance(self, dt: float) -> None:
        """Walk toward the next waypoint for `dt` seconds."""
        budget = self.speed * dt
        while self.waypoints and budget > 0:
            step = self.waypoints[0] - self.position
            distance = norm(step)
            if distance > 1e-9:
                self.facing = math.atan2(step[1], step[0])
            if distance <= budget:
                self.position = self.waypoints.pop(0)
                budget -= distance
            else:
                self.position = self.position + step * (budget / distance)
                budget = 0.0
        if not self.waypoints and self.turn_to is not None:  # arrived: turn as asked
            self.facing, self.turn_to = self.turn_to, None

    def skeleton(self, floor: float) -> np.ndarray:
        """True joints (15 x 3)."""
        at = (float(self.position[0]), float(self.position[1]))
        joints = standing(at, self.facing, build=self.build, floor=floor)
        if self.lean > 0:  # arms reach forward to hands at table height
            ahead = np.array([math.cos(self.facing), math.sin(self.facing), 0.0])
            shoulders = joints[[JOINTS.index("left_shoulder"), JOINTS.index("right_shoulder")]]
            hands = shoulders + ahead * self.lean
            hands[:, 2] = floor + 0.85
            joints[_HANDS] = hands
            joints[_ELBOWS] = (shoulders + hands) / 2
        return joints


class PeopleWorld(Component):
    """Moves scripted people and publishes their true skeletons (`sim/people`)."""

    floor = prop(float, -0.8, unit="m", doc="floor height in the robot base frame")
    people = Out(Skeletons, doc="true skeletons of everyone in the room (base frame)")
    joints = In(JointState, doc="the arm's joints, for the referee (unconnected: no referee)")

    def configure_hook(self) -> bool:
        self.crowd: dict[int, Person] = {}
        self._last = time.monotonic()
        self._kinematics: Any = None
        self._links: tuple[np.ndarray, np.ndarray, float] | None = None  # a, b, time
        self.shortfall = 0.0
        self.closest_moving = math.inf
        return True

    def start_hook(self) -> bool:
        self._last = time.monotonic()
        return True

    def update_hook(self) -> None:
        now = time.monotonic()
        dt, self._last = min(now - self._last, 0.1), now
        for person in self.crowd.values():
            person.advance(dt)
        truth = [p.skeleton(self.floor) for _, p in sorted(self.crowd.items())]
        users = tuple(
            Skeleton(pid, tuple(joints.ravel().tolist()), (1.0,) * len(JOINTS))
            for pid, joints in zip(sorted(self.crowd), truth, strict=True)
        )
        self.people.write(Skeletons(time.time(), "world", users))
        self._referee(truth, now)

    def _referee(self, truth: list[np.ndarray], now: float) -> None:
        """The true separation against the room the moving arm needs (module docstring)."""
        status, joints = self.joints.read()
        if status is ReadStatus.NO_DATA:
            return
        if self._kinematics is None:
            from components.domain.lwr4 import Kinematics

            self._kinematics = Kinematics()
        links = self._kinematics.capsules(np.asarray(joints.position, dtype=float))
        before, self._links = self._links, (links.a, links.b, now)
        if before is None or now <= before[2] or not truth:
            return
        speed = link_speed(before[:2], (links.a, links.b), now - before[2])
        if speed < 1e-4:  # standing: a person may touch a robot that stands
            return
        p, q, r, _, _ = envelopes(np.stack(truth), np.zeros((len(truth), len(JOINTS))))
        separation = float(np.min(capsule_distances(links.a, links.b, links.radius, p, q, r)))
        model = SsmParams()
        need = model.person_speed * model.stopping_time(speed) + model.stopping_distance(speed)
        self.closest_moving = min(self.closest_moving, separation)
        self.shortfall = max(self.shortfall, need - separation)

    @operation(readonly=True)
    def report(self) -> dict[str, Any]:
        """The referee: the least true separation while the arm moved (m; None: never
        near anyone) and the most it fell short of the room to stop (m; 0: never)."""
        closest = self.closest_moving
        return {
            "closest_moving": round(closest, 4) if math.isfinite(closest) else None,
            "shortfall": round(self.shortfall, 4),
        }

    def _person(self, person: int) -> Person:
        if person not in self.crowd:
            raise FwError(f"no person {person} in the room (place them first)")
        return self.crowd[person]

    @operation
    def place(self, person: int, x: float, y: float, facing_deg: float = 0.0) -> None:
        """Put a person standing at floor position (x, y) (m, base frame)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            raise FwError("a person's position must be finite")
        self.crowd[person] = Person(np.array([x, y], dtype=float), math.radians(facing_deg))

    @operation
    def walk(
        self,
        person: int,
        x: float,
        y: float,
        speed: float = WALK_SPEED,
        facing_deg: float | None = None,
    ) -> None:
        """Walk (after any waypoints already queued) to (x, y) at `speed` (m/s), facing
        where they walk; on arrival turn to `facing_deg` if given (a surgeon who walks
        up to the table turns to it: leaning, they reach where they face)."""
        if not (math.isfinite(x) and math.isfinite(y)) or not 0 < speed <= 3:
            raise FwError("walk needs a finite (x, y) and 0 < speed <= 3 m/s")
        if facing_deg is not None and not math.isfinite(facing_deg):
            raise FwError("facing_deg must be finite")
        p = self._person(person)
        p.waypoints.append(np.array([x, y], dtype=float))
        p.speed = speed
        p.turn_to = None if facing_deg is None else math.radians(facing_deg)

    @operation
    def lean(self, person: int, reach: float = 0.5) -> None:
        """Reach forward over the table by `reach` metres (0: stand upright)."""
        if not 0 <= reach <= 1.0:
            raise FwError("reach is between 0 and 1 m")
        self._person(person).lean = reach

    @operation
    def leave(self, person: int) -> None:
        """The person leaves the room."""
        self.crowd.pop(person, None)

    @operation(readonly=True)
    def where(self) -> dict[str, Any]:
        """Everyone's floor position, facing and lean."""
        return {
            str(pid): {
                "x": round(float(p.position[0]), 3),
                "y": round(float(p.position[1]), 3),
                "facing_deg": round(math.degrees(p.facing), 1),
                "lean": p.lean,
                "walking": bool(p.waypoints),
            }
            for pid, p in self.crowd.items()
        }
