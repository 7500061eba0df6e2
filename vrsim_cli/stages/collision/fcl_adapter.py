"""python-fcl for the pairs without a closed form here: convex hulls (GJK/EPA), triangle
meshes (BVH), cylinders, and any pair involving them. Also the exact distance used by
conservative advancement for such pairs.

fcl is imported inside functions: only scenes that need it pay for it. fcl's contact
normal points from its first object to its second, like ours. Its capsules and cylinders
stand along their local z; ours along y, hence a fixed rotation.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.products import dot, matmul, norm

from vrsim_cli.model.collision import BOX, CAPSULE, CONVEX, CYLINDER, MESH, PLANE, SPHERE
from vrsim_cli.stages.collision.contacts import no_pair_contacts

MAX_CONTACTS = 8  # per pair: enough for a face-on-face mesh contact, bounded output
# Maps fcl's local z (capsule, cylinder axis) to vrsim's local y: a -90 deg turn about x.
Z_TO_Y = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _fcl():
    try:
        import fcl
    except ImportError as exc:  # pragma: no cover - python-fcl is a core dependency
        raise RuntimeError("this collision pair needs the 'python-fcl' package") from exc
    return fcl


def geometry(cm, g: int, half=None):
    """The fcl collision geometry of geom g (cached unless its size changes per step)."""
    fcl = _fcl()
    kind = int(cm.geom_type[g])
    if kind == BOX and cm.geom_world_aabb[g]:
        return fcl.Box(*(2.0 * np.asarray(half)))
    # Hulls and meshes are costly to build: cache them by their vertex array, which
    # subsets of the model share (continuous.py), so the key stays valid.
    key = ("fcl", id(cm.geom_vertices[g])) if kind in (CONVEX, MESH) else None
    if key is not None and key in cm.cache:
        return cm.cache[key]
    r, h = float(cm.geom_radius[g]), float(cm.geom_half[g][1])
    if kind == SPHERE:
        geom = fcl.Sphere(r)
    elif kind == BOX:
        geom = fcl.Box(*(2.0 * cm.geom_half[g]))
    elif kind == CAPSULE:
        geom = fcl.Capsule(r, 2.0 * h)
    elif kind == CYLINDER:
        geom = fcl.Cylinder(r, 2.0 * h)
    elif kind == PLANE:
        geom = fcl.Halfspace(np.asarray(cm.geom_plane_normal[g], float),
                             float(cm.geom_plane_offset[g]))
    elif kind == CONVEX:
        faces = np.asarray(cm.geom_faces[g], np.int64)
        flat = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
        geom = fcl.Convex(np.asarray(cm.geom_vertices[g], float), len(faces), flat)
    elif kind == MESH:
        geom = fcl.BVHModel()
        geom.beginModel(len(cm.geom_vertices[g]), len(cm.geom_faces[g]))
        geom.addSubModel(np.asarray(cm.geom_vertices[g], float),
                         np.asarray(cm.geom_faces[g], np.int64))
        geom.endModel()
    else:  # pragma: no cover - every type is listed above
        raise ValueError(f"no fcl geometry for type {kind}")
    if key is not None:
        cm.cache[key] = geom
    return geom


def collision_object(cm, world, g: int, shift=None):
    """fcl's object of geom g where `world` places it, moved by `shift` (3,) m if given."""
    fcl = _fcl()
    kind = int(cm.geom_type[g])
    move = np.zeros(3) if shift is None else np.asarray(shift, float)
    if kind == PLANE:  # the half-space is already in world coordinates
        return fcl.CollisionObject(geometry(cm, g), fcl.Transform(np.eye(3), move))
    rot = matmul(world.rot[g], Z_TO_Y) if kind in (CAPSULE, CYLINDER) else world.rot[g]
    return fcl.CollisionObject(geometry(cm, g, world.half[g]),
                               fcl.Transform(np.asarray(rot, float),
                                             np.asarray(world.pos[g], float) + move))


def pair_contacts(cm, world, ia, ib, margin):
    """Contacts of candidate pairs (ia, ib) through fcl; same signature as the closed-form
    pair functions. Penetrating pairs: fcl's contacts (GJK/EPA for convex shapes, triangle
    tests for meshes). Separated pairs within the margin: one contact at the closest points."""
    fcl = _fcl()
    request = fcl.CollisionRequest(num_max_contacts=MAX_CONTACTS, enable_contact=True)
    out_pair, out_point, out_normal, out_depth = [], [], [], []

    def emit(p, point, normal, depth):
        out_pair.append(p)
        out_point.append(point)
        out_normal.append(normal)
        out_depth.append(depth)

    for p, (a, b) in enumerate(zip(ia.tolist(), ib.tolist())):
        oa, ob = collision_object(cm, world, a), collision_object(cm, world, b)
        convex = MESH not in (int(cm.geom_type[a]), int(cm.geom_type[b]))
        result = fcl.CollisionResult()
        found = None
        if fcl.collide(oa, ob, request, result):
            # an overlap below the probe's is measured by the probe: libccd's EPA normal
            # there is off by ~1e-16 / depth rad (1.9e-4 rad at 1e-12 m, a box on a
            # cylinder's cap)
            if convex and max(c.penetration_depth for c in result.contacts) < PROBE_STEPS[0]:
                found = _touching(cm, world, a, b, oa, 0.0)
            if found is None:
                for c in result.contacts:
                    normal = np.asarray(c.normal, float)
                    length = norm(normal)
                    emit(p, np.asarray(c.pos, float),
                         normal / length if length > 0 else np.array([0.0, 1, 0]),
                         float(c.penetration_depth))
                continue
        elif margin > 0.0:
            d, pa, pb = distance(oa, ob)
            apart = _separated(d, pa, pb)
            if apart and (d > margin or d >= PROBE_STEPS[0] or not convex):
                if d <= margin:
                    emit(p, 0.5 * (pa + pb), (pb - pa) / norm(pb - pa), -d)
                continue
            # touching, overlapping by less than fcl's collide resolves, or apart by less
            # than its distance resolves: its distance then says -1 (its "in collision")
            # or 0 with NaN points, which were taken for a depth of 1 m and for NaN
            # contacts; and its closest points this close are poor (a capsule's
            # direction off by 0.8 rad at a gap of 1e-12 m)
            found = _touching(cm, world, a, b, oa, d if apart else 0.0)
        if found is not None:
            emit(p, *found)
    if not out_pair:
        return no_pair_contacts()
    return (np.array(out_pair, np.int64), np.array(out_point), np.array(out_normal),
            np.array(out_depth))


def _separated(d, pa, pb) -> bool:
    """fcl's distance result is a gap with its closest points (not its -1 for "in
    collision", nor 0 with NaN points for shapes that exactly touch)."""
    return d > 0.0 and bool(np.isfinite(pa).all() and np.isfinite(pb).all()) and \
        norm(pb - pa) > 0.0


# Probe overlaps (m) of `_touching`, smallest first. fcl's collide (libccd's GJK/EPA)
# misses overlaps of cylinders, capsules and boxes up to ~1e-6 m in random poses (65 % at
# 1e-9 m, 0.5 % at 1e-6 m, none at 1e-4 m: 1000 poses per pair kind, 2026-12-04), and its
# distance's closest points are poor this close (a capsule's direction off by 0.8 rad).
PROBE_STEPS = (1e-4, 3e-4, 1e-3)


def _touching(cm, world, a: int, b: int, oa, gap: float):
    """(point, normal, depth) of geoms a and b that touch or overlap by less than fcl's
    collide sees, or None. b is pushed into a by a probe step s along -u, where collide
    works: to first order its depth is depth + s (n . u), so the depth is that less
    s (n . u) (second order: s^2 / radius of curvature, ~1e-7 m for 0.1 m shapes). u:
    the centres' direction first, then the axes (no plane comes here: every plane pair
    has a closed form); a probe that pushes mostly sideways of the contact normal
    (n . u < 0.5) is not used. `gap` m: what fcl measured apart (0 when it did not);
    steps below 4 gap are skipped."""
    fcl = _fcl()
    centre = world.pos[b] - world.pos[a]
    length = norm(centre)
    probes = [centre / length] if length > 0.0 else []
    probes += [sign * axis for axis in np.eye(3) for sign in (1.0, -1.0)]
    request = fcl.CollisionRequest(num_max_contacts=MAX_CONTACTS, enable_contact=True)
    for step in PROBE_STEPS:
        if step < 4.0 * gap:
            continue
        for u in probes:
            result = fcl.CollisionResult()
            if not fcl.collide(oa, collision_object(cm, world, b, -step * u), request,
                               result):
                continue
            deepest = max(result.contacts, key=lambda c: c.penetration_depth)
            n = np.asarray(deepest.normal, float)
            length = norm(n)
            if not length > 0.0 or dot(n, u) < 0.5 * length:
                continue
            n = n / length
            along = step * dot(n, u)
            return (np.asarray(deepest.pos, float) + 0.5 * step * u, n,
                    float(deepest.penetration_depth) - along)
    return None


def distance(oa, ob):
    """(distance m, closest point on a, on b) of two separated fcl objects; distance <= 0
    when they touch (fcl then reports no meaningful points)."""
    fcl = _fcl()
    result = fcl.DistanceResult()
    d = fcl.distance(oa, ob, fcl.DistanceRequest(enable_nearest_points=True), result)
    pa, pb = (np.asarray(p, float) for p in result.nearest_points)
    return float(d), pa, pb


def pair_distance(cm, world, a: int, b: int) -> float:
    """Signed distance of geoms a and b: the gap when separated, minus fcl's penetration
    depth when they overlap."""
    fcl = _fcl()
    oa, ob = collision_object(cm, world, a), collision_object(cm, world, b)
    d = distance(oa, ob)[0]
    if d > 0.0:
        return d
    result = fcl.CollisionResult()
    fcl.collide(oa, ob, fcl.CollisionRequest(num_max_contacts=MAX_CONTACTS,
                                             enable_contact=True), result)
    return -max((c.penetration_depth for c in result.contacts), default=0.0)
