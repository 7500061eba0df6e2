"""Projected Gauss-Seidel over the contacts of one plastic impact, compiled.

The located impact solve (`stages/collision/solver.resolve_impacts`) goes in rounds: the
contacts that approach get their normal impulses together, then friction, and the
friction's turn can make others approach again. In a grid or pile of touching boxes the
rounds pass the impulse back and forth (measured: 124 rounds per event in the median,
681 at most, on 293 contacts of a 32-box grid; 0.8 s each event). `plastic_sweeps` takes
over a plastic impact (restitution 0 on every row in play) with more than
`solver.PLASTIC_ROWS` approaching rows. Per contact it computes the normal impulse that
stops the approach, clamped so that the total stays >= 0. It then solves the 2 x 2
tangent block that stops the slip and scales it into the cone mu lam_n. A friction
update that would raise the kinetic energy is skipped (the radial scaling is not the
cone's minimiser when the tangent block is anisotropic), unless the friction before it
has left its cone because the normal impulse fell. The result never pulls and never
leaves a cone; from zero impulses it does not add energy. Sweeps stop when no impulse
changes by more than `tol` (N s) or after `max_sweeps`. The reference is a plain numpy
loop of the same updates (tests/test_contact_solve.py, with the energy and cone checks
on random contact sets).
"""

from __future__ import annotations

import math

from vrsim_cli.kernels.jit import kernel


@kernel
def _along(i, j, a, b, dirs, jac_a, jac_b, vel, angvel):
    """Relative velocity v_B - v_A at contact i along its direction j."""
    ia, ib = a[i], b[i]
    s = 0.0
    for d in range(3):
        s += dirs[i, j, d] * (vel[ib, d] - vel[ia, d])
        s += jac_b[i, j, d] * angvel[ib, d] - jac_a[i, j, d] * angvel[ia, d]
    return s


@kernel
def _push(i, j, x, a, b, lin_a, lin_b, rot_a, rot_b, vel, angvel):
    """Impulse x along contact i's direction j: on B, minus on A."""
    ia, ib = a[i], b[i]
    for d in range(3):
        vel[ib, d] += x * lin_b[i, j, d]
        angvel[ib, d] += x * rot_b[i, j, d]
        vel[ia, d] -= x * lin_a[i, j, d]
        angvel[ia, d] -= x * rot_a[i, j, d]


@kernel
def _coupling(i, j, m, dirs, jac_a, jac_b, lin_a, lin_b, rot_a, rot_b):
    """The entry (j, m) of contact i's 3 x 3 Delassus block: the velocity change along
    d_j per unit impulse along d_m."""
    s = 0.0
    for d in range(3):
        s += dirs[i, j, d] * (lin_b[i, m, d] + lin_a[i, m, d])
        s += jac_b[i, j, d] * rot_b[i, m, d] + jac_a[i, j, d] * rot_a[i, m, d]
    return s


@kernel
def _friction_step(o1, o2, v1, v2, t11, t12, t21, t22, limit):
    """The friction impulse (n1, n2) of one point after a Gauss-Seidel update: the old
    one (o1, o2) minus the 2 x 2 tangent block's solve of the slip (v1, v2), scaled into
    the cone of radius limit (0 when limit <= 0); and whether to take it: when it does
    not raise the energy quadratic (its change d.(v_t + T d / 2) <= 0: the radial
    scaling is not the cone's minimiser when T is anisotropic), or when the old friction
    has left a cone that shrank (the cone comes first)."""
    if limit <= 0.0:
        n1, n2 = 0.0, 0.0
    else:
        det = t11 * t22 - t12 * t21
        if abs(det) > 1e-300:
            s1 = (t22 * v1 - t12 * v2) / det
            s2 = (t11 * v2 - t21 * v1) / det
        else:
            s1 = v1 / t11 if t11 > 0.0 else 0.0
            s2 = v2 / t22 if t22 > 0.0 else 0.0
        n1, n2 = o1 - s1, o2 - s2
        size = math.sqrt(n1 * n1 + n2 * n2)
        if size > limit:
            n1, n2 = n1 * (limit / size), n2 * (limit / size)
    d1, d2 = n1 - o1, n2 - o2
    if d1 == 0.0 and d2 == 0.0:
        return n1, n2, False
    work = d1 * (v1 + 0.5 * (t11 * d1 + t12 * d2)) + d2 * (v2 + 0.5 * (t21 * d1 + t22 * d2))
    return n1, n2, work <= 0.0 or o1 * o1 + o2 * o2 > limit * limit


@kernel
def plastic_sweeps(a, b, dirs, jac_a, jac_b, lin_a, lin_b, rot_a, rot_b, mu, vel, angvel,
                   lam, max_sweeps, tol):
    """Projected Gauss-Seidel on the contacts (k rows: a, b body indices; the ContactSet
    tables) towards v_n >= 0 and Coulomb friction, from the accumulated impulses lam
    (k, 3) along (n, t1, t2), which it updates, as it does vel and angvel (n, 3).
    Returns the number of sweeps made."""
    k = a.shape[0]
    sweeps = 0
    for _ in range(max_sweeps):
        sweeps += 1
        change = 0.0
        for i in range(k):
            knn = _coupling(i, 0, 0, dirs, jac_a, jac_b, lin_a, lin_b, rot_a, rot_b)
            if knn > 0.0:
                vn = _along(i, 0, a, b, dirs, jac_a, jac_b, vel, angvel)
                new = lam[i, 0] - vn / knn
                if new < 0.0:
                    new = 0.0
                dn = new - lam[i, 0]
                if dn != 0.0:
                    _push(i, 0, dn, a, b, lin_a, lin_b, rot_a, rot_b, vel, angvel)
                    lam[i, 0] = new
                    change = max(change, abs(dn))
            limit = mu[i] * lam[i, 0]
            v1 = _along(i, 1, a, b, dirs, jac_a, jac_b, vel, angvel)
            v2 = _along(i, 2, a, b, dirs, jac_a, jac_b, vel, angvel)
            t11 = _coupling(i, 1, 1, dirs, jac_a, jac_b, lin_a, lin_b, rot_a, rot_b)
            t12 = _coupling(i, 1, 2, dirs, jac_a, jac_b, lin_a, lin_b, rot_a, rot_b)
            t21 = _coupling(i, 2, 1, dirs, jac_a, jac_b, lin_a, lin_b, rot_a, rot_b)
            t22 = _coupling(i, 2, 2, dirs, jac_a, jac_b, lin_a, lin_b, rot_a, rot_b)
            o1, o2 = lam[i, 1], lam[i, 2]
            n1, n2, take = _friction_step(o1, o2, v1, v2, t11, t12, t21, t22, limit)
            if take:
                d1, d2 = n1 - o1, n2 - o2
                _push(i, 1, d1, a, b, lin_a, lin_b, rot_a, rot_b, vel, angvel)
                _push(i, 2, d2, a, b, lin_a, lin_b, rot_a, rot_b, vel, angvel)
                lam[i, 1], lam[i, 2] = n1, n2
                change = max(change, max(abs(d1), abs(d2)))
        if change <= tol:
            break
    return sweeps


@kernel
def dense_sweeps(A, target, mu, v, lam, max_sweeps, rel_tol):
    """Projected Gauss-Seidel on one body's contact problem in Delassus form (the
    fallback of `solver._patch`): A (3k, 3k) the Delassus matrix along (n, t1, t2) per
    point, v (3k,) the velocities (updated), lam (3k,) the impulses (updated), target
    (k,) allowed approach, mu (k,). Per point: the normal impulse that meets v_n =
    -target, clamped at >= 0; then the 2 x 2 tangent block solved and the friction
    scaled into mu lam_n, skipped when it would raise lam.v + lam.A lam / 2 unless the
    old friction has left a cone that shrank. Stops when no impulse changes by more
    than rel_tol (1 + the largest impulse). Returns 1 if it stopped so, else 0."""
    k = target.shape[0]
    m = 3 * k
    for _ in range(max_sweeps):
        change = 0.0
        for i in range(k):
            n = 3 * i
            if A[n, n] > 0.0:
                new = lam[n] - (v[n] + target[i]) / A[n, n]
                if new < 0.0:
                    new = 0.0
                d = new - lam[n]
                if d != 0.0:
                    for r in range(m):
                        v[r] += A[r, n] * d
                    lam[n] = new
                    change = max(change, abs(d))
            t1, t2 = n + 1, n + 2
            o1, o2 = lam[t1], lam[t2]
            limit = mu[i] * lam[n]
            a11, a12, a21, a22 = A[t1, t1], A[t1, t2], A[t2, t1], A[t2, t2]
            n1, n2, take = _friction_step(o1, o2, v[t1], v[t2], a11, a12, a21, a22, limit)
            if take:
                d1, d2 = n1 - o1, n2 - o2
                for r in range(m):
                    v[r] += A[r, t1] * d1 + A[r, t2] * d2
                lam[t1], lam[t2] = n1, n2
                change = max(change, max(abs(d1), abs(d2)))
        largest = 0.0
        for r in range(m):
            largest = max(largest, abs(lam[r]))
        if change <= rel_tol * (1.0 + largest):
            return 1
    return 0
