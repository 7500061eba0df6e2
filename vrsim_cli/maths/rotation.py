"""Rotation matrices for rigid-body integration, vectorised over a leading body axis.

Layer 0, beside `spatial` (which holds quaternion helpers for scene input). Everything
here takes and returns stacks: `R: (k, 3, 3)`, `w: (k, 3)`. Matrices are active rotations
mapping body (model) coordinates to world coordinates: `p_world = S + R p0` (slide 5.3).
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths import trig
from vrsim_cli.maths.products import matmul


def skew(w: np.ndarray) -> np.ndarray:
    """(k, 3) -> (k, 3, 3) cross-product matrices `w*` with `w* b = w x b` (slide 5.3.2):
    `(w*)_ik = eps_ijk w_j`."""
    return np.einsum("ijk,...j->...ik", _EPS, w)


def _levi_civita() -> np.ndarray:
    eps = np.zeros((3, 3, 3))
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        eps[i, j, k], eps[i, k, j] = 1.0, -1.0
    return eps


_EPS = _levi_civita()


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k, 3) x (k, 3) -> (k, 3) cross products, (a x b)_i = eps_ijk a_j b_k, in one numpy
    call (np.cross spends most of its time on axis bookkeeping for such small stacks)."""
    return np.einsum("ijk,...j,...k->...i", _EPS, a, b)


def orthonormalize(R: np.ndarray) -> np.ndarray:
    """(k, 3, 3) -> nearest rotation matrices (polar decomposition).

    With the singular value decomposition `R = U S Vt`, the orthonormal polar factor
    `U Vt` is the rotation closest to R in the Frobenius norm (Higham, *Functions of
    Matrices*, thm 8.4), so the correction removes only the drift and no rotation
    direction is preferred (unlike Gram-Schmidt, which keeps the first column exactly).
    """
    # Near a rotation (drift d = max|R^T R - E| < 1e-8, as after every step of the
    # splitting methods) one Newton-Schulz step R (3E - R^T R) / 2 gives the same polar
    # factor to O(d^2) < 1e-16 at a fraction of the cost of an SVD.
    gram = matmul(np.swapaxes(R, -1, -2), R) - _EYE
    if R.size and np.abs(gram).max() < 1e-8:
        return R - 0.5 * matmul(R, gram)
    u, _, vt = np.linalg.svd(R)
    return matmul(u, vt)


_EYE = np.eye(3)


def orthonormality_error(R: np.ndarray) -> np.ndarray:
    """(k, 3, 3) -> (k,) max |R^T R - E| over the entries."""
    eye = np.eye(3)
    return np.abs(matmul(np.swapaxes(R, -1, -2), R) - eye).max(axis=(-2, -1))


def axis_rotation(axis: int, angle: np.ndarray) -> np.ndarray:
    """(k,) angles in rad -> (k, 3, 3) rotations about coordinate axis 0, 1 or 2."""
    # Few numpy calls (this runs 5 times per body batch per step): [cos, sin] times a
    # (2, 9) table of where they go, plus the fixed 1 on the axis.
    s, c = trig.sin_cos(angle)  # not libm: the same bits on every CPU (maths/trig.py)
    cos_sin = np.stack([c, s], axis=-1)
    return (_FIXED[axis] + matmul(cos_sin, _COS_SIN[axis])).reshape(angle.shape + (3, 3))


def _axis_tables():
    fixed, cos_sin = np.zeros((3, 9)), np.zeros((3, 2, 9))
    for axis, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):
        fixed[axis, 4 * axis] = 1.0
        cos_sin[axis, 0, [4 * i, 4 * j]] = 1.0
        cos_sin[axis, 1, 3 * i + j] = -1.0
        cos_sin[axis, 1, 3 * j + i] = 1.0
    return fixed, cos_sin


_FIXED, _COS_SIN = _axis_tables()


def exp_so3(w: np.ndarray) -> np.ndarray:
    """(k, 3) rotation vectors (axis * angle, rad) -> (k, 3, 3) by Rodrigues' formula."""
    theta = np.linalg.norm(w, axis=-1)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    # Taylor series below 1e-8 rad: sin t / t = 1 - t^2/6, (1 - cos t) / t^2 = 1/2 - t^2/24.
    sin, cos = trig.sin_cos(safe)  # not libm: the same bits on every CPU
    a = np.where(small, 1.0 - theta ** 2 / 6.0, sin / safe)
    b = np.where(small, 0.5 - theta ** 2 / 24.0, (1.0 - cos) / safe ** 2)
    K = skew(w)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * matmul(K, K)


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotation matrices -> (k, 4) unit quaternions [w, x, y, z] with w >= 0.

    Shepperd's method: the entries of R give every product 4 q_i q_j; divide the row of
    the largest |q_i| (found from the diagonal) by 4 |q_i| >= 1, so there is no
    cancellation however the matrix is turned. Rows with trace > -1/2 (w^2 > 1/8, most
    of them) take the w row directly, the others pick their pivot.
    """
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    a = R[:, 2, 1] - R[:, 1, 2]  # 4 w x
    b = R[:, 0, 2] - R[:, 2, 0]  # 4 w y
    c = R[:, 1, 0] - R[:, 0, 1]  # 4 w z
    trace = m00 + m11 + m22
    four_w = 2.0 * np.sqrt(np.maximum(1.0 + trace, 0.5))
    q = np.stack([0.25 * four_w, a / four_w, b / four_w, c / four_w], -1)
    hard = trace <= -0.5
    if hard.any():
        h = np.nonzero(hard)[0]
        e = R[h, 0, 1] + R[h, 1, 0]  # 4 x y
        f = R[h, 0, 2] + R[h, 2, 0]  # 4 x z
        g = R[h, 1, 2] + R[h, 2, 1]  # 4 y z
        d = np.stack([1 + m00[h] - m11[h] - m22[h], 1 - m00[h] + m11[h] - m22[h],
                      1 - m00[h] - m11[h] + m22[h]], -1)  # 4 x^2, 4 y^2, 4 z^2
        table = np.stack([np.stack([a[h], d[:, 0], e, f], -1),
                          np.stack([b[h], e, d[:, 1], g], -1),
                          np.stack([c[h], f, g, d[:, 2]], -1)], 1)  # (k, pivot, 4)
        pick = np.argmax(d, axis=-1)
        rows = np.arange(len(h))
        q[h] = table[rows, pick] / np.sqrt(d[rows, pick])[:, None]
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[:, :1] < 0, -q, q)
