"""Narrow phase: closed-form contact functions per shape pair, vectorised over pairs, and
the dispatch table keyed by shape-type pair (Box2D's `manifold.c`, one function per pair).

Every pair function has the signature
    f(cm, world, ia, ib, margin) -> (pair (k,), point (k, 3), normal (k, 3), depth (k,))
where ia, ib (P,) are geom indices of P candidate pairs, `pair` says which candidate each
of the k contacts belongs to, normal points from geom ia to geom ib, and only contacts with
depth >= -margin are returned. `point` is the midpoint of the two witness points.
Triangle meshes against spheres, capsules and boxes are in `mesh_pairs`. Pairs without
a closed form here (convex hull, mesh against the others) go to python-fcl
(`fcl_adapter`); box–cylinder and cylinder–cylinder take fcl's deepest point and build a
face manifold around it (`cylinder_pairs`).
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.products import matmul

from vrsim_cli.model.collision import BOX, CAPSULE, CONVEX, CYLINDER, MESH, PLANE, SPHERE
from vrsim_cli.maths.triangles import box_sdf as _box_sdf
from vrsim_cli.maths.triangles import closest_segment_points
from vrsim_cli.stages.collision import cylinder_pairs, fcl_adapter, mesh_pairs
from vrsim_cli.stages.collision.contacts import no_pair_contacts, reduce_manifold

_EPS = 1e-12
_UP = np.array([0.0, 1.0, 0.0])
# Box corners in a fixed order: the signs of the half extents.
_CORNERS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                    dtype=float)
TIE_TOL = 1e-9  # of the boxes' size: separating axes this close are equally shallow
PARALLEL_COS = 1e-9  # face normals closer than this (1 - |cos|) are parallel
GOLDEN_ITERATIONS = 48  # bracket shrinks to 0.618^48 ~ 1e-10 of the capsule's length


def _dot(u, v):
    return np.einsum("...i,...i->...", u, v)


def _unit(v, fallback=_UP):
    """Unit vectors (..., 3) and their lengths; zero vectors become `fallback`."""
    length = np.linalg.norm(v, axis=-1)
    safe = length > _EPS
    out = np.where(safe[..., None], v / np.where(safe, length, 1.0)[..., None], fallback)
    return out, length


def _keep(pair, point, normal, depth, margin):
    mask = depth >= -margin
    return pair[mask], point[mask], normal[mask], depth[mask]


def _spheres(ca, ra, cb, rb):
    """Contact of spheres (ca, ra) and (cb, rb): point, normal A->B, depth (vectorised)."""
    n, dist = _unit(cb - ca)
    depth = ra + rb - dist
    point = ca + n * (ra - 0.5 * depth)[:, None]
    return point, n, depth


def _segment(world, g):
    """End points (P, 3) of the axis segment of capsules g."""
    axis = world.rot[g][:, :, 1] * world.half[g][:, 1:2]
    return world.pos[g] - axis, world.pos[g] + axis


def sphere_sphere(cm, world, ia, ib, margin):
    # Most candidates of a pile are apart: keep by distance first (the same test as
    # _keep's depth >= -margin), then compute contacts for the kept only.
    ra, rb = cm.geom_radius[ia], cm.geom_radius[ib]
    ca, cb = world.pos[ia], world.pos[ib]
    pair = np.flatnonzero(ra + rb - np.linalg.norm(cb - ca, axis=-1) >= -margin)
    point, n, depth = _spheres(ca[pair], ra[pair], cb[pair], rb[pair])
    return pair, point, n, depth


def plane_sphere(cm, world, ia, ib, margin):
    """Half-space n.p <= o (A) and sphere (B): the normal is the plane's outward n."""
    n = cm.geom_plane_normal[ia]
    c, r = world.pos[ib], cm.geom_radius[ib]
    depth = r - (_dot(n, c) - cm.geom_plane_offset[ia])
    point = c - n * (r - 0.5 * depth)[:, None]
    return _keep(np.arange(len(ia)), point, n, depth, margin)


def _box_point(c, rot, half, p, r):
    """Box (c, rot, half) against spheres of radius r at points p (P, 3): point, normal
    box->sphere, depth. Outside: towards the clamped point; inside: out of the nearest face."""
    local = np.einsum("pji,pj->pi", rot, p - c)
    clamped = np.clip(local, -half, half)
    diff, dist = _unit(local - clamped)
    inside = dist <= _EPS
    face_gap = half - np.abs(local)
    axis = np.argmin(face_gap, axis=1)
    rows = np.arange(len(p))
    sign = np.where(local[rows, axis] >= 0.0, 1.0, -1.0)
    n_in = np.zeros_like(local)
    n_in[rows, axis] = sign
    surf_in = local.copy()
    surf_in[rows, axis] = sign * half[rows, axis]
    n_local = np.where(inside[:, None], n_in, diff)
    surface = np.where(inside[:, None], surf_in, clamped)
    depth = r - np.where(inside, -face_gap[rows, axis], dist)
    normal = np.einsum("pij,pj->pi", rot, n_local)
    world_surface = c + np.einsum("pij,pj->pi", rot, surface)
    # Midpoint between the box surface and the sphere's deepest point p - n r.
    point = 0.5 * (world_surface + p - normal * r[:, None])
    return point, normal, depth


def box_sphere(cm, world, ia, ib, margin):
    point, n, depth = _box_point(world.pos[ia], world.rot[ia], world.half[ia], world.pos[ib],
                                 cm.geom_radius[ib])
    return _keep(np.arange(len(ia)), point, n, depth, margin)


def capsule_sphere(cm, world, ia, ib, margin):
    a, b = _segment(world, ia)
    c = world.pos[ib]
    ab = b - a
    t = np.clip(_dot(c - a, ab) / np.maximum(_dot(ab, ab), _EPS), 0.0, 1.0)
    point, n, depth = _spheres(a + t[:, None] * ab, cm.geom_radius[ia], c, cm.geom_radius[ib])
    return _keep(np.arange(len(ia)), point, n, depth, margin)


def cylinder_sphere(cm, world, ia, ib, margin):
    """Cylinder (A, axis along its local y) and sphere (B): in the cylinder's frame the
    problem is 2D in (distance from the axis, height), a rectangle of half sizes (r, h):
    outside, towards the closest point; inside, out of the nearest side or cap."""
    c, rot = world.pos[ia], world.rot[ia]
    r, h = cm.geom_radius[ia], world.half[ia][:, 1]
    local = np.einsum("pji,pj->pi", rot, world.pos[ib] - c)
    radial_vec = local * [1.0, 0.0, 1.0]
    radial_dir, radial = _unit(radial_vec, np.array([1.0, 0.0, 0.0]))
    y = local[:, 1]
    closest = radial_dir * np.minimum(radial, r)[:, None]
    closest[:, 1] = np.clip(y, -h, h)
    diff, dist = _unit(local - closest)
    side_gap, cap_gap = r - radial, h - np.abs(y)
    # inside also where the centre is on the axis to within _EPS: there the radial
    # direction is a fallback and `closest` misses the centre by up to 2 radial
    inside = (dist <= _EPS) | ((side_gap >= 0.0) & (cap_gap >= 0.0))
    to_side = side_gap <= cap_gap
    sign = np.where(y >= 0.0, 1.0, -1.0)
    n_in = np.where(to_side[:, None], radial_dir, sign[:, None] * _UP)
    surf_in = np.where(to_side[:, None], radial_dir * r[:, None] + y[:, None] * _UP,
                       radial_vec + (sign * h)[:, None] * _UP)
    n_local = np.where(inside[:, None], n_in, diff)
    surface = np.where(inside[:, None], surf_in, closest)
    rs = cm.geom_radius[ib]
    depth = rs - np.where(inside, -np.minimum(side_gap, cap_gap), dist)
    normal = np.einsum("pij,pj->pi", rot, n_local)
    world_surface = c + np.einsum("pij,pj->pi", rot, surface)
    point = 0.5 * (world_surface + world.pos[ib] - normal * rs[:, None])
    return _keep(np.arange(len(ia)), point, normal, depth, margin)


def plane_box(cm, world, ia, ib, margin):
    """Half-space against the 8 box corners; up to the 4 deepest corners within margin."""
    n = cm.geom_plane_normal[ia]
    corners = world.pos[ib][:, None, :] + np.einsum(
        "pij,pkj->pki", world.rot[ib], _CORNERS[None] * world.half[ib][:, None, :])
    depth = cm.geom_plane_offset[ia][:, None] - _dot(n[:, None, :], corners)
    return _deepest(np.arange(len(ia)), corners, depth, n, margin)


def _deepest(pair, points, depth, n, margin, keep: int = 4):
    """The `keep` deepest of candidate points (P, m, 3) below a plane with normal n (P, 3):
    contacts at the midpoint between each point and the plane."""
    order = np.argsort(-depth, axis=1, kind="stable")[:, :keep]
    rows = np.arange(len(depth))[:, None]
    depth, points = depth[rows, order], points[rows, order]
    k = order.shape[1]
    mid = points + n[:, None, :] * (0.5 * depth)[..., None]
    return _keep(np.repeat(pair, k), mid.reshape(-1, 3), np.repeat(n, k, axis=0),
                 depth.reshape(-1), margin)


FLAT_COS = cylinder_pairs.ALIGN_COS  # a cap within ~0.01 rad of a plane lies flat on it


def plane_cylinder(cm, world, ia, ib, margin):
    """Half-space against the rims of both caps: on each cap the lowest rim point (along
    -n), its opposite and the two between, so a tilted cylinder gets its single lowest
    rim point. A cap lying flat (within FLAT_COS) gets four rim points fixed in the body
    (at its local x and z) and its lowest rim point besides, all of them: turned with the
    tilt's direction, which changes with every wobble, the points went round the rim from
    step to step, and stepped mode's warm start (by rank in the pair) kept a loaded
    cylinder jittering; kept in candidate order, the ranks stay."""
    flat = np.abs(_dot(cm.geom_plane_normal[ia], world.rot[ib][:, :, 1])) >= FLAT_COS
    tilted = np.flatnonzero(~flat)
    pair, point, normal, depth = _plane_cylinder(cm, world, ia[tilted], ib[tilted], margin)
    out = [(tilted[pair], point, normal, depth),
           _flat_cap(cm, world, ia, ib, np.flatnonzero(flat), margin)]
    pair, point, normal, depth = (np.concatenate(x) for x in zip(*out))
    order = np.argsort(pair, kind="stable")
    return pair[order], point[order], normal[order], depth[order]


def _flat_cap(cm, world, ia, ib, rows, margin):
    """plane_cylinder's contacts of the pairs `rows` whose lower cap lies flat."""
    n = cm.geom_plane_normal[ia[rows]]
    R = world.rot[ib[rows]]
    axis = R[:, :, 1]
    h, r = world.half[ib[rows]][:, 1], cm.geom_radius[ib[rows]]
    s = np.where(_dot(n, axis) > 0.0, -1.0, 1.0)  # the cap whose normal s axis faces -n
    centre = world.pos[ib[rows]] + (s * h)[:, None] * axis
    x, z = R[:, :, 0], R[:, :, 2]
    radial = n - _dot(n, axis)[:, None] * axis
    length = np.linalg.norm(radial, axis=1)
    u = -radial / np.where(length > 1e-9, length, 1.0)[:, None]  # towards -n
    pts = np.stack([x, z, -x, -z, u], axis=1) * r[:, None, None] + centre[:, None, :]
    depth = cm.geom_plane_offset[ia[rows]][:, None] - _dot(n[:, None, :], pts)
    ok = depth >= -margin
    ok[:, 4] &= length > 1e-9  # upright: the lowest point is every rim point
    mid = pts + n[:, None, :] * (0.5 * depth)[..., None]
    pair = np.repeat(rows, 5).reshape(-1, 5)
    return (pair[ok], mid[ok], np.repeat(n[:, None, :], 5, axis=1)[ok], depth[ok])


def _plane_cylinder(cm, world, ia, ib, margin):
    """plane_cylinder's contacts of pairs whose caps do not lie flat."""
    n = cm.geom_plane_normal[ia]
    axis = world.rot[ib][:, :, 1]
    h, r = world.half[ib][:, 1], cm.geom_radius[ib]
    radial = n - _dot(n, axis)[:, None] * axis
    fallback = world.rot[ib][:, :, 0]  # any direction in the cap's plane
    u, _ = _unit(radial, fallback)
    u = np.where((np.linalg.norm(radial, axis=1) > 1e-9)[:, None], u, fallback)
    w = np.cross(axis, u)
    rim = np.stack([-u, u, w, -w], axis=1) * r[:, None, None]  # (P, 4, 3)
    caps = [world.pos[ib] + s * axis * h[:, None] for s in (-1.0, 1.0)]
    points = np.concatenate([c[:, None, :] + rim for c in caps], axis=1)  # (P, 8, 3)
    depth = cm.geom_plane_offset[ia][:, None] - _dot(n[:, None, :], points)
    return _deepest(np.arange(len(ia)), points, depth, n, margin)


def plane_vertices(cm, world, ia, ib, margin):
    """Half-space against the vertices of a convex hull or mesh: the 4 deepest. A hull
    whose face lies flat on the plane (within FLAT_COS) touches it with that face: its
    corners (at most cylinder_pairs.HULL_KEEP of them, well spread, fixed in the body)
    and its deepest vertex besides. (The 4 deepest of a hexagon lying flat were picked
    by round-off, other ones every step, and could all lie on one side of the centre of
    mass: a prism on the ground rocked and slid at 2 mm/s.)"""
    out = []
    for p, (a, b) in enumerate(zip(ia.tolist(), ib.tolist())):
        v = cylinder_pairs.world_vertices(cm, world, b)
        n = cm.geom_plane_normal[a]
        depth = cm.geom_plane_offset[a] - matmul(v, n)
        face = _flat_face(cm, world, b, n) if cm.geom_type[b] == CONVEX else None
        if face is None:
            out.append(_deepest(np.array([p]), v[None], depth[None], n[None], margin))
            continue
        deepest = int(np.argmax(depth))
        if depth[deepest] > depth[face].max() + cylinder_pairs.TIE_TOL:
            face = np.append(face, deepest)
        out.append(_keep(np.full(len(face), p), v[face] + n * (0.5 * depth[face])[:, None],
                         np.repeat(n[None], len(face), axis=0), depth[face], margin))
    if not out:
        return no_pair_contacts()
    return tuple(np.concatenate(x) for x in zip(*out))


def _flat_face(cm, world, g, n):
    """The corners (vertex indices, at most cylinder_pairs.HULL_KEEP, in the face's
    order) of hull g's face lying flat against the plane with normal n (its outward
    normal within FLAT_COS of -n), or None."""
    f = cylinder_pairs.hull(cm, g)
    along = matmul(f.normals, matmul(world.rot[g].T, -np.asarray(n, float)))
    k = int(np.argmax(along))
    if along[k] < FLAT_COS:
        return None
    key = ("flat face", id(cm.geom_vertices[g]), k)
    if key not in cm.cache:
        loop = f.loops[k]
        corners = np.asarray(cm.geom_vertices[g], float)[loop]
        cm.cache[key] = loop[reduce_manifold(corners, np.zeros(len(loop)),
                                              cylinder_pairs.HULL_KEEP)]
    return cm.cache[key]


def plane_capsule(cm, world, ia, ib, margin):
    """Half-space against both end spheres: two points when the capsule lies flat."""
    a, b = _segment(world, ib)
    n = cm.geom_plane_normal[ia]
    r = cm.geom_radius[ib]
    ends = np.stack([a, b], axis=1)  # (P, 2, 3)
    depth = r[:, None] - (_dot(n[:, None, :], ends) - cm.geom_plane_offset[ia][:, None])
    point = ends - n[:, None, :] * (r[:, None] - 0.5 * depth)[..., None]
    pair = np.repeat(np.arange(len(ia)), 2)
    return _keep(pair, point.reshape(-1, 3), np.repeat(n, 2, axis=0), depth.reshape(-1),
                 margin)


PARALLEL_SIN = 1e-3  # capsule axes closer than this (sine of the angle) count as parallel


def _closest_on_segment(p, a, b):
    ab = b - a
    t = np.clip(_dot(p - a, ab) / np.maximum(_dot(ab, ab), _EPS), 0.0, 1.0)
    return a + t[:, None] * ab


def _least_distance_nearly_parallel(a1, b1, a2, b2):
    """The closest points of segments a1b1 and a2b2 whose directions are nearly but not
    exactly parallel: the lines' closest points where both lie inside the segments, else
    the nearest of the four ends to the other segment. The lines' parameters come from
    n = d1 x d2 (s = ((a2 - a1) x d2) . n / |n|^2), not from a e - b^2: that difference
    cancels to eps / sin^2 relative, enough to put crossing axes 1e-8 m apart; the cross
    products keep the distance to ~eps |a2 - a1|. Exactly parallel pairs (n = 0) keep
    the ends' candidates only (the two-point manifold is exact for them). Returns (p1,
    p2, inside): inside where the lines' closest points won (the axes cross between
    their ends), else the least distance is at a segment's end."""
    d1, d2, r = b1 - a1, b2 - a2, a2 - a1
    n = np.cross(d1, d2)
    nn = _dot(n, n)
    safe = np.where(nn > 0.0, nn, 1.0)
    s = _dot(np.cross(r, d2), n) / safe
    t = _dot(np.cross(r, d1), n) / safe
    inside = (nn > 0.0) & (s >= 0.0) & (s <= 1.0) & (t >= 0.0) & (t <= 1.0)
    candidates = [(a1, _closest_on_segment(a1, a2, b2)), (b1, _closest_on_segment(b1, a2, b2)),
                  (_closest_on_segment(a2, a1, b1), a2), (_closest_on_segment(b2, a1, b1), b2),
                  (a1 + s[:, None] * d1, a2 + t[:, None] * d2)]
    dist = np.stack([np.linalg.norm(q - p, axis=1) for p, q in candidates], axis=1)
    dist[:, 4] = np.where(inside, dist[:, 4], np.inf)
    best = np.argmin(dist, axis=1)
    pick = np.arange(len(a1))
    p1 = np.stack([c[0] for c in candidates], axis=1)[pick, best]
    p2 = np.stack([c[1] for c in candidates], axis=1)[pick, best]
    return p1, p2, best == 4


def capsule_capsule(cm, world, ia, ib, margin):
    """Closest points of the two axes, then spheres. Parallel axes that overlap along
    their length (capsules lying side by side) get two contacts, at the two ends of the
    overlap, so that a response can stop them rolling about the contact line; where
    the axes' least distance is deeper than both ends, it replaces the nearer end (at a
    capsule's end) or joins them (axes crossing between the ends)."""
    a1, b1 = _segment(world, ia)
    a2, b2 = _segment(world, ib)
    ra, rb = cm.geom_radius[ia], cm.geom_radius[ib]
    s, t = closest_segment_points(a1, b1, a2, b2)
    point, n, depth = _spheres(a1 + s[:, None] * (b1 - a1), ra, a2 + t[:, None] * (b2 - a2),
                               rb)
    u, length = _unit(b1 - a1)
    parallel = np.linalg.norm(np.cross(u, _unit(b2 - a2)[0]), axis=1) < PARALLEL_SIN
    s_a, s_b = _dot(a2 - a1, u), _dot(b2 - a1, u)  # axis 2's ends along axis 1
    lo = np.maximum(np.minimum(s_a, s_b), 0.0)
    hi = np.minimum(np.maximum(s_a, s_b), length)
    two = parallel & (hi - lo > 1e-9 * (1.0 + length))
    pairs, points, normals, depths = [np.flatnonzero(~two)], [point[~two]], [n[~two]], \
        [depth[~two]]
    if two.any():
        # The ends of the overlap along the bisector of the two axes, and the points of
        # both axes there: the same contacts whichever capsule comes first (measured
        # along axis 1 and projected onto axis 2, a capsule side by side with its mirror
        # image got one contact off the mirror plane)
        ends_depth = []
        a1, b1, a2, b2 = a1[two], b1[two], a2[two], b2[two]
        u2 = _unit(b2 - a2)[0]
        w = _unit(u[two] + np.where(_dot(u[two], u2) >= 0.0, 1.0, -1.0)[:, None] * u2)[0]
        s1, e1, s2, e2 = _dot(a1, w), _dot(b1, w), _dot(a2, w), _dot(b2, w)
        lo = np.maximum(np.minimum(s1, e1), np.minimum(s2, e2))
        hi = np.minimum(np.maximum(s1, e1), np.maximum(s2, e2))
        for end in (lo, hi):
            p1 = a1 + np.clip((end - s1) / (e1 - s1), 0.0, 1.0)[:, None] * (b1 - a1)
            p2 = a2 + np.clip((end - s2) / (e2 - s2), 0.0, 1.0)[:, None] * (b2 - a2)
            q, m, d = _spheres(p1, ra[two], p2, rb[two])
            pairs.append(np.flatnonzero(two))
            points.append(q)
            normals.append(m)
            depths.append(d)
            ends_depth.append(d)
        # Axes not exactly parallel have one least distance. Where it is deeper than both
        # ends (beyond round-off: the depths are r - |p1 - p2| of points of magnitude X,
        # each to a few ulps of X, so two differ by at most ~16 eps X < 1e-13 (1 + X)), it
        # is the manifold's deepest point: at a capsule's end it replaces the overlap's end
        # nearer to it (the two lie within ~theta L of each other: kept both, they were
        # two nearly equal rows with normals theta/2 apart, and an elastic impact gained
        # up to 3e-7 of its energy), and where the axes cross between the ends it joins
        # them as a third contact.
        p1, p2, inside = _least_distance_nearly_parallel(a1, b1, a2, b2)
        q, m, d = _spheres(p1, ra[two], p2, rb[two])
        scale = 1.0 + np.maximum(np.abs(a1).max(axis=1), np.abs(a2).max(axis=1)) \
            + length[two]
        deeper = d > np.maximum(*ends_depth) + 1e-13 * scale
        nearer_hi = np.linalg.norm(q - points[-1], axis=1) < np.linalg.norm(q - points[-2],
                                                                            axis=1)
        for k, side in ((-2, ~nearer_hi), (-1, nearer_hi)):
            swap = deeper & ~inside & side
            points[k] = np.where(swap[:, None], q, points[k])
            normals[k] = np.where(swap[:, None], m, normals[k])
            depths[k] = np.where(swap, d, depths[k])
        third = deeper & inside
        pairs.append(np.flatnonzero(two)[third])
        points.append(q[third])
        normals.append(m[third])
        depths.append(d[third])
    pair = np.concatenate(pairs)
    order = np.argsort(pair, kind="stable")
    return _keep(pair[order], np.concatenate(points)[order], np.concatenate(normals)[order],
                 np.concatenate(depths)[order], margin)


def box_capsule(cm, world, ia, ib, margin):
    """Box (A) and capsule (B). The box's signed distance is convex, so along the capsule's
    axis it has one minimum: a golden-section search finds the deepest axis point, and the
    contact is that of a sphere there. When an end sphere touches the same face (the
    capsule lies on the box, one end as deep as the deepest point) the end points replace
    it: a two-point manifold."""
    c, rot, half = world.pos[ia], world.rot[ia], world.half[ia]
    a, b = _segment(world, ib)
    r = cm.geom_radius[ib]
    la = np.einsum("pji,pj->pi", rot, a - c)
    lb = np.einsum("pji,pj->pi", rot, b - c)
    lo, hi = np.zeros(len(ia)), np.ones(len(ia))
    g = (np.sqrt(5.0) - 1.0) / 2.0
    for _ in range(GOLDEN_ITERATIONS):
        x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
        f1 = _box_sdf(la + x1[:, None] * (lb - la), half)
        f2 = _box_sdf(la + x2[:, None] * (lb - la), half)
        left = f1 <= f2
        hi, lo = np.where(left, x2, hi), np.where(left, lo, x1)
    s = 0.5 * (lo + hi)
    candidates = np.stack([np.zeros_like(s), s, np.ones_like(s)], axis=1)  # (P, 3)
    f = _box_sdf(la[:, None] + candidates[..., None] * (lb - la)[:, None], half[:, None])
    s = candidates[np.arange(len(s)), np.argmin(f, axis=1)]
    p_min = a + s[:, None] * (b - a)
    point, n, depth = _box_point(c, rot, half, p_min, r)
    pe, ne, de = _box_point(np.repeat(c, 2, axis=0), np.repeat(rot, 2, axis=0),
                            np.repeat(half, 2, axis=0), np.stack([a, b], 1).reshape(-1, 3),
                            np.repeat(r, 2))
    same = (_dot(ne, np.repeat(n, 2, axis=0)) > 0.999) & (de >= -margin)
    # Ends replace the deepest point only when one of them is as deep: otherwise the axis
    # dips between them (over an edge) and the deepest point is the contact.
    deepest_end = de.reshape(-1, 2).max(axis=1) >= depth - 1e-12 * (1.0 + np.abs(depth))
    use_ends = same.reshape(-1, 2).all(axis=1) & deepest_end
    pair = np.concatenate([np.flatnonzero(~use_ends), np.repeat(np.flatnonzero(use_ends), 2)])
    take = np.repeat(use_ends, 2)
    return _keep(pair, np.concatenate([point[~use_ends], pe[take]]),
                 np.concatenate([n[~use_ends], ne[take]]),
                 np.concatenate([depth[~use_ends], de[take]]), margin)


# ---------------------------------------------------------------------------- box - box

def _face_points(fc, n, u, v, hu, hv, inc_c, inc_n, inc_u, inc_v, inc_hu, inc_hv):
    """Contact candidates of a reference face (centre fc, outward normal n towards the
    other box, in-plane axes u, v with half sizes hu, hv) and an incident face (centre,
    normal, axes, half sizes). In the reference face's 2D coordinates, the overlap polygon
    of the face rectangle and the projected incident quad has its vertices among: incident
    corners inside the rectangle, rectangle corners inside the quad, and edge crossings.
    Returns points (P, 24, 3) on the incident face, heights above the reference face
    (P, 24) (negative: penetrating) and validity (P, 24)."""
    signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], dtype=float)  # cyclic order
    inc = (inc_c[:, None] + signs[None, :, :1] * (inc_hu[:, None, None] * inc_u[:, None])
           + signs[None, :, 1:] * (inc_hv[:, None, None] * inc_v[:, None]))  # (P, 4, 3)
    rel = inc - fc[:, None]
    qx, qy = _dot(rel, u[:, None]), _dot(rel, v[:, None])  # (P, 4)
    hu_, hv_ = hu[:, None], hv[:, None]
    tol = 1e-9 * (1.0 + np.maximum(hu_, hv_))
    # (a) incident corners inside the rectangle
    ax, ay = qx, qy
    a_ok = (np.abs(qx) <= hu_ + tol) & (np.abs(qy) <= hv_ + tol)
    # (b) rectangle corners inside the incident quad (convex, either winding)
    bx, by = signs[None, :, 0] * hu_, signs[None, :, 1] * hv_
    ex, ey = np.roll(qx, -1, axis=1) - qx, np.roll(qy, -1, axis=1) - qy  # edges (P, 4)
    cross = ex[:, None, :] * (by[:, :, None] - qy[:, None, :]) - \
        ey[:, None, :] * (bx[:, :, None] - qx[:, None, :])  # (P, corner, edge)
    area = (qx * np.roll(qy, -1, axis=1) - np.roll(qx, -1, axis=1) * qy).sum(axis=1)
    wind = np.where(area >= 0.0, 1.0, -1.0)[:, None, None]
    b_ok = (cross * wind >= -tol[..., None] * (np.abs(ex) + np.abs(ey))[:, None, :]).all(2)
    # (c) incident edges crossing the rectangle's edge lines x = +-hu, y = +-hv
    cx, cy, c_ok = [], [], []
    for line, along in ((0, 1), (1, 0)):
        q_line, q_along = (qx, qy) if line == 0 else (qy, qx)
        e_line, e_along = (ex, ey) if line == 0 else (ey, ex)
        h_line, h_along = (hu_, hv_) if line == 0 else (hv_, hu_)
        for side in (-1.0, 1.0):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (side * h_line - q_line) / e_line
            w = q_along + t * e_along
            ok = np.isfinite(t) & (t >= 0) & (t <= 1) & (np.abs(w) <= h_along + tol)
            x = np.broadcast_to(side * h_line, w.shape)
            cx.append(x if line == 0 else w)
            cy.append(w if line == 0 else x)
            c_ok.append(ok)
    px = np.concatenate([ax, bx] + cx, axis=1)  # (P, 24)
    py = np.concatenate([ay, by] + cy, axis=1)
    ok = np.concatenate([a_ok, b_ok] + c_ok, axis=1)
    px, py = np.where(ok, px, 0.0), np.where(ok, py, 0.0)  # no NaN from parallel edges
    # Lift each 2D point onto the incident face's plane along n.
    base = fc[:, None] + px[..., None] * u[:, None] + py[..., None] * v[:, None]
    inc_d = _dot(inc_n, inc_c)
    height = (inc_d[:, None] - _dot(base, inc_n[:, None])) / _dot(inc_n, n)[:, None]
    return base + height[..., None] * n[:, None], height, ok


def _sat(world, ia, ib, hb=None):
    """The 15 separating axes of box pairs (P, 15, 3) (unit; 3 + 3 face normals, 9 edge
    crosses), the centres' distance along them (P, 15) and the overlap of the two
    projections (P, 15) m (inf for the cross of parallel edges: no axis). hb: B's half
    extents (P, 3) if not its geoms' (a segment is a box of half extents (0, l, 0))."""
    A, B = world.rot[ia], world.rot[ib]  # columns: box axes in world
    ha, hb = world.half[ia], (world.half[ib] if hb is None else hb)
    t = world.pos[ib] - world.pos[ia]
    a_axes, b_axes = np.swapaxes(A, 1, 2), np.swapaxes(B, 1, 2)  # rows: the axes
    edges = np.cross(a_axes[:, :, None, :], b_axes[:, None, :, :]).reshape(-1, 9, 3)
    L = np.concatenate([a_axes, b_axes, edges], axis=1)  # (P, 15, 3)
    L, length = _unit(L)
    ra = np.einsum("pk,pkn->pn", ha, np.abs(np.einsum("pik,pni->pkn", A, L)))
    rb = np.einsum("pk,pkn->pn", hb, np.abs(np.einsum("pik,pni->pkn", B, L)))
    dist = _dot(t[:, None, :], L)
    overlap = ra + rb - np.abs(dist)
    overlap[:, 6:][length[:, 6:] < 1e-6] = np.inf  # parallel edges: no axis
    return L, dist, overlap


def box_box_separation(world, ia, ib) -> np.ndarray:
    """(P,) m: the largest separation of box pairs along the 15 axes, <= 0 exactly when
    they touch or overlap (separating-axis theorem), and never more than their distance
    (a projection): a conservative gap, without the contact manifold."""
    return -_sat(world, ia, ib)[2].min(axis=1)


def box_capsule_separation(cm, world, ia, ib) -> np.ndarray:
    """(P,) m: a lower bound on the distance of boxes ia and capsules ib (the boxes'
    separation from the capsules' core segments, minus the radius); cheap, for
    conservative advancement; not 0 exactly at the touch."""
    core = world.half[ib] * np.array([0.0, 1.0, 0.0])
    return -_sat(world, ia, ib, core)[2].min(axis=1) - cm.geom_radius[ib]


def box_box(cm, world, ia, ib, margin):
    """Separating-axis test over the 15 axes (3 + 3 face normals, 9 edge crosses), then a
    contact manifold: face contact -> the overlap of the reference face and the incident
    face (up to 4 points, each with its own depth); edge contact -> the closest points of
    the two edges (1 point), with the shallowest face's manifold points within the margin
    too. Face axes win unless an edge axis is clearly shallower (5 %), as in Box2D and
    ODE, so resting boxes keep a stable face manifold."""
    P = len(ia)
    ca, cb = world.pos[ia], world.pos[ib]
    A, B = world.rot[ia], world.rot[ib]  # columns: box axes in world
    ha, hb = world.half[ia], world.half[ib]
    L, dist, overlap = _sat(world, ia, ib)
    rows = np.arange(P)
    face_a = np.argmin(overlap[:, :3], axis=1)
    face_b = 3 + np.argmin(overlap[:, 3:6], axis=1)
    face = np.where(overlap[rows, face_b] < overlap[rows, face_a], face_b, face_a)
    edge_order = 6 + np.argsort(overlap[:, 6:], axis=1, kind="stable")
    edge, edge2 = edge_order[:, 0], edge_order[:, 1]
    f_ov, e_ov = overlap[rows, face], overlap[rows, edge]
    use_edge = e_ov < f_ov - 0.05 * np.abs(f_ov) - 1e-6
    best = np.where(use_edge, edge, face)
    depth_sat = overlap[rows, best]
    hit = depth_sat >= -margin
    axis_sign = np.where(dist >= 0.0, 1.0, -1.0)[..., None]
    n = L[rows, best] * axis_sign[rows, best]  # A -> B
    # A tie between two axes that are not parallel (a face of A and a face of B, or two
    # edge pairs, equally shallow to TIE_TOL) is not broken by the order of the bodies:
    # both give contacts (a box meeting its mirror image corner to corner touches both
    # face planes; the first body's face alone gave one contact off the mirror plane and
    # an asymmetric impulse). Parallel faces (boxes stacked face to face) clip to the same
    # polygon either way: one is enough.
    tie_tol = TIE_TOL * (1.0 + ha.max(axis=1) + hb.max(axis=1))
    faces_tie = (np.abs(overlap[rows, face_a] - overlap[rows, face_b]) <= tie_tol) & \
        (np.abs(_dot(L[rows, face_a], L[rows, face_b])) < 1.0 - PARALLEL_COS)
    face_tie = ~use_edge & hit & faces_tie
    edge_tie = use_edge & hit & (overlap[rows, edge2] - e_ov <= tie_tol)
    # An edge contact takes the shallowest face's manifold points within the margin (what
    # the pair can close in a step) too: an edge lying across a face (a bar across a
    # table) touches along a segment, and its one edge-edge point at a rim let it rock
    # about that rim (kernels.collide.box_box does the same). Callers asking for the
    # pair's depth alone (margin inf) keep the edge's.
    # (both faces where they tie, as for face contacts: a mirror image's pair)
    near_face = use_edge & hit & np.isfinite(margin)
    near_other = near_face & faces_tie
    other = np.where(face == face_a, face_b, face_a)
    jobs = np.concatenate([rows, rows[face_tie], rows[near_face], rows[near_other]])
    axis = np.concatenate([best, other[face_tie], face[near_face], other[near_other]])
    n_near = int(near_face.sum()) + int(near_other.sum())
    is_face = np.concatenate([~use_edge, np.ones(len(jobs) - P, bool)])
    fallback = np.concatenate([np.ones(len(jobs) - n_near, bool), np.zeros(n_near, bool)])
    job_n = L[jobs, axis] * axis_sign[jobs, axis]
    out = []
    # Face contacts: reference face on A (axes 0-2) or on B (axes 3-5).
    for on_a in (True, False):
        job = np.flatnonzero(hit[jobs] & is_face & ((axis < 3) if on_a else (axis >= 3)))
        if not len(job):
            continue
        sel = jobs[job]
        k = axis[job] % 3
        R_ref, h_ref, c_ref = (A, ha, ca) if on_a else (B, hb, cb)
        R_inc, h_inc, c_inc = (B, hb, cb) if on_a else (A, ha, ca)
        R_ref, h_ref, c_ref = R_ref[sel], h_ref[sel], c_ref[sel]
        R_inc, h_inc, c_inc = R_inc[sel], h_inc[sel], c_inc[sel]
        nj = job_n[job]
        nr = nj if on_a else -nj  # reference face normal, towards the other box
        r = np.arange(len(sel))
        fc = c_ref + nr * h_ref[r, k][:, None]
        u, v = R_ref[r, :, (k + 1) % 3], R_ref[r, :, (k + 2) % 3]
        hu, hv = h_ref[r, (k + 1) % 3], h_ref[r, (k + 2) % 3]
        dots = np.einsum("pik,pi->pk", R_inc, nr)
        m = np.argmax(np.abs(dots), axis=1)
        sign = -np.where(dots[r, m] >= 0.0, 1.0, -1.0)
        inc_n = R_inc[r, :, m] * sign[:, None]
        inc_c = c_inc + inc_n * h_inc[r, m][:, None]
        pts, height, ok = _face_points(
            fc, nr, u, v, hu, hv, inc_c, inc_n, R_inc[r, :, (m + 1) % 3],
            R_inc[r, :, (m + 2) % 3], h_inc[r, (m + 1) % 3], h_inc[r, (m + 2) % 3])
        depth = -height
        ok &= depth >= -margin
        for q in range(len(sel)):
            idx = np.flatnonzero(ok[q])
            if not len(idx):
                if not fallback[job[q]]:
                    continue
                # Apart within the margin with faces that do not overlap side by side:
                # the incident corner nearest to the reference plane, at the axis' gap.
                corner = int(np.argmax(np.where(np.arange(24) < 4, depth[q], -np.inf)))
                mid = pts[q, corner] + nr[q] * (0.5 * depth[q, corner])
                out.append((sel[q:q + 1], mid[None], nj[q][None],
                            overlap[sel[q], axis[job[q]]][None]))
                continue
            chosen = idx[reduce_manifold(pts[q, idx], depth[q, idx])]
            mid = pts[q, chosen] + nr[q] * (0.5 * depth[q, chosen])[:, None]
            out.append((np.full(len(chosen), sel[q]), mid, np.repeat(nj[q][None],
                        len(chosen), axis=0), depth[q, chosen]))
    # Edge contacts: the supporting edges of A (towards B) and of B (towards A).
    sel = np.concatenate([rows[hit & use_edge], rows[edge_tie]])
    e_axis = np.concatenate([best[hit & use_edge], edge2[edge_tie]])
    if len(sel):
        i, j = (e_axis - 6) // 3, (e_axis - 6) % 3
        r = np.arange(len(sel))
        nn = L[sel, e_axis] * axis_sign[sel, e_axis]
        pa = ca[sel].copy()
        pb = cb[sel].copy()
        for k in range(3):
            sa = np.where(_dot(A[sel][:, :, k], nn) >= 0.0, 1.0, -1.0)
            sb = np.where(_dot(B[sel][:, :, k], nn) >= 0.0, -1.0, 1.0)
            pa += np.where((k != i)[:, None], A[sel][:, :, k] * (sa * ha[sel][:, k])[:, None], 0)
            pb += np.where((k != j)[:, None], B[sel][:, :, k] * (sb * hb[sel][:, k])[:, None], 0)
        da = A[sel][r, :, i] * ha[sel][r, i][:, None]
        db = B[sel][r, :, j] * hb[sel][r, j][:, None]
        s, tt = closest_segment_points(pa - da, pa + da, pb - db, pb + db)
        wa = pa - da + (2 * s)[:, None] * da
        wb = pb - db + (2 * tt)[:, None] * db
        out.append((sel, 0.5 * (wa + wb), nn, overlap[sel, e_axis]))
    if not out:
        return no_pair_contacts()
    pair, point, normal, depth = (np.concatenate(x) for x in zip(*out))
    order = np.argsort(pair, kind="stable")
    return pair[order], point[order], normal[order], depth[order]


_EDGES = np.array([(i, j) for i in range(8) for j in range(i + 1, 8)
                   if np.count_nonzero(_CORNERS[i] != _CORNERS[j]) == 1])  # the 12 edges


def box_box_distance(world, ia, ib):
    """Exact distance (P,) m between separated boxes; <= 0 when they touch or overlap.

    The closest points of two convex polyhedra can be taken on a vertex and the other
    solid, or on two edges (faces and parallel edges reach their minimum there too), so
    the distance is the least of: the 16 corners' distances to the other box and the
    144 edge-edge distances. Used by continuous detection; fcl's GJK is not used here
    because it errs in flush configurations (two aligned boxes: 1.118 m for 1.1 m)."""
    ca, cb = world.pos[ia], world.pos[ib]
    A, B = world.rot[ia], world.rot[ib]
    ha, hb = world.half[ia], world.half[ib]
    corners_a = ca[:, None] + np.einsum("pij,pkj->pki", A, _CORNERS[None] * ha[:, None])
    corners_b = cb[:, None] + np.einsum("pij,pkj->pki", B, _CORNERS[None] * hb[:, None])

    def to_box(points, c, rot, half):
        local = np.einsum("pji,pkj->pki", rot, points - c[:, None])
        return _box_sdf(local, half[:, None]).min(axis=1)

    d = np.minimum(to_box(corners_a, cb, B, hb), to_box(corners_b, ca, A, ha))
    p1 = np.repeat(corners_a[:, _EDGES[:, 0]], 12, axis=1)  # (P, 144, 3)
    q1 = np.repeat(corners_a[:, _EDGES[:, 1]], 12, axis=1)
    p2 = np.tile(corners_b[:, _EDGES[:, 0]], (1, 12, 1))
    q2 = np.tile(corners_b[:, _EDGES[:, 1]], (1, 12, 1))
    shape = p1.shape
    s, t = closest_segment_points(*(x.reshape(-1, 3) for x in (p1, q1, p2, q2)))
    gap = (p1.reshape(-1, 3) + s[:, None] * (q1 - p1).reshape(-1, 3)) - \
        (p2.reshape(-1, 3) + t[:, None] * (q2 - p2).reshape(-1, 3))
    d = np.minimum(d, np.linalg.norm(gap, axis=1).reshape(shape[:2]).min(axis=1))
    return d


# Keyed by (type of A, type of B). A pair found as (B, A) is computed swapped and its
# normals are flipped (`detect.narrow_phase`).
DISPATCH = {
    (SPHERE, SPHERE): sphere_sphere,
    (PLANE, SPHERE): plane_sphere,
    (BOX, SPHERE): box_sphere,
    (CAPSULE, SPHERE): capsule_sphere,
    (PLANE, BOX): plane_box,
    (PLANE, CAPSULE): plane_capsule,
    (CAPSULE, CAPSULE): capsule_capsule,
    (BOX, CAPSULE): box_capsule,
    (BOX, BOX): box_box,
    (PLANE, CYLINDER): plane_cylinder,
    (CYLINDER, SPHERE): cylinder_sphere,
    (BOX, CYLINDER): cylinder_pairs.box_cylinder,
    (CYLINDER, CYLINDER): cylinder_pairs.cylinder_cylinder,
    (CYLINDER, CAPSULE): cylinder_pairs.cylinder_capsule,
    (PLANE, CONVEX): plane_vertices,
    (CONVEX, BOX): cylinder_pairs.hull_pairs,
    (CONVEX, CYLINDER): cylinder_pairs.hull_pairs,
    (CONVEX, CONVEX): cylinder_pairs.hull_pairs,
    (CONVEX, CAPSULE): cylinder_pairs.hull_pairs,
    (PLANE, MESH): plane_vertices,
    (MESH, SPHERE): mesh_pairs.mesh_sphere,
    (MESH, CAPSULE): mesh_pairs.mesh_capsule,
    (MESH, BOX): mesh_pairs.mesh_box,
}


def narrow_phase(cm, world, ia, ib, margin: float):
    """Contacts of candidate geom pairs (ia, ib): dispatch by type pair, swap when the
    table has (B, A), fcl when there is no closed form. Returns (pair, point, normal,
    depth) with `pair` indexing the candidates and normals from ia to ib."""
    ta, tb = cm.geom_type[ia], cm.geom_type[ib]
    parts = []
    codes = ta * 16 + tb
    for code in np.unique(codes):
        sel = np.flatnonzero(codes == code)
        key = (int(code) // 16, int(code) % 16)
        if key in DISPATCH:
            pair, point, normal, depth = DISPATCH[key](cm, world, ia[sel], ib[sel], margin)
        elif key[::-1] in DISPATCH:
            pair, point, normal, depth = DISPATCH[key[::-1]](cm, world, ib[sel], ia[sel],
                                                            margin)
            normal = -normal
        else:
            pair, point, normal, depth = fcl_adapter.pair_contacts(cm, world, ia[sel],
                                                                   ib[sel], margin)
        parts.append((sel[pair], point, normal, depth))
    if not parts:
        return no_pair_contacts()
    pair, point, normal, depth = (np.concatenate(x) for x in zip(*parts))
    order = np.argsort(pair, kind="stable")
    return pair[order], point[order], normal[order], depth[order]
