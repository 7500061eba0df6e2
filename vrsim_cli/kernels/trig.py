"""sin, cos, asin and x^(-1/5) for kernels with the same bits on every CPU.

numba lowers `math.sin`, `math.asin`, `math.log` and `**` to libm calls, and glibc's libm
picks an FMA or a plain variant by CPU: the two differ in the last bit for ~0.07 % of
arguments (maths/trig.py, tests/test_cpu_independence.py). These use only +, -, *, / and
sqrt, which IEEE 754 rounds correctly everywhere (numba does not contract them into
FMAs without fastmath, which the kernels never use):

- `sin_cos`: maths/trig.py's algorithm written for scalars (fdlibm's reduction by parts
  of pi/2, its __kernel_sin/__kernel_cos), in the same order of operations: the same bits as
  `maths.trig.sin_cos` (tests/test_trig.py);
- `asin`: fdlibm's e_asin.c (Sun Microsystems, 1993), with the high part of sqrt(z)
  split off by Veltkamp's product (26 bits, so f * f is exact) instead of clearing its
  low word: within 1 ulp of libm;
- `inv_fifth_root`: x^(-1/5) by Newton's method from a power-of-two start, for step
  size control, where only determinism and ~1e-15 relative matter.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.kernels.jit import kernel

_TWO_OVER_PI = 6.36619772367581382433e-01
_PIO2_1 = 1.57079632673412561417e+00  # pi/2 in parts of 33 bits and their tails
_PIO2_1T = 6.07710050650619224932e-11  # (maths/trig.py)
_PIO2_2 = 6.07710050630396597660e-11
_PIO2_2T = 2.02226624879595063154e-21
_PIO2_3 = 2.02226624871116645580e-21
_PIO2_3T = 8.47842766036889956997e-32
_S0, _S1, _S2, _S3, _S4, _S5 = (
    -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
    2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_C0, _C1, _C2, _C3, _C4, _C5 = (
    4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
    -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)


@kernel
def sin_cos(x):
    """(sin x, cos x), x in rad; NaN for non-finite x (maths.trig.sin_cos)."""
    if not math.isfinite(x):
        return math.nan, math.nan
    k = np.rint(x * _TWO_OVER_PI)
    ex = math.frexp(x)[1]
    r = x - k * _PIO2_1  # exact
    w = k * _PIO2_1T
    if ex - math.frexp(r - w)[1] > 16:  # cancelled: a second round
        t = r
        w = k * _PIO2_2
        r = t - w
        w = k * _PIO2_2T - ((t - r) - w)
        if ex - math.frexp(r - w)[1] > 49:  # and a third
            t = r
            w = k * _PIO2_3
            r = t - w
            w = k * _PIO2_3T - ((t - r) - w)
    head = r - w
    y = (r - head) - w
    r = head
    quadrant = k - 4.0 * np.floor(0.25 * k)  # k mod 4, exact for every float k (np.floor:
    # numba's math.floor returns an int64, which overflows)
    z = r * r
    p = _S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * _S5)))
    v = z * r
    s = r - ((z * (0.5 * y - v * p) - y) - v * _S0)
    p = z * (_C0 + z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * _C5)))))
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + (z * p - r * y))
    if x == 0.0:
        return x, c  # sin(-0) = -0
    if quadrant == 0.0:
        return s, c
    if quadrant == 1.0:
        return c, -s
    if quadrant == 2.0:
        return -s, -c
    return -c, s


_PIO2_HI = 1.57079632679489655800e+00
_PIO2_LO = 6.12323399573676603587e-17
_PS0, _PS1, _PS2, _PS3, _PS4, _PS5 = (
    1.66666666666666657415e-01, -3.25565818622400915405e-01, 2.01212532134862925881e-01,
    -4.00555345006794114027e-02, 7.91534994289814532176e-04, 3.47933107596021167570e-05)
_QS1, _QS2, _QS3, _QS4 = (-2.40339491173441421878e+00, 2.02094576023350569471e+00,
                          -6.88283971605453293030e-01, 7.70381505559019352791e-02)
_SPLIT = 134217729.0  # 2^27 + 1: Veltkamp's split into 26 high bits and the rest


@kernel
def _asin_r(t):
    p = t * (_PS0 + t * (_PS1 + t * (_PS2 + t * (_PS3 + t * (_PS4 + t * _PS5)))))
    q = 1.0 + t * (_QS1 + t * (_QS2 + t * (_QS3 + t * _QS4)))
    return p / q


@kernel
def asin(x):
    """asin x in rad for x in [-1, 1] (NaN outside), fdlibm's algorithm."""
    a = abs(x)
    if not a <= 1.0:
        return math.nan
    if a == 1.0:
        return x * _PIO2_HI + x * _PIO2_LO
    if a < 0.5:
        if a < 7.450580596923828e-09:  # 2^-27: x + x^3/6 rounds to x
            return x
        return x + x * _asin_r(x * x)
    z = (1.0 - a) * 0.5
    s = math.sqrt(z)
    r = _asin_r(z)
    if a >= 0.975:
        t = _PIO2_HI - (2.0 * (s + s * r) - _PIO2_LO)
    else:
        g = _SPLIT * s
        f = g - (g - s)  # s's high 26 bits: f * f is exact
        c = (z - f * f) / (s + f)
        t = 0.5 * _PIO2_HI - (2.0 * s * r - (_PIO2_LO - 2.0 * c) - (0.5 * _PIO2_HI - 2.0 * f))
    return t if x > 0.0 else -t


@kernel
def inv_fifth_root(x):
    """x^(-1/5) for finite x > 0: x = m 32^j with m in [1, 32) (exact scalings), then
    Newton's iteration y <- y (6 - m y^5) / 5 for m^(-1/5) in (0.5, 1] from y = 0.5.
    f(y) = y^-5 - m is convex and falling, so Newton from below climbs monotonically to
    the root: 9 steps reach round-off over all of [1, 32) (measured: 2.2e-16 relative
    after 9, 5e-12 after 8); 10 are taken."""
    if x == math.inf:
        return 0.0
    scale = 1.0
    m = x
    while m >= 32.0:
        m *= 0.03125
        scale *= 0.5
    while m < 1.0:
        m *= 32.0
        scale *= 2.0
    y = 0.5
    for _ in range(10):
        y5 = y * y * y * y * y
        y = y * (6.0 - m * y5) / 5.0
    return y * scale
