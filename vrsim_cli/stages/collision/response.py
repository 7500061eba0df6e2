"""Loop stage 2.3, response half (slide 5.4.2): what contacts do to the motion.

`step(model, before, after, advance) -> State` replaces the free-flight state `after`
(one physics step from `before`) by the state with collision response:

1. **Event location** (isolated impacts). Pairs that come into contact during the step
   (separated at its start, penetrating at its end or swept through by continuous
   detection), and touching pairs that approach faster than `rest_speed`, are impacts.
   The first time of impact tau is the root of G(tau) = min over those pairs of their
   signed distance after advancing the *integrator itself* by tau from the step's start
   (`advance`), found by the Illinois variant of regula falsi to 1e-13 of the step. The
   bodies are advanced to tau, the impulses are applied there (`solver.resolve_impacts`),
   and the rest of the step is integrated from that state; repeated for up to MAX_EVENTS
   impacts per step and EVENTS_PER_BODY more per dynamic body. With an integrator that
   is exact for constant acceleration (rk4, verlet, dopri5), a ball under gravity follows
   its parabola exactly and its distance to a plane is a quadratic in tau whose root is
   found to round-off: bounce times and apex heights h_k = h0 eps^(2k) are exact at any
   dt. (euler and symplectic-euler are not exact in free flight, O(dt), whatever the
   response does.) When the pairs are apart
   again at the step's end (swept through a thin wall, or a ball that bounced and lands
   again), or a body turning about the point it just hit may hit with another, the
   bracket comes from conservative advancement along the integrator's path (Mirtich
   1996; `_march`), which uses continuous detection's time of impact and cannot step
   over an overlap deeper than the collision tolerance: fast bodies do not tunnel.
2. **Resting contact** at the end of the step: sequential impulses with friction (from
   zero each step: `solver._iterate_resting` says why), shock propagation and position
   correction (`solver.solve_resting`, `solver.correct_positions`).

Responses per pair (`model.response`): `impulse` (above), `slide` (the slide's
v <- v - (v.n) n for each body moving into the other, then pushed out of penetration),
`stop` (a body keeps its last non-colliding pose, at rest: at an impact it stops at the
time of impact; in a resting contact it goes back to its pose after the step's last
impact, or at the step's start), `none`.

The state's `contacts` are the contacts of the end of the step (before the position
correction) followed by the impact contacts (`toi` = time of impact after the step's
start); `contact_impulse` holds the impulse (N s, world, on B) of each.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.products import dot, matmul

from vrsim_cli.maths.rotation import cross, exp_so3, quat_from_matrix
from vrsim_cli.maths.spatial import quat_conjugate, quat_rotate
from vrsim_cli.model.collision import BOX, CAPSULE, CYLINDER, SPHERE, body_thinness
from vrsim_cli.model.model import BODY_DYNAMIC, DRIFT_SHARE
from vrsim_cli.model.response import IMPULSE, NONE, SLIDE, STOP
from vrsim_cli.stages.collision import solver
from vrsim_cli.stages.collision.broadphase import broad_phase
from vrsim_cli.stages.collision.contacts import Contacts, planar, to_contacts
from vrsim_cli.stages.collision.continuous import (approach_bound, pair_distance,
                                                    swept_contacts)
from vrsim_cli.stages.collision.narrowphase import (box_box_separation,
                                                     box_capsule_separation, narrow_phase)
from vrsim_cli.stages.collision.shapes import aabbs, place

# impacts located per step: MAX_EVENTS and EVENTS_PER_BODY per dynamic body; later ones
# in the step go to the resting solver, unlocated (80 box bullets hitting their walls in
# one step took 64 events and more: with a fixed 64, 12 of them passed through)
MAX_EVENTS = 64
EVENTS_PER_BODY = 4
ROOT_ITERATIONS = 200
ROOT_TOLERANCE = 1e-13  # of the step: the time of impact is found to this fraction
MARCH_STEPS = 1024  # conservative-advancement steps along the path before sampling the rest
LEAVE_SAMPLES = 16  # samples of the rest of the step after MARCH_STEPS
ARM_ROUNDOFF = 1e-12  # of the coordinates: a turning pair's gap must open beyond this
THROUGH_SHARE = 0.25  # of the thinner body: the most a watched pair's material fall counts


def detect(model, state) -> Contacts:
    """All contacts of `state` with a gap of at most collision.tolerance, as
    `collision.detect`, but with the broad phase's boxes grown by the tolerance too: a
    resting contact that position correction left 1e-10 m apart must stay a contact
    (unpadded boxes would drop it, and it would come back next step as a new impact)."""
    cm = model.collision
    if cm.n_geom == 0:
        return Contacts.empty()
    world = place(cm, state.body_pos, state.body_quat)
    lo, hi = aabbs(cm, world)
    ia, ib = broad_phase(model, lo - cm.tolerance, hi + cm.tolerance, state.step)
    c = to_contacts(cm, ia, ib, *narrow_phase(cm, world, ia, ib, cm.tolerance))
    return planar(c) if model.dimension == 2 else c


def bodies_of(model, state) -> solver.Bodies:
    """The solver's working view of a state: inverse masses (0 unless dynamic and in the
    scene), world inverse inertia tensors R I^-1 R^T of the freely turning bodies."""
    moving = (model.body_type == BODY_DYNAMIC) & (model.body_emit_step <= state.step)
    inv_mass = np.where(moving, model.body_inv_mass, 0.0)
    n = model.n_body
    inv_inertia = np.zeros((n, 3, 3))
    rigid = model.rigid
    if rigid is not None and rigid.n_rot:
        R = state.rot_matrix
        world = matmul(matmul(R, rigid.rot_inv_inertia), np.swapaxes(R, -1, -2))
        inv_inertia[rigid.rot_index] = world  # kinematic: rot_inv_inertia is 0
    return solver.Bodies(inv_mass, inv_inertia, state.body_vel.copy(),
                         state.body_angvel.copy(), state.body_pos)


def write_back(model, state, bodies: solver.Bodies, stopped=None, dpos=None, dtheta=None):
    """The state with the bodies' velocities (and position corrections) applied."""
    movable = bodies.inv_mass > 0.0
    vel = np.where(movable[:, None], bodies.vel, state.body_vel)
    changes = {}
    rigid = model.rigid
    R, L = state.rot_matrix, state.rot_angmom
    pos, quat, angvel = state.body_pos, state.body_quat, state.body_angvel
    if stopped is not None and stopped.any():
        vel = np.where(stopped[:, None], 0.0, vel)
    if dpos is not None:
        pos = pos + np.where(movable[:, None], dpos, 0.0)
    if rigid is not None and rigid.n_rot:
        idx = rigid.rot_index
        free = ~rigid.rot_kinematic
        # Impulses changed omega by I(t)^-1 (sum p x P); L changes by I(t) times that.
        inertia = matmul(matmul(R, rigid.rot_inertia), np.swapaxes(R, -1, -2))
        dw = bodies.angvel[idx] - state.body_angvel[idx]
        L = L + np.where(free[:, None], np.einsum("kij,kj->ki", inertia, dw), 0.0)
        if stopped is not None:
            L = np.where(stopped[idx, None] & free[:, None], 0.0, L)
        if dtheta is not None and np.abs(dtheta[idx]).max() > 0.0:
            # A position correction moves the body, it does not push it: L turns with it
            # (the body-frame angular momentum is kept), so 1/2 L.I^-1 L, the kinetic
            # energy, is unchanged; keeping the world L changed it.
            turn = exp_so3(np.where(free[:, None], dtheta[idx], 0.0))
            R = matmul(turn, R)
            L = np.einsum("kij,kj->ki", turn, L)
            quat = quat.copy()
            quat[idx] = quat_from_matrix(R)
        inv = matmul(matmul(R, rigid.rot_inv_inertia), np.swapaxes(R, -1, -2))
        w = np.einsum("kij,kj->ki", inv, L)
        angvel = angvel.copy()
        angvel[idx] = np.where(free[:, None], w, angvel[idx])
        changes.update(rot_matrix=R, rot_angmom=L)
    return state.replace(body_pos=pos, body_vel=vel, body_quat=quat, body_angvel=angvel,
                         **changes)


def _contact_set(model, bodies, c: Contacts, rows=None):
    rows = np.arange(len(c)) if rows is None else rows
    a, b = c.body_a[rows], c.body_b[rows]
    _, eps, mu = model.response.pair_values(a, b)
    return solver.prepare(bodies, a, b, c.point[rows], c.normal[rows], c.depth[rows], eps,
                          mu)


def _modes(model, c: Contacts):
    return model.response.pair_values(c.body_a, c.body_b)[0]


def _approach(bodies, c: Contacts, rows) -> np.ndarray:
    """(len(rows),) m/s relative normal velocity at the contact points (< 0: approaching)."""
    a, b = c.body_a[rows], c.body_b[rows]
    point, n = c.point[rows], c.normal[rows]
    vr = bodies.vel[b] + cross(bodies.angvel[b], point - bodies.pos[b]) - \
        bodies.vel[a] - cross(bodies.angvel[a], point - bodies.pos[a])
    return (vr * n).sum(1)


# ------------------------------------------------------------------------ impacts


def _approach_then(model, last, state, c: Contacts, rows) -> np.ndarray:
    """As `_approach`, with the velocities of `last` (the step's start or its last
    impact) at the contacts of `state`, taken on the bodies: arms from the bodies'
    centres in `state`. (Arms from their centres in `last` moved a rolling sphere's
    contact ahead by v h: its spin then read as an approach of omega v h, 0.17 m/s at
    1 m/s and dt 1/30 s, above rest_speed, and it hopped with restitution.)"""
    then = solver.Bodies(None, None, last.body_vel, last.body_angvel, state.body_pos)
    return _approach(then, c, rows)  # (reads velocities and centres only)


def _slide(bodies, c: Contacts, rows) -> None:
    """The slide's v <- v - (v.n) n for each movable body moving into the other."""
    for k in rows.tolist():
        n = c.normal[k]
        for body, sign in ((c.body_b[k], -1.0), (c.body_a[k], 1.0)):
            vn = dot(bodies.vel[body], n)
            if bodies.inv_mass[body] > 0.0 and sign * vn > 0.0:
                bodies.vel[body] = bodies.vel[body] - vn * n


def apply_impacts(model, state, c: Contacts):
    """Impulses (or stop / slide) for the contacts `c` of `state` at an instant of impact.
    Returns (new state, impulse (k, 3) N s on B per contact)."""
    bodies = bodies_of(model, state)
    mode = _modes(model, c)
    impulse = np.zeros((len(c), 3))
    approaching = np.zeros(len(c), bool)
    if len(c):
        approaching = _approach(bodies, c, np.arange(len(c))) < -solver.APPROACH_EPS
    stopped = np.zeros(model.n_body, bool)
    stop = np.flatnonzero((mode == STOP) & approaching)
    for body in np.concatenate([c.body_a[stop], c.body_b[stop]]).tolist():
        stopped[body] = bodies.inv_mass[body] > 0.0
    bodies.vel[stopped] = 0.0
    bodies.angvel[stopped] = 0.0
    _slide(bodies, c, np.flatnonzero((mode == SLIDE) & approaching))
    rows = np.flatnonzero(mode == IMPULSE)
    if len(rows):
        cs = _contact_set(model, bodies, c, rows)
        impulse[rows] = solver.resolve_impacts(bodies, cs, model.response.rest_speed)
    return write_back(model, state, bodies, stopped), impulse


def _pair_geoms(model, a, b):
    cm = model.collision
    body_geom = np.full(model.n_body, -1, np.int64)
    body_geom[cm.geom_body] = np.arange(cm.n_geom)
    return body_geom[a], body_geom[b]


def _signed_gaps(cm, world, ia, ib, separation=False):
    """Signed gap (P,) m of geom pairs, <= 0 exactly when they touch or overlap (only the
    sign and continuity matter for the root): detection's pair distance, but box pairs
    through the separating-axis test (its largest separation is 0 exactly at the touch),
    which agrees with fcl where the corner/edge distance does not. `separation`: box
    pairs by the separation alone (`narrowphase.box_box_separation`, no manifold: a
    lower bound on their distance, as conservative advancement needs, and ~10x cheaper)."""
    boxes = (cm.geom_type[ia] == BOX) & (cm.geom_type[ib] == BOX)
    d = np.full(len(ia), np.inf)
    rest = ~boxes
    if separation:  # box-capsule: the exact distance only where a cheap bound is <= 0
        for box, cap in ((ia, ib), (ib, ia)):
            sel = np.flatnonzero((cm.geom_type[box] == BOX) & (cm.geom_type[cap] == CAPSULE))
            if len(sel):
                d[sel] = box_capsule_separation(cm, world, box[sel], cap[sel])
                rest[sel[d[sel] > 0.0]] = False
    rest = np.flatnonzero(rest)
    if len(rest):
        d[rest] = pair_distance(cm, world, ia[rest], ib[rest])
    sat = np.flatnonzero(boxes)
    if len(sat) and separation:
        d[sat] = box_box_separation(world, ia[sat], ib[sat])
    elif len(sat):
        pair, _, _, depth = narrow_phase(cm, world, ia[sat], ib[sat], np.inf)
        np.minimum.at(d, sat[pair], -depth)
    return d


def _first_impact(model, s, end, h: float, touching: set, advance, c0=None, c1=None,
                  solved=False):
    """Time tau in [0, h] of the first impact of the motion from s (free flight to `end`),
    or None. Candidates: pairs penetrating at the end that did not touch at s; touching
    pairs approaching faster than rest_speed (impact now or soon); touching pairs leaving
    faster than rest_speed (a ball that just bounced may land again within the step), and
    touching pairs that are apart at the end (a box that turned about the corner it just
    hit may hit with another corner, or pass through a thin wall); pairs swept through
    (continuous detection). c0, c1: the contacts of s and `end` when the caller has them.
    solved: s is an instant whose impacts were just solved (c0 its contacts); what its
    touching pairs still approach is what that solve left (round-off of the impulses, or
    the little a solve stopped short of: see `solver.resolve_impacts`), not an impact:
    they are never `fast`. (A box bullet's two corners at 200 m from the origin were left
    approaching at 1.4e-11 m/s, above 1e-12 (1 + the speeds) once the impact had
    stopped it: the same impact was found at tau = 0 until the step's MAX_EVENTS ran
    out, and another bullet of the scene passed through its wall.)

    The bracket of the root: [0, h] when every candidate is apart at 0, some overlap at h
    and continuous detection found no pair swept through (the exact bounce). Otherwise
    conservative advancement along the integrator's path (`_march`), which takes
    continuous detection's time of impact (found on the step's chord) as a lower bound
    for its pair: no overlap deeper than the tolerance is stepped over, however fast
    the bodies and however thin the obstacle."""
    rm, cm = model.response, model.collision
    c1 = detect(model, end) if c1 is None else c1
    pairs = []
    fast, leaving, still = set(), set(), set()
    closing = {}  # m/s: a touching pair's fastest approach at the start (>= 0)
    if touching:
        c0 = detect(model, s) if c0 is None else c0
        keep = np.flatnonzero(_modes(model, c0) != NONE)
        if len(keep):
            bodies = bodies_of(model, s)
            vn = _approach(bodies, c0, keep)
            # Without gravity rest_speed is 0: the round-off left by a plastic impact
            # (relative to the bodies' speeds) is neither approaching nor leaving.
            speed = np.linalg.norm(bodies.vel, axis=1)
            slow = np.maximum(rm.rest_speed, solver.APPROACH_EPS * (
                1.0 + speed[c0.body_a[keep]] + speed[c0.body_b[keep]]))
            for k, v, u in zip(keep.tolist(), vn.tolist(), slow.tolist()):
                pair = (int(c0.body_a[k]), int(c0.body_b[k]))
                closing[pair] = max(closing.get(pair, 0.0), -v)
                if v < -u and not solved:
                    fast.add(pair)
                elif v > u:
                    leaving.add(pair)
                else:
                    still.add(pair)
    leaving -= fast
    mode1 = _modes(model, c1)
    # A touching pair that neither approached nor left (it turns about the point it just
    # hit, or rests) and at the end is apart or deeper than the tolerance may have hit
    # with another point (a box's next corner, or through a thin wall): it takes part
    # once its gap has opened beyond its gap at the start (a resting contact that sinks
    # under gravity never does).
    end_depth = {}
    for k in np.flatnonzero(mode1 != NONE).tolist():
        pair = (int(c1.body_a[k]), int(c1.body_b[k]))
        end_depth[pair] = max(end_depth.get(pair, -np.inf), float(c1.depth[k]))
    turning = {p for p in still - fast - leaving
               if end_depth.get(p, np.inf) > cm.tolerance}
    pairs.extend(leaving | turning)
    for k in np.flatnonzero((mode1 != NONE) & (c1.depth >= 0.0)).tolist():
        pair = (int(c1.body_a[k]), int(c1.body_b[k]))
        if pair not in touching or pair in fast or pair in leaving:
            pairs.append(pair)
    swept_toi = {}
    if cm.continuous:
        # (a pair within the tolerance at the end may be there after passing through)
        inside = set(zip(c1.body_a[c1.depth >= 0.0].tolist(),
                         c1.body_b[c1.depth >= 0.0].tolist()))
        swept = swept_contacts(model, s, end, inside | touching)
        keep = np.flatnonzero(_modes(model, swept) != NONE)
        for k in keep.tolist():
            pair = (int(swept.body_a[k]), int(swept.body_b[k]))
            pairs.append(pair)
            swept_toi[pair] = min(float(swept.toi[k]), swept_toi.get(pair, np.inf))
    if not pairs:
        return None
    pairs = sorted(set(pairs))
    ia, ib = _pair_geoms(model, np.array([p[0] for p in pairs]), np.array([p[1] for p in
                                                                            pairs]))

    memo = {0.0: s}  # the march and the root ask for the same times twice (gap, level)

    def state_at(tau):
        if tau not in memo:
            if len(memo) > 2:
                memo.clear()
                memo[0.0] = s
            memo[tau] = advance(model, s, tau)
        return memo[tau]

    def gaps(tau, sel=slice(None), separation=False):
        st = state_at(tau)
        return _signed_gaps(cm, place(cm, st.body_pos, st.body_quat), ia[sel], ib[sel],
                            separation)

    def separations(tau, sel=slice(None)):
        return gaps(tau, sel, True)

    d0 = gaps(0.0)
    back = np.array([p in leaving or p in turning for p in pairs])
    if (d0[~back] <= 0.0).any():
        return 0.0
    # The exact bounce: every pair apart at 0, some overlapping at h, none swept through.
    # (Not for a touching pair that neither approached nor left, with a gap at 0 that is
    # position correction's 1e-17 m: its resting point sinking under gravity, or a push,
    # would be found as an "impact" every step; `_march` watches it.)
    if not swept_toi and (d0 > 0.0).all() and not (back & (d0 <= cm.tolerance)).any():
        g_hi = float(gaps(h).min())
        if g_hi <= 0.0:
            return _root(lambda t: float(gaps(t).min()), 0.0, float(d0.min()), h, g_hi, h)
    toi = np.array([swept_toi.get(p, 0.0) for p in pairs])
    mu = approach_bound(cm, s, end, ia, ib)
    sep0 = separations(0.0)
    turns = np.array([p in turning for p in pairs])
    # A turning pair takes part once its gap has opened beyond round-off: a body sliding
    # off the face it rests on (a sphere leaving a mesh's face sideways) has a gap that
    # only wobbles by ulps of its coordinates, and each wobble below 0 was an "impact"
    # (64 events of 2e-5 s filled a step, and a later impact in it was lost).
    noise = ARM_ROUNDOFF * (1.0 + float(np.abs(s.body_pos[np.concatenate([
        [p[0] for p in pairs], [p[1] for p in pairs]])]).max()))
    arm = np.where(back, np.where(turns, np.maximum(sep0, 0.0) + noise, 0.0), -np.inf)
    # Until then, such a pair is watched for sinking: another of its points (a capsule's
    # other end, a box's next corner) may reach the obstacle without the gap ever
    # opening, since the least gap is the touching point's ~0 until the other one is
    # lower. A gap that falls to the tolerance below where its resting points can be has
    # hit with another point (a capsule at 661 m/s went through a 1 cm plate so).
    sink = np.where(back, np.minimum(sep0, 0.0) - cm.tolerance, -np.inf)
    # (the material part of that fall counts up to THROUGH_SHARE of the thinner body)
    thin = body_thinness(cm, len(model.body_type))
    cap = THROUGH_SHARE * np.minimum(thin[[p[0] for p in pairs]], thin[[p[1] for p in pairs]])
    fall = _resting_fall(model, s, end, h, pairs, closing, c0 if touching else None,
                         state_at, cap)
    bracket = _march(separations, sep0, arm, toi, h, mu, cm.tolerance, (sink, fall))
    if bracket is None:
        return None
    sel, lo, g_lo, hi, g_hi, level = bracket
    return _root(lambda t: float((separations(t, sel) - level(t)).min()), lo, g_lo, hi, g_hi,
                 h)


def _resting_fall(model, s, end, h, pairs, closing, c0, state_at, room):
    """fall(t) -> (len(pairs),) m: how far each touching pair's resting points can sink
    by t after s. Kinematic: v0 t + k a t^2 (v0 the pair's approach at s, a the two
    bodies' mean acceleration over the step, k the integrator's share of it in the
    drift, DRIFT_SHARE: symplectic Euler drops a point a t^2, rk4 a t^2 / 2, 5.4 mm in
    1/30 s under gravity); it holds for a point that rolls away (a sphere's contact
    point is not a body point). Material: the sinking of the body points at the
    contacts of s (c0) along the integrator's own path, which includes what the
    kinematic bound misses: a torque or an off-centre force swings a pressed edge down.
    (Not capped at the tolerance: a pressed point that sinks far in a step, a corner
    pressed with 10 times a box's weight at dt 1/30 s, is found deep at the step's end,
    and the box may be thrown; capping the material bound at 2 tolerances beyond the
    kinematic one cut those steps with events instead, whose friction let pressed boxes
    slide 0.46 m in 1 s at dt 10 ms where they had stood still. docs/collision-response.md,
    Known limits. It stops at `room`, the caller's share of the thinner body.) Both
    bounds depend on the pair alone, so mirror-image pairs keep mirror-image events."""
    v0 = np.array([max(closing.get(p, 0.0), 0.0) for p in pairs])
    accel = np.linalg.norm(end.body_vel - s.body_vel, axis=1) / h  # m/s^2, mean
    pace = accel[[p[0] for p in pairs]] + accel[[p[1] for p in pairs]]
    share = max(DRIFT_SHARE[model.integrator], 0.5)  # (euler's 0: bounded by 1/2)
    rows = np.zeros(0, np.int64)
    if c0 is not None and len(c0):
        index = {p: i for i, p in enumerate(pairs)}
        of = np.array([index.get((a, b), -1) for a, b in zip(c0.body_a.tolist(),
                                                              c0.body_b.tolist())])
        rows = np.flatnonzero((of >= 0) & (_modes(model, c0) != NONE))
    if not len(rows):
        return lambda t: v0 * t + share * pace * t * t
    pair_of = of[rows]
    a, b = c0.body_a[rows], c0.body_b[rows]
    back_a, back_b = quat_conjugate(s.body_quat[a]), quat_conjugate(s.body_quat[b])
    local_a = _curvature_centres(model, a, quat_rotate(back_a, c0.point[rows] -
                                                       s.body_pos[a]))
    local_b = _curvature_centres(model, b, quat_rotate(back_b, c0.point[rows] -
                                                       s.body_pos[b]))
    local_n = quat_rotate(back_a, c0.normal[rows])  # (the normal turns with A)

    def apart(st):  # (rows,) m: the distance along n between the points' centres
        qa, qb = st.body_quat[a], st.body_quat[b]
        return ((st.body_pos[b] + quat_rotate(qb, local_b) - st.body_pos[a] -
                 quat_rotate(qa, local_a)) * quat_rotate(qa, local_n)).sum(1)
    start = apart(s)  # (the centres stay their radii from the surfaces: they cancel)

    # The material bound measures the points along A's turning normal: points that slide
    # apart fast on a body that turns fast (a capsule after an 895 m/s impact on a
    # dynamic 1 cm plate) read as sinking metres in a step, and the other end of the
    # capsule went through the plate unseen. No point may sink further than into the
    # thinner body: that bound stops at `room` ((len(pairs),) m, THROUGH_SHARE of it).

    def fall(t):
        kinematic = v0 * t + share * pace * t * t
        rise = apart(state_at(t)) - start
        material = np.zeros(len(pairs))
        np.maximum.at(material, pair_of, -rise)
        return np.maximum(kinematic, np.minimum(material, room))
    return fall


def _curvature_centres(model, body, local):
    """(k, 3) m body frame: the centres of curvature of the bodies' surfaces at contact
    points `local` (body frame). On a sphere its centre, on a capsule's or a cylinder's
    side the nearest point of its axis: the contact point of a rolling body is not a
    body point (it rises by (v t)^2 / 2 r as the body rolls on), the centre is, and
    stays r from the surface. Elsewhere (a corner, an edge, a flat face, a cylinder's
    rims, a mesh) the contact point itself. (A cylinder lying on a plane touches it at
    its rims: the kinematic bound covers its rolling.)"""
    cm = model.collision
    geom = _pair_geoms(model, body, body)[0]
    out = local.copy()
    kind = cm.geom_type[geom]
    for k in np.flatnonzero((kind == SPHERE) | (kind == CAPSULE) | (kind == CYLINDER)):
        g = int(geom[k])
        centre = cm.geom_local_pos[g]
        if kind[k] == SPHERE:
            out[k] = centre
            continue
        axis = quat_rotate(cm.geom_local_quat[g], np.array([0.0, 1.0, 0.0]))
        half = float(cm.geom_half[g, 1])
        along = float(dot(local[k] - centre, axis))
        if kind[k] == CYLINDER and abs(along) >= half:
            continue  # on a cap's face or rim: flat, or an edge (a standing cylinder's
            # rim is its support: tracked as the cap's centre, a pushed one sank "below")
        out[k] = centre + min(max(along, -half), half) * axis
    return out


def _march(gaps, d0, arm, toi, h, mu, tol, watch=None):
    """Conservative advancement (Mirtich 1996) along the integrator's path to the first
    overlap of a candidate pair. From t, where every pair taking part is apart (gaps
    d_i > 0), pair i cannot touch before t + max(d_i, tol) / mu_i (mu_i:
    `continuous.approach_bound`; the gap closes by at most max(d_i, tol) in that time, so
    an overlap deeper than `tol` is never stepped over), nor before toi_i, continuous
    detection's time of impact (found on the step's chord; 0 when it found none); the
    march steps to the earliest of these. A pair takes part once its gap exceeds arm_i
    (-inf: from the start; 0: a pair touching at 0 and leaving, once apart; its gap at 0:
    a touching pair that neither approached nor left). Until then, with watch = (sink,
    fall) ((k,) m; fall(t) -> (k,) m, `_resting_fall`), a pair with a finite sink_i takes
    part when its gap falls to sink_i - fall(t)_i (below where its resting points are).
    Returns (pairs taking part, lo, E(lo) > 0, hi, E(hi) <= 0, level), E the least of
    their gaps less level(t) (their levels at t: 0 for an armed pair), or None (no
    overlap within h)."""
    sink, fall = watch if watch is not None else (np.full(len(d0), -np.inf),
                                                   lambda t: np.zeros(len(d0)))
    t, d = 0.0, d0
    armed = d0 > arm
    watching = np.isfinite(sink)

    def below(t, idx):  # sink - fall(t), -inf for unwatched pairs (fall not evaluated)
        if not watching[idx].any():
            return np.full(len(idx), -np.inf)
        return np.where(watching[idx], sink[idx] - fall(t)[idx], -np.inf)

    def levels(t, idx):
        return np.where(armed[idx], 0.0, below(t, idx))

    def event(t_next, d, d_next, idx):
        """The pairs idx that take part in an event at t_next ((k,) bool: the armed ones
        and the sunk ones, if any pair hit) and their levels (a function of time)."""
        hit = d_next - levels(t_next, idx) <= 0.0
        if not hit.any():
            return None, None
        take = armed[idx] | hit
        chosen = idx[take]
        fixed = armed[chosen].copy()
        return take, lambda t: np.where(fixed, 0.0, below(t, chosen))

    every = np.arange(len(d0))
    for _ in range(MARCH_STEPS):
        with np.errstate(divide="ignore"):
            step = np.where(mu > 0.0, np.maximum(np.where(armed, d, 0.0), tol) / mu, np.inf)
        t_next = min(float(np.maximum(t + step, toi).min()), h)
        d_next = gaps(t_next)
        take, level = event(t_next, d, d_next, every)
        if take is not None:
            sel = np.flatnonzero(take)
            return (sel, t, float((d[sel] - level(t)).min()), t_next,
                    float((d_next[sel] - level(t_next)).min()), level)
        armed |= d_next > arm
        t, d = t_next, d_next
        if t >= h:
            return None
    # very slow progress (a pair skimming past within the tolerance): sample the rest
    watched = np.flatnonzero(armed | np.isfinite(sink))
    d = d[watched]
    for j in range(1, LEAVE_SAMPLES + 1):
        t_next = t + (h - t) * j / LEAVE_SAMPLES
        d_next = gaps(t_next, watched)
        take, level = event(t_next, d, d_next, watched)
        if take is not None:
            return (watched[take], t, float((d[take] - level(t)).min()), t_next,
                    float((d_next[take] - level(t_next)).min()), level)
        t, d = t_next, d_next
    return None


def _root(gap, lo, g_lo, hi, g_hi, h):
    """The root of gap in [lo, hi] (gap(lo) > 0 >= gap(hi)) to ROOT_TOLERANCE * h, by the
    Illinois variant of regula falsi; returns its upper end (overlapping or touching)."""
    side = 0
    for _ in range(ROOT_ITERATIONS):
        if hi - lo <= ROOT_TOLERANCE * h:  # (not at g = 0: a distance may be 0 for
            break                             # any overlap, so 0 is not yet the touch)
        m = hi - g_hi * (hi - lo) / (g_hi - g_lo)
        if not lo < m < hi:
            m = 0.5 * (lo + hi)
        g = gap(m)
        if g > 0.0:
            lo, g_lo = m, g
            if side == 1:
                g_hi *= 0.5  # Illinois: halve the stale end so the bracket shrinks on both
            side = 1
        else:
            hi, g_hi = m, g
            if side == -1:
                g_lo *= 0.5
            side = -1
    return hi


# ------------------------------------------------------------------------ resting


def resting(model, start, state, last=None, c=None):
    """Resting contact at the end of a step (`state`; `start`: the step's start; `last`:
    the state after the step's last impact, default `start`: a `stop` body goes back to
    its pose there, the last pose known not to collide). Returns the
    corrected state with contacts and impulses. c: the contacts of `state` if known."""
    last = start if last is None else last
    rm = model.response
    c = detect(model, state) if c is None else c
    mode, pair_eps, pair_mu = rm.pair_values(c.body_a, c.body_b)
    impulse = np.zeros((len(c), 3))
    bodies = bodies_of(model, state)
    # stop: a body in penetrating contact goes back to its pose at the step's start, at rest
    stop = np.flatnonzero((mode == STOP) & (c.depth > 0.0))
    stopped = np.zeros(model.n_body, bool)
    for body in np.concatenate([c.body_a[stop], c.body_b[stop]]).tolist():
        stopped[body] = bodies.inv_mass[body] > 0.0
    dpos = np.zeros((model.n_body, 3))
    if stopped.any():
        dpos[stopped] = last.body_pos[stopped] - state.body_pos[stopped]
    slide = np.flatnonzero(mode == SLIDE)
    if len(slide):
        _slide(bodies, c, slide[_approach(bodies, c, slide) < 0.0])
        for k in slide[c.depth[slide] > 0.0].tolist():  # out along n, shared if both move
            a, b = int(c.body_a[k]), int(c.body_b[k])
            share = 0.5 if bodies.inv_mass[a] > 0 and bodies.inv_mass[b] > 0 else 1.0
            for body, sign in ((b, 1.0), (a, -1.0)):
                if bodies.inv_mass[body] > 0.0:
                    push = sign * share * c.depth[k] * c.normal[k]
                    dpos[body] = np.where(np.abs(push) > np.abs(dpos[body]), push,
                                          dpos[body])
    rows = np.flatnonzero(mode == IMPULSE)
    if len(rows):  # a gap closing fast is the next step's impact, located, unless it
        # was not closing at the step's start (or its last impact): a resting body under
        # euler, which moves with the start velocity, keeps its gap and ends the step
        # approaching at g dt, above rest_speed from dt = 14 ms; left out here, it fell
        # for a step, bounced next step and spun up on the corners' round-off (0.8 rad/s).
        then = _approach_then(model, last, state, c, rows)
        closing = (c.depth[rows] < 0.0) & (_approach(bodies, c, rows) < -rm.rest_speed) & \
            (then < -rm.rest_speed)
        rows, then = rows[~closing], then[~closing]
    dtheta = np.zeros((model.n_body, 3))
    if len(rows):
        impulse[rows] += _missed_impacts(model, then, bodies, c, rows)
        cs = _contact_set(model, bodies, c, rows)
        kink = np.full((model.n_body, 4), np.nan)
        impulse[rows] = solver.solve_resting(bodies, cs, model.dt, rm.iterations,
                                             (last.body_vel, last.body_angvel), kink)
        # held: an impulse that changes the contact's velocity by more than round-off
        # (a contact with 2e-15 N s and its mirror image with 0 were treated apart)
        held = np.abs(impulse[rows]).max(axis=1) > solver.APPROACH_EPS * cs.inv_k[:, 0]
        dpos += _drift(model, last, state, bodies, c, rows[held], kink, impulse[rows[held]])
        dp, dth = solver.correct_positions(bodies, cs, rm.slop, rm.position_iterations)
        dpos += dp
        dtheta += dth
    if stopped.any():
        bodies.vel[stopped] = 0.0
        dtheta[stopped] = 0.0
    new = write_back(model, state, bodies, stopped, dpos, dtheta)
    if stopped.any() and model.rigid is not None and model.rigid.n_rot:
        new = _restore_orientation(model, last, new, stopped)
    return new, c, impulse


def _missed_impacts(model, then, bodies, c: Contacts, rows) -> np.ndarray:
    """Impacts the event search did not locate, applied at the step's end with their
    restitution (`solver.resolve_impacts`) instead of plastically by the resting solver:
    contacts that penetrate at the step's end and approach faster than rest_speed both
    now and at the step's start or its last impact (`then`, (len(rows),) m/s,
    `_approach_then`; a body resting under gravity approaches at g dt at the end but not
    at the start). Seen: a box whose second corner
    reaches a wall in the step of the first corner's bounce lost 8 % of its energy in
    that step. Returns the impulses (len(rows), 3) N s on B; changes `bodies`. (The
    time of impact is lost: the body bounces up to a step late, penetrating; position
    correction then pushes it out without changing its kinetic energy.)"""
    rest = model.response.rest_speed
    out = np.zeros((len(rows), 3))
    fast = (c.depth[rows] >= 0.0) & (_approach(bodies, c, rows) < -rest) & \
        (then < -rest)
    if fast.any():
        # with every touching contact of the bodies concerned: an impulse at one corner
        # may drive another into the wall, which then takes its own (the impact rounds)
        hit = np.unique(np.concatenate([c.body_a[rows[fast]], c.body_b[rows[fast]]]))
        hit = hit[bodies.inv_mass[hit] > 0.0]
        near = (c.depth[rows] >= 0.0) & (np.isin(c.body_a[rows], hit) |
                                         np.isin(c.body_b[rows], hit))
        out[near] = solver.resolve_impacts(bodies, _contact_set(model, bodies, c, rows[near]),
                                           rest)
    return out


PRIMARY_COS = 0.7071  # cos 45 deg: support normals this close to the supports' sum
SUPPORT_SHARE = 0.25  # or carrying this share of the supports' normal impulse


def _drift(model, last, state, bodies, c: Contacts, rows, kink=None, impulse=None) -> np.ndarray:
    """(n, 3) m: the translation that makes a body held by resting contact move along its
    contact surfaces as its corrected velocity says, not as the free flight did.

    The free flight from `last` (the step's start or its last impact) moved every body
    with the unconstrained velocities: a box that friction holds on an incline slid by
    g sin(th) h^2 / 2 per step before the resting impulses set its velocity to zero, and
    crept. Here its position along the surfaces is integrated again with the trapezoid of
    its velocity before and after the contact impulses, x = x_last + h (v_last + v) / 2,
    exact for the constant accelerations of sticking and of sliding. A body whose slip
    stopped inside the step (`kink` (n, 4): fraction f of the step and velocity v_f then,
    NaN elsewhere; solver._patch) has two ramps: x = x_last + f h (v_last + v_f) / 2 +
    (1 - f) h (v_f + v) / 2.

    Along the normals of a body's supports (contacts with bodies nearer the ground:
    fixed ones, or movable ones of a lower shock level, `solver.levels`) the penetration
    pass decides, as the orientation stays the free flight's (a tipping box's centre
    rises and falls with its turn: re-integrating it along the support's normal alone
    added energy); of those, only the normals within 45 degrees of the supports' sum, or
    carrying a share of the load (`impulse`: (len(rows), 3) N s, below). The normals
    of contacts with neighbours of the same level or with bodies it carries are not
    removed: a block of boxes on a slope has neighbours' normals along the slope, every
    box had slid down it by the same g sin(th) h^2 / 2, no contact penetrated more for
    it, and when those directions were removed too (all of a body's normals, before) a
    3 x 2 x 2 block on 10 degrees crept 9 cm in 3 s. Nor those of lightly loaded
    supports across the main direction (the sum of the supports' normal impulses, into
    the body): aligned boxes touch their diagonal neighbours below along an edge, with a
    normal along the slope as often as across it, and such an edge contact, counted as a
    support, stopped the drift along the slope again (the block moved 1.7 cm; taken by
    the largest single impulse as the main support, a 2 x 2 x 1 block still moved
    1.4e-5 m). A support that carries SUPPORT_SHARE of the load counts whatever its
    direction: the two walls of a steep groove both hold a ball, at 87 degrees from
    their sum (tests/test_position_correction.py)."""
    drift = np.zeros((model.n_body, 3))
    if not len(rows):
        return drift
    h = state.t - last.t
    moved = last.body_pos + (0.5 * h) * (last.body_vel + bodies.vel)
    if kink is not None and np.isfinite(kink[:, 0]).any():
        f = np.where(np.isfinite(kink[:, 0]), kink[:, 0], 1.0)[:, None]
        v_f = np.where(np.isfinite(kink[:, 1:]), kink[:, 1:], bodies.vel)
        moved = last.body_pos + (0.5 * h) * (f * (last.body_vel + v_f) +
                                             (1.0 - f) * (v_f + bodies.vel))
    delta = moved - state.body_pos
    a, b = c.body_a[rows], c.body_b[rows]
    level = solver.levels(model.n_body, a, b, bodies.inv_mass > 0.0)
    if impulse is not None:
        load = np.maximum((impulse * c.normal[rows]).sum(1), 0.0)  # N s along n
    for body in np.unique(np.concatenate([a, b])).tolist():
        if bodies.inv_mass[body] <= 0.0:
            continue
        other = np.where(a == body, b, a)
        support = ((a == body) | (b == body)) & (level[other] < level[body])
        if impulse is not None and support.any():
            side = np.where(b == body, 1.0, -1.0)[:, None]  # normals pointing into body
            total = ((load * support)[:, None] * side * c.normal[rows]).sum(0)
            size = float(np.sqrt(dot(total, total)))
            share = load / max(float(load[support].sum()), 1e-300)
            if size > 0.0:
                along = side[:, 0] * (c.normal[rows] * (total / size)).sum(1) >= PRIMARY_COS
                support &= along | (share >= SUPPORT_SHARE)
        d = delta[body].copy()
        basis = []
        for n in c.normal[rows[support]]:  # remove the components along the supports'
            for e in basis:  # normals (their span)
                n = n - dot(n, e) * e
            size = float(np.sqrt(dot(n, n)))
            if size > 1e-9:
                basis.append(n / size)
        for e in basis:
            d = d - dot(d, e) * e
        drift[body] = d
    return drift


def _restore_orientation(model, start, state, stopped):
    rigid = model.rigid
    idx = rigid.rot_index
    back = stopped[idx]
    R = np.where(back[:, None, None], start.rot_matrix, state.rot_matrix)
    quat = np.where(stopped[:, None], start.body_quat, state.body_quat)
    angvel = np.where(stopped[:, None], 0.0, state.body_angvel)
    return state.replace(rot_matrix=R, body_quat=quat, body_angvel=angvel)


# ------------------------------------------------------------------------ the stage


def step(model, before, after, advance):
    """One physics step with collision response. `after`: the free-flight step from
    `before` (dynamics and scene graph); `advance(model, state, h)`: the dynamics
    integrated over h <= dt from `state` (the loop passes `dynamics.advance`)."""
    prev = before.contacts if before.contacts is not None else detect(model, before)
    at_end = np.isnan(prev.toi)  # the impact rows are from earlier in the last step
    prev = Contacts(*(getattr(prev, f)[at_end] for f in (
        "body_a", "body_b", "point", "normal", "depth", "toi")))
    touching = prev.pairs()
    s, end = before, after
    t_end = after.t
    event_contacts, event_impulses = [], []
    # Last step's contacts stand for this step's start (before its position correction,
    # which moved them by at most the penetration): they only sort pairs into touching,
    # approaching and leaving. The end's contacts serve the impact search and, when no
    # impact cuts the step, the resting solver.
    c0, c_end = prev, detect(model, after)
    budget = MAX_EVENTS + EVENTS_PER_BODY * int((model.body_type == BODY_DYNAMIC).sum())
    for _ in range(budget):
        h = t_end - s.t
        if h <= 0.0:
            break
        tau = _first_impact(model, s, end, h, touching, advance, c0, c_end, s is not before)
        if tau is None:
            break
        at = s if tau == 0.0 else advance(model, s, tau)
        c = detect(model, at)
        at, imp = apply_impacts(model, at, c)
        event_contacts.append(Contacts(c.body_a, c.body_b, c.point, c.normal, c.depth,
                                       np.full(len(c), at.t - before.t)))
        event_impulses.append(imp)
        touching = c.pairs()
        s, c0 = at, c
        end = advance(model, s, t_end - s.t)
        c_end = None
    if s is not before:  # the step was cut: kinematic bodies follow the scene graph
        kin = model.body_type != BODY_DYNAMIC
        end = end.replace(step=after.step, t=after.t,
                          body_pos=np.where(kin[:, None], after.body_pos, end.body_pos),
                          body_vel=np.where(kin[:, None], after.body_vel, end.body_vel),
                          body_quat=np.where(kin[:, None], after.body_quat, end.body_quat),
                          body_angvel=np.where(kin[:, None], after.body_angvel,
                                               end.body_angvel))
    new, c, impulse = resting(model, before, end, s, c_end if s is before else None)
    contacts = Contacts.concatenate([c] + event_contacts)
    impulses = np.concatenate([impulse] + event_impulses) if event_impulses else impulse
    return new.replace(contacts=contacts, contact_impulse=impulses.reshape(-1, 3))
