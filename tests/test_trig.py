"""sin and cos of our own (maths/trig.py): libm's FMA and plain variants differ in the
last bit by CPU, ours use only correctly rounded + - * /.

Truth: libm through numpy (nearly correctly rounded: glibc's sin and cos err < 1 ulp),
so ours must be within 1 ulp of it for |x| <= 1.6e6 rad (fdlibm's kernels err < 1 ulp on
[-pi/4, pi/4]; its reduction by parts of pi/2 with their tails, a further round where one
cancelled, keeps the distance to k pi/2 to ~2^-150). Near the zeros too: cos of the float
nearest pi/2 is 6.1e-17, and a reduction without the tails (before 2026-12-07) gave it 7
ulp off."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.maths.trig import cos, sin, sin_cos


def ulps(a, b) -> np.ndarray:
    return np.abs(np.asarray(a).view(np.int64) - np.asarray(b).view(np.int64))


def test_within_one_ulp_of_libm_where_the_simulation_uses_them():
    rng = np.random.default_rng(11)
    for lo, hi, most in ((-1.0, 1.0, 1), (-7.0, 7.0, 1), (-100.0, 100.0, 1), (-1e5, 1e5, 1),
                         (-1.6e6, 1.6e6, 1)):
        x = rng.uniform(lo, hi, 200_000)
        s, c = sin_cos(x)
        assert ulps(s, np.sin(x)).max() <= most and ulps(c, np.cos(x)).max() <= most


@settings(max_examples=300, deadline=None)
@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_scalars_and_identities(x):
    s, c = sin(x), cos(x)
    assert isinstance(s, float) and isinstance(c, float)
    assert ulps(s, np.sin(x)) <= 1 and ulps(c, np.cos(x)) <= 1
    assert abs(s * s + c * c - 1.0) <= 4e-16


def test_near_the_multiples_of_half_pi():
    """The floats nearest k pi/2 and their neighbours (|k| <= 10^5), where sin or cos is
    ~1e-17 and only the reduction's tails keep it to the ulp."""
    k = np.arange(-100_000, 100_001)
    x = (np.pi / 2) * k
    x = np.concatenate([x, np.nextafter(x, np.inf), np.nextafter(x, -np.inf)])
    s, c = sin_cos(x)
    assert ulps(s, np.sin(x)).max() <= 1 and ulps(c, np.cos(x)).max() <= 1


def test_special_values():
    s, c = sin_cos(np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1e-300]))
    assert s[0] == 0.0 and np.signbit(s[1]) and c[0] == c[1] == 1.0
    assert np.isnan(s[2:5]).all() and np.isnan(c[2:5]).all()
    assert s[5] == 1e-300 and c[5] == 1.0


def test_sin_over_x_is_within_two_ulp_of_numpys_sinc_and_exact_at_zero():
    """sin(x)/x replaces numpy's sinc(x / pi) on the simulation path (the drive, slerps):
    against sin(x)/x computed from libm's sin (one rounding of the division on top of
    <= 1 ulp of sin), and 1 at 0, where sinc's own definition holds."""
    from vrsim_cli.maths.trig import sin_over_x

    rng = np.random.default_rng(5)
    x = np.concatenate([rng.uniform(-10.0, 10.0, 100_000), rng.uniform(-1e-6, 1e-6, 1000)])
    assert ulps(sin_over_x(x), np.sin(x) / x).max() <= 2
    assert sin_over_x(0.0) == 1.0 and sin_over_x(np.zeros(3)).tolist() == [1.0] * 3
    assert sin_over_x(-0.0) == 1.0
    assert abs(sin_over_x(np.pi) - np.sinc(1.0)) <= 1e-16


# ------------------------------------------------------------------ the kernels' own
# kernels/trig.py: numba lowers math.sin, math.asin and ** to libm; these replace them.


def _kernel_sin_cos(x):
    from vrsim_cli.kernels import trig as kt

    out = np.array([kt.sin_cos(float(v)) for v in x])
    return out[:, 0], out[:, 1]


def test_the_kernels_sin_cos_has_the_bits_of_maths_trig():
    """The compiled scalar version against the numpy one, bit for bit (both the same
    operations in the same order), over the ranges the simulation uses, far beyond, and
    the special values."""
    rng = np.random.default_rng(12)
    x = np.concatenate([rng.uniform(-1.0, 1.0, 20_000), rng.uniform(-100.0, 100.0, 20_000),
                        rng.uniform(-1e6, 1e6, 5_000), 10.0 ** rng.uniform(-300, 300, 2_000),
                        -(10.0 ** rng.uniform(-300, 300, 2_000)),
                        np.pi / 4 * np.arange(-40, 41), [0.0, -0.0, 1e300, -1e300,
                                                         5e-324, np.inf, -np.inf, np.nan]])
    s, c = _kernel_sin_cos(x)
    ws, wc = sin_cos(x)
    for got, want in ((s, ws), (c, wc)):
        nan = np.isnan(want)
        assert (np.isnan(got) == nan).all()
        assert (got[~nan].view(np.int64) == want[~nan].view(np.int64)).all()


def test_the_kernels_asin_is_within_one_ulp_of_libm():
    """fdlibm's asin (kernels/trig.py) against libm's over [-1, 1]: uniform draws, the
    branch points (0.5, 0.975, 2^-27) and their neighbours, the ends; odd; NaN outside."""
    from vrsim_cli.kernels import trig as kt

    rng = np.random.default_rng(13)
    edges = np.array([0.5, 0.975, 2.0 ** -27, 1.0, 1e-300, 0.0])
    near = np.concatenate([np.nextafter(edges, 2.0), np.nextafter(edges, -1.0), edges])
    x = np.concatenate([rng.uniform(-1.0, 1.0, 50_000), 1.0 - 10.0 ** rng.uniform(-16, 0, 5_000),
                        near, -near])
    x = x[np.abs(x) <= 1.0]
    got = np.array([kt.asin(float(v)) for v in x])
    assert ulps(got, np.arcsin(x)).max() <= 1
    assert (got == -np.array([kt.asin(float(-v)) for v in x])).all()
    assert kt.asin(-0.0) == 0.0 and np.signbit(kt.asin(-0.0))
    for bad in (1.0 + 2e-16, -1.5, np.inf, np.nan):
        assert np.isnan(kt.asin(bad))


def test_the_kernels_inverse_fifth_root_is_within_one_ulp():
    """x^(-1/5) by Newton from a power-of-two start (kernels/trig.py, step size control)
    against 50-digit decimal arithmetic (libm's pow is no truth here: -0.2 is not 1/5, a
    relative 1e-17 that ln x ~ 700 makes 5e-15): log-uniform x over the whole double range,
    uniform x around the start's range [1, 32), exact powers of 32 and the ends."""
    from decimal import Decimal, localcontext

    from vrsim_cli.kernels import trig as kt

    rng = np.random.default_rng(14)
    x = np.concatenate([10.0 ** rng.uniform(-300, 300, 3_000), rng.uniform(0.5, 40.0, 3_000),
                        2.0 ** np.arange(-1070, 1020, 5.0), [1.0, 32.0, 5e-324]])
    got = np.array([kt.inv_fifth_root(float(v)) for v in x])

    def truth(v):  # x^(-1/5) to ~1e-49: Newton's y (6 - x y^5) / 5 in 50-digit decimals
        # from numpy's pow (a relative 5e-15 off: three quadratic steps pass 1e-49);
        # Decimal's own ** -1/5 gave the same 6420 doubles, 25x slower (ln and exp)
        d, y = Decimal(float(v)), Decimal(float(np.float64(v) ** -0.2))
        for _ in range(3):
            y = y * (6 - d * y ** 5) / 5
        return float(y)

    with localcontext() as ctx:
        ctx.prec = 50
        want = np.array([truth(v) for v in x])
    assert ulps(got, want).max() <= 1
    assert kt.inv_fifth_root(np.inf) == 0.0
    assert kt.inv_fifth_root(32.0) == 0.5 and kt.inv_fifth_root(2.0 ** -500) == 2.0 ** 100


# ---------------------------------------------------------------- atan2 and acos
# maths.trig.atan2 (fdlibm's s_atan.c and e_atan2.c) and acos through it: keyframes'
# quaternion logarithm, continuous collision's turn, slerp and navigation's pitch.


def test_atan2_is_within_two_ulp_of_libm_and_has_its_special_values():
    """Random pairs over 60 orders of magnitude each and in the unit square, within 2
    ulp of numpy's (libm's, correctly rounded in glibc) arctan2: fdlibm's pi - atan for
    x < 0 rounds twice (measured: 2 ulp for 1 of 1e5 pairs); every pair of special values (signed zeros,
    infinities, NaN, subnormals, the largest floats) bit for bit as libm."""
    from vrsim_cli.maths.trig import atan2

    rng = np.random.default_rng(15)
    n = 100_000
    y = rng.normal(size=n) * 10.0 ** rng.uniform(-30, 30, n)
    x = rng.normal(size=n) * 10.0 ** rng.uniform(-30, 30, n)
    assert ulps(atan2(y, x), np.arctan2(y, x)).max() <= 2
    y, x = rng.uniform(-1.0, 1.0, n), rng.uniform(-1.0, 1.0, n)
    assert ulps(atan2(y, x), np.arctan2(y, x)).max() <= 2
    special = [0.0, -0.0, 1.0, -1.0, np.inf, -np.inf, np.nan, 1e-320, -1e-320, 1e308,
               -1e308, 1e-300, -1e-300, 5e-324]
    Y, X = (a.ravel() for a in np.meshgrid(special, special))
    got, want = atan2(Y, X), np.arctan2(Y, X)
    nan = np.isnan(want)
    assert (np.isnan(got) == nan).all()
    assert (got[~nan].view(np.int64) == want[~nan].view(np.int64)).all()
    assert isinstance(atan2(1.0, 2.0), float)


def test_acos_is_within_two_ulp_of_libm():
    """acos x = atan2(sqrt((1 - x)(1 + x)), x): uniform x and x within 1e-16..1 of +-1
    (where slerp and the pitch use it), within 2 ulp of libm (the square root's
    argument rounds once more); NaN outside [-1, 1]."""
    from vrsim_cli.maths.trig import acos

    rng = np.random.default_rng(16)
    x = np.concatenate([rng.uniform(-1.0, 1.0, 100_000), 1.0 - 10.0 ** rng.uniform(-16, 0, 10_000),
                        [-1.0, 0.0, -0.0, 1.0]])
    x = np.concatenate([x, -x])
    assert ulps(acos(x), np.arccos(x)).max() <= 2
    assert acos(1.0) == 0.0 and acos(-1.0) == np.pi and acos(0.0) == np.pi / 2
    assert np.isnan(acos(1.0 + 2e-16)) and np.isnan(acos(np.nan))


def test_no_libm_transcendental_on_the_simulation_path():
    """A scan of the package's code (comments and docstrings aside, roughly: lines
    whose code part calls them) for libm's transcendental functions through math or
    numpy; allowed only in the renderer, the camera (pictures) and the tools (sweeps,
    benchmarks). A new call elsewhere would make trajectories CPU-dependent again.
    math.hypot is CPython's own code (Modules/mathmodule.c), not libm's: allowed."""
    import re
    from pathlib import Path

    import vrsim_cli

    root = Path(vrsim_cli.__file__).parent
    call = re.compile(r"\b(?:math|np|numpy)\.(?:sin|cos|tan|arcsin|arccos|arctan|arctan2|"
                      r"asin|acos|atan|atan2|exp|expm1|log|log1p|log2|log10|power|pow|"
                      r"sinh|cosh|tanh|sinc)\(")
    allowed = ("render/", "tools/", "maths/camera.py")
    found = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.startswith(allowed):
            continue
        for number, line in enumerate(path.read_text().splitlines(), 1):
            code = line.split("#", 1)[0]
            if call.search(code) and not code.lstrip().startswith(("\"", "'", "-", "`")):
                found.append(f"{rel}:{number}: {line.strip()}")
    assert not found, "\n".join(found)
