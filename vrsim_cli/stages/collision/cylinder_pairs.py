"""Contact manifolds of the pairs fcl gives one point: a box and a cylinder, two
cylinders, and a convex hull against a box, a cylinder, a hull or a capsule.

python-fcl (GJK/EPA, `fcl_adapter`) finds such a pair's deepest point and normal, and
nothing else: a cylinder standing on a box, a box on a cylinder's cap or cylinders end
on end rested on that one point and rocked (a 1 kg box on a cylinder at 1 rad/s for
seconds). Here fcl's normal picks the features that face each other (Box2D's and ODE's
reference-face clipping, as `narrowphase.box_box`):

- a box face: the face whose normal is closest to the direction;
- a cylinder cap: a disc, as 8 points of its rim at 45 deg steps;
- a cylinder side: the segment of the side nearest along the direction.

When a box face or a cap lies across the normal (within ALIGN_COS, ~0.01 rad) it is the
reference face: the normal becomes its normal exactly, the other shape's facing feature
(face, cap or side segment) is clipped to its side planes, and every clipped point gets
its own depth below the reference plane. A tilted cap (beyond ALIGN_COS) starts its rim
polygon at its lowest rim point, so that point is exact (as `narrowphase.plane_cylinder`),
and keeps the deepest and best spread KEEP points. A cap lying nearly flat on the other
face, and a reference cap, keep their rim polygon fixed in the body (at the local x) and
all their points; a flat incident cap adds its exact lowest rim point. (Turned with the
tilt's direction, which changes with every wobble, the points went round the rim from
step to step: stepped mode's warm start, which matches contacts by their rank in the
pair, then kept a box on a cylinder jittering at ~5e-3 rad/s.) The contact area of a flat
cap is the octagon inscribed in its disc (reach r cos(pi / 8) = 0.924 r in its worst
direction). Two cylinders lying side by side (parallel axes) touch along a line: its two
ends. Anything else (an edge on a rim, crossed sides, a rim on a rim) keeps fcl's
contacts, as before.

A convex hull's faces are its facets (`maths.polytope.facets`: coplanar triangles merged
into one polygon; a hull read from a file is triangles, and a box resting on a hull
rested on one triangle's corner). Its candidate axes are its facet normals as they are
(a hull is not symmetric), its reach along a direction its farthest vertex, and a
capsule facing a reference face offers its core segment moved by its radius towards
it (the capsule's farthest points along that direction, each over its core point). On
3235969 a box on a hull, a hull on a box and a hull on a hull moved 2-6 cm and spun up
to 11 m/s in 1 s (an independent review); `tests/test_hull_stacks.py`.

fcl is not trusted where shapes touch: it misses them now and then, and its probe for
them (`fcl_adapter._touching`) can answer with a normal across a face (a can resting on
a wide box 2.5 m from its centre got (-0.70, -0.10, -0.70)). So the faces' separating
axis (`face_axis`: a box's three axes, a cylinder's axis, the one along which the two
are farthest apart) is computed too, and wins when fcl found nothing or when it
separates the two at least as far as fcl's normal does (`separation`, exact for boxes
and cylinders; no direction separates two convex shapes more than the contact normal).
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.maths.polytope import Facets, facets
from vrsim_cli.maths.products import dot, matmul
from vrsim_cli.model.collision import BOX, CAPSULE, CONVEX, CYLINDER
from vrsim_cli.stages.collision import fcl_adapter
from vrsim_cli.stages.collision.contacts import no_pair_contacts, reduce_manifold

KEEP = 4  # contacts kept of a tilted cap or a face (as box_box and plane_cylinder)
# ... and of a pair with a hull: its faces may have more corners than 4, and 4 of a
# hexagon picked by farthest points can leave the centre of mass outside them (a hull
# resting 45 mm inside its 6-cornered base rocked and walked 0.5 mm/s on a static box;
# a tumbling prism's sixth cap corner, left out, sank 2.3 mm in stepped mode); also the
# corners kept of a hull's face lying flat on a plane (narrowphase.plane_vertices)
HULL_KEEP = 8
ALIGN_COS = 1.0 - 5e-5  # a face within ~0.01 rad of the normal is the reference face
PARALLEL_COS = 1.0 - 1e-12  # axes this close are parallel (two lying cylinders)
TIE_TOL = 1e-9  # m: depths this close are equal when picking the points to keep
SAT_TOL = 1e-9  # of 1 m + the gap: separations this close along two axes are equal
CAP_COS = math.sqrt(0.5)  # a cylinder faces a direction with its cap when |axis . d| >= this
# fcl's deepest point lying deeper than the clipped manifold's by more than this (m, plus
# DEPTH_SHARE of the depth) is not on the face pair: fcl's contacts stay
DEPTH_TOL, DEPTH_SHARE = 1e-6, 1e-3


def box_cylinder(cm, world, ia, ib, margin):
    """Box ia against cylinder ib (narrowphase's signature: normals from ia to ib)."""
    return _pairs(cm, world, ia, ib, margin)


def cylinder_cylinder(cm, world, ia, ib, margin):
    """Cylinder ia against cylinder ib."""
    return _pairs(cm, world, ia, ib, margin)


def hull_pairs(cm, world, ia, ib, margin):
    """A convex hull ia against a box, a cylinder, a hull or a capsule ib (the module
    docstring: a hull's facets are its faces)."""
    return _pairs(cm, world, ia, ib, margin)


def cylinder_capsule(cm, world, ia, ib, margin):
    """Cylinder ia against capsule ib. fcl gives one point: a capsule lying on a cap
    (a pen on a can) then rested on one end of its line of contact, turned about it,
    and gained energy in every mode (an independent review: 3.7 rad/s after 1 s; up to
    1.6e3 m/s in stacks). Where fcl's normal is the cap's and the capsule's axis lies in
    the cap's plane (`_capsule_on_cap`), the two ends of its core segment within the
    cap's disc are the contacts instead; elsewhere fcl's."""
    pair, point, normal, depth = fcl_adapter.pair_contacts(cm, world, ia, ib, margin)
    out = []
    for p in range(len(ia)):
        rows = np.flatnonzero(pair == p)
        got = None
        if len(rows):
            deepest = rows[int(np.argmax(depth[rows]))]
            got = _capsule_on_cap(cm, world, int(ia[p]), int(ib[p]),
                                  np.asarray(normal[deepest], float), float(depth[deepest]),
                                  margin)
        out.append(_rows_or(got, p, pair[rows], point[rows], normal[rows], depth[rows]))
    return _joined(out)


def _rows_or(got, p, pair, point, normal, depth):
    """Pair p's contacts: the manifold `got` (points, normal, depths) if one was made,
    else fcl's rows."""
    if got is None:
        return pair, point, normal, depth
    pts, n, d = got
    return np.full(len(d), p), pts, np.repeat(n[None], len(d), axis=0), d


def _joined(out):
    if not out:
        return no_pair_contacts()
    return tuple(np.concatenate(x) for x in zip(*out))


def _capsule_on_cap(cm, world, a, b, n0, depth0, margin):
    """Capsule b lying on cylinder a's cap (n0 from a to b within ~0.01 rad of a's axis,
    b's axis within ~0.01 rad of the cap's plane): its core segment clipped to the cap's
    disc, each end at its depth below the cap (the capsule's radius under the segment),
    or None."""
    axis = world.rot[a][:, 1]
    along = dot(axis, n0)
    if abs(along) < ALIGN_COS:
        return None
    nf = axis if along > 0.0 else -axis  # the cap's outward normal, towards b
    u = world.rot[b][:, 1]
    if abs(dot(u, nf)) > 0.01:
        return None  # standing or tilted: fcl's point
    centre = world.pos[a] + world.half[a][1] * nf  # the cap's centre
    hb, rb, ra = world.half[b][1], float(cm.geom_radius[b]), float(cm.geom_radius[a])
    p0 = world.pos[b] - hb * u
    # |radial(p0 + t u)|^2 <= ra^2 on t in [0, 2 hb]: a quadratic in t
    w0 = p0 - centre
    w0 = w0 - dot(w0, nf) * nf
    ut = u - dot(u, nf) * nf
    qa, qb, qc = dot(ut, ut), 2.0 * dot(w0, ut), dot(w0, w0) - ra * ra
    disc = qb * qb - 4.0 * qa * qc
    if not qa > 0.0 or disc <= 0.0:
        return None
    root = math.sqrt(disc)
    lo, hi = max((-qb - root) / (2.0 * qa), 0.0), min((-qb + root) / (2.0 * qa), 2.0 * hb)
    if not hi > lo:
        return None
    ends = np.array([p0 + lo * u, p0 + hi * u]) - rb * nf  # the capsule's underside
    depth = dot(nf, centre) - matmul(ends, nf)
    return _finish(ends, depth, nf, 1.0, depth0, margin, keep=2)


def _pairs(cm, world, ia, ib, margin):
    pair, point, normal, depth = fcl_adapter.pair_contacts(cm, world, ia, ib, margin)
    out = []
    for p in range(len(ia)):
        a, b = int(ia[p]), int(ib[p])
        rows = np.flatnonzero(pair == p)
        axis, gap = face_axis(cm, world, a, b)
        got = None
        face_wins = True
        if len(rows):
            deepest = rows[int(np.argmax(depth[rows]))]
            n0 = np.asarray(normal[deepest], float)
            face_wins = gap >= separation(cm, world, a, b, n0) - SAT_TOL * (1.0 + abs(gap))
            if not face_wins:
                got = manifold(cm, world, a, b, n0, float(depth[deepest]), margin)
        # fcl saw nothing within the margin, or its normal separates the two less than a
        # face's does: shapes that touch, where fcl misses them (a cylinder resting on a
        # box's face fell for a step every few steps and crept down a slope) or its
        # probe returns a normal across the face (a can sliding on a wide box, 2.5 m
        # from its centre, was stopped sideways and spun at 2 rad/s in stepped mode):
        # the faces' own separating axis decides, as in box_box
        if got is None and face_wins and gap <= margin:
            got = manifold(cm, world, a, b, axis, -gap, margin)
        out.append(_rows_or(got, p, pair[rows], point[rows], normal[rows], depth[rows]))
    return _joined(out)


def world_vertices(cm, world, g):
    """The vertices (k, 3) of hull or mesh geom g where `world` puts it."""
    return world.pos[g] + matmul(cm.geom_vertices[g], world.rot[g].T)


def hull(cm, g) -> Facets:
    """The facets of convex hull geom g (cached by its vertex array, as fcl's geometry)."""
    key = ("facets", id(cm.geom_vertices[g]))
    if key not in cm.cache:
        cm.cache[key] = facets(cm.geom_vertices[g], cm.geom_faces[g])
    return cm.cache[key]


def separation(cm, world, a, b, d):
    """How far apart (m; negative: overlapping) geoms a and b are along unit direction d
    (from a to b): the gap between their projections, exact for these shapes. No
    direction separates them more than the contact normal does (the separating-axis
    theorem for convex shapes)."""
    return float(_separations(cm, world, a, b, np.asarray(d, float)[None])[0])


def _face_normals(cm, world, g, centre):
    """The candidate separating directions of geom g's faces, from g towards the other
    geom (`centre`: from g's centre to the other's): a box's three axes and a cylinder's
    axis, turned towards it; a hull's facet normals as they are (a hull is not
    symmetric: its face at -n is another face); none for a capsule."""
    R = world.rot[g]
    kind = cm.geom_type[g]
    if kind == CONVEX:
        return list(matmul(hull(cm, g).normals, R.T))
    if kind == CAPSULE:
        return []
    axes = (R[:, 0], R[:, 1], R[:, 2]) if kind == BOX else (R[:, 1],)
    return [axis if dot(axis, centre) >= 0.0 else -axis for axis in axes]


def face_axis(cm, world, a, b):
    """Of the face normals of geoms a and b (a box's three axes, a cylinder's axis, a
    hull's facet normals), the one along which the two are farthest apart (the
    separating-axis test over faces; of axes within ALIGN_COS of each other or equal to
    SAT_TOL the first, a's before b's): (unit normal from a to b, separation m; negative:
    overlap)."""
    centre = world.pos[b] - world.pos[a]
    best, best_gap = None, -np.inf
    for g, sign in ((a, 1.0), (b, -1.0)):
        dirs = [sign * d for d in _face_normals(cm, world, g, sign * centre)]  # a to b
        rows = np.array(dirs).reshape(-1, 3)
        gaps = _separations(cm, world, a, b, rows).tolist()  # a hull's facets at once
        for d, gap, (x, y, z) in zip(dirs, gaps, rows.tolist()):
            # of two axes within ALIGN_COS of each other, the first (a's): two nearly
            # parallel caps swapped the normal with every wobble, and stepped mode's warm
            # start, by rank, left a cylinder on a cylinder jittering. Only axes along
            # the same direction: a hull's facet normals are not turned towards the
            # other body, and its face pointing away, tried first, made the opposite
            # one, which separated the two, count as "parallel" (a hull 2 mm above a
            # static box got four contacts 0.28 m deep and fell through it: a review)
            if best is not None and x * bx + y * by + z * bz >= ALIGN_COS:
                continue
            if best is None or gap > best_gap + SAT_TOL * (1.0 + abs(best_gap)):
                best, best_gap, (bx, by, bz) = d, gap, (x, y, z)
    return best, best_gap


def _separations(cm, world, a, b, D):
    """`separation` along each row of D (k, 3) (unit, from a to b) at once: a hull's
    facets are hundreds (an icosphere's 1280 took 45 ms per pair and step one by one)."""
    return matmul(D, world.pos[b] - world.pos[a]) - _supports(cm, world, a, D) - \
        _supports(cm, world, b, -D)


def _supports(cm, world, g, D):
    """How far (m) geom g (box, cylinder, capsule or hull) reaches from its centre along
    each unit row d of D (k, 3): max over its points x of d . (x - centre)."""
    R = world.rot[g]
    kind = cm.geom_type[g]
    local = matmul(D, R)  # rows: R^T d
    if kind == BOX:
        return matmul(np.abs(local), world.half[g])
    if kind == CONVEX:
        return matmul(np.asarray(cm.geom_vertices[g], float), local.T).max(axis=0)
    along = np.abs(local[:, 1])
    if kind == CAPSULE:
        return world.half[g][1] * along + cm.geom_radius[g]
    return world.half[g][1] * along + cm.geom_radius[g] * np.sqrt(
        np.maximum(0.0, 1.0 - along * along))


# ----------------------------------------------------------------------------- features


def _face(cm, world, g, d):
    """The face of geom g (a box face, a cylinder cap) facing direction d (unit, world):
    (outward normal, vertices (m, 3) in cyclic order, |normal . d|), or None for a
    cylinder whose cap does not face d."""
    c, R = world.pos[g], world.rot[g]
    kind = cm.geom_type[g]
    if kind == CONVEX:  # the facet most along d (within ALIGN_COS it is the face)
        f = hull(cm, g)
        along = matmul(f.normals, matmul(R.T, d))
        k = int(np.argmax(along))
        verts = c + matmul(np.asarray(cm.geom_vertices[g], float)[f.loops[k]], R.T)
        return matmul(R, f.normals[k]), verts, float(along[k])
    if kind == CAPSULE:
        return None
    if kind == BOX:
        local = matmul(R.T, d)
        k = int(np.argmax(np.abs(local)))
        s = 1.0 if local[k] >= 0.0 else -1.0
        nf = s * R[:, k]
        u, v = R[:, (k + 1) % 3], R[:, (k + 2) % 3]
        h = world.half[g]
        hu, hv = h[(k + 1) % 3], h[(k + 2) % 3]
        centre = c + nf * h[k]
        signs = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))
        return nf, np.array([centre + a * hu * u + b * hv * v for a, b in signs]), abs(local[k])
    axis = R[:, 1]
    along = dot(axis, d)
    if abs(along) < CAP_COS:
        return None
    nf = axis if along >= 0.0 else -axis
    centre = c + nf * world.half[g][1]
    return nf, _rim(centre, nf, R, d, cm.geom_radius[g]), abs(along)


def _radial(R, d):
    """The unit direction of d across the cylinder's axis (its local x when d lies
    along the axis)."""
    axis = R[:, 1]
    radial = d - dot(axis, d) * axis
    length = math.sqrt(dot(radial, radial))
    return radial / length if length > 1e-9 else R[:, 0]


def _rim(centre, nf, R, d, r):
    """The 8 rim points of the cap at `centre` (normal nf) at 45 deg steps, the first
    the deepest along d."""
    u = _radial(R, d)
    w = np.cross(nf, u)
    return centre + r * (_RIM[:, :1] * u + _RIM[:, 1:] * w)


_C45 = math.sqrt(0.5)
_RIM = np.array([(1.0, 0.0), (_C45, _C45), (0.0, 1.0), (-_C45, _C45), (-1.0, 0.0),
                 (-_C45, -_C45), (0.0, -1.0), (_C45, -_C45)])  # cos, sin: cyclic


def _incident(cm, world, g, d):
    """The feature of geom g facing direction d: a box face or a cap (polygon, closed)
    or a cylinder's side segment (open). Returns (points (m, 3), closed)."""
    face = _face(cm, world, g, d)
    if face is not None:
        return face[1], True
    c, R = world.pos[g], world.rot[g]
    axis, h = R[:, 1], world.half[g][1]
    if cm.geom_type[g] == CAPSULE:
        # its core segment moved by r along d: each point the capsule's farthest along
        # d over that core point (exact at the ends when it tilts)
        line = c + cm.geom_radius[g] * d
        return np.array([line - h * axis, line + h * axis]), False
    line = c + cm.geom_radius[g] * _radial(R, d)
    return np.array([line - h * axis, line + h * axis]), False


# ----------------------------------------------------------------------------- clipping


def _clip(points, closed, planes):
    """Sutherland-Hodgman: the part of a convex polygon (closed) or a segment (open, 2
    points), points (m, 3), on the inner side of every plane (unit normal s, offset o):
    s . x <= o."""
    pts = [np.asarray(p, float) for p in points]
    for s, o in planes:
        if not pts:
            break
        dist = [dot(s, p) - o for p in pts]
        if not closed:  # a segment: keep its inner part
            (p, q), (dp, dq) = pts, dist
            if dp > 0.0 and dq > 0.0:
                return []
            if dp > 0.0:
                pts = [p + (dp / (dp - dq)) * (q - p), q]
            elif dq > 0.0:
                pts = [p, p + (dp / (dp - dq)) * (q - p)]
            continue
        out = []
        for i in range(len(pts)):
            j = (i + 1) % len(pts)
            p, q, dp, dq = pts[i], pts[j], dist[i], dist[j]
            if dp <= 0.0:
                out.append(p)
            if (dp < 0.0 < dq) or (dq < 0.0 < dp):
                out.append(p + (dp / (dp - dq)) * (q - p))
        pts = out
    return pts


def _side_planes(verts, nf):
    """The side planes (outward normal, offset) of a convex face (vertices in cyclic
    order, normal nf): the planes through its edges along nf."""
    centre = verts.mean(axis=0)
    planes = []
    for i in range(len(verts)):
        e = verts[(i + 1) % len(verts)] - verts[i]
        s = np.cross(e, nf)
        length = math.sqrt(dot(s, s))
        if not length > 0.0:
            continue
        s = s / length
        if dot(s, centre - verts[i]) > 0.0:
            s = -s
        planes.append((s, dot(s, verts[i])))
    return planes


def manifold(cm, world, a, b, n0, depth0, margin):
    """The manifold of geoms a and b (box, cylinder, hull; b may be a capsule) around
    fcl's deepest contact (normal n0 from a to b, depth0 m): (points (k, 3), normal
    a -> b, depths (k,)), or None when no face lies across n0 or the deepest point is not
    on the faces' overlap."""
    n0 = np.asarray(n0, float)
    fa, fb = _face(cm, world, a, n0), _face(cm, world, b, -n0)
    ref = None
    if fa is not None and fa[2] >= ALIGN_COS and (fb is None or fa[2] >= fb[2]):
        ref, inc, sign = fa, b, 1.0
    elif fb is not None and fb[2] >= ALIGN_COS:
        ref, inc, sign = fb, a, -1.0
    if ref is None:
        return _parallel_sides(cm, world, a, b, n0, depth0, margin)
    nf, verts, _ = ref
    keep = HULL_KEEP if CONVEX in (cm.geom_type[a], cm.geom_type[b]) else KEEP
    g_ref = a if sign > 0.0 else b
    if cm.geom_type[g_ref] == CYLINDER:
        # a reference cap's rim polygon fixed in its body (at its local x), not turned
        # with the normal (module docstring); all the corners the other face covers
        verts = _rim(verts.mean(axis=0), nf, world.rot[g_ref], nf, cm.geom_radius[g_ref])
        keep = len(_RIM)
    pts, closed = _incident(cm, world, inc, -nf)
    planes = _side_planes(verts, nf)
    lowest = []
    if cm.geom_type[inc] == CYLINDER and closed and \
            abs(dot(world.rot[inc][:, 1], nf)) >= ALIGN_COS:
        # a cap lying nearly flat on the reference face: its rim polygon fixed in its
        # body too, and its lowest rim point (pts[0]) besides, which the polygon misses
        # by up to r (1 - cos(pi / 8)) sin(tilt)
        R = world.rot[inc]
        if all(dot(s, pts[0]) <= o for s, o in planes):
            lowest = [pts[0]]
        cap = R[:, 1] if dot(R[:, 1], nf) <= 0.0 else -R[:, 1]  # its outward normal
        pts = _rim(pts.mean(axis=0), cap, R, R[:, 1], cm.geom_radius[inc])
        keep = len(_RIM) + 1
    clipped = _clip(pts, closed, planes)
    if cm.geom_type[inc] == CONVEX:
        # and the hull's other vertices over the reference face within the margin: a
        # tumbling hull's vertex on a neighbouring face can reach the face within the
        # step (stepped mode's margin is the step's travel): left out, a prism's corner
        # 2.2 mm above a box sank 2.3 mm, a spinning hull's 37 mm above it 4.4 mm
        v = world_vertices(cm, world, inc)
        over = dot(nf, verts[0]) - matmul(v, nf) >= -margin
        for s_, o_ in planes:
            over &= matmul(v, s_) <= o_
        lowest = lowest + list(v[over])
    if not clipped and not lowest:
        return None
    q = np.array(clipped + lowest)
    depth = dot(nf, verts[0]) - matmul(q, nf)  # how far below the reference plane
    return _finish(q, depth, nf, sign, depth0, margin, keep)


def _finish(q, depth, nf, sign, depth0, margin, keep=KEEP):
    """Points q (k, 3) on the incident surface at `depth` below the reference plane
    (normal nf towards them): the contacts (midpoints) within margin, at most `keep` of
    them (`reduce_manifold`); None when none is, or when fcl's deepest is clearly deeper
    than them."""
    near = depth >= -margin
    if not near.any() or depth.max() < depth0 - DEPTH_TOL - DEPTH_SHARE * abs(depth0):
        return None
    q, depth = q[near], depth[near]
    # points as deep as the deepest to TIE_TOL count as equally deep, so the first of
    # them starts the reduction (round-off does not pick another subset every step)
    ties = np.where(depth >= depth.max() - TIE_TOL, depth.max(), depth)
    chosen = reduce_manifold(q, ties, keep)
    q, depth = q[chosen], depth[chosen]
    return q + nf * (0.5 * depth)[:, None], sign * nf, depth


def _parallel_sides(cm, world, a, b, n0, depth0, margin):
    """Two cylinders lying side by side (parallel axes, n0 across them): the two ends of
    the line they touch along, or None."""
    if not (cm.geom_type[a] == CYLINDER and cm.geom_type[b] == CYLINDER):
        return None
    Ra, Rb = world.rot[a], world.rot[b]
    if abs(dot(Ra[:, 1], Rb[:, 1])) < PARALLEL_COS:
        return None
    axis = Ra[:, 1]
    across = world.pos[b] - world.pos[a]
    across = across - dot(across, axis) * axis
    length = math.sqrt(dot(across, across))
    if not length > 0.0 or abs(dot(n0, across)) < ALIGN_COS * length:
        return None
    nf = across / length  # from a's axis to b's, exactly across both
    seg, _ = _incident(cm, world, b, -nf)
    top = world.pos[a] + cm.geom_radius[a] * nf  # a's side line along nf
    ha = world.half[a][1]
    planes = [(axis, dot(axis, top + ha * axis)), (-axis, dot(-axis, top - ha * axis))]
    clipped = _clip(seg, False, planes)
    if not clipped:
        return None
    q = np.array(clipped)
    depth = dot(nf, top) - matmul(q, nf)
    return _finish(q, depth, nf, 1.0, depth0, margin)
