"""sin and cos with the same bits on every CPU.

glibc's libm (which numpy's float64 sin and cos call on this platform, and Python's
`math`) picks an FMA or a plain variant by CPU; the two differ in the last bit for
~0.07 % of arguments (tests/test_cpu_independence.py), which changed the launch
directions of the fountain's particles. These use only +, -, * and /, which IEEE 754
rounds correctly everywhere (numpy does not contract them into FMAs):

- reduction x = k pi/2 + (r + tail), |r| <= pi/4, as fdlibm's __ieee754_rem_pio2 for
  medium arguments: pi/2 in three parts of 33 bits and their tails, a further round while
  the last cancelled (k pi/2_1 is exact for |k| < 2^20, so for |x| < ~1.6e6 rad; beyond,
  the result loses accuracy but stays deterministic);
- the minimax polynomials of fdlibm's __kernel_sin and __kernel_cos (Sun Microsystems,
  1993) on [-pi/4, pi/4] with the tail's correction, error < 1 ulp of the result.
Accuracy: within 1 ulp of libm over the tested range (tests/test_trig.py).

Every sine and cosine on the simulation path goes through here (the kinematic drive,
keyframe slerps, 2D angle tracks: issue 53 found the car's drive, numpy's sin of the
heading, differing in the last bit from t = 3.3 s without FMA).
"""

from __future__ import annotations

import numpy as np

_TWO_OVER_PI = 6.36619772367581382433e-01
# pi/2 in parts of 33 bits (k * part is exact for |k| < 2^20), each with the tail of pi/2
# beyond it: fdlibm's __ieee754_rem_pio2 (Sun Microsystems, 1993)
_PIO2_1 = 1.57079632673412561417e+00  # 0x3FF921FB, 0x54400000
_PIO2_1T = 6.07710050650619224932e-11  # pi/2 - _PIO2_1
_PIO2_2 = 6.07710050630396597660e-11  # 0x3DD0B461, 0x1A600000
_PIO2_2T = 2.02226624879595063154e-21  # pi/2 - _PIO2_1 - _PIO2_2
_PIO2_3 = 2.02226624871116645580e-21  # 0x3BA3198A, 0x2E000000
_PIO2_3T = 8.47842766036889956997e-32  # pi/2 - _PIO2_1 - _PIO2_2 - _PIO2_3
_S = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
      2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_C = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
      -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)


def _reduce(x: np.ndarray):
    """x = k pi/2 + (r + tail), |r| <= ~pi/4, as fdlibm: a round per part of pi/2 while
    the last one cancelled more than its bits (16, then 49 binary orders), so r + tail
    holds x's distance to k pi/2 to ~2^-150: results near a zero (cos(pi/2) ~ 6e-17)
    keep their ulps."""
    k = np.rint(x * _TWO_OVER_PI)
    ex = np.frexp(x)[1]
    r = x - k * _PIO2_1  # exact
    w = k * _PIO2_1T
    again = ex - np.frexp(r - w)[1] > 16
    t = r
    w2 = k * _PIO2_2
    r2 = t - w2
    w2 = k * _PIO2_2T - ((t - r2) - w2)
    third = again & (ex - np.frexp(r2 - w2)[1] > 49)
    t = r2
    w3 = k * _PIO2_3
    r3 = t - w3
    w3 = k * _PIO2_3T - ((t - r3) - w3)
    r = np.where(third, r3, np.where(again, r2, r))
    w = np.where(third, w3, np.where(again, w2, w))
    head = r - w
    return head, (r - head) - w, k - 4.0 * np.floor(0.25 * k)  # k mod 4, exact for any k


def _kernel_sin(r: np.ndarray, y: np.ndarray) -> np.ndarray:
    z = r * r
    p = _S[1] + z * (_S[2] + z * (_S[3] + z * (_S[4] + z * _S[5])))
    v = z * r
    return r - ((z * (0.5 * y - v * p) - y) - v * _S[0])


def _kernel_cos(r: np.ndarray, y: np.ndarray) -> np.ndarray:
    z = r * r
    p = z * (_C[0] + z * (_C[1] + z * (_C[2] + z * (_C[3] + z * (_C[4] + z * _C[5])))))
    hz = 0.5 * z
    w = 1.0 - hz
    return w + (((1.0 - w) - hz) + (z * p - r * y))


def sin_cos(x) -> tuple[np.ndarray, np.ndarray]:
    """(sin x, cos x) for an array (or scalar) x in rad, the same bits on every CPU.
    Non-finite x gives NaN."""
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore"):
        finite = np.isfinite(x)
        r, tail, quadrant = _reduce(np.where(finite, x, 0.0))
        s, c = _kernel_sin(r, tail), _kernel_cos(r, tail)
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


# fdlibm's s_atan.c and e_atan2.c (Sun Microsystems, 1993): atan(0.5), atan(1),
# atan(1.5) and pi/2 in a high and a low part, and the odd polynomial on |t| < 7/16
_ATAN_HI = np.array([4.63647609000806093515e-01, 7.85398163397448278999e-01,
                     9.82793723247329054082e-01, 1.57079632679489655800e+00])
_ATAN_LO = np.array([2.26987774529616870924e-17, 3.06161699786838301793e-17,
                     1.39033110312309984516e-17, 6.12323399573676603587e-17])
_AT = (3.33333333333329318027e-01, -1.99999999998764832476e-01, 1.42857142725034663711e-01,
       -1.11111104054623557880e-01, 9.09088713343650656196e-02, -7.69187620504482999495e-02,
       6.66107313738753120669e-02, -5.83357013379057348645e-02, 4.97687799461593236017e-02,
       -3.65315727442169155270e-02, 1.62858201153657823623e-02)
_PI = 3.1415926535897931160e+00
_PI_LO = 1.2246467991473531772e-16  # pi - _PI


def _atan_abs(a: np.ndarray) -> np.ndarray:
    """atan a for a >= 0 (finite or inf): fdlibm's reduction to |t| < 7/16 by the
    arguments 0.5, 1, 1.5 and inf, then its polynomial."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ident = np.select([a < 0.4375, a < 0.6875, a < 1.1875, a < 2.4375], [-1, 0, 1, 2], 3)
        t = np.select([ident == -1, ident == 0, ident == 1, ident == 2],
                      [a, (2.0 * a - 1.0) / (2.0 + a), (a - 1.0) / (a + 1.0),
                       (a - 1.5) / (1.0 + 1.5 * a)], -1.0 / a)
        z = t * t
        w = z * z
        s1 = z * (_AT[0] + w * (_AT[2] + w * (_AT[4] + w * (_AT[6] + w * (_AT[8] + w * _AT[10])))))
        s2 = w * (_AT[1] + w * (_AT[3] + w * (_AT[5] + w * (_AT[7] + w * _AT[9]))))
        i = np.maximum(ident, 0)
        reduced = _ATAN_HI[i] - ((t * (s1 + s2) - _ATAN_LO[i]) - t)
        out = np.where(ident < 0, a - a * (s1 + s2), reduced)
    out = np.where(a < 7.450580596923828e-09, a, out)  # 2^-27: atan a rounds to a
    return np.where(a >= 7.378697629483821e+19, _ATAN_HI[3] + _ATAN_LO[3], out)  # 2^66


def atan2(y, x):
    """atan2(y, x) in rad, the same bits on every CPU: fdlibm's e_atan2.c for finite and
    infinite arguments (zeros signed as libm's), NaN for NaN. Within 2 ulp of libm
    (tests/test_trig.py). A float for floats."""
    y_, x_ = np.broadcast_arrays(np.asarray(y, dtype=float), np.asarray(x, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
        ratio = np.abs(y_ / x_)
        z = _atan_abs(np.where(np.isnan(ratio), 0.0, ratio))
        left = np.signbit(x_)
        out = np.where(left, _PI - (z - _PI_LO), z)  # x < 0: pi - atan |y/x|
        # exponents as fdlibm reads them: the biased field, 0 (frexp's -1021) for subnormals
        ey, ex = np.maximum(np.frexp(y_)[1], -1021), np.maximum(np.frexp(x_)[1], -1021)
        # fdlibm's shortcuts, which the division's over- and underflow would otherwise
        # decide: |y/x| > 2^60 (or y infinite, or x zero) is pi/2 on either side; x < 0
        # and |y/x| < 2^-60 is pi
        out = np.where(left & (ey - ex < -60), _PI, out)
        vertical = ((ey - ex > 60) | np.isinf(y_)) & np.isfinite(x_)
        out = np.where(vertical, _ATAN_HI[3] + 0.5 * _PI_LO, out)
        out = np.where(np.isinf(x_) & np.isfinite(y_), np.where(left, _PI, 0.0), out)
        out = np.where(np.isinf(x_) & np.isinf(y_), np.where(left, 0.75 * _PI, 0.25 * _PI),
                       out)
        out = np.where(x_ == 0.0, _ATAN_HI[3] + _ATAN_LO[3], out)
        out = np.where(y_ == 0.0, np.where(left, _PI, 0.0), out)  # atan2(+-0, -x) = +-pi
        out = np.copysign(out, y_)
        out = np.where(np.isnan(x_) | np.isnan(y_), np.nan, out)
    return float(out) if out.ndim == 0 else out


def acos(x):
    """acos x in rad for x in [-1, 1] (NaN outside), the same bits on every CPU:
    atan2(sqrt((1 - x)(1 + x)), x), within 2 ulp of libm (tests/test_trig.py)."""
    x = np.asarray(x, dtype=float)
    with np.errstate(invalid="ignore"):
        out = atan2(np.sqrt((1.0 - x) * (1.0 + x)), x)
    out = np.where(np.abs(x) <= 1.0, out, np.nan)
    return float(out) if out.ndim == 0 else out
