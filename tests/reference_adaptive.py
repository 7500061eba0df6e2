"""Dormand-Prince 5(4): an explicit Runge-Kutta pair with error control.

Layer 0 numerics (numpy only). Dormand & Prince, "A family of embedded Runge-Kutta
formulae", J. Comp. Appl. Math. 6 (1980); the coefficients are those of Hairer, Norsett &
Wanner, *Solving ODEs I*, table II.5.2. The 5th-order solution is propagated (local
extrapolation); the embedded 4th-order one only estimates the error.

`integrate(f, t0, t1, y0, h, tol)` advances a flat vector from t0 to exactly t1: the last
step is clipped to land on t1 (step clipping instead of dense output), so the fixed
output grid is hit exactly, and the step proposed by the controller before clipping is
returned so the next interval starts with it. Cost: 7 evaluations of f per attempted step
(the first-same-as-last reuse is not used because the caller may project y between steps).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
A = [
    [],
    [1 / 5],
    [3 / 40, 9 / 40],
    [44 / 45, -56 / 15, 32 / 9],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656],
    [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84],
]
B5 = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0])
B4 = np.array([5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100,
               1 / 40])
E = B5 - B4

SAFETY = 0.9  # aim a little below the tolerance so few steps are rejected
MIN_SHRINK, MAX_GROW = 0.2, 5.0  # bounds on the step-size ratio per step
ORDER = 5


class StepSizeUnderflow(ArithmeticError):
    """The controller needs steps below round-off: the solution is not smooth or not finite.
    `t` s: where it happened; `component`: index of the worst error component."""

    def __init__(self, t: float, component: int):
        super().__init__(f"step size underflow at t = {t:.6g} s")
        self.t, self.component = t, component


def step(f: Callable, t: float, y: np.ndarray, h: float):
    """One Dormand-Prince step: (5th-order y at t + h, error estimate vector)."""
    k = []
    for i in range(7):
        yi = y
        for j, a in enumerate(A[i]):
            if a:
                yi = yi + (h * a) * k[j]
        k.append(f(t + C[i] * h, yi))
    y5 = y + h * sum(b * kk for b, kk in zip(B5, k) if b)
    err = h * sum(e * kk for e, kk in zip(E, k) if e)
    return y5, err


def integrate(f: Callable, t0: float, t1: float, y0: np.ndarray, h: float, tol: float,
              project: Callable | None = None):
    """Advance y' = f(t, y) from t0 to t1 with local error <= tol per step (mixed absolute
    and relative, RMS norm). Returns (y1, next proposed step, accepted steps, rejected)."""
    t, y = t0, y0
    span = t1 - t0
    accepted = rejected = 0
    h = min(h, span) if h > 0 else span
    while t1 - t > 1e-14 * max(abs(t1), span):
        last = h >= t1 - t
        hh = t1 - t if last else h
        y_new, err = step(f, t, y, hh)
        scale = tol + tol * np.maximum(np.abs(y), np.abs(y_new))
        ratio = np.abs(err) / scale
        norm = float(np.sqrt(np.mean(ratio ** 2))) if ratio.size else 0.0
        if not np.isfinite(norm):
            norm = np.inf
        factor = MAX_GROW if norm == 0 else min(MAX_GROW, max(MIN_SHRINK,
                                                               SAFETY * norm ** (-1 / ORDER)))
        if norm <= 1.0:
            t = t1 if last else t + hh
            y = project(y_new) if project is not None else y_new
            accepted += 1
            # A clipped last step says little about the natural step: keep the larger.
            h = max(h, hh * factor) if last else hh * factor
        else:
            rejected += 1
            h = hh * factor
            if h < 1e-13 * max(abs(t), span):
                bad = int(np.nanargmax(np.where(np.isfinite(ratio), ratio, np.inf)))
                raise StepSizeUnderflow(t, bad)
    return y, h, accepted, rejected
