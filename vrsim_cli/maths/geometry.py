"""Exact geometric queries against analytic shapes: signed distance, ray casts, and the
closest approach of a capsule (the observer's body) to a shape.

Layer 0, used by observer navigation (terrain height under the observer, walls).
Shapes are the model's normalised shape dicts (see `model.model._shape`): sphere, box (full edge
lengths), plane (world-frame half-space `n.p <= offset`), capsule and cylinder (along the
body's local y). Poses: position (3,) m and unit quaternion [w, x, y, z].
Meshes are not handled here (they join with the collision-detection issue).
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.maths.products import dot, norm

from vrsim_cli.maths.spatial import quat_conjugate, quat_rotate

ANALYTIC = ("sphere", "box", "plane", "capsule", "cylinder")
GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def _to_local(pos, quat, point):
    return quat_rotate(quat_conjugate(quat), np.asarray(point, dtype=float) - pos)


def _box_sdf(half, p):
    """Signed distance and outward normal of an axis-aligned box of half extents `half`."""
    q = np.abs(p) - half
    outside = np.maximum(q, 0.0)
    out_len = float(norm(outside))
    if out_len > 0.0:
        return out_len, np.sign(p) * outside / out_len
    axis = int(np.argmax(q))
    normal = np.zeros(3)
    normal[axis] = 1.0 if p[axis] >= 0.0 else -1.0
    return float(q[axis]), normal


def _local_sdf(shape: dict, p) -> tuple[float, np.ndarray]:
    """Signed distance and outward normal in the shape's own frame (not for planes)."""
    kind = shape["type"]
    if kind == "sphere":
        r = float(norm(p))
        normal = p / r if r > 0.0 else np.array([0.0, 1.0, 0.0])
        return r - shape["radius"], normal
    if kind == "box":
        return _box_sdf(0.5 * np.asarray(shape["size"], dtype=float), p)
    if kind == "capsule":
        half = 0.5 * shape["length"]
        offset = p - np.array([0.0, min(max(p[1], -half), half), 0.0])
        r = float(norm(offset))
        return r - shape["radius"], (offset / r if r > 0.0 else np.array([1.0, 0.0, 0.0]))
    if kind == "cylinder":
        radial = float(math.hypot(p[0], p[2]))
        # 2D box distance in (radial, |y|) coordinates; the unused axis never binds.
        d2, n2 = _box_sdf(np.array([shape["radius"], 0.5 * shape["length"], math.inf]),
                          np.array([radial, p[1], 0.0]))
        dir_xz = np.array([p[0], 0.0, p[2]]) / radial if radial > 0.0 else np.array([1.0, 0, 0])
        return d2, n2[0] * dir_xz + np.array([0.0, n2[1], 0.0])
    raise ValueError(f"no signed distance for shape '{kind}'")


def local_half_extents(shape: dict) -> np.ndarray:
    """Half extents (3,) of the shape's bounding box in its own frame (not for planes)."""
    kind = shape["type"]
    if kind == "sphere":
        return np.full(3, float(shape["radius"]))
    if kind == "box":
        return 0.5 * np.asarray(shape["size"], dtype=float)
    r, half = float(shape["radius"]), 0.5 * shape["length"]
    return np.array([r, half + (r if kind == "capsule" else 0.0), r])


def signed_distance(shape: dict, pos, quat, point) -> tuple[float, np.ndarray]:
    """(distance m, outward unit normal (3,)) from `point` to the solid; negative inside."""
    if shape["type"] == "plane":
        n = np.asarray(shape["normal"], dtype=float)
        return float(dot(n, point) - shape["offset"]), n
    d, n_local = _local_sdf(shape, _to_local(pos, quat, point))
    return float(d), quat_rotate(quat, n_local)


def _ray_sphere(o, d, centre, r):
    oc = o - centre
    b = float(dot(oc, d))
    c = float(dot(oc, oc)) - r * r
    disc = b * b - c
    if disc < 0.0:
        return None
    t = -b - math.sqrt(disc)
    return t if t >= 0.0 else None


def _ray_slab(o, d, lo, hi):
    """Entry parameter of a ray into the box [lo, hi] (local axes), or None."""
    t_near, t_far = -math.inf, math.inf
    for i in range(3):
        if abs(d[i]) < 1e-300:
            if o[i] < lo[i] or o[i] > hi[i]:
                return None
            continue
        t1, t2 = (lo[i] - o[i]) / d[i], (hi[i] - o[i]) / d[i]
        t_near, t_far = max(t_near, min(t1, t2)), min(t_far, max(t1, t2))
    if t_near > t_far or t_far < 0.0:
        return None
    return t_near


def _ray_cylinder_side(o, d, r, half):
    a = d[0] ** 2 + d[2] ** 2
    if a < 1e-300:
        return None
    b = o[0] * d[0] + o[2] * d[2]
    c = o[0] ** 2 + o[2] ** 2 - r * r
    disc = b * b - a * c
    if disc < 0.0:
        return None
    t = (-b - math.sqrt(disc)) / a
    if t >= 0.0 and abs(o[1] + t * d[1]) <= half:
        return t
    return None


def ray_cast(shape: dict, pos, quat, origin, direction) -> float | None:
    """Distance along the unit `direction` from `origin` to the first point of the solid;
    0 when the origin is inside; None when the ray misses."""
    origin = np.asarray(origin, dtype=float)
    if signed_distance(shape, pos, quat, origin)[0] <= 0.0:
        return 0.0
    kind = shape["type"]
    direction = np.asarray(direction, dtype=float)
    if kind == "plane":
        n = np.asarray(shape["normal"], dtype=float)
        denom = float(dot(n, direction))
        if denom >= 0.0:
            return None
        return (shape["offset"] - float(dot(n, origin))) / denom
    o = _to_local(pos, quat, origin)
    d = quat_rotate(quat_conjugate(quat), direction)
    if kind == "sphere":
        return _ray_sphere(o, d, np.zeros(3), shape["radius"])
    if kind == "box":
        half = 0.5 * np.asarray(shape["size"], dtype=float)
        return _ray_slab(o, d, -half, half)
    r, half = shape["radius"], 0.5 * shape["length"]
    hits = [_ray_cylinder_side(o, d, r, half)]
    if kind == "cylinder":
        for cap in (-half, half):  # the flat ends
            if abs(d[1]) > 1e-300:
                t = (cap - o[1]) / d[1]
                p = o + t * d
                if t >= 0.0 and p[0] ** 2 + p[2] ** 2 <= r * r:
                    hits.append(t)
    else:  # capsule: the two spherical ends
        for cap in (-half, half):
            hits.append(_ray_sphere(o, d, np.array([0.0, cap, 0.0]), r))
    hits = [t for t in hits if t is not None]
    return min(hits) if hits else None


def capsule_distance(shape: dict, pos, quat, a, b, radius: float):
    """Closest approach of the capsule with axis a->b and `radius` to the solid.

    Returns (distance m, normal (3,), closest axis point (3,)); negative distance is the
    penetration depth. For a convex solid the signed distance along a segment is a convex
    function of the segment parameter, so a golden-section search finds its minimum; 64
    iterations shrink the bracket to 0.618^64 ~ 4e-14 of the segment length. A plane's
    distance is linear along the segment, so an end point is closest.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if shape["type"] == "plane":
        da, db = (signed_distance(shape, pos, quat, p)[0] for p in (a, b))
        point = a if da <= db else b
        return min(da, db) - radius, np.asarray(shape["normal"], dtype=float), point
    la, lb = _to_local(pos, quat, a), _to_local(pos, quat, b)
    axis = lb - la
    length2 = float(dot(axis, axis))

    def f(s):
        return _local_sdf(shape, la + s * axis)[0]

    s_best = 0.0
    if length2 > 0.0:
        lo, hi = 0.0, 1.0
        x1, x2 = hi - GOLDEN * (hi - lo), lo + GOLDEN * (hi - lo)
        f1, f2 = f(x1), f(x2)
        for _ in range(64):
            if f1 <= f2:
                hi, x2, f2 = x2, x1, f1
                x1 = hi - GOLDEN * (hi - lo)
                f1 = f(x1)
            else:
                lo, x1, f1 = x1, x2, f2
                x2 = lo + GOLDEN * (hi - lo)
                f2 = f(x2)
        s_best = min((f(0.0), 0.0), (f(1.0), 1.0), (f(0.5 * (lo + hi)), 0.5 * (lo + hi)))[1]
    d, n_local = _local_sdf(shape, la + s_best * axis)
    return float(d) - radius, quat_rotate(quat, n_local), a + s_best * (b - a)


def capsule_overlaps_bounds(shape: dict, pos, quat, a, b, radius: float) -> bool:
    """Cheap test: do the capsule's and the shape's bounding boxes (in the shape's frame)
    overlap? False means the capsule certainly does not touch the shape."""
    if shape["type"] == "plane":
        return True
    la, lb = _to_local(pos, quat, a), _to_local(pos, quat, b)
    half = local_half_extents(shape) + radius
    return bool(np.all(np.minimum(la, lb) <= half) and np.all(np.maximum(la, lb) >= -half))
