"""Differential inverse kinematics: a Cartesian setpoint each cycle to joint setpoints.

Damped least squares (Wampler 1986; Nakamura & Hanafusa 1986) on the 6x7
Jacobian, so the solution stays bounded near singularities; the seventh degree
of freedom pulls gently toward a rest posture in the Jacobian's null space (the
elbow does not drift over a long approach); every step respects the joint
velocity limits and keeps a margin from the joint position limits.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.linalg import lapack

from components.domain.geometry import norm
from components.domain.kernel import _fwkernel
from components.domain.lwr4 import HOME, Kinematics

COMPILED = _fwkernel is not None
"""True when the IK step runs in the compiled kernel (else in numpy, ~5x slower)."""


class DifferentialIK:
    """Maps a desired TCP pose to the next joint setpoint, one control cycle at a time."""

    def __init__(
        self,
        kinematics: Kinematics | None = None,
        dt: float = 0.001,
        damping: float = 0.02,
        rest: tuple[float, ...] = HOME,
        rest_gain: float = 0.5,
        limit_margin: float = np.radians(2.0),
    ):
        self.kin = kinematics or Kinematics()
        self.dt = dt
        self.damping2 = damping * damping
        self.rest = np.array(rest)
        self.rest_gain = rest_gain
        self.lower = self.kin.lower + limit_margin
        self.upper = self.kin.upper - limit_margin
        self.max_step = self.kin.velocity_limit * dt
        self._damping = self.damping2 * np.eye(6)

    def error(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Pose error (6,): translation (m) then rotation vector (rad), base frame."""
        pose = self.kin.tcp(q)
        rotation = pin.log3(target[:3, :3] @ pose[:3, :3].T)
        return np.concatenate([target[:3, 3] - pose[:3, 3], rotation])

    def step(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Joints one cycle closer to putting the TCP at `target` (4x4, base frame): in
        the compiled kernel where it was built (the same formulas as `step_reference`,
        which a spec holds it to), else in numpy."""
        if _fwkernel is None:
            return self.step_reference(q, target)
        out = np.empty(7)
        solved = _fwkernel.ik_step(
            self.kin.placements,
            self.kin.tool,
            np.ascontiguousarray(q, dtype=float),
            np.ascontiguousarray(target, dtype=float),
            self.rest,
            self.lower,
            self.upper,
            self.max_step,
            out,
            self.damping2,
            self.rest_gain * self.dt,
        )
        return out if solved else self.step_reference(q, target)

    def step_reference(self, q: np.ndarray, target: np.ndarray) -> np.ndarray:
        """`step` in numpy: the reference of the compiled kernel, and its fallback."""
        pose, jac = self.kin.jacobian(q)
        err = np.concatenate(
            [target[:3, 3] - pose[:3, 3], pin.log3(target[:3, :3] @ pose[:3, :3].T)]
        )
        # dq = pinv err + (I - pinv J) rest, pinv = J^T (J J^T + d^2 I)^-1: one solve of
        # the damped 6x6 system (Cholesky: it is positive definite), no inverse, no 7x7
        rest = self.rest_gain * self.dt * (self.rest - q)
        jjt, rhs = jac @ jac.T + self._damping, err - jac @ rest
        _, y, info = lapack.dposv(jjt, rhs)
        if info:  # not finite: let numpy say what it makes of it
            y = np.linalg.solve(jjt, rhs)
        dq = jac.T @ y + rest
        scale = (np.abs(dq) / self.max_step).max()
        if scale > 1.0:  # keep the direction, respect every joint's speed
            dq /= scale
        # the clamp by two ufuncs: np.clip's wrapper costs more than the work at 1 kHz
        return np.minimum(np.maximum(q + dq, self.lower), self.upper)

    def solve(self, q: np.ndarray, target: np.ndarray, iterations: int = 2000) -> np.ndarray:
        """Joints placing the TCP at `target`, from `q` (offline use: homes, tests)."""
        q = np.asarray(q, dtype=float)
        for _ in range(iterations):
            q = self.step(q, target)
            if norm(self.error(q, target)) < 1e-7:
                break
        return q
