"""Pseudo-inverses of small symmetric matrices by Jacobi's eigenvalue method, compiled.

The resting-contact block solve (`stages/collision/solver.py`) needs the pseudo-inverse of
each stack's contact matrix J W J^T (symmetric, positive semi-definite, rank-deficient
when contacts are redundant: the four corners of a box on a plane). `np.linalg.pinv` does
that with LAPACK's SVD in OpenBLAS, whose kernels (and so the last bits) depend on the
CPU. Here: cyclic Jacobi rotations in a fixed order (Golub & Van Loan, "Matrix
Computations", section 8.5), then A+ = sum over |lambda_i| > rcond max|lambda| of
v_i v_i^T / lambda_i, the same minimum-norm solution as the SVD's for a symmetric matrix.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.kernels.jit import kernel

MAX_SWEEPS = 60  # Jacobi converges quadratically; a 24 x 24 matrix needs ~8 sweeps


@kernel
def pinv_symmetric(A, rcond, out):
    """out[b] = the pseudo-inverse of the symmetric A[b] for every b of A (nb, m, m);
    singular values below rcond times the largest count as zero (as np.linalg.pinv)."""
    nb, m = A.shape[0], A.shape[1]
    a = np.empty((m, m))
    v = np.empty((m, m))
    for b in range(nb):
        for i in range(m):
            for j in range(m):
                a[i, j] = 0.5 * (A[b, i, j] + A[b, j, i])
                v[i, j] = 1.0 if i == j else 0.0
        for _ in range(MAX_SWEEPS):
            off = 0.0
            diag = 0.0
            for i in range(m):
                diag += a[i, i] * a[i, i]
                for j in range(i + 1, m):
                    off += a[i, j] * a[i, j]
            if off <= 1e-32 * diag or off == 0.0:
                break
            for p in range(m - 1):
                for q in range(p + 1, m):
                    apq = a[p, q]
                    if apq == 0.0:
                        continue
                    theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                    c = 1.0 / math.sqrt(t * t + 1.0)
                    s = t * c
                    for k in range(m):  # columns p, q
                        akp, akq = a[k, p], a[k, q]
                        a[k, p] = c * akp - s * akq
                        a[k, q] = s * akp + c * akq
                    for k in range(m):  # rows p, q
                        apk, aqk = a[p, k], a[q, k]
                        a[p, k] = c * apk - s * aqk
                        a[q, k] = s * apk + c * aqk
                    a[p, q] = 0.0
                    a[q, p] = 0.0
                    for k in range(m):
                        vkp, vkq = v[k, p], v[k, q]
                        v[k, p] = c * vkp - s * vkq
                        v[k, q] = s * vkp + c * vkq
        largest = 0.0
        for i in range(m):
            largest = max(largest, abs(a[i, i]))
        for i in range(m):
            for j in range(m):
                out[b, i, j] = 0.0
        if largest == 0.0:
            continue
        for e in range(m):
            lam = a[e, e]
            if abs(lam) <= rcond * largest:
                continue
            inv = 1.0 / lam
            for i in range(m):
                vi = v[i, e] * inv
                for j in range(m):
                    out[b, i, j] += vi * v[j, e]
