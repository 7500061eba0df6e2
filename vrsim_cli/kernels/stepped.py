"""Stepped impacts, compiled: one whole step of many colliding bodies in one call.

`collision.impacts: auto` (docs/collision-response.md, "The default: one compiled step").
From the state S at the step's start, one call of `entry(...)` does:

1. the kick: the velocities v* = v0 + dt a after the step's forces (kernels.dynamics);
2. speculative detection (`kernels.collide`): every pair whose gap is within what the
   two bodies can travel in the step (sweep_a + sweep_b, sweep = dt (|v| + |w| rbound)
   with the larger of the start and kicked speeds) plus the tolerance;
3. impacts, at the step's start: a contact that approaches faster than the bounce speed
   (rest_speed) and would close within the step takes Newton's restitution relative to
   its approach velocity at the step's start, with Coulomb friction; all points of one
   pair (a face, an edge) in one solve taken to convergence, the pairs one after the
   other in order of contact with repeats while any pair still approaches (propagation of
   impulses, Guendelman, Bridson & Fedkiw 2003: a Newton's cradle passes its impulse down
   the chain), restitution 0 for a contact after MAX_ELASTIC_PASSES impulses;
4. rest: sequential impulses (Gauss-Seidel, warm-started) on the kicked velocities with
   the speculative bound: the normal velocity at the end of the step may close the gap g
   exactly, v_n >= -max(g, 0)/dt, and friction in the Coulomb cone (a disc, so sliding
   opposes the sliding velocity);
5. if a body now moves farther than its sweep, its missing pairs are found and the solve
   goes on (a ball knocked by another must not tunnel through a wall it was not tested
   against);
6. small islands (bodies joined by contacts, at most SMALL_ISLAND_ROWS rows) rest on to
   convergence and are polished by Newton's method (`rest_small_islands`,
   `kernels.coulomb`); larger ones keep the scene's `iterations` sweeps and the shock
   levels;
7. Moreau-Jean's theta = 1/2: the impacts' velocity change is added to the start state
   (positions move by all of it), the resting impulses go to the scene's integrator as
   a constant wrench (impulse / dt per body), so a second-order integrator moves a body
   by the mean of its start and end velocities and steady sliding and rolling are
   exact (symplectic Euler keeps x1 = x0 + dt v1; Euler moves a body that took a
   resting impulse by symplectic Euler). For that mean velocity to be consistent with
   contact, every approach that closes within the step is an impact (`impact_pair`),
   a pair that held at the end of the last step holds in the mean (`_target`, the
   friction of `_rest_row`), and the position pass closes loaded contacts that end
   apart (docs/collision-response.md, "Integration");
8. whatever still penetrates is pushed out along the normals by pseudo-velocities
   (a position-only Gauss-Seidel): positions and orientations change, velocities do
   not, and a body turned by it keeps its body-frame angular momentum, so its kinetic
   energy is unchanged.

Why restitution relative to the start of the step, and not to the kicked velocity as in
Box2D: with symplectic Euler the energy of a step with contact impulses P applied at the
step's start is E1 - E0 = KE(v0 + M^-1 J^T P) - KE(v0) - dt^2 |f|^2_{M^-1}/2 under constant
forces f (docs/collision-response.md has the derivation), so impacts that do not gain
kinetic energy (eps <= 1) give a step that does not gain energy. Restitution on v* would
add the step's gravity work to every bounce (a ball with eps = 1 gains ~2 m g dt |v| per
bounce).

Layout (as kernels.dynamics): the model of the dynamics mf, the geometry table gf
(kernels.collide), the response tables rb (n, RB_SIZE) [mode, eps, mu, rbound] (NaN:
not set) and rp (p, RP_SIZE) [key a * n + b, mode (-1: not set), eps, mu] sorted by key,
the parameters prm (PR_SIZE), the state rows S (n, 13), RS (r, 12). Contacts live in a
table K (k, K_SIZE) with named columns.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.kernels import collide as kc
from vrsim_cli.kernels import coulomb as kcb
from vrsim_cli.kernels import dynamics as kd
from vrsim_cli.kernels import linalg as la
from vrsim_cli.kernels import pinv as kp
from vrsim_cli.kernels.jit import kernel

NONE, STOP, SLIDE, IMPULSE = range(4)  # as model.response
RB_MODE, RB_EPS, RB_MU, RB_RBOUND, RB_SIZE = 0, 1, 2, 3, 4
RP_KEY, RP_MODE, RP_EPS, RP_MU, RP_SIZE = 0, 1, 2, 3, 4
PR_DT, PR_TOL, PR_BOUNCE, PR_ITER, PR_POS_ITER, PR_SLOP, PR_PLANAR, PR_H_PROP, \
    PR_DEF_EPS, PR_DEF_MU, PR_STEP, PR_T = range(12)
PR_SIZE = 12

# contact table K (k, K_SIZE)
K_A, K_B = 0, 1
K_N, K_T1, K_T2 = 2, 5, 8  # basis: normal A -> B, two tangents
K_RNA, K_RNB, K_R1A, K_R1B, K_R2A, K_R2B = 11, 14, 17, 20, 23, 26  # arm x direction
K_RA, K_RB = 29, 32  # arms from the centres of mass to the witness points, m
K_MN = 35  # 1 / K along n
K_KT = 36  # the tangent block K_t: t1t1, t1t2, t2t2
K_FSTEP = 39  # 1 / largest eigenvalue of K_t: the step of the friction projection
K_EPS, K_MU, K_MODE = 40, 41, 42
K_GAP = 43  # m, the gap at the step's start (-depth)
K_KICK = 44  # m/s: the kick's change of the relative velocity along n, t1, t2
K_LN, K_LT = 47, 48  # resting impulses (normal, two tangents), N s
K_IN, K_IT = 50, 51  # impact impulses (normal, two tangents), N s
K_PASSES = 53  # impacts this contact took part in
K_Q = 54  # position pass: accumulated pseudo-impulse
K_SEND = 55  # m, the separation after the integrator moved the bodies
K_DEPTH = 56  # m, as detected
K_P = 57  # m, contact point (midpoint of the witness points), world
K_WNA, K_WNB, K_W1A, K_W1B, K_W2A, K_W2B = 60, 63, 66, 69, 72, 75  # I^-1 (arm x direction)
K_IMA, K_IMB = 78, 79  # inverse masses, 1/kg
K_SN = 80  # shock propagation's impulses on the upper body (normal, two tangents), N s
K_LK = 83  # impact impulses with the bodies' turning locked (normal, two tangents), N s
K_KLIN = 86  # m/s: the kick's change of the relative linear velocity along n, t1, t2
K_ROUND = 89  # m: the rounding radii at the witness points on A and B (collide.C_ROUND_A)
K_V0N = 91  # m/s: a held contact's normal velocity at the step's start (impacts in), if > 0
K_V0T = 92  # m/s: a stuck contact's slip velocity (two tangents) at the step's start
K_SIZE = 94

MAX_ELASTIC_PASSES = 32  # impacts per contact in a step before its restitution drops to 0
MAX_IMPACT_SWEEPS = 64  # sweeps over the pairs of the impact phase
IMPACT_ITERATIONS = 5000  # Gauss-Seidel sweeps of one pair's impact, at most (to
# convergence: a face's four corners have a singular Delassus matrix and the sweeps
# converge slowly; 100 left edge landings up to 0.48 of their speed off the planar
# impact, 1000 one 3e-8). The sweeps stop earlier (`_impact_done`) when
IMPACT_CONVERGED = 1e-14  # no impulse changes by more than this share of the largest,
IMPACT_SETTLED = 1e-15  # or the bodies' velocities by no more than this share of theirs,
IMPACT_WINDOW = 50  # or the largest velocity change of a window of this many sweeps has
IMPACT_PROGRESS = 0.8  # not fallen to this share of the last window's: no convergence
# (piles of boxes with friction cycle: with the 5000 alone they ran 7-14 times slower)
MAX_IMPACT_TURN = 0.25 * math.pi  # rad: an impact that would turn a body more in one step
# is solved with its turning locked (a linearised corner impact of a fast box spun it at
# ~1e4 rad/s, and it passed through a thin wall in the next step)
MAX_ROUNDS = 4  # searches for pairs a body knocked faster than its sweep
SWEEP_GROWTH = 1.5  # a knocked body's new sweep: this times its travel (no re-search for
# the last ulps)
APPROACH_EPS = 1e-12  # m/s: slower is not approaching


# ----------------------------------------------------------------------------- bodies


@kernel
def body_tables(mf, step, S, RS, inv_m, IW):
    """inv_m (n,) 1/kg of the bodies that move (dynamic and in the scene), else 0; IW
    (n, 9) the world inverse inertia R I^-1 R^T of the freely turning ones, else 0."""
    n = S.shape[0]
    ob = int(mf[kd.H_BODY])
    for b in range(n):
        i = ob + b * kd.B_SIZE
        moving = mf[i + kd.B_DYNAMIC] != 0.0 and mf[i + kd.B_EMIT] <= step
        inv_m[b] = mf[i + kd.B_INV_MASS] if moving else 0.0
        for c in range(9):
            IW[b, c] = 0.0
    for k in range(RS.shape[0]):
        i = kd.at(mf, kd.H_ROT, k, kd.RT_SIZE)
        b = int(mf[i + kd.RT_INDEX])
        if mf[i + kd.RT_KINEMATIC] != 0.0 or inv_m[b] == 0.0:
            continue
        W = la.sandwich(kd.row9(RS, k, kd.RS_R), kd.mat9(mf, i + kd.RT_INV_INERTIA))
        for c in range(9):
            IW[b, c] = W[c]


@kernel
def kick(mf, step, t, dt, S, RS, inv_m, IW, acc, M, Wr, ext0, V0, W0, U, Wv):
    """Start velocities V0, W0 (n, 3) and the kicked ones U, Wv = v0 + dt a, w0 + dt
    I^-1 M (world), the forces of kernels.dynamics at the step's start (no contact)."""
    n = S.shape[0]
    if int(mf[kd.H_S]):
        kd.omegas(mf, RS, Wr)
    kd.forces(mf, step, t, S, RS, Wr, ext0, acc, M)
    for b in range(n):
        for c in range(3):
            V0[b, c] = S[b, kd.S_VEL + c]
            W0[b, c] = S[b, kd.S_ANGVEL + c]
            U[b, c] = V0[b, c] + dt * acc[b, c]
            Wv[b, c] = W0[b, c]
    for k in range(RS.shape[0]):
        i = kd.at(mf, kd.H_ROT, k, kd.RT_SIZE)
        b = int(mf[i + kd.RT_INDEX])
        if mf[i + kd.RT_KINEMATIC] != 0.0 or inv_m[b] == 0.0:
            continue
        dw = la.matvec(kd.row9(IW, b, 0), la.scale(dt, kd.row3(M, k, 0)))
        for c in range(3):
            Wv[b, c] = W0[b, c] + dw[c]


@kernel
def sweeps(dt, V0, W0, U, Wv, rb, out):
    """out (n,) m: how far a point of each body can move in the step, dt (|v| + |w|
    rbound) with the larger of the start and the current speeds."""
    for b in range(V0.shape[0]):
        v = max(la.norm(kd.row3(V0, b, 0)), la.norm(kd.row3(U, b, 0)))
        w = max(la.norm(kd.row3(W0, b, 0)), la.norm(kd.row3(Wv, b, 0)))
        d = v
        if w > 0.0:
            d += w * rb[b, RB_RBOUND]
        out[b] = dt * d


# ----------------------------------------------------------------------------- contacts


@kernel
def pair_material(rb, rp, a, b, n, def_eps, def_mu):
    """(mode, eps, mu) of bodies a < b: the more restrictive mode, the larger eps, the
    geometric mean of mu (a value one body sets is used as it is), a pair entry replacing
    them (model.response.ResponseModel.pair_values)."""
    mode = min(int(rb[a, RB_MODE]), int(rb[b, RB_MODE]))
    ea, eb = rb[a, RB_EPS], rb[b, RB_EPS]
    if ea != ea:
        eps = eb
    elif eb != eb:
        eps = ea
    else:
        eps = max(ea, eb)
    if eps != eps:
        eps = def_eps
    fa, fb = rb[a, RB_MU], rb[b, RB_MU]
    if fa != fa:
        mu = fb
    elif fb != fb:
        mu = fa
    else:
        mu = math.sqrt(fa * fb)
    if mu != mu:
        mu = def_mu
    p = rp.shape[0]
    if p:
        key = a * n + b
        lo, hi = 0, p
        while lo < hi:
            mid = (lo + hi) // 2
            if rp[mid, RP_KEY] < key:
                lo = mid + 1
            else:
                hi = mid
        if lo < p and rp[lo, RP_KEY] == key:
            if rp[lo, RP_MODE] >= 0.0:
                mode = int(rp[lo, RP_MODE])
            if rp[lo, RP_EPS] == rp[lo, RP_EPS]:
                eps = rp[lo, RP_EPS]
            if rp[lo, RP_MU] == rp[lo, RP_MU]:
                mu = rp[lo, RP_MU]
    return mode, eps, mu


@kernel
def basis(n):
    """Two unit tangents completing n to a right-handed basis; a normal in the xy plane
    (all of 2D) gets t1 in the plane and t2 = +-z, so 2D stays exactly planar."""
    if n[2] == 0.0:
        t1 = (-n[1], n[0], 0.0)
        return t1, la.cross(n, t1)
    helper = (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0)
    t1 = la.cross(n, helper)
    length = la.norm(t1)
    t1 = (t1[0] / length, t1[1] / length, t1[2] / length)
    return t1, la.cross(n, t1)


@kernel(inline="always")
def put(K, i, c, v):
    K[i, c] = v[0]
    K[i, c + 1] = v[1]
    K[i, c + 2] = v[2]


@kernel(inline="always")
def get(K, i, c):
    return (K[i, c], K[i, c + 1], K[i, c + 2])


@kernel
def prepare(K, i, C, q, S, inv_m, IW, V0, W0, U, Wv, rb, rp, prm):
    """Contact row i of K from detection row q of C: basis, arms to the witness points
    (P -+ depth/2 n: a sphere's arm is its radius even while it penetrates), the arm
    crosses (a sphere's r x n, round-off only, is dropped so pushing it never turns it),
    effective masses, material, and the kick's change of the relative velocity."""
    a, b = int(C[q, kc.C_A]), int(C[q, kc.C_B])
    n_body = S.shape[0]
    K[i, K_A] = a
    K[i, K_B] = b
    n = (C[q, kc.C_N], C[q, kc.C_N + 1], C[q, kc.C_N + 2])
    p = (C[q, kc.C_P], C[q, kc.C_P + 1], C[q, kc.C_P + 2])
    depth = C[q, kc.C_D]
    t1, t2 = basis(n)
    half = la.scale(0.5 * depth, n)
    ra = la.sub(la.add(p, half), kd.row3(S, a, kd.S_POS))
    rbv = la.sub(la.sub(p, half), kd.row3(S, b, kd.S_POS))
    rna, rnb = la.cross(ra, n), la.cross(rbv, n)
    if la.norm(rna) <= 1e-12 * la.norm(ra):
        rna = (0.0, 0.0, 0.0)
    if la.norm(rnb) <= 1e-12 * la.norm(rbv):
        rnb = (0.0, 0.0, 0.0)
    r1a, r1b = la.cross(ra, t1), la.cross(rbv, t1)
    r2a, r2b = la.cross(ra, t2), la.cross(rbv, t2)
    put(K, i, K_N, n)
    put(K, i, K_T1, t1)
    put(K, i, K_T2, t2)
    put(K, i, K_RNA, rna)
    put(K, i, K_RNB, rnb)
    put(K, i, K_R1A, r1a)
    put(K, i, K_R1B, r1b)
    put(K, i, K_R2A, r2a)
    put(K, i, K_R2B, r2b)
    put(K, i, K_RA, ra)
    put(K, i, K_RB, rbv)
    put(K, i, K_P, p)
    Ia, Ib = kd.row9(IW, a, 0), kd.row9(IW, b, 0)
    wna, wnb = la.matvec(Ia, rna), la.matvec(Ib, rnb)
    w1a, w1b = la.matvec(Ia, r1a), la.matvec(Ib, r1b)
    w2a, w2b = la.matvec(Ia, r2a), la.matvec(Ib, r2b)
    put(K, i, K_WNA, wna)
    put(K, i, K_WNB, wnb)
    put(K, i, K_W1A, w1a)
    put(K, i, K_W1B, w1b)
    put(K, i, K_W2A, w2a)
    put(K, i, K_W2B, w2b)
    K[i, K_IMA] = inv_m[a]
    K[i, K_IMB] = inv_m[b]
    m = inv_m[a] + inv_m[b]
    kn = m + la.dot(rna, wna) + la.dot(rnb, wnb)
    K[i, K_MN] = 1.0 / kn if kn > 0.0 else 0.0
    k11 = m + la.dot(r1a, w1a) + la.dot(r1b, w1b)
    k12 = la.dot(r1a, w2a) + la.dot(r1b, w2b)
    k22 = m + la.dot(r2a, w2a) + la.dot(r2b, w2b)
    K[i, K_KT] = k11
    K[i, K_KT + 1] = k12
    K[i, K_KT + 2] = k22
    mean, dif = 0.5 * (k11 + k22), 0.5 * (k11 - k22)
    top = mean + math.sqrt(dif * dif + k12 * k12)
    K[i, K_FSTEP] = 1.0 / top if top > 0.0 else 0.0
    mode, eps, mu = pair_material(rb, rp, a, b, n_body, prm[PR_DEF_EPS], prm[PR_DEF_MU])
    K[i, K_MODE] = mode
    K[i, K_EPS] = eps
    K[i, K_MU] = mu
    K[i, K_GAP] = -depth
    K[i, K_DEPTH] = depth
    K[i, K_ROUND] = C[q, kc.C_ROUND_A]
    K[i, K_ROUND + 1] = C[q, kc.C_ROUND_B]
    for j in range(3):
        K[i, K_KICK + j] = rel(K, i, j, U, Wv) - rel(K, i, j, V0, W0)
        K[i, K_KLIN + j] = _lin(K, i, j, U) - _lin(K, i, j, V0)
    for c in range(K_LN, K_SEND + 1):
        K[i, c] = 0.0
    for c in range(K_SN, K_LK + 3):
        K[i, c] = 0.0
    K[i, K_V0N] = 0.0
    K[i, K_V0T] = 0.0
    K[i, K_V0T + 1] = 0.0


@kernel(inline="always")
def rel(K, i, j, V, W):
    """Relative velocity of contact i along its direction j (0: n, 1: t1, 2: t2):
    d.(v_B - v_A) + (r_B x d).w_B - (r_A x d).w_A."""
    a, b = int(K[i, K_A]), int(K[i, K_B])
    d = get(K, i, K_N + 3 * j)
    ca = get(K, i, K_RNA + 6 * j)
    cb = get(K, i, K_RNB + 6 * j)
    return (d[0] * (V[b, 0] - V[a, 0]) + d[1] * (V[b, 1] - V[a, 1]) + d[2] * (V[b, 2] - V[a, 2])
            + cb[0] * W[b, 0] + cb[1] * W[b, 1] + cb[2] * W[b, 2]
            - ca[0] * W[a, 0] - ca[1] * W[a, 1] - ca[2] * W[a, 2])


@kernel(inline="always")
def apply(K, i, j, lam, U, Wv):
    """An impulse lam along direction j of contact i: +lam d on B, -lam d on A (at their
    arms), into the velocities U, Wv (n, 3); the impulse sums are made once at the end
    (`wrench`)."""
    if lam == 0.0:
        return
    a, b = int(K[i, K_A]), int(K[i, K_B])
    d, wa, wb = K_N + 3 * j, K_WNA + 6 * j, K_WNB + 6 * j
    sa, sb = lam * K[i, K_IMA], lam * K[i, K_IMB]
    for c in range(3):
        U[b, c] += sb * K[i, d + c]
        Wv[b, c] += lam * K[i, wb + c]
        U[a, c] -= sa * K[i, d + c]
        Wv[a, c] -= lam * K[i, wa + c]


@kernel(inline="always")
def rel3(K, i, U, Wv):
    """Relative velocity of contact i along n, t1, t2 (as `rel`, all three at once)."""
    a, b = int(K[i, K_A]), int(K[i, K_B])
    dv = (U[b, 0] - U[a, 0], U[b, 1] - U[a, 1], U[b, 2] - U[a, 2])
    out0 = out1 = out2 = 0.0
    for j in range(3):
        d, ca, cb = K_N + 3 * j, K_RNA + 6 * j, K_RNB + 6 * j
        v = dv[0] * K[i, d] + dv[1] * K[i, d + 1] + dv[2] * K[i, d + 2] \
            + K[i, cb] * Wv[b, 0] + K[i, cb + 1] * Wv[b, 1] + K[i, cb + 2] * Wv[b, 2] \
            - K[i, ca] * Wv[a, 0] - K[i, ca + 1] * Wv[a, 1] - K[i, ca + 2] * Wv[a, 2]
        if j == 0:
            out0 = v
        elif j == 1:
            out1 = v
        else:
            out2 = v
    return out0, out1, out2


@kernel(inline="always")
def _add_impulse(K, i, j, lam, DP, DL, turning):
    """lam along direction j of contact i into the sums DP, DL (n, 3): +lam on B, -lam
    on A, with their torques through the arm crosses when `turning`."""
    a, b = int(K[i, K_A]), int(K[i, K_B])
    d, ca, cb = K_N + 3 * j, K_RNA + 6 * j, K_RNB + 6 * j
    for c in range(3):
        DP[b, c] += lam * K[i, d + c]
        DP[a, c] -= lam * K[i, d + c]
        if turning:
            DL[b, c] += lam * K[i, cb + c]
            DL[a, c] -= lam * K[i, ca + c]


@kernel
def wrench(K, k, DP, DL, DPi, DLi):
    """The impulse sums (N s, N m s; world; (n, 3) each) through the same arm crosses the
    velocities saw: the resting impulses into DP, DL, the impacts' into DPi, DLi (impacts
    with turning locked push without torque)."""
    for i in range(k):
        for j in range(3):
            if K[i, K_LN + j] != 0.0:
                _add_impulse(K, i, j, K[i, K_LN + j], DP, DL, True)
            if K[i, K_IN + j] != 0.0:
                _add_impulse(K, i, j, K[i, K_IN + j], DPi, DLi, True)
            if K[i, K_LK + j] != 0.0:
                _add_impulse(K, i, j, K[i, K_LK + j], DPi, DLi, False)


@kernel(inline="always")
def friction(K, i, lt1, lt2, vt1, vt2, limit):
    """The next tangent impulse (lt1, lt2) for tangential velocity (vt1, vt2) within the
    Coulomb disc of radius `limit`: the impulse that stops the sliding (the 2x2 block of
    K_t) when it lies in the disc, else a projected step along -vt (scalar step 1/lambda_max
    of K_t), whose fixed points are exactly Coulomb's law: friction opposite to the
    sliding velocity at its limit, or sticking."""
    k11, k12, k22 = K[i, K_KT], K[i, K_KT + 1], K[i, K_KT + 2]
    det = k11 * k22 - k12 * k12
    if det > 0.0:
        s1 = lt1 - (k22 * vt1 - k12 * vt2) / det
        s2 = lt2 - (k11 * vt2 - k12 * vt1) / det
        if s1 * s1 + s2 * s2 <= limit * limit:
            return s1, s2
    h = K[i, K_FSTEP]
    s1, s2 = lt1 - h * vt1, lt2 - h * vt2
    norm = math.sqrt(s1 * s1 + s2 * s2)
    if norm > limit:
        scale = limit / norm if norm > 0.0 else 0.0
        return s1 * scale, s2 * scale
    return s1, s2


# ----------------------------------------------------------------------------- impacts


@kernel
def impact_pair(K, c0, c1, dt, bounce, U, Wv, lam, mean):
    """The impact of one pair's points c0 .. c1 - 1 at the step's start, if any of them
    approaches faster than `bounce` and would close within the step: all its approaching
    points in one Gauss-Seidel solve to convergence, each normal towards -eps v_n (v_n its
    approach velocity before this impact, at the step's start: the current one less the
    kick), the slower ones towards -gap/dt (they arrive; gap: the pair's smallest), with Coulomb
    friction; a plastic impact (eps 0) also aims at -gap/dt: it lands on the surface.
    `mean` (positions move by the mean velocity): a pair whose points all approach
    slower than `bounce` takes its (plastic) impact too. Returns whether it acted.
    lam (>= 3 (c1 - c0),): scratch."""
    fast = False
    m = c1 - c0
    # a pair arrives as a whole: every point may close at most the pair's smallest gap
    # (points aiming at their own gaps would spin the body to meet them all: a bullet box
    # spun at 1e4 rad/s and went through a wall)
    gap = math.inf
    for q in range(m):
        gap = min(gap, K[c0 + q, K_GAP])
    arrive = -max(gap, 0.0) / dt
    for q in range(m):
        i = c0 + q
        lam[3 * q] = -1.0  # not in this impact
        if int(K[i, K_MODE]) != IMPULSE:
            continue
        vn = rel3(K, i, U, Wv)[0] - K[i, K_KICK]
        if vn < -APPROACH_EPS and K[i, K_GAP] + dt * (vn + K[i, K_KICK]) < 0.0:
            eps = K[i, K_EPS] if K[i, K_PASSES] < MAX_ELASTIC_PASSES else 0.0
            # the target: Newton's law; a plastic one lands on the surface (closes the gap
            # exactly) instead of stopping short of it (as Box2D v3, which skips its
            # restitution pass for eps = 0); an elastic one turns at the step's start, up
            # to eps |v_n| dt short of the surface (docs/collision-response.md)
            if vn < -bounce:
                fast = True
                lam[3 * q + 1] = -eps * vn if eps > 0.0 else arrive
            else:
                lam[3 * q + 1] = arrive
            # slow ones too where positions move by the mean velocity: an approach at the
            # step's start is stopped at the step's start, so that the positions move by
            # the stopped velocity (a slow approach stopped by the rest would end
            # h |v_n| / 2 deep, and the position pass would lift it: energy from nowhere)
            fast = fast or mean
            lam[3 * q] = 0.0
    if not fast:
        return False
    a, b = int(K[c0, K_A]), int(K[c0, K_B])
    saved = np.empty((4, 3))
    for c in range(3):
        saved[0, c], saved[1, c] = U[a, c], U[b, c]
        saved[2, c], saved[3, c] = Wv[a, c], Wv[b, c]
    tl = np.zeros((m, 3))  # accumulated impulses of this impact: n, t1, t2
    vb = np.zeros((m, 3))  # each point's start-of-step velocity before this impact
    for q in range(m):
        if lam[3 * q] >= 0.0:
            _start_velocity(K, c0 + q, U, Wv, vb, q)
    frictionless = True
    for q in range(m):
        if lam[3 * q] >= 0.0 and K[c0 + q, K_MU] > 0.0:
            frictionless = False
    if not (frictionless and _exact_normals(K, c0, m, lam, vb, tl, U, Wv)):
        if not _direct_impact(K, c0, m, lam, vb, tl, U, Wv):
            _impact_solve(K, c0, m, lam, tl, U, Wv, True)
    gain, scale = _impact_work(K, c0, m, lam, tl, vb, U, Wv)
    if gain > IMPACT_GAIN_ROUNDOFF * scale:
        # Newton's law at the points solved together with Coulomb friction can add
        # energy (friction changes the normal velocity through the arms, and the law then
        # asks for more normal impulse: measured +0.18 J on 7 J for a spinning capsule
        # landing with eps = 1, mu = 0.3). Then as located mode's solver does: the
        # normal impulses alone (they cannot add energy: each acting point ends at -eps
        # times its approach, sum lam (1 - eps) v / 2 <= 0), friction after them, and
        # that friction shortened along itself where it would add energy.
        for c in range(3):
            U[a, c], U[b, c] = saved[0, c], saved[1, c]
            Wv[a, c], Wv[b, c] = saved[2, c], saved[3, c]
        for q in range(m):
            tl[q, 0] = tl[q, 1] = tl[q, 2] = 0.0
        if not _exact_normals(K, c0, m, lam, vb, tl, U, Wv):
            _impact_solve(K, c0, m, lam, tl, U, Wv, False)
        _impact_friction(K, c0, m, lam, tl, U, Wv)
    turn = 0.0
    for c in range(3):
        turn = max(turn, abs(Wv[a, c] - saved[2, c]), abs(Wv[b, c] - saved[3, c]))
    if turn * dt > MAX_IMPACT_TURN / math.sqrt(3.0):  # (a component bound of |dw| dt)
        for c in range(3):
            U[a, c], U[b, c] = saved[0, c], saved[1, c]
            Wv[a, c], Wv[b, c] = saved[2, c], saved[3, c]
        _locked_impact(K, c0, m, lam, tl, U, Wv)
        return True
    for q in range(m):
        if lam[3 * q] < 0.0:
            continue
        i = c0 + q
        K[i, K_IN] += tl[q, 0]
        K[i, K_IT] += tl[q, 1]
        K[i, K_IT + 1] += tl[q, 2]
        K[i, K_PASSES] += 1.0
    return True


IMPACT_GAIN_ROUNDOFF = 1e-12  # an impact's energy change above this share of its
# impulses' work |lam . v| is a gain, not round-off


SLIP_ROUNDS = 32  # stick/slip status and slip-direction updates of `_direct_impact`
SLIP_TURN = 1e-10  # rad: a sliding point's slip direction is settled when it turns less


@kernel
def _sub_pinv(W, rows, nr):
    """(A, P): A = W's submatrix of rows[:nr] (rows and columns), shaped (1, nr, nr) for
    `kernels.pinv`, and P its pseudo-inverse (singular values below 1e-10 of the
    largest dropped: a face's corners make W singular)."""
    A = np.empty((1, nr, nr))
    for r in range(nr):
        for t in range(nr):
            A[0, r, t] = W[rows[r], rows[t]]
    P = np.empty((1, nr, nr))
    kp.pinv_symmetric(A, 1e-10, P)
    return A, P


@kernel
def _direct_impact(K, c0, m, lam, vb, tl, U, Wv):
    """An impact of two or more points (lam[3q] >= 0) solved at once, when it can be: every
    normal to its target lam[3q + 1] and, where mu > 0, every point sticking, as one
    minimum-norm solve W x = goal - v over those rows (W = J M^-1 J^T of the pair's two
    bodies; the pseudo-inverse of `kernels.pinv`, singular values below 1e-10 of the
    largest dropped: a face's corners make W singular). Where a point's friction would
    leave its cone, the point slides instead: friction mu lam_n against its slip after
    the impact, statuses and slip directions updated until they agree (`_slip_solve`,
    the located solver's `solver._slipping_solve`). Applied (into U, Wv and tl) and True
    when it is a solution: the targets are met (residual <= 1e-9 of the velocity
    scale), no normal impulse pulls and every friction lies in (or, sliding, on) its
    cone; else False and nothing changed, and the sweeps solve the impact. Why: the
    sweeps over a face's corners converge slowly, and cycle in piles, where this solve is
    exact at once (the located solver's sticking round, `solver._sticking_round`); the
    caller's energy check still rejects a solution that adds energy (Kane's paradox).
    vb (m, 3): the points' start-of-step velocities before the impact
    (`_start_velocity`)."""
    n_pts = 0
    for q in range(m):
        if lam[3 * q] >= 0.0:
            n_pts += 1
            if K[c0 + q, K_PASSES] > 0.0:
                return False  # a later round of a chain or pile: left to the sweeps
    if n_pts < 2:
        return False
    pq = np.empty(n_pts, np.int64)  # the impact's points, in order
    mu = np.empty(n_pts)
    p = 0
    for q in range(m):
        if lam[3 * q] >= 0.0:
            pq[p] = q
            mu[p] = K[c0 + q, K_MU]
            p += 1
    nf = 3 * n_pts
    Wf = np.empty((nf, nf))  # rows 3 p + j: point p, direction j (n, t1, t2)
    im = K[c0, K_IMA] + K[c0, K_IMB]
    for r in range(nf):
        i, j = c0 + pq[r // 3], r % 3
        for t in range(nf):
            i2, j2 = c0 + pq[t // 3], t % 3
            w = 0.0
            for c in range(3):
                w += im * K[i, K_N + 3 * j + c] * K[i2, K_N + 3 * j2 + c] \
                    + K[i, K_RNB + 6 * j + c] * K[i2, K_WNB + 6 * j2 + c] \
                    + K[i, K_RNA + 6 * j + c] * K[i2, K_WNA + 6 * j2 + c]
            Wf[r, t] = w
    rhs = np.empty(nf)  # goal - v
    scale = 0.0
    for r in range(nf):
        v = vb[pq[r // 3], r % 3]
        goal = lam[3 * pq[r // 3] + 1] if r % 3 == 0 else 0.0
        rhs[r] = goal - v
        scale = max(scale, abs(v), abs(goal))
    # every point sticking: the rows n (and t1, t2 where mu > 0), W symmetric
    rows = np.empty(nf, np.int64)
    nr = 0
    for p in range(n_pts):
        for j in range(3 if mu[p] > 0.0 else 1):
            rows[nr] = 3 * p + j
            nr += 1
    A, P = _sub_pinv(Wf, rows, nr)
    xs = np.zeros(nr)
    largest = 0.0
    for r in range(nr):
        for t in range(nr):
            xs[r] += P[0, r, t] * rhs[rows[t]]
        largest = max(largest, abs(xs[r]))
    for r in range(nr):  # the targets met: W x = rhs
        wx = 0.0
        for t in range(nr):
            wx += A[0, r, t] * xs[t]
        if not abs(wx - rhs[rows[r]]) <= 1e-9 * scale:
            return False
    x = np.zeros(nf)
    for r in range(nr):
        x[rows[r]] = xs[r]
    over = np.zeros(n_pts, np.bool_)
    if not _in_cones(x, mu, 1e-12 * largest, 0.0, 0.0, over):
        # the minimum-norm share among the points is one of many when W is singular (a
        # face's corners): look for a share inside the cones (`_inside_cones`)
        _inside_cones(P[0], A[0], xs, rows, nr, mu)
        largest = 0.0
        for r in range(nr):
            x[rows[r]] = xs[r]
            largest = max(largest, abs(xs[r]))
    if not _in_cones(x, mu, 1e-12 * largest, CONE_ROUNDOFF, 1e-12 * largest, over):
        # some point slides, if any can: first only those over their cones, then every
        # point that slips (as `solver._sticking_round`)
        rubbing = False
        for p in range(n_pts):
            rubbing = rubbing or mu[p] > 0.0
        if not rubbing:
            return False
        start = x.copy()
        if not _slip_solve(Wf, rhs, mu, over, x, scale, False):
            x[:] = start
            if not _slip_solve(Wf, rhs, mu, over, x, scale, True):
                return False
    for p in range(n_pts):
        i = c0 + pq[p]
        for j in range(3):
            apply(K, i, j, x[3 * p + j], U, Wv)
            tl[pq[p], j] = x[3 * p + j]
    return True


# The normal impulses of an impact alone (no friction) are a linear complementarity
# problem: w = W x + (v - t) >= 0, x >= 0, w . x = 0 with W = J M^-1 J^T symmetric
# positive semidefinite, i.e. the convex problem min 1/2 x.W x + x.(v - t), x >= 0, whose
# velocities W x are unique. Gauss-Seidel reaches them only slowly where two points'
# rows are nearly parallel (two corners of one edge): its stop for slow progress then
# left a frictionless elastic box-box impact 1e-3 of its energy off, gains included.
# Small impacts are solved exactly instead: every set of acting points, the larger sets
# first, is tried as the minimum-norm solve of its rows, and the first that is a solution
# (its rows met, no point pulling, the others at or above their targets) is taken.
EXACT_NORMAL_POINTS = 4  # points solved so: 2^4 - 1 = 15 sets of at most 4 x 4 at worst
EXACT_NORMAL_MET = 1e-12  # relative to the velocity scale: a row met, a point not pulling


@kernel
def _exact_normals(K, c0, m, lam, vb, tl, U, Wv):
    """The normal impulses of the impact's points (lam[3q] >= 0) towards their targets
    lam[3q + 1] solved exactly (the comment above), for at most EXACT_NORMAL_POINTS of
    them and at least two: applied into U, Wv and tl[:, 0] and True, else False and
    nothing changed. vb
    (m, 3): the points' start-of-step velocities before the impact."""
    n_pts = 0
    for q in range(m):
        if lam[3 * q] >= 0.0:
            n_pts += 1
    if n_pts < 2 or n_pts > EXACT_NORMAL_POINTS:
        return False  # one point: the sweep is exact at once
    pq = np.empty(n_pts, np.int64)
    p = 0
    for q in range(m):
        if lam[3 * q] >= 0.0:
            pq[p] = q
            p += 1
    Wn = np.empty((n_pts, n_pts))
    im = K[c0, K_IMA] + K[c0, K_IMB]
    for r in range(n_pts):
        i = c0 + pq[r]
        for t in range(n_pts):
            i2 = c0 + pq[t]
            w = 0.0
            for c in range(3):
                w += im * K[i, K_N + c] * K[i2, K_N + c] + K[i, K_RNB + c] * K[i2, K_WNB + c] \
                    + K[i, K_RNA + c] * K[i2, K_WNA + c]
            Wn[r, t] = w
    rhs = np.empty(n_pts)
    scale = 0.0
    for r in range(n_pts):
        v, goal = vb[pq[r], 0], lam[3 * pq[r] + 1]
        rhs[r] = goal - v
        scale = max(scale, abs(v), abs(goal))
    met = EXACT_NORMAL_MET * scale
    x = np.zeros(n_pts)
    for size in range(n_pts, 0, -1):
        for bits in range(1, 1 << n_pts):
            count = 0
            for r in range(n_pts):
                count += (bits >> r) & 1
            if count != size:
                continue
            rows = np.empty(size, np.int64)
            nr = 0
            for r in range(n_pts):
                if (bits >> r) & 1:
                    rows[nr] = r
                    nr += 1
            _, P = _sub_pinv(Wn, rows, nr)
            ok = True
            for r in range(n_pts):
                x[r] = 0.0
            for r in range(nr):
                for t in range(nr):
                    x[rows[r]] += P[0, r, t] * rhs[rows[t]]
                if x[rows[r]] < -met * (1.0 / Wn[rows[r], rows[r]] if Wn[rows[r], rows[r]]
                                        > 0.0 else 0.0):
                    ok = False
            if not ok:
                continue
            for r in range(n_pts):  # rows met where acting, at or above elsewhere
                wx = 0.0
                for t in range(n_pts):
                    wx += Wn[r, t] * x[t]
                acting = (bits >> r) & 1
                if acting and not abs(wx - rhs[r]) <= met:
                    ok = False
                if not acting and not wx - rhs[r] >= -met:
                    ok = False
            if ok:
                for r in range(n_pts):
                    xr = max(x[r], 0.0)
                    apply(K, c0 + pq[r], 0, xr, U, Wv)
                    tl[pq[r], 0] = xr
                return True
    return False


CONE_ROUNDS = 5000  # alternating projections of `_inside_cones`, at most,
CONE_WINDOW = 100  # and they stop when a window of this many rounds has not shrunk the
CONE_PROGRESS = 0.9  # step to this share of the last window's (as the located solver's)
CONE_ROUNDOFF = 1e-9  # relative: friction this little outside its cone is inside


@kernel
def _in_cones(x, mu, pull, roundoff, tiny, over):
    """Whether x (3 n,: n, t1, t2 per point) pulls nowhere (no normal below -pull) and
    has every friction in its cone (|t| <= mu max(n, 0) (1 + roundoff) + tiny); over
    (n,) bool: set where a friction leaves its cone."""
    inside = True
    for p in range(mu.shape[0]):
        xn = x[3 * p]
        over[p] = False
        if xn < -pull:
            inside = False
        if mu[p] > 0.0:
            f = math.sqrt(x[3 * p + 1] * x[3 * p + 1] + x[3 * p + 2] * x[3 * p + 2])
            if f > mu[p] * max(xn, 0.0) * (1.0 + roundoff) + tiny:
                over[p] = True
                inside = False
    return inside


@kernel
def _inside_cones(P, A, xs, rows, nr, mu):
    """xs (nr,) on the rows `rows` (3 p + j) replaced by impulses that solve the same
    equations (A xs = b, P the pseudo-inverse of A) with every point's friction inside
    its cone, if alternating projections find them (von Neumann's method between the
    solutions and the cones, to CONE_ROUNDOFF, at most CONE_ROUNDS, stopped when the
    steps stop shrinking); else the last iterate, which the caller's cone check rejects. As the located solver's `solver._inside_cones`: a
    box landing flat and sticking with its load on the leading edge got minimum-norm
    friction outside the trailing corners' cones."""
    b = np.empty(nr)
    for r in range(nr):
        acc = 0.0
        for t in range(nr):
            acc += A[r, t] * xs[t]
        b[r] = acc
    res = np.empty(nr)
    before = np.empty(nr)
    last = math.inf
    for round_ in range(CONE_ROUNDS):
        for q in range(nr):
            before[q] = xs[q]
        r = 0
        while r < nr:  # onto the cones (normals >= 0, |t| <= mu n)
            m = mu[rows[r] // 3]
            if m > 0.0 and r + 2 < nr and rows[r + 1] == rows[r] + 1:
                n, t1, t2 = xs[r], xs[r + 1], xs[r + 2]
                t = math.sqrt(t1 * t1 + t2 * t2)
                if t > m * n:
                    if m * t <= -n:
                        xs[r] = xs[r + 1] = xs[r + 2] = 0.0
                    else:
                        n2 = (n + m * t) / (1.0 + m * m)
                        f = m * n2 / t
                        xs[r], xs[r + 1], xs[r + 2] = n2, f * t1, f * t2
                r += 3
            else:
                xs[r] = max(xs[r], 0.0)
                r += 1
        for q in range(nr):  # back onto the solutions: xs - P (A xs - b)
            acc = -b[q]
            for t in range(nr):
                acc += A[q, t] * xs[t]
            res[q] = acc
        largest = 0.0
        for q in range(nr):
            acc = 0.0
            for t in range(nr):
                acc += P[q, t] * res[t]
            xs[q] -= acc
            largest = max(largest, abs(xs[q]))
        inside = True
        r = 0
        while r < nr:
            m = mu[rows[r] // 3]
            if xs[r] < -1e-12 * largest:
                inside = False
                break
            if m > 0.0 and r + 2 < nr and rows[r + 1] == rows[r] + 1:
                t = math.sqrt(xs[r + 1] * xs[r + 1] + xs[r + 2] * xs[r + 2])
                if t > m * max(xs[r], 0.0) * (1.0 + CONE_ROUNDOFF) + 1e-12 * largest:
                    inside = False  # (+ a corner left with no load: 0 +- round-off)
                    break
                r += 3
            else:
                r += 1
        if inside:
            return
        if (round_ + 1) % CONE_WINDOW == 0:  # stop when the steps stop shrinking
            step = 0.0
            for q in range(nr):
                step = max(step, abs(xs[q] - before[q]))
            if step >= CONE_PROGRESS * last:
                return
            last = step


@kernel
def _slip_solve(Wf, rhs, mu, over, x, scale, every):
    """The impulses x (3 n,) of an impact with some points sliding: Newton's law on the
    normal rows, each point with friction sticking (slip 0, friction inside its cone) or
    sliding (friction -mu x_n s, s its slip direction after the impact, not reversed),
    updating statuses and directions until they agree (SLIP_ROUNDS, to SLIP_TURN). First
    every point with friction that slips after a frictionless impact slides, in that
    direction; one that does not but whose sticking friction (in x) is `over` its cone,
    against that friction (starting from the sticking friction alone, whose share among
    a face's corners is arbitrary, a box landing flat while sliding cycled). Each
    round is one minimum-norm solve of the square A y = rhs on the normal rows and the
    sticking points' tangent rows, y the normal impulses and sticking frictions (A =
    Wf B, B mapping y to the impulses; not symmetric, so through A^T A's
    pseudo-inverse), kept when it meets its rows to 1e-9 of `scale`. True with x the
    solution, or False (x undefined) when none is found. `every`: every point that slips
    without friction starts sliding, else only those `over` their cones. A point whose
    normal would pull leaves the solve (the most pulling ones), and must then not be
    driven below its target. Wf (3 n, 3 n): the Delassus matrix over every point's n,
    t1, t2; rhs (3 n,): goal - v. As the located solver's `solver._slipping_solve`."""
    n = mu.shape[0]
    nf = 3 * n
    # the frictionless impact (normal rows, minimum-norm) and the slip after it
    Wn = np.empty((1, n, n))
    for p in range(n):
        for p2 in range(n):
            Wn[0, p, p2] = Wf[3 * p, 3 * p2]
    Pn = np.empty((1, n, n))
    kp.pinv_symmetric(Wn, 1e-10, Pn)
    xn = np.zeros(n)
    for p in range(n):
        for p2 in range(n):
            xn[p] += Pn[0, p, p2] * rhs[3 * p2]
    slide = np.zeros(n, np.bool_)
    s = np.zeros((n, 2))
    for p in range(n):
        if mu[p] == 0.0:
            continue
        v1, v2 = -rhs[3 * p + 1], -rhs[3 * p + 2]  # (v = goal - rhs: goal 0 along t)
        for p2 in range(n):
            v1 += Wf[3 * p + 1, 3 * p2] * xn[p2]
            v2 += Wf[3 * p + 2, 3 * p2] * xn[p2]
        speed = math.sqrt(v1 * v1 + v2 * v2)
        if speed > 0.0 and (every or over[p]):
            slide[p] = True
            s[p, 0], s[p, 1] = v1 / speed, v2 / speed
        elif over[p]:
            f = math.sqrt(x[3 * p + 1] * x[3 * p + 1] + x[3 * p + 2] * x[3 * p + 2])
            slide[p] = True
            s[p, 0], s[p, 1] = -x[3 * p + 1] / f, -x[3 * p + 2] / f
    rows = np.empty(nf, np.int64)
    w = np.empty(nf)
    pushing = np.ones(n, np.bool_)
    for _ in range(SLIP_ROUNDS):
        nr = 0
        for p in range(n):
            if not pushing[p]:
                continue
            rows[nr] = 3 * p
            nr += 1
            if mu[p] > 0.0 and not slide[p]:
                rows[nr], rows[nr + 1] = 3 * p + 1, 3 * p + 2
                nr += 2
        A = np.empty((nr, nr))  # A[r, u] = (Wf B)[rows[r], u]: column u is row u's unknown
        for r in range(nr):
            for u in range(nr):
                c = rows[u]
                a = Wf[rows[r], c]
                if c % 3 == 0 and slide[c // 3]:
                    p = c // 3
                    a -= mu[p] * (s[p, 0] * Wf[rows[r], c + 1] + s[p, 1] * Wf[rows[r], c + 2])
                A[r, u] = a
        N = np.empty((1, nr, nr))
        g = np.zeros(nr)
        for u in range(nr):
            for u2 in range(nr):
                acc = 0.0
                for r in range(nr):
                    acc += A[r, u] * A[r, u2]
                N[0, u, u2] = acc
            for r in range(nr):
                g[u] += A[r, u] * rhs[rows[r]]
        P = np.empty((1, nr, nr))
        kp.pinv_symmetric(N, 1e-10, P)
        y = np.zeros(nr)
        for u in range(nr):
            for u2 in range(nr):
                y[u] += P[0, u, u2] * g[u2]
        for r in range(nr):
            ay = 0.0
            for u in range(nr):
                ay += A[r, u] * y[u]
            if not abs(ay - rhs[rows[r]]) <= 1e-9 * scale:
                return False
        for c in range(nf):
            x[c] = 0.0
        for u in range(nr):
            c = rows[u]
            x[c] = y[u]
            if c % 3 == 0 and slide[c // 3]:
                p = c // 3
                x[c + 1] = -mu[p] * s[p, 0] * y[u]
                x[c + 2] = -mu[p] * s[p, 1] * y[u]
        for r in range(nf):  # the change of velocity W x (the velocity after less before)
            acc = 0.0
            for c in range(nf):
                acc += Wf[r, c] * x[c]
            w[r] = acc
        largest = 0.0
        least = 0.0
        for u in range(nr):
            largest = max(largest, abs(y[u]))
            if rows[u] % 3 == 0:
                least = min(least, y[u])
        if least < -1e-12 * largest:  # the most pulling points leave (no impulse there)
            left = 0
            for p in range(n):
                if pushing[p] and x[3 * p] <= least + 1e-9 * abs(least) + 1e-15 * largest:
                    pushing[p] = False
                    slide[p] = False
                if pushing[p]:
                    left += 1
            if left == 0:
                return False
            continue
        settled = True
        for p in range(n):
            if not pushing[p]:  # it left: not driven below its target
                if w[3 * p] - rhs[3 * p] < -1e-12 * scale:
                    return False
                continue
            if mu[p] == 0.0:
                continue
            # the slip after: (v + W x) along t1, t2, with v = goal - rhs = -rhs there
            v1, v2 = w[3 * p + 1] - rhs[3 * p + 1], w[3 * p + 2] - rhs[3 * p + 2]
            if slide[p]:
                along = v1 * s[p, 0] + v2 * s[p, 1]
                if along <= 1e-12 * scale:  # the slip reversed: it sticks
                    slide[p] = False
                    settled = False
                    continue
                speed = math.sqrt(v1 * v1 + v2 * v2)
                d1, d2 = v1 / speed, v2 / speed
                if max(abs(d1 - s[p, 0]), abs(d2 - s[p, 1])) > SLIP_TURN:
                    settled = False
                s[p, 0], s[p, 1] = d1, d2
            else:
                f = math.sqrt(x[3 * p + 1] * x[3 * p + 1] + x[3 * p + 2] * x[3 * p + 2])
                if f > mu[p] * x[3 * p]:
                    slide[p] = True
                    s[p, 0], s[p, 1] = -x[3 * p + 1] / f, -x[3 * p + 2] / f
                    settled = False
        if settled:
            return True
    return False


@kernel(inline="always")
def _start_velocity(K, i, U, Wv, out, q):
    """out[q] = contact i's relative velocity along n, t1, t2 less the kick's change."""
    v0, v1, v2 = rel3(K, i, U, Wv)
    out[q, 0] = v0 - K[i, K_KICK]
    out[q, 1] = v1 - K[i, K_KICK + 1]
    out[q, 2] = v2 - K[i, K_KICK + 2]


@kernel
def _impact_solve(K, c0, m, lam, tl, U, Wv, with_friction):
    """Gauss-Seidel over the impact's points (lam[3q] >= 0) to convergence: each normal
    towards its target lam[3q + 1] (a start-of-step velocity), with Coulomb friction at
    each point when `with_friction`. Accumulates into tl (m, 3). Converged when a sweep
    changes no impulse by more than IMPACT_CONVERGED of the largest, or the bodies'
    velocities by no more than IMPACT_SETTLED of theirs, or stop converging
    (`_impact_done`)."""
    before = np.empty(12)
    marks = np.zeros(2)
    for sweep in range(IMPACT_ITERATIONS):
        _velocities(K, c0, U, Wv, before)
        change, size = 0.0, 0.0
        for q in range(m):
            if lam[3 * q] < 0.0:
                continue
            i = c0 + q
            vn = rel3(K, i, U, Wv)[0] - K[i, K_KICK]
            new = max(tl[q, 0] + (lam[3 * q + 1] - vn) * K[i, K_MN], 0.0)
            d = new - tl[q, 0]
            tl[q, 0] = new
            apply(K, i, 0, d, U, Wv)
            d1 = d2 = 0.0
            if with_friction:
                _, vt1, vt2 = rel3(K, i, U, Wv)
                vt1 -= K[i, K_KICK + 1]
                vt2 -= K[i, K_KICK + 2]
                s1, s2 = friction(K, i, tl[q, 1], tl[q, 2], vt1, vt2, K[i, K_MU] * new)
                d1, d2 = s1 - tl[q, 1], s2 - tl[q, 2]
                tl[q, 1], tl[q, 2] = s1, s2
                apply(K, i, 1, d1, U, Wv)
                apply(K, i, 2, d2, U, Wv)
            change = max(change, abs(d), abs(d1), abs(d2))
            size = max(size, new)
        if _impact_done(sweep, change, size, _velocity_change(K, c0, U, Wv, before), marks):
            break


@kernel(inline="always")
def _velocities(K, c0, U, Wv, out):
    """out (12,) = the linear and angular velocities of the pair's bodies A and B."""
    a, b = int(K[c0, K_A]), int(K[c0, K_B])
    for c in range(3):
        out[c], out[3 + c] = U[a, c], U[b, c]
        out[6 + c], out[9 + c] = Wv[a, c], Wv[b, c]


@kernel
def _velocity_change(K, c0, U, Wv, before):
    """How much a sweep changed the pair's body velocities (`_velocities` before it):
    the larger of the linear and the angular change, each relative to its size."""
    a, b = int(K[c0, K_A]), int(K[c0, K_B])
    dv = dw = sv = sw = 0.0
    for c in range(3):
        dv = max(dv, abs(U[a, c] - before[c]), abs(U[b, c] - before[3 + c]))
        dw = max(dw, abs(Wv[a, c] - before[6 + c]), abs(Wv[b, c] - before[9 + c]))
        sv = max(sv, abs(U[a, c]), abs(U[b, c]))
        sw = max(sw, abs(Wv[a, c]), abs(Wv[b, c]))
    return max(dv / sv if sv > 0.0 else 0.0, dw / sw if sw > 0.0 else 0.0)


@kernel(inline="always")
def _impact_done(sweep, change, size, moved, marks):
    """Whether an impact's Gauss-Seidel stops after sweep `sweep` (from 0): the impulses
    changed by `change` at most (their largest `size`), the bodies' velocities by `moved`
    (relative, `_velocity_change`). Stop when the impulses or the velocities no longer
    change (IMPACT_CONVERGED, IMPACT_SETTLED), or when the sweeps no longer converge: the
    largest `moved` of each window of IMPACT_WINDOW sweeps must have fallen to
    IMPACT_PROGRESS of the window before's (marks (2,): this window's and the last's).
    Why both: a face's four corners have a singular Delassus matrix and converge slowly
    but surely (edge landings needed ~3000 sweeps to be right to 1e-9, not monotonically),
    while in piles of boxes with friction the sweeps cycle and never converge (a cap of
    5000 made such piles 7-14 times slower than 100, for nothing)."""
    if change <= IMPACT_CONVERGED * size or moved <= IMPACT_SETTLED:
        return True
    marks[0] = max(marks[0], moved)
    if (sweep + 1) % IMPACT_WINDOW == 0:
        if sweep + 1 > IMPACT_WINDOW and marks[0] > IMPACT_PROGRESS * marks[1]:
            return True
        marks[1] = marks[0]
        marks[0] = 0.0
    return False


@kernel
def _impact_work(K, c0, m, lam, tl, vb, U, Wv):
    """(kinetic energy change J, its scale J) of the impulses tl (m, 3) of an impact at
    the step's start: an impulse changes the energy by lam . (v_before + v_after) / 2
    (contact-space velocities: lam . J u = (J^T lam) . u); scale: sum |lam| |v| / 2."""
    gain, scale = 0.0, 0.0
    va = np.zeros((1, 3))
    for q in range(m):
        if lam[3 * q] < 0.0:
            continue
        _start_velocity(K, c0 + q, U, Wv, va, 0)
        for j in range(3):
            gain += 0.5 * tl[q, j] * (vb[q, j] + va[0, j])
            scale += 0.5 * abs(tl[q, j]) * (abs(vb[q, j]) + abs(va[0, j]))
    return gain, scale


@kernel
def _impact_friction(K, c0, m, lam, tl, U, Wv):
    """Coulomb friction after an impact's normal impulses tl[:, 0] (fixed): Gauss-Seidel
    to convergence, each point within its disc mu lam_n; then, if the friction as a whole
    would add energy (work lt . vt + lt . W lt / 2 > 0: points clamped into their discs
    by different factors), shortened along itself to the most dissipative point of that
    line, alpha = -lt . vt / lt . W lt in [0, 1) (there the change is -(lt . vt)^2 /
    (2 lt . W lt) < 0), as located mode's `solver._impact_round`."""
    vt = np.zeros((m, 3))
    for q in range(m):
        if lam[3 * q] >= 0.0:
            _start_velocity(K, c0 + q, U, Wv, vt, q)
    before = np.empty(12)
    marks = np.zeros(2)
    for sweep in range(IMPACT_ITERATIONS):
        _velocities(K, c0, U, Wv, before)
        change, size = 0.0, 0.0
        for q in range(m):
            if lam[3 * q] < 0.0 or tl[q, 0] <= 0.0:
                continue
            i = c0 + q
            _, vt1, vt2 = rel3(K, i, U, Wv)
            vt1 -= K[i, K_KICK + 1]
            vt2 -= K[i, K_KICK + 2]
            limit = K[i, K_MU] * tl[q, 0]
            s1, s2 = friction(K, i, tl[q, 1], tl[q, 2], vt1, vt2, limit)
            d1, d2 = s1 - tl[q, 1], s2 - tl[q, 2]
            tl[q, 1], tl[q, 2] = s1, s2
            apply(K, i, 1, d1, U, Wv)
            apply(K, i, 2, d2, U, Wv)
            change = max(change, abs(d1), abs(d2))
            size = max(size, limit)
        if _impact_done(sweep, change, size, _velocity_change(K, c0, U, Wv, before), marks):
            break
    work, curv = 0.0, 0.0
    after = np.zeros((1, 3))
    for q in range(m):
        if lam[3 * q] < 0.0:
            continue
        _start_velocity(K, c0 + q, U, Wv, after, 0)
        for j in range(1, 3):
            work += tl[q, j] * vt[q, j]
            curv += tl[q, j] * (after[0, j] - vt[q, j])  # lt . W lt
    if work + 0.5 * curv <= 0.0:
        return
    alpha = min(max(-work / curv, 0.0), 1.0) if curv > 0.0 else 0.0
    for q in range(m):
        if lam[3 * q] < 0.0:
            continue
        i = c0 + q
        apply(K, i, 1, (alpha - 1.0) * tl[q, 1], U, Wv)
        apply(K, i, 2, (alpha - 1.0) * tl[q, 2], U, Wv)
        tl[q, 1] *= alpha
        tl[q, 2] *= alpha


@kernel
def _locked_impact(K, c0, m, lam, tl, U, Wv):
    """The impact of `impact_pair` with the bodies' turning locked: the two bodies meet as
    particles. Newton's law and Coulomb friction act on the relative velocity of their
    centres of mass (its start-of-step part), through linear impulses only (effective
    mass 1 / (1/m_a + 1/m_b) along every direction); kept in K_LK (no torque in
    `wrench`). The spins are left as they are: aiming a corner's velocity, most of which
    is the spin's, with a push of the centre alone threw a spinning box up at 15 m/s
    (90 J from 10 J). A central impact of two particles with eps <= 1 and friction that
    at most stops the sliding does not gain kinetic energy; what the spin still brings
    towards the surface is the rest's and the position pass's (both dissipative)."""
    im = K[c0, K_IMA] + K[c0, K_IMB]
    if im <= 0.0:
        return
    for q in range(m):
        tl[q, 0] = tl[q, 1] = tl[q, 2] = 0.0
    for q in range(m):
        if lam[3 * q] < 0.0:
            continue
        i = c0 + q
        vn = _lin(K, i, 0, U) - K[i, K_KLIN]
        if vn >= -APPROACH_EPS:
            lam[3 * q + 2] = -1.0  # the centres do not approach here: no impulse
            continue
        lam[3 * q + 2] = 1.0
        eps = K[i, K_EPS] if K[i, K_PASSES] < MAX_ELASTIC_PASSES else 0.0
        # Newton's law on the centres' approach; a plastic one arrives as impact_pair's
        # target says (the pair's smallest gap closed within the step)
        lam[3 * q + 1] = -eps * vn if eps > 0.0 else min(lam[3 * q + 1], 0.0)
    for _ in range(IMPACT_ITERATIONS):
        change, size = 0.0, 0.0
        for q in range(m):
            if lam[3 * q] < 0.0 or lam[3 * q + 2] < 0.0:
                continue
            i = c0 + q
            vn = _lin(K, i, 0, U) - K[i, K_KLIN]
            new = max(tl[q, 0] + (lam[3 * q + 1] - vn) / im, 0.0)
            d0 = new - tl[q, 0]
            tl[q, 0] = new
            _linear(K, i, 0, d0, U)
            s1 = tl[q, 1] - (_lin(K, i, 1, U) - K[i, K_KLIN + 1]) / im
            s2 = tl[q, 2] - (_lin(K, i, 2, U) - K[i, K_KLIN + 2]) / im
            limit = K[i, K_MU] * new
            norm = math.sqrt(s1 * s1 + s2 * s2)
            if norm > limit:
                scale = limit / norm if norm > 0.0 else 0.0
                s1, s2 = s1 * scale, s2 * scale
            d1, d2 = s1 - tl[q, 1], s2 - tl[q, 2]
            tl[q, 1], tl[q, 2] = s1, s2
            _linear(K, i, 1, d1, U)
            _linear(K, i, 2, d2, U)
            change = max(change, abs(d0), abs(d1), abs(d2))
            size = max(size, new)
        if change <= IMPACT_CONVERGED * size:
            break
    for q in range(m):
        if lam[3 * q] < 0.0:
            continue
        i = c0 + q
        for j in range(3):
            K[i, K_LK + j] += tl[q, j]
        K[i, K_PASSES] += 1.0


@kernel(inline="always")
def _lin(K, i, j, U):
    """Relative linear velocity of contact i's bodies (B's less A's) along direction j."""
    a, b = int(K[i, K_A]), int(K[i, K_B])
    d = K_N + 3 * j
    return (K[i, d] * (U[b, 0] - U[a, 0]) + K[i, d + 1] * (U[b, 1] - U[a, 1])
            + K[i, d + 2] * (U[b, 2] - U[a, 2]))


@kernel(inline="always")
def _linear(K, i, j, lam, U):
    """An impulse lam along direction j of contact i on the linear velocities only."""
    if lam == 0.0:
        return
    a, b = int(K[i, K_A]), int(K[i, K_B])
    d = K_N + 3 * j
    for c in range(3):
        U[b, c] += lam * K[i, K_IMB] * K[i, d + c]
        U[a, c] -= lam * K[i, K_IMA] * K[i, d + c]


@kernel
def impacts(K, starts, npairs, first_pair, dt, bounce, U, Wv, changed, mean):
    """The impact phase over the pairs from `first_pair` on (starts (npairs + 1,): the
    first contact of each pair): sweeps in pair order, each pair visited while one of its
    bodies changed in the last sweep, until no pair acts (or MAX_IMPACT_SWEEPS).
    changed (n,) int64: scratch."""
    for b in range(changed.shape[0]):
        changed[b] = -2
    lam = np.empty(3 * kc.MAX_PER_PAIR * 2)
    for sweep in range(MAX_IMPACT_SWEEPS):
        acted = False
        for p in range(first_pair, npairs):
            c0, c1 = starts[p], starts[p + 1]
            a, b = int(K[c0, K_A]), int(K[c0, K_B])
            if sweep > 0 and changed[a] < sweep - 1 and changed[b] < sweep - 1:
                continue
            if c1 - c0 > kc.MAX_PER_PAIR * 2:
                continue
            if impact_pair(K, c0, c1, dt, bounce, U, Wv, lam, mean):
                changed[a] = sweep
                changed[b] = sweep
                acted = True
        if not acted:
            break


# ----------------------------------------------------------------------------- rest


@kernel
def warm_start(K, k, prev_a, prev_b, prev_toi, prev_imp, prev_rest, mean, U, Wv, held):
    """Start the resting impulses from last step's (the same pair and rank within the
    pair; rows of impacts, toi = 0, are not used): the world impulse projected on this
    contact's basis, the normal >= 0, friction in its disc. held (k, 2) bool, out: the
    contact was loaded at the end of the last step (a normal impulse > 0), and it stuck
    (its friction inside the cone, STICK_MARGIN)."""
    for i in range(k):
        held[i, 0] = False
        held[i, 1] = False
    np_ = prev_a.shape[0]
    if np_ == 0 or k == 0:
        return
    j = 0
    i = 0
    while i < k:
        a, b = int(K[i, K_A]), int(K[i, K_B])
        i_end = i
        while i_end < k and int(K[i_end, K_A]) == a and int(K[i_end, K_B]) == b:
            i_end += 1
        while j < np_ and (prev_a[j] < a or (prev_a[j] == a and prev_b[j] < b)):
            j += 1
        j_end = j
        while j_end < np_ and prev_a[j_end] == a and prev_b[j_end] == b:
            j_end += 1
        for q in range(min(i_end - i, j_end - j)):
            row, old = i + q, j + q
            if int(K[row, K_MODE]) != IMPULSE:
                continue
            P = (prev_imp[old, 0], prev_imp[old, 1], prev_imp[old, 2])
            ln = max(la.dot(P, get(K, row, K_N)), 0.0)
            l1, l2 = la.dot(P, get(K, row, K_T1)), la.dot(P, get(K, row, K_T2))
            limit = K[row, K_MU] * ln
            norm = math.sqrt(l1 * l1 + l2 * l2)
            # held by an impact too (a landing that stopped it), but not started from it
            held[row, 0] = ln > 0.0
            held[row, 1] = ln > 0.0 and norm < STICK_MARGIN * limit
            if mean:
                # with the mean every slow approach is an impact: a pile's resting
                # contacts take one each step, so they start from their resting part
                # (from nothing they never converged in a 20-box pile, which then never
                # settled; from the whole impulse, the impact's part broke a mirror case)
                P = (prev_rest[old, 0], prev_rest[old, 1], prev_rest[old, 2])
                ln = max(la.dot(P, get(K, row, K_N)), 0.0)
                l1, l2 = la.dot(P, get(K, row, K_T1)), la.dot(P, get(K, row, K_T2))
                limit = K[row, K_MU] * ln
                norm = math.sqrt(l1 * l1 + l2 * l2)
            elif prev_toi[old] == prev_toi[old]:
                continue
            if norm > limit:
                s = limit / norm if norm > 0.0 else 0.0
                l1, l2 = l1 * s, l2 * s
            K[row, K_LN], K[row, K_LT], K[row, K_LT + 1] = ln, l1, l2
            apply(K, row, 0, ln, U, Wv)
            apply(K, row, 1, l1, U, Wv)
            apply(K, row, 2, l2, U, Wv)
        i = i_end
        j = j_end


@kernel(inline="always")
def _target(K, i, dt):
    """The least normal velocity at the step's end of resting contact i: the gap may
    close within the step; and a contact that held at the end of the last step but
    separates at this step's start (K_V0N > 0: its arm turned with the body, as a box's
    pivoting on an edge) may approach as fast at the end, so that its mean velocity,
    which moves the positions, does not open it (opened, the corner rose 1-13 um a step:
    potential energy no force paid for)."""
    return -max(K[i, K_GAP], 0.0) / dt - K[i, K_V0N]


@kernel(inline="always")
def _normal_row(K, i, dt, U, Wv):
    """The normal part of a Gauss-Seidel update of resting contact i: towards its target
    (`_target`), clamped >= 0. Returns (the new normal impulse, its change), N s."""
    target = _target(K, i, dt)
    vn = rel3(K, i, U, Wv)[0]
    new = max(K[i, K_LN] + (target - vn) * K[i, K_MN], 0.0)
    d0 = new - K[i, K_LN]
    apply(K, i, 0, d0, U, Wv)
    K[i, K_LN] = new
    return new, d0


@kernel(inline="always")
def _set_friction(K, i, s1, s2, U, Wv):
    """Contact i's tangent impulses set to (s1, s2); returns the larger change, N s."""
    d1, d2 = s1 - K[i, K_LT], s2 - K[i, K_LT + 1]
    apply(K, i, 1, d1, U, Wv)
    apply(K, i, 2, d2, U, Wv)
    K[i, K_LT], K[i, K_LT + 1] = s1, s2
    return max(abs(d1), abs(d2))


@kernel(inline="always")
def _rest_row(K, i, dt, U, Wv):
    """One Gauss-Seidel update of resting contact i (`rest`): the normal, then friction
    in the Coulomb disc of the new normal impulse; returns the largest change of its
    three impulses, N s."""
    new, d0 = _normal_row(K, i, dt, U, Wv)
    _, vt1, vt2 = rel3(K, i, U, Wv)
    vt1 += K[i, K_V0T]
    vt2 += K[i, K_V0T + 1]
    s1, s2 = friction(K, i, K[i, K_LT], K[i, K_LT + 1], vt1, vt2, K[i, K_MU] * new)
    return max(abs(d0), _set_friction(K, i, s1, s2, U, Wv))


@kernel(inline="always")
def _sliding_row(K, i, dt, U, Wv, e1, e2):
    """`_rest_row` with the friction held at sliding along the fixed direction -e (unit,
    in t1, t2): mu times the normal impulse, whatever the slip does."""
    new, d0 = _normal_row(K, i, dt, U, Wv)
    return max(abs(d0), _set_friction(K, i, -K[i, K_MU] * new * e1, -K[i, K_MU] * new * e2,
                                      U, Wv))


@kernel
def rest(K, k, dt, iterations, U, Wv, until_fixed):
    """Sequential impulses on the kicked velocities: per contact the normal towards
    v_n >= -max(gap, 0)/dt (a gap may close exactly within the step; a penetration is left
    to the position pass, no velocity is added for it), clamped >= 0, then friction in
    the Coulomb disc of the normal impulse. `until_fixed`: stop after a sweep that changed
    no impulse (a fixed point: the same bits as all `iterations`; the tests compare)."""
    for _ in range(iterations):
        moved = False
        for i in range(k):
            if int(K[i, K_MODE]) != IMPULSE:
                continue
            if _rest_row(K, i, dt, U, Wv) != 0.0:
                moved = True
        if until_fixed and not moved:  # a sweep that changed nothing: every later one
            break  # would repeat it exactly (the same bits as the full count)


# Small islands are solved to convergence. An island is a set of moving bodies joined by
# contacts (static and kinematic bodies do not join: they take any impulse); islands do
# not share a moving body, so sweeping one island's contacts alone is the Gauss-Seidel
# solve of that island. The scene's `iterations` sweeps (8) leave a box sliding on a face
# 1e-5 .. 2e-2 off Coulomb's law in its first steps (the face's four corners make a
# singular system that converges slowly); an island of at most SMALL_ISLAND_ROWS rows
# (3 per contact: 16 contacts, four boxes on their faces) sweeps on until no impulse
# changes by more than REST_SETTLED of the island's largest, at most SMALL_ISLAND_SWEEPS
# times. A box sliding on a face takes up to 285 sweeps (measured over the incline class
# of tests/test_compiled_incline.py; 128 left two of its 40 sliding boxes 4e-9 and 7e-7
# off); islands that converge slowly (a stack of 1 kg plates and 100 kg boxes:
# Gauss-Seidel's rate is near 1 at such mass ratios) stop at the cap, which bounds an
# island's cost to 48 x 512 row updates (~0.4 ms; a cap of 2000 made such a stack 20-41
# times slower per step than 8 sweeps, 512 about a quarter of that). The sweeps find the
# contacts that act and slide but stop at the cap near the friction cone's edge (a slide
# starting within 1 % of it ended up to 6e-4 of a t^2 / 2 off), so Newton's method then
# finishes each island to round-off (`polish_islands`, `kernels.coulomb`).
SMALL_ISLAND_ROWS = 48
SMALL_ISLAND_SWEEPS = 512
REST_SETTLED = 1e-15  # relative: an impulse's own round-off


@kernel
def _root(parent, b):
    while parent[b] != b:
        parent[b] = parent[parent[b]]
        b = parent[b]
    return b


@kernel
def islands(K, k, inv_m, island):
    """island (k,) int64: for each contact the island it belongs to (the root body of its
    moving bodies under union-find over the contacts; -1 for a contact of no moving
    body). Returns rows (n,) int64: 3 x the IMPULSE contacts of each root's island."""
    n = inv_m.shape[0]
    parent = np.arange(n)
    for i in range(k):
        a, b = int(K[i, K_A]), int(K[i, K_B])
        if inv_m[a] != 0.0 and inv_m[b] != 0.0:
            ra, rb_ = _root(parent, a), _root(parent, b)
            if ra != rb_:
                if ra < rb_:
                    parent[rb_] = ra
                else:
                    parent[ra] = rb_
    rows = np.zeros(n, np.int64)
    for i in range(k):
        a, b = int(K[i, K_A]), int(K[i, K_B])
        body = a if inv_m[a] != 0.0 else b
        if inv_m[body] == 0.0:
            island[i] = -1
            continue
        island[i] = _root(parent, body)
        if int(K[i, K_MODE]) == IMPULSE:
            rows[island[i]] += 3
    return rows


@kernel
def delassus(K, idx, m, A):
    """A (3m, 3m): the Delassus matrix J M^-1 J^T of contacts idx[:m] (rows n, t1, t2 of
    each), through the same columns `apply` and `rel` use: the velocity change of row p
    per unit impulse of row q (static and kinematic bodies have no inverse mass)."""
    for p in range(m):
        i = idx[p]
        ai, bi = int(K[i, K_A]), int(K[i, K_B])
        for q in range(m):
            l = idx[q]
            al, bl = int(K[l, K_A]), int(K[l, K_B])
            for j in range(3):
                for jj in range(3):
                    s = 0.0
                    for bi_, si, ci in ((bi, 1.0, K_RNB + 6 * j), (ai, -1.0, K_RNA + 6 * j)):
                        for bl_, sl, wl, im in ((bl, 1.0, K_WNB + 6 * jj, K_IMB),
                                                (al, -1.0, K_WNA + 6 * jj, K_IMA)):
                            if bi_ != bl_ or K[l, im] == 0.0 and K[l, wl] == 0.0 and \
                                    K[l, wl + 1] == 0.0 and K[l, wl + 2] == 0.0:
                                continue
                            d = K[i, K_N + 3 * j] * K[l, K_N + 3 * jj] \
                                + K[i, K_N + 3 * j + 1] * K[l, K_N + 3 * jj + 1] \
                                + K[i, K_N + 3 * j + 2] * K[l, K_N + 3 * jj + 2]
                            s += si * sl * (K[l, im] * d + K[i, ci] * K[l, wl]
                                            + K[i, ci + 1] * K[l, wl + 1]
                                            + K[i, ci + 2] * K[l, wl + 2])
                    A[3 * p + j, 3 * q + jj] = s


@kernel
def _island_met(K, idx, m, dt, U, Wv, fixed, e):
    """Whether contacts idx[:m] (an island) meet Coulomb's law to `coulomb.ROUNDOFF`
    already, as `coulomb.polish` would judge it (its row scales are K_MN and K_FSTEP,
    the same inverse effective masses up to round-off): most islands at rest or sliding
    steadily do after their sweeps, and skip building their Delassus matrix."""
    worst, scale = 0.0, 0.0
    for p in range(m):
        i = idx[p]
        un, ut1, ut2 = rel3(K, i, U, Wv)
        ln, lt1, lt2 = K[i, K_LN], K[i, K_LT], K[i, K_LT + 1]
        tn = _target(K, i, dt)
        rn = K[i, K_MN] if K[i, K_MN] > 0.0 else 1.0
        rt = K[i, K_FSTEP] if K[i, K_FSTEP] > 0.0 else 1.0
        f0, f1, f2 = kcb.contact_residual(ln, lt1, lt2, un, ut1, ut2, tn, K[i, K_V0T],
                                          K[i, K_V0T + 1], K[i, K_MU], fixed[i], e[i, 0],
                                          e[i, 1], rn, rt)
        worst = max(worst, abs(f0), abs(f1), abs(f2))
        scale = max(scale, abs(ln), abs(lt1), abs(lt2), abs(f0), abs(f1), abs(f2),
                    rn * abs(un - tn))
    return worst <= kcb.ROUNDOFF * scale


@kernel
def polish_islands(K, k, dt, U, Wv, island, live, fixed, e):
    """Each island marked `live` (n,) (`island` (k,): each contact's), after its sweeps,
    polished to Coulomb's law (`coulomb.polish`: Newton on Alart-Curnier's function from
    the sweeps' impulses; |F| never grows), the change of its impulses applied to U, Wv.
    `fixed` (k,) contacts slide: their friction is held at mu N along -e (k, 2)
    (`slip_stops`). The contacts are grouped by island once (a scene of many small
    islands costs O(k), not islands x k)."""
    n = live.shape[0]
    count = np.zeros(n + 1, np.int64)
    for i in range(k):
        g = island[i]
        if g >= 0 and live[g] and int(K[i, K_MODE]) == IMPULSE:
            count[g + 1] += 1
    for g in range(n):  # count[g] becomes island g's first slot in `order`
        count[g + 1] += count[g]
    order = np.empty(k, np.int64)
    fill = count[:n].copy()
    for i in range(k):  # contacts in their own order within each island
        g = island[i]
        if g >= 0 and live[g] and int(K[i, K_MODE]) == IMPULSE:
            order[fill[g]] = i
            fill[g] += 1
    for g in range(n):
        m = count[g + 1] - count[g]
        if m == 0:
            continue
        idx = order[count[g]:count[g + 1]]
        if _island_met(K, idx, m, dt, U, Wv, fixed, e):
            continue
        A = np.empty((3 * m, 3 * m))
        delassus(K, idx, m, A)
        u0, lam0, lam = np.empty(3 * m), np.empty(3 * m), np.empty(3 * m)
        tn, off, mu = np.empty(m), np.empty((m, 2)), np.empty(m)
        fx, ee = np.empty(m, np.bool_), np.empty((m, 2))
        for p in range(m):
            i = idx[p]
            v = rel3(K, i, U, Wv)
            for j in range(3):
                u0[3 * p + j] = v[j]
                lam0[3 * p + j] = K[i, K_LN + j]
                lam[3 * p + j] = K[i, K_LN + j]
            tn[p] = _target(K, i, dt)
            off[p, 0], off[p, 1] = K[i, K_V0T], K[i, K_V0T + 1]
            mu[p] = K[i, K_MU]
            fx[p] = fixed[i]
            ee[p, 0], ee[p, 1] = e[i, 0], e[i, 1]
        kcb.polish(A, u0, lam0, tn, off, mu, fx, ee, lam)
        for p in range(m):
            i = idx[p]
            for j in range(3):
                d = lam[3 * p + j] - K[i, K_LN + j]
                apply(K, i, j, d, U, Wv)
                K[i, K_LN + j] = lam[3 * p + j]


@kernel
def rest_small_islands(K, k, dt, inv_m, U, Wv):
    """The rest of every island of at most SMALL_ISLAND_ROWS rows taken on to convergence
    (the comment above): sweeps of those islands' contacts until a sweep changes no
    impulse of an island by more than REST_SETTLED of its largest, then Newton's polish
    (`polish_islands`) where Coulomb's law is not yet met to round-off."""
    if k == 0:
        return
    island = np.empty(k, np.int64)
    rows = islands(K, k, inv_m, island)
    n = inv_m.shape[0]
    live = np.zeros(n, np.bool_)
    any_live = False
    for b in range(n):
        if 0 < rows[b] <= SMALL_ISLAND_ROWS:
            live[b] = True
            any_live = True
    if not any_live:
        return
    fixed, e = np.zeros(k, np.bool_), np.zeros((k, 2))
    swept = live.copy()
    sweep_islands(K, k, dt, U, Wv, island, live, fixed, e)
    polish_islands(K, k, dt, U, Wv, island, swept, fixed, e)


@kernel
def unsettled_islands(K, k, dt, inv_m, U, Wv, island, live):
    """Marks in `live` (n,) the islands above SMALL_ISLAND_ROWS rows (`island` (k,) set
    here: each contact's) whose velocity solve (rest and shock, ending at U, Wv) has not
    met its normal rows; returns whether there is one. A met row ends a loaded point
    (`_loaded`) at its target (`_target`) and any other point not below it; a point off
    by more than position round-off over the step, dt |v_n - target| >
    `_pos_roundoff` (as `push_out`), marks a solve not finished. Unmet, a loaded point
    that ends above its target is pushed apart while it opens (positive work: the
    integrator applies the impulse as a constant force and moves the point by its mean
    velocity), and one below it sinks in, which the position pass then lifts out
    (potential energy no force paid for): with the scene's `iterations` sweeps a pile
    of 20 boxes gained 6.9e-8 of its energy in a step and a row of leaning dominoes
    3.5e-5, and shock propagation held blocks that statics says must tip
    (tests/test_resting_blocks.py). Friction rows are not tested."""
    n = inv_m.shape[0]
    for b in range(n):
        live[b] = False
    if k == 0:
        return False
    rows = islands(K, k, inv_m, island)
    found = False
    for i in range(k):
        g = island[i]
        if g < 0 or rows[g] <= SMALL_ISLAND_ROWS or live[g] or \
                int(K[i, K_MODE]) != IMPULSE:
            continue
        off = rel(K, i, 0, U, Wv) - _target(K, i, dt)
        if not _loaded(K, i):
            off = min(off, 0.0)
        if dt * abs(off) > _pos_roundoff(K, i):
            live[g] = True
            found = True
    return found


@kernel
def sweep_islands(K, k, dt, U, Wv, island, live, fixed, e):
    """Gauss-Seidel sweeps of the contacts of the islands marked `live` (n,) (`island`
    (k,): each contact's), each island until a sweep changes none of its impulses by
    more than REST_SETTLED of its largest, at most SMALL_ISLAND_SWEEPS times. `fixed`
    (k,) contacts slide: their friction is held at mu N along -e (k, 2) (`slip_stops`).
    `live` is consumed."""
    n = live.shape[0]
    change, size = np.zeros(n), np.zeros(n)
    for _ in range(SMALL_ISLAND_SWEEPS):
        for b in range(n):
            change[b] = 0.0
            size[b] = 0.0
        for i in range(k):
            g = island[i]
            if g < 0 or not live[g] or int(K[i, K_MODE]) != IMPULSE:
                continue
            if fixed[i]:
                d = _sliding_row(K, i, dt, U, Wv, e[i, 0], e[i, 1])
            else:
                d = _rest_row(K, i, dt, U, Wv)
            change[g] = max(change[g], d)
            size[g] = max(size[g], abs(K[i, K_LN]), abs(K[i, K_LT]), abs(K[i, K_LT + 1]))
        any_live = False
        for b in range(n):
            if live[b]:
                if change[b] <= REST_SETTLED * size[b]:
                    live[b] = False
                else:
                    any_live = True
        if not any_live:
            break


@kernel
def slide(K, k, dt, inv_m, U, DP):
    """`response: slide` contacts that would close within the step: the slide's
    v <- v - (v.n) n for each movable body moving into the other (linear velocity only,
    no mass weighting, no friction)."""
    for i in range(k):
        if int(K[i, K_MODE]) != SLIDE:
            continue
        if K[i, K_GAP] + dt * rel_linear(K, i, U) >= 0.0:
            continue
        n = get(K, i, K_N)
        for body, sign in ((int(K[i, K_B]), -1.0), (int(K[i, K_A]), 1.0)):
            vn = la.dot(kd.row3(U, body, 0), n)
            if inv_m[body] > 0.0 and sign * vn > 0.0:
                for c in range(3):
                    U[body, c] -= vn * n[c]
                    DP[body, c] -= vn * n[c] / inv_m[body]


@kernel(inline="always")
def rel_linear(K, i, U):
    a, b = int(K[i, K_A]), int(K[i, K_B])
    n = get(K, i, K_N)
    return la.dot(la.sub(kd.row3(U, b, 0), kd.row3(U, a, 0)), n)


# ----------------------------------------------------------------------------- shock


SHOCK_ITERATIONS = 16  # Gauss-Seidel sweeps of a body's contacts in a shock level
FACE_SWEEPS = 4  # times as many for a body with levers (a face) that the direct solve
# left, when the rest loads all its contacts: its redundant rows converge at ~0.5 per
# sweep (a standing cylinder's settling to 1e-9 m needs ~64; spheres in a pile, many of
# which never settle to the bit, and boxes still tumbling in one keep 16: a 200-box pile
# stepped 30 % slower with 64 for all)
STICK_MARGIN = 1.0 - 1e-9  # friction below this share of its limit: the contact sticks


@kernel
def contact_levels(K, k, inv_m, tol, level):
    """level (n,) int64: each body's distance in touching contacts (gap <= tol, a mode
    that pushes) from a body that does not move (level 0); n + 1 when it touches none
    (a cluster in the air). Bellman-Ford over the contacts."""
    n = level.shape[0]
    for b in range(n):
        level[b] = 0 if inv_m[b] == 0.0 else n + 1
    changed = True
    while changed:
        changed = False
        for i in range(k):
            mode = int(K[i, K_MODE])
            if (mode != IMPULSE and mode != SLIDE) or K[i, K_GAP] > tol:
                continue
            a, b = int(K[i, K_A]), int(K[i, K_B])
            if level[a] + 1 < level[b]:
                level[b] = level[a] + 1
                changed = True
            if level[b] + 1 < level[a]:
                level[a] = level[b] + 1
                changed = True


@kernel
def level_order(K, k, level, between):
    """Rows of K ordered by the lower level of their two bodies, ground up (a counting
    sort, stable); `between`: only contacts whose bodies' levels differ. Returns
    (order, m)."""
    n = level.shape[0]
    count = np.zeros(n + 3, np.int64)
    for i in range(k):
        la, lb = level[int(K[i, K_A])], level[int(K[i, K_B])]
        if between and la == lb:
            continue
        count[min(la, lb) + 1] += 1
    for c in range(1, n + 3):
        count[c] += count[c - 1]
    order = np.empty(k, np.int64)
    m = 0
    for i in range(k):
        la, lb = level[int(K[i, K_A])], level[int(K[i, K_B])]
        if between and la == lb:
            continue
        lv = min(la, lb)
        order[count[lv]] = i
        count[lv] += 1
        m += 1
    return order, m


@kernel(inline="always")
def _upper_mass(K, i, j, upper_b, im):
    """1 / effective mass along direction j of contact i for its upper body alone."""
    arm = (K_RNB if upper_b else K_RNA) + 6 * j
    wv = (K_WNB if upper_b else K_WNA) + 6 * j
    return im + K[i, arm] * K[i, wv] + K[i, arm + 1] * K[i, wv + 1] + \
        K[i, arm + 2] * K[i, wv + 2]


@kernel(inline="always")
def _shock_apply(K, i, j, upper_b, u, sgn, im, dl, U, Wv, DP, DL):
    """An impulse dl along direction j of contact i on its upper body u only."""
    if dl == 0.0:
        return
    d = K_N + 3 * j
    arm = (K_RNB if upper_b else K_RNA) + 6 * j
    wv = (K_WNB if upper_b else K_WNA) + 6 * j
    for c in range(3):
        U[u, c] += sgn * dl * im * K[i, d + c]
        Wv[u, c] += sgn * dl * K[i, wv + c]
        DP[u, c] += sgn * dl * K[i, d + c]
        DL[u, c] += sgn * dl * K[i, arm + c]


SHOCK_ROUNDOFF = 1e-12  # relative: a direct solve's rows met within this share of
# their velocity scale,
SHOCK_GAP = 1e-12  # plus this share of the body's arms per step: contact points and gaps
# of a face on a face agree to round-off of the geometry only (1e-13 m of a 1 m box make
# its corners' targets, -gap/dt, disagree by ~1e-11 m/s at dt 1/60 s)
SHOCK_RANK = 1e-10  # a Cholesky pivot below this share of its diagonal: rank deficient


@kernel(inline="always")
def _sticks(K, i):
    """Whether the rest found contact i sticking (its friction inside the cone)."""
    lt1 = K[i, K_LT] + K[i, K_IT]
    lt2 = K[i, K_LT + 1] + K[i, K_IT + 1]
    return K[i, K_LN] > 0.0 and math.sqrt(lt1 * lt1 + lt2 * lt2) < \
        STICK_MARGIN * K[i, K_MU] * (K[i, K_LN] + K[i, K_IN])


@kernel(inline="always")
def _held(K, i, j):
    """Contact i's impulse along direction j before the shock: the rest's and the
    impact's, N s."""
    return K[i, K_LN] + K[i, K_IN] if j == 0 else K[i, K_LT + j - 1] + K[i, K_IT + j - 1]


@kernel
def _cholesky_solve(G, nc, x):
    """x <- G^-1 x with G's upper triangle holding R of G = R^T R (`_shock_direct`)."""
    for p in range(nc):
        acc = x[p]
        for q in range(p):
            acc -= G[q, p] * x[q]
        x[p] = acc / G[p, p]
    for p in range(nc - 1, -1, -1):
        acc = x[p]
        for q in range(p + 1, nc):
            acc -= G[p, q] * x[q]
        x[p] = acc / G[p, p]


SHOCK_SETS = 16  # active sets a direct solve tries (contacts leaving or joining), at most


SPREAD_ROUNDS = 100  # alternating projections of `_spread`, at most (the resting stacks
# of tests/test_shock_direct.py need <= 52), and they stop when
SPREAD_WINDOW = 20  # a window of this many rounds has not shrunk the step to
SPREAD_PROGRESS = 0.9  # this share of the last window's
SPREAD_ROUNDOFF = 1e-9  # relative: friction this little outside its cone is inside


@kernel
def _spread(K, cont, rows, dirs, nr, J, G, nc, lam, off, keep):
    """lam[off + r] (the impulses of `_shock_direct`'s rows) replaced by impulses with
    the same wrench (J^T lam, J (nr, nc) and G = J^T J factored in G) whose totals (the
    rest's and these) keep every normal >= 0 and every sticking contact's friction in
    its cone, by alternating projections (von Neumann's method, as `_inside_cones`)
    between the cones and the impulses of that wrench; returns whether it found them
    (then lam holds them). Contacts that took an impact's impulse are left to the sweeps
    (False). lam[keep + r]: scratch."""
    for r in range(nr):
        i = cont[rows[r]]
        if K[i, K_IN] != 0.0 or K[i, K_IT] != 0.0 or K[i, K_IT + 1] != 0.0:
            return False
        lam[keep + r] = lam[off + r]
    e = np.empty(nc)
    last = math.inf
    for round_ in range(SPREAD_ROUNDS):
        r = 0
        step = 0.0
        while r < nr:  # the totals onto the cones (normals >= 0, |t| <= mu n)
            i = cont[rows[r]]
            n = K[i, K_LN] + lam[off + r]
            if r + 2 < nr and rows[r + 1] == rows[r]:
                m = K[i, K_MU]
                t1 = K[i, K_LT] + lam[off + r + 1]
                t2 = K[i, K_LT + 1] + lam[off + r + 2]
                t = math.sqrt(t1 * t1 + t2 * t2)
                if t > m * n:
                    if m * t <= -n:
                        n, t1, t2 = 0.0, 0.0, 0.0
                    else:
                        n2 = (n + m * t) / (1.0 + m * m)
                        f = m * n2 / t
                        n, t1, t2 = n2, f * t1, f * t2
                    lam[off + r + 1] = t1 - K[i, K_LT]
                    lam[off + r + 2] = t2 - K[i, K_LT + 1]
                    lam[off + r] = n - K[i, K_LN]
                r += 3
            else:
                lam[off + r] = max(n, 0.0) - K[i, K_LN]
                r += 1
        for p in range(nc):  # back onto the wrench: lam - J G^-1 J^T (lam - lam0)
            acc = 0.0
            for r in range(nr):
                acc += J[r, p] * (lam[off + r] - lam[keep + r])
            e[p] = acc
        _cholesky_solve(G, nc, e)
        largest = 0.0
        for r in range(nr):
            acc = 0.0
            for p in range(nc):
                acc += J[r, p] * e[p]
            lam[off + r] -= acc
            step = max(step, abs(acc))
            largest = max(largest, abs(lam[off + r]))
        inside = True
        r = 0
        while r < nr:
            i = cont[rows[r]]
            n = K[i, K_LN] + lam[off + r]
            if not n >= -1e-12 * largest:
                inside = False
                break
            if r + 2 < nr and rows[r + 1] == rows[r]:
                t1 = K[i, K_LT] + lam[off + r + 1]
                t2 = K[i, K_LT + 1] + lam[off + r + 2]
                limit = K[i, K_MU] * max(n, 0.0) * (1.0 + SPREAD_ROUNDOFF)
                if not math.sqrt(t1 * t1 + t2 * t2) <= limit + 1e-12 * largest:
                    inside = False
                    break
                r += 3
            else:
                r += 1
        if inside:
            return True
        if (round_ + 1) % SPREAD_WINDOW == 0:  # stop when the steps stop shrinking
            if step >= SPREAD_PROGRESS * last:
                return False
            last = step
    return False


@kernel
def _shock_direct(K, cont, ncont, u, dt, im, IW, U, Wv, DP, DL, act, fix, rows, dirs, J,
                  bb, G, x, y, all_stick):
    """One upper body's contacts of a shock level solved at once (its lower bodies are
    frozen, so no other body's contacts of the level touch it), as the level's problem
    states it: each contact either active (its normal velocity at its target; if it
    sticks, its tangential velocity zero) or released (its normal impulse at its floor,
    -K_LN: rest and shock together push nothing; the rest's friction taken back; moving
    apart at least as fast as its target allows). `all_stick`: every active contact
    sticks, else those the rest found sticking (as the sweeps).

    A small active-set loop, all contacts active at first: the body's one velocity
    change that meets the active rows (least squares on its twist, exact when they
    agree) and, of the impulses that make it, those with the least totals (the load
    spread evenly; where they leave a cone or pull, `_spread`); when the rows disagree
    the active contact with the widest gap is released, else one that would pull, else
    a released one that would close faster than its target comes back (SHOCK_SETS sets
    at most). Applied only when it is a solution: rows met to round-off (SHOCK_ROUNDOFF,
    SHOCK_GAP), floors and cones kept; otherwise nothing is applied (returns False) and
    the sweeps solve this body. cont (ncont,): the body's contact rows of K. act (ncont,)
    bool, fix (ncont, 3), rows, dirs (>= 3 ncont,), J (>= 3 ncont, 6), bb (>= 9 ncont,),
    G (7, 6), x, y (6,): scratch.

    Why: the sweeps converge at ~0.5 per sweep on a box's four corners (the rows are
    redundant: four normals for three motions), so SHOCK_ITERATIONS = 16 left ~1e-5 of a
    correction each step, which a 10-box stack turned into 1.9e-7 m of drift in 5 s and a
    standing cylinder into settling by 2.9e-5 m; solved at once, a level is exact."""
    rot = False
    for c in range(9):
        if IW[u, c] != 0.0:
            rot = True
    nc = 6 if rot else 3
    arm_len = 0.0  # m: the angular columns are scaled by it (columns of one unit)
    for q in range(ncont):
        i = cont[q]
        base = K_RNB if int(K[i, K_B]) == u else K_RNA
        for c in range(3):
            for j in range(3):
                arm_len = max(arm_len, abs(K[i, base + 6 * j + c]))
        act[q] = True
    if arm_len == 0.0:
        arm_len = 1.0
    for _ in range(SHOCK_SETS):
        # released contacts: fixed impulses (normal at its floor, the rest's friction
        # taken back; with an impact's friction still on it, the sweeps decide)
        f0 = f1 = f2 = g0 = g1 = g2 = 0.0  # their velocity change of the body
        for q in range(ncont):
            i = cont[q]
            if act[q]:
                continue
            if K[i, K_IN] != 0.0 or K[i, K_IT] != 0.0 or K[i, K_IT + 1] != 0.0:
                return False
            fix[q, 0] = min(-K[i, K_LN], 0.0)
            fix[q, 1] = -K[i, K_LT]
            fix[q, 2] = -K[i, K_LT + 1]
            upper_b = int(K[i, K_B]) == u
            s = 1.0 if upper_b else -1.0
            for j in range(3):
                lam = s * fix[q, j]
                d = K_N + 3 * j
                wv = (K_WNB if upper_b else K_WNA) + 6 * j
                f0 += lam * im * K[i, d]
                f1 += lam * im * K[i, d + 1]
                f2 += lam * im * K[i, d + 2]
                g0 += lam * K[i, wv]
                g1 += lam * K[i, wv + 1]
                g2 += lam * K[i, wv + 2]
        nr = 0
        scale = 0.0
        for q in range(ncont):
            if not act[q]:
                continue
            i = cont[q]
            for j in range(3 if all_stick or _sticks(K, i) else 1):
                rows[nr] = q
                dirs[nr] = j
                upper_b = int(K[i, K_B]) == u
                s = 1.0 if upper_b else -1.0
                d = K_N + 3 * j
                arm = (K_RNB if upper_b else K_RNA) + 6 * j
                for c in range(3):
                    J[nr, c] = s * K[i, d + c]
                    J[nr, 3 + c] = s * K[i, arm + c] / arm_len
                target = _target(K, i, dt) if j == 0 else -K[i, K_V0T + j - 1]
                fixed = s * (K[i, d] * f0 + K[i, d + 1] * f1 + K[i, d + 2] * f2
                             + K[i, arm] * g0 + K[i, arm + 1] * g1 + K[i, arm + 2] * g2)
                bb[nr] = target - rel(K, i, j, U, Wv) - fixed
                scale = max(scale, abs(bb[nr]), abs(K[i, K_KICK + j]))
                nr += 1
        if nr == 0:
            return False
        slack = SHOCK_ROUNDOFF * scale + SHOCK_GAP * arm_len / dt
        # G = J^T J over the body's motions (6, or 3 when it does not turn); a motion no
        # row reaches is left out (zero change)
        top = 0.0
        for p in range(nc):
            for q in range(p, nc):
                acc = 0.0
                for r in range(nr):
                    acc += J[r, p] * J[r, q]
                G[p, q] = acc
            G[6, p] = G[p, p]
            top = max(top, G[p, p])
        if top == 0.0:
            return False
        for p in range(nc):
            if G[6, p] <= SHOCK_RANK * top:
                G[6, p] = 0.0
                for q in range(nc):
                    G[min(p, q), max(p, q)] = 0.0
                G[p, p] = 1.0
        for p in range(nc):  # Cholesky, G = R^T R in the upper triangle
            if G[6, p] == 0.0:
                continue
            piv = G[p, p]
            for q in range(p):
                piv -= G[q, p] * G[q, p]
            if not piv > SHOCK_RANK * G[6, p]:
                return False  # the rows do not fix this motion: the sweeps solve it
            piv = math.sqrt(piv)
            G[p, p] = piv
            for q in range(p + 1, nc):
                acc = G[p, q]
                for z in range(p):
                    acc -= G[z, p] * G[z, q]
                G[p, q] = acc / piv
        for p in range(nc):  # the velocity change (scaled: dv, arm_len dw)
            acc = 0.0
            if G[6, p] != 0.0:
                for r in range(nr):
                    acc += J[r, p] * bb[r]
            x[p] = acc
        _cholesky_solve(G, nc, x)
        # the wrench that makes it, (m dv, I dw / arm_len), and the least impulses J y
        for c in range(3):
            y[c] = x[c] / im
        if rot:
            dL = la.solve3(kd.row9(IW, u, 0),
                           (x[3] / arm_len, x[4] / arm_len, x[5] / arm_len))
            for c in range(3):
                y[3 + c] = dL[c] / arm_len
                if not abs(y[3 + c]) < math.inf:
                    return False
        # of all the impulses that make this wrench, the one whose totals (the rest's,
        # the impact's and these) are least: the load spread as evenly as it can be
        # (smallest corrections instead pushed loaded corners below zero and friction out
        # of its cones where an even spread fits)
        for r in range(nr):
            i, j = cont[rows[r]], dirs[r]
            held = _held(K, i, j)
            for p in range(nc):
                y[p] += J[r, p] * held
        _cholesky_solve(G, nc, y)
        dv0, dv1, dv2, dw0, dw1, dw2 = f0, f1, f2, g0, g1, g2
        for r in range(nr):
            i, j = cont[rows[r]], dirs[r]
            lam = -_held(K, i, j)
            for p in range(nc):
                lam += J[r, p] * y[p]
            upper_b = int(K[i, K_B]) == u
            s = 1.0 if upper_b else -1.0
            wv = (K_WNB if upper_b else K_WNA) + 6 * j
            dv0 += s * lam * im * K[i, K_N + 3 * j]
            dv1 += s * lam * im * K[i, K_N + 3 * j + 1]
            dv2 += s * lam * im * K[i, K_N + 3 * j + 2]
            dw0 += s * lam * K[i, wv]
            dw1 += s * lam * K[i, wv + 1]
            dw2 += s * lam * K[i, wv + 2]
            bb[3 * ncont + r] = lam  # the row's impulse, kept beside its target change
        # checks: the rows met (the change the impulses and the fixed ones make), floors,
        # cones; the worst floor broken releases its contact
        worst, worst_q = 0.0, -1
        met = True
        for r in range(nr):
            i, j = cont[rows[r]], dirs[r]
            upper_b = int(K[i, K_B]) == u
            arm = (K_RNB if upper_b else K_RNA) + 6 * j
            s = 1.0 if upper_b else -1.0
            d = K_N + 3 * j
            got = s * (K[i, d] * (dv0 - f0) + K[i, d + 1] * (dv1 - f1)
                       + K[i, d + 2] * (dv2 - f2) + K[i, arm] * (dw0 - g0)
                       + K[i, arm + 1] * (dw1 - g1) + K[i, arm + 2] * (dw2 - g2))
            met = met and abs(got - bb[r]) <= slack
            lam = bb[3 * ncont + r]
            if j == 0:
                below = min(-K[i, K_LN], 0.0) - lam
                if below > worst:
                    worst, worst_q = below, rows[r]
                elif not below <= worst:
                    return False  # NaN
        if not met:
            # the targets disagree (touching corners hold at 0, contacts a little apart
            # may close their gap): the widest gap is released
            widest, wq = 0.0, -1
            for q in range(ncont):
                if act[q] and K[cont[q], K_GAP] > widest:
                    widest, wq = K[cont[q], K_GAP], q
            if wq < 0:
                return False
            act[wq] = False
            continue
        inside = worst_q < 0
        for r in range(nr):
            if dirs[r] == 0 and r + 2 < nr and rows[r + 1] == rows[r]:  # sticking
                i = cont[rows[r]]
                t1 = K[i, K_LT] + K[i, K_IT] + bb[3 * ncont + r + 1]
                t2 = K[i, K_LT + 1] + K[i, K_IT + 1] + bb[3 * ncont + r + 2]
                if not math.sqrt(t1 * t1 + t2 * t2) <= \
                        K[i, K_MU] * (K[i, K_LN] + K[i, K_IN] + bb[3 * ncont + r]):
                    inside = False
        # the same wrench from other impulses, inside the floors and cones, if there are
        # any (the load of a face on a face is statically indeterminate)
        if not inside and not _spread(K, cont, rows, dirs, nr, J, G, nc, bb, 3 * ncont,
                                      6 * ncont):
            if worst_q >= 0:
                act[worst_q] = False
                continue
            return False
        # released contacts: apart at least as fast as their targets allow
        back = -1
        for q in range(ncont):
            if act[q]:
                continue
            i = cont[q]
            upper_b = int(K[i, K_B]) == u
            s = 1.0 if upper_b else -1.0
            arm = K_RNB if upper_b else K_RNA
            v = rel(K, i, 0, U, Wv) + s * (
                K[i, K_N] * dv0 + K[i, K_N + 1] * dv1 + K[i, K_N + 2] * dv2
                + K[i, arm] * dw0 + K[i, arm + 1] * dw1 + K[i, arm + 2] * dw2)
            if v < _target(K, i, dt) - slack:
                back = q
                break
        if back >= 0:
            act[back] = True
            continue
        for r in range(nr):
            i, j = cont[rows[r]], dirs[r]
            upper_b = int(K[i, K_B]) == u
            lam = bb[3 * ncont + r]
            _shock_apply(K, i, j, upper_b, u, 1.0 if upper_b else -1.0, im, lam, U, Wv,
                         DP, DL)
            K[i, K_SN + j] = lam
        for q in range(ncont):
            if act[q]:
                continue
            i = cont[q]
            upper_b = int(K[i, K_B]) == u
            for j in range(3):
                _shock_apply(K, i, j, upper_b, u, 1.0 if upper_b else -1.0, im,
                             fix[q, j], U, Wv, DP, DL)
                K[i, K_SN + j] = fix[q, j]
        return True
    return False


@kernel(inline="always")
def _shock_sweep(K, i, level, dt, U, Wv, DP, DL):
    """Contact i of a shock level once (Gauss-Seidel) on its upper body; returns whether
    an impulse changed."""
    a, b = int(K[i, K_A]), int(K[i, K_B])
    upper_b = level[b] > level[a]
    u = b if upper_b else a
    sgn = 1.0 if upper_b else -1.0
    im = K[i, K_IMB] if upper_b else K[i, K_IMA]
    moved = False
    # friction only where the rest found the contact sticking (its friction inside the
    # cone): against a frozen lower body, friction at a sliding or rolling contact spun a
    # pile's spheres up
    sticks = _sticks(K, i)
    for j in range(3 if sticks else 1):
        mass = _upper_mass(K, i, j, upper_b, im)
        if mass <= 0.0:
            continue
        v = rel(K, i, j, U, Wv)
        old = K[i, K_SN + j]
        if j == 0:
            # a contact that carries load (the rest gave it an impulse) may also be held
            # from separating, down to no resting impulse at all: a stack that rocks is
            # held as well as one that sinks (an impact's impulse stays: a bounce is not
            # pulled back)
            floor = -K[i, K_LN]
            new = max(old + (_target(K, i, dt) - v) / mass, min(floor, 0.0))
        else:
            new = old - (v + K[i, K_V0T + j - 1]) / mass
            if j == 2:  # both tangents: the whole friction in the disc
                limit = K[i, K_MU] * (K[i, K_LN] + K[i, K_IN] + K[i, K_SN])
                t1 = K[i, K_LT] + K[i, K_IT] + K[i, K_SN + 1]
                t2 = K[i, K_LT + 1] + K[i, K_IT + 1] + new
                norm = math.sqrt(t1 * t1 + t2 * t2)
                if norm > limit:
                    scale = limit / norm
                    d1 = t1 * scale - t1
                    _shock_apply(K, i, 1, upper_b, u, sgn, im, d1, U, Wv, DP, DL)
                    K[i, K_SN + 1] += d1
                    new = t2 * scale - (K[i, K_LT + 1] + K[i, K_IT + 1])
                    moved = moved or d1 != 0.0
        _shock_apply(K, i, j, upper_b, u, sgn, im, new - old, U, Wv, DP, DL)
        K[i, K_SN + j] = new
        moved = moved or new - old != 0.0
    return moved


@kernel
def shock(K, order, m, level, dt, iterations, U, Wv, DP, DL, until_fixed, IW):
    """Shock propagation (Guendelman, Bridson & Fedkiw 2003) on velocities, after the
    rest iterations: level by level from the ground up, each contact between two levels
    solved with its lower body frozen (infinite mass: the impulse acts on the upper body
    only), normal towards v_n >= -max(gap, 0)/dt (v_n = that for a contact that carries
    resting load: it may pull back what the rest pushed) and friction in the Coulomb disc of all
    the contact's normal impulse. The iterations' leftover error then cannot make a
    stack sink, whatever the mass ratio (a 100 kg box on a 1 kg slab). `order` (m,): the
    contacts between levels, ground up (`level_order`). With the lower bodies frozen, each
    upper body's contacts of a level are a problem of their own: it is solved at once
    where it can be (`_shock_direct`); the bodies left are swept, each on its own
    (Gauss-Seidel over its contacts, at most `iterations` sweeps, FACE_SWEEPS times as
    many where the contacts have levers on it). `until_fixed`: a body's
    sweeps stop after one that changed no impulse (its later sweeps would repeat it
    exactly). IW (n, 9): inverse inertia."""
    n = level.shape[0]
    head = np.full(n, -1, np.int64)
    tail = np.full(n, -1, np.int64)
    solved = np.zeros(n, np.bool_)
    rests = np.zeros(n, np.bool_)  # on a face, every contact loaded: FACE_SWEEPS
    nxt = np.empty(max(m, 1), np.int64)
    cont = np.empty(max(m, 1), np.int64)
    act = np.empty(max(m, 1), np.bool_)
    fix = np.empty((max(m, 1), 3))
    rows = np.empty(3 * m + 3, np.int64)
    dirs = np.empty(3 * m + 3, np.int64)
    J = np.empty((3 * m + 3, 6))
    bb = np.empty(9 * m + 9)
    G = np.empty((7, 6))
    x, y = np.empty(6), np.empty(6)
    q0 = 0
    while q0 < m:
        i0 = order[q0]
        lv = min(level[int(K[i0, K_A])], level[int(K[i0, K_B])])
        q1 = q0
        while q1 < m and min(level[int(K[order[q1], K_A])],
                             level[int(K[order[q1], K_B])]) == lv:
            q1 += 1
        for q in range(q0, q1):  # each upper body's contacts, a list in order
            i = order[q]
            a, b = int(K[i, K_A]), int(K[i, K_B])
            upper_b = level[b] > level[a]
            u = b if upper_b else a
            im = K[i, K_IMB] if upper_b else K[i, K_IMA]
            if int(K[i, K_MODE]) != IMPULSE or im == 0.0:
                continue
            nxt[q] = -1
            if head[u] < 0:
                head[u] = q
            else:
                nxt[tail[u]] = q
            tail[u] = q
        for q in range(q0, q1):
            i = order[q]
            a, b = int(K[i, K_A]), int(K[i, K_B])
            upper_b = level[b] > level[a]
            u = b if upper_b else a
            if head[u] != q:
                continue
            nk = 0
            p = q
            levers = False  # a normal with a lever on u (a face, not a sphere's point)
            loaded = True  # the rest put load on every one of these contacts
            while p >= 0:
                ii = order[p]
                cont[nk] = ii
                nk += 1
                loaded = loaded and K[ii, K_LN] > 0.0
                arm = K_RNB if int(K[ii, K_B]) == u else K_RNA
                levers = levers or K[ii, arm] != 0.0 or K[ii, arm + 1] != 0.0 or \
                    K[ii, arm + 2] != 0.0
                p = nxt[p]
            # swept instead: two contacts or one (a box on an edge, whose turning about it
            # the rows leave free), and a sphere's (its normals pass through its centre:
            # pushing it does not turn it, and its sweeps converge in a few)
            if nk >= 3 and levers:
                im = K[i, K_IMB] if upper_b else K[i, K_IMA]
                # first with every contact sticking: the rest's sweeps, not converged,
                # leave some corners of a face at their cones' edge (a box on a slope
                # slid 5e-6 m when only one corner was taken as sticking), then as the
                # rest found them
                solved[u] = _shock_direct(K, cont, nk, u, dt, im, IW, U, Wv, DP, DL, act,
                                          fix, rows, dirs, J, bb, G, x, y, True) or \
                    _shock_direct(K, cont, nk, u, dt, im, IW, U, Wv, DP, DL, act, fix,
                                  rows, dirs, J, bb, G, x, y, False)
            # FACE_SWEEPS only for a body that rests on all its contacts: one still landing
            # or tumbling (a pile) gains nothing exact from them, and they cost 4x
            rests[u] = levers and loaded
        for q in range(q0, q1):  # the bodies left: each one's contacts swept on its own
            i = order[q]
            a, b = int(K[i, K_A]), int(K[i, K_B])
            upper_b = level[b] > level[a]
            u = b if upper_b else a
            if head[u] != q or solved[u]:
                continue
            for _ in range(FACE_SWEEPS * iterations if rests[u] else iterations):
                moved = False
                p = q
                while p >= 0:
                    moved = _shock_sweep(K, order[p], level, dt, U, Wv, DP, DL) or moved
                    p = nxt[p]
                if until_fixed and not moved:  # a sweep that changed nothing: every
                    break  # later one would repeat it exactly (the same bits as all)
        for q in range(q0, q1):
            i = order[q]
            u = int(K[i, K_B]) if level[int(K[i, K_B])] > level[int(K[i, K_A])] \
                else int(K[i, K_A])
            head[u] = -1
            solved[u] = False
        q0 = q1


# ----------------------------------------------------------------------------- positions


@kernel
def end_separations(mf, K, k, S, RS, S1, RS1):
    """K_SEND: each contact's separation after the step, measured along its normal, with
    the points that define it carried with their bodies (rotated by R1 R0^T): a corner
    or a point of a face, or for a rounded witness (a sphere's, a capsule's) the centre
    of its rounding, which keeps its radius along the normal. Carrying a rounded witness
    point itself would lift it off the surface by r (1 - cos theta) in a turn theta (a
    capsule on its end cap at 0.3 rad per step: 2-7 mm), and the position pass would
    leave that much penetration for later steps to push out, gaining energy."""
    for i in range(k):
        a, b = int(K[i, K_A]), int(K[i, K_B])
        n = get(K, i, K_N)
        core_a = la.sub(get(K, i, K_RA), la.scale(K[i, K_ROUND], n))
        core_b = la.add(get(K, i, K_RB), la.scale(K[i, K_ROUND + 1], n))
        da = moved(mf, a, core_a, S, RS, S1, RS1)
        db = moved(mf, b, core_b, S, RS, S1, RS1)
        K[i, K_SEND] = K[i, K_GAP] + la.dot(la.sub(db, da), n)


@kernel(inline="always")
def moved(mf, b, r, S, RS, S1, RS1):
    """Displacement over the step of the point at arm r from body b's centre."""
    d = la.sub(kd.row3(S1, b, kd.S_POS), kd.row3(S, b, kd.S_POS))
    slot = kd.slot_of(mf, b)
    if slot >= 0:
        R0, R1 = kd.row9(RS, slot, kd.RS_R), kd.row9(RS1, slot, kd.RS_R)
        d = la.add(d, la.sub(la.matvec(R1, la.mattvec(R0, r)), r))
    return d


POS_ROUNDOFF = 1e-12  # of a contact's arms: a penetration this shallow is round-off of
# the step's position update and of the contact geometry (a resting 10-box stack ended
# its steps 1e-16 m deep and the pass swept 14 times a step to push that out)


@kernel(inline="always")
def _pos_roundoff(K, i):
    """m: POS_ROUNDOFF of contact i's longer arm (largest component)."""
    arm = 0.0
    for c in range(3):
        arm = max(arm, abs(K[i, K_RA + c]), abs(K[i, K_RB + c]))
    return POS_ROUNDOFF * arm


@kernel(inline="always")
def _loaded(K, i):
    """Whether contact i carried a resting normal impulse (the rest's or the shock's)."""
    return int(K[i, K_MODE]) == IMPULSE and K[i, K_LN] + K[i, K_SN] > 0.0


@kernel
def push_out(mf, K, k, order, level, iterations, slop, inv_m, IW, S1, RS1, dx, dth,
             until_fixed, mean):
    """The position pass: pseudo-impulses Q along the normals (Gauss-Seidel on the
    linearised separations, the contacts ground up in `order` (k,), and with shock
    propagation: a contact between two `level`s moves its upper body only) until every
    contact that ends deeper than `slop` (and than round-off, POS_ROUNDOFF) is back at
    -slop, and, where positions move by the mean velocity (`mean`), every loaded one (a
    resting normal impulse > 0: its velocity solve kept it closed) that ends apart is
    back at -slop too (Q < 0 allowed there: the arc of a pivoting body's turn lifted its
    loaded corner 1-13 um a step, potential energy that no velocity paid for); then the
    bodies are moved by dx and turned by exp(dth), their angular momentum turned with
    them (body-frame L kept, so the kinetic energy is unchanged), and no velocity
    changes. dx, dth (n, 3): scratch. `until_fixed`: stop after a sweep that moved
    nothing (later sweeps would repeat it exactly)."""
    n = S1.shape[0]
    for b in range(n):
        for c in range(3):
            dx[b, c] = 0.0
            dth[b, c] = 0.0
    any_deep = False
    for i in range(k):
        K[i, K_Q] = 0.0
        mode = int(K[i, K_MODE])
        deep = K[i, K_SEND] < -slop - _pos_roundoff(K, i)
        if mean and _loaded(K, i):
            deep = abs(K[i, K_SEND] + slop) > _pos_roundoff(K, i)
        if (mode == IMPULSE or mode == SLIDE) and deep:
            any_deep = True
    if not any_deep:
        return
    for _ in range(iterations):
        moved = False
        for o in range(k):
            i = order[o]
            mode = int(K[i, K_MODE])
            if mode != IMPULSE and mode != SLIDE:
                continue
            a, b = int(K[i, K_A]), int(K[i, K_B])
            nrm = get(K, i, K_N)
            sep = K[i, K_SEND] + la.dot(la.sub(kd.row3(dx, b, 0), kd.row3(dx, a, 0)), nrm) \
                + la.dot(get(K, i, K_RNB), kd.row3(dth, b, 0)) \
                - la.dot(get(K, i, K_RNA), kd.row3(dth, a, 0))
            ima, imb = inv_m[a], inv_m[b]
            inv_k = K[i, K_MN]
            if level[a] != level[b]:  # shock propagation: the lower body stays
                upper_b = level[b] > level[a]
                if upper_b:
                    ima = 0.0
                else:
                    imb = 0.0
                mass = _upper_mass(K, i, 0, upper_b, imb if upper_b else ima)
                inv_k = 1.0 / mass if mass > 0.0 else 0.0
            loaded = mean and _loaded(K, i)
            if K[i, K_Q] == 0.0 and (abs(sep + slop) <= _pos_roundoff(K, i) if loaded
                                     else sep + slop >= -_pos_roundoff(K, i)):
                continue  # deep (or, loaded, apart) by round-off only: not moved
            new = K[i, K_Q] - (sep + slop) * inv_k
            if not loaded:
                new = max(new, 0.0)
            q = new - K[i, K_Q]
            if q == 0.0:
                continue
            moved = True
            K[i, K_Q] = new
            if imb != 0.0:
                wb = la.matvec(kd.row9(IW, b, 0), la.scale(q, get(K, i, K_RNB)))
                for c in range(3):
                    dx[b, c] += imb * q * nrm[c]
                    dth[b, c] += wb[c]
            if ima != 0.0:
                wa = la.matvec(kd.row9(IW, a, 0), la.scale(q, get(K, i, K_RNA)))
                for c in range(3):
                    dx[a, c] -= ima * q * nrm[c]
                    dth[a, c] -= wa[c]
        if until_fixed and not moved:  # a sweep that changed nothing: every later one
            break  # would repeat it exactly (the same bits as the full count)
    move_and_turn(mf, dx, dth, True, S1, RS1)


@kernel
def move_and_turn(mf, dx, dth, turn_L, S1, RS1):
    """Bodies moved by dx and turned by exp(dth) (n, 3 each; world), no velocity change
    meant: `turn_L` turns the angular momentum with the body (its body-frame value and
    so the kinetic energy kept: the position pass), else the world angular momentum is
    kept (as the impulses left it: a ball's spin, and so its rolling, stay as solved)."""
    for b in range(S1.shape[0]):
        for c in range(3):
            S1[b, kd.S_POS + c] += dx[b, c]
    for kk in range(RS1.shape[0]):
        i = kd.at(mf, kd.H_ROT, kk, kd.RT_SIZE)
        b = int(mf[i + kd.RT_INDEX])
        th = kd.row3(dth, b, 0)
        if th[0] == 0.0 and th[1] == 0.0 and th[2] == 0.0:
            continue
        E = la.exp_so3(th)
        R = la.matmul(E, kd.row9(RS1, kk, kd.RS_R))
        L = kd.row3(RS1, kk, kd.RS_L)
        if turn_L:
            L = la.matvec(E, L)
        kd.put9(RS1, kk, kd.RS_R, R)
        kd.put3(RS1, kk, kd.RS_L, L)
        kd.put4(S1, b, kd.S_QUAT, la.quat_from_matrix(R))
        kd.put3(S1, b, kd.S_ANGVEL, kd.world_omega(mf, kk, R, L))


@kernel(inline="always")
def _slides_to_stop(K, i, v0, dt, U, Wv):
    """Whether contact i slid at the step's start and is stuck at its end: its slip
    stopped within the step (a resting contact, no impact, not held stuck from the last
    step). Stuck is kinematic, the end slip gone to the round-off of the start slip
    (1 - STICK_MARGIN of it), or friction inside the cone: a face's corner loads are
    indeterminate, and a solve that stopped a box put the friction of two of its four
    corners on the cone's edge, where taken as sliding they hid the stop (its positions
    then overshot by the uncorrected dt (1 - tau) |u0| / 2). Near that bound either
    answer is right: a slip that ends there stopped at tau ~ 1, and the correction is
    ~ (1 - tau). A stop moves the contact point by less than dt |u0| / 2 against the
    one-ramp path (the slip falls from |u0| to 0 either way), so a start slip for which
    that is below the position round-off
    (POS_ROUNDOFF of its arms) is round-off too: its direction is noise (a resting stack's
    1e-18 m/s slips jumped it 2e-7 m when taken as stops). A contact without friction
    (mu = 0) has no force to switch: its slip may pass zero (a frictionless box pushing
    one that stops), but that is no stop of its own, and counted as one it hid the
    other's (`slip_stops` places an island's stops only where one pair stops)."""
    if i >= v0.shape[0] or int(K[i, K_MODE]) != IMPULSE or K[i, K_LN] <= 0.0 or \
            K[i, K_MU] <= 0.0:
        return False
    if K[i, K_IN] != 0.0 or K[i, K_IT] != 0.0 or K[i, K_IT + 1] != 0.0 or \
            K[i, K_LK] != 0.0 or K[i, K_V0T] != 0.0 or K[i, K_V0T + 1] != 0.0:
        return False
    u0 = math.sqrt(v0[i, 1] * v0[i, 1] + v0[i, 2] * v0[i, 2])
    if 0.5 * dt * u0 <= _pos_roundoff(K, i):
        return False
    _, s1, s2 = rel3(K, i, U, Wv)
    if math.sqrt(s1 * s1 + s2 * s2) <= (1.0 - STICK_MARGIN) * u0:
        return True
    lt1, lt2 = K[i, K_LT], K[i, K_LT + 1]
    return math.sqrt(lt1 * lt1 + lt2 * lt2) < STICK_MARGIN * K[i, K_MU] * K[i, K_LN]


@kernel
def slip_stops(mf, K, k, v0, dt, inv_m, U, Wv, S1, RS1):
    """Where positions move by the mean velocity: a contact that slid at the step's start
    and sticks at its end stopped slipping at some tau dt within the step, so its
    friction was a force constant at mu N until then and another one after. The
    integrator applied the step's resting impulse as one constant force; the two-piece
    force moves the bodies further by (dt tau / 2) (v_s - v1), where v1 is the solved end
    velocity and v_s the end velocity had the contact slid all the step (its friction
    held at mu N against the start slip, the normals solved anew), and tau the fraction
    at which that sliding solution's slip passes zero: tau = |u0| / (|u0| - u_s.e), e the
    start slip's direction. (The piecewise-constant forces integrate exactly: a ball
    thrown on the ground or an incline, to 1e-13 m, was up to 1e-4 m off a stop; a box
    or a cylinder stopping on its face to 1e-13 of the distance, since stuck is read
    from the end slip: `_slides_to_stop`.)
    For islands of one moving body or one stopping pair, solved to convergence
    (SMALL_ISLAND_ROWS; a stack sliding to a stop: `tests/test_stack_slides.py`), where v1
    is the rest's fixed point; the re-solve is a copy (K, U, Wv are not changed). One tau
    per island: the mean of its stopping contacts', weighted by their friction limits
    (equal for a body sliding without turning). Positions and orientations only; no
    velocity changes."""
    if k == 0 or v0.shape[0] == 0:
        return
    any_stop = False
    for i in range(min(k, v0.shape[0])):
        if _slides_to_stop(K, i, v0, dt, U, Wv):
            any_stop = True
            break
    if not any_stop:
        return
    island = np.empty(k, np.int64)
    rows = islands(K, k, inv_m, island)
    n = inv_m.shape[0]
    # islands of one moving body, or whose stopping contacts are all of one pair: one
    # switch, placed by one tau (the island's other contacts keep their state, as a box's
    # stuck on the sliding one). Where several bodies' pairs stop, they stop at different
    # times and one tau misplaces the others (a domino row and an rk4 pile gained energy
    # and did not come to rest with every island taken)
    member = np.full(n, -1, np.int64)  # the island's one moving body, -2: several
    pair = np.full(n, -1, np.int64)  # its one stopping pair (a * n + b), -2: several
    stopping = np.zeros(k, np.bool_)  # `_slides_to_stop`, once per contact
    for i in range(k):
        g = island[i]
        if g < 0:
            continue
        for body in (int(K[i, K_A]), int(K[i, K_B])):
            if inv_m[body] != 0.0 and member[g] != body:
                member[g] = body if member[g] == -1 else -2
        if _slides_to_stop(K, i, v0, dt, U, Wv):
            stopping[i] = True
            key = int(K[i, K_A]) * n + int(K[i, K_B])
            if pair[g] != key:
                pair[g] = key if pair[g] == -1 else -2
    live = np.zeros(n, np.bool_)
    e = np.zeros((k, 2))
    stops = np.zeros(k, np.bool_)
    for i in range(k):
        g = island[i]
        if stopping[i] and (member[g] >= 0 or pair[g] >= 0) and \
                rows[g] <= SMALL_ISLAND_ROWS:
            u = math.sqrt(v0[i, 1] * v0[i, 1] + v0[i, 2] * v0[i, 2])
            e[i, 0], e[i, 1] = v0[i, 1] / u, v0[i, 2] / u
            stops[i] = True
            live[g] = True
    Ks, Us, Ws = K.copy(), U.copy(), Wv.copy()
    swept = live.copy()
    sweep_islands(Ks, k, dt, Us, Ws, island, live, stops, e)
    polish_islands(Ks, k, dt, Us, Ws, island, swept, stops, e)
    tau_w, w_sum = np.zeros(n), np.zeros(n)
    for i in range(k):
        if not stops[i]:
            continue
        u = math.sqrt(v0[i, 1] * v0[i, 1] + v0[i, 2] * v0[i, 2])
        _, s1, s2 = rel3(Ks, i, Us, Ws)
        us = s1 * e[i, 0] + s2 * e[i, 1]  # the sliding solution's end slip along e
        if us >= 0.0:  # it does not pass zero: no stop to place in the step
            continue
        w = K[i, K_MU] * K[i, K_LN]
        tau_w[island[i]] += w * u / (u - us)
        w_sum[island[i]] += w
    dx, dth = np.zeros((n, 3)), np.zeros((n, 3))
    done = np.zeros(n, np.bool_)
    moved_any = False
    for i in range(k):  # every moving body of an island with a stop, once
        g = island[i]
        if g < 0 or w_sum[g] == 0.0:
            continue
        half = 0.5 * dt * tau_w[g] / w_sum[g]
        for body in (int(K[i, K_A]), int(K[i, K_B])):
            if inv_m[body] == 0.0 or done[body]:
                continue
            done[body] = True
            for c in range(3):
                dx[body, c] = half * (Us[body, c] - U[body, c])
                dth[body, c] = half * (Ws[body, c] - Wv[body, c])
            moved_any = True
    # The stop's extra way is a slide along the surfaces: both solutions keep every
    # loaded contact closed, so the correction moves none of them along its normal, nor
    # the centre of mass (its height is potential energy the correction would not pay
    # for). Where it would (by more than the position round-off, POS_ROUNDOFF of the
    # arms), the body's contact forces did not switch once (a falling domino pivots on
    # its sliding edge: given the correction it gained 5e-7 of the scene's energy in a
    # step): it keeps the integrator's pose.
    for i in range(k):
        if not moved_any:
            break
        if int(K[i, K_MODE]) != IMPULSE or K[i, K_LN] <= 0.0:
            continue
        a, b = int(K[i, K_A]), int(K[i, K_B])
        shift = la.dot(la.sub(kd.row3(dx, b, 0), kd.row3(dx, a, 0)), get(K, i, K_N))
        dn = shift + la.dot(get(K, i, K_RNB), kd.row3(dth, b, 0)) \
            - la.dot(get(K, i, K_RNA), kd.row3(dth, a, 0))
        if abs(dn) > _pos_roundoff(K, i) or abs(shift) > _pos_roundoff(K, i):
            for body in (a, b):
                for c in range(3):
                    dx[body, c] = 0.0
                    dth[body, c] = 0.0
    if moved_any:
        move_and_turn(mf, dx, dth, False, S1, RS1)


@kernel
def exact_spin(mf, DL, inv_m, RS0, RS1):
    """Runge-Kutta (rk4, dopri5) integrates turning in the body frame, where the step's
    resting torque, constant in the world, turns with the body and is integrated to
    O(dt^5) only: a ball spinning at ~1 rad a step ended its rolling step with a slip of
    up to 1e-3 m/s. For a body with isotropic inertia (a sphere) on which nothing but the
    contacts acts on its turning (no force at a point, torque, spring or angular
    damping), the world angular momentum at the step's end is exactly L0 + DL (L0 with
    the impacts, RS0): it is set so, and its angular velocity L / I follows exactly. Other
    bodies keep the body-frame integration (whose accuracy for a tumbling free body the
    world frame loses: Dzhanibekov's flip 1.4e-6 rad off at dt 10 ms, in the world frame
    1.1 rad)."""
    n = inv_m.shape[0]
    torqued = np.zeros(n, np.bool_)
    of = int(mf[kd.H_FORCE])
    for j in range(int(mf[kd.H_F])):
        i = of + j * kd.FC_SIZE
        if mf[i + kd.FC_HAS_POINT] != 0.0:
            torqued[int(mf[i + kd.FC_BODY])] = True
    ot = int(mf[kd.H_TORQUE])
    for j in range(int(mf[kd.H_K])):
        torqued[int(mf[ot + j * kd.TQ_SIZE + kd.TQ_BODY])] = True
    for j in range(int(mf[kd.H_S])):
        i = kd.at(mf, kd.H_SPRING, j, kd.SP_SIZE)
        torqued[int(mf[i + kd.SP_A])] = True
        if mf[i + kd.SP_B] >= 0.0:
            torqued[int(mf[i + kd.SP_B])] = True
    ob = int(mf[kd.H_BODY])
    for q in range(RS1.shape[0]):
        j = kd.at(mf, kd.H_ROT, q, kd.RT_SIZE)
        b = int(mf[j + kd.RT_INDEX])
        if mf[j + kd.RT_KINEMATIC] != 0.0 or inv_m[b] == 0.0 or torqued[b] or \
                mf[ob + b * kd.B_SIZE + kd.B_ANG_DAMP] != 0.0:
            continue
        if DL[b, 0] == 0.0 and DL[b, 1] == 0.0 and DL[b, 2] == 0.0:
            continue
        I = kd.mat9(mf, j + kd.RT_INV_INERTIA)
        if not (I[0] == I[4] == I[8] and I[1] == 0.0 and I[2] == 0.0 and I[3] == 0.0
                and I[5] == 0.0 and I[6] == 0.0 and I[7] == 0.0):
            continue
        for c in range(3):
            RS1[q, kd.RS_L + c] = RS0[q, kd.RS_L + c] + DL[b, c]


# ----------------------------------------------------------------------------- pairs


@kernel
def end_stop(mf, K, k, inv_m, iterations, S1, RS1):
    """Where positions move by the mean velocity: a stuck pair's end slip to zero,
    velocities only. Such a pair took the target slip -v0_t (`_rest_row`), so its mean
    slip, which moved the positions, is zero; its end velocity -v0_t is the scheme's
    artefact (next step it would take +v0_t again: a still box in a pile reported an
    alternating 4 mm/s for ever). Read as an impulsive stop of the start slip plus a
    force that keeps it stopped, the same positions end with zero slip: Gauss-Seidel on
    the end velocities with the pair's friction disc (the rest's normal impulse) as its
    bound. Every update is a projection in the mass metric, so kinetic energy only
    falls; positions are not touched."""
    n = S1.shape[0]
    V, Wd = np.empty((n, 3)), np.empty((n, 3))
    for b in range(n):
        for c in range(3):
            V[b, c] = S1[b, kd.S_VEL + c]
            Wd[b, c] = S1[b, kd.S_ANGVEL + c]
    DPc, DLc = np.zeros((n, 3)), np.zeros((n, 3))
    extra = np.zeros((k, 2))  # this pass's friction impulses, on top of the step's
    touched = False
    for _ in range(iterations):
        moved = False
        for i in range(k):
            # (the normal's analogue, an end approach -v0_n stopped, made 2 of the 16
            # pivot draws gain energy: the next step's plastic impact stops it instead)
            if int(K[i, K_MODE]) != IMPULSE or not _sticks(K, i) or \
                    (K[i, K_V0T] == 0.0 and K[i, K_V0T + 1] == 0.0):
                continue
            l1 = K[i, K_LT] + K[i, K_IT] + extra[i, 0]
            l2 = K[i, K_LT + 1] + K[i, K_IT + 1] + extra[i, 1]
            vt1, vt2 = rel(K, i, 1, V, Wd), rel(K, i, 2, V, Wd)
            s1, s2 = friction(K, i, l1, l2, vt1, vt2, K[i, K_MU] * (K[i, K_LN] + K[i, K_IN]))
            d1, d2 = s1 - l1, s2 - l2
            if d1 == 0.0 and d2 == 0.0:
                continue
            moved = touched = True
            apply(K, i, 1, d1, V, Wd)
            apply(K, i, 2, d2, V, Wd)
            _add_impulse(K, i, 1, d1, DPc, DLc, True)
            _add_impulse(K, i, 2, d2, DPc, DLc, True)
            extra[i, 0] += d1
            extra[i, 1] += d2
        if not moved:
            break
    if not touched:
        return
    for b in range(n):
        if inv_m[b] == 0.0:
            continue
        for c in range(3):
            S1[b, kd.S_VEL + c] += DPc[b, c] * inv_m[b]
    for q in range(RS1.shape[0]):
        i = kd.at(mf, kd.H_ROT, q, kd.RT_SIZE)
        b = int(mf[i + kd.RT_INDEX])
        if mf[i + kd.RT_KINEMATIC] != 0.0 or inv_m[b] == 0.0:
            continue
        for c in range(3):
            RS1[q, kd.RS_L + c] += DLc[b, c]
        kd.put3(S1, b, kd.S_ANGVEL, kd.world_omega(mf, q, kd.row9(RS1, q, kd.RS_R),
                                                     kd.row3(RS1, q, kd.RS_L)))


@kernel
def pair_starts(K, k, first, starts):
    """starts[p]: the first row of each pair (rows sorted or appended by pair) from row
    `first` on; returns the number of pairs. starts (>= k + 1,)."""
    np_ = 0
    for i in range(first, k):
        if i == first or K[i, K_A] != K[i - 1, K_A] or K[i, K_B] != K[i - 1, K_B]:
            starts[np_] = i
            np_ += 1
    starts[np_] = k
    return np_


@kernel
def has_pair(K, k0, k, a, b):
    """Whether K holds a contact of bodies (a, b): rows [0, k0) are sorted by pair
    (binary search), rows [k0, k) were appended (scanned)."""
    key = a * (1 << 31) + b
    lo, hi = 0, k0
    while lo < hi:
        mid = (lo + hi) // 2
        if int(K[mid, K_A]) * (1 << 31) + int(K[mid, K_B]) < key:
            lo = mid + 1
        else:
            hi = mid
    if lo < k0 and int(K[lo, K_A]) == a and int(K[lo, K_B]) == b:
        return True
    for i in range(k0, k):
        if int(K[i, K_A]) == a and int(K[i, K_B]) == b:
            return True
    return False


@kernel(inline="always")
def _late_pair(gf, lo, hi, pad, step, grown, K, k0, k, i, j):
    """Whether grown geom i and geom j make a new candidate pair: j in the scene, the
    pair once when both grew, a candidate (`kc._candidate`), their bodies without a
    contact in K yet."""
    if j == i or gf[j, kc.G_EMIT] > step:
        return False
    if grown[int(gf[j, kc.G_BODY])] and j < i:
        return False  # both grew: once
    if not kc._candidate(gf, pad, lo, hi, i, j):
        return False
    ba, bb = int(gf[i, kc.G_BODY]), int(gf[j, kc.G_BODY])
    return not has_pair(K, k0, k, min(ba, bb), max(ba, bb))


@kernel
def expand_pairs(gf, lo, hi, pad, step, grown, K, k0, k):
    """Candidate geom pairs of the bodies whose sweep grew (grown (n,) bool) against all
    geoms in the scene at `step`, whose boxes overlap (`kc._candidate`) and whose bodies
    have no contact in K yet. Returns (P, m), in the order of the plain double loop over
    (i, j) (its reference in tests/test_stepped.py): the contact rows of later rounds are
    appended in that order and the solves visit them so. Each grown geom looks only at
    the geoms whose box starts within the widest box's width of its own along x (boxes
    sorted by their low x once per call) and at the unbounded ones (planes, NaN)."""
    n_geom = gf.shape[0]
    P = np.empty((16, 2), np.int64)
    m = np.int64(0)
    any_grown = False
    for i in range(n_geom):
        if gf[i, kc.G_EMIT] <= step and grown[int(gf[i, kc.G_BODY])]:
            any_grown = True
            break
    if not any_grown:
        return P, m
    bounded = np.empty(n_geom, np.int64)
    others = np.empty(n_geom, np.int64)
    nb = no = 0
    width = 0.0
    for j in range(n_geom):
        if math.isfinite(lo[j, 0]) and math.isfinite(hi[j, 0]) and hi[j, 0] >= lo[j, 0]:
            bounded[nb] = j
            nb += 1
            width = max(width, hi[j, 0] - lo[j, 0])
        else:
            others[no] = j
            no += 1
    x = np.empty(nb)
    for q in range(nb):
        x[q] = lo[bounded[q], 0]
    by_x = np.argsort(x, kind="mergesort")
    xs = np.empty(nb)
    box = np.empty((nb, 5))  # in that order, for the quick rejection below: the high x,
    for q in range(nb):  # then low and high y and z
        g = bounded[by_x[q]]
        xs[q] = x[by_x[q]]
        box[q, 0] = hi[g, 0]
        for c in range(1, 3):
            box[q, 2 * c - 1] = lo[g, c]
            box[q, 2 * c] = hi[g, c]
    near = np.empty(n_geom, np.int64)
    for i in range(n_geom):
        if gf[i, kc.G_EMIT] > step or not grown[int(gf[i, kc.G_BODY])]:
            continue
        # the test is pure, so test first and sort only the pairs it keeps (sorting
        # every geom of the window, for each grown geom in each round, was most of a step
        # of 1000 spheres while they still flew)
        cnt = 0
        if not (math.isfinite(lo[i, 0]) and math.isfinite(hi[i, 0])):
            for j in range(n_geom):
                if _late_pair(gf, lo, hi, pad, step, grown, K, k0, k, i, j):
                    near[cnt] = j
                    cnt += 1
        else:
            # a box overlapping i's along x starts in [lo_i - width, hi_i] (the slack
            # covers the rounding of the widths)
            first = lo[i, 0] - width - 1e-9 * (width + abs(lo[i, 0]))
            a, b = np.searchsorted(xs, first, "left"), np.searchsorted(xs, hi[i, 0], "right")
            for q in range(a, b):
                # boxes apart along an axis fail `_late_pair`'s overlap test: rejected
                # here from contiguous rows first (most of the window)
                if (box[q, 0] < lo[i, 0] or box[q, 1] > hi[i, 1] or box[q, 2] < lo[i, 1]
                        or box[q, 3] > hi[i, 2] or box[q, 4] < lo[i, 2]):
                    continue
                j = bounded[by_x[q]]
                if _late_pair(gf, lo, hi, pad, step, grown, K, k0, k, i, j):
                    near[cnt] = j
                    cnt += 1
            for q in range(no):
                j = others[q]
                if _late_pair(gf, lo, hi, pad, step, grown, K, k0, k, i, j):
                    near[cnt] = j
                    cnt += 1
            near[:cnt].sort()
        for e in range(cnt):
            P = kc._push_pair(P, m, i, near[e])
            m += 1
    return P, m


# output rows
O_A, O_B, O_P, O_N, O_D, O_TOI, O_IMP, O_REST, O_SIZE = 0, 1, 2, 5, 8, 9, 10, 13, 16


@kernel
def outputs(K, k, tol):
    """The contacts to report, OUT (k', O_SIZE): the pairs that have a point within the
    tolerance or an impulse (speculative contacts far apart are not contacts), with the
    impulse on B (world, N s: impact + rest) and toi = 0 for contacts that took an
    impact at the step's start (NaN otherwise: the next step warm-starts from those)."""
    OUT = np.empty((k, O_SIZE))
    m = 0
    i = 0
    while i < k:
        j = i
        keep = False
        while j < k and K[j, K_A] == K[i, K_A] and K[j, K_B] == K[i, K_B]:
            if K[j, K_DEPTH] >= -tol or K[j, K_LN] != 0.0 or K[j, K_IN] != 0.0 or \
                    K[j, K_LK] != 0.0 or \
                    K[j, K_LT] != 0.0 or K[j, K_LT + 1] != 0.0 or K[j, K_IT] != 0.0 or \
                    K[j, K_IT + 1] != 0.0:
                keep = True
            j += 1
        if keep:
            for q in range(i, j):
                OUT[m, O_A] = K[q, K_A]
                OUT[m, O_B] = K[q, K_B]
                for c in range(3):
                    OUT[m, O_P + c] = K[q, K_P + c]
                    OUT[m, O_N + c] = K[q, K_N + c]
                OUT[m, O_D] = K[q, K_DEPTH]
                impact = K[q, K_IN] != 0.0 or K[q, K_IT] != 0.0 or \
                    K[q, K_IT + 1] != 0.0 or K[q, K_LK] != 0.0
                OUT[m, O_TOI] = 0.0 if impact else math.nan
                # (shock impulses, K_SN, act on one body: not part of the pair's impulse,
                # and warm starting from them made a 10-box stack rock)
                ln = K[q, K_LN] + K[q, K_IN] + K[q, K_LK]
                l1 = K[q, K_LT] + K[q, K_IT] + K[q, K_LK + 1]
                l2 = K[q, K_LT + 1] + K[q, K_IT + 1] + K[q, K_LK + 2]
                for c in range(3):
                    OUT[m, O_IMP + c] = ln * K[q, K_N + c] + l1 * K[q, K_T1 + c] + \
                        l2 * K[q, K_T2 + c]
                    # the resting part alone (the next step's warm start with the mean)
                    OUT[m, O_REST + c] = K[q, K_LN] * K[q, K_N + c] + \
                        K[q, K_LT] * K[q, K_T1 + c] + K[q, K_LT + 1] * K[q, K_T2 + c]
                m += 1
        i = j
    return OUT, m


@kernel
def find_stops(C, k, dt, rb, rp, prm, n, inv_m, U, stopped):
    """`response: stop`: a movable body of a contact that penetrates or would close
    within the step stops (stopped (n,) bool)."""
    any_stop = False
    for q in range(k):
        a, b = int(C[q, kc.C_A]), int(C[q, kc.C_B])
        mode, _, _ = pair_material(rb, rp, a, b, n, prm[PR_DEF_EPS], prm[PR_DEF_MU])
        if mode != STOP:
            continue
        nrm = (C[q, kc.C_N], C[q, kc.C_N + 1], C[q, kc.C_N + 2])
        vn = la.dot(la.sub(kd.row3(U, b, 0), kd.row3(U, a, 0)), nrm)
        if C[q, kc.C_D] > 0.0 or -C[q, kc.C_D] + dt * vn < 0.0:
            for body in (a, b):
                if inv_m[body] > 0.0:
                    stopped[body] = True
                    any_stop = True
    return any_stop


# ----------------------------------------------------------------------------- the entry
#
# One compiled entry per set of shape pairs, made on first use: the pair kinds the scene
# can have are constants of the closure (the stage asks for every pair kind: one entry for
# every stepped scene). The integrator is read from the model (P_INTEGRATOR) at run time:
# pruned to the scene's integrator, each integrator was another first compile of the
# whole step (~130 s of CPU for the first, 25-30 s for each further one whose callees the
# cache already held), which a user who tried a second integrator met again and the suite
# paid four times on an empty cache; the other integrators' steps add ~20 s to the one
# first compile (docs/benchmarks.md, "First compile").

PAIR_KINDS = ("sphere-sphere", "plane-sphere", "box-sphere", "capsule-sphere",
              "cylinder-sphere", "plane-box", "plane-cylinder", "plane-capsule",
              "capsule-capsule", "box-capsule", "box-box")
_ENTRIES: dict = {}


def entry(kinds: tuple):
    """The stepped-step kernel for the pair kinds `kinds` (a bool per PAIR_KINDS), every
    integrator."""
    key = tuple(bool(x) for x in kinds)
    if key not in _ENTRIES:
        _ENTRIES[key] = _make_entry(key)
    return _ENTRIES[key]


def _make_entry(kinds: tuple):
    SS, PS, BS, CS, YS, PB, PY, PC, CC, BC, BB = kinds

    @kernel
    def step_kernel(mf, gf, rb, rp, prm, S, RS, prev_a, prev_b, prev_toi, prev_imp, prev_rest,
                    XC,
                    KIN, KIN_RS, S1, RS1, wb, wr, wm, kS):
        """One stepped step from (S, RS) into (S1, RS1) (module docstring). XC (x, C_SIZE):
        contacts of the pairs Python detects (meshes, hulls), at S. KIN, KIN_RS: the end
        states of kinematic bodies (the scene graph's), used when KIN has rows. Returns
        (OUT, k, h_prop): the contacts (outputs) and dopri5's step proposal."""
        n, r, ng = S.shape[0], RS.shape[0], gf.shape[0]
        integ = int(kd.param(mf, kd.P_INTEGRATOR))
        EU, SE, VE, R4 = (integ == kd.EULER, integ == kd.SYMPLECTIC_EULER,
                          integ == kd.VERLET, integ == kd.RK4)
        MEAN = not (EU or SE)  # positions move by the mean velocity (`_target`)
        body_frame = integ == kd.RK4 or integ == kd.DOPRI5
        dt, tol = prm[PR_DT], prm[PR_TOL]
        step = int(prm[PR_STEP])
        t = prm[PR_T]
        planar = prm[PR_PLANAR] != 0.0
        inv_m = np.empty(n)
        IW = np.empty((n, 9))
        body_tables(mf, step, S, RS, inv_m, IW)
        acc, M, Wr = wb[kd.WB_ACC], wr[kd.WR_M], wr[kd.WR_W]
        ext = np.zeros((n, 6))
        V0, W0 = np.empty((n, 3)), np.empty((n, 3))
        U, Wv = np.empty((n, 3)), np.empty((n, 3))
        kick(mf, step, t, dt, S, RS, inv_m, IW, acc, M, Wr, ext, V0, W0, U, Wv)
        sw = np.empty(n)
        sweeps(dt, V0, W0, U, Wv, rb, sw)
        need = np.empty(n)
        grown = np.zeros(n, np.bool_)
        stopped = np.zeros(n, np.bool_)
        W = np.empty((ng, kc.W_SIZE))
        cand = kc.box_scratch()  # box_box's, one for all its pairs (not one a pair)
        kc.place(gf, S, W)
        pad = np.empty(ng)
        lo, hi = np.empty((ng, 3)), np.empty((ng, 3))
        DP, DL = np.zeros((n, 3)), np.zeros((n, 3))
        DPi, DLi = np.zeros((n, 3)), np.zeros((n, 3))
        K = np.zeros((16, K_SIZE))
        k = np.int64(0)
        k0 = np.int64(0)
        changed = np.empty(n, np.int64)
        bounce = prm[PR_BOUNCE]
        rnd = 0
        rested = False
        v0 = np.empty((0, 3))  # the contacts' start velocities (round 0's, below)
        while True:
            if rnd > 0:  # bodies knocked faster than their sweep: find their new pairs
                sweeps(dt, V0, W0, U, Wv, rb, need)
                more = False
                for b in range(n):
                    grown[b] = need[b] > sw[b]
                    if grown[b]:
                        sw[b] = SWEEP_GROWTH * need[b]
                        more = True
                if not more or rnd > 2 * MAX_ROUNDS:
                    if rested:
                        break
                    rest(K, k, dt, int(prm[PR_ITER]), U, Wv, True)  # all pairs known: rest
                    rested = True
                    continue
            for g in range(ng):
                pad[g] = sw[int(gf[g, kc.G_BODY])] + 0.5 * tol
            kc.aabbs(gf, S, W, pad, lo, hi)
            if rnd == 0:
                P, m = kc.broad_phase(gf, lo, hi, step, pad)
            else:
                P, m = expand_pairs(gf, lo, hi, pad, step, grown, K, k0, k)
            C = np.empty((max(16, 2 * m + XC.shape[0]), kc.C_SIZE))
            kn = np.int64(0)
            for p in range(m):  # the narrow phase, pruned to the scene's pair kinds
                g1, g2 = P[p, 0], P[p, 1]
                if gf[g1, kc.G_PYTHON] != 0.0 or gf[g2, kc.G_PYTHON] != 0.0:
                    continue  # Python's (XC)
                first = kc._first(int(gf[g1, kc.G_TYPE]), int(gf[g2, kc.G_TYPE]))
                if first < 0:
                    continue
                ga, gb = (g1, g2) if first == 0 else (g2, g1)
                ta, tb = int(gf[ga, kc.G_TYPE]), int(gf[gb, kc.G_TYPE])
                ba, bb = int(gf[ga, kc.G_BODY]), int(gf[gb, kc.G_BODY])
                margin = sw[ba] + sw[bb] + tol
                C = kc._grow(C, kn, kc.MAX_PER_PAIR)
                got = 0
                if ta == kc.SPHERE:
                    if SS:
                        got = kc.sphere_sphere(gf, W, ga, gb, margin, C, kn)
                elif ta == kc.PLANE:
                    if tb == kc.SPHERE:
                        if PS:
                            got = kc.plane_sphere(gf, W, ga, gb, margin, C, kn)
                    elif tb == kc.BOX:
                        if PB:
                            got = kc.plane_box(gf, W, ga, gb, margin, C, kn)
                    elif tb == kc.CAPSULE:
                        if PC:
                            got = kc.plane_capsule(gf, W, ga, gb, margin, C, kn)
                    elif PY:
                        got = kc.plane_cylinder(gf, W, ga, gb, margin, C, kn)
                elif ta == kc.BOX:
                    if tb == kc.SPHERE:
                        if BS:
                            got = kc.box_sphere(gf, W, ga, gb, margin, C, kn)
                    elif tb == kc.CAPSULE:
                        if BC:
                            got = kc.box_capsule(gf, W, ga, gb, margin, C, kn)
                    elif BB:
                        got = kc.box_box(gf, W, ga, gb, margin, C, kn, cand)
                elif ta == kc.CAPSULE:
                    if tb == kc.SPHERE:
                        if CS:
                            got = kc.capsule_sphere(gf, W, ga, gb, margin, C, kn)
                    elif CC:
                        got = kc.capsule_capsule(gf, W, ga, gb, margin, C, kn)
                elif YS:
                    got = kc.cylinder_sphere(gf, W, ga, gb, margin, C, kn)
                kc.own_rows(gf, ga, gb, C, kn, got)
                kn += got
            if rnd == 0:
                C = kc._grow(C, kn, XC.shape[0])
                for q in range(XC.shape[0]):
                    for c in range(kc.C_SIZE):
                        C[kn, c] = XC[q, c]
                    kn += 1
                if kn > 1:
                    C = kc.sort_by_pair(C, kn)
            if planar:
                kn = kc.make_planar(C, kn)
            if rnd == 0 and find_stops(C, kn, dt, rb, rp, prm, n, inv_m, U, stopped):
                for b in range(n):
                    if stopped[b]:
                        inv_m[b] = 0.0
                        for c in range(9):
                            IW[b, c] = 0.0
                        for c in range(3):
                            U[b, c] = 0.0
                            Wv[b, c] = 0.0
                            V0[b, c] = 0.0
                            W0[b, c] = 0.0
            K = kc._grow(K, k, kn)
            for q in range(kn):
                prepare(K, k + q, C, q, S, inv_m, IW, V0, W0, U, Wv, rb, rp, prm)
            first_new = k
            k += kn
            if rnd == 0:
                k0 = k
            starts = np.empty(k - first_new + 1, np.int64)
            npairs = pair_starts(K, k, first_new, starts)
            impacts(K, starts, npairs, 0, dt, bounce, U, Wv, changed, MEAN)
            if rnd == 0:
                # the contacts' velocities at the step's start, impacts in (the kick taken
                # out again), before the warm start changes them: a contact that held at
                # the end of the last step holds in the mean over this one (`_target`)
                v0 = np.empty((k, 3))
                for i in range(k):
                    for j in range(3):
                        v0[i, j] = rel(K, i, j, U, Wv) - K[i, K_KICK + j]
                # after the impacts: they read the start-of-step approach velocities, which
                # last step's resting impulses must not change (an impulse the rest would
                # take back again is otherwise bounced on: energy gain in piles)
                held = np.empty((k, 2), np.bool_)
                warm_start(K, k, prev_a, prev_b, prev_toi, prev_imp, prev_rest, MEAN, U, Wv,
                           held)
                if MEAN:
                    # a pair holds as a whole, so that mirror-image points are treated
                    # alike (each point's own test split them by round-off, one loaded or
                    # stuck and the other not, and a symmetric box turned out of its
                    # plane): it held if one of its points carried load, and stuck if all
                    # those did stick; then every point of it holds in the mean (a point
                    # that carried none, apart, is only let close more slowly: `_target`)
                    i = 0
                    while i < k:
                        i_end = i
                        loaded, stuck = False, True
                        while i_end < k and K[i_end, K_A] == K[i, K_A] and \
                                K[i_end, K_B] == K[i, K_B]:
                            if held[i_end, 0]:
                                loaded = True
                                stuck = stuck and held[i_end, 1]
                            i_end += 1
                        for q in range(i, i_end):
                            held[q, 0] = loaded
                            held[q, 1] = loaded and stuck
                        i = i_end
                    for i in range(k):
                        if held[i, 0]:
                            K[i, K_V0N] = max(v0[i, 0], 0.0)
                        if held[i, 1]:
                            K[i, K_V0T] = v0[i, 1]
                            K[i, K_V0T + 1] = v0[i, 2]
                slide(K, k, dt, inv_m, U, DPi)
            if rested:  # pairs found after the rest: rest again with them
                rest(K, k, dt, int(prm[PR_ITER]), U, Wv, True)
            rnd += 1
        rest_small_islands(K, k, dt, inv_m, U, Wv)
        level = np.empty(n, np.int64)
        contact_levels(K, k, inv_m, tol, level)
        order, m_order = level_order(K, k, level, True)
        # an island has at most 3 k rows: with no island above SMALL_ISLAND_ROWS possible
        # (every small scene), the check and its copies are skipped
        large = 3 * k > SMALL_ISLAND_ROWS
        U_rest, W_rest = (U.copy(), Wv.copy()) if large else (U, Wv)
        shock(K, order, m_order, level, dt, SHOCK_ITERATIONS, U, Wv, DP, DL, True, IW)
        island = np.empty(k if large else 0, np.int64)
        live = np.empty(n if large else 0, np.bool_)
        if large and unsettled_islands(K, k, dt, inv_m, U, Wv, island, live):
            # a large island whose solve has not met its normal rows (`unsettled_islands`):
            # its rest swept on to convergence, then the shock levels again from the rest
            for b in range(n):
                for c in range(3):
                    U[b, c], Wv[b, c] = U_rest[b, c], W_rest[b, c]
                    DP[b, c], DL[b, c] = 0.0, 0.0
            for i in range(k):
                for j in range(3):
                    K[i, K_SN + j] = 0.0
            sweep_islands(K, k, dt, U, Wv, island, live, np.zeros(k, np.bool_),
                          np.zeros((k, 2)))
            shock(K, order, m_order, level, dt, SHOCK_ITERATIONS, U, Wv, DP, DL, True, IW)
        wrench(K, k, DP, DL, DPi, DLi)
        # the resting impulses as a constant wrench over the step: the integrator applies
        # them as it does the forces (a second-order one moves positions by the mean of
        # the start and end velocities, Moreau-Jean's theta = 1/2, so motion at a steady
        # acceleration in contact is exact); the impacts at the step's start, where they
        # were solved: their whole velocity change moves the positions
        for b in range(n):
            for c in range(3):
                ext[b, c] = DP[b, c] / dt
                ext[b, 3 + c] = DL[b, c] / dt
        S0i, RS0i = S, RS
        kicked = False
        for b in range(n):
            for c in range(3):
                if DPi[b, c] != 0.0 or DLi[b, c] != 0.0:
                    kicked = True
        if kicked:
            S0i, RS0i = S.copy(), RS.copy()
            for b in range(n):
                if inv_m[b] == 0.0:
                    continue
                for c in range(3):
                    S0i[b, kd.S_VEL + c] += DPi[b, c] * inv_m[b]
                slot = kd.slot_of(mf, b)
                if slot >= 0:
                    dw = la.matvec(kd.row9(IW, b, 0), kd.row3(DLi, b, 0))
                    for c in range(3):
                        RS0i[slot, kd.RS_L + c] += DLi[b, c]
                        S0i[b, kd.S_ANGVEL + c] += dw[c]
        for b in range(n):  # quaternions of bodies that do not turn stay as they are
            for c in range(kd.S_QUAT, kd.S_QUAT + 4):
                S1[b, c] = S[b, c]
        h_prop = prm[PR_H_PROP]
        ratios = wm[kd.WM_RATIOS:kd.WM_RATIOS + 16]
        if EU:
            kd.step_euler(mf, step, t, dt, S0i, RS0i, ext, S1, RS1, wb, wr)
        elif SE:
            kd.step_symplectic(mf, step, t, dt, S0i, RS0i, ext, S1, RS1, wb, wr, ratios)
        elif VE:
            kd.step_verlet(mf, step, t, dt, S0i, RS0i, ext, S1, RS1, wb, wr, ratios)
        elif R4:
            Ss, S0, RSs = np.empty((n, kd.S_SIZE)), np.empty((n, kd.S_SIZE)), \
                np.empty((r, kd.RS_SIZE))
            kd.step_rk4(mf, step, t, dt, S0i, RS0i, ext, S1, RS1, wb, wr, kS, Ss, S0, RSs)
        else:
            Ss, S0, RSs = np.empty((n, kd.S_SIZE)), np.empty((n, kd.S_SIZE)), \
                np.empty((r, kd.RS_SIZE))
            h_prop = kd.step_dopri5(mf, step, t, dt, S0i, RS0i, ext, S1, RS1, wb, wr, wm, kS,
                                    Ss, S0, RSs, h_prop)
            if h_prop < 0.0:
                return np.empty((0, O_SIZE)), 0, h_prop
        if body_frame:
            exact_spin(mf, DL, inv_m, RS0i, RS1)
        kd.post_step(mf, body_frame, step, dt, RS0i, S1, RS1)
        if EU:
            # Euler's positions do not see the step's forces (x1 = x0 + dt v0): a body
            # that took a resting impulse moves with symplectic Euler in this step, the
            # contact solve's model for it; free bodies keep Euler
            touched = np.zeros(n, np.bool_)
            any_touched = False
            for b in range(n):
                for c in range(3):
                    if DP[b, c] != 0.0 or DL[b, c] != 0.0 or DPi[b, c] != 0.0 \
                            or DLi[b, c] != 0.0:
                        touched[b] = True
                if touched[b]:
                    any_touched = True
            if any_touched:
                Sx, RSx = np.empty_like(S1), np.empty_like(RS1)
                for b in range(n):
                    for c in range(kd.S_QUAT, kd.S_QUAT + 4):
                        Sx[b, c] = S[b, c]
                kd.step_symplectic(mf, step, t, dt, S0i, RS0i, ext, Sx, RSx, wb, wr, ratios)
                kd.post_step(mf, False, step, dt, RS0i, Sx, RSx)
                for b in range(n):
                    if touched[b] and inv_m[b] != 0.0:
                        for c in range(kd.S_SIZE):
                            S1[b, c] = Sx[b, c]
                        slot = kd.slot_of(mf, b)
                        if slot >= 0:
                            for c in range(kd.RS_SIZE):
                                RS1[slot, c] = RSx[slot, c]
        if KIN.shape[0]:  # kinematic bodies where the scene graph put them
            ob = int(mf[kd.H_BODY])
            for b in range(n):
                if mf[ob + b * kd.B_SIZE + kd.B_DYNAMIC] == 0.0:
                    for c in range(kd.S_SIZE):
                        S1[b, c] = KIN[b, c]
            for kk in range(r):
                b = int(mf[kd.at(mf, kd.H_ROT, kk, kd.RT_SIZE) + kd.RT_INDEX])
                if mf[ob + b * kd.B_SIZE + kd.B_DYNAMIC] == 0.0:
                    for c in range(kd.RS_SIZE):
                        RS1[kk, c] = KIN_RS[kk, c]
        for b in range(n):  # stopped bodies keep their start pose, at rest
            if stopped[b]:
                for c in range(3):
                    S1[b, kd.S_POS + c] = S[b, kd.S_POS + c]
                    S1[b, kd.S_VEL + c] = 0.0
                    S1[b, kd.S_ANGVEL + c] = 0.0
                for c in range(4):
                    S1[b, kd.S_QUAT + c] = S[b, kd.S_QUAT + c]
                slot = kd.slot_of(mf, b)
                if slot >= 0:
                    for c in range(9):
                        RS1[slot, kd.RS_R + c] = RS[slot, kd.RS_R + c]
                    for c in range(3):
                        RS1[slot, kd.RS_L + c] = 0.0
        if MEAN:
            slip_stops(mf, K, k, v0, dt, inv_m, U, Wv, S1, RS1)
        end_separations(mf, K, k, S, RS, S1, RS1)
        dx, dth = np.empty((n, 3)), np.empty((n, 3))
        everything, _ = level_order(K, k, level, False)
        push_out(mf, K, k, everything, level, int(prm[PR_POS_ITER]), prm[PR_SLOP], inv_m,
                 IW, S1, RS1, dx, dth, True, MEAN)
        if MEAN:
            end_stop(mf, K, k, inv_m, int(prm[PR_ITER]), S1, RS1)
        if k > k0:  # rows of later rounds were appended: sort them in (K_A, K_B are
            K = kc.sort_by_pair(K, k)  # columns 0 and 1, as in detection's rows)
        OUT, m_out = outputs(K, k, tol)
        return OUT, m_out, h_prop

    return step_kernel


# ----------------------------------------------------------------------------- many steps
#
# The loop's call between two output samples (as kernels.dynamics.entry's run): several
# stepped steps in one compiled call, each step's contacts and impulses handed to the
# next as its warm start, the loop's per-step checks made after every step.

RUN_OK, RUN_FLAGGED, RUN_UNDERFLOW = 0, 1, 2  # run status codes
UNIT_FLAG = 0.5e-9  # |q|^2 - 1 that stops a run for the loop's own check (it fails at 1e-9)
_RUNS: dict = {}


def run_entry(kinds: tuple):
    """The many-steps kernel of the stepped step `entry(kinds)`."""
    key = tuple(bool(x) for x in kinds)
    if key not in _RUNS:
        _RUNS[key] = _make_run(entry(key))
    return _RUNS[key]


def _make_run(step_kernel):
    @kernel
    def run_kernel(mf, gf, rb, rp, prm, step0, count, n_steps, steps_per_frame, t_first,
                   h_prop, bS, bRS, prev_a, prev_b, prev_toi, prev_imp, prev_rest, XC, KIN,
                   KIN_RS,
                   wb, wr, wm, kS, base, base_set, set_base, guard, status):
        """Up to `count` stepped steps from step0 on the double buffers bS (2, n, 13) and
        bRS (2, r, 12), starting in buffer 0 at t_first (the later steps at (step0 + s)
        dt), from the contacts prev_* (as `entry`'s) and dopri5's proposal h_prop. XC,
        KIN, KIN_RS as `entry`'s (no rows: scenes with Python's contacts or animation
        call `entry` per step).

        After every step, as the loop's `check_state` and the stage's energy baseline: a
        state with a position, velocity, R or L not finite or past the loop's bounds, a
        quaternion off unit by more than UNIT_FLAG, or (`guard`, at frame ends) energy
        past `kernels.dynamics.energy_check`'s bound stops the run as RUN_FLAGGED for the
        loop to check (and raise) in Python; `set_base`: the energy baseline `base` (n,)
        J is replaced (base_set[0] = 1) when the force windows close within the step.

        status (out, int64 (5,)): [code, steps done, buffer of the last good state,
        body or component (RUN_UNDERFLOW), buffer of the flagged state]. Returns (OUT, m,
        h) of the last good step and of the flagged one: the contacts (`outputs`) and
        dopri5's proposal."""
        n = bS.shape[1]
        dt = prm[PR_DT]
        guard_from = kd.param(mf, kd.P_GUARD_FROM)
        per_body = np.empty(n)
        pa, pb, ptoi, pimp, prest = prev_a, prev_b, prev_toi, prev_imp, prev_rest
        out_good = np.empty((0, O_SIZE))
        out_last = out_good
        m_good, m_last = 0, 0
        h_good, h_last = h_prop, h_prop
        status[0] = RUN_OK
        status[1] = 0
        status[2] = 0
        status[3] = -1
        status[4] = 1
        cur = 0
        for s in range(count):
            st = step0 + s
            t = t_first if s == 0 else st * dt
            nxt = 1 - cur
            S, RS, S1, RS1 = bS[cur], bRS[cur], bS[nxt], bRS[nxt]
            status[4] = nxt
            prm[PR_STEP] = st
            prm[PR_T] = t
            prm[PR_H_PROP] = h_prop
            OUT, m, h_new = step_kernel(mf, gf, rb, rp, prm, S, RS, pa, pb, ptoi, pimp, prest, XC,
                                        KIN, KIN_RS, S1, RS1, wb, wr, wm, kS)
            if h_new < 0.0:
                status[0] = RUN_UNDERFLOW
                status[3] = int(-1.0 - h_new)
                break
            after = st + 1
            t_after = after * dt
            if set_base and 0.0 < guard_from and t < guard_from <= t_after:
                kd.body_energy(mf, S1, RS1, base)
                base_set[0] = 1
            flagged = kd.translation_ok(S1) >= 0 or kd.rotation_ok(mf, RS1) >= 0
            for b in range(n):
                qq = 0.0
                for c in range(kd.S_QUAT, kd.S_QUAT + 4):
                    qq += S1[b, c] * S1[b, c]
                if not abs(qq - 1.0) <= UNIT_FLAG:
                    flagged = True
            if not flagged and guard and t_after >= guard_from and (
                    after % steps_per_frame == 0 or after == n_steps):
                flagged = kd.energy_check(mf, S1, RS1, base, per_body, t_after - guard_from,
                                          dt)[0] >= 0
            if flagged:
                status[0] = RUN_FLAGGED
                out_last, m_last, h_last = OUT, m, h_new
                break
            out_good, m_good, h_good = OUT, m, h_new
            h_prop = h_new
            pa, pb = np.empty(m, np.int64), np.empty(m, np.int64)
            ptoi, pimp, prest = np.empty(m), np.empty((m, 3)), np.empty((m, 3))
            for i in range(m):
                pa[i] = int(OUT[i, O_A])
                pb[i] = int(OUT[i, O_B])
                ptoi[i] = OUT[i, O_TOI]
                for c in range(3):
                    pimp[i, c] = OUT[i, O_IMP + c]
                    prest[i, c] = OUT[i, O_REST + c]
            cur = nxt
            status[1] = s + 1
            status[2] = cur
        return out_good, m_good, h_good, out_last, m_last, h_last

    return run_kernel
