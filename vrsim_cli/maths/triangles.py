"""Closest points between triangles and points, segments and boxes, vectorised over rows,
and the topology of a triangle mesh that tells a real contact from a ghost one.

Pure numpy, no scene (layer 0). Used by collision detection against triangle meshes
(`stages/collision/mesh_pairs.py`). Conventions: a triangle is three corners (..., 3) a,
b, c; its edge j runs from corner j to corner (j + 1) % 3; a closest-point *feature* is
FACE (0), EDGE + j (1..3) or VERTEX + j (4..6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FACE, EDGE, VERTEX = 0, 1, 4
_EPS = 1e-12


def _dot(u, v):
    return np.einsum("...i,...i->...", u, v)


def closest_segment_points(p1, q1, p2, q2):
    """Parameters s, t (P,) of the closest points p1 + s (q1 - p1), p2 + t (q2 - p2) of two
    segments (Ericson, Real-Time Collision Detection, 5.1.9), vectorised."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    denom = a * e - b * b
    safe_a, safe_e = np.maximum(a, _EPS), np.maximum(e, _EPS)
    s = np.where(denom > _EPS * np.maximum(a * e, _EPS),
                 np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / safe_e
    s = np.where(t < 0.0, np.clip(-c / safe_a, 0.0, 1.0), np.where(
        t > 1.0, np.clip((b - c) / safe_a, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    s = np.where(a <= _EPS, 0.0, s)
    t = np.where(a <= _EPS, np.clip(f / safe_e, 0.0, 1.0), t)
    t = np.where(e <= _EPS, 0.0, t)
    s = np.where((e <= _EPS) & (a > _EPS), np.clip(-c / safe_a, 0.0, 1.0), s)
    return s, t


def box_sdf(local, half):
    """Signed distance (...) m of points `local` (..., 3), in a box's frame, to the box of
    half extents `half` (..., 3): negative inside."""
    q = np.abs(local) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


def closest_on_triangle(p, a, b, c):
    """The closest point (P, 3) of triangles (a, b, c) (P, 3) each to points p (P, 3), and
    its feature (P,) int: FACE, EDGE + j or VERTEX + j (Ericson 5.1.5, by Voronoi region,
    tested in the book's order so that each point gets one region)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        denom = 1.0 / (va + vb + vc)
    v, w = vb * denom, vc * denom
    regions = [(d1 <= 0.0) & (d2 <= 0.0),
               (d3 >= 0.0) & (d4 <= d3),
               (vc <= 0.0) & (d1 >= 0.0) & (d3 <= 0.0),
               (d6 >= 0.0) & (d5 <= d6),
               (vb <= 0.0) & (d2 >= 0.0) & (d6 <= 0.0),
               (va <= 0.0) & (d4 - d3 >= 0.0) & (d5 - d6 >= 0.0)]
    features = [VERTEX + 0, VERTEX + 1, EDGE + 0, VERTEX + 2, EDGE + 2, EDGE + 1]
    feature = np.select(regions, features, FACE)
    points = [a, b, a + t_ab[:, None] * ab, c, a + t_ac[:, None] * ac,
              b + t_bc[:, None] * (c - b)]
    face = a + ab * v[:, None] + ac * w[:, None]
    out = face.copy()
    for region, point in zip(regions[::-1], points[::-1]):  # the first region wins
        out = np.where(region[:, None], point, out)
    return np.where(np.isfinite(out), out, a), feature


def point_triangle_distance(p, a, b, c):
    """Distance (P,) of points p (P, 3) to triangles (a, b, c)."""
    q, _ = closest_on_triangle(p, a, b, c)
    return np.linalg.norm(p - q, axis=1)


def segment_triangle_distance(p, q, a, b, c, normal):
    """Distance (P,) of segments p-q (P, 3) to triangles (a, b, c) with unit normals (P,
    3): 0 when the segment pierces the triangle, else the least of the end points'
    distances and the segment's distances to the three edges."""
    P = len(p)
    ends = point_triangle_distance(np.concatenate([p, q]), *(np.concatenate([x, x]) for x in
                                                             (a, b, c)))
    d = np.minimum(ends[:P], ends[P:])
    corners = (a, b, c)
    e0 = np.concatenate(corners)  # the three edges at once: (3P, 3)
    e1 = np.concatenate([b, c, a])
    p3, q3 = np.concatenate([p, p, p]), np.concatenate([q, q, q])
    s, t = closest_segment_points(p3, q3, e0, e1)
    gap = p3 + s[:, None] * (q3 - p3) - (e0 + t[:, None] * (e1 - e0))
    d = np.minimum(d, np.linalg.norm(gap, axis=1).reshape(3, P).min(axis=0))
    hp, hq = _dot(p - a, normal), _dot(q - a, normal)
    crosses = (hp * hq < 0.0)
    if crosses.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            x = p + (hp / (hp - hq))[:, None] * (q - p)
        inside = np.ones(len(p), bool)
        for j in range(3):
            e0, e1 = corners[j], corners[(j + 1) % 3]
            inside &= _dot(np.cross(e1 - e0, x - e0), normal) >= 0.0
        d = np.where(crosses & inside, 0.0, d)
    return d


@dataclass(frozen=True)
class Topology:
    """What a mesh's neighbourhood says about its features, in the mesh frame.

    faces: (F, 3) int64 vertex indices
    corners: (F, 3, 3) m, the triangles' corners
    normal: (F, 3) unit (as wound; zero for a degenerate triangle)
    inward: (F, 3, 3) unit: for edge j, the direction in the triangle's plane,
        perpendicular to the edge, into the triangle
    across: (F, 3, 3) unit: the same for the other triangle on that edge (zero on a
        boundary edge, or an edge with more than two triangles)
    spokes: (V, D, 3) unit directions of the edges leaving each vertex (zero padded)
    lo, hi: (F, 3) m, the triangles' bounding boxes
    """

    faces: np.ndarray
    corners: np.ndarray
    normal: np.ndarray
    inward: np.ndarray
    across: np.ndarray
    spokes: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def _unit(v):
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(length > 0.0, v / np.where(length > 0.0, length, 1.0), 0.0)


def topology(vertices, faces) -> Topology:
    """The Topology of a triangle mesh (V, 3), (F, 3). Built once per mesh."""
    vertices = np.asarray(vertices, float)
    faces = np.asarray(faces, np.int64)
    corners = vertices[faces]
    F = len(faces)
    normal = _unit(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]))
    inward = np.zeros((F, 3, 3))
    for j in range(3):
        e0, e1, opp = corners[:, j], corners[:, (j + 1) % 3], corners[:, (j + 2) % 3]
        u = _unit(e1 - e0)
        w = opp - e0
        inward[:, j] = _unit(w - _dot(w, u)[:, None] * u)
    key = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2), axis=2)  # (F,3,2)
    flat = key.reshape(-1, 2)
    _, inverse, counts = np.unique(flat, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    across = np.zeros((F, 3, 3))
    two = np.flatnonzero(counts[inverse] == 2)
    order = two[np.argsort(inverse[two], kind="stable")]  # the two rows of an edge together
    first, second = order[0::2], order[1::2]
    across.reshape(-1, 3)[first] = inward.reshape(-1, 3)[second]
    across.reshape(-1, 3)[second] = inward.reshape(-1, 3)[first]
    edges = np.unique(flat, axis=0)
    direction = _unit(vertices[edges[:, 1]] - vertices[edges[:, 0]])
    start = np.concatenate([edges[:, 0], edges[:, 1]])
    spoke = np.concatenate([direction, -direction])
    degree = np.bincount(start, minlength=len(vertices))
    spokes = np.zeros((len(vertices), max(int(degree.max(initial=0)), 1), 3))
    order = np.argsort(start, kind="stable")
    slot = np.arange(len(start)) - np.repeat(np.cumsum(degree) - degree, degree)
    spokes[start[order], slot] = spoke[order]
    return Topology(faces, corners, normal, inward, across, spokes, corners.min(axis=1),
                    corners.max(axis=1))


def admissible(topo: Topology, tri, feature, normal, slack: float = 1e-9):
    """(P,) bool: is `normal` (P, 3, unit, pointing from the mesh to the other body) one the
    mesh can have at feature `feature` of triangle `tri` (P,)? A contact there is a local
    minimum of the distance over the surface only then: on an edge, the normal must not
    lean into either triangle that shares it (n . inward <= 0 for both); at a vertex, not
    along any edge leaving it. Inside a flat mesh this leaves only the face normal, so a
    body sliding over the edge between two coplanar triangles is not tripped by the
    edge's ghost contact (Bullet's internal-edge problem)."""
    ok = np.ones(len(tri), bool)
    edge = (feature >= EDGE) & (feature < VERTEX)
    if edge.any():
        j = feature[edge] - EDGE
        n = normal[edge]
        ok[edge] = (_dot(n, topo.inward[tri[edge], j]) <= slack) & \
            (_dot(n, topo.across[tri[edge], j]) <= slack)
    vertex = feature >= VERTEX
    if vertex.any():
        v = topo.faces[tri[vertex], feature[vertex] - VERTEX]
        lean = np.einsum("pdi,pi->pd", topo.spokes[v], normal[vertex])
        ok[vertex] = lean.max(axis=1) <= slack
    return ok
