"""Rotations: unit quaternions [w, x, y, z], rotation matrices and Euler angles.

Layer 0. Vectorised over a leading axis where that is useful. Quaternions are
Hamilton-convention, active rotations: v' = q v q*. Angles are radians unless the name
ends in `_deg`.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths import trig
from vrsim_cli.maths.products import dot, matmul, norm

IDENTITY_QUAT = np.array([1.0, 0.0, 0.0, 0.0])


def unit(v) -> np.ndarray:
    """v / |v| for (..., n) vectors, scaled by the largest component first so that tiny
    (1e-320) and huge (1e300) inputs neither underflow nor overflow. v must not be zero."""
    v = np.asarray(v, dtype=float)
    v = v / np.abs(v).max(axis=-1, keepdims=True)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def quat_normalize(q) -> np.ndarray:
    """q: (..., 4) -> unit quaternion(s) with w >= 0 (one representative per rotation)."""
    q = unit(q)
    return np.where(q[..., :1] < 0, -q, q)


def quat_multiply(a, b) -> np.ndarray:
    """Hamilton product a*b of (..., 4) quaternions: rotate by b, then by a."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    # written into one array, not stacked: the located loop calls this for one or a few
    # quaternions per pair and step, where np.stack's bookkeeping was most of the cost
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = aw * bw - ax * bx - ay * by - az * bz
    out[..., 1] = aw * bx + ax * bw + ay * bz - az * by
    out[..., 2] = aw * by - ax * bz + ay * bw + az * bx
    out[..., 3] = aw * bz + ax * by - ay * bx + az * bw
    return out


def quat_from_axis_angle(axis, angle) -> np.ndarray:
    """Rotation by `angle` (rad) about `axis` (3,), which need not be unit length."""
    axis = unit(axis)
    s, c = trig.sin_cos(0.5 * angle)  # not libm: the same bits on every CPU
    return np.concatenate([[c], s * axis])


def quat_from_euler_deg(euler_deg) -> np.ndarray:
    """Rotations about the world x, then y, then z axes (degrees): q = qz * qy * qx."""
    x, y, z = np.radians(np.asarray(euler_deg, dtype=float))
    qx = quat_from_axis_angle([1, 0, 0], x)
    qy = quat_from_axis_angle([0, 1, 0], y)
    qz = quat_from_axis_angle([0, 0, 1], z)
    return quat_normalize(quat_multiply(qz, quat_multiply(qy, qx)))


def quat_to_matrix(q) -> np.ndarray:
    """(..., 4) unit quaternion(s) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=float)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(q.shape[:-1] + (3, 3))  # filled in place, not stacked (quat_multiply)
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def quat_rotating(from_vec, to_vec) -> np.ndarray:
    """The shortest-arc rotation taking direction `from_vec` (3,) to direction `to_vec` (3,)."""
    a = unit(from_vec)
    b = unit(to_vec)
    cos = dot(a, b)
    if cos < -1.0 + 1e-12:  # opposite: any axis perpendicular to a will do
        perp = np.cross(a, [1.0, 0.0, 0.0])
        if norm(perp) < 1e-6:
            perp = np.cross(a, [0.0, 0.0, 1.0])
        return quat_from_axis_angle(perp, np.pi)
    q = np.concatenate([[1.0 + cos], np.cross(a, b)])
    return quat_normalize(q)


def quat_conjugate(q) -> np.ndarray:
    """Inverse of unit quaternion(s) (..., 4)."""
    q = np.asarray(q, dtype=float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_rotate(q, v) -> np.ndarray:
    """Rotate vector(s) v (..., 3) by unit quaternion(s) q (..., 4)."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    if q.ndim == 1 and v.ndim == 1:  # one vector: np.cross costs ~20 us, this ~2 us
        w, x, y, z = q.tolist()
        vx, vy, vz = v.tolist()
        tx, ty, tz = 2.0 * (y * vz - z * vy), 2.0 * (z * vx - x * vz), 2.0 * (x * vy - y * vx)
        return np.array([vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz),
                         vz + w * tz + (x * ty - y * tx)])
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_from_matrix(m) -> np.ndarray:
    """(3, 3) rotation matrix -> unit quaternion [w, x, y, z] (Shepperd's method: divide by
    the largest of the four candidate terms, so no branch loses precision)."""
    m = np.asarray(m, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif k == 1:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif k == 2:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return quat_normalize(q)


def look_rotation(forward, up, fallback_quat=None) -> np.ndarray:
    """Orientation of a camera that looks along `forward` with `up` as up (OpenGL and X3D
    convention: the camera looks along its local -z, local +y is up, local +x is right).

    When forward is parallel to up the view has no defined roll; then `fallback_quat`'s
    right axis is kept (or world x if there is none).
    """
    f = np.asarray(forward, dtype=float)
    f = f / norm(f)
    right = np.cross(f, np.asarray(up, dtype=float))
    if norm(right) < 1e-9:
        right = quat_rotate(fallback_quat, [1.0, 0.0, 0.0]) if fallback_quat is not None \
            else np.array([1.0, 0.0, 0.0])
        right = right - dot(right, f) * f
    right = right / norm(right)
    true_up = np.cross(right, f)
    return quat_from_matrix(np.column_stack([right, true_up, -f]))


def rotate_about_y(v, angle) -> np.ndarray:
    """R_y(angle) v for a 3-vector. In the slides' (z, x) notation:
    z' = z cos(a) - x sin(a), x' = x cos(a) + z sin(a) (right-handed, y up)."""
    s, c = trig.sin_cos(angle)
    x, y, z = v
    return np.array([x * c + z * s, y, z * c - x * s])


def quat_slerp(a, b, s: float) -> np.ndarray:
    """Shortest-arc spherical interpolation between unit quaternions a (s=0) and b (s=1)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    cos = dot(a, b)
    if cos < 0.0:
        b, cos = -b, -cos
    if cos > 1.0 - 1e-12:
        return quat_normalize(a + s * (b - a))
    theta = trig.acos(min(cos, 1.0))
    return (trig.sin((1.0 - s) * theta) * a + trig.sin(s * theta) * b) / trig.sin(theta)


# Quaternion products as 4x4 matrices, for batches of small arrays where numpy's per-call
# cost dominates: a * b = quat_left_matrix(a) @ b = quat_right_matrix(b) @ a.
_LEFT_IDX = np.array([[0, 1, 2, 3], [1, 0, 3, 2], [2, 3, 0, 1], [3, 2, 1, 0]])
_LEFT_SIGN = np.array([[1, -1, -1, -1], [1, 1, -1, 1], [1, 1, 1, -1], [1, -1, 1, 1]], float)
_RIGHT_SIGN = np.array([[1, -1, -1, -1], [1, 1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1]], float)


def quat_left_matrix(q) -> np.ndarray:
    """(..., 4) -> (..., 4, 4) matrix L(q) with L(q) p = q * p (Hamilton product)."""
    return np.asarray(q, dtype=float)[..., _LEFT_IDX] * _LEFT_SIGN


def quat_right_matrix(q) -> np.ndarray:
    """(..., 4) -> (..., 4, 4) matrix R(q) with R(q) p = p * q (Hamilton product)."""
    return np.asarray(q, dtype=float)[..., _LEFT_IDX] * _RIGHT_SIGN


def quat_rotation_matrices(q) -> tuple:
    """(..., 4) unit quaternions -> (L(q) (..., 4, 4), rotation matrices (..., 3, 3)):
    q v q* = L(q) R(q*) v, whose lower-right 3x3 block is the rotation."""
    q = np.asarray(q, dtype=float)
    left = quat_left_matrix(q)
    conj = q * np.array([1.0, -1.0, -1.0, -1.0])
    return left, matmul(left, quat_right_matrix(conj))[..., 1:, 1:]
