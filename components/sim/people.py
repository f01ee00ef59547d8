"""The people of the simulated OR: one ground truth that every simulated camera sees.

People walk along scripted waypoints (walk to the table, stand, lean over the
robot, leave) at walking speed; `PeopleWorld` publishes their true skeletons
(robot base frame, z up, floor at `floor`) on `sim/people`, and each `KinectSim`
observes that truth through its own noise model. Scenarios move people with the
`walk`, `lean`, `place` and `leave` operations.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from components.people.skeleton import JOINTS, standing
from framework.component import Component, Out, operation
from framework.errors import FwError
from framework.messages import Skeleton, Skeletons
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

    def advance(self, dt: float) -> None:
        """Walk toward the next waypoint for `dt` seconds."""
        budget = self.speed * dt
        while self.waypoints and budget > 0:
            step = self.waypoints[0] - self.position
            distance = float(np.linalg.norm(step))
            if distance > 1e-9:
                self.facing = math.atan2(step[1], step[0])
            if distance <= budget:
                self.position = self.waypoints.pop(0)
                budget -= distance
            else:
                self.position = self.position + step * (budget / distance)
                budget = 0.0

    def skeleton(self, floor: float) -> np.ndarray:
        """True joints (15 x 3)."""
        joints = standing((float(self.position[0]), float(self.position[1])), self.facing)
        joints[:, 2] += floor
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

    def configure_hook(self) -> bool:
        self.crowd: dict[int, Person] = {}
        self._last = time.monotonic()
        return True

    def start_hook(self) -> bool:
        self._last = time.monotonic()
        return True

    def update_hook(self) -> None:
        now = time.monotonic()
        dt, self._last = min(now - self._last, 0.1), now
        for person in self.crowd.values():
            person.advance(dt)
        users = tuple(
            Skeleton(pid, tuple(p.skeleton(self.floor).ravel().tolist()), (1.0,) * len(JOINTS))
            for pid, p in sorted(self.crowd.items())
        )
        self.people.write(Skeletons(time.time(), "world", users))

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
    def walk(self, person: int, x: float, y: float, speed: float = WALK_SPEED) -> None:
        """Walk (after any waypoints already queued) to (x, y) at `speed` (m/s)."""
        if not (math.isfinite(x) and math.isfinite(y)) or not 0 < speed <= 3:
            raise FwError("walk needs a finite (x, y) and 0 < speed <= 3 m/s")
        p = self._person(person)
        p.waypoints.append(np.array([x, y], dtype=float))
        p.speed = speed

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
