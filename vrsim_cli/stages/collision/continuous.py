"""Continuous detection: the time of impact (TOI) within the step, found to within the
scene's tolerance epsilon (slide 5.4: "the step must be small enough that every collision
is found within a tolerance epsilon" -- here the step need not be small: the TOI is found
inside it).

Motion over a step is taken as linear in position and constant angular velocity, from the
two states (`motion`), so the swept path is the one the integrator actually took.
- sphere-sphere and sphere-plane (sphere centred on its body): closed form, the smallest
  root of |d0 + w t| = r_A + r_B, resp. of n.(c0 + v t) - o = r.
- every other pair: conservative advancement (Mirtich 1996; Zhang et al. 2006): with the
  exact distance d(t) and a bound mu on how fast any surface point of one body can
  approach the other (|v_B - v_A| + |w_A| R_A + |w_B| R_B, R the bounding radius about the
  body's origin; against a plane |n . v| instead of |v_B - v_A|), advance t by d/mu. The distance cannot reach zero within that time, so
  the TOI is never overshot; iterate until d <= epsilon.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths import trig
from vrsim_cli.maths.spatial import quat_conjugate, quat_multiply
from vrsim_cli.model.collision import BOX, MESH, PLANE, SPHERE
from vrsim_cli.stages.collision import mesh_pairs
from vrsim_cli.stages.collision.broadphase import broad_phase
from vrsim_cli.stages.collision.contacts import Contacts, to_contacts
from vrsim_cli.stages.collision.narrowphase import box_box_distance, narrow_phase
from vrsim_cli.stages.collision.shapes import aabbs, place, subset

MAX_ITERATIONS = 200  # conservative advancement steps per pair before giving up (no TOI)


def motion(before, after, dt: float):
    """Linear velocity (n_body, 3) m/s and angular velocity (n_body, 3) rad/s (world) that
    take the bodies from `before` to `after` in dt."""
    vel = (after.body_pos - before.body_pos) / dt
    dq = quat_multiply(after.body_quat, quat_conjugate(before.body_quat))
    dq = np.where(dq[:, :1] < 0.0, -dq, dq)
    s = np.linalg.norm(dq[:, 1:], axis=1)
    angle = 2.0 * trig.atan2(s, dq[:, 0])  # not libm: the same bits on every CPU
    axis = dq[:, 1:] / np.where(s > 0.0, s, 1.0)[:, None]
    return vel, axis * (angle / dt)[:, None]


def advance(pos, quat, vel, angvel, t):
    """Poses after time t (per row) of linear and constant-angular-velocity motion."""
    t = np.asarray(t, float)
    angle = np.linalg.norm(angvel, axis=1) * t
    axis = angvel / np.where(angle > 0.0, np.linalg.norm(angvel, axis=1), 1.0)[:, None]
    sin, cos = trig.sin_cos(0.5 * angle)  # not libm: the same bits on every CPU
    dq = np.concatenate([cos[:, None], sin[:, None] * axis], axis=1)
    q = quat_multiply(dq, quat)
    return pos + vel * t[:, None], q / np.linalg.norm(q, axis=1, keepdims=True)


def _closed_form(cm, ta, tb, pa, pb, va, vb, ia, ib, dt):
    """TOI (P,) for sphere-sphere and plane-sphere rows; NaN where not applicable."""
    toi = np.full(len(ia), np.nan)
    centred = ~np.any(cm.geom_local_pos[ia] != 0.0, axis=1) & \
        ~np.any(cm.geom_local_pos[ib] != 0.0, axis=1)
    ss = (ta == SPHERE) & (tb == SPHERE) & centred
    if ss.any():
        d0, w = pb[ss] - pa[ss], vb[ss] - va[ss]
        r = cm.geom_radius[ia[ss]] + cm.geom_radius[ib[ss]]
        a, b, c = (w * w).sum(1), (d0 * w).sum(1), (d0 * d0).sum(1) - r * r
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            # The smaller root, written so that it does not cancel: t = c / (-b + sqrt).
            root = c / (-b + np.sqrt(np.maximum(disc, 0.0)))
        t = np.where(c <= 0.0, 0.0, np.where((b < 0.0) & (disc >= 0.0), root, np.inf))
        toi[ss] = t
    for plane_first in (True, False):
        ps = ((ta == PLANE) & (tb == SPHERE) if plane_first else
              (ta == SPHERE) & (tb == PLANE)) & centred
        if not ps.any():
            continue
        gp, gs = (ia[ps], ib[ps]) if plane_first else (ib[ps], ia[ps])
        c, v = (pb[ps], vb[ps]) if plane_first else (pa[ps], va[ps])
        n = cm.geom_plane_normal[gp]
        d0 = (n * c).sum(1) - cm.geom_plane_offset[gp] - cm.geom_radius[gs]
        nv = (n * v).sum(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d0 <= 0.0, 0.0, np.where(nv < 0.0, -d0 / nv, np.inf))
        toi[ps] = t
    return np.where(toi <= dt, toi, np.where(np.isnan(toi), np.nan, np.inf))


def approach_bound(cm, before, after, ia, ib) -> np.ndarray:
    """(P,) m/s: a bound on how fast any surface point of geom ia can approach geom ib
    while the bodies move from `before` to `after`: the larger of the two ends' relative
    speed |v_B - v_A| (for constant accelerations |v(t)| is convex, so its maximum over
    the step is at an end; against a plane, |n . v|, affine in t as well) plus |w| R for
    each turning body (R its bounding radius about the body's origin, |w| the larger of
    the two ends'). Conservative advancement along the integrator's own path steps by
    distance / bound."""
    ba, bb = cm.geom_body[ia], cm.geom_body[ib]
    rel = np.maximum(linear_rate(cm, ia, ib, before.body_vel[ba], before.body_vel[bb]),
                     linear_rate(cm, ia, ib, after.body_vel[ba], after.body_vel[bb]))
    for g, body in ((ia, ba), (ib, bb)):
        w = max_norm(before.body_angvel[body], after.body_angvel[body])
        # planes have an infinite bounding radius but never turn: 0 * inf must not be NaN
        rel = rel + w * np.where(w > 0.0, cm.geom_rbound[g], 0.0)
    return rel


def max_norm(a, b) -> np.ndarray:
    return np.maximum(np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1))


def linear_rate(cm, ia, ib, vel_a, vel_b) -> np.ndarray:
    """(P,) m/s: how fast the translation (vel_a, vel_b (P, 3)) can close the gap of geoms
    ia, ib: |v_B - v_A|, but against a plane only the other body's speed along the
    plane's normal, |n . v| (a plane is fixed in the world whatever its body does, and a
    body moving along it does not approach it: bounding that by |v| made conservative
    advancement crawl at tolerance / |v| for a box sliding fast down an incline)."""
    rate = np.linalg.norm(vel_b - vel_a, axis=1)
    for plane, other in ((ia, vel_b), (ib, vel_a)):
        sel = np.flatnonzero(cm.geom_type[plane] == PLANE)
        if len(sel):
            rate[sel] = np.abs((cm.geom_plane_normal[plane[sel]] * other[sel]).sum(1))
    return rate


def pair_distance(cm, world, ia, ib):
    """Distance (P,) of geom pairs (<= 0 when they touch): closed forms; for box pairs the
    exact corner/edge distance (the separating-axis gap is only a lower bound); triangle
    meshes against spheres, capsules and boxes through `mesh_pairs.gap` (the least over
    the triangles near the body, without a contact manifold); fcl's GJK for pairs without
    a closed form."""
    d = np.full(len(ia), np.inf)
    boxes = (cm.geom_type[ia] == BOX) & (cm.geom_type[ib] == BOX)
    done = boxes.copy()
    for mesh, other in ((ia, ib), (ib, ia)):
        sel = np.flatnonzero((cm.geom_type[mesh] == MESH) &
                             np.isin(cm.geom_type[other], mesh_pairs.KINDS))
        if len(sel):
            d[sel] = mesh_pairs.gap(cm, world, mesh[sel], other[sel])
            done[sel] = True
    rest = np.flatnonzero(~done)
    if len(rest):
        pair, _, _, depth = narrow_phase(cm, world, ia[rest], ib[rest], np.inf)
        np.minimum.at(d, rest[pair], -depth)
    if boxes.any():
        d[boxes] = box_box_distance(world, ia[boxes], ib[boxes])
    return d


def time_of_impact(cm, body_pos, body_quat, body_vel, body_angvel, ia, ib, dt: float,
                   tolerance: float | None = None) -> np.ndarray:
    """First time in [0, dt] at which geoms ia and ib (P,) come within `tolerance` (default
    cm.tolerance) of each other, moving from the body poses with the given velocities;
    inf when they do not within dt. 0 when they already touch."""
    tol = cm.tolerance if tolerance is None else tolerance
    ia, ib = np.asarray(ia, np.int64), np.asarray(ib, np.int64)
    ba, bb = cm.geom_body[ia], cm.geom_body[ib]
    pos, quat = np.asarray(body_pos, float), np.asarray(body_quat, float)
    vel, angvel = np.asarray(body_vel, float), np.asarray(body_angvel, float)
    world0 = place(cm, pos, quat)
    toi = _closed_form(cm, cm.geom_type[ia], cm.geom_type[ib], world0.pos[ia],
                       world0.pos[ib], vel[ba], vel[bb], ia, ib, dt)
    todo = np.flatnonzero(np.isnan(toi))
    if not len(todo):
        return toi
    sub = subset(cm, np.concatenate([ia[todo], ib[todo]]))
    m = len(todo)
    rows = np.concatenate([ba[todo], bb[todo]])
    w_a, w_b = np.linalg.norm(angvel[ba[todo]], axis=1), np.linalg.norm(angvel[bb[todo]],
                                                                        axis=1)
    # Planes have an infinite bounding radius but never turn: 0 * inf must not be NaN.
    spin = w_a * np.where(w_a > 0, cm.geom_rbound[ia[todo]], 0.0) + \
        w_b * np.where(w_b > 0, cm.geom_rbound[ib[todo]], 0.0)
    mu = linear_rate(cm, ia[todo], ib[todo], vel[ba[todo]], vel[bb[todo]]) + spin
    t = np.zeros(m)
    result = np.full(m, np.inf)
    live = np.arange(m)
    for _ in range(MAX_ITERATIONS):
        tt = np.concatenate([t, t])
        p, q = advance(pos[rows], quat[rows], vel[rows], angvel[rows], tt)
        world = place(sub, p, q)
        d = pair_distance(sub, world, live, live + m)
        hit = d <= tol
        result[live[hit]] = t[live[hit]]
        with np.errstate(divide="ignore"):
            step = np.where(mu[live] > 0.0, d / mu[live], np.inf)
        t_next = t[live] + step
        # A touch exactly at the step's end must not be lost to round-off in d / mu.
        go = ~hit & (t_next <= dt * (1.0 + 1e-12))
        t[live[go]] = np.minimum(t_next[go], dt)
        live = live[go]
        if not len(live):
            break
    toi[todo] = result
    return toi


def swept_contacts(model, before, after, exclude=frozenset(), world_after=None) -> Contacts:
    """Contacts at the time of impact of pairs that touch during the step from `before` to
    `after` but not at its end (pairs of bodies in `exclude` are skipped). `world_after`:
    the geoms already placed at `after`, if the caller has them."""
    cm = model.collision
    dt = after.t - before.t
    if cm is None or cm.n_geom == 0 or dt <= 0.0:
        return Contacts.empty()
    vel, angvel = motion(before, after, dt)
    w0 = place(cm, before.body_pos, before.body_quat)
    w1 = place(cm, after.body_pos, after.body_quat) if world_after is None else world_after
    (lo0, hi0), (lo1, hi1) = aabbs(cm, w0), aabbs(cm, w1)
    lo, hi = np.minimum(lo0, lo1), np.maximum(hi0, hi1)
    spins = np.linalg.norm(angvel[cm.geom_body], axis=1) > 0.0
    spins &= np.isfinite(cm.geom_rbound)
    if spins.any():  # a turning body sweeps at most the ball of its bounding radius
        b = cm.geom_body[spins]
        r = cm.geom_rbound[spins, None]
        lo[spins] = np.minimum(before.body_pos[b], after.body_pos[b]) - r
        hi[spins] = np.maximum(before.body_pos[b], after.body_pos[b]) + r
    ia, ib = broad_phase(model, lo, hi, after.step)
    body_pairs = list(zip(cm.geom_body[ia].tolist(), cm.geom_body[ib].tolist()))
    fresh = np.array([(min(p), max(p)) not in exclude for p in body_pairs], bool)
    ia, ib = ia[fresh], ib[fresh]
    if not len(ia):
        return Contacts.empty()
    toi = time_of_impact(cm, before.body_pos, before.body_quat, vel, angvel, ia, ib, dt)
    hit = np.isfinite(toi)
    ia, ib, toi = ia[hit], ib[hit], toi[hit]
    if not len(ia):
        return Contacts.empty()
    sub = subset(cm, np.concatenate([ia, ib]))
    rows = np.concatenate([cm.geom_body[ia], cm.geom_body[ib]])
    p, q = advance(before.body_pos[rows], before.body_quat[rows], vel[rows], angvel[rows],
                   np.concatenate([toi, toi]))
    world = place(sub, p, q)
    k = len(ia)
    pair, point, normal, depth = narrow_phase(sub, world, np.arange(k), np.arange(k) + k,
                                              cm.tolerance)
    return to_contacts(cm, ia, ib, pair, point, normal, depth, toi[pair])


def first_mesh_contacts(cm, body_pos, body_quat, body_vel, body_angvel, ia, ib,
                        window: float):
    """Speculative contacts of pairs (mesh ia, sphere, capsule or box ib) (P,) for a step
    of stepped impacts, which solves every contact at the step's start: per pair, the
    triangles touching now (within the tolerance) and the ones the body reaches *first*
    moving on (linear velocity, constant angular velocity) within `window` s, at their
    time of impact (conservative advancement per triangle), moved back to the start:
    the point with the body, the depth by what the approach closes until the impact
    (depth(toi) + v_n toi, a gap that the contact's approach speed closes exactly at
    the impact). Contacts at the start with every triangle within the body's reach made
    a fast ball bounce off a neighbouring face of a convex mesh it never reached (the
    impact law was off by 10 %). Returns (pair, point, normal, depth) as a pair
    function (normals from the mesh)."""
    from vrsim_cli.stages.collision import mesh_pairs
    from vrsim_cli.stages.collision.contacts import no_pair_contacts

    tol = cm.tolerance
    ia, ib = np.asarray(ia, np.int64), np.asarray(ib, np.int64)
    pos, quat = np.asarray(body_pos, float), np.asarray(body_quat, float)
    vel, angvel = np.asarray(body_vel, float), np.asarray(body_angvel, float)
    ba, bb = cm.geom_body[ia], cm.geom_body[ib]
    w_a, w_b = np.linalg.norm(angvel[ba], axis=1), np.linalg.norm(angvel[bb], axis=1)
    mu = np.linalg.norm(vel[bb] - vel[ba], axis=1) + w_a * cm.geom_rbound[ia] + \
        w_b * cm.geom_rbound[ib]
    _, (pair, tri, corners, tnormal) = mesh_pairs.rows_near(
        cm, place(cm, pos, quat), ia, ib, float((mu * window).max(initial=0.0)) + tol)
    R = len(pair)
    if not R:
        return no_pair_contacts()
    sub = subset(cm, np.concatenate([ia[pair], ib[pair]]))
    rows = np.concatenate([ba[pair], bb[pair]])
    own = np.arange(R)

    def local_at(t, live):
        p, q = advance(pos[rows], quat[rows], vel[rows], angvel[rows], np.concatenate([t, t]))
        world = place(sub, p, q)
        return world, mesh_pairs._Local(sub, world, own[live], R + own[live])

    t, toi, live = np.zeros(R), np.full(R, np.inf), own.copy()
    for _ in range(MAX_ITERATIONS):
        _, local = local_at(t, live)
        g = mesh_pairs.row_gaps(sub, local, R + own[live], np.arange(len(live)), tri[live],
                                corners[live], tnormal[live])
        hit = g <= tol
        toi[live[hit]] = t[live[hit]]
        with np.errstate(divide="ignore"):
            step = np.where(mu[pair[live]] > 0.0, g / mu[pair[live]], np.inf)
        go = ~hit & (t[live] + step <= window)
        t[live[go]] = t[live[go]] + step[go]
        live = live[go]
        if not len(live):
            break
    first = np.full(len(ia), np.inf)
    ahead = np.flatnonzero((toi > 0.0) & np.isfinite(toi))
    np.minimum.at(first, pair[ahead], toi[ahead])
    with np.errstate(divide="ignore", invalid="ignore"):
        soon = first + np.where(mu > 0.0, 2.0 * tol / mu, 0.0)
    keep = np.flatnonzero((toi == 0.0) | (np.isfinite(toi) & (toi <= soon[pair])))
    if not len(keep):
        return no_pair_contacts()
    k = len(keep)
    sub = subset(cm, np.concatenate([ia[pair[keep]], ib[pair[keep]]]))
    rows = np.concatenate([ba[pair[keep]], bb[pair[keep]]])
    at = np.concatenate([toi[keep], toi[keep]])
    p, q = advance(pos[rows], quat[rows], vel[rows], angvel[rows], at)
    c_pair, point, normal, depth = mesh_pairs.row_contacts(
        sub, place(sub, p, q), np.arange(k), np.arange(k) + k, tri[keep], tol)
    if not len(c_pair):
        return no_pair_contacts()
    when = toi[keep][c_pair]
    a, b = ba[pair[keep]][c_pair], bb[pair[keep]][c_pair]
    xa, xb = p[c_pair], p[k + c_pair]
    rel = vel[b] + np.cross(angvel[b], point - xb) - vel[a] - np.cross(angvel[a], point - xa)
    v_n = np.einsum("ki,ki->k", rel, normal)
    out = [(pair[keep][c_pair], point - (xb - pos[b]), normal,
            depth + np.minimum(v_n, 0.0) * when)]
    # Boxes and capsules turn about the point they hit: their other corners or end meet
    # the face within the step. The face's contacts at the start (along its normal, as
    # an analytic face's manifold) hold them; spheres do not turn onto anything else.
    solid = np.flatnonzero(cm.geom_type[ib[pair[keep]]] != SPHERE)
    if len(solid):
        rows = np.concatenate([ba[pair[keep][solid]], bb[pair[keep][solid]]])
        sub = subset(cm, np.concatenate([ia[pair[keep][solid]], ib[pair[keep][solid]]]))
        m = len(solid)
        world = place(sub, pos[rows], quat[rows])
        s_pair, s_point, s_normal, s_depth = mesh_pairs.row_contacts(
            sub, world, np.arange(m), np.arange(m) + m, tri[keep][solid],
            float((mu * window).max(initial=0.0)) + tol)
        face = mesh_pairs.triangles_of(sub, np.arange(m), s_pair, tri[keep][solid][s_pair])[1]
        face = np.einsum("kij,kj->ki", world.rot[s_pair], face)  # the mesh's frame -> world
        ok = np.abs(np.einsum("ki,ki->k", s_normal, face)) >= 1.0 - 1e-9
        out.append((pair[keep][solid][s_pair][ok], s_point[ok], s_normal[ok], s_depth[ok]))
    out = tuple(np.concatenate(x) for x in zip(*out))
    one = mesh_pairs.once(out[0], out[1], out[2])  # two rows touching one edge
    return tuple(x[one] for x in out)
