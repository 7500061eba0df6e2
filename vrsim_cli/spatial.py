"""Rotations: unit quaternions [w, x, y, z], rotation matrices and Euler angles.

Layer 0. Vectorised over a leading axis where that is useful. Quaternions are
Hamilton-convention, active rotations: v' = q v q*. Angles are radians unless the name
ends in `_deg`.
"""

from __future__ import annotations

import numpy as np

IDENTITY_QUAT = np.array([1.0, 0.0, 0.0, 0.0])


def quat_normalize(q) -> np.ndarray:
    """q: (..., 4) -> unit quaternion(s) with w >= 0 (one representative per rotation)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product a*b of (..., 4) quaternions: rotate by b, then by a."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_from_axis_angle(axis, angle) -> np.ndarray:
    """Rotation by `angle` (rad) about `axis` (3,), which need not be unit length."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    half = 0.5 * angle
    return np.concatenate([[np.cos(half)], np.sin(half) * axis])


def quat_from_euler_deg(euler_deg) -> np.ndarray:
    """Rotations about the world x, then y, then z axes (degrees): q = qz * qy * qx."""
    x, y, z = np.radians(np.asarray(euler_deg, dtype=float))
    qx = quat_from_axis_angle([1, 0, 0], x)
    qy = quat_from_axis_angle([0, 1, 0], y)
    qz = quat_from_axis_angle([0, 0, 1], z)
    return quat_normalize(quat_multiply(qz, quat_multiply(qy, qx)))


def quat_to_matrix(q) -> np.ndarray:
    """(..., 4) unit quaternion(s) -> (..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def quat_rotating(from_vec, to_vec) -> np.ndarray:
    """The shortest-arc rotation taking direction `from_vec` (3,) to direction `to_vec` (3,)."""
    a = np.asarray(from_vec, dtype=float)
    b = np.asarray(to_vec, dtype=float)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    cos = float(np.dot(a, b))
    if cos < -1.0 + 1e-12:  # opposite: any axis perpendicular to a will do
        perp = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(a, [0.0, 0.0, 1.0])
        return quat_from_axis_angle(perp, np.pi)
    q = np.concatenate([[1.0 + cos], np.cross(a, b)])
    return quat_normalize(q)
