"""Rigid transforms for tracking: poses as 4x4 matrices, batched where it matters."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from components.domain.kernel import _fwkernel
from framework.messages import Pose


def _quadratic_form() -> np.ndarray:
    """The 16 x 9 map from the products q_a q_b to the rotation matrix entries."""
    entries = {  # entry: {(a, b): coefficient} over w, x, y, z = 0, 1, 2, 3
        (0, 0): {(0, 0): 1, (1, 1): 1, (2, 2): -1, (3, 3): -1},
        (0, 1): {(1, 2): 2, (0, 3): -2},
        (0, 2): {(1, 3): 2, (0, 2): 2},
        (1, 0): {(1, 2): 2, (0, 3): 2},
        (1, 1): {(0, 0): 1, (1, 1): -1, (2, 2): 1, (3, 3): -1},
        (1, 2): {(2, 3): 2, (0, 1): -2},
        (2, 0): {(1, 3): 2, (0, 2): -2},
        (2, 1): {(2, 3): 2, (0, 1): 2},
        (2, 2): {(0, 0): 1, (1, 1): -1, (2, 2): -1, (3, 3): 1},
    }
    form = np.zeros((16, 9))
    for (row, col), terms in entries.items():
        for (a, b), coefficient in terms.items():
            form[4 * a + b, 3 * row + col] = coefficient
    return form


_QUADRATIC = _quadratic_form()


def norm(v: Any) -> float:
    """Euclidean length of a vector (or of a matrix's entries, Frobenius).

    Why not `np.linalg.norm`: for a whole array it calls BLAS `dot`, which releases the
    interpreter lock; in a process where another Python thread is busy (a bus callback,
    another component) taking it back waits for that thread's switch interval (5 ms).
    Measured: 4 us alone, 430 us beside one busy thread (2.4 ms for `ndarray.dot`), in
    the Navigator and the Sensor Manager hundreds of times a second. `@` on small arrays
    keeps the lock (tests/test_architecture.py keeps runtime code to it).
    """
    a = np.asarray(v, dtype=float).ravel()
    return math.sqrt(float(a @ a))


def joint_gap(a: Any, b: Any) -> float:
    """The largest |a_i - b_i| of two vectors of 7 joints (tuples, lists or float64
    arrays; Python's max over them: a NaN first stays, a later one is skipped); in the
    compiled kernel where it was built (`max_abs_diff`)."""
    if _fwkernel is not None:
        return _fwkernel.max_abs_diff(a, b)
    return joint_gap_reference(a, b)


def joint_gap_reference(a: Any, b: Any) -> float:
    """`joint_gap` in plain Python."""
    x, y = list(a), list(b)
    if len(x) != 7 or len(y) != 7:
        raise ValueError("max_abs_diff: two sequences of 7 numbers")
    return max(abs(float(u) - float(v)) for u, v in zip(x, y, strict=True))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in w, x, y, z order.

    The entries are a quadratic form in q, divided by |q|^2 so that non-unit
    quaternions still give rotations; three numpy calls whatever the batch size
    (the Sensor Manager converts every tool's quaternion at 1 kHz)."""
    q = np.asarray(q, dtype=float)
    products = q[..., :, None] * q[..., None, :]
    flat = products.reshape(*q.shape[:-1], 16)
    scale = np.einsum("...ii->...", products)[..., None]
    return ((flat @ _QUADRATIC) / scale).reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat(r: np.ndarray) -> tuple[float, float, float, float]:
    """A unit quaternion (w, x, y, z) from one rotation matrix (w >= 0).

    Shepperd's method on plain floats (~20x faster than scipy for one matrix; the
    robot publishes two poses every millisecond)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(r, dtype=float).tolist()
    trace = m00 + m11 + m22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = (0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s)
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = ((m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s)
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = ((m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = ((m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s)
    norm = math.sqrt(sum(v * v for v in q))
    sign = 1.0 if q[0] >= 0 else -1.0
    return tuple(sign * v / norm for v in q)  # type: ignore[return-value]


def transform(position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform(s) from position(s) and quaternion(s)."""
    position = np.asarray(position, dtype=float)
    out = np.zeros((*position.shape[:-1], 4, 4))
    out[..., :3, :3] = quat_to_matrix(quaternion)
    out[..., :3, 3] = position
    out[..., 3, 3] = 1.0
    return out


def pose_matrix(pose: Pose) -> np.ndarray:
    """The 4x4 transform of a Pose."""
    return transform(np.array(pose.position), np.array(pose.orientation))


def invert(t: np.ndarray) -> np.ndarray:
    """Inverse of rigid transform(s) (..., 4, 4), using R^T."""
    out = np.zeros_like(t)
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, t[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def rotation_angle(r: np.ndarray) -> np.ndarray:
    """Angle (rad) of rotation matrices (..., 3, 3)."""
    cos = (np.trace(r, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.arccos(np.clip(cos, -1.0, 1.0))


def rotvec_matrix(rotvec: object) -> np.ndarray:
    """The rotation matrix of a rotation vector (axis times angle, rad): Rodrigues'
    formula in numpy, so a process that needs only this does not load scipy (every
    shared library a process maps delays the moment its death is seen, docs/safety.md)."""
    v = np.asarray(rotvec, dtype=float)
    angle = norm(v)
    if angle < 1e-12:
        return np.eye(3)
    x, y, z = v / angle
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)


def as_matrix(value: object) -> np.ndarray:
    """A 4x4 rigid transform from YAML data: a 4x4 list, or {position: [..], quaternion:
    [..]}; `ValueError` for anything that is not one (non-finite values, a quaternion far
    from unit length, a matrix that is not a rotation and a translation)."""
    if isinstance(value, dict):
        position = np.array(value.get("position", [0, 0, 0]), dtype=float)
        quaternion = np.array(value.get("quaternion", [1, 0, 0, 0]), dtype=float)
        if position.shape != (3,) or quaternion.shape != (4,):
            raise ValueError("a transform needs 3 position values and 4 quaternion values")
        if not (np.isfinite(position).all() and np.isfinite(quaternion).all()):
            raise ValueError("a transform's values must be finite numbers")
        norm = math.hypot(*quaternion)  # no overflow, whatever the values
        if abs(norm - 1.0) > 1e-3:
            raise ValueError(f"the quaternion [w, x, y, z] must have unit length, not {norm:.4g}")
        return transform(position, quaternion / norm)
    matrix = np.array(value, dtype=float)
    if matrix.shape != (4, 4):
        raise ValueError(
            f"a transform is 4x4 or {{position, quaternion}}, got shape {matrix.shape}"
        )
    rotation = matrix[:3, :3]
    if (
        not np.isfinite(matrix).all()
        or np.abs(rotation).max() > 1.0 + 1e-3  # no rotation has such entries (nor overflows)
        or not np.allclose(matrix[3], [0, 0, 0, 1])
        or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4)
        or np.linalg.det(rotation) < 0
    ):
        raise ValueError("a 4x4 transform must be a rotation and a translation, last row 0 0 0 1")
    return matrix


def rigid(
    translation: tuple[float, float, float], rotvec: tuple[float, float, float]
) -> np.ndarray:
    """A 4x4 transform from a translation (m) and a rotation vector (rad)."""
    out = np.eye(4)
    out[:3, :3] = rotvec_matrix(rotvec)
    out[:3, 3] = translation
    return out


def look_at(position: tuple[float, float, float], target: tuple[float, float, float]) -> np.ndarray:
    """Camera pose (world_from_camera, 4x4): z along the optical axis towards `target`,
    x to the right, y down, as depth cameras report."""
    eye, at = np.asarray(position, float), np.asarray(target, float)
    z = at - eye
    z /= norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, y, z], axis=1)
    pose[:3, 3] = eye
    return pose


def pose_list(pose: np.ndarray) -> list[float]:
    """A 4x4 pose as [x, y, z, qw, qx, qy, qz] (m), for a message."""
    return [round(float(v), 7) for v in (*pose[:3, 3], *matrix_to_quat(pose[:3, :3]))]


def pose_from_list(values: Any) -> np.ndarray:
    """`pose_list` read back: a 4x4 pose; ValueError unless 7 finite numbers with a unit
    quaternion (a goal from a message is checked before the robot steers by it)."""
    v = [float(x) for x in values]
    if len(v) != 7 or not all(map(math.isfinite, v)):
        raise ValueError(f"a pose is 7 finite numbers, got {values!r}")
    w, x, y, z = v[3:]
    if abs(w * w + x * x + y * y + z * z - 1.0) > 1e-3:
        raise ValueError("a pose's quaternion must be a unit one")
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix(np.array([w, x, y, z]))
    out[:3, 3] = v[:3]
    return out
