"""The end of one small island's contact solve: Newton on Coulomb's conditions, compiled.

Issue 48 item 3. The compiled step sweeps a small island's resting contacts (projected
Gauss-Seidel, `stepped.sweep_islands`), which finds the contacts that act and the ones
that slide, but converges slowly where contacts are redundant (a face's four corners)
and stops at its cap near the friction cone's edge (a box starting to slide within 1 %
of it ended up to 6e-4 of a t^2 / 2 off). From the sweeps' impulses, this polishes the
island's solution to round-off by a semismooth Newton method (Alart & Curnier 1991;
Acary & Brogliato 2008, section 13.4). Per contact i with impulses lam = (l_n, l_t)
(N s) and velocities u = (u_n, u_t) (m/s), u = u0 + A (lam - lam0), A the island's
Delassus matrix (3m x 3m, symmetric positive semi-definite; singular where contacts are
redundant):

    l_n >= 0,  u_n >= t_n,  l_n (u_n - t_n) = 0            (the target t_n: a gap may close)
    |l_t| <= mu l_n; |l_t| < mu l_n -> w = 0, else l_t = -mu l_n w / |w|,  w = u_t + o

(o: an offset of the slip, a stuck contact's start slip under theta = 1/2). Those
conditions are the zeros of Alart-Curnier's function, with r_n, r_t (N s per m/s) each
row's inverse effective mass (so F is an impulse):

    F_n = l_n - max(0, z_n),               z_n = l_n - r_n (u_n - t_n)
    F_t = l_t - proj_D(mu max(0, z_n)) z_t,  z_t = l_t - r_t w

and for a contact held sliding along a fixed unit direction e (`slip_stops`): F_t = l_t +
mu max(0, z_n) e. F is piecewise smooth; Newton's method takes an element of its
generalized Jacobian with a backtracking line search on |F|^2, so |F| never grows: the
polish ends no farther from Coulomb's law than the sweeps left it. Where A is singular
its Jacobian is too, so the steps are proximal: each round's problem has RIDGE diag(A)
(lam - centre) added to the velocities (regular), centred at the last round's answer,
and moves only A's range; the split of a redundant load (which the velocities do not
fix, but a sliding face's friction torque does depend on) stays the sweeps'. The polish
stops where F is met to ROUNDOFF of the island's impulse scale, where a step cannot
descend, or after NEWTON_STEPS steps.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.kernels.jit import kernel

NEWTON_STEPS = 64  # cap: from converged sweeps a polish takes 1-3 steps, from sweeps
# stopped at their cap near redundancy up to ~40 (each round gains RIDGE A_rr / s)
RIDGE = 1e-10  # of each row's diagonal: the proximal term. The Newton matrix's condition
# stays ~1e10, so A's range keeps every digit; a round shrinks the velocities' error by
# RIDGE A_rr / s for an eigenvalue s of A; a step adds ~1e-16/RIDGE of the residual it
# starts from to the load split (from converged sweeps' residual, ~1e-15 of the loads:
# nothing)
ROUNDOFF = 1e-13  # of the impulse scale: F's round-off, up to 48 terms of a row each off by
# ~2e-16 of |A| |lam| (an r-scaled A is ~1), with a margin of ten
ARMIJO = 1e-4  # sufficient decrease of |F|^2 (the usual constant: Nocedal & Wright 3.1)
HALVINGS = 40  # step halvings of the line search before a step counts as not descending
# (then the polish stops: the step is below ~1e-12 of the full one)


@kernel
def rho(A, r):
    """r (3m,): per contact, 1 / A_nn for the normal row and 1 / the larger eigenvalue of
    the 2 x 2 tangent block for both tangent rows (the largest step of the tangent
    projection that cannot overshoot); 1 where the block is zero (a row no body sees)."""
    m = A.shape[0] // 3
    for i in range(m):
        p = 3 * i
        r[p] = 1.0 / A[p, p] if A[p, p] > 0.0 else 1.0
        a11, a12, a22 = A[p + 1, p + 1], A[p + 1, p + 2], A[p + 2, p + 2]
        mean, dif = 0.5 * (a11 + a22), 0.5 * (a11 - a22)
        top = mean + math.sqrt(dif * dif + a12 * a12)
        r[p + 1] = r[p + 2] = 1.0 / top if top > 0.0 else 1.0


@kernel
def velocities(A, u0, lam0, lam, centre, ridge, u):
    """u = u0 + A (lam - lam0) + ridge diag(A) (lam - centre): the velocities of the
    proximal problem (module docstring); ridge 0 gives the island's own."""
    nr = lam.shape[0]
    for i in range(nr):
        s = u0[i]
        for j in range(nr):
            d = lam[j] - lam0[j]
            if d != 0.0:
                s += A[i, j] * d
        u[i] = s + ridge * A[i, i] * (lam[i] - centre[i])


@kernel(inline="always")
def contact_residual(ln, lt1, lt2, un, ut1, ut2, tn, o1, o2, mu, fixed, e1, e2, rn, rt):
    """Alart-Curnier's F (module docstring) of one contact: impulses (ln, lt1, lt2),
    velocities (un, ut1, ut2), target tn, slip offset (o1, o2), friction mu, held sliding
    along -(e1, e2) when `fixed`, row scales rn, rt. Returns (F_n, F_t1, F_t2)."""
    lnp = max(ln - rn * (un - tn), 0.0)
    bound = mu * lnp
    if fixed:
        return ln - lnp, lt1 + bound * e1, lt2 + bound * e2
    z1 = lt1 - rt * (ut1 + o1)
    z2 = lt2 - rt * (ut2 + o2)
    nz = math.sqrt(z1 * z1 + z2 * z2)
    if nz > bound:
        z1 *= bound / nz
        z2 *= bound / nz
    return ln - lnp, lt1 - z1, lt2 - z2


@kernel
def residual(u, lam, tn, off, mu, fixed, e, r, F):
    """Alart-Curnier's F (module docstring) at lam, whose velocities are u; returns
    max |F|."""
    m = lam.shape[0] // 3
    worst = 0.0
    for i in range(m):
        p = 3 * i
        F[p], F[p + 1], F[p + 2] = contact_residual(
            lam[p], lam[p + 1], lam[p + 2], u[p], u[p + 1], u[p + 2], tn[i], off[i, 0],
            off[i, 1], mu[i], fixed[i], e[i, 0], e[i, 1], r[p], r[p + 1])
        for j in range(3):
            worst = max(worst, abs(F[p + j]))
    return worst


@kernel
def jacobian(A, u, lam, tn, off, mu, fixed, e, r, ridge, J):
    """J (3m, 3m): an element of F's generalized Jacobian at lam, for the proximal
    problem's velocities (A with `ridge` times its diagonal added)."""
    nr = lam.shape[0]
    m = nr // 3
    for i in range(nr):
        for j in range(nr):
            J[i, j] = 0.0
    dln = np.empty(nr)  # the derivative of max(0, z_n) of one contact
    dz1, dz2 = np.empty(nr), np.empty(nr)
    for i in range(m):
        p = 3 * i
        zn = lam[p] - r[p] * (u[p] - tn[i])
        if zn > 0.0:
            for j in range(nr):
                J[p, j] = r[p] * A[p, j]
            J[p, p] += r[p] * ridge * A[p, p]
            for j in range(nr):
                dln[j] = -J[p, j]
            dln[p] += 1.0
        else:
            J[p, p] = 1.0
            for j in range(nr):
                dln[j] = 0.0
        lnp = max(zn, 0.0)
        bound = mu[i] * lnp
        if fixed[i]:
            for c in range(2):
                J[p + 1 + c, p + 1 + c] = 1.0
                for j in range(nr):
                    J[p + 1 + c, j] += mu[i] * e[i, c] * dln[j]
            continue
        z1 = lam[p + 1] - r[p + 1] * (u[p + 1] + off[i, 0])
        z2 = lam[p + 2] - r[p + 2] * (u[p + 2] + off[i, 1])
        for j in range(nr):  # dz_t = e_t - r_t A_t (with the ridge)
            dz1[j] = -r[p + 1] * A[p + 1, j]
            dz2[j] = -r[p + 2] * A[p + 2, j]
        dz1[p + 1] += 1.0 - r[p + 1] * ridge * A[p + 1, p + 1]
        dz2[p + 2] += 1.0 - r[p + 2] * ridge * A[p + 2, p + 2]
        nz = math.sqrt(z1 * z1 + z2 * z2)
        if nz <= bound:  # inside the disc: F_t = l_t - z_t
            for j in range(nr):
                J[p + 1, j] = -dz1[j]
                J[p + 2, j] = -dz2[j]
            J[p + 1, p + 1] += 1.0
            J[p + 2, p + 2] += 1.0
            continue
        # on the disc's edge: F_t = l_t - bound z_t / |z_t|
        h1, h2 = z1 / nz, z2 / nz
        s = bound / nz
        for j in range(nr):
            db = mu[i] * dln[j]
            # (I - h h^T) dz
            q1 = (1.0 - h1 * h1) * dz1[j] - h1 * h2 * dz2[j]
            q2 = -h1 * h2 * dz1[j] + (1.0 - h2 * h2) * dz2[j]
            J[p + 1, j] = -h1 * db - s * q1
            J[p + 2, j] = -h2 * db - s * q2
        J[p + 1, p + 1] += 1.0
        J[p + 2, p + 2] += 1.0


@kernel
def lu_solve(J, b, x):
    """x = -J^-1 b by Gaussian elimination with partial pivoting (J and b are changed;
    ties between equal pivots go to the first row, so the result is deterministic).
    Returns False where a pivot is zero."""
    nr = b.shape[0]
    for c in range(nr):
        best, piv = abs(J[c, c]), c
        for i in range(c + 1, nr):
            if abs(J[i, c]) > best:
                best, piv = abs(J[i, c]), i
        if best == 0.0:
            return False
        if piv != c:
            for j in range(nr):
                J[c, j], J[piv, j] = J[piv, j], J[c, j]
            b[c], b[piv] = b[piv], b[c]
        for i in range(c + 1, nr):
            f = J[i, c] / J[c, c]
            if f != 0.0:
                for j in range(c + 1, nr):
                    J[i, j] -= f * J[c, j]
                b[i] -= f * b[c]
    for i in range(nr - 1, -1, -1):
        s = b[i]
        for j in range(i + 1, nr):
            s -= J[i, j] * x[j]
        x[i] = s / J[i, i]
    for i in range(nr):
        x[i] = -x[i]
    return True


@kernel
def _newton(A, u0, lam0, tn, off, mu, fixed, e, r, centre, ridge, lam, u, F, J, dx, trial,
            ut, Ft, limit):
    """One Newton step with a backtracking line search on |F|^2 of the proximal problem
    centred at `centre`; lam, u, F updated. A step is shortened to move no impulse by
    more than `limit` (the island's impulse scale: a polish is a local method, and where
    the sweeps left a wrong set of acting contacts the near-singular Newton matrix
    otherwise threw loads to 1e10 along A's null space). Returns False where it cannot
    descend."""
    nr = lam.shape[0]
    jacobian(A, u, lam, tn, off, mu, fixed, e, r, ridge, J)
    for i in range(nr):
        Ft[i] = F[i]
    if not lu_solve(J, Ft, dx):
        return False
    longest = 0.0
    for i in range(nr):
        longest = max(longest, abs(dx[i]))
    if longest > limit:
        for i in range(nr):
            dx[i] *= limit / longest
    merit = 0.0
    for i in range(nr):
        merit += F[i] * F[i]
    step = 1.0
    for _ in range(HALVINGS):
        for i in range(nr):
            trial[i] = lam[i] + step * dx[i]
        velocities(A, u0, lam0, trial, centre, ridge, ut)
        residual(ut, trial, tn, off, mu, fixed, e, r, Ft)
        value = 0.0
        for i in range(nr):
            value += Ft[i] * Ft[i]
        if value <= (1.0 - 2.0 * ARMIJO * step) * merit:
            for i in range(nr):
                lam[i] = trial[i]
                u[i] = ut[i]
                F[i] = Ft[i]
            return True
        step *= 0.5
    return False


@kernel
def polish(A, u0, lam0, tn, off, mu, fixed, e, lam):
    """lam (3m,): the island's impulses polished towards Coulomb's conditions (module
    docstring) from lam's values on entry (the sweeps' answer; lam0 are the impulses at
    which the velocities are u0), in proximal rounds of Newton steps; it ends on the
    answer with the least |F| it saw. Returns (met, Newton steps): met when F is met to
    round-off."""
    nr = lam.shape[0]
    m = nr // 3
    r = np.empty(nr)
    rho(A, r)
    u, F, J = np.empty(nr), np.empty(nr), np.empty((nr, nr))
    dx, trial, ut, Ft = np.empty(nr), np.empty(nr), np.empty(nr), np.empty(nr)
    centre = lam.copy()
    velocities(A, u0, lam0, lam, centre, 0.0, u)
    worst = residual(u, lam, tn, off, mu, fixed, e, r, F)
    scale = 0.0  # the island's impulse scale: its impulses and the first residual
    for i in range(nr):
        scale = max(scale, abs(lam[i]), abs(F[i]))
    for i in range(m):
        scale = max(scale, r[3 * i] * abs(u0[3 * i] - tn[i]))
    best, best_worst = lam.copy(), worst  # the answer nearest Coulomb's law so far
    steps = 0
    while steps < NEWTON_STEPS:
        for i in range(nr):
            scale = max(scale, abs(lam[i]))
        if worst <= ROUNDOFF * scale:
            return True, steps
        for i in range(nr):  # a new proximal round, centred here (F unchanged at lam)
            centre[i] = lam[i]
        while steps < NEWTON_STEPS:
            steps += 1
            if not _newton(A, u0, lam0, tn, off, mu, fixed, e, r, centre, RIDGE, lam, u, F,
                           J, dx, trial, ut, Ft, scale):
                break
            inner = 0.0
            for i in range(nr):
                inner = max(inner, abs(F[i]))
            if inner <= ROUNDOFF * scale:
                break
        velocities(A, u0, lam0, lam, centre, 0.0, u)
        worst = residual(u, lam, tn, off, mu, fixed, e, r, F)
        if worst >= best_worst:  # a round that did not bring the island's own F down: stop
            break
        best_worst = worst
        for i in range(nr):
            best[i] = lam[i]
    # the rounds descend on their own problems, not on F: the polish returns the answer
    # nearest Coulomb's law it saw, never one farther than the sweeps' (its start)
    for i in range(nr):
        lam[i] = best[i]
    return best_worst <= ROUNDOFF * scale, steps
