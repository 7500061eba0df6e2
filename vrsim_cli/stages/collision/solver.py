"""Contact solvers of the response stage: isolated impacts and resting/stacked contact.

Two solvers share the impulse law of slide 5.4.2 (`vrsim_cli.impulse`) and a working set
of body velocities (`Bodies`):

- `resolve_impacts`: the impulses at one instant of impact (event-located by
  `response.py`), in rounds. Each round takes every contact that approaches and solves
  their normal impulses together: a small complementarity problem (impulses >= 0, each
  normal velocity >= its own restitution target -eps v_n, one of the two tight), solved
  exactly by active sets with a minimum-norm pseudo-inverse, so that the points of one
  impact (a box landing flat, a bar on its edge) get equal impulses and a symmetric
  impact stays symmetric (Anitescu & Potra 1997; Stewart & Trinkle 1996). Friction
  follows in the same round, all points together, scaled into each Coulomb cone.
  Contacts that only touch wait: when the impulses make them approach, the next round
  solves them, so a chain passes the impulse along in order (Guendelman, Bridson &
  Fedkiw 2003: Newton's cradle). Every impulse acts along the contact directions, so
  linear and angular momentum are conserved to round-off. After MAX_ELASTIC_PASSES
  rounds of a contact its restitution drops to 0, so the rounds end.

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

from vrsim_cli.maths.impulse import inverse_mass_along
from vrsim_cli.maths.products import dot, matmul
from vrsim_cli.maths.rotation import cross

MAX_ELASTIC_PASSES = 32  # impulses per contact at one impact before eps is set to 0
APPROACH_EPS = 1e-12  # m/s: a relative normal velocity below -this is "approaching"


@dataclass
class Bodies:
    """Working velocities of all bodies while impulses are applied (not a State).

    inv_mass: (n,) 1/kg, 0 for static, kinematic and waiting bodies
    inv_inertia: (n, 3, 3) world frame 1/(kg m^2), 0 for bodies that do not turn freely
    vel: (n, 3) m/s; angvel: (n, 3) rad/s world (angular momentum follows as I(t) omega)
    pos: (n, 3) m centres of mass (fixed while velocities are solved)
    """

    inv_mass: np.ndarray
    inv_inertia: np.ndarray
    vel: np.ndarray
    angvel: np.ndarray
    pos: np.ndarray

    @property
    def movable(self) -> np.ndarray:
        return (self.inv_mass > 0.0) | (np.abs(self.inv_inertia).max(axis=(1, 2)) > 0.0)


@dataclass(frozen=True)
class ContactSet:
    """Contacts prepared for the solvers (k rows), with everything an impulse needs
    precomputed along the three directions d_j = (n, t1, t2):

    a, b: (k,) body indices; normal: (k, 3); depth: (k,) m; arm_a, arm_b: (k, 3) m
    restitution, friction: (k,) combined material values
    dirs: (k, 3, 3) rows n, t1, t2 (an orthonormal basis)
    jac_a, jac_b: (k, 3, 3) p x d_j: the normal velocity is d.(v_B - v_A) + (p_B x d).w_B
        - (p_A x d).w_A
    lin_a, lin_b: (k, 3, 3) d_j / m; rot_a, rot_b: (k, 3, 3) I^-1 (p x d_j): the velocity
        changes per unit impulse along d_j
    inv_k: (k, 3) 1/K along each d_j (the slide's denominator; 0 where K = 0)
    """

    a: np.ndarray
    b: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    arm_a: np.ndarray
    arm_b: np.ndarray
    restitution: np.ndarray
    friction: np.ndarray
    dirs: np.ndarray
    jac_a: np.ndarray
    jac_b: np.ndarray
    lin_a: np.ndarray
    lin_b: np.ndarray
    rot_a: np.ndarray
    rot_b: np.ndarray
    inv_k: np.ndarray

    def __len__(self) -> int:
        return len(self.a)

    def take(self, idx) -> "ContactSet":
        return ContactSet(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))


def tangents(normal: np.ndarray):
    """Two unit tangents (k, 3) completing each normal to a right-handed basis. A normal
    in the xy plane (all of 2D) gets t1 in the plane and t2 = +-z."""
    if len(normal) and not normal[:, 2].any():
        t1 = np.stack([-normal[:, 1], normal[:, 0], np.zeros(len(normal))], axis=1)
        return t1, cross(normal, t1)
    helper = np.where((np.abs(normal[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    t1 = cross(normal, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, cross(normal, t1)


def prepare(bodies: Bodies, a, b, point, normal, depth, restitution, friction,
            inv_mass_a=None, inv_mass_b=None, inv_inertia_a=None, inv_inertia_b=None) \
        -> ContactSet:
    """Contacts with their lever arms and effective masses. The arm of each body ends at
    its own witness point (P^K -+ depth/2 n, the point of its surface detection found), not
    at the midpoint P^K: the two coincide at an impact (depth 0), and in a resting
    contact the arm of a sphere is then exactly its radius, so rolling is v = omega r.
    The inverse masses and inertias default to the bodies' (shock propagation passes
    zeros for the frozen lower body)."""
    half = 0.5 * depth[:, None] * normal
    arm_a, arm_b = point + half - bodies.pos[a], point - half - bodies.pos[b]
    t1, t2 = tangents(normal)
    im_a = bodies.inv_mass[a] if inv_mass_a is None else inv_mass_a
    im_b = bodies.inv_mass[b] if inv_mass_b is None else inv_mass_b
    ii_a = bodies.inv_inertia[a] if inv_inertia_a is None else inv_inertia_a
    ii_b = bodies.inv_inertia[b] if inv_inertia_b is None else inv_inertia_b
    dirs = np.stack([normal, t1, t2], axis=1)
    k = len(a)
    arm3_a, arm3_b = np.repeat(arm_a, 3, axis=0), np.repeat(arm_b, 3, axis=0)
    flat = dirs.reshape(-1, 3)
    jac_a = cross(arm3_a, flat).reshape(k, 3, 3)
    jac_b = cross(arm3_b, flat).reshape(k, 3, 3)
    rot_a = np.einsum("kij,kdj->kdi", ii_a, jac_a)
    rot_b = np.einsum("kij,kdj->kdi", ii_b, jac_b)
    kk = np.stack([inverse_mass_along(im_a, im_b, ii_a, ii_b, arm_a, arm_b, dirs[:, j])
                   for j in range(3)], axis=1)
    inv_k = np.where(kk > 0, 1.0 / np.where(kk > 0, kk, 1.0), 0.0)
    return ContactSet(a, b, normal, depth, arm_a, arm_b, restitution, friction, dirs, jac_a,
                      jac_b, im_a[:, None, None] * dirs, im_b[:, None, None] * dirs, rot_a,
                      rot_b, inv_k)


def velocity_along(bodies: Bodies, c: ContactSet, j=slice(None)):
    """Relative velocity v_rel = v_B - v_A at the contact points (slide 5.4.2) along the
    directions j: (k, 3) for all three, (k,) for one."""
    dv = bodies.vel[c.b] - bodies.vel[c.a]
    if isinstance(j, int):
        return (c.dirs[:, j] * dv).sum(1) + (c.jac_b[:, j] * bodies.angvel[c.b]).sum(1) - \
            (c.jac_a[:, j] * bodies.angvel[c.a]).sum(1)
    return np.einsum("kjd,kd->kj", c.dirs[:, j], dv) + \
        np.einsum("kjd,kd->kj", c.jac_b[:, j], bodies.angvel[c.b]) - \
        np.einsum("kjd,kd->kj", c.jac_a[:, j], bodies.angvel[c.a])


def apply_along(bodies: Bodies, c: ContactSet, lam, j=slice(None)) -> None:
    """Impulses sum_j lam_j d_j (lam: (k, len(j)) N s) on B and minus on A. Rows must not
    share a movable body (a colour, or k = 1); fixed bodies may repeat (their rows of
    lin and rot are 0, so they receive nothing)."""
    bodies.vel[c.b] += np.einsum("kj,kjd->kd", lam, c.lin_b[:, j])
    bodies.angvel[c.b] += np.einsum("kj,kjd->kd", lam, c.rot_b[:, j])
    bodies.vel[c.a] -= np.einsum("kj,kjd->kd", lam, c.lin_a[:, j])
    bodies.angvel[c.a] -= np.einsum("kj,kjd->kd", lam, c.rot_a[:, j])


def apply_vector(bodies: Bodies, c: ContactSet, impulse) -> None:
    """Impulse vectors (k, 3) N s, world, on B (minus on A)."""
    apply_along(bodies, c, np.einsum("kjd,kd->kj", c.dirs, impulse))


def _friction(bodies: Bodies, c: ContactSet, lam_t, limit):
    """Coulomb friction: the tangential impulse that stops the sliding at the contact,
    added to the accumulated lam_t (k, 2) and clamped to the cone |lam_t| <= limit (k,).
    Returns the new lam_t; the change is applied."""
    vt = velocity_along(bodies, c, slice(1, 3))
    new = lam_t - vt * c.inv_k[:, 1:]
    norm = np.linalg.norm(new, axis=1)
    new = new * np.where(norm > limit, limit / np.where(norm > 0, norm, 1.0), 1.0)[:, None]
    apply_along(bodies, c, new - lam_t, slice(1, 3))
    return new


def resolve_impacts(bodies: Bodies, c: ContactSet, rest_speed: float) -> np.ndarray:
    """Apply the impulses of one instant of impact; returns the total impulse on B per
    contact (k, 3) N s. A contact approaching slower than rest_speed gets eps = 0.

    In rounds: every contact that approaches now takes part in one solve (`_impact_round`:
    the normal impulses of all its points together, Newton's restitution on each point's
    own approach speed, then Coulomb friction together), so an impact at several points
    at once (a box landing flat on its face, a bar on its edge) is symmetric. Contacts that
    only touch do not take part: when the impulses make them approach, the next round
    solves them, so a chain passes the impulse on ball by ball (Newton's cradle)."""
    k = len(c)
    lam = np.zeros((k, 3))
    count = np.zeros(k, np.int64)
    responds = c.inv_k[:, 0] > 0
    for _ in range(MAX_ELASTIC_PASSES * k + 4 * k + 16 if k else 0):
        vn = np.where(responds, velocity_along(bodies, c, 0), 0.0)
        rows = np.flatnonzero(vn < -APPROACH_EPS)
        if not len(rows):
            break
        eps = np.where((-vn[rows] < rest_speed) | (count[rows] >= MAX_ELASTIC_PASSES), 0.0,
                       c.restitution[rows])
        if len(rows) > PLASTIC_ROWS and not eps.any():
            _plastic_sweeps(bodies, c, lam)
            break
        lam[rows] += _impact_round(bodies, c.take(rows), -eps * vn[rows],
                                   stick=not count[rows].any())
        count[rows] += 1
    return np.einsum("kj,kjd->kd", lam, c.dirs)


PLASTIC_ROWS = 24  # a plastic round with more approaching rows is swept at once
PLASTIC_SWEEPS = 2000  # at most, of `_plastic_sweeps`
PLASTIC_TOL = 1e-13  # relative to the largest impulse: sweeps stop below this change


def _plastic_sweeps(bodies: Bodies, c: ContactSet, lam) -> None:
    """A round of an impact with more than PLASTIC_ROWS approaching rows, all plastic
    (restitution 0 or spent), and the rest of that impact, solved over every contact
    at once by projected Gauss-Seidel from the impulses so far (`kernels.plastic`).
    Why: the rounds pass the impulse back and forth in a pile of touching boxes (median
    124 rounds, at most 681, per event of a 32-box grid), and each round's exact solves
    (pseudo-inverses of contact matrices up to 300 x 300) cost 0.01-0.5 s: the grid's
    first 0.4 s took 89 s, now 9 s. Smaller impacts keep the exact rounds (a box landing
    on a face or an edge: 4 rows). A switch after a number of rounds instead was tried:
    a box bullet's 2-row ping-pong against a wall reached it, the sweeps left one corner
    leaving at round-off speed and the other touching, the event search found the same
    impact at tau = 0 until its 64 events per step ran out, and another bullet in the
    scene passed through its wall (tests/test_located_tunnelling.py). The totals lam
    (k, 3) along (n, t1, t2) stay >= 0 and inside the cones; where the sweeps stop short
    (nearly dependent rows), a contact may still approach by about their last change,
    which the resting solve and position correction take. Updates lam and bodies."""
    from vrsim_cli.kernels.plastic import plastic_sweeps  # numba: piles only

    tol = PLASTIC_TOL * (1.0 + float(np.abs(lam).max()))
    plastic_sweeps(c.a, c.b, c.dirs, c.jac_a, c.jac_b, c.lin_a, c.lin_b, c.rot_a, c.rot_b,
                   c.friction, bodies.vel, bodies.angvel, lam, PLASTIC_SWEEPS, tol)


def _delassus(c: ContactSet, dirs) -> np.ndarray:
    """(m, m) velocity change along the rows (contact i, direction dirs[p]) per unit
    impulse along the rows: W = J M^-1 J^T, summed over the bodies two rows share (fixed
    bodies have zero lin and rot rows, so sharing one adds nothing)."""
    k, d = len(c), len(dirs)
    body = {"b": np.repeat(c.b, d), "a": np.repeat(c.a, d)}
    sign = {"b": 1.0, "a": -1.0}
    row_dir = c.dirs[:, dirs].reshape(k * d, 3)
    jac = {"b": c.jac_b[:, dirs].reshape(k * d, 3), "a": c.jac_a[:, dirs].reshape(k * d, 3)}
    lin = {"b": c.lin_b[:, dirs].reshape(k * d, 3), "a": c.lin_a[:, dirs].reshape(k * d, 3)}
    rot = {"b": c.rot_b[:, dirs].reshape(k * d, 3), "a": c.rot_a[:, dirs].reshape(k * d, 3)}
    W = np.zeros((k * d, k * d))
    for s_ in "ba":  # the body of row i whose velocity the relative velocity reads
        for t in "ba":  # the body of row j that the impulse moves
            same = body[s_][:, None] == body[t][None, :]
            effect = np.einsum("id,jd->ij", row_dir, lin[t]) + \
                np.einsum("id,jd->ij", jac[s_], rot[t])
            W += np.where(same, sign[s_] * sign[t] * effect, 0.0)
    return 0.5 * (W + W.T)


def _apply_all(bodies: Bodies, c: ContactSet, lam, dirs) -> None:
    """Impulses sum_p lam[:, p] d_p at every row at once (rows may share bodies)."""
    np.add.at(bodies.vel, c.b, np.einsum("kj,kjd->kd", lam, c.lin_b[:, dirs]))
    np.add.at(bodies.angvel, c.b, np.einsum("kj,kjd->kd", lam, c.rot_b[:, dirs]))
    np.add.at(bodies.vel, c.a, -np.einsum("kj,kjd->kd", lam, c.lin_a[:, dirs]))
    np.add.at(bodies.angvel, c.a, -np.einsum("kj,kjd->kd", lam, c.rot_a[:, dirs]))


TIE = 1e-9  # relative: rows whose violations agree this closely are equally violated


def _worst(candidates, value) -> np.ndarray:
    """(m,) bool: the candidate rows with the least `value` (the most violated), together
    with every candidate within TIE of it (relative, and round-off of the values' scale).
    Active sets change all of them at once: taking the first of equal rows (argmin) made
    the solution depend on the order of the contacts, and where it is not unique (two
    normals at one point, friction) a contact and its mirror image got different ones."""
    least = float(np.min(np.where(candidates, value, np.inf)))
    scale = float(np.abs(np.where(candidates, value, 0.0)).max())
    return candidates & (value <= least + TIE * abs(least) + 1e-15 * scale)


def _lcp(W, v, target) -> np.ndarray:
    """lam >= 0 with w = v + W lam >= target and lam (w - target) = 0, by active sets:
    solve the active rows exactly (minimum-norm, so equal points get equal impulses),
    drop rows that would pull, add rows that would still approach; small m, few rounds."""
    m = len(v)
    active = np.ones(m, bool)
    lam = np.zeros(m)
    tol = 1e-12 * (1.0 + np.abs(target))
    for _ in range(4 * m + 4):
        lam = np.zeros(m)
        if active.any():
            sub = np.ix_(active, active)
            lam[active] = matmul(_pinv(W[sub][None])[0], (target - v)[active])
        pulls = active & (lam < 0.0)
        if pulls.any():
            active[_worst(pulls, lam)] = False
            continue
        w = v + matmul(W, lam)
        short = w < target - tol
        if not short.any():
            return lam
        if (short & active).any():
            break  # dependent active rows with inconsistent targets: least squares only
        active[short] = True  # all at once (see `_patch`)
    # the active sets cycled or their rows are dependent with targets that no impulse
    # on them meets (more contacts than the bodies' freedoms, speculative gaps);
    # the problem always has a solution (the projection of the velocity onto the cone
    # the contacts allow, in the kinetic-energy metric), which projected Gauss-Seidel
    # approaches from the last admissible impulses
    lam = np.maximum(lam, 0.0)
    w = v + matmul(W, lam)
    for _ in range(SWEEPS):
        change = 0.0
        for i in range(m):
            if W[i, i] <= 0.0:
                continue
            new = max(lam[i] + (target[i] - w[i]) / W[i, i], 0.0)
            d = new - lam[i]
            if d != 0.0:
                w += W[:, i] * d
                lam[i] = new
                change = max(change, abs(d))
        if change <= 1e-13 * (1.0 + float(lam.max())):
            break
    return lam


def _impact_round(bodies: Bodies, c: ContactSet, target, stick=True) -> np.ndarray:
    """One round of an impact: normal impulses (k,) of all rows together so that each
    row's normal velocity becomes >= target (its restitution target) with complementarity,
    then friction: the tangential impulses that stop the slip of all rows together,
    each row scaled into its cone |lam_t| <= mu lam_n, and shortened as a whole where
    that would add energy. Applies them; returns lam (k, 3).

    Neither part can add kinetic energy. An impulse lam on rows with Delassus matrix W
    and velocity v before changes it by lam.v + lam.W lam / 2 = lam.(v + w) / 2 (w the
    velocity after): for the normal rows lam_i > 0 only where w_i = -eps_i v_i, so the
    change is sum lam_i (1 - eps_i) v_i / 2 <= 0 (v_i < 0: approaching; the minimum-norm
    solve keeps this on singular W); friction is checked and, when positive, shortened
    (above) to -(lam.v_t)^2 / (2 lam.W lam) < 0.

    Friction acts at the points levelled (`_levelled`): points of one pair and normal
    moved along the normal onto their mean plane.

    First, in an impact's first round (`stick`: every point new to the impact) and where
    friction can act, the round is tried as one coupled solve in which the rubbing
    points stick (`_sticking_round`); the normal-then-friction passes below are for the
    rounds where that solution does not exist (a point would slide or pull) and for the
    later rounds of a chain or a pile (there it was tried 25 000 times in a 24-box pile
    and failed 99 % of the time, and the run took 1.5 times as long)."""
    k = len(c)
    lam = np.zeros((k, 3))
    vn = velocity_along(bodies, c, 0)
    lam[:, 0] = _lcp(_delassus(c, [0]), vn, target)
    if stick and (c.friction * lam[:, 0] > 0.0).any():
        stuck = _sticking_round(bodies, c, vn, target, lam[:, 0])
        if stuck is not None:
            return stuck
    _apply_all(bodies, c, lam[:, :1], [0])
    limit = c.friction * lam[:, 0]
    rubbing = limit > 0.0
    if rubbing.any():
        f = _levelled(bodies, c.take(np.flatnonzero(rubbing)))
        vt = velocity_along(bodies, f, slice(1, 3)).ravel()
        if np.abs(vt).max() > 0.0:
            W = _delassus(f, [1, 2])
            lt = matmul(_pinv(W[None])[0], -vt).reshape(-1, 2)
            size = np.sqrt(np.einsum("kj,kj->k", lt, lt))
            cap = limit[rubbing]
            lt *= np.where(size > cap, cap / np.where(size > 0.0, size, 1.0), 1.0)[:, None]
            # Rows clamped into their cones by different factors can add energy (the
            # change is lt.vt + lt.W lt / 2; measured up to +320 % on random contact
            # sets): then shorten lt along itself to the point of that line which
            # dissipates most, alpha = -lt.vt / lt.W lt in [0, 1), where the change is
            # -(lt.vt)^2 / (2 lt.W lt) < 0 (no friction if lt.vt >= 0).
            flat = lt.ravel()
            work, curv = dot(flat, vt), dot(flat, matmul(W, flat))
            if work + 0.5 * curv > 0.0:
                lt *= min(max(-work / curv, 0.0), 1.0) if curv > 0.0 else 0.0
            _apply_all(bodies, f, lt, [1, 2])
            lam[rubbing, 1:] = lt
    return lam


CONE_ROUNDS = 5000  # alternating projections of `_inside_cones`, at most,
CONE_WINDOW = 100  # and they stop when a window of this many rounds has not shrunk the
CONE_PROGRESS = 0.9  # step to this share of the last window's (no share inside: the
# steps tend to the cones' distance from the solutions, not to 0)
CONE_ROUNDOFF = 1e-9  # relative: friction this little outside its cone is inside
SLIP_ROUNDS = 32  # stick/slip status and slip-direction updates of `_sticking_round`
SLIP_TURN = 1e-10  # rad: a sliding point's slip direction is settled when it turns less


def _sticking_round(bodies: Bodies, c: ContactSet, vn, target, lam_n):
    """The impulses (k, 3) of one impact round solved as one coupled problem: Newton's law
    on the normal rows of the points with a normal impulse (`lam_n`, the frictionless
    solve's) and Coulomb friction at those with friction, each point sticking or
    sliding. First every such point sticks: W lam = goal - v on those rows (normal: the
    restitution target; along the surface: 0), minimum-norm. Where that friction leaves
    a point's cone, the point slides instead (`_slipping_solve`): its friction is mu
    lam_n against its slip after the impact, with the slip direction and which points
    stick found by updating both until they agree (a point whose slip would reverse
    sticks again). Applied and returned when it is a solution (normal impulses >= 0,
    friction in or on its cone, the other points not driven below their targets, no
    energy gained); where Newton's law with every point sticking would add kinetic
    energy, the restitution is scaled down until it adds none. None when no solution is
    found (bodies unchanged): the caller's normal-then-friction passes take the round.

    Why: friction solved after the normal impulses changes the normal velocities through
    the coupling of the two at a point whose arm is not along the normal (an edge or a
    corner of a turning box): a box landing on an edge with eps = 0 and sticking friction
    left the ground at 1.1 m/s, and with eps = 0.5 landing from a pivot it lost its whole
    bounce in the following rounds (each restitution is of the approach then left); one
    landing on an edge with too little friction to stick left at 1.48 instead of 1.80 m/s
    with eps = 1. Newton's law with the point sticking, or sliding at the friction limit,
    is the planar rigid impact (for eps = 0 and sticking Housner's rocking block: the
    angular momentum about the landing edge is kept); `tests/test_simultaneous_impacts.py`
    checks them against it."""
    k = len(c)
    rubbing = (c.friction * lam_n > 0.0)
    active = np.zeros((k, 3), bool)
    active[:, 0] = lam_n > 0.0
    active[:, 1:] = rubbing[:, None]
    f = _levelled(bodies, c)  # (moves points along n only: the normal rows are c's)
    W = _delassus(f, [0, 1, 2])  # rows contact-major: 3 i + j
    v = velocity_along(bodies, f).ravel()
    v[0::3] = vn
    goal = np.zeros((k, 3))
    goal[:, 0] = target
    goal = goal.ravel()
    on = active.ravel()
    inverse = _pinv(W[np.ix_(on, on)][None])[0]
    plastic, bounce = np.zeros(3 * k), np.zeros(3 * k)  # x = plastic + s bounce
    plastic[on] = -matmul(inverse, v[on])
    bounce[on] = matmul(inverse, goal[on])
    # Twice the kinetic energy the impulses x add, x.(v + w), is a + b s + c s^2 (w =
    # v + W x): <= 0 at s = 0 (a plastic impact), and with Newton's law and sticking it
    # may be > 0 at s = 1 (Kane's paradox). The restitution is then scaled down to the
    # largest s that adds none (continuous in the contacts: a branch to another method
    # there made the outcome jump between nearly equal impacts).
    Wp, Wb = matmul(W, plastic), matmul(W, bounce)
    a = dot(plastic, 2.0 * v + Wp)
    b = dot(bounce, 2.0 * v + Wp) + dot(plastic, Wb)
    curv = dot(bounce, Wb)
    share = 1.0
    if a + b + curv > 0.0:
        if curv > 0.0:
            share = (-b + np.sqrt(max(b * b - 4.0 * curv * a, 0.0))) / (2.0 * curv)
        elif b > 0.0:
            share = -a / b
        share = min(max(share, 0.0), 1.0)
    x = plastic + share * bounce
    lam = x.reshape(k, 3)
    w = v + matmul(W, x)
    scale = 1e-12 * (1.0 + float(np.abs(v).max()) + float(np.abs(goal).max()))
    size = np.sqrt(lam[:, 1] ** 2 + lam[:, 2] ** 2)
    # the equations met (no least-squares answer to rows that have no solution)
    unmet = np.abs(w[on] - share * goal[on]).max() > 1e3 * scale
    below = (w[0::3][~active[:, 0]] < share * target[~active[:, 0]] - scale).any() or unmet
    pulls = (lam[:, 0] < 0.0).any() or below
    over = size > c.friction * lam[:, 0]
    if not below and (pulls or over.any()):
        # the minimum-norm share of the impulses among the points is one of many when W
        # is singular (a face's corners): look for a share inside the cones
        x = x.copy()
        x[on] = _inside_cones(inverse, W[np.ix_(on, on)], x[on], k, active, c.friction)
        lam = x.reshape(k, 3)
        size = np.sqrt(lam[:, 1] ** 2 + lam[:, 2] ** 2)
        tiny = 1e-12 * np.abs(x).max()
        over = size > c.friction * np.maximum(lam[:, 0], 0.0) * (1.0 + CONE_ROUNDOFF) + tiny
        pulls = (lam[:, 0] < -tiny).any()
    if pulls or over.any():  # sticking is no solution: some point slides, if any can
        if not rubbing.any():
            return None
        free = np.zeros(3 * k)
        free[0::3] = lam_n
        free = (v + matmul(W, free)).reshape(k, 3)[:, 1:]  # the slip after no friction
        # first only the points over their cones slide, then every point that slips
        stuck = lam
        for every in (False, True):
            lam = _slipping_solve(W, v, goal, active[:, 0], rubbing, over, stuck, free,
                                  c.friction, every)
            if lam is not None:
                break
        if lam is None:
            return None
    _apply_all(bodies, f, lam, [0, 1, 2])
    return lam


def _inside_cones(inverse, A, x, k, active, mu):
    """Impulses on the rows `active` (k, 3) that solve the same equations as x (A x = b,
    A = W on those rows, inverse its pseudo-inverse) with no normal pulling and every
    point's friction inside its cone |lam_t| <= mu lam_n, if alternating projections find
    them (von Neumann's method for two convex sets, the solutions and the cones: to
    CONE_ROUNDOFF, at most CONE_ROUNDS, stopped when the steps stop shrinking); else the
    last iterate, which the caller rejects. Why: a box landing flat and sticking, its
    load shifted to the leading edge, got minimum-norm friction that left the trailing
    corners' cones, and was solved as sliding (wrong by up to 0.63 of its speed) where a
    sticking share exists (a review's 22 of 100 such landings). Slow where the cones
    touch the solutions at a small angle: 400 rounds left a box landing on a face with
    its corners up to 2 mm apart sliding, where ~1000 found it sticking as with the
    corners level (a jump of 195 times the continuity bound of
    `tests/test_simultaneous_impacts.py`)."""
    b = matmul(A, x)
    rows = np.flatnonzero(active.ravel())
    point, along = rows // 3, rows % 3
    normal = np.flatnonzero(along == 0)
    rub = normal[mu[point[normal]] > 0.0]  # (its t1, t2 rows follow it)
    m = mu[point[rub]]
    y = x.copy()
    last = np.inf
    for round_ in range(CONE_ROUNDS):
        before = y.copy()
        # onto the cones: |t| <= m n (the second-order cone's projection, scaled by mu)
        n, t1, t2 = y[rub], y[rub + 1], y[rub + 2]
        t = np.sqrt(t1 * t1 + t2 * t2)
        outside = t > m * n
        gone = outside & (m * t <= -n)
        edge = outside & ~gone
        n_new = np.where(edge, (n + m * t) / (1.0 + m * m), np.where(gone, 0.0, n))
        f = np.where(edge, m * n_new / np.where(t > 0.0, t, 1.0), np.where(gone, 0.0, 1.0))
        y[rub], y[rub + 1], y[rub + 2] = n_new, f * t1, f * t2
        y[normal] = np.maximum(y[normal], 0.0)
        # back onto the solutions: y - A+ (A y - b)
        y = y - matmul(inverse, matmul(A, y) - b)
        t = np.sqrt(y[rub + 1] ** 2 + y[rub + 2] ** 2)
        tiny = 1e-12 * np.abs(y).max()  # (a corner left with no load: 0 +- round-off)
        if (t <= m * np.maximum(y[rub], 0.0) * (1.0 + CONE_ROUNDOFF) + tiny).all() and \
                y[normal].min() >= -tiny:
            break
        if (round_ + 1) % CONE_WINDOW == 0:
            step = float(np.abs(y - before).max())
            if step >= CONE_PROGRESS * last:
                break
            last = step
    return y


def _slipping_solve(W, v, goal, normal, rubbing, over, stuck, free, mu, every=True):
    """The impulses (k, 3) of an impact round with some points sliding: Newton's law on
    the `normal` rows, points with friction (`rubbing`) either sticking (slip 0, friction
    inside the cone) or sliding (friction -mu lam_n s along their slip direction s after
    the impact, the slip not reversed), found by starting from the sticking solve
    (`stuck`; the points `over` their cones slide, against the friction sticking
    wanted) and updating statuses and directions until they agree (SLIP_ROUNDS, to
    SLIP_TURN). Each round is one minimum-norm solve of the square system A y = goal -
    v on the normal rows and the sticking points' tangent rows, y the normal impulses and
    the sticking frictions (A = W B, B mapping y to the impulses; not symmetric, so
    through A^T A's pseudo-inverse), kept only when it meets its rows to 1e-10 of the
    velocity scale. A point whose normal impulse would pull leaves the solve (the most
    pulling ones, `_worst`), and must then not be driven below its target. None when no
    consistent solution is found or the impulses would add energy (Newton's law with
    friction can: the caller's passes never do)."""
    k = len(normal)
    normal, rubbing = normal.copy(), rubbing.copy()
    # the slip direction after the impact (t1, t2): first that after a frictionless
    # impact, or where there is none, against the friction sticking wanted (with a face's
    # singular W the sticking friction's share among the corners is arbitrary: starting
    # from it, the statuses of a box landing flat while sliding cycled)
    speed = np.sqrt((free ** 2).sum(axis=1))
    start = np.where((speed > 0.0)[:, None], free, -stuck[:, 1:])
    # `every`: every point that slips without friction starts sliding, else only those
    # `over` their cones (a box whose sticking solve made two corners pull, landing on
    # the verge of sticking, dropped corner after corner from the first start)
    slide = rubbing & (((speed > 0.0) & every) | over)
    s = np.zeros((k, 2))
    s[slide] = start[slide] / np.sqrt((start[slide] ** 2).sum(axis=1))[:, None]
    rhs_all = goal - v
    scale = float(np.abs(v).max()) + float(np.abs(goal).max())
    for _ in range(SLIP_ROUNDS):
        rows, cols = [], []
        for i in range(k):
            if normal[i]:
                col = np.zeros(3 * k)
                col[3 * i] = 1.0
                if slide[i]:
                    col[3 * i + 1:3 * i + 3] = -mu[i] * s[i]
                rows.append(3 * i)
                cols.append(col)
            if rubbing[i] and not slide[i]:
                for j in (1, 2):
                    col = np.zeros(3 * k)
                    col[3 * i + j] = 1.0
                    rows.append(3 * i + j)
                    cols.append(col)
        B = np.array(cols).T  # (3k, nu)
        A = matmul(W[rows], B)
        rhs = rhs_all[rows]
        y = matmul(_pinv(matmul(A.T, A)[None])[0], matmul(A.T, rhs))
        if np.abs(matmul(A, y) - rhs).max() > 1e-10 * scale:
            return None
        x = matmul(B, y)
        lam = x.reshape(k, 3)
        w = v + matmul(W, x)
        pull = normal & (lam[:, 0] < -1e-12 * np.abs(y).max())
        if pull.any():  # it leaves: no impulse there (complementarity)
            drop = _worst(pull, lam[:, 0])
            normal[drop] = rubbing[drop] = slide[drop] = False
            if not normal.any():
                return None
            continue
        if (w[0::3][~normal] < goal[0::3][~normal] - 1e-12 * scale).any():
            return None
        slip = w.reshape(k, 3)[:, 1:]
        speed = np.sqrt((slip ** 2).sum(axis=1))
        size = np.sqrt((lam[:, 1:] ** 2).sum(axis=1))
        limit = mu * lam[:, 0]
        over = rubbing & ~slide & (size > limit)
        back = slide & ((slip * s).sum(axis=1) <= 1e-12 * scale)  # slip reversed: sticks
        turned = np.zeros(k, bool)
        new_s = s.copy()
        moving = slide & ~back
        new_s[moving] = slip[moving] / speed[moving, None]
        turned[moving] = np.abs(new_s[moving] - s[moving]).max(axis=1) > SLIP_TURN
        if not (over.any() or back.any() or turned.any()):
            work = dot(x, v + w)  # twice the kinetic energy the impulses add
            if work > 1e-12 * dot(np.abs(x), np.abs(v) + np.abs(w)):
                return None
            return lam
        s[over] = -lam[over, 1:] / size[over, None]
        s[moving] = new_s[moving]
        slide = (slide & ~back) | over
    return None


def _levelled(bodies: Bodies, c: ContactSet) -> ContactSet:
    """c with the points of each pair and normal moved along that normal onto their mean
    plane, for the tangential solve of an impact. The points of one impact lie up to two
    tolerances apart along the normal (an event is located when a landing point is the
    tolerance below a resting one). Tangential impulses equal and opposite at two points
    d apart along the normal only turn the body, by d^2 / I per unit impulse: the solve
    for the slip of every point then asked for impulses of 80 N s against each other at
    the corners of a 0.4 m cube that had landed flat with 0.3 N s, which the cones and the
    energy safeguard cut to nothing (it slid on at 0.6 m/s with mu = 1). Level points
    make those directions exactly singular, which the pseudo-inverse drops for any
    size of d (a cutoff tied to d's size instead made mirror-image contact sets, whose
    eigenvalues differ by round-off, get different friction). The points move by at
    most the depth difference, so the friction's arms by that."""
    k = len(c)
    if k < 2:
        return c
    witness = bodies.pos[c.b] + c.arm_b  # B's surface point (see `prepare`)
    height = np.einsum("kd,kd->k", witness, c.normal)
    shift = np.zeros(k)
    done = np.zeros(k, bool)
    for i in range(k):
        if done[i]:
            continue
        group = ~done & (c.a == c.a[i]) & (c.b == c.b[i]) & \
            (np.abs(c.normal - c.normal[i]).max(axis=1) <= 1e-12)
        # (summed in sorted order: mirror-image sets list their points in other orders)
        shift[group] = np.sort(height[group]).sum() / group.sum() - height[group]
        done |= group
    if not shift.any():
        return c
    point = witness + shift[:, None] * c.normal + 0.5 * c.depth[:, None] * c.normal
    return prepare(bodies, c.a, c.b, point, c.normal, c.depth, c.restitution, c.friction)


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


def solve_resting(bodies: Bodies, c: ContactSet, dt: float, iterations: int, start=None,
                  kink=None):
    """Sequential impulses on the contacts c (restitution 0), then a shock-propagation pass
    on the normal velocities. Returns the accumulated impulse (k, 3) N s, world, on B of
    each contact. `start`: (vel,
    angvel) (n, 3) of the bodies at the step's start and `kink` (n, 4): where a point
    that slipped then sticks at the step's end, kink[body] is set to (fraction of the
    step at which its slip stopped, linear velocity (3,) m/s then) (`_patch`).

    Per contact the accumulated normal impulse lam_n stays >= 0 and the friction impulse
    in the Coulomb cone |lam_t| <= mu lam_n (the accumulated, not the incremental,
    impulse is clamped; Catto 2006). A contact with a gap (depth < 0) may still close at
    speed -depth/dt (a speculative contact)."""
    k = len(c)
    if not k:
        return np.zeros((0, 3))
    movable = bodies.movable
    target = np.maximum(-c.depth, 0.0) / dt  # m/s allowed approach of a gap
    if k <= EXACT_CONTACTS:
        lam = _exact_resting(bodies, c, target)
    else:
        lam = _iterate_resting(bodies, c, target, iterations, movable)
    loaded = lam[:, 0] > 0.0
    # Sticking: the friction impulse that would stop the sliding now fits in the cone of
    # the final normal impulse (the last clamp used an earlier, smaller lam_n).
    needed = lam[:, 1:] - velocity_along(bodies, c, slice(1, 3)) * c.inv_k[:, 1:]
    stick = loaded & (np.linalg.norm(needed, axis=1) <= c.friction * lam[:, 0])
    _shock_velocities(bodies, _shock_plan(bodies, c, movable), target, loaded, stick, lam,
                      start, kink, swept=k > EXACT_CONTACTS)
    return np.einsum("kj,kjd->kd", lam, c.dirs)


EXACT_CONTACTS = 16  # resting contact sets up to this size are solved exactly, at once


def _exact_resting(bodies: Bodies, c: ContactSet, target) -> np.ndarray:
    """The resting impulses (k, 3) along (n, t1, t2) of every contact at once: normal
    complementarity (v_n >= -target) and Coulomb friction per point, by `_patch`'s
    active sets with the minimum-norm solution over the Delassus matrix of all the
    contacts (bodies may repeat). Unlike sequential impulses, the result does not depend
    on the order of the contacts: two contacts of a pair that are each other's mirror
    image get mirror impulses (the sweeps gave the first one more). Applied to bodies."""
    lam, _ = _patch(_delassus(c, [0, 1, 2]), velocity_along(bodies, c), target, c.friction,
                    faces=_faces(c))
    _apply_all(bodies, c, lam, [0, 1, 2])
    return lam


def _iterate_resting(bodies: Bodies, c: ContactSet, target, iterations, movable):
    """Sequential impulses over colours (see `solve_resting`), from zero; returns lam
    (k, 3). Not warm-started from last step's impulses: where contacts are statically
    indeterminate (boxes side by side, a wall), a warm start carries last step's
    self-balanced share (boxes pushing each other apart, held by friction below) into
    the next, the sweeps add to it, and it grew step by step until friction gave way: a
    2 x 2 block of cubes at rest kicked one to 0.17 m/s after 0.77 s, a 4 x 5 wall moved
    at up to 1.8 m/s. Shock propagation and the exact patch solves, not the warm start,
    are what keep stacks from sinking."""
    k = len(c)
    lam = np.zeros((k, 3))
    groups = colours(c.a, c.b, movable)
    subs = [c.take(g) for g in groups]
    rubs = [bool((sub.friction > 0).any()) for sub in subs]
    for _ in range(iterations):
        for g, sub, rub in zip(groups, subs, rubs):
            if rub:  # friction first, as Box2D: the normal constraint has the last word
                lam[g, 1:] = _friction(bodies, sub, lam[g, 1:], sub.friction * lam[g, 0])
            vn = velocity_along(bodies, sub, 0)
            new = np.maximum(lam[g, 0] - (vn + target[g]) * sub.inv_k[:, 0], 0.0)
            apply_along(bodies, sub, (new - lam[g, 0])[:, None], slice(0, 1))
            lam[g, 0] = new
    return lam


def _shock_plan(bodies: Bodies, c: ContactSet, movable):
    """Shock propagation order: contacts grouped by the lower level of their two bodies,
    ground up. In each level the contacts whose other body is lower (frozen) are solved
    as one block per upper body (`_block`); contacts between bodies of equal level (a
    cluster touching nothing fixed) are coloured and solved one colour at a time."""
    level = levels(len(movable), c.a, c.b, movable)
    la, lb = level[c.a], level[c.b]
    low = np.minimum(la, lb)
    plan = []
    for lv in np.unique(low):
        idx = np.flatnonzero(low == lv)
        block = la[idx] != lb[idx]
        if block.any():
            rows = idx[block]
            plan.append(("block", _block(bodies, c, rows, lb[rows] > la[rows])))
        same = idx[~block]
        free = bool(lv > len(movable))  # a cluster touching nothing fixed
        if 0 < len(same) <= EXACT_CONTACTS:  # all at once, in no order (`_cluster`)
            plan.append(("cluster", (same, c.take(same), free)))
            continue
        for g in colours(c.a[same], c.b[same], movable):
            rows = same[g]
            plan.append(("pairs", (rows, c.take(rows), free)))
    return plan


MOVE_CAP = 10.0  # a block's pass may move a body's points this many times its deepest
MOVE_REACH = 0.5  # excess, or this share of its reach (largest arm), whichever is more


def _move_cap(blk, sub: ContactSet, excess, dv, dw) -> np.ndarray:
    """(nb,) factors <= 1 for the position changes (dv, dw) of a block's upper bodies: 1
    unless a body's largest point movement (bound: |dv| + |dw| times its largest arm)
    exceeds both MOVE_CAP times the deepest excess of its contacts and MOVE_REACH times
    that arm, then what brings it down to the larger of the two. Why: a body wedged
    between two bodies whose normals are nearly opposite, both penetrating, has contact
    rows with no solution: the least-squares pass of old moved a box of a 27-box pile by
    50 m and turned one by 1926 rad in one pass (energy +1e4 J, the run stopped by its
    guard), and the complementarity pass (`_block_positions`) ends in projected sweeps
    that grow without bound there (20 of the 40 wedges of the test still reach the cap). A body in a
    steep groove needs a large multiple of its excess (1 / sin of the walls' angle from
    vertical: 19 times at 3 degrees), a small share of its size: a cap at the excess alone
    left a sphere 1.3 mm deep in a 3-degree groove (review of the first cap)."""
    _, _, bodies_u, slot_body = blk[:4]
    upper = bodies_u[slot_body]
    arm = np.where((sub.b == upper)[:, None], sub.arm_b, sub.arm_a)
    nb = len(bodies_u)
    deepest, reach = np.zeros(nb), np.zeros(nb)
    np.maximum.at(deepest, slot_body, excess)
    np.maximum.at(reach, slot_body, np.sqrt((arm ** 2).sum(axis=1)))
    move = np.sqrt((dv ** 2).sum(axis=1)) + np.sqrt((dw ** 2).sum(axis=1)) * reach
    cap = np.maximum(MOVE_CAP * deepest, MOVE_REACH * reach)
    wild = move > cap
    return np.where(wild, cap / np.where(wild, move, 1.0), 1.0)


def _cluster(sub: ContactSet, v, target) -> np.ndarray:
    """Normal impulses (k,) >= 0 of contacts between bodies of one level (they may share
    bodies) that make every normal velocity (or displacement) v + W lam >= target, solved
    together (`_lcp`, minimum norm): no contact goes first, so a symmetric cluster stays
    symmetric."""
    return _lcp(_delassus(sub, [0]), v, target)


def _block(bodies: Bodies, c: ContactSet, rows, upper_is_b):
    """The contacts `rows` of one level, each with one frozen (lower) body, grouped per
    upper body u: (rows, their ContactSet, bodies_u, slot_body, slot, WJt, A) with the
    rows J = s (d_j, p x d_j) along d_j = n, t1, t2 (s = +1 when u is B), W = diag(1/m,
    I^-1) u's kinetic-energy metric, WJt = W J^T (u's velocity change per unit impulse
    along each row) and A = J W J^T (the Delassus matrix of u's rows). Three rows per
    contact, padded to the largest count per body (slot: a contact's place among its
    body's). `_patch_blocks` and `_block_positions` solve on them."""
    upper = np.where(upper_is_b, c.b[rows], c.a[rows])
    sign = np.where(upper_is_b, 1.0, -1.0)[:, None, None]
    jac = np.where(upper_is_b[:, None, None], c.jac_b[rows], c.jac_a[rows])
    bodies_u, slot_body = np.unique(upper, return_inverse=True)
    count = np.bincount(slot_body)
    order = np.argsort(slot_body, kind="stable")
    slot = np.empty(len(rows), np.int64)
    slot[order] = np.arange(len(rows)) - np.repeat(np.cumsum(count) - count, count)
    nb, kmax = len(bodies_u), int(count.max())
    J = np.zeros((nb, kmax, 3, 6))
    J[slot_body, slot, :, :3] = sign * c.dirs[rows]
    J[slot_body, slot, :, 3:] = sign * jac
    J = J.reshape(nb, 3 * kmax, 6)
    W = np.zeros((nb, 6, 6))
    W[:, :3, :3] = bodies.inv_mass[bodies_u, None, None] * np.eye(3)
    W[:, 3:, 3:] = bodies.inv_inertia[bodies_u]
    WJt = matmul(W, np.swapaxes(J, 1, 2))
    return rows, c.take(rows), bodies_u, slot_body, slot, WJt, matmul(J, WJt)


def _pinv(A):
    """Pseudo-inverses of the symmetric blocks A (nb, m, m), singular values below 1e-10 of
    the largest dropped: compiled Jacobi rotations (`kernels.pinv`), not LAPACK, whose
    last bits depend on the CPU."""
    from vrsim_cli.kernels.pinv import pinv_symmetric  # numba: scenes with stacks only

    out = np.empty_like(A)
    pinv_symmetric(np.ascontiguousarray(A, dtype=float), 1e-10, out)
    return out


def _block_positions(blk, moved, target):
    """Position changes (dv, dw) (nb, 3) of a block's upper bodies that remove the
    excess penetration of their contacts with frozen lower bodies: per upper body the
    normal displacements lam >= 0 with moved + W lam >= target and complementarity
    (`_lcp` over the body's normal rows, W = J M^-1 J^T, minimum norm), the same problem
    `_cluster` solves between bodies of one level. moved: (k,) m each contact's normal
    displacement so far; target: (k,) m depth - slop.

    Not a least-squares solve of the rows with excess: a cube overlapping a second lower
    cube by 1 mm has contacts on both top faces whose normals differ by 8 mrad; with
    unequal excesses their least-squares solution (singular values down to 1e-10 of the
    largest kept) turned the cube by 0.8 rad per pass, the next pass chased the corner
    that pushed in, and one pass lifted the cube 11 cm (a 32-box grid boiled at 1-2
    m/s, `tests/test_position_correction.py`). Impulses that may not pull keep the move
    near the excess."""
    _, _, bodies_u, slot_body, slot, WJt, A = blk
    nb = len(bodies_u)
    dv, dw = np.zeros((nb, 3)), np.zeros((nb, 3))
    for i in range(nb):
        mem = np.flatnonzero(slot_body == i)
        if not (target[mem] - moved[mem] > 0.0).any():
            continue
        idx = 3 * slot[mem]
        lam = _lcp(A[i][np.ix_(idx, idx)], moved[mem], target[mem])
        delta = matmul(WJt[i][:, idx], lam)
        dv[i], dw[i] = delta[:3], delta[3:]
    return bodies_u, dv, dw


def _shock_velocities(bodies: Bodies, plan, target, loaded, stick, lam, start=None,
                      kink=None, swept=False) -> None:
    """One pass from the ground up: afterwards no contact approaches (beyond its
    speculative allowance), whatever the mass ratios. A body whose contacts of its level
    all have a frozen (lower) other body gets its impulses there from one exact solve
    (`_patch`: normal and Coulomb friction of all its points together), replacing the
    iterations' (`lam`, updated in place); contacts within a cluster of one level keep
    theirs and get a normal-velocity pass.

    swept: lam is the sweeps' (`_iterate_resting`, more than EXACT_CONTACTS contacts,
    from zero, a few sweeps: not converged). Their impulses between bodies of one level
    (neighbours side by side; not within a cluster touching nothing fixed) are then taken
    back first: what they left (a box of a block at rest spun at 0.13 rad/s by friction
    at a neighbour's corner) stayed in the velocity the block solves start from, which
    answered with the box turning at 1 rad/s about its support, or were refused; blocks
    kicked and a running-bond wall balanced on edges fell. The level's normal pass then
    pushes neighbours apart where they approach. (After `_exact_resting` lam is the exact
    solution of all the contacts together and stays: taking part of it back gave a pair
    of bodies +35 % kinetic energy.)"""
    if swept:
        for kind, data in plan:
            rows, sub = data[0], data[1]
            if kind == "block" or data[2]:
                continue
            _apply_all(bodies, sub, -lam[rows], [0, 1, 2])
            lam[rows] = 0.0
            loaded[rows] = False
    for kind, data in plan:
        rows, sub = data[0], data[1]
        if kind == "block":
            _patch_blocks(bodies, data, target[rows], lam, start, kink)
            continue
        if kind == "cluster":
            extra = _cluster(sub, velocity_along(bodies, sub, 0), -target[rows])
            _apply_all(bodies, sub, extra[:, None], [0])
            lam[rows, 0] += extra
            continue
        want = -velocity_along(bodies, sub)
        want[:, 0] -= target[rows]
        want[:, 0] = np.where(loaded[rows], want[:, 0], np.maximum(want[:, 0], 0.0))
        apply_along(bodies, sub, (want[:, 0] * sub.inv_k[:, 0])[:, None], slice(0, 1))


def _patch_blocks(bodies: Bodies, blk, target, lam, start=None, kink=None) -> None:
    """The contacts of one level block, each with a frozen (lower) other body, solved
    exactly per upper body u (`_patch`) from u's velocity without their impulses: the
    iterations' impulses of these rows (lam, (k, 3) along n, t1, t2) are taken back and
    replaced by the patch solution, unless the patch has none (`_patch`, strict: the
    frozen bodies' motion may ask for the impossible); then the iterations' stand.
    target: (len(rows),) m/s allowed approach. start, kink: see `solve_resting`."""
    rows, sub, bodies_u, slot_body, slot, WJt, A = blk
    v_now = velocity_along(bodies, sub)
    v_start = None
    if start is not None:
        v_start = velocity_along(Bodies(bodies.inv_mass, bodies.inv_inertia, start[0],
                                        start[1], bodies.pos), sub)
    for i, u in enumerate(bodies_u.tolist()):
        mem = np.flatnonzero(slot_body == i)
        idx = (3 * slot[mem][:, None] + np.arange(3)).ravel()
        Ab = A[i][np.ix_(idx, idx)]
        old = lam[rows[mem]]
        pre = v_now[mem] - matmul(Ab, old.ravel()).reshape(-1, 3)
        new, slid = _patch(Ab, pre, target[mem], sub.friction[mem],
                           None if v_start is None else v_start[mem, 1:], strict=True,
                           faces=_faces(sub.take(mem)))
        if new is None:
            continue  # no solution against the frozen bodies: the iterations' stand
        delta = matmul(WJt[i][:, idx], (new - old).ravel())
        if slid is not None and kink is not None:
            frac, lam_slide = slid  # the velocity when the slip stopped: linear in time
            v_slide = bodies.vel[u] + matmul(WJt[i][:, idx], (lam_slide - old).ravel())[:3]
            kink[u, 0] = frac
            kink[u, 1:] = start[0][u] + frac * (v_slide - start[0][u])
        bodies.vel[u] += delta[:3]
        bodies.angvel[u] += delta[3:]
        lam[rows[mem]] = new


def _min_norm(M, r) -> np.ndarray:
    """The minimum-norm least-squares solution of M x = r (M square, maybe singular and
    not symmetric) through the symmetric [[0, M], [M^T, 0]], whose eigenvalues are +-
    the singular values of M and whose pseudo-inverse is [[0, M+^T], [M+, 0]]: the
    compiled Jacobi pseudo-inverse, without squaring M's condition number."""
    m = len(r)
    S = np.zeros((2 * m, 2 * m))
    S[:m, m:] = M
    S[m:, :m] = M.T
    return matmul(_pinv(S[None])[0][m:, :m], r)


def _support(W, q, tol) -> np.ndarray | None:
    """The normal impulses lam (k,) >= 0 that minimise lam.W lam / 2 + q.lam (W: the
    normal rows' Delassus matrix, positive semi-definite; q: each point's normal velocity
    without them plus its allowance, m/s), or None where that has no minimum (frozen
    bodies asking for the impossible). The velocity after, q + W lam >= 0 with
    complementarity, is the problem's unique one; lam is one of its impulses.

    A primal active-set method that copes with dependent rows: the free points' Newton
    step is the minimum-norm one; where their equations are inconsistent (more points
    than the body has freedoms, with allowances no rigid motion meets: a box on two
    boxes with gaps of 1e-9-1e-3 m at some corners) the part of the gradient that no
    impulse on them changes is a descent direction along which the objective falls
    linearly, followed until a point's impulse reaches zero and it leaves. `_patch`'s
    rounds, which start from all the approaching points' equations at once, then leave
    some approaching and others leaving and do not settle: 22 % of the block solves of a
    collapsing running-bond wall ended so, had no answer and kept the iterations'
    impulses, and its boxes went on falling at g dt into their supports. `_patch` starts
    its rounds again from the points this carries. Every step lowers the objective, so
    no set of free points repeats (Nocedal & Wright, "Numerical Optimization", 16.5)."""
    k = len(q)
    lam = np.zeros(k)
    free = np.zeros(k, bool)
    for _ in range(8 * k + 8):
        if free.any():
            F = np.flatnonzero(free)
            WF = W[np.ix_(F, F)]
            g = q[F] + matmul(WF, lam[F])
            step = -matmul(_pinv(WF[None])[0], g)
            ray = g + matmul(WF, step)  # the gradient no impulse on F changes
            if np.abs(ray).max() > tol:
                step = -ray  # W_FF step = 0: the objective falls by |ray|^2 per unit
                if not (step < 0.0).any():
                    return None  # unbounded below: no impulse stops these points
                full = False
            else:
                full = True
            shrink = step < 0.0
            ratio = np.where(shrink, lam[F] / np.where(shrink, -step, 1.0), np.inf)
            alpha = float(ratio.min()) if shrink.any() else np.inf
            if full and alpha >= 1.0:
                lam[F] = lam[F] + step
            else:
                lam[F] = np.maximum(lam[F] + alpha * step, 0.0)
                block = np.zeros(k, bool)
                block[F] = _worst(shrink, ratio) if shrink.any() else False
                lam[block] = 0.0
                free &= ~block
                continue
        w = q + matmul(W, lam)
        join = ~free & (w < -tol)
        if not join.any():
            return lam
        free |= _worst(join, w)
    return None


PATCH_TOL = 1e-12  # m/s per m/s of a patch's scale: velocity equations met to round-off
TORN_TOL = 1e-9  # m/s per m/s: slip at a sticking point that no rigid motion removes (a
# pushed box held by friction leaves 1e-12 of round-off; moving supports leave 1e-3)
PATCH_ROUNDS = 64  # active-set and slip-direction rounds of one body's patch solve
# rad: a sliding point's slip direction is settled when a round turns it less. Not 1e-14:
# where the slip is small against what the friction impulse changes (a box on a slope
# just steeper than its friction angle: mu g cos(th) ~ 12 g (sin(th) - mu cos(th))), each
# round amplified the round-off of the right directions ~12-fold; they drifted by 1e-4
# in ten rounds, cycled through sticking statuses, and the rounds' last solution held the
# box for 0.1 s and spun it (0.11 rad/s) at dt 3-7 ms. 1e-9 rad of friction direction is
# ~1e-10 of the impulse: far below the 1e-6 the incline tests hold the slide to.
SLIDE_TURN = 1e-9


def _rounds(A, pre, target, mu, active, slide, s, tol_v, faces=None):
    """`_patch`'s active-set rounds from the statuses (active, slide: (k,) bool; s: (k, 2)
    slip directions). faces: see `_spread_faces`. Returns (lam, active, slide, s,
    settled)."""
    k = len(pre)
    active, slide, s = active.copy(), slide.copy(), s.copy()
    lam = np.zeros((k, 3))
    seen = set()
    settled = False
    visited = set()
    for _ in range(PATCH_ROUNDS):
        key = (active.tobytes(), slide.tobytes())
        state = key + (s.tobytes(),)
        if state in visited:
            break  # statuses and slip directions repeat exactly: a cycle, not settling
        visited.add(state)
        lam = _patch_statuses(A, pre, target, mu, active, slide, s)
        v = pre + matmul(A, lam.ravel()).reshape(k, 3)
        tol_l = 1e-12 * (1.0 + float(np.abs(lam).max()))
        lt = np.sqrt((lam[:, 1:] ** 2).sum(1))
        over = active & ~slide & (mu > 0.0) & (lt > mu * lam[:, 0] + tol_l)
        if over.any() and faces is not None:
            spread, holds = _spread_faces(A, lam, mu, active & ~slide & (mu > 0.0), faces,
                                          tol_v)
            if spread is not None:  # the same motion with every point inside its cone
                lam = spread
                v = pre + matmul(A, lam.ravel()).reshape(k, 3)
                lt = np.sqrt((lam[:, 1:] ** 2).sum(1))
                over = active & ~slide & (mu > 0.0) & (lt > mu * lam[:, 0] + tol_l)
            elif holds and (active & (lam[:, 0] < -tol_l)).any():
                # faces whose friction is inside their cones, one point pulling: that
                # point leaves first, then the face is spread again (a corner let slide
                # first sent a held box sliding)
                over[:] = False
        if over.any():
            for i in np.flatnonzero(over).tolist():
                vt = pre[i, 1:]
                size = float(np.sqrt((vt * vt).sum()))
                s[i] = vt / size if size > tol_v else -lam[i, 1:] / lt[i]
            slide |= over
            if (active.tobytes(), slide.tobytes()) in seen:
                break
            seen.add(key)
            continue
        pulls = active & (lam[:, 0] < -tol_l)
        if pulls.any():
            active[_worst(pulls, lam[:, 0])] = False
            slide[~active] = False
            continue
        short = ~active & (v[:, 0] < -target - tol_v)
        if short.any():
            # all that still approach join at once (the minimum-norm solve then shares
            # between contacts that overlap, as two normals at one corner do; adding the
            # worst first gave all to one of them, chosen by round-off)
            active[short], slide[short] = True, False
            continue
        slip = np.sqrt((v[:, 1:] ** 2).sum(1))
        torn = active & ~slide & (mu > 0.0) & (slip > (TORN_TOL / PATCH_TOL) * tol_v)
        if torn.any():
            # sticking everywhere has no solution (the supports move apart: a box on two
            # boxes that slide differently); the least-squares answer slips at the points
            # that cannot stick, which then slide the way they slip
            worst = _worst(torn, -slip)
            for i in np.flatnonzero(worst).tolist():
                s[i] = v[i, 1:] / slip[i]
            slide |= worst
            if (active.tobytes(), slide.tobytes()) in seen:
                break
            seen.add(key)
            continue
        moved = False
        for i in np.flatnonzero(active & slide & (mu > 0.0)).tolist():
            vt = v[i, 1:]
            size = float(np.sqrt((vt * vt).sum()))
            if size <= tol_v:
                continue  # at the cone's edge without slip: a valid Coulomb state
            if (vt * s[i]).sum() < -tol_v:  # the friction would reverse it: it sticks
                slide[i] = False
                moved = True
                continue
            new = vt / size
            if np.abs(new - s[i]).max() > SLIDE_TURN:
                s[i] = new
                moved = True
        if not moved:  # settled, unless dependent active rows left a point approaching
            settled = not (v[:, 0] < -target - tol_v).any()
            break
        if not (active.tobytes(), slide.tobytes()) == key:
            if (active.tobytes(), slide.tobytes()) in seen:
                break
        seen.add(key)
    return lam, active, slide, s, settled


def _patch(A, pre, target, mu, slip0=None, strict=False, faces=None):
    """Impulses (k, 3) along (n, t1, t2) at the k contacts of one body with fixed (or
    frozen) bodies, normal and friction solved together: the relative velocity after is
    v = pre + A lam (A: (3k, 3k) Delassus matrix, pre: (k, 3) velocity without them), and

    - normal: lam_n >= 0, v_n >= -target, one of the two tight (complementarity);
    - friction (Coulomb): a sticking point has v_t = 0 and |lam_t| <= mu lam_n; a sliding
      point has lam_t = -mu lam_n s with s the direction of its slip v_t after the solve.

    By active sets: each round solves the equations of the current statuses exactly (the
    normal rows of the active points; the tangent rows of the sticking ones; a sliding
    point's impulse is lam_n (n - mu s): one unknown) with the minimum-norm solution, then
    changes one status (a point that pulls leaves; a point that still approaches joins,
    sticking; a sticking point outside its cone slides, along its slip or its impulse)
    or updates the slip directions to the solution's. A face sliding without turning
    gets all its points sliding along the same s, so the patch's friction is mu N s at the
    centre of pressure, which the normal rows put on the line of s: no torque about the
    normal, and the body slides at exactly g (sin th - mu cos th) (the corner-by-corner
    iterations left 0.2-0.4 % of it and turned the box). Polyhedral cones (MuJoCo's
    pyramidal) and Box2D v3's per-point friction clamped with the previous iteration's
    normal impulse both leave such errors; this is the exact Coulomb law per point.

    slip0: (k, 2) tangential velocity at the step's start, or None. Returns (lam, slid):
    slid is None unless a point that slipped at the step's start sticks at its end; then
    the step is solved again with those points sliding along their start slip s0 all
    step (constant forces: every velocity linear in time), and slid = (fraction of the
    step at which that slip reaches 0, the impulses (k, 3) of that sliding solution).
    The caller moves the body with the two velocity ramps meeting there, not with one
    (the ball thrown sliding rolls from t* = 2 v0 / (7 mu g), inside a step).

    strict: when the statuses do not settle and the projected sweeps do not solve the
    problem either (`_projected_sweeps`), return (None, None) instead of their impulses.
    faces: (dirs, pair) of the points (`_faces`), for `_spread_faces`; None: not tried."""
    k = len(pre)
    scale = 1.0 + float(np.abs(pre).max()) + float(np.abs(target).max())
    tol_v = PATCH_TOL * scale
    active = pre[:, 0] < -target - tol_v
    slide = np.zeros(k, bool)
    s = np.zeros((k, 2))

    def accepted(rounds):  # settled, or a cycle's answer that may stand (`_admissible`)
        lam, active, slide, _, settled = rounds
        if not settled and faces is not None and not _spread_faces(
                A, lam, mu, active & (mu > 0.0), faces, tol_v)[1]:
            return False  # a face with more friction than mu N: no solution (the sliding
            # points counted in: a spinning box's cycle ended with a corner at 5.8 its cone)
        return settled or _admissible(A, pre, target, lam, tol_v,
                                      active & ~slide & (mu > 0.0))

    result = _rounds(A, pre, target, mu, active, slide, s, tol_v, faces)
    if not accepted(result):
        # again from the points that carry the frictionless problem (`_support`): all
        # the approaching points at once may ask for what no rigid motion does
        support = _support(A[0::3, 0::3], pre[:, 0] + target, tol_v)
        again = None if support is None else _rounds(
            A, pre, target, mu, support > 0.0, np.zeros(k, bool), np.zeros((k, 2)), tol_v)
        if again is None or not accepted(again):
            # (statuses that cycle end the rounds with the last solution: on a statically
            # indeterminate face that holds, a lightly loaded corner may carry more than
            # its own cone while the face's total is inside; clamping it there let held
            # boxes slide)
            lam, solved = _projected_sweeps(A, pre, target, mu)
            return (lam if solved or not strict else None), None
        result = again
    lam, active, slide, s, _ = result
    if slip0 is None:
        return lam, None
    size0 = np.sqrt((slip0 * slip0).sum(1))
    stuck = active & ~slide & (mu > 0.0) & (size0 > tol_v)
    if not stuck.any():
        return lam, None
    s0 = np.where(stuck[:, None], slip0 / np.where(size0 > 0.0, size0, 1.0)[:, None], s)
    lam_slide = _patch_statuses(A, pre, target, mu, active, slide | stuck, s0)
    v_slide = pre + matmul(A, lam_slide.ravel()).reshape(k, 3)
    end = (v_slide[:, 1:] * s0).sum(1)  # the slip along s0 at the end: < 0, it reversed
    ok = stuck & (end < 0.0)
    if not ok.any():
        return lam, None
    frac = float(np.min(np.where(ok, size0 / np.where(ok, size0 - end, 1.0), np.inf)))
    return lam, (frac, lam_slide)


FACE_COS = 1.0 - 1e-12  # normals this close are one face's (`_spread_faces`)


def _faces(c: ContactSet) -> tuple:
    """(dirs, pair) of contacts c for `_spread_faces`: their world bases (k, 3, 3) and an
    id of each one's pair of bodies (k,)."""
    if not len(c):
        return c.dirs, np.zeros(0, np.int64)
    return c.dirs, c.a * (int(max(c.a.max(), c.b.max())) + 1) + c.b


def _spread_faces(A, lam, mu, stick, faces, tol_v):
    """(spread, holds): spread is lam (k, 3) along (n, t1, t2) with the friction of each
    face's sticking points (the `stick` points of one pair of bodies with one normal)
    spread over them in proportion to their normal impulses, if that leaves every
    velocity as it was (A lam, to tol_v) and puts every such point inside its cone, else
    None; holds: every such face's friction force is within mu times its pushing normal
    impulses (the face could hold, whatever its split).

    Why: a face held by friction is statically indeterminate; the minimum-norm solution
    picks one split of its friction, which can put more on a lightly loaded corner than
    its cone takes (7 times, a box held on a 36 degree slope at mu = 1.01 tan(th)). The
    rounds then let that corner slide, cycled, and ended on a solution that slid and
    turned the box (7 mm/s). Spread with the normal impulses, the friction's centre is
    the normal impulses' centre, which for a face at rest lies on the line of the
    friction force (the moment balance that holds it): the same force and torque, every
    corner at the face's ratio |F_t| / N. Where the torque differs (a face that must stop
    a turn) the velocities differ and the rounds go on as before."""
    dirs, pair = faces
    normal = dirs[:, 0]
    new = lam.copy()
    done = np.zeros(len(lam), bool)
    holds, pulls = True, False
    for i in np.flatnonzero(stick).tolist():
        if done[i]:
            continue
        face = stick & (pair == pair[i]) & ((normal * normal[i]).sum(1) >= FACE_COS)
        done |= face
        members = np.flatnonzero(face)
        force = (lam[members, 1:2] * dirs[members, 1] +
                 lam[members, 2:3] * dirs[members, 2]).sum(0)  # world, N s
        load = float(np.maximum(lam[members, 0], 0.0).sum())
        holds = holds and float(np.sqrt(dot(force, force))) <= \
            float(mu[members].min()) * load * (1.0 + 1e-12)
        pulls = pulls or bool((lam[members, 0] < 0.0).any())
        if len(members) < 2 or load <= 0.0:
            continue
        for j in members.tolist():
            share = force * (lam[j, 0] / load)
            new[j, 1] = dot(share, dirs[j, 1])
            new[j, 2] = dot(share, dirs[j, 2])
    if not holds or pulls or not done.any():
        return None, holds
    lt = np.sqrt((new[:, 1:] ** 2).sum(1))
    if (stick & (lt > mu * new[:, 0] * (1.0 + 1e-12))).any():
        return None, holds
    if np.abs(matmul(A, (new - lam).ravel())).max() > tol_v:
        return None, holds  # another torque: not the same motion
    return new, holds


SLIDE_LAW_SLIP = 1e-6  # m/s per m/s of the scale: a sticking point's slip beyond round-off


def _admissible(A, pre, target, lam, tol_v, stuck=None) -> bool:
    """Whether impulses lam (k, 3) that `_patch` ended with, without its statuses
    settling, may stand: no normal impulse pulls, no point still approaches beyond its
    allowance, and the kinetic energy does not grow. The last holds for every solution
    of the contact laws (the change lam.pre + lam.A lam / 2 = lam.v - lam.A lam / 2 with
    v the velocity after: lam_n v_n = -lam_n target <= 0 and friction opposes the slip),
    so a gain marks a wrong solution. Seen: a box corner sliding down a step's side at
    mu = 1.375 has a negative effective normal mass while it slides (A_nn - mu A_nt < 0,
    Painleve's paradox); the statuses cycled through sticking, sliding and leaving and
    ended on lam_n = -8.4 N s, which threw a 2.7 kg box at 6 m/s and 42 rad/s.

    stuck: (k,) bool, the points the rounds ended on as sticking: also none of them may
    slip (more than SLIDE_LAW_SLIP of the scale). Rounds that break off on a cycle end on
    the last solve's impulses, whose statuses were other ones: a box of a block at rest,
    alone on the ground, was accepted with its four corners "sticking" and slipping at
    0.24 m/s, and turned at 1.6 rad/s (an inclined block's kick). (Sticking points whose
    friction leaves their own cone while the face's total is inside stay admissible, as
    above.)"""
    size = 1.0 + float(np.abs(lam).max())
    change = matmul(A, lam.ravel())
    v = pre + change.reshape(-1, 3)
    if (lam[:, 0] < -1e-12 * size).any() or (v[:, 0] < -target - tol_v).any():
        return False
    if stuck is not None and stuck.any():
        slip = np.sqrt((v[:, 1:] ** 2).sum(1))
        if (slip[stuck] > (SLIDE_LAW_SLIP / PATCH_TOL) * tol_v).any():
            return False
    gain = dot(lam.ravel(), pre.ravel() + 0.5 * change)
    return gain <= 1e-12 * size * (1.0 + float(np.abs(pre).max()))


SWEEPS = 200  # projected Gauss-Seidel sweeps of `_projected_sweeps` and `_lcp`, at most


def _projected_sweeps(A, pre, target, mu):
    """(lam, solved) for `_patch`'s problem by projected Gauss-Seidel from zero, the
    fallback where its active sets do not settle (`_admissible`). lam: (k, 3) along (n,
    t1, t2). Per point: the normal impulse that meets v_n = -target, clamped at >= 0,
    then the friction impulse that stops its slip (the 2 x 2 tangent block solved),
    scaled into the cone mu lam_n. Each update lowers the quadratic lam.pre + lam.A lam
    / 2 over a convex set (an update that would raise it is skipped unless the cone
    shrank under the old friction), so the result never pulls and never leaves a cone.
    With fixed other bodies that quadratic is the kinetic energy change. The result is
    order-dependent (mirror images may differ) and converges slowly where points are
    nearly dependent. Sweeps stop when no impulse changes by more than 1e-13 of the
    largest, or after SWEEPS. solved: the sweeps converged and no point approaches
    after the final normal pass. Against frozen bodies that move (`_patch_blocks`),
    pre need not be a velocity the body can have: two lower bodies closing on it ask
    for the impossible, the quadratic has no minimum and the sweeps grow impulses
    without bound (940 N s in a 32-box grid, which threw a 1 kg box at 6 m/s).
    (Painleve's configurations have rigid-body velocity solutions only with sticking;
    Stewart 2000, SIAM Review 42.)"""
    from vrsim_cli.kernels.plastic import dense_sweeps  # numba: hard contact sets only

    k = len(pre)
    flat = np.zeros(3 * k)
    v = pre.ravel().copy()
    converged = bool(dense_sweeps(np.ascontiguousarray(A, dtype=float),
                                  np.ascontiguousarray(target, dtype=float),
                                  np.ascontiguousarray(mu, dtype=float), v, flat, SWEEPS,
                                  1e-13))
    # what still approaches after the sweeps gets normal impulses only, all at once
    # (`_lcp`): lam_n only grows, so the friction stays in its cones, and the pass
    # is dissipative like any plastic normal impulse
    rows = 3 * np.arange(k)
    tol = 1e-12 * (1.0 + float(np.abs(v).max()))
    if (v[rows] < -target - tol).any():
        extra = _lcp(A[np.ix_(rows, rows)], v[rows], -target)
        flat[rows] += extra
        v += matmul(A[:, rows], extra)
    return flat.reshape(k, 3), bool(converged and not (v[rows] < -target - tol).any())


def _patch_statuses(A, pre, target, mu, active, slide, s) -> np.ndarray:
    """The impulses (k, 3) of `_patch` for given statuses: the normal rows of the active
    points (v_n = -target), the tangent rows of the sticking ones (v_t = 0); a sliding (or
    frictionless) point's impulse is lam_n (1, -mu s) in (n, t1, t2): one unknown. The
    minimum-norm solution (equal corners of a face share equally)."""
    k = len(pre)
    cols, eqs = [], []
    for i in np.flatnonzero(active).tolist():
        if slide[i] or mu[i] <= 0.0:
            d = np.array([1.0, -mu[i] * s[i, 0], -mu[i] * s[i, 1]])
            cols.append((i, matmul(A[:, 3 * i:3 * i + 3], d), d, None))
            eqs.append(3 * i)
        else:
            for j in range(3):
                cols.append((i, A[:, 3 * i + j], None, j))
                eqs.append(3 * i + j)
    lam = np.zeros((k, 3))
    if cols:
        eqs = np.array(eqs)
        want = -pre.ravel()[eqs] - np.where(eqs % 3 == 0, target[eqs // 3], 0.0)
        M = np.stack([c[1][eqs] for c in cols], axis=1)
        x = _min_norm(M, want)
        for (i, _, d, j), xi in zip(cols, x.tolist()):
            if d is None:
                lam[i, j] = xi
            else:
                lam[i] = xi * d
    return lam


def correct_positions(bodies: Bodies, c: ContactSet, slop: float, iterations: int):
    """Penetration removal (linearised non-linear Gauss-Seidel with shock propagation):
    returns (dpos (n, 3) m, dtheta (n, 3) rad world rotation vectors) that bring every
    contact's depth down to `slop`. The depth of a contact after corrections so far is
    depth - n . (dp_B + dtheta_B x p_B - dp_A - dtheta_A x p_A); the same block and
    pairwise solves as for velocities, with displacements in place of velocities."""
    n = len(bodies.inv_mass)
    dpos, dtheta = np.zeros((n, 3)), np.zeros((n, 3))
    if not len(c) or not iterations:
        return dpos, dtheta
    plan = _shock_plan(bodies, c, bodies.movable)
    for _ in range(iterations):
        for kind, data in plan:
            sub = data[1]
            moved = (sub.normal * (dpos[sub.b] - dpos[sub.a])).sum(1) + \
                (sub.jac_b[:, 0] * dtheta[sub.b]).sum(1) - (sub.jac_a[:, 0] * dtheta[sub.a]).sum(1)
            excess = np.maximum(sub.depth - moved - slop, 0.0)
            if kind == "block":
                u, dv, dw = _block_positions(data, moved, sub.depth - slop)
                scale = _move_cap(data, sub, excess, dv, dw)
                dpos[u] += scale[:, None] * dv
                dtheta[u] += scale[:, None] * dw
            elif kind == "cluster":
                d = _cluster(sub, moved, sub.depth - slop)[:, None]
                np.add.at(dpos, sub.b, d * sub.lin_b[:, 0])
                np.add.at(dtheta, sub.b, d * sub.rot_b[:, 0])
                np.add.at(dpos, sub.a, -d * sub.lin_a[:, 0])
                np.add.at(dtheta, sub.a, -d * sub.rot_a[:, 0])
            else:
                d = (excess * sub.inv_k[:, 0])[:, None]
                dpos[sub.b] += d * sub.lin_b[:, 0]
                dtheta[sub.b] += d * sub.rot_b[:, 0]
                dpos[sub.a] -= d * sub.lin_a[:, 0]
                dtheta[sub.a] -= d * sub.rot_a[:, 0]
    return dpos, dtheta
