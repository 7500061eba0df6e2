# Usage: python tests/probes/island_solvers.py REPO_ROOT [LAYERS [MU_FACTOR [SWEEPS]]]
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
"""Four solves of one large island's resting contacts, against statics (issue 48 (d))."""
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
print(f"{len(centres(R_S, LAYERS))} spheres, mu {MU:.4f}: {m} contacts, {3 * m} rows, "
      f"rank {np.linalg.matrix_rank(A)}")

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
ONLY = os.environ.get("ONLY", "coulomb pyramid block desaxce").split()
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
