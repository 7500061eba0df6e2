"""Small-vector algebra for kernels, written out by components.

A 3-vector is a tuple (x, y, z), a 3x3 matrix a row-major 9-tuple, a quaternion a tuple
(w, x, y, z). numba keeps such tuples in registers (no allocation), and writing every
product out fixes the order of operations: the same bits on every CPU, no BLAS, no SIMD
library whose rounding depends on the machine. `load*`/`store*` move them in and out of
the state's arrays.
"""

from __future__ import annotations

import math

from vrsim_cli.kernels.jit import kernel
from vrsim_cli.kernels.trig import sin_cos


@kernel
def load3(a, i):
    return (a[i, 0], a[i, 1], a[i, 2])


@kernel
def store3(a, i, v):
    a[i, 0] = v[0]
    a[i, 1] = v[1]
    a[i, 2] = v[2]


@kernel
def load4(a, i):
    return (a[i, 0], a[i, 1], a[i, 2], a[i, 3])


@kernel
def store4(a, i, q):
    a[i, 0] = q[0]
    a[i, 1] = q[1]
    a[i, 2] = q[2]
    a[i, 3] = q[3]


@kernel
def load33(a, i):
    return (a[i, 0, 0], a[i, 0, 1], a[i, 0, 2], a[i, 1, 0], a[i, 1, 1], a[i, 1, 2],
            a[i, 2, 0], a[i, 2, 1], a[i, 2, 2])


@kernel
def store33(a, i, m):
    a[i, 0, 0] = m[0]
    a[i, 0, 1] = m[1]
    a[i, 0, 2] = m[2]
    a[i, 1, 0] = m[3]
    a[i, 1, 1] = m[4]
    a[i, 1, 2] = m[5]
    a[i, 2, 0] = m[6]
    a[i, 2, 1] = m[7]
    a[i, 2, 2] = m[8]


@kernel
def add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


@kernel
def sub(a, b):
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


@kernel
def scale(s, a):
    return (s * a[0], s * a[1], s * a[2])


@kernel
def axpy(s, a, b):
    """s a + b."""
    return (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2])


@kernel
def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def norm(a):
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


@kernel
def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@kernel
def matvec(m, v):
    """M v."""
    return (m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
            m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
            m[6] * v[0] + m[7] * v[1] + m[8] * v[2])


@kernel
def mattvec(m, v):
    """M^T v."""
    return (m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
            m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
            m[2] * v[0] + m[5] * v[1] + m[8] * v[2])


@kernel
def matmul(a, b):
    """A B."""
    return (a[0] * b[0] + a[1] * b[3] + a[2] * b[6],
            a[0] * b[1] + a[1] * b[4] + a[2] * b[7],
            a[0] * b[2] + a[1] * b[5] + a[2] * b[8],
            a[3] * b[0] + a[4] * b[3] + a[5] * b[6],
            a[3] * b[1] + a[4] * b[4] + a[5] * b[7],
            a[3] * b[2] + a[4] * b[5] + a[5] * b[8],
            a[6] * b[0] + a[7] * b[3] + a[8] * b[6],
            a[6] * b[1] + a[7] * b[4] + a[8] * b[7],
            a[6] * b[2] + a[7] * b[5] + a[8] * b[8])


@kernel
def transpose(m):
    return (m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8])


@kernel
def mat_add(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5],
            a[6] + b[6], a[7] + b[7], a[8] + b[8])


@kernel
def mat_axpy(s, a, b):
    """s A + B."""
    return (s * a[0] + b[0], s * a[1] + b[1], s * a[2] + b[2], s * a[3] + b[3],
            s * a[4] + b[4], s * a[5] + b[5], s * a[6] + b[6], s * a[7] + b[7],
            s * a[8] + b[8])


@kernel
def skew_mul(w, m):
    """[w]x M: the columns of M crossed with w."""
    return (w[1] * m[6] - w[2] * m[3], w[1] * m[7] - w[2] * m[4], w[1] * m[8] - w[2] * m[5],
            w[2] * m[0] - w[0] * m[6], w[2] * m[1] - w[0] * m[7], w[2] * m[2] - w[0] * m[8],
            w[0] * m[3] - w[1] * m[0], w[0] * m[4] - w[1] * m[1], w[0] * m[5] - w[1] * m[2])


@kernel
def sandwich(r, m):
    """R M R^T (a body-frame tensor in world axes)."""
    return matmul(matmul(r, m), transpose(r))


@kernel
def solve3(m, b):
    """M^-1 b by Cramer's rule (M need not be orthonormal; NaN when singular)."""
    c0 = m[4] * m[8] - m[5] * m[7]
    c1 = m[5] * m[6] - m[3] * m[8]
    c2 = m[3] * m[7] - m[4] * m[6]
    det = m[0] * c0 + m[1] * c1 + m[2] * c2
    x = (b[0] * c0 + b[1] * (m[2] * m[7] - m[1] * m[8]) + b[2] * (m[1] * m[5] - m[2] * m[4]))
    y = (b[0] * c1 + b[1] * (m[0] * m[8] - m[2] * m[6]) + b[2] * (m[2] * m[3] - m[0] * m[5]))
    z = (b[0] * c2 + b[1] * (m[1] * m[6] - m[0] * m[7]) + b[2] * (m[0] * m[4] - m[1] * m[3]))
    return (x / det, y / det, z / det)


@kernel
def orthonormalize(r):
    """The polar factor of R (the rotation nearest to R in the Frobenius norm; Higham,
    Functions of Matrices, thm 8.4), for det R > 0. Near a rotation (drift d = max|R^T R
    - E| < 1e-8, as after every step of the splitting methods) one Newton-Schulz step
    R - R (R^T R - E) / 2 is exact to O(d^2); farther away (the slide's explicit step)
    Newton's iteration R <- (R + R^-T) / 2 first brings it there, quadratically."""
    for _ in range(60):
        g = matmul(transpose(r), r)
        g = (g[0] - 1.0, g[1], g[2], g[3], g[4] - 1.0, g[5], g[6], g[7], g[8] - 1.0)
        drift = 0.0
        for i in range(9):
            drift = max(drift, abs(g[i]))
        if drift < 1e-8:
            return mat_axpy(-0.5, matmul(r, g), r)
        r = mat_axpy(0.5, r, scale9(0.5, inverse_transpose(r)))
    return r


@kernel
def scale9(s, m):
    return (s * m[0], s * m[1], s * m[2], s * m[3], s * m[4], s * m[5], s * m[6], s * m[7],
            s * m[8])


@kernel
def inverse_transpose(m):
    """M^-T = cof(M) / det M."""
    c00 = m[4] * m[8] - m[5] * m[7]
    c01 = m[5] * m[6] - m[3] * m[8]
    c02 = m[3] * m[7] - m[4] * m[6]
    c10 = m[2] * m[7] - m[1] * m[8]
    c11 = m[0] * m[8] - m[2] * m[6]
    c12 = m[1] * m[6] - m[0] * m[7]
    c20 = m[1] * m[5] - m[2] * m[4]
    c21 = m[2] * m[3] - m[0] * m[5]
    c22 = m[0] * m[4] - m[1] * m[3]
    inv = 1.0 / (m[0] * c00 + m[1] * c01 + m[2] * c02)
    return (inv * c00, inv * c01, inv * c02, inv * c10, inv * c11, inv * c12, inv * c20,
            inv * c21, inv * c22)


@kernel
def axis_rotation(axis, angle):
    """The rotation by `angle` rad about coordinate axis 0, 1 or 2."""
    s, c = sin_cos(angle)  # not libm: the same bits on every CPU (kernels/trig.py)
    if axis == 0:
        return (1.0, 0.0, 0.0, 0.0, c, -s, 0.0, s, c)
    if axis == 1:
        return (c, 0.0, s, 0.0, 1.0, 0.0, -s, 0.0, c)
    return (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)


@kernel
def exp_so3(w):
    """exp([w]x) by Rodrigues' formula (Taylor series below 1e-8 rad)."""
    theta = norm(w)
    if theta < 1e-8:
        a = 1.0 - theta * theta / 6.0
        b = 0.5 - theta * theta / 24.0
    else:
        sin, cos = sin_cos(theta)
        a = sin / theta
        b = (1.0 - cos) / (theta * theta)
    x, y, z = w
    return (1.0 - b * (y * y + z * z), -a * z + b * x * y, a * y + b * x * z,
            a * z + b * x * y, 1.0 - b * (x * x + z * z), -a * x + b * y * z,
            -a * y + b * x * z, a * x + b * y * z, 1.0 - b * (x * x + y * y))


@kernel
def quat_mul(p, q):
    return (p[0] * q[0] - p[1] * q[1] - p[2] * q[2] - p[3] * q[3],
            p[0] * q[1] + p[1] * q[0] + p[2] * q[3] - p[3] * q[2],
            p[0] * q[2] - p[1] * q[3] + p[2] * q[0] + p[3] * q[1],
            p[0] * q[3] + p[1] * q[2] - p[2] * q[1] + p[3] * q[0])


@kernel
def quat_normalize(q):
    s = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (s * q[0], s * q[1], s * q[2], s * q[3])


@kernel
def quat_to_matrix(q):
    """R of a unit quaternion [w, x, y, z]."""
    w, x, y, z = q
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))


@kernel
def quat_from_matrix(m):
    """The unit quaternion (w >= 0) of a rotation matrix, Shepperd's method: divide by the
    largest of 4|w|, 4|x|, 4|y|, 4|z| (read off the diagonal), so nothing cancels."""
    m00, m11, m22 = m[0], m[4], m[8]
    a = m[7] - m[5]  # 4 w x
    b = m[2] - m[6]  # 4 w y
    c = m[3] - m[1]  # 4 w z
    trace = m00 + m11 + m22
    if trace > -0.5:
        four_w = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * four_w, a / four_w, b / four_w, c / four_w)
    else:
        e = m[1] + m[3]  # 4 x y
        f = m[2] + m[6]  # 4 x z
        g = m[5] + m[7]  # 4 y z
        dx = 1.0 + m00 - m11 - m22
        dy = 1.0 - m00 + m11 - m22
        dz = 1.0 - m00 - m11 + m22
        if dx >= dy and dx >= dz:
            s = math.sqrt(dx)
            q = (a / s, dx / s, e / s, f / s)
        elif dy >= dz:
            s = math.sqrt(dy)
            q = (b / s, e / s, dy / s, g / s)
        else:
            s = math.sqrt(dz)
            q = (c / s, f / s, g / s, dz / s)
    q = quat_normalize(q)
    if q[0] < 0.0:
        return (-q[0], -q[1], -q[2], -q[3])
    return q
