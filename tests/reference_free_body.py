"""The exact flow of the torque-free rigid body (Euler-Poinsot motion), vectorised.

Part of loop stage 2.1 (dynamics), pure maths beside `maths.rotation`. `exact_free_rotation(moments, Rp, L, h)` returns the
principal-frame orientations after time h of torque-free motion under a constant world
angular momentum L, to round-off for any h (Jacobi 1849; Celledoni, Fasso, Safstrom &
Zanna, SIAM J. Sci. Comput. 30(4), 2008; van Zon & Schofield, J. Comput. Phys. 225,
2007). scipy.special is imported on the first call only (runs that never ask for the
exact flow do not load scipy).

The maths (docs/dynamics.md has the long form). Principal moments I1 <= I2 <= I3, body
angular momentum m = Rp^T L (principal frame), G = |m|, 2T = sum m_i^2 / I_i.

1. m(t), Jacobi. m circulates about the major axis 3 when G^2 > 2T I2 and about the
   minor axis 1 otherwise. Label the circulated ("dn") axis c, the middle one b and the
   remaining one a: (a, b, c) = (1, 2, 3) or (3, 2, 1). Then
       m_a = sa A_a cn(u), m_b = sb A_b sn(u), m_c = sc A_c dn(u),  u = u0 + lam t,
   with sc = sign(m_c), sa = sign(m_a), sb = sa sc (Euler's equations fix this sign
   product in both regimes), and, written so that no difference of nearly equal numbers
   is formed except the one that is the separatrix distance itself,
       A_a^2 = m_a^2 + m_b^2 (I_c - I_b) I_a / (I_b (I_c - I_a))
       A_b^2 = m_a^2 (I_c - I_a) I_b / (I_a (I_c - I_b)) + m_b^2
       A_c^2 = m_b^2 (I_b - I_a) I_c / (I_b (I_c - I_a)) + m_c^2
       lam^2 = (I_c - I_b) (I_c - I_a) A_c^2 / (I_a I_b I_c^2)
       k^2   = (I_b - I_a) I_c A_a^2 / ((I_c - I_b) I_a A_c^2)
   (each ratio of differences is positive in both regimes); the phase u0 = F(phi0 | k^2)
   = sn0 R_F(cn0^2, dn0^2, 1) (Carlson's R_F) with cn0, sn0, dn0 read off m.

2. Orientation. The world L is constant. With e = sc e_c (the circulated axis, on the
   side m lies: e . m = |m_c| = A_c dn u > 0 always) let P(n) be the smallest rotation
   taking e to n = m / G, P = E + [e x n]x + [e x n]x^2 / (1 + e . n) (regular, as
   e . n >= 0). Then Rp(t) = U Rot_e(psi(t)) P(n(t))^T for a fixed U, and Rp(t) m(t) = L.
   Rp^T Rp' = Omega* (Omega = I^-1 m) gives, after a line of vector algebra with
   m' = m x Omega,
       psi' = (2T + mu G / I_c) / (G + mu) = G / I_c + (2T - G^2/I_c) / (G + mu),
   mu = A_c dn u. So over a step, Rp(h) = Rp(0) Q with
       Q = P(n0) Rot_e(dpsi) P(n1)^T,
       dpsi = h G / I_c + (2T - G^2 / I_c) int_0^h dt / (G + A_c dn(u0 + lam t)).
   The integrand is periodic in u (period 2K) and analytic in the strip |Im u| < K'
   (K' >= pi/2: dn has its poles at +-i K', and G + A_c dn u vanishes only where
   dn is real and <= -1, at |Im u| > K'). Whole periods are counted once (the integral
   over one period times their number) and the rest is integrated by composite
   Gauss-Legendre quadrature on panels at most 1 long in u: in the strip of half-width
   pi/2 the error of n nodes falls like rho^(-2n) with rho = d/L + sqrt(1 + (d/L)^2)
   (Trefethen, Approximation Theory and Approximation Practice, thm 19.3), and n is
   picked for rho^(-2n) < 1e-20, so the quadrature error is below round-off. This is the
   elliptic integral of the third kind of Celledoni et al. (their Pi(n; phi | k)),
   evaluated by quadrature instead of Carlson's R_J: near rotation about a principal
   axis the Pi form subtracts two nearly equal large terms, the quadrature does not.

Cases: a body with equal extreme moments (spherical, and every 2D body, whose tensor is
Izz E) or whose m is exactly along a principal axis (a steady rotation, also about the
unstable middle axis) turns about the fixed m at Omega: Q = exp(h Omega*). Symmetric
bodies (I1 = I2 or I2 = I3) get k = 0 (cn, sn = cos, sin: regular precession).
G = 0 gives Q = E. On the separatrix (k = 1) the period is infinite and dn = sech.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.maths.rotation import cross, exp_so3, skew

# Strip half-width (in u) in which the psi integrand is analytic, with a margin: the
# nearest singularity is at distance K' >= pi/2.
_STRIP = 0.8 * (0.5 * math.pi)
_PANEL = 1.0  # longest quadrature panel in u
_QUAD_EXPONENT = 20.0  # rho^(-2n) < 10^-20: the quadrature error is far below round-off
_GAUSS: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _gauss(n: int):
    """Gauss-Legendre nodes on [0, 1] and weights summing to 1, cached."""
    if n not in _GAUSS:
        x, w = np.polynomial.legendre.leggauss(n)
        _GAUSS[n] = (0.5 * (x + 1.0), 0.5 * w)
    return _GAUSS[n]


def _nodes_for(half_length: float) -> int:
    ratio = _STRIP / max(half_length, 1e-300)
    rho = ratio + math.sqrt(1.0 + ratio * ratio)
    return max(2, math.ceil(_QUAD_EXPONENT * math.log(10.0) / (2.0 * math.log(rho))))


def _smallest_rotation(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(k, 3) unit vectors with e . n >= 0 -> (k, 3, 3) the rotations about e x n taking
    e to n: E + K + K^2 / (1 + e . n), K = [e x n]x (Rodrigues with sin = |e x n|,
    1 - cos = |e x n|^2 / (1 + cos))."""
    K = skew(cross(e, n))
    c = (e * n).sum(-1)
    return np.eye(3) + K + (K @ K) / (1.0 + c)[:, None, None]


def _whole_periods(special, u0, du, lam, G, A, k2, kc2):
    """Split du = lam h into whole periods 2K of the psi integrand and a rest (module
    docstring): returns (the integral over the whole periods, in t, (k,); the rest of du,
    (k,), |rest| < 2K). K >= pi/2, so a step shorter than pi in u has no whole period."""
    whole = np.zeros_like(u0)
    long = np.abs(du) >= math.pi
    if not long.any():
        return whole, du
    periods = np.zeros_like(u0)
    K = np.full_like(u0, np.inf)
    K[long] = special.ellipkm1(kc2[long])  # K(1 - kc2), exact from kc2; inf on the separatrix
    periods[long] = np.trunc(du[long] / (2.0 * K[long]))
    sel = np.nonzero(periods != 0)[0]
    if len(sel):
        nodes, weights = _panels(np.zeros(len(sel)), 2.0 * K[sel])
        dn = jacobi(nodes, k2[sel], kc2[sel])[2]
        one = (weights / (G[sel, None] + A[sel, None] * dn)).sum(1)
        whole[sel] = periods[sel] * one / lam[sel]
        du = du.copy()
        du[sel] -= periods[sel] * 2.0 * K[sel]
    return whole, du


def _panels(start, length):
    """Composite Gauss-Legendre rule for int_start^(start + length) du on equal panels,
    each at most _PANEL long (length < 0: backwards): (nodes (k, q), weights (k, q))."""
    longest = float(np.abs(length).max(initial=0.0))
    panels = max(1, math.ceil(longest / _PANEL))
    width = length / panels  # (k,)
    x, w = _gauss(_nodes_for(0.5 * longest / panels))
    offsets = (np.arange(panels)[:, None] + x[None, :]).ravel()  # (panels * nodes,)
    return start[:, None] + width[:, None] * offsets, width[:, None] * np.tile(w, panels)


def _agm(k2, kc2):
    """The arithmetic-geometric mean of (1, k') for `jacobi`: (2^N a_N (k,), the ratios
    c_n / a_n, n = 1..N, (N, k))."""
    a, c = np.ones_like(kc2), np.sqrt(k2)
    b = np.sqrt(kc2)
    ratios = []
    # c >= 0 falls quadratically: ~6 rounds for k' >= 1e-30, 1 for k = 0, at most 16 for
    # any double. 1e-19 < 1e-17 a_n (a_n > pi / (2 K) > 0.02 for k' > 1e-30).
    while not ratios or (c.max() > 1e-19 and len(ratios) < 16):
        a, b, c = 0.5 * (a + b), np.sqrt(a * b), 0.5 * (a - b)
        ratios.append(c / a)
    return (2.0 ** len(ratios)) * a, np.array(ratios)


def jacobi(u, k2, kc2, agm=None):
    """(sn, cn, dn)(u | k^2), u: (k, q), k2 and kc2 = 1 - k^2: (k,), by the
    arithmetic-geometric mean (Abramowitz & Stegun 16.4; `agm`: `_agm(k2, kc2)` if
    already known).

    scipy.special.ellipj takes k^2 alone and forms 1 - k^2 itself: next to the separatrix
    (k'^2 ~ 1e-12 for a body spun 1e-6 off its middle axis) that keeps only a few digits of
    k'^2, and the period K ~ ln(4 / k') with them. Here the AGM starts from b0 = k'
    exactly. dn = sqrt(k'^2 + k^2 cn^2) adds two positive terms (no cancellation where
    dn is tiny, and no 0/0 of the textbook cos(phi0) / cos(phi1 - phi0))."""
    scale, ratios = _agm(k2, kc2) if agm is None else agm
    phi = scale[:, None] * u
    for ratio in ratios[::-1]:
        phi = 0.5 * (phi + np.arcsin(ratio[:, None] * np.sin(phi)))
    cn = np.cos(phi)
    return np.sin(phi), cn, np.sqrt(kc2[:, None] + k2[:, None] * cn * cn)


def exact_free_rotation(moments: np.ndarray, Rp: np.ndarray, L: np.ndarray,
                        h: float) -> np.ndarray:
    """Principal-frame orientations after time h of torque-free motion.

    moments: (k, 3) kg m^2 principal moments, ascending; Rp: (k, 3, 3) principal frame ->
    world; L: (k, 3) kg m^2/s world angular momentum (constant); h: s (any sign).
    Returns (k, 3, 3) Rp(h) with Rp(h) (Rp(h)^T L) = L and Rp(h)^T L the Jacobi solution.
    """
    m = (L[:, None, :] @ Rp)[:, 0, :]  # (Rp^T L)^T
    Q = np.broadcast_to(np.eye(3), Rp.shape).copy()
    G = np.linalg.norm(m, axis=-1)
    I1, I3 = moments[:, 0], moments[:, 2]
    omega = m / moments
    axial = (np.count_nonzero(m, axis=-1) <= 1)  # m along a principal axis: steady
    # Spherical (also every 2D body): Omega || m. Moments equal to 1e-12 (relative) count:
    # treating them as equal turns the body wrong by ~1e-12 |Omega| h, round-off level.
    round_ = (I3 - I1) <= 1e-12 * I3
    finite = np.isfinite(G)
    Q[~finite] = np.nan  # a blown-up state stays blown up: rigid.check names the body
    steady = finite & (G > 0) & (axial | round_)
    if steady.any():
        Q[steady] = exp_so3(h * omega[steady])
    gen = np.nonzero(finite & (G > 0) & ~steady)[0]
    if len(gen):
        Q[gen] = _jacobi_step(moments[gen], m[gen], G[gen], h)
    return Rp @ Q


def _jacobi_step(moments, m, G, h):
    """(k, 3, 3) body rotations Q, Rp(h) = Rp(0) Q, for bodies off the steady cases."""
    from scipy import special

    I1, I2, I3 = moments[:, 0], moments[:, 1], moments[:, 2]
    # G^2 - 2T I2, the separatrix distance, from m directly (the only cancellation).
    sep = m[:, 0] ** 2 * (I1 - I2) / I1 + m[:, 2] ** 2 * (I3 - I2) / I3
    # Ties (sep == 0): a symmetric body is labelled so that I_b = I_a (k = 0); otherwise
    # it is the separatrix, where both labellings are the same motion.
    major = (sep > 0) | ((sep == 0) & (I3 > I2))
    order = np.where(major[:, None], [0, 1, 2], [2, 1, 0])  # (a, b, c) per body
    rows = np.arange(len(m))[:, None]
    Ia, Ib, Ic = moments[rows, order].T
    ma, mb, mc = m[rows, order].T
    dca, dcb, dba = Ic - Ia, Ic - Ib, Ib - Ia  # all >= 0 (major) or all <= 0: ratios >= 0
    Aa2 = ma ** 2 + mb ** 2 * _ratio(dcb * Ia, Ib * dca)
    Ab2 = ma ** 2 * _ratio(dca * Ib, Ia * dcb) + mb ** 2
    Ac2 = mb ** 2 * _ratio(dba * Ic, Ib * dca) + mc ** 2
    lam = np.sqrt(np.maximum(dcb * dca, 0.0) * Ac2 / (Ia * Ib * Ic * Ic))
    k2 = np.clip(_ratio(dba * Ic * Aa2, dcb * Ia * Ac2), 0.0, 1.0)
    # k'^2 = 1 - k^2 = I_c (G^2 - 2T I_b) / ((I_c - I_b) A_c^2) (the m_b^2 terms cancel
    # exactly): from the separatrix distance itself, so that k'^2 keeps its relative
    # accuracy next to the separatrix, where dn >= k' matters.
    kc2 = np.clip(_ratio(Ic * sep, dcb * Ac2), 0.0, 1.0)
    k2, kc2 = np.where(kc2 < 0.5, 1.0 - kc2, k2), np.where(kc2 < 0.5, kc2, 1.0 - k2)
    sc = np.where(mc < 0, -1.0, 1.0)
    sa = np.where(ma < 0, -1.0, 1.0)
    sb = sa * sc
    Aa, Ab, Ac = np.sqrt(Aa2), np.sqrt(Ab2), np.sqrt(Ac2)
    # u0 = F(phi0 | k^2) = sn R_F(cn^2, dn^2, 1) (Carlson; |phi0| <= pi/2 as cn0 >= 0),
    # from cn0, sn0, dn0 read off m: no amplitude angle, whose rounding next to pi/2 (m
    # close to the unstable axis) would make u0 infinite.
    cn0 = np.clip(_ratio(ma * sa, Aa), 0.0, 1.0)
    sn0 = np.clip(_ratio(mb * sb, Ab), -1.0, 1.0)
    dn0 = np.clip(_ratio(mc * sc, Ac), 0.0, 1.0)
    u0 = sn0 * special.elliprf(cn0 * cn0, dn0 * dn0, 1.0)
    # One pass of the Jacobi functions: column 0 is the step's end u1, the others the
    # quadrature nodes of the psi integral's rest after whole periods.
    du = lam * h
    whole, rest = _whole_periods(special, u0, du, lam, G, Ac, k2, kc2)
    nodes, weights = _panels(u0, rest)
    sn, cn, dn = jacobi(np.concatenate([(u0 + du)[:, None], nodes], 1), k2, kc2)
    moving = lam > 0
    integral = whole + np.where(
        moving, (weights / (G[:, None] + Ac[:, None] * dn[:, 1:])).sum(1) /
        np.where(moving, lam, 1.0), h / (G + Ac * dn[:, 0]))  # lam = 0: dn stays dn(u0)
    m1 = np.empty_like(m)
    m1[rows[:, 0], order[:, 0]] = sa * Aa * cn[:, 0]
    m1[rows[:, 0], order[:, 1]] = sb * Ab * sn[:, 0]
    m1[rows[:, 0], order[:, 2]] = sc * Ac * dn[:, 0]
    # psi: rate G/I_c plus (2T - G^2/I_c) / (G + A_c dn u), 2T - G^2/I_c without cancellation.
    excess = ma ** 2 * (1.0 / Ia - 1.0 / Ic) + mb ** 2 * (1.0 / Ib - 1.0 / Ic)
    dpsi = h * G / Ic + excess * integral
    e = np.zeros_like(m)
    e[rows[:, 0], order[:, 2]] = sc
    n = len(m)
    P = _smallest_rotation(np.concatenate([e, e]), np.concatenate(
        [m / G[:, None], m1 / np.linalg.norm(m1, axis=-1, keepdims=True)]))
    # Rot_e(dpsi) = exp(dpsi e*): e is a signed coordinate axis, so exp_so3 is exact.
    return P[:n] @ exp_so3(dpsi[:, None] * e) @ np.swapaxes(P[n:], -1, -2)


def _ratio(num, den):
    """num / den, 0 where den == 0 (a symmetric body's vanishing difference)."""
    zero = den == 0
    return np.where(zero, 0.0, num / np.where(zero, 1.0, den))
