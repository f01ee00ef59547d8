"""A protective stop in joint space: full deceleration along the path the arm was on.

When the safety monitor trips, the robot interface no longer trusts the planner that
fed it; it stops the arm itself from the last commanded joint velocities (a category 1
stop: decelerate, then brakes on). Every joint decelerates linearly to zero over the
same time T, set by the joint that needs longest at its deceleration limit, so the arm
stays on the straight joint-space line it was following and no joint reverses.
"""

from __future__ import annotations

import numpy as np


class SafeStop:
    """Setpoints from `q` at velocity `v` down to rest at `deceleration` (rad/s^2 per
    joint), one per `dt`; `done` once at rest."""

    def __init__(self, q: np.ndarray, v: np.ndarray, deceleration: np.ndarray, dt: float):
        # made in the cycle that decides a stop, before its first command: few numpy calls
        self.q0 = np.array(q, dtype=float)
        self.v0 = np.array(v, dtype=float)
        if not np.isfinite(self.v0).all():
            self.v0 = np.zeros_like(self.q0)  # no trustworthy velocity: hold where it is
        times = np.abs(self.v0) / deceleration  # a deceleration per joint, or one for all
        if times.shape != self.q0.shape:
            raise ValueError(
                f"a deceleration per joint or one for all, not {np.shape(deceleration)}"
            )
        self.duration = float(times.max()) if self.v0.any() else 0.0
        self.dt = dt
        self.t = 0.0

    @property
    def done(self) -> bool:
        """True once the stop point is reached."""
        return self.t >= self.duration

    def at(self, t: float) -> np.ndarray:
        """The setpoint `t` seconds into the stop (the stop point after it)."""
        t = min(max(t, 0.0), self.duration)
        if self.duration == 0.0:
            return self.q0.copy()
        return self.q0 + self.v0 * (t - t * t / (2.0 * self.duration))

    def step(self) -> np.ndarray:
        """The next setpoint."""
        self.t = min(self.t + self.dt, self.duration)
        return self.at(self.t)

    @property
    def stop_point(self) -> np.ndarray:
        """Where the arm comes to rest."""
        return self.at(self.duration)
