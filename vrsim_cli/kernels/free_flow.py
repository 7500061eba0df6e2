"""The exact torque-free flow of a rigid body (Euler-Poinsot), one body at a time.

The maths, its derivation and references are in `stages/dynamics/free_body.py`'s
docstring (Jacobi 1849; Celledoni, Fasso, Safstrom & Zanna 2008): m(t) by Jacobi's
elliptic functions from the arithmetic-geometric mean started at k' exactly, the phase
u0 = sn0 R_F(cn0^2, dn0^2, 1) (Carlson), and the precession angle psi by composite
Gauss-Legendre quadrature below round-off. This is that algorithm written per body with
scalar arithmetic (no scipy: Carlson's R_F and K(k) by the AGM are a few lines), so that
it runs inside the compiled step.

`free_rotation(moments, Rp, L, h, gl_x, gl_w, gl_start)` -> Rp(h) as a 9-tuple.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.kernels import linalg as la
from vrsim_cli.kernels import trig
from vrsim_cli.kernels.jit import kernel

STRIP = 0.8 * (0.5 * math.pi)  # half-width (in u) where the psi integrand is analytic
PANEL = 1.0  # longest quadrature panel in u
QUAD_EXPONENT = 20.0  # rho^(-2n) < 1e-20: the quadrature error is far below round-off
QUAD_TARGET = 1e20  # 10^QUAD_EXPONENT
MAX_NODES = 64
_TABLES: list = []  # gauss_tables(), built once per process on first use


def no_tables():
    """Empty stand-ins for `gauss_tables` in a model without the exact flow: building
    the tables costs ~30 ms (63 leggauss calls), a tenth of a small run's budget."""
    return np.zeros(0), np.zeros(0), np.zeros(MAX_NODES + 2, np.int64)


def gauss_tables():
    """Gauss-Legendre nodes on [0, 1] and weights summing to 1 for n = 2 .. MAX_NODES,
    packed: (x (total,), w (total,), start (MAX_NODES + 2,) offsets by n)."""
    if not _TABLES:
        for table in _build_tables():
            table.flags.writeable = False  # shared by every model of the process
            _TABLES.append(table)
    return _TABLES[0], _TABLES[1], _TABLES[2]


def _build_tables():
    start = np.zeros(MAX_NODES + 2, np.int64)
    xs, ws = [], []
    offset = 0
    for n in range(MAX_NODES + 1):
        start[n] = offset
        if n >= 2:
            x, w = np.polynomial.legendre.leggauss(n)
            xs.append(0.5 * (x + 1.0))
            ws.append(0.5 * w)
            offset += n
    start[MAX_NODES + 1] = offset
    return np.concatenate(xs), np.concatenate(ws), start


@kernel
def nodes_for(half_length):
    ratio = STRIP / max(half_length, 1e-300)
    rho = ratio + math.sqrt(1.0 + ratio * ratio)
    # the least n with rho^(2n) >= 10^QUAD_EXPONENT, by products (libm's log differs
    # in the last bit between CPUs, which could move n at a boundary)
    rho2 = rho * rho
    n, power = 0, 1.0
    while power < QUAD_TARGET and n < MAX_NODES:
        power *= rho2
        n += 1
    return min(max(2, n), MAX_NODES)


@kernel
def carlson_rf(x, y, z):
    """Carlson's symmetric elliptic integral R_F(x, y, z) by duplication (Carlson 1995,
    Numer. Algorithms 10; the fifth-order series after the loop)."""
    for _ in range(64):
        mu = (x + y + z) / 3.0
        if mu == 0.0:
            return math.inf
        dx, dy, dz = 1.0 - x / mu, 1.0 - y / mu, 1.0 - z / mu
        if max(abs(dx), abs(dy), abs(dz)) < 1e-4:  # series error ~ 1e-4^6 / 4 < 1e-24
            e2 = dx * dy - dz * dz
            e3 = dx * dy * dz
            return (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0) \
                / math.sqrt(mu)
        sx, sy, sz = math.sqrt(x), math.sqrt(y), math.sqrt(z)
        lam = sx * (sy + sz) + sy * sz
        x, y, z = 0.25 * (x + lam), 0.25 * (y + lam), 0.25 * (z + lam)
    mu = (x + y + z) / 3.0
    return 1.0 / math.sqrt(mu)


@kernel
def agm_k(kc2):
    """K(k) from k'^2 = 1 - k^2 exactly: pi / (2 AGM(1, k')); inf on the separatrix."""
    if kc2 <= 0.0:
        return math.inf
    a, b = 1.0, math.sqrt(kc2)
    for _ in range(64):
        if abs(a - b) <= 1e-16 * a:
            break
        a, b = 0.5 * (a + b), math.sqrt(a * b)
    return math.pi / (a + b)


@kernel
def jacobi_prepare(k2, kc2, ratios):
    """The AGM of (1, k') for `jacobi`: writes c_n / a_n into `ratios` (16,) and returns
    (2^N a_N, N)."""
    a, b, c = 1.0, math.sqrt(kc2), math.sqrt(k2)
    count = 0
    while count == 0 or (c > 1e-19 and count < 16):
        a, b, c = 0.5 * (a + b), math.sqrt(a * b), 0.5 * (a - b)
        ratios[count] = c / a
        count += 1
    return (2.0 ** count) * a, count


@kernel
def jacobi(u, k2, kc2, scale, ratios, count):
    """(sn, cn, dn)(u | k^2) by the AGM (Abramowitz & Stegun 16.4); dn = sqrt(k'^2 +
    k^2 cn^2) adds two positive terms."""
    phi = scale * u
    for i in range(count - 1, -1, -1):
        phi = 0.5 * (phi + trig.asin(ratios[i] * trig.sin_cos(phi)[0]))
    sn, cn = trig.sin_cos(phi)  # not libm: the same bits on every CPU
    return sn, cn, math.sqrt(kc2 + k2 * cn * cn)


@kernel
def _ratio(num, den):
    return 0.0 if den == 0.0 else num / den


@kernel
def _smallest_rotation(e, n):
    """The rotation about e x n taking unit e to unit n (e . n >= 0): E + K + K^2/(1+c)."""
    k = la.cross(e, n)
    c = la.dot(e, n)
    f = 1.0 / (1.0 + c)
    x, y, z = k
    # K = [k]x; K^2 = k k^T - |k|^2 E
    kk = x * x + y * y + z * z
    return (1.0 + f * (x * x - kk), -z + f * x * y, y + f * x * z,
            z + f * x * y, 1.0 + f * (y * y - kk), -x + f * y * z,
            -y + f * x * z, x + f * y * z, 1.0 + f * (z * z - kk))


@kernel
def _psi_integral(u0, du, lam, G, Ac, k2, kc2, scale, ratios, count, gl_x, gl_w, gl_start):
    """int over u from u0 to u0 + du of du' / (lam (G + Ac dn u')), whole periods 2K
    counted once."""
    total = 0.0
    if abs(du) >= math.pi:
        K = agm_k(kc2)
        periods = math.trunc(du / (2.0 * K)) if math.isfinite(K) else 0.0
        if periods != 0.0:
            one = _panel_sum(0.0, 2.0 * K, G, Ac, k2, kc2, scale, ratios, count, gl_x, gl_w,
                             gl_start)
            total += periods * one
            du = du - periods * 2.0 * K
    total += _panel_sum(u0, du, G, Ac, k2, kc2, scale, ratios, count, gl_x, gl_w, gl_start)
    return total / lam


@kernel
def _panel_sum(start, length, G, Ac, k2, kc2, scale, ratios, count, gl_x, gl_w, gl_start):
    panels = max(1, int(math.ceil(abs(length) / PANEL)))
    width = length / panels
    n = nodes_for(0.5 * abs(length) / panels)
    first = int(gl_start[n])
    total = 0.0
    for p in range(panels):
        for j in range(n):
            u = start + width * (p + gl_x[first + j])
            dn = jacobi(u, k2, kc2, scale, ratios, count)[2]
            total += width * gl_w[first + j] / (G + Ac * dn)
    return total


@kernel
def jacobi_step(moments, m, G, h, gl_x, gl_w, gl_start, ratios):
    """The body rotation Q (9-tuple), Rp(h) = Rp(0) Q, off the steady cases."""
    I1, I2, I3 = moments
    sep = m[0] * m[0] * (I1 - I2) / I1 + m[2] * m[2] * (I3 - I2) / I3
    major = sep > 0.0 or (sep == 0.0 and I3 > I2)
    if major:
        ia, ib, ic = 0, 1, 2
    else:
        ia, ib, ic = 2, 1, 0
    Ia, Ib, Ic = moments[ia], moments[ib], moments[ic]
    ma, mb, mc = m[ia], m[ib], m[ic]
    dca, dcb, dba = Ic - Ia, Ic - Ib, Ib - Ia
    Aa2 = ma * ma + mb * mb * _ratio(dcb * Ia, Ib * dca)
    Ab2 = ma * ma * _ratio(dca * Ib, Ia * dcb) + mb * mb
    Ac2 = mb * mb * _ratio(dba * Ic, Ib * dca) + mc * mc
    lam = math.sqrt(max(dcb * dca, 0.0) * Ac2 / (Ia * Ib * Ic * Ic))
    k2 = min(max(_ratio(dba * Ic * Aa2, dcb * Ia * Ac2), 0.0), 1.0)
    kc2 = min(max(_ratio(Ic * sep, dcb * Ac2), 0.0), 1.0)
    if kc2 < 0.5:
        k2 = 1.0 - kc2
    else:
        kc2 = 1.0 - k2
    sc = -1.0 if mc < 0.0 else 1.0
    sa = -1.0 if ma < 0.0 else 1.0
    sb = sa * sc
    Aa, Ab, Ac = math.sqrt(Aa2), math.sqrt(Ab2), math.sqrt(Ac2)
    cn0 = min(max(_ratio(ma * sa, Aa), 0.0), 1.0)
    sn0 = min(max(_ratio(mb * sb, Ab), -1.0), 1.0)
    dn0 = min(max(_ratio(mc * sc, Ac), 0.0), 1.0)
    u0 = sn0 * carlson_rf(cn0 * cn0, dn0 * dn0, 1.0)
    du = lam * h
    scale, count = jacobi_prepare(k2, kc2, ratios)
    sn1, cn1, dn1 = jacobi(u0 + du, k2, kc2, scale, ratios, count)
    if lam > 0.0:
        integral = _psi_integral(u0, du, lam, G, Ac, k2, kc2, scale, ratios, count, gl_x,
                                 gl_w, gl_start)
    else:
        integral = h / (G + Ac * dn1)
    excess = ma * ma * (1.0 / Ia - 1.0 / Ic) + mb * mb * (1.0 / Ib - 1.0 / Ic)
    dpsi = h * G / Ic + excess * integral
    if major:  # (a, b, c) = (1, 2, 3); e = sc e_c
        mv = (sa * Aa * cn1, sb * Ab * sn1, sc * Ac * dn1)
        ev = (0.0, 0.0, sc)
    else:  # (a, b, c) = (3, 2, 1)
        mv = (sc * Ac * dn1, sb * Ab * sn1, sa * Aa * cn1)
        ev = (sc, 0.0, 0.0)
    n0 = la.scale(1.0 / G, m)
    n1 = la.scale(1.0 / la.norm(mv), mv)
    P0 = _smallest_rotation(ev, n0)
    P1 = _smallest_rotation(ev, n1)
    turn = la.exp_so3(la.scale(dpsi, ev))  # about a signed coordinate axis: exact
    return la.matmul(la.matmul(P0, turn), la.transpose(P1))


@kernel
def free_rotation(moments, Rp, L, h, gl_x, gl_w, gl_start, ratios):
    """Rp(h) of torque-free motion with constant world L from the principal frame Rp
    (9-tuple, principal -> world); moments (3-tuple, ascending) kg m^2."""
    m = la.mattvec(Rp, L)
    G = la.norm(m)
    if not math.isfinite(G):
        nan = math.nan
        return (nan, nan, nan, nan, nan, nan, nan, nan, nan)
    if G == 0.0:
        return Rp
    I1, I3 = moments[0], moments[2]
    zeros = (m[0] == 0.0) + (m[1] == 0.0) + (m[2] == 0.0)
    if zeros >= 2 or (I3 - I1) <= 1e-12 * I3:  # steady: along an axis, or spherical
        omega = (m[0] / moments[0], m[1] / moments[1], m[2] / moments[2])
        return la.matmul(Rp, la.exp_so3(la.scale(h, omega)))
    return la.matmul(Rp, jacobi_step(moments, m, G, h, gl_x, gl_w, gl_start, ratios))


@kernel
def _rotate_all(moments, Rp, L, h, gl_x, gl_w, gl_start, out):
    ratios = np.zeros(16)
    for i in range(moments.shape[0]):
        m = (moments[i, 0], moments[i, 1], moments[i, 2])
        R = la.load33(Rp, i)
        q = free_rotation(m, R, la.load3(L, i), h, gl_x, gl_w, gl_start, ratios)
        la.store33(out, i, q)


def exact_free_rotation(moments, Rp, L, h: float) -> np.ndarray:
    """Principal-frame orientations after time h of torque-free motion, for a stack of
    bodies: moments (k, 3) kg m^2 ascending; Rp (k, 3, 3) principal frame -> world; L
    (k, 3) kg m^2/s world angular momentum (constant); h s (any sign). Returns (k, 3, 3)
    Rp(h) with Rp(h)^T L the Jacobi solution (the kernel `free_rotation`, per body)."""
    gl_x, gl_w, gl_start = gauss_tables()
    moments = np.ascontiguousarray(moments, dtype=float).reshape(-1, 3)
    Rp = np.ascontiguousarray(Rp, dtype=float).reshape(-1, 3, 3)
    L = np.ascontiguousarray(L, dtype=float).reshape(-1, 3)
    out = np.empty_like(Rp)
    _rotate_all(moments, Rp, L, float(h), gl_x, gl_w, gl_start.astype(float), out)
    return out
