"""Calibration: TCP pivoting, robot-tracker hand-eye (AX = YB), tracker-tracker (eq. 3.3).

Hand-eye (thesis 3.3.2): for robot poses k the tracker measures the CTO in the
reference tool's frame, A_k = (T_RTO)^-1 T_CTO, and the joints give the
end-effector in the base frame, B_k. Then A_k = X B_k Y with X = RTO_X_base and
Y = ee_Y_CTO. X comes first in closed form from pose pairs (A_j A_k^-1) X =
X (B_j B_k^-1) (Park & Martin for the rotation, linear least squares for the
translation), Y from the average of B_k^-1 X^-1 A_k; then scipy's least squares
refines both over all rotation and translation residuals.

A calibration that cannot be trusted is refused, never returned: first the pose set
must make X and Y observable (`observability`: rotations between poses about at least
two well-separated axes, a well-conditioned translation system); then, given the
measurement noise, the residuals must be consistent with it (a reference tool that
moved during the protocol, a tracker that lied). Each refusal is a `CalibrationError`
naming what is missing.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy.linalg import sqrtm
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from components.domain.geometry import invert, norm
from framework.errors import FwError

ROTATION_SCALE = 0.1  # metres per radian when rotation and translation residuals are mixed
MIN_ROTATION = np.radians(5.0)
"""A pose pair rotating less than this says nothing about the rotation of X."""
MIN_AXIS_SPREAD = 0.25
"""Second over first singular value of the pairs' rotation axes: below, the axes are
(nearly) one, and X's rotation about it and Y's translation along it are unobservable."""
MAX_CONDITION = 1e3
"""Condition number of the translation system above which X's translation is refused."""
RESIDUAL_FACTOR = 4.0
"""Residuals above this many times the stated noise (plus `RESIDUAL_FLOOR`) are refused."""
RESIDUAL_FLOOR = 2e-4  # m: the robot's own kinematic error


class CalibrationError(FwError, ValueError):
    """A calibration that cannot be trusted (the message says what is missing)."""


@dataclass
class PivotResult:
    """Tip in the tool frame, pivot point in the tracker frame, RMS residual (m)."""

    tip: np.ndarray
    pivot: np.ndarray
    rms: float


def pivot_calibration(poses: list[np.ndarray]) -> PivotResult:
    """Least-squares TCP from tool poses pivoting about one fixed point:
    R_i tip + p_i = pivot for every pose i."""
    if len(poses) < 3:
        raise ValueError("pivot calibration needs at least 3 poses")
    rows, rhs = [], []
    for t in poses:
        rows.append(np.hstack([t[:3, :3], -np.eye(3)]))
        rhs.append(-t[:3, 3])
    a, b = np.vstack(rows), np.hstack(rhs)
    solution, *_ = np.linalg.lstsq(a, b, rcond=None)
    residual = a @ solution - b
    return PivotResult(
        solution[:3],
        solution[3:],
        float(np.sqrt(np.mean(np.sum(residual.reshape(-1, 3) ** 2, axis=1)))),
    )


def _log(r: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(r).as_rotvec()


def _average_rotation(rotations: list[np.ndarray]) -> np.ndarray:
    u, _, vt = np.linalg.svd(sum(rotations))
    r = u @ vt
    if np.linalg.det(r) < 0:
        u[:, -1] *= -1
        r = u @ vt
    return r


def observability(b: list[np.ndarray]) -> str:
    """'' if robot poses `b` (base frame) make X and Y of A = X B Y observable, else what
    is missing: enough rotation between poses, about at least two separated axes, and
    a well-conditioned translation system."""
    if len(b) < 3:
        return f"{len(b)} poses: hand-eye calibration needs at least 3 (8 recommended)"
    axes, blocks = [], []
    for j, k in combinations(range(len(b)), 2):
        rotation = (b[j] @ invert(b[k]))[:3, :3]
        vector = _log(rotation)
        if not np.all(np.isfinite(vector)):
            return "a robot pose is not a finite rigid transform"
        if norm(vector) >= MIN_ROTATION:
            axes.append(vector / norm(vector))
            blocks.append(rotation - np.eye(3))
    if len(axes) < 2:
        return (
            "the robot poses rotate less than 5 deg from one another: the rotation of X is "
            "unobservable; tilt the tool between poses (about two axes at least)"
        )
    singular = np.linalg.svd(np.array(axes), compute_uv=False)
    if singular[1] < MIN_AXIS_SPREAD * singular[0]:
        axis = np.linalg.svd(np.array(axes))[2][0]
        return (
            "every rotation between the robot poses is about one axis "
            f"(~[{axis[0]:.2f}, {axis[1]:.2f}, {axis[2]:.2f}] in the base frame): X and Y "
            "are unobservable along it; add poses tilted about a second axis"
        )
    condition = np.linalg.cond(np.vstack(blocks))
    if not np.isfinite(condition) or condition > MAX_CONDITION:
        return (
            f"the translation of X is ill-conditioned (condition number {condition:.3g}): "
            "spread the rotations between poses more"
        )
    return ""


def hand_eye_closed_form(a: list[np.ndarray], b: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Initial X, Y for A_k = X B_k Y from pose pairs (see the module docstring)."""
    alphas, betas, pairs = [], [], []
    for j, k in combinations(range(len(a)), 2):
        aa = a[j] @ invert(a[k])
        bb = b[j] @ invert(b[k])
        alpha, beta = _log(aa[:3, :3]), _log(bb[:3, :3])
        if norm(alpha) < 1e-3 or norm(beta) < 1e-3:
            continue  # a pure translation pair says nothing about the rotation
        alphas.append(alpha)
        betas.append(beta)
        pairs.append((aa, bb))
    if len(pairs) < 2:
        raise CalibrationError("the robot poses need rotations about at least two axes")
    m = sum(np.outer(beta, alpha) for alpha, beta in zip(alphas, betas, strict=True))
    rx = np.real(sqrtm(np.linalg.inv(m.T @ m))) @ m.T
    u, _, vt = np.linalg.svd(rx)
    rx = u @ vt
    lhs = np.vstack([aa[:3, :3] - np.eye(3) for aa, _ in pairs])
    rhs = np.hstack([rx @ bb[:3, 3] - aa[:3, 3] for aa, bb in pairs])
    tx, *_ = np.linalg.lstsq(lhs, rhs, rcond=None)
    x = np.eye(4)
    x[:3, :3], x[:3, 3] = rx, tx
    ys = [invert(bk) @ invert(x) @ ak for ak, bk in zip(a, b, strict=True)]
    y = np.eye(4)
    y[:3, :3] = _average_rotation([yk[:3, :3] for yk in ys])
    y[:3, 3] = np.mean([yk[:3, 3] for yk in ys], axis=0)
    return x, y


def _unpack(params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    out = []
    for offset in (0, 6):
        t = np.eye(4)
        t[:3, :3] = Rotation.from_rotvec(params[offset : offset + 3]).as_matrix()
        t[:3, 3] = params[offset + 3 : offset + 6]
        out.append(t)
    return out[0], out[1]


def _pack(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.hstack([_log(x[:3, :3]), x[:3, 3], _log(y[:3, :3]), y[:3, 3]])


@dataclass
class HandEyeResult:
    """X = RTO_X_base, Y = ee_Y_CTO and the per-axis residuals (Table 3.4's columns)."""

    x: np.ndarray
    y: np.ndarray
    translation_residual: np.ndarray  # RMS per axis, m
    rotation_residual_deg: np.ndarray  # RMS per axis, degrees
    poses: int


def residuals(
    x: np.ndarray, y: np.ndarray, a: list[np.ndarray], b: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose translation (m) and rotation-vector (rad) residuals of A_k vs X B_k Y."""
    trans, rot = [], []
    for ak, bk in zip(a, b, strict=True):
        predicted = x @ bk @ y
        trans.append(ak[:3, 3] - predicted[:3, 3])
        rot.append(_log(predicted[:3, :3].T @ ak[:3, :3]))
    return np.array(trans), np.array(rot)


def hand_eye(a: list[np.ndarray], b: list[np.ndarray], noise: float | None = None) -> HandEyeResult:
    """Solve A_k = X B_k Y: closed form, then least squares over all residuals.

    Refused with `CalibrationError` if the poses do not make X and Y observable, and,
    when the measurement `noise` (3-D RMS of A's translation, m) is given, if the
    residuals are inconsistent with it."""
    if len(a) != len(b) or len(a) < 3:
        raise CalibrationError("hand-eye calibration needs at least 3 matching pose pairs")
    if not all(np.all(np.isfinite(t)) for t in (*a, *b)):
        raise CalibrationError("a measured or robot pose is not finite (NaN or infinite)")
    problem = observability(b)
    if problem:
        raise CalibrationError(problem)
    x0, y0 = hand_eye_closed_form(a, b)

    def cost(params: np.ndarray) -> np.ndarray:
        x, y = _unpack(params)
        trans, rot = residuals(x, y, a, b)
        return np.hstack([trans.ravel(), ROTATION_SCALE * rot.ravel()])

    fit = least_squares(cost, _pack(x0, y0), method="lm")
    x, y = _unpack(fit.x)
    trans, rot = residuals(x, y, a, b)
    if noise is not None:
        rms = float(np.sqrt(np.mean(np.sum(trans**2, axis=1))))
        limit = RESIDUAL_FACTOR * noise + RESIDUAL_FLOOR
        if not rms <= limit:
            raise CalibrationError(
                f"residuals of {rms * 1e3:.2f} mm RMS are inconsistent with the stated "
                f"{noise * 1e3:.2f} mm noise (limit {limit * 1e3:.2f} mm): did the reference "
                "tool or the camera move during the protocol? Repeat it"
            )
    return HandEyeResult(
        x,
        y,
        np.sqrt(np.mean(trans**2, axis=0)),
        np.degrees(np.sqrt(np.mean(rot**2, axis=0))),
        len(a),
    )


def tracker_to_tracker(x_master: np.ndarray, x_sensor: np.ndarray) -> np.ndarray:
    """Eq. 3.3: C = X_master X_sensor^-1 maps the sensor's reference frame to the master's."""
    return x_master @ invert(x_sensor)


def protocol_poses(count: int, seed: int = 0, half: float = 0.075) -> list[np.ndarray]:
    """End-effector poses (base frame) spread for a well-conditioned calibration: a
    cube of positions (half-size `half`, m) in front of the robot, orientations tilted
    about all axes."""
    from components.domain.geometry import rigid

    rng = np.random.default_rng(seed)
    poses = []
    for k in range(count):
        corner = np.array([(k >> i) & 1 for i in range(3)], dtype=float) - 0.5
        position = np.array([0.55, 0.0, 0.45]) + 2 * half * corner + rng.normal(0, 0.02, 3)
        tilt = rng.uniform(-0.45, 0.45, 3)
        tilt[1] += np.pi  # the tool points down at the table (as at the target)
        poses.append(rigid(tuple(position), tuple(tilt)))
    return poses


def pivot_poses(count: int, seed: int = 0, tilt: float = 0.5) -> list[np.ndarray]:
    """Poses of a tool (its tip frame, base frame) pivoted by hand about a divot on the
    table: the tip stays in the divot while the tool is tilted up to `tilt` rad about two
    axes and turned about its own; the pivot's shape, never the arm's kinematics."""
    from components.domain.geometry import rigid

    rng = np.random.default_rng(seed)
    divot = np.array([0.55, 0.10, 0.05])
    poses = []
    for _ in range(count):
        tilt_xy = rng.uniform(-tilt, tilt, 2)
        turn = rng.uniform(-np.pi / 2, np.pi / 2)
        down = rigid((0.0, 0.0, 0.0), (np.pi, 0.0, 0.0))  # pointing at the table
        pose = rigid(tuple(divot), (tilt_xy[0], tilt_xy[1], 0.0)) @ down
        poses.append(pose @ rigid((0.0, 0.0, 0.0), (0.0, 0.0, turn)))
    return poses
