"""sin and cos with the same bits on every CPU.

glibc's libm (which numpy's float64 sin and cos call on this platform, and Python's
`math`) picks an FMA or a plain variant by CPU; the two differ in the last bit for
~0.07 % of arguments (tests/test_cpu_independence.py), which changed the launch
directions of the fountain's particles. These use only +, -, * and /, which IEEE 754
rounds correctly everywhere (numpy does not contract them into FMAs):

- reduction x = k pi/2 + r, |r| <= pi/4, by Cody & Waite with pi/2 in three parts of 33
  bits (k pi/2_1 is exact for |k| < 2^20, so for |x| < ~1.6e6 rad; beyond, the result
  loses accuracy gracefully but stays deterministic);
- the minimax polynomials of fdlibm's __kernel_sin and __kernel_cos (Sun Microsystems,
  1993) on [-pi/4, pi/4], error < 1 ulp of the result.
Accuracy: within 1 ulp of libm over the tested range (tests/test_trig.py).

Every sine and cosine on the simulation path goes through here (the kinematic drive,
keyframe slerps, 2D angle tracks: issue 53 found the car's drive, numpy's sin of the
heading, differing in the last bit from t = 3.3 s without FMA).
"""

from __future__ import annotations

import numpy as np

_TWO_OVER_PI = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e+00  # the first 33 bits of pi/2
_PIO2_2 = 6.07710050630396597660e-11  # the next 33 bits
_PIO2_3 = 2.02226624871116645580e-21  # the next 33 bits
_S = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
      2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_C = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
      -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)


def _reduce(x: np.ndarray):
    k = np.rint(x * _TWO_OVER_PI)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3
    return r, k.astype(np.int64) & 3


def _kernel_sin(r: np.ndarray) -> np.ndarray:
    z = r * r
    p = _S[1] + z * (_S[2] + z * (_S[3] + z * (_S[4] + z * _S[5])))
    return r + (r * z) * (_S[0] + z * p)


def _kernel_cos(r: np.ndarray) -> np.ndarray:
    z = r * r
    p = z * (_C[0] + z * (_C[1] + z * (_C[2] + z * (_C[3] + z * (_C[4] + z * _C[5])))))
    hz = 0.5 * z
    w = 1.0 - hz
    return w + (((1.0 - w) - hz) + z * p)


def sin_cos(x) -> tuple[np.ndarray, np.ndarray]:
    """(sin x, cos x) for an array (or scalar) x in rad, the same bits on every CPU.
    Non-finite x gives NaN."""
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(x)
        r, quadrant = _reduce(np.where(finite, x, 0.0))
    s, c = _kernel_sin(r), _kernel_cos(r)
    sin = np.select([quadrant == 0, quadrant == 1, quadrant == 2], [s, c, -s], -c)
    cos = np.select([quadrant == 0, quadrant == 1, quadrant == 2], [c, -s, -c], s)
    sin = np.where(x == 0.0, x, sin)  # sin(-0) = -0
    return np.where(finite, sin, np.nan), np.where(finite, cos, np.nan)


def sin(x):
    """sin x (rad), the same bits on every CPU (a float for a float)."""
    out = sin_cos(x)[0]
    return float(out) if np.ndim(x) == 0 else out


def cos(x):
    """cos x (rad), the same bits on every CPU (a float for a float)."""
    out = sin_cos(x)[1]
    return float(out) if np.ndim(x) == 0 else out


def sin_over_x(x):
    """sin(x) / x (1 at x = 0), the same bits on every CPU: numpy's `sinc(x / pi)`
    without libm (an array for an array)."""
    x = np.asarray(x, dtype=float)
    s = sin_cos(x)[0]
    zero = x == 0.0
    out = np.where(zero, 1.0, s / np.where(zero, 1.0, x))
    return float(out) if out.ndim == 0 else out
