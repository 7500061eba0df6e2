"""Eigen-decomposition of symmetric 3 x 3 matrices (inertia tensors) without LAPACK.

`np.linalg.eigh` calls LAPACK in OpenBLAS, whose kernels (and so the last bits of the
principal moments and axes) depend on the CPU (tests/test_cpu_independence.py). Here:
cyclic Jacobi rotations in a fixed order (Golub & Van Loan, "Matrix Computations", 4th
ed., section 8.5.2-8.5.3; the rotation of Rutishauser's stable form), in plain Python
floats: only +, -, *, / and sqrt, which IEEE 754 rounds correctly on every CPU.

Jacobi is accurate to a few ulps of the largest eigenvalue for every eigenvalue (and to
a few ulps of each for positive definite matrices, Demmel & Veselic 1992), with
orthonormal vectors to round-off. Conventions, deterministic:
- eigenvalues ascending; equal ones keep the order of their diagonal entries (a diagonal
  matrix keeps the unit axes, e.g. the axes of a box, a sphere, the slide's cube);
- each eigenvector's sign makes its component of largest magnitude positive (the first
  such component on a tie);
- `principal_axes` then makes the frame right-handed by negating the third column.
"""

from __future__ import annotations

import math

import numpy as np

MAX_SWEEPS = 50  # a 3 x 3 converges in 4-6 sweeps (quadratic convergence)


def eigh3(matrix) -> tuple[np.ndarray, np.ndarray]:
    """(eigenvalues (3,) ascending, eigenvectors (3, 3) as columns) of the symmetric
    matrix (3, 3) (its upper and lower halves are averaged). Non-finite input gives NaN."""
    m = np.asarray(matrix, dtype=float)
    a = [[0.5 * (float(m[i, j]) + float(m[j, i])) for j in range(3)] for i in range(3)]
    if not all(math.isfinite(x) for row in a for x in row):
        return np.full(3, np.nan), np.full((3, 3), np.nan)
    v = [[1.0 if i == j else 0.0 for j in range(3)] for i in range(3)]
    for _ in range(MAX_SWEEPS):
        if a[0][1] == 0.0 and a[0][2] == 0.0 and a[1][2] == 0.0:
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            apq = a[p][q]
            if apq == 0.0:
                continue
            app, aqq = a[p][p], a[q][q]
            # negligible against both diagonal entries: zero it (Numerical Recipes' test)
            g = 100.0 * abs(apq)
            if abs(app) + g == abs(app) and abs(aqq) + g == abs(aqq):
                a[p][q] = a[q][p] = 0.0
                continue
            theta = (aqq - app) / (2.0 * apq)
            if abs(theta) > 1e150:  # theta^2 would overflow: t ~ 1 / (2 theta)
                t = 0.5 / theta
            else:
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            tau = s / (1.0 + c)
            # A' = J^T A J with J the rotation in the (p, q) plane: a'_pq = 0
            a[p][p] = app - t * apq
            a[q][q] = aqq + t * apq
            a[p][q] = a[q][p] = 0.0
            r = 3 - p - q  # the third index
            arp, arq = a[r][p], a[r][q]
            a[r][p] = a[p][r] = arp - s * (arq + tau * arp)
            a[r][q] = a[q][r] = arq + s * (arp - tau * arq)
            for k in range(3):
                vkp, vkq = v[k][p], v[k][q]
                v[k][p] = vkp - s * (vkq + tau * vkp)
                v[k][q] = vkq + s * (vkp - tau * vkq)
    order = sorted(range(3), key=lambda i: (a[i][i], i))  # stable: ties keep their order
    values = np.array([a[i][i] for i in order])
    vectors = np.array([[v[k][i] for i in order] for k in range(3)])
    for j in range(3):
        col = vectors[:, j]
        big = int(np.argmax(np.abs(col)))  # the first of the largest
        if col[big] < 0.0:
            vectors[:, j] = -col
    return values, vectors


def det3(m) -> float:
    """The determinant of a 3 x 3 matrix, written out (np.linalg.det is LAPACK)."""
    m = np.asarray(m, dtype=float)
    return float(m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
                 - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
                 + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]))


def principal_axes(inertia) -> tuple[np.ndarray, np.ndarray]:
    """(moments (3,) ascending, axes (3, 3) as columns, right-handed) of a symmetric
    inertia tensor (3, 3): `eigh3` with the third axis negated when needed."""
    moments, axes = eigh3(inertia)
    if det3(axes) < 0.0:
        axes[:, 2] = -axes[:, 2]
    return moments, axes
