"""3D rotations on plain arrays, batched over any leading axes.

Axis-angle vectors are ``(..., 3)`` radians (the SMPL pose convention), matrices ``(..., 3, 3)`` act on
column vectors, quaternions are scipy's scalar-last ``(..., 4)``.  scipy's `Rotation` does the
conversions; these wrappers only keep the leading axes.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

#: SMPL/AMASS files are Y up (person facing +Z); the project's world is Z up (facing -Y).  This is the
#: +90 degree rotation about X that takes the first to the second: x -> x, y -> z, z -> -y.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _flat(rotation: Rotation, lead: tuple[int, ...], tail: tuple[int, ...], how: str) -> np.ndarray:
    return getattr(rotation, how)().reshape(lead + tail)


def rotvec_to_matrix(rotvec: np.ndarray) -> np.ndarray:
    """Axis-angle (..., 3) -> rotation matrices (..., 3, 3)."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    if rotvec.size == 0:
        return np.zeros(rotvec.shape[:-1] + (3, 3))
    return _flat(Rotation.from_rotvec(rotvec.reshape(-1, 3)), rotvec.shape[:-1], (3, 3), "as_matrix")


def matrix_to_rotvec(matrix: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angle (..., 3), angles in [0, pi]."""
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.size == 0:
        return np.zeros(matrix.shape[:-2] + (3,))
    return _flat(Rotation.from_matrix(matrix.reshape(-1, 3, 3)), matrix.shape[:-2], (3,), "as_rotvec")


def rotvec_to_quat(rotvec: np.ndarray) -> np.ndarray:
    """Axis-angle (..., 3) -> unit quaternions (..., 4), scalar last."""
    rotvec = np.asarray(rotvec, dtype=np.float64)
    return _flat(Rotation.from_rotvec(rotvec.reshape(-1, 3)), rotvec.shape[:-1], (4,), "as_quat")


def quat_to_rotvec(quat: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4), scalar last -> axis-angle (..., 3)."""
    quat = np.asarray(quat, dtype=np.float64)
    return _flat(Rotation.from_quat(quat.reshape(-1, 4)), quat.shape[:-1], (3,), "as_rotvec")


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions (..., 4) at fractions t (...,), shortest arc."""
    q0 = np.asarray(q0, dtype=np.float64)
    q1 = np.asarray(q1, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0.0, -q1, q1)  # q and -q are one rotation: take the short way round
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin = np.sin(theta)
    near = sin < 1e-8  # nearly identical: linear interpolation is exact to rounding
    safe = np.where(near, 1.0, sin)
    w0 = np.where(near, 1.0 - t, np.sin((1.0 - t) * theta) / safe)
    w1 = np.where(near, t, np.sin(t * theta) / safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def align_vectors(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Minimal rotations (..., 3, 3) taking directions a (..., 3) onto directions b (..., 3).

    The rotation is about ``a x b``; for opposite vectors it turns by pi about an axis perpendicular
    to a.  Inputs need not be unit length.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    axis = np.cross(a, b)
    sin = np.linalg.norm(axis, axis=-1, keepdims=True)
    cos = np.sum(a * b, axis=-1, keepdims=True)
    # Opposite directions: any axis perpendicular to a works; take a x e for the least-aligned e.
    helper = np.eye(3)[np.argmin(np.abs(a), axis=-1)]
    fallback = np.cross(a, helper)
    fallback /= np.linalg.norm(fallback, axis=-1, keepdims=True)
    unit = np.where(sin > 1e-12, axis / np.maximum(sin, 1e-300), fallback)
    angle = np.arctan2(sin, cos)
    return rotvec_to_matrix(unit * angle)


def conjugate_rotvec(rotvec: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Express axis-angle rotations (..., 3) given in one frame in another: ``F R F^T`` is the rotation
    about the axis ``F a`` by the same angle, so only the axis turns."""
    return np.asarray(rotvec, dtype=np.float64) @ np.asarray(frame, dtype=np.float64).T
