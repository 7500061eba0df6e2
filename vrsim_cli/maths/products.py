"""Matrix and vector products that never go through BLAS.

numpy's `@`, `np.dot` and `np.matmul` call the BLAS library for float64, and OpenBLAS picks
its kernels by CPU (with or without FMA, in another summation order): the same scene then
gives other bits on another machine (tests/test_cpu_independence.py). `np.einsum` without
`optimize` uses numpy's own loops, which add in a fixed order: every product on the
simulation path goes through here.
"""

from __future__ import annotations

import numpy as np


def matmul(a, b) -> np.ndarray:
    """`a @ b` with numpy's broadcasting rules for stacks, without BLAS."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if b.ndim == 1:
        return np.einsum("...ij,j->...i", a, b) if a.ndim > 1 else np.einsum("i,i->", a, b)
    if a.ndim == 1:
        return np.einsum("i,...ij->...j", a, b)
    return np.einsum("...ij,...jk->...ik", a, b)


def dot(a, b) -> float:
    """The dot product of two vectors, as a Python float, without BLAS."""
    return float(np.einsum("i,i->", np.asarray(a, dtype=float), np.asarray(b, dtype=float)))


def inv3(m) -> np.ndarray:
    """Inverses of (..., 3, 3) matrices by their adjugate (cofactors / determinant): LAPACK's
    `np.linalg.inv` is OpenBLAS too. Singular matrices give inf/nan, as callers expect of
    matrices they know are invertible (inertia tensors of bodies with mass)."""
    m = np.asarray(m, dtype=float)
    a, b, c = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    d, e, f = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    g, h, i = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    cof = np.stack([np.stack([e * i - f * h, c * h - b * i, b * f - c * e], -1),
                    np.stack([f * g - d * i, a * i - c * g, c * d - a * f], -1),
                    np.stack([d * h - e * g, b * g - a * h, a * e - b * d], -1)], -2)
    det = a * cof[..., 0, 0] + b * cof[..., 1, 0] + c * cof[..., 2, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        return cof / det[..., None, None]


def norm(a) -> float:
    """The Euclidean length of a vector, without BLAS (`np.linalg.norm` without `axis` is
    sqrt(a.dot(a)), a BLAS call)."""
    a = np.asarray(a, dtype=float).ravel()
    return float(np.sqrt(np.einsum("i,i->", a, a)))
