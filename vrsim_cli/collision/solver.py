"""Contact solvers of the response stage: isolated impacts and resting/stacked contact.

Two solvers share the impulse law of slide 5.4.2 (`vrsim_cli.impulse`) and a working set
of body velocities (`Bodies`):

- `resolve_impacts`: the impulses at one instant of impact (event-located by
  `response.py`). Contacts are processed one at a time, always the one approaching
  fastest, each with its own restitution (Guendelman, Bridson & Fedkiw 2003, propagation
  of impulses): a chain of touching bodies (Newton's cradle) passes the impulse along in
  order. Every impulse is the slide's exact alpha n plus Coulomb friction, so linear and
  angular momentum are conserved to round-off and eps = 1 conserves energy pairwise.
  After MAX_ELASTIC_PASSES impulses per contact, restitution drops to 0 so the loop ends.

- `solve_resting`: sequential impulses (Catto, GDC 2006; Box2D) for the contacts at the
  end of a step, restitution 0: accumulated normal impulses clamped to >= 0, friction
  clamped to the Coulomb cone |lambda_t| <= mu lambda_n, warm started from the previous
  step. Contacts are split into colours in which no movable body appears twice (Box2D v3's
  graph colouring), so each colour is one vectorised numpy update and colours run in
  Gauss-Seidel order. Then shock propagation (Guendelman et al. 2003): the bodies are
  layered by their contact distance from static or kinematic ones, and one pass from the
  ground up treats the lower body of each contact as infinite mass, first for the normal
  velocities, then for the penetration (linearised non-linear Gauss-Seidel on positions).
  This makes a stack or a heavy box on a light one hold independently of the mass ratio,
  which plain Gauss-Seidel (convergence ~ 1 - m_light/m_heavy per iteration) cannot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim_cli.impulse import inverse_mass_along, point_velocity, restitution_alpha
from vrsim_cli.rotation import cross

MAX_ELASTIC_PASSES = 32  # impulses per contact at one impact before eps is set to 0
APPROACH_EPS = 1e-12  # m/s: a relative normal velocity below -this is "approaching"


@dataclass
class Bodies:
    """Working velocities of all bodies while impulses are applied (not a State).

    inv_mass: (n,) 1/kg, 0 for static, kinematic and waiting bodies
    inv_inertia: (n, 3, 3) world frame 1/(kg m^2), 0 for bodies that do not turn freely
    vel: (n, 3) m/s; angvel: (n, 3) rad/s world
    d_angmom: (n, 3) kg m^2/s, the angular momentum added by impulses (p x P)
    pos: (n, 3) m centres of mass (fixed while velocities are solved)
    """

    inv_mass: np.ndarray
    inv_inertia: np.ndarray
    vel: np.ndarray
    angvel: np.ndarray
    d_angmom: np.ndarray
    pos: np.ndarray

    @property
    def movable(self) -> np.ndarray:
        return (self.inv_mass > 0.0) | (np.abs(self.inv_inertia).max(axis=(1, 2)) > 0.0)

    def apply(self, a, b, arm_a, arm_b, impulse) -> None:
        """Impulses (k, 3) on B and minus on A. Rows must not share a movable body
        (a colour, or k = 1); fixed bodies may repeat (they receive nothing)."""
        for body, arm, sign in ((b, arm_b, 1.0), (a, arm_a, -1.0)):
            p = sign * impulse
            dl = cross(arm, p)
            self.vel[body] += p * self.inv_mass[body, None]
            self.angvel[body] += np.einsum("kij,kj->ki", self.inv_inertia[body], dl)
            self.d_angmom[body] += np.where(self.inv_mass[body, None] > 0.0, dl, 0.0)


@dataclass(frozen=True)
class ContactSet:
    """Contacts prepared for the solvers (k rows).

    a, b: (k,) body indices; point, normal: (k, 3); depth: (k,) m; arm_a, arm_b: (k, 3) m
    restitution, friction: (k,) combined material values; t1, t2: (k, 3) unit tangents
    k_n, k_t1, k_t2: (k,) 1/kg inverse effective masses along n, t1, t2
    """

    a: np.ndarray
    b: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    arm_a: np.ndarray
    arm_b: np.ndarray
    restitution: np.ndarray
    friction: np.ndarray
    t1: np.ndarray
    t2: np.ndarray
    k_n: np.ndarray
    k_t1: np.ndarray
    k_t2: np.ndarray

    def __len__(self) -> int:
        return len(self.a)

    def take(self, idx) -> "ContactSet":
        return ContactSet(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))


def tangents(normal: np.ndarray):
    """Two unit tangents (k, 3) completing each normal to a right-handed basis."""
    helper = np.where((np.abs(normal[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t1 = cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, cross(normal, t1)


def prepare(bodies: Bodies, a, b, point, normal, depth, restitution, friction) -> ContactSet:
    arm_a, arm_b = point - bodies.pos[a], point - bodies.pos[b]
    t1, t2 = tangents(normal)
    im, ii = bodies.inv_mass, bodies.inv_inertia

    def kk(d):
        return inverse_mass_along(im[a], im[b], ii[a], ii[b], arm_a, arm_b, d)

    return ContactSet(a, b, point, normal, depth, arm_a, arm_b, restitution, friction, t1,
                      t2, kk(normal), kk(t1), kk(t2))


def relative_velocity(bodies: Bodies, c: ContactSet):
    """(k, 3) m/s: v_rel = v_B - v_A at the contact points (slide 5.4.2)."""
    return point_velocity(bodies.vel[c.b], bodies.angvel[c.b], c.arm_b) - \
        point_velocity(bodies.vel[c.a], bodies.angvel[c.a], c.arm_a)


def _friction(bodies: Bodies, c: ContactSet, lam_t, limit):
    """Coulomb friction: the tangential impulse that stops the sliding at the contact,
    added to the accumulated lam_t (k, 2) and clamped to the cone |lam_t| <= limit (k,).
    Returns the new lam_t and the impulse applied (k, 3)."""
    vr = relative_velocity(bodies, c)
    d1 = -np.where(c.k_t1 > 0, (vr * c.t1).sum(1) / np.where(c.k_t1 > 0, c.k_t1, 1), 0.0)
    d2 = -np.where(c.k_t2 > 0, (vr * c.t2).sum(1) / np.where(c.k_t2 > 0, c.k_t2, 1), 0.0)
    new = lam_t + np.stack([d1, d2], axis=1)
    norm = np.linalg.norm(new, axis=1)
    scale = np.where(norm > limit, limit / np.where(norm > 0, norm, 1.0), 1.0)
    new = new * scale[:, None]
    delta = new - lam_t
    return new, delta[:, :1] * c.t1 + delta[:, 1:] * c.t2


def resolve_impacts(bodies: Bodies, c: ContactSet, rest_speed: float) -> np.ndarray:
    """Apply the impulses of one instant of impact; returns the total impulse on B per
    contact (k, 3) N s. A contact approaching slower than rest_speed gets eps = 0."""
    k = len(c)
    total = np.zeros((k, 3))
    if not k:
        return total
    count = np.zeros(k, np.int64)
    for _ in range(MAX_ELASTIC_PASSES * k + 4 * k + 16):
        vn = (relative_velocity(bodies, c) * c.normal).sum(1)
        vn = np.where(c.k_n > 0, vn, 0.0)
        i = int(np.argmin(vn))
        if vn[i] >= -APPROACH_EPS:
            break
        one = c.take([i])
        eps = 0.0 if (-vn[i] < rest_speed or count[i] >= MAX_ELASTIC_PASSES) else \
            float(c.restitution[i])
        alpha = restitution_alpha(vn[i:i + 1], eps, one.k_n)
        p = alpha[:, None] * one.normal
        bodies.apply(one.a, one.b, one.arm_a, one.arm_b, p)
        total[i] += p[0]
        if one.friction[0] > 0.0:
            _, pt = _friction(bodies, one, np.zeros((1, 2)), one.friction * alpha)
            bodies.apply(one.a, one.b, one.arm_a, one.arm_b, pt)
            total[i] += pt[0]
        count[i] += 1
    return total


def colours(a, b, movable) -> list[np.ndarray]:
    """Split contacts into groups in which no movable body appears twice (greedy, in
    contact order, so bodies listed bottom-up are solved bottom-up)."""
    groups: list[list[int]] = []
    used: list[set] = []
    for k, (i, j) in enumerate(zip(a.tolist(), b.tolist())):
        mine = {x for x in (i, j) if movable[x]}
        for g, u in enumerate(used):
            if not (mine & u):
                groups[g].append(k)
                u |= mine
                break
        else:
            groups.append([k])
            used.append(set(mine))
    return [np.array(g, np.int64) for g in groups]


def levels(n_body: int, a, b, movable) -> np.ndarray:
    """(n,) contact distance of each body from a fixed (static or kinematic) body; movable
    bodies touching nothing fixed get a large level (they are all solved together)."""
    big = n_body + 1
    level = np.where(movable, big, 0)
    for _ in range(n_body + 1):
        old = level.copy()
        np.minimum.at(level, b, level[a] + 1)
        np.minimum.at(level, a, level[b] + 1)
        level = np.where(movable, level, 0)
        if np.array_equal(level, old):
            break
    return level


def solve_resting(bodies: Bodies, c: ContactSet, dt: float, iterations: int,
                  warm_n=None, warm_t=None):
    """Sequential impulses on the contacts c (restitution 0), then a shock-propagation pass
    on the normal velocities. Returns (lam_n (k,), lam_t (k, 2), impulse (k, 3)): the
    accumulated impulses (N s) and their world vector on B.

    A contact with a gap (depth < 0) may still close at speed -depth/dt (a speculative
    contact: it is not stopped before it touches)."""
    k = len(c)
    lam_n = np.zeros(k) if warm_n is None else np.maximum(warm_n, 0.0)
    lam_t = np.zeros((k, 2)) if warm_t is None else warm_t.copy()
    if not k:
        return lam_n, lam_t, np.zeros((0, 3))
    movable = bodies.movable
    groups = colours(c.a, c.b, movable)
    target = np.maximum(-c.depth, 0.0) / dt  # m/s allowed approach of a gap
    if warm_n is not None:
        lam_t = np.where((np.linalg.norm(lam_t, axis=1) <= c.friction * lam_n)[:, None],
                         lam_t, 0.0)
        for g in groups:
            sub = c.take(g)
            p = lam_n[g, None] * sub.normal + lam_t[g, :1] * sub.t1 + lam_t[g, 1:] * sub.t2
            bodies.apply(sub.a, sub.b, sub.arm_a, sub.arm_b, p)
    for _ in range(iterations):
        for g in groups:
            sub = c.take(g)
            if (sub.friction > 0).any():  # friction first, as Box2D: the normal wins last
                lam_t[g], pt = _friction(bodies, sub, lam_t[g], sub.friction * lam_n[g])
                bodies.apply(sub.a, sub.b, sub.arm_a, sub.arm_b, pt)
            vn = (relative_velocity(bodies, sub) * sub.normal).sum(1)
            safe = np.where(sub.k_n > 0, sub.k_n, 1.0)
            d = np.where(sub.k_n > 0, -(vn + target[g]) / safe, 0.0)
            new = np.maximum(lam_n[g] + d, 0.0)
            bodies.apply(sub.a, sub.b, sub.arm_a, sub.arm_b,
                         (new - lam_n[g])[:, None] * sub.normal)
            lam_n[g] = new
    _shock_velocities(bodies, c, target, movable)
    impulse = lam_n[:, None] * c.normal + lam_t[:, :1] * c.t1 + lam_t[:, 1:] * c.t2
    return lam_n, lam_t, impulse


def _shock_order(bodies: Bodies, c: ContactSet, movable):
    """Contacts grouped by the lower level of their bodies, each group coloured; and per
    contact whether A (resp. B) is the lower body, frozen during the pass."""
    level = levels(len(movable), c.a, c.b, movable)
    la, lb = level[c.a], level[c.b]
    freeze_a, freeze_b = la < lb, lb < la
    order = []
    for lv in np.unique(np.minimum(la, lb)):
        idx = np.flatnonzero(np.minimum(la, lb) == lv)
        order.extend(idx[g] for g in colours(c.a[idx], c.b[idx], movable))
    return order, freeze_a, freeze_b


def _frozen_view(bodies: Bodies, sub: ContactSet, fa, fb):
    """Inverse masses with the lower body of each contact made infinite."""
    im_a = np.where(fa, 0.0, bodies.inv_mass[sub.a])
    im_b = np.where(fb, 0.0, bodies.inv_mass[sub.b])
    ii_a = np.where(fa[:, None, None], 0.0, bodies.inv_inertia[sub.a])
    ii_b = np.where(fb[:, None, None], 0.0, bodies.inv_inertia[sub.b])
    return im_a, im_b, ii_a, ii_b


def _push(bodies: Bodies, sub: ContactSet, fa, fb, im_a, im_b, ii_a, ii_b, p, dpos, dtheta):
    """Apply impulses p (k, 3) to velocities (dpos None) or as position corrections."""
    for body, arm, sign, frozen, im, ii in ((sub.b, sub.arm_b, 1.0, fb, im_b, ii_b),
                                            (sub.a, sub.arm_a, -1.0, fa, im_a, ii_a)):
        q = sign * p
        turn = np.einsum("kij,kj->ki", ii, cross(arm, q))
        if dpos is None:
            bodies.vel[body] += q * im[:, None]
            bodies.angvel[body] += turn
            bodies.d_angmom[body] += np.where((im > 0)[:, None], cross(arm, q), 0.0)
        else:
            dpos[body] += q * im[:, None]
            dtheta[body] += turn


def _shock_velocities(bodies: Bodies, c: ContactSet, target, movable) -> None:
    """One pass from the ground up: no contact approaches (beyond its speculative
    allowance) afterwards, whatever the mass ratios."""
    order, freeze_a, freeze_b = _shock_order(bodies, c, movable)
    for g in order:
        sub = c.take(g)
        fa, fb = freeze_a[g], freeze_b[g]
        views = _frozen_view(bodies, sub, fa, fb)
        kn = inverse_mass_along(*views, sub.arm_a, sub.arm_b, sub.normal)
        vn = (relative_velocity(bodies, sub) * sub.normal).sum(1)
        d = np.where((kn > 0) & (vn + target[g] < 0), -(vn + target[g]) / np.where(
            kn > 0, kn, 1.0), 0.0)
        _push(bodies, sub, fa, fb, *views, d[:, None] * sub.normal, None, None)


def correct_positions(bodies: Bodies, c: ContactSet, slop: float, iterations: int):
    """Penetration removal (linearised non-linear Gauss-Seidel with shock propagation):
    returns (dpos (n, 3) m, dtheta (n, 3) rad world rotation vectors) that bring every
    contact's depth down to `slop`. The depth of a contact after corrections so far is
    depth - n . (dp_B + dtheta_B x p_B - dp_A - dtheta_A x p_A)."""
    n = len(bodies.inv_mass)
    dpos, dtheta = np.zeros((n, 3)), np.zeros((n, 3))
    if not len(c):
        return dpos, dtheta
    order, freeze_a, freeze_b = _shock_order(bodies, c, bodies.movable)
    for _ in range(iterations):
        for g in order:
            sub = c.take(g)
            fa, fb = freeze_a[g], freeze_b[g]
            views = _frozen_view(bodies, sub, fa, fb)
            kn = inverse_mass_along(*views, sub.arm_a, sub.arm_b, sub.normal)
            moved = dpos[sub.b] + cross(dtheta[sub.b], sub.arm_b) - dpos[sub.a] - \
                cross(dtheta[sub.a], sub.arm_a)
            depth = sub.depth - (moved * sub.normal).sum(1)
            d = np.where((kn > 0) & (depth > slop), (depth - slop) / np.where(kn > 0, kn, 1.0),
                         0.0)
            _push(bodies, sub, fa, fb, *views, d[:, None] * sub.normal, dpos, dtheta)
    return dpos, dtheta
