"""Reference (tests only): the numpy contact solver stepped impacts used before
kernels/stepped.py, projected Jacobi with mass splitting.

Used by `response.step` when `collision.impacts` is `stepped` (many bodies: a pile of
spheres, a box full of debris), where locating every impact in time would cut the step
once per impact. All contacts of the step's end are solved together, every contact in
parallel, so one iteration is a fixed handful of numpy calls whatever the number of
contacts (no colouring, no Python loop over contacts).

Mass splitting (Tonge, Benevolenski & Voroshilov 2012, "Mass splitting for jitter-free
parallel rigid body simulation", ACM TOG 31(4)): a body in n_c contacts is split into n_c
copies of mass m / n_c, each contact is solved exactly against its copies, and the body
takes the average of its copies' velocities. That average is the plain sum of all its
contacts' impulses divided by the full mass, so the update is a Jacobi step whose
per-contact effective mass is computed with the split masses: 1/K = 1/(n_A K_A + n_B K_B).
Unlike plain Jacobi (which overshoots when a body has several contacts) it converges;
unlike Gauss-Seidel it needs no ordering and no colouring.

Per contact (n, t1, t2), accumulated impulses lam (Catto 2006): the normal impulse stays
>= 0, friction stays in the Coulomb cone |lam_t| <= mu lam_n. The normal target velocity:
- touching, penetrating, or with a gap g that it would close within a step (-vn0 dt >=
  g), and approaching faster than the bounce speed: -eps vn0 (Newton's restitution on
  the velocity the contact had at the step's end, vn0; slide 5.4.2);
- touching, slower: 0 (resting contact);
- a gap g > 0 (within the tolerance) it would not close: -g / dt, the contact may close
  the gap this step.
The bounce speed (`response.resting`) is rest_speed, but at least 2 |g| dt: a resting
contact approaches at |g| dt after each free-flight step, which must not bounce.
Warm starting takes last step's impulse of the same contact. Penetration is then removed
by the same Jacobi iteration on positions (linearised, along the normal), down to `slop`.
"""

from __future__ import annotations

import numpy as np

# J, G are scipy sparse matrices: their products are scipy's own loops, not BLAS
from vrsim_cli.maths.products import matmul

from vrsim_cli.stages.collision.solver import Bodies


class System:
    """The contacts of one step as sparse matrices over the stacked body velocities
    u = (v_0 .. v_n-1, omega_0 .. omega_n-1) (6n,):

    J (3k, 6n): row 3c + j gives contact c's relative velocity along d_j (n, t1, t2):
        d_j . (v_B - v_A) + (p_B x d_j) . omega_B - (p_A x d_j) . omega_A
    GT (6n, 3k): column 3c + j is the change of u per unit impulse along d_j:
        (d_j / m_B, I_B^-1 (p_B x d_j)) on B and minus A's on A. J's pattern, transposed
        (the same arrays read as compressed columns).
    inv_k (k, 3): 1 / K along each d_j with every body's mass split among its contacts.
    dirs (k, 3, 3): rows n, t1, t2.
    """

    def __init__(self, bodies: Bodies, a, b, point, normal, depth):
        from scipy.sparse import csc_matrix, csr_matrix  # scenes with stepped impacts only

        n, k = len(bodies.inv_mass), len(a)
        half = 0.5 * depth[:, None] * normal  # each arm ends at its own witness point
        arm_a, arm_b = point + half - bodies.pos[a], point - half - bodies.pos[b]
        dirs = _basis(normal)  # (k, 3, 3): rows n, t1, t2
        jac_a = _cross(arm_a[:, None, :], dirs)  # (k, 3, 3): p x d_j per row
        jac_b = _cross(arm_b[:, None, :], dirs)
        # An arm along the normal (every sphere) has no normal torque: drop the round-off
        # of p x n, so pushing a sphere out of penetration does not turn it by 1e-20 rad.
        for arm, jac in ((arm_a, jac_a), (arm_b, jac_b)):
            length = np.sqrt((arm * arm).sum(1))
            tiny = np.sqrt((jac[:, 0] ** 2).sum(1)) <= 1e-12 * length
            jac[tiny, 0] = 0.0
        rot_a = matmul(jac_a, bodies.inv_inertia[a])  # rows I^-1 (p x d_j) (I^-1 is symmetric)
        rot_b = matmul(jac_b, bodies.inv_inertia[b])
        im_a = bodies.inv_mass[a, None, None]
        im_b = bodies.inv_mass[b, None, None]
        xyz = np.arange(3)
        cols = np.concatenate([3 * b[:, None] + xyz, 3 * a[:, None] + xyz,
                               3 * (n + b[:, None]) + xyz, 3 * (n + a[:, None]) + xyz], axis=1)
        cols = np.broadcast_to(cols[:, None, :], (k, 3, 12)).ravel()  # 12 entries per row
        ptr = np.arange(0, 36 * k + 1, 12)
        self.J = csr_matrix((np.concatenate([dirs, -dirs, jac_b, -jac_a], axis=2).ravel(),
                             cols, ptr), shape=(3 * k, 6 * n))
        g = np.concatenate([im_b * dirs, -im_a * dirs, rot_b, -rot_a], axis=2).ravel()
        self.GT = csc_matrix((g, cols, ptr), shape=(6 * n, 3 * k))  # G's arrays, transposed
        # K of each body alone along d_j; split: n_A K_A + n_B K_B (Tonge et al. 2012)
        part_a = im_a[:, :, 0] + (jac_a * rot_a).sum(2)
        part_b = im_b[:, :, 0] + (jac_b * rot_b).sum(2)
        count = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
        count = np.where(bodies.movable, np.maximum(count, 1), 0).astype(float)
        kk = count[a, None] * part_a + count[b, None] * part_b
        self.inv_k = np.where(kk > 0.0, 1.0 / np.where(kk > 0.0, kk, 1.0), 0.0)
        self.dirs, self.depth, self.n_body, self.k = dirs, depth, n, k


def _cross(u, v):
    """u x v over the last axis (broadcast), by components (einsum is slower here)."""
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=-1)


def _basis(normal):
    """(k, 3, 3) rows n, t1, t2: an orthonormal right-handed basis per normal (t1 is n
    crossed with the world axis least along n, so it is never ill-conditioned)."""
    helper = np.zeros_like(normal)
    helper[np.arange(len(normal)), np.argmin(np.abs(normal), axis=1)] = 1.0
    t1 = _cross(normal, helper)
    t1 /= np.sqrt((t1 * t1).sum(1))[:, None]
    return np.stack([normal, t1, _cross(normal, t1)], axis=1)


def _stack(bodies: Bodies) -> np.ndarray:
    return np.concatenate([bodies.vel.ravel(), bodies.angvel.ravel()])


def _unstack(bodies: Bodies, u) -> None:
    n = len(bodies.inv_mass)
    bodies.vel[:] = u[:3 * n].reshape(n, 3)
    bodies.angvel[:] = u[3 * n:].reshape(n, 3)


def _cone_scale(lam, friction):
    """(k,) factor that brings the friction impulse lam[:, 1:] into |lam_t| <= mu lam_n."""
    limit = friction * lam[:, 0]
    norm = np.sqrt(lam[:, 1] ** 2 + lam[:, 2] ** 2)
    return np.where(norm > limit, limit / np.where(norm > 0.0, norm, 1.0), 1.0)


def solve(bodies: Bodies, system: System, restitution, friction, dt: float,
          bounce_speed: float, iterations: int, warm=None) -> np.ndarray:
    """Velocities of `bodies` after the contacts' impulses (in place). Returns the
    accumulated impulse (k, 3) N s, world, on B of each contact. restitution, friction:
    (k,) combined material values; bounce_speed: m/s, contacts approaching slower rest;
    warm: (k, 3) impulses (N s, world) to start from (last step's, same contact), or
    None."""
    k = system.k
    if not k:
        return np.zeros((0, 3))
    u = _stack(bodies)
    vn0 = (system.J @ u)[0::3]
    impact = vn0 < -bounce_speed
    bounce = np.where(impact, -restitution * vn0, 0.0)
    # A gap this step's approach would close is an impact now: waiting a step would
    # first slow it to gap/dt and then bounce that tiny speed.
    closes = (system.depth >= 0.0) | (impact & (-vn0 * dt >= -system.depth))
    target = np.zeros((k, 3))
    target[:, 0] = np.where(closes, bounce, system.depth / dt)  # m/s wanted
    lam = np.zeros((k, 3))
    if warm is not None:
        lam = (system.dirs * warm[:, None, :]).sum(2)
        lam[:, 0] = np.maximum(lam[:, 0], 0.0)
        lam[:, 1:] *= _cone_scale(lam, friction)[:, None]
        u += system.GT @ lam.ravel()
    for _ in range(iterations):
        vr = (system.J @ u).reshape(k, 3)
        new = lam - (vr - target) * system.inv_k
        np.maximum(new[:, 0], 0.0, out=new[:, 0])
        new[:, 1:] *= _cone_scale(new, friction)[:, None]
        u += system.GT @ (new - lam).ravel()
        lam = new
    _unstack(bodies, u)
    return (lam[:, :, None] * system.dirs).sum(1)


def correct_positions(system: System, slop: float, iterations: int):
    """(dpos (n, 3) m, dtheta (n, 3) rad) that bring the contacts' depths towards `slop`:
    the same split-mass Jacobi on the depth along each normal, linearised."""
    n = system.n_body
    q = np.zeros(6 * n)  # stacked displacements (dpos, dtheta)
    if system.k and iterations:
        Jn, GnT = system.J[0::3], system.GT[:, 0::3]
        inv_k = system.inv_k[:, 0]
        for _ in range(iterations):
            lam = np.maximum(system.depth - Jn @ q - slop, 0.0) * inv_k
            q += GnT @ lam
    return q[:3 * n].reshape(n, 3), q[3 * n:].reshape(n, 3)
