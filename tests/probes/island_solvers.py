# Usage: python tests/probes/island_solvers.py REPO_ROOT [LAYERS [MU_FACTOR [SWEEPS]]]
# (ONLY="coulomb pyramid block desaxce newton" picks the solvers; all but newton by default)
# The resting-contact system of a sphere pyramid (tests/test_sphere_pyramids.py) at its
# first step, taken from the compiled step run as Python (NUMBA_DISABLE_JIT=1: the first
# `kernels.stepped.rest` call's contact table and kicked velocities), solved four ways in
# numpy against statics (issue 48 (d): 30 spheres fall at 1.2 x the least mu):
# - "coulomb":  the kernel's rows (normal to its target clamped >= 0, then friction in the
#               disc of the new normal), Gauss-Seidel;
# - "pyramid":  the convex problem (Anitescu) min 1/2 l'Al + b'l over inscribed 8-gon
#               cones, projected Gauss-Seidel on the generators' weights;
# - "block":    the same convex problem over the exact cones, block Gauss-Seidel (each
#               contact's 3 impulses minimised exactly over its cone);
# - "desaxce":  block Gauss-Seidel on Coulomb's law itself (the convex block with b_n +
#               mu |w_t|, De Saxce's change of variables, 4 fixed-point passes a block).
# Measured 2026-12-07 (30 spheres, mu 1.2 x 0.613, dt 1/60, verlet; docs/benchmarks.md):
# statics holds (the LP); coulomb and desaxce cycle (|w_t| of loaded contacts 1-4e-2 m/s
# from 8 to 512 sweeps); pyramid converges slowly (2e-4 at 512, 2e-11 at 4096); block
# converges (1.5e-5 at 128, 1.4e-7 at 256, 2.8e-9 at 512 sweeps).
# ONLY=newton (env EPS, OUTER, INNER, GTOL): the convex problem's primal in the bodies'
# space, Newton with an exact line search on a stiff penalty (MuJoCo's method), and the
# method of multipliers on top (OUTER rounds). Measured the same day (30 spheres, 180
# velocities: a 180 x 180 Cholesky a step): EPS 1e-10, 5 Newton steps to 7.7e-10 m/s of
# loaded contacts' slip (the penalty's floor, ~3 EPS m/s); EPS 1e-8 with multipliers:
# 10 steps, then 1 and 1 more: 3e-14 and 1.3e-15 m/s, all 112 contacts loaded.
# PILE=PATH (pile_class.py SEED 0 --save PATH): one step of a saved pile instead (the
# warm start's impulses taken out of the velocities). rk4 202 at 6 s (87 contacts, 120
# velocities): the kernel's rows from zero, 512 sweeps: slip 7.7e-5 m/s, 13 of 77 loaded
# contacts on their cone's edge; Newton with multipliers (EPS 1e-8): 21 steps to 8.7e-8
# m/s with all 77 loaded, then 2e-8 .. 6.6e-8 over three more rounds with either
# stopping rule (RULE=terms, GTOL 1e-10 or 1e-12: the pyramid in 15-16 steps to 1.3e-15
# m/s): so the pile's residual is not the inner rounds' stop; to be examined. The
# all-held LP is infeasible there (some contacts must open): not the oracle for piles.
# 2026-12-08: the level is the step's problem, not the solver's: a least-squares solve
# holding all 77 loaded contacts at their targets leaves 2.0e-8 m/s (contact 54, loaded
# 0.6-0.7 of the largest, has a 1e-7 m gap: target -6e-6 m/s); docs/benchmarks.md.
"""Five solves of one large island's resting contacts, against statics (issue 48 (d))."""
import math
import os
import sys

os.environ["NUMBA_DISABLE_JIT"] = "1"  # before vrsim: its kernels run as Python
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, os.path.join(sys.argv[1], "tests"))

import numpy as np  # noqa: E402
from scipy.optimize import linprog  # noqa: E402

import vrsim_cli  # noqa: E402
from test_sphere_pyramids import centres  # noqa: E402
from vrsim_cli.kernels import stepped as ks  # noqa: E402

LAYERS = int(sys.argv[2]) if len(sys.argv) > 2 else 4
FACTOR = float(sys.argv[3]) if len(sys.argv) > 3 else 1.2
SWEEPS = int(sys.argv[4]) if len(sys.argv) > 4 else 512
NEED = {2: 0.430, 3: 0.537, 4: 0.613}[LAYERS]  # statics' least mu (the test's oracle)
MU, R_S, DT = FACTOR * NEED, 0.1, 1 / 60

# the island at the first rest call
calls = []
_rest = ks.rest


def _hook(K, k, dt, iterations, U, Wv, until_fixed):
    calls.append((K[:k].copy(), U.copy(), Wv.copy()))
    return _rest(K, k, dt, iterations, U, Wv, until_fixed)


ks.rest = _hook
if os.environ.get("PILE"):  # a pile saved by pile_class.py --save: one step from there
    import pickle

    from vrsim_cli.loop import run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import parse_scene

    with open(os.environ["PILE"], "rb") as f:
        _src, _state = pickle.load(f)
    _model = compile_model(parse_scene(_src))
    _stops = iter((False, True))
    run(_model, _state, resume=True, should_stop=lambda: next(_stops))
    DT = _model.dt
    MU = float(calls[0][0][0, ks.K_MU])  # every box's and the floor's
    NEED = MU
else:  # the pyramid: its first step
    bodies = "\n".join(
        f"  - {{name: s{k}, mass: 1.0, position: {[float(x) for x in p]}, shape: {{type: sphere, "
        f"radius: {R_S}}}, material: {{friction: {MU!r}, restitution: 0}}}}"
        for k, p in enumerate(centres(R_S, LAYERS)))
    vrsim_cli.simulate(vrsim_cli.load(
        f"vrsim: 1\nduration: 1.0\nframe_rate: {1 / DT!r}\ndt: {DT!r}\nintegrator: verlet\n"
        "gravity: [0, -9.81, 0]\ncollision: {}\nbodies:\n  - {name: ground, type: static, "
        "shape: {type: plane, normal: [0, 1, 0]}, material: {friction: " + repr(MU)
        + ", restitution: 0}}\n" + bodies + "\n")).step(1)
K, U0, W0 = calls[0]
rows = [i for i in range(K.shape[0]) if int(K[i, ks.K_MODE]) == ks.IMPULSE]
m, n = len(rows), U0.shape[0]

# Delassus matrix A (3m x 3m) and free velocities b, through the kernel's own rows
A = np.zeros((3 * m, 3 * m))
for c in range(3 * m):
    U, W = np.zeros((n, 3)), np.zeros((n, 3))
    ks.apply(K, rows[c // 3], c % 3, 1.0, U, W)
    for r, i in enumerate(rows):
        A[3 * r:3 * r + 3, c] = ks.rel3(K, i, U, W)
b = np.zeros(3 * m)
for r, i in enumerate(rows):
    vn, v1, v2 = ks.rel3(K, i, U0, W0)
    b[3 * r:3 * r + 3] = (vn - ks._target(K, i, DT), v1 + K[i, ks.K_V0T],
                          v2 + K[i, ks.K_V0T + 1])
# the rest is called with the warm start's impulses already applied (a later step: the
# last step's): take them out, so that every solver solves for the whole impulse
LAM_WARM = np.array([K[i, ks.K_LN + j] for i in rows for j in range(3)])
b -= A @ LAM_WARM
print(f"{os.environ.get('PILE') or len(centres(R_S, LAYERS))} (bodies), mu {MU:.4f}: "
      f"{m} contacts, {3 * m} rows, "
      f"rank {np.linalg.matrix_rank(A)}")

# Which part of b no impulses can reach (outside range(A) = range(J): a set of velocity
# targets no motion of the bodies meets), with the targets as they are, without the
# normal ones (gap and the mean hold's K_V0N: `_target`), and also without friction's
# mean-hold slips K_V0T. Pile rk4 202 at 6 s: 9e-2 (the gaps of open contacts, which
# need not be met), 3.8e-6, 7e-16: K_V0T is the unreachable part (docs/benchmarks.md).
_u, _s, _ = np.linalg.svd(A)
_R = _u[:, :int((_s > 1e-12 * _s[0]).sum())]
_tn = np.zeros(3 * m)
_tn[0::3] = [ks._target(K, i, DT) for i in rows]
_tt = np.array([[0.0, K[i, ks.K_V0T], K[i, ks.K_V0T + 1]] for i in rows]).ravel()
print("b outside range(A), m/s: as is %.1e, normal targets out %.1e, also K_V0T out %.1e"
      % tuple(np.abs(x - _R @ (_R.T @ x)).max() for x in (b, b + _tn, b + _tn - _tt)))

# statics through the kernel's rows: every contact held (w = 0) by impulses in 8-gons
S = 8
P = np.zeros((3 * m, m * S))
for r in range(m):
    for e in range(S):
        a = 2 * math.pi * e / S
        inner = MU * math.cos(math.pi / S)
        P[3 * r:3 * r + 3, r * S + e] = (1.0, inner * math.cos(a), inner * math.sin(a))
lp = linprog(np.zeros(m * S), A_eq=A @ P, b_eq=-b, bounds=(0, None), method="highs")
print("every contact held inside its cone (LP):", "feasible" if lp.status == 0 else lp.message)


def report(name, sweep, lam):
    w = A @ lam + b
    ln = lam[0::3]
    loaded = ln > 1e-12 * max(ln.max(), 1e-300)
    slip = np.hypot(w[1::3], w[2::3])[loaded]
    edge = np.hypot(lam[1::3], lam[2::3])[loaded] >= (1.0 - 1e-6) * MU * ln[loaded]
    print(f"  {name:8s} {sweep:5d} sweeps: max |w_t| of loaded contacts "
          f"{slip.max() if len(slip) else 0.0:.2e} m/s, approach past target "
          f"{max(-w[0::3].min(), 0.0):.2e} m/s, {edge.sum()} of {loaded.sum()} loaded "
          "on their cone's edge", flush=True)


PHI = np.linspace(0.0, 2.0 * math.pi, 256, endpoint=False)


def cone_block(B, c, mu):
    """argmin 1/2 l'Bl + c'l over |l_t| <= mu l_n: inside, or on the boundary (an angle
    search: 256 samples, then golden sections), or zero."""
    free = -np.linalg.solve(B, c)
    if free[0] >= 0.0 and math.hypot(free[1], free[2]) <= mu * free[0]:
        return free

    def along(phi):
        d = np.stack([np.ones_like(phi), mu * np.cos(phi), mu * np.sin(phi)])
        cd, dbd = c @ d, np.einsum("ik,ij,jk->k", d, B, d)
        s = np.maximum(0.0, -cd / dbd)
        return 0.5 * s * s * dbd + s * cd, s, d

    k = int(np.argmin(along(PHI)[0]))
    lo, hi = PHI[k] - 2 * math.pi / 256, PHI[k] + 2 * math.pi / 256
    for _ in range(40):
        m1, m2 = lo + 0.382 * (hi - lo), lo + 0.618 * (hi - lo)
        lo, hi = (lo, m2) if along(np.array([m1]))[0][0] < along(np.array([m2]))[0][0] \
            else (m1, hi)
    f, s, d = along(np.array([0.5 * (lo + hi)]))
    return s[0] * d[:, 0] if f[0] < 0.0 else np.zeros(3)


marks = {2 ** p for p in range(3, 13)} | {SWEEPS}
lam = np.zeros(3 * m)  # coulomb: the kernel's split rows
ONLY = os.environ.get("ONLY", "coulomb pyramid block desaxce").split()  # newton: ask
for sweep in range(1, SWEEPS + 1 if "coulomb" in ONLY else 1):
    for r in range(m):
        i0 = 3 * r
        lam[i0] = max(0.0, lam[i0] - (A[i0] @ lam + b[i0]) / A[i0, i0])
        lt = lam[i0 + 1:i0 + 3] - np.linalg.solve(A[i0 + 1:i0 + 3, i0 + 1:i0 + 3],
                                                  A[i0 + 1:i0 + 3] @ lam + b[i0 + 1:i0 + 3])
        lim, norm = MU * lam[i0], math.hypot(*lt)
        lam[i0 + 1:i0 + 3] = lt * (lim / norm) if norm > lim else lt
    if sweep in marks:
        report("coulomb", sweep, lam)
H, g = P.T @ A @ P, P.T @ b
x = np.zeros(m * S)  # pyramid: the convex problem on the generators' weights
for sweep in range(1, SWEEPS + 1 if "pyramid" in ONLY else 1):
    for e in range(m * S):
        x[e] = max(0.0, x[e] - (H[e] @ x + g[e]) / H[e, e])
    if sweep in marks:
        report("pyramid", sweep, P @ x)
for name in [name for name in ("block", "desaxce") if name in ONLY]:
    lam = np.zeros(3 * m)
    for sweep in range(1, SWEEPS + 1):
        for r in range(m):
            sl = slice(3 * r, 3 * r + 3)
            B = A[sl, sl]
            c = A[sl] @ lam - B @ lam[sl] + b[sl]
            if name == "block":
                lam[sl] = cone_block(B, c, MU)
            else:
                le = lam[sl].copy()
                for _ in range(4):
                    w = B @ le + c
                    le = cone_block(B, c + np.array([MU * math.hypot(w[1], w[2]), 0, 0]), MU)
                lam[sl] = le
        if sweep in marks:
            report(name, sweep, lam)


# "newton": the convex problem's primal in the bodies' space (MuJoCo's Newton solver, with
# hard contacts approximated by a stiff penalty): minimise over body velocities v
#   1/2 (v - v0)' M (v - v0) + sum_i D_i/2 dist(w_i, C_i)^2,  w_i = J_i v + c_i,
# C_i = {w : w_n >= mu |w_t|} (the velocities Anitescu's relaxation allows), D_i =
# 1 / (EPS A_ii): a contact's impulse D_i (Pi(w_i) - w_i) lies in its friction cone, and
# its velocity misses C_i by EPS A_ii |l_i|. Newton's direction from M + sum J' D (I - dPi)
# J, an exact line search (bisection on the slope). J and M^-1 J' come from the kernel's
# own functions (rel3 of unit body velocities, apply of unit impulses), M from them.
def cone_projection(w, mu):
    """(Pi(w), dPi/dw) for C = {w_n >= mu |w_t|}."""
    s = math.hypot(w[1], w[2])
    if w[0] >= mu * s:
        return w.copy(), np.eye(3)
    if mu * w[0] <= -s:
        return np.zeros(3), np.zeros((3, 3))
    u = w[1:] / s  # onto C's edge (mu, 1) in the plane of the normal and u
    t = (mu * w[0] + s) / (1.0 + mu * mu)
    p = np.array([mu * t, t * u[0], t * u[1]])
    d = np.empty((3, 3))
    d[0, 0] = mu * mu / (1.0 + mu * mu)
    d[0, 1:] = d[1:, 0] = mu * u / (1.0 + mu * mu)
    d[1:, 1:] = np.outer(u, u) / (1.0 + mu * mu) + t * (np.eye(2) - np.outer(u, u)) / s
    return p, d


if "newton" in ONLY:
    EPS = float(os.environ.get("EPS", "1e-10"))
    J = np.zeros((3 * m, 6 * n))
    for col in range(6 * n):
        U, W = np.zeros((n, 3)), np.zeros((n, 3))
        (U if col % 6 < 3 else W)[col // 6, col % 3] = 1.0
        for r, i in enumerate(rows):
            J[3 * r:3 * r + 3, col] = ks.rel3(K, i, U, W)
    G = np.zeros((6 * n, 3 * m))  # M^-1 J'
    for c in range(3 * m):
        U, W = np.zeros((n, 3)), np.zeros((n, 3))
        ks.apply(K, rows[c // 3], c % 3, 1.0, U, W)
        G[:, c] = np.concatenate([U, W], axis=1).ravel()
    Minv = G @ np.linalg.pinv(J.T)  # exact where J' spans a body's six directions
    moving = np.abs(G).sum(axis=1) > 0  # static and kinematic bodies take no velocity
    Mm = np.linalg.inv(Minv[np.ix_(moving, moving)])
    Jm = J[:, moving]
    v0 = (np.concatenate([U0, W0], axis=1).ravel() - G @ LAM_WARM)[moving]
    c0 = b - Jm @ v0
    D = 1.0 / (EPS * np.diag(A))

    def report_newton(label, v, ggl):
        g, _, lam = ggl
        w = Jm @ v + c0
        ln = lam[0::3]
        loaded = ln > 1e-12 * max(ln.max(), 1e-300)
        slip = np.hypot(w[1::3], w[2::3])[loaded]
        print(f"  newton {label}: loaded contacts' slip "
              f"{slip.max() if len(slip) else 0.0:.2e} m/s, approach past target "
              f"{max(-w[0::3].min(), 0.0):.2e} m/s, {loaded.sum()} loaded", flush=True)

    def gradient(v, hessian):
        """(the cost's gradient, its Hessian or None, the contacts' impulses)."""
        w = Jm @ v + c0 - shift
        g = Mm @ (v - v0)
        H = Mm.copy() if hessian else None
        lam = np.zeros(3 * m)
        for r in range(m):
            sl = slice(3 * r, 3 * r + 3)
            p, dp = cone_projection(w[sl], MU)
            lam[sl] = D[3 * r] * (p - w[sl])
            g -= Jm[sl].T @ lam[sl]
            if hessian:
                H += D[3 * r] * Jm[sl].T @ (np.eye(3) - dp) @ Jm[sl]
        return g, H, lam

    # exact line search: the cost is convex along the step, so its slope rises through 0;
    # OUTER > 1: the method of multipliers (augmented Lagrangian): the constraint shifted
    # by the last impulses / D, so the penalty's miss EPS A_ii |l| goes to 0 at fixed EPS
    OUTER = int(os.environ.get("OUTER", "1"))
    INNER = int(os.environ.get("INNER", "100"))  # Newton steps per outer round, at most
    GTOL = float(os.environ.get("GTOL", "1e-13"))  # an outer round ends at this |gradient|
    RULE = os.environ.get("RULE", "first")  # "terms": GTOL of the gradient's terms' size
    shift = np.zeros(3 * m)
    v = v0.copy()
    g0 = np.abs(gradient(v, False)[0]).max()
    total = 0
    for outer in range(OUTER):
        for it in range(1, INNER + 1):
            g, H, lam = gradient(v, True)
            # done: the gradient at GTOL of its own terms' size (RULE=terms: momentum
            # and impulses, whose difference is not resolved below their round-off), or
            # at GTOL of the first round's first gradient (RULE=first)
            terms = np.abs(Mm @ (v - v0)).max() + np.abs(Jm.T @ lam).max()
            if np.abs(g).max() <= (GTOL * terms if RULE == "terms" else GTOL * g0):
                break
            step = -np.linalg.solve(H, g)
            lo, hi = 0.0, 1.0
            while gradient(v + hi * step, False)[0] @ step < 0.0 and hi < 1e6:
                lo, hi = hi, 2.0 * hi
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if gradient(v + mid * step, False)[0] @ step < 0.0 \
                    else (lo, mid)
            v = v + hi * step
            total += 1
            if OUTER == 1 and it in (1, 2, 3, 5, 8, 12, 20, 30, 50, 100):
                report_newton(f"{it:5d} steps", v, gradient(v, False))
        g, _, lam = gradient(v, False)
        if OUTER > 1:
            report_newton(f"outer {outer + 1}, {total} Newton steps in all", v, (g, None, lam))
        shift = np.concatenate([lam[3 * r:3 * r + 3] / D[3 * r] for r in range(m)])
