"""Rigid transforms for tracking: poses as 4x4 matrices, batched where it matters."""

from __future__ import annotations

import numpy as np

from framework.messages import Pose


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) in w, x, y, z order."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - z * w)
    out[..., 0, 2] = 2 * (x * z + y * w)
    out[..., 1, 0] = 2 * (x * y + z * w)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - x * w)
    out[..., 2, 0] = 2 * (x * z - y * w)
    out[..., 2, 1] = 2 * (y * z + x * w)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def matrix_to_quat(r: np.ndarray) -> tuple[float, float, float, float]:
    """A unit quaternion (w, x, y, z) from one rotation matrix (w >= 0)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = (float(v) for v in Rotation.from_matrix(r).as_quat())
    q = (w, x, y, z)
    return q if w >= 0 else tuple(-v for v in q)  # type: ignore[return-value]


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


def as_matrix(value: object) -> np.ndarray:
    """A 4x4 transform from YAML data: a 4x4 list, or {position: [..], quaternion: [..]}."""
    if isinstance(value, dict):
        return transform(
            np.array(value.get("position", [0, 0, 0]), dtype=float),
            np.array(value.get("quaternion", [1, 0, 0, 0]), dtype=float),
        )
    matrix = np.array(value, dtype=float)
    if matrix.shape != (4, 4):
        raise ValueError(
            f"a transform is 4x4 or {{position, quaternion}}, got shape {matrix.shape}"
        )
    return matrix
