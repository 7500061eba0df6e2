"""Spheres, capsules and boxes against triangle meshes: contacts and gaps, closed form.

The pair functions have the narrow phase's signature (`narrowphase.DISPATCH`, mesh first:
normals point from the mesh to the other body). They replace python-fcl for these pairs:
fcl 0.7's triangle-sphere test reports penetration depths with the wrong sign (a sphere
0.01 m into a face came back 0.01 m *apart*, and was dropped), normals that flip when the
centre crosses a face, and the nearest points of `distance` in the sphere's frame, so a
sphere fell through a static mesh in every impact mode.

Each body is taken into the mesh's frame, tested against the triangles whose boxes are
within the margin, and its contacts are the *features* that meet (Ericson, Real-Time
Collision Detection, ch. 5):
- sphere, capsule (a segment of radius r): the part of the segment over a triangle (its
  ends, along the face normal); the segment's closest points to each edge; each corner's
  closest point on the segment;
- box: its corners against each triangle (face, edge or corner of the triangle), the
  triangle's corners against the box, the deepest point of each triangle edge in (or
  nearest to) the box, the ends of the part of each box edge over the triangle, and the
  box's edges crossing the triangle's edges.
A face contact's normal is the face's, turned to the side of the body's centre (a mesh is
a surface: both sides collide). Edge and corner contacts are kept only where their normal
is one the mesh can have there (`maths.triangles.admissible`): between two coplanar
triangles that is the face normal alone, so no ghost edge trips a body sliding over a
flat mesh. Contacts of one pair at the same point with the same normal (the shared edge of
two triangles) are reported once.

`gap(cm, world, ia, ib)`: the signed gap of each pair (> 0 the exact distance when apart,
<= 0 touching or overlapping), for continuous detection and the impact search.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.triangles import (EDGE, FACE, VERTEX, admissible, box_sdf,
                                       closest_on_triangle, closest_segment_points,
                                       point_triangle_distance, segment_triangle_distance,
                                       topology)
from vrsim_cli.model.collision import BOX, CAPSULE, SPHERE
from vrsim_cli.stages.collision.contacts import no_pair_contacts

GOLDEN_ITERATIONS = 48  # the bracket shrinks to 0.618^48 ~ 1e-10 of the edge
_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
EDGE_SLACK = 0.1  # a box edge's normal may lean this far (cosine) out of its own cone
_INTERIOR = 1e-9  # segment parameters this close to an end are that end (a corner)
_TRI_KEY = 1 << 32  # pair * _TRI_KEY + triangle: one key per candidate row
_ROUND = 1e9  # contacts equal to 1e-9 m and 1e-9 in their normal are one contact


def _dot(u, v):
    return np.einsum("...i,...i->...", u, v)


def _unit(v, fallback):
    length = np.linalg.norm(v, axis=-1, keepdims=True)
    ok = length > 1e-300
    return np.where(ok, v / np.where(ok, length, 1.0), fallback), length[..., 0]


def _topology(cm, g):
    key = ("topology", id(cm.geom_vertices[g]))
    if key not in cm.cache:
        cm.cache[key] = topology(cm.geom_vertices[g], cm.geom_faces[g])
    return cm.cache[key]


class _Local:
    """The bodies of pairs (mesh ia, body ib) in their mesh's frame: centre (P, 3), axes
    (P, 3, 3) (columns), half extents (P, 3), radius (P,), segment ends (P, 3) each."""

    def __init__(self, cm, world, ia, ib):
        R = world.rot[ia]
        self.R, self.origin = R, world.pos[ia]
        self.centre = np.einsum("pji,pj->pi", R, world.pos[ib] - world.pos[ia])
        self.axes = np.einsum("pji,pjk->pik", R, world.rot[ib])
        self.half = world.half[ib]
        self.radius = cm.geom_radius[ib]
        kind = cm.geom_type[ib]
        along = np.where((kind == CAPSULE)[:, None], self.axes[:, :, 1] *
                         self.half[:, 1:2], 0.0)
        self.p0, self.p1 = self.centre - along, self.centre + along
        extent = np.where((kind == BOX)[:, None],
                          np.einsum("pij,pj->pi", np.abs(self.axes), self.half),
                          np.abs(along) + self.radius[:, None])
        self.lo, self.hi = self.centre - extent, self.centre + extent
        self.bound = np.where(kind == BOX, np.linalg.norm(self.half, axis=1),
                              np.linalg.norm(along, axis=1) + self.radius)

    def to_world(self, pair, point, normal):
        R = self.R[pair]
        return (self.origin[pair] + np.einsum("pij,pj->pi", R, point),
                np.einsum("pij,pj->pi", R, normal))


def _near(cm, ia, local, margin):
    """Rows (pair (R,), triangle (R,)) of the triangles whose boxes come within `margin`
    of each pair's body box; with an infinite margin, the triangles that can hold the
    least distance (their box is no farther from the body's centre than the nearest
    corner is, plus the body's reach)."""
    pairs, tris = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for g in np.unique(ia).tolist():  # the pairs of one mesh at once: (pairs, triangles)
        topo = _topology(cm, g)
        sel = np.flatnonzero(ia == g)
        if np.isfinite(margin):
            lo, hi = local.lo[sel] - margin, local.hi[sel] + margin
            near = np.all((topo.lo[None] <= hi[:, None]) & (topo.hi[None] >= lo[:, None]),
                          axis=2)
        else:
            c = local.centre[sel][:, None]
            upper = np.sqrt(((topo.corners[None, :, 0] - c) ** 2).sum(2)).min(axis=1)
            box = np.sqrt((np.maximum(np.maximum(topo.lo[None] - c, c - topo.hi[None]), 0.0)
                           ** 2).sum(2))
            near = box - local.bound[sel][:, None] <= upper[:, None]
        p, t = np.nonzero(near)
        pairs.append(sel[p])
        tris.append(t)
    pair, tri = np.concatenate(pairs).astype(np.int64), np.concatenate(tris).astype(np.int64)
    order = np.argsort(pair, kind="stable")
    return pair[order], tri[order]


def _finish(cm, ia, local, rows, margin, deepest):
    """Contacts (pair, point, normal, depth) in the world from candidate rows (pair,
    triangle, feature, mesh witness, body witness, normal, depth), all in the mesh frame:
    within the margin, no deeper than the body overlaps that triangle, admissible, once
    per point and normal, sorted by pair. deepest: (keys pair * n_tri + tri sorted,
    their overlap + tolerance) of the candidate triangles.

    The overlap bound catches a wrong side: a face contact is turned to the side of the
    body's centre, and a box beside a closed mesh (over one face, its centre inside the
    plane of the next face) had a corner past that next face's plane, outside the mesh,
    reported 4.4 cm deep towards the inside while it overlapped the mesh by 0.3 mm."""
    pair, tri, feature, on_mesh, on_body, normal, depth = (np.concatenate(x) for x in
                                                            zip(*rows))
    keys, bound = deepest
    at = np.searchsorted(keys, pair * _TRI_KEY + tri)
    keep = (depth >= -margin) & (depth <= bound[np.minimum(at, len(bound) - 1)])
    ok = np.zeros(len(pair), bool)
    for g in np.unique(ia[pair[keep]]).tolist():
        sel = np.flatnonzero(keep & (ia[pair] == g))
        ok[sel] = admissible(_topology(cm, g), tri[sel], feature[sel], normal[sel])
    sel = np.flatnonzero(ok)
    if not len(sel):
        return no_pair_contacts()
    sel = sel[once(pair[sel], 0.5 * (on_mesh[sel] + on_body[sel]), normal[sel])]
    order = sel[np.argsort(pair[sel], kind="stable")]
    p, n = local.to_world(pair[order], 0.5 * (on_mesh[order] + on_body[order]), normal[order])
    return pair[order], p, n, depth[order]


def once(pair, point, normal) -> np.ndarray:
    """Indices (sorted) of the contacts to keep: one of each pair's contacts at the same
    point (to 1e-9 m) with the same normal (to 1e-9), as two triangles sharing the edge
    a body touches both report it."""
    key = np.column_stack([pair, np.round(point * _ROUND), np.round(normal * _ROUND)])
    _, first = np.unique(key, axis=0, return_index=True)
    return np.sort(first)


def _rows(cm, ia, local, margin):
    pair, tri = _near(cm, ia, local, margin)
    return (pair, tri) + triangles_of(cm, ia, pair, tri)


def _prism_clip(p0, d, corners, tnormal):
    """The parameters [s0, s1] (R,) each of the part of segments p0 + s d, s in [0, 1],
    over triangles (R, 3, 3) of unit normals (R, 3) (inside their prisms along the
    normal), and whether there is such a part (R,) bool."""
    s0, s1 = np.zeros(len(p0)), np.ones(len(p0))
    live = np.ones(len(p0), bool)
    for j in range(3):
        e0, e1 = corners[:, j], corners[:, (j + 1) % 3]
        u = np.cross(tnormal, e1 - e0)  # into the triangle (counter-clockwise about n)
        f0, df = _dot(p0 - e0, u), _dot(d, u)
        with np.errstate(divide="ignore", invalid="ignore"):
            cut = -f0 / df
        s0 = np.where(df > 0.0, np.maximum(s0, cut), s0)
        s1 = np.where(df < 0.0, np.minimum(s1, cut), s1)
        live &= (df != 0.0) | (f0 >= 0.0)
    return s0, s1, live & (s0 <= s1)


def _segments(cm, ia, local, margin, pair, tri, corners, tnormal):
    """Candidate rows of segments of radius r (spheres: of length 0) against triangles."""
    p0, p1, r, centre = local.p0[pair], local.p1[pair], local.radius[pair], \
        local.centre[pair]
    d = p1 - p0
    a = corners[:, 0]
    side = np.where(_dot(centre - a, tnormal) < 0.0, -1.0, 1.0)
    out = []
    live = np.linalg.norm(tnormal, axis=1) > 0.0  # degenerate triangles have no face
    # 1. The part of the segment over the triangle (its prism): its two ends, face normal.
    s0, s1, over = _prism_clip(p0, d, corners, tnormal)
    live &= over
    n = side[:, None] * tnormal
    for s in (s0, s1):
        rows = np.flatnonzero(live)
        x = p0[rows] + s[rows, None] * d[rows]
        h = _dot(x - a[rows], n[rows])
        out.append((pair[rows], tri[rows], np.full(len(rows), FACE),
                    x - h[:, None] * n[rows], x - r[rows, None] * n[rows], n[rows],
                    r[rows] - h))
    # 2. The segment (and each of its ends) against the inside of each edge.
    for j in range(3):
        e0, e1 = corners[:, j], corners[:, (j + 1) % 3]
        s, t = closest_segment_points(p0, p1, e0, e1)
        ends = [(s, t)]
        for s_end in (0.0, 1.0):
            x = p0 + s_end * d
            e = e1 - e0
            t_end = np.clip(_dot(x - e0, e) / np.maximum(_dot(e, e), 1e-300), 0.0, 1.0)
            ends.append((np.full(len(pair), s_end), t_end))
        for s, t in ends:
            rows = np.flatnonzero((t > _INTERIOR) & (t < 1.0 - _INTERIOR))
            xs = p0[rows] + s[rows, None] * d[rows]
            xe = e0[rows] + t[rows, None] * (e1 - e0)[rows]
            e = _unit(e1[rows] - e0[rows], 0.0)[0]
            away = centre[rows] - xe
            fallback = _unit(away - _dot(away, e)[:, None] * e, tnormal[rows])[0]
            m, dist = _unit(xs - xe, fallback)
            out.append((pair[rows], tri[rows], np.full(len(rows), EDGE + j), xe,
                        xs - r[rows, None] * m, m, r[rows] - dist))
    # 3. Each corner against the segment.
    for j in range(3):
        v = corners[:, j]
        t = np.clip(_dot(v - p0, d) / np.maximum(_dot(d, d), 1e-300), 0.0, 1.0)
        xs = p0 + t[:, None] * d
        m, dist = _unit(xs - v, _unit(centre - v, tnormal)[0])
        out.append((pair, tri, np.full(len(pair), VERTEX + j), v, xs - r[:, None] * m, m,
                    r - dist))
    return out


_SIGNS = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                  dtype=float)


def _box_corners(local, pair):
    """The 8 corners (R, 8, 3) of the boxes of pairs `pair`."""
    return local.centre[pair][:, None] + np.einsum(
        "pij,pkj->pki", local.axes[pair], _SIGNS[None] * local.half[pair][:, None])


def _box_edges(local, pair):
    """The 12 edges of each box (R, 12, 3) start, end, and the outward normals (R, 12, 2,
    3) of the two faces that meet there."""
    A, h, c = local.axes[pair], local.half[pair], local.centre[pair]
    mid = c[:, None] + np.einsum("pij,pej->pei", A, _EDGE_MID[None] * h[:, None])
    along = np.einsum("pij,pej->pei", A, _EDGE_DIR[None] * h[:, None])
    faces = np.einsum("pij,efj->pefi", A, _EDGE_FACES)
    return mid - along, mid + along, faces


# the 12 box edges: along axis i, at signs sj, sk of the other two (half extents 1)
_EDGE_MID, _EDGE_DIR, _EDGE_FACES = (np.array(x, float) for x in zip(*[
    (np.eye(3)[(i + 1) % 3] * sj + np.eye(3)[(i + 2) % 3] * sk, np.eye(3)[i],
     [np.eye(3)[(i + 1) % 3] * sj, np.eye(3)[(i + 2) % 3] * sk])
    for i in range(3) for sj in (-1.0, 1.0) for sk in (-1.0, 1.0)]))


def _onto_box(lp, half):
    """Points lp (R, 3) in a box's frame against the box of half extents (R, 3): the
    box's surface point that meets them (outside: the clamped point; inside: out of the
    nearest face), the unit normal (R, 3) from the point to the box's side that pushes
    the box away, and the depth (R,) (negative: a gap)."""
    clamped = np.clip(lp, -half, half)
    outside = np.any(np.abs(lp) > half, axis=1)
    gap_axis = half - np.abs(lp)
    k = np.argmin(gap_axis, axis=1)
    r = np.arange(len(lp))
    sign = np.where(lp[r, k] >= 0.0, 1.0, -1.0)
    surface = lp.copy()
    surface[r, k] = sign * half[r, k]
    surface = np.where(outside[:, None], clamped, surface)
    inward = np.zeros_like(lp)
    inward[r, k] = -sign  # into the box, out of its nearest face
    m_local, dist = _unit(surface - lp, inward)
    m_local = np.where(outside[:, None], m_local, inward)
    return surface, m_local, np.where(outside, -dist, gap_axis[r, k])


def _boxes(cm, ia, local, margin, pair, tri, corners, tnormal):
    """Candidate rows of boxes against triangles."""
    centre = local.centre[pair]
    A, half = local.axes[pair], local.half[pair]
    a = corners[:, 0]
    side = np.where(_dot(centre - a, tnormal) < 0.0, -1.0, 1.0)
    out = []
    # 1. The box's corners against the triangle.
    box_corners = _box_corners(local, pair)
    for k in range(8):
        x = box_corners[:, k]
        q, feature = closest_on_triangle(x, a, corners[:, 1], corners[:, 2])
        face = (feature == FACE) & (np.linalg.norm(tnormal, axis=1) > 0.0)
        m, dist = _unit(x - q, _unit(centre - q, tnormal)[0])
        n_face = side[:, None] * tnormal
        h = _dot(x - a, n_face)
        m = np.where(face[:, None], n_face, m)
        gap = np.where(face, h, dist)
        q = np.where(face[:, None], x - h[:, None] * n_face, q)
        feature = np.where(face | (feature != FACE), feature, VERTEX)  # degenerate: a corner
        out.append((pair, tri, feature, q, x, m, -gap))
    # 2. The triangle's corners against the box.
    for j in range(3):
        v = corners[:, j]
        lv = np.einsum("pji,pj->pi", A, v - centre)
        surface, m_local, depth = _onto_box(lv, half)
        on_box = centre + np.einsum("pij,pj->pi", A, surface)
        m = np.einsum("pij,pj->pi", A, m_local)
        out.append((pair, tri, np.full(len(pair), VERTEX + j), v, on_box, m, depth))
    # 3. The triangle's edges through the box: the deepest point of each (the box's
    # signed distance is convex along a line: golden-section search), where a box
    # overlapping an edge between its corners has no corner, vertex or edge crossing deep.
    for j in range(3):
        la = np.einsum("pji,pj->pi", A, corners[:, j] - centre)
        lb = np.einsum("pji,pj->pi", A, corners[:, (j + 1) % 3] - centre)
        lo, hi = np.zeros(len(pair)), np.ones(len(pair))
        for _ in range(GOLDEN_ITERATIONS):
            x1, x2 = hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo)
            f1 = box_sdf(la + x1[:, None] * (lb - la), half)
            f2 = box_sdf(la + x2[:, None] * (lb - la), half)
            lo, hi = np.where(f1 < f2, lo, x1), np.where(f1 < f2, x2, hi)
        t = 0.5 * (lo + hi)
        rows = np.flatnonzero((t > _INTERIOR) & (t < 1.0 - _INTERIOR))
        lp = la[rows] + t[rows, None] * (lb - la)[rows]
        surface, m_local, depth = _onto_box(lp, half[rows])
        Ar = A[rows]
        out.append((pair[rows], tri[rows], np.full(len(rows), EDGE + j),
                    centre[rows] + np.einsum("pij,pj->pi", Ar, lp),
                    centre[rows] + np.einsum("pij,pj->pi", Ar, surface),
                    np.einsum("pij,pj->pi", Ar, m_local), depth))
    # 4. The part of each box edge over the triangle, its ends along the face normal:
    # an edge that dips under the face between the triangle's edges, from a corner over
    # the face to one beyond it.
    R = len(pair)
    b0, b1, _ = _box_edges(local, pair)
    flat = lambda x: np.repeat(x, 12, axis=0)  # noqa: E731 - (R * 12, ...)
    e_start, e_dir = b0.reshape(-1, 3), (b1 - b0).reshape(-1, 3)
    t_corners, t_normal = flat(corners), flat(tnormal)
    s0, s1, over = _prism_clip(e_start, e_dir, t_corners, t_normal)
    over &= np.linalg.norm(t_normal, axis=1) > 0.0
    n = flat(side)[:, None] * t_normal
    for s_end in (s0, s1):
        rows = np.flatnonzero(over & (s_end > _INTERIOR) & (s_end < 1.0 - _INTERIOR))
        x = e_start[rows] + s_end[rows, None] * e_dir[rows]
        h = _dot(x - t_corners[rows, 0], n[rows])
        out.append((pair[rows // 12], tri[rows // 12], np.full(len(rows), FACE),
                    x - h[:, None] * n[rows], x, n[rows], -h))
    # 5. The box's edges across the triangle's edges.
    b0, b1, bfaces = _box_edges(local, pair)
    for j in range(3):
        e0, e1 = corners[:, j], corners[:, (j + 1) % 3]
        for k in range(12):
            s, t = closest_segment_points(b0[:, k], b1[:, k], e0, e1)
            inside = (s > _INTERIOR) & (s < 1.0 - _INTERIOR) & (t > _INTERIOR) & \
                (t < 1.0 - _INTERIOR)
            cross = np.cross(b1[:, k] - b0[:, k], e1 - e0)
            size = np.linalg.norm(b1[:, k] - b0[:, k], axis=1) * np.linalg.norm(e1 - e0, axis=1)
            inside &= np.linalg.norm(cross, axis=1) > 1e-9 * size
            rows = np.flatnonzero(inside)
            xb = b0[rows, k] + s[rows, None] * (b1[rows, k] - b0[rows, k])
            xe = e0[rows] + t[rows, None] * (e1 - e0)[rows]
            m = _unit(cross[rows], 0.0)[0]
            w = xb - xe
            towards = np.where(np.linalg.norm(w, axis=1) > 1e-12 * (1.0 + np.sqrt(size[rows])),
                               _dot(m, w), _dot(m, centre[rows] - xe))
            m = m * np.where(towards < 0.0, -1.0, 1.0)[:, None]
            own = (_dot(bfaces[rows, k, 0], m) <= EDGE_SLACK) & \
                (_dot(bfaces[rows, k, 1], m) <= EDGE_SLACK)
            rows, xb, xe, m = rows[own], xb[own], xe[own], m[own]
            out.append((pair[rows], tri[rows], np.full(len(rows), EDGE + j), xe, xb, m,
                        -_dot(m, xb - xe)))
    return out


def _pair_contacts(cm, world, ia, ib, margin, make):
    local = _Local(cm, world, ia, ib)
    pair, tri, corners, tnormal = _rows(cm, ia, local, margin)
    if not len(pair):
        return no_pair_contacts()
    return _finish(cm, ia, local, make(cm, ia, local, margin, pair, tri, corners, tnormal),
                   margin, _deepest(cm, local, ib, pair, tri, corners, tnormal))


def _deepest(cm, local, ib, pair, tri, corners, tnormal):
    """(keys sorted, bound): the deepest a contact of each candidate row may be, its
    overlap (-row_gaps) plus the tolerance."""
    keys = pair * _TRI_KEY + tri
    order = np.argsort(keys, kind="stable")
    g = row_gaps(cm, local, ib, pair[order], tri[order], corners[order], tnormal[order])
    return keys[order], np.maximum(-g, 0.0) + cm.tolerance


def mesh_sphere(cm, world, ia, ib, margin):
    """Triangle mesh (A) and sphere (B)."""
    return _pair_contacts(cm, world, ia, ib, margin, _segments)


def mesh_capsule(cm, world, ia, ib, margin):
    """Triangle mesh (A) and capsule (B)."""
    return _pair_contacts(cm, world, ia, ib, margin, _segments)


def mesh_box(cm, world, ia, ib, margin):
    """Triangle mesh (A) and box (B)."""
    return _pair_contacts(cm, world, ia, ib, margin, _boxes)


# ------------------------------------------------------------------------ gaps


def _box_triangle_separation(centre, A, half, corners, tnormal):
    """(R,) m: the largest separation of boxes and triangles along the 13 axes (the face
    normal, the box's 3 axes, the 9 crosses of box axes and triangle edges); <= 0 exactly
    when they touch or overlap."""
    edges = np.roll(corners, -1, axis=1) - corners  # (R, 3, 3): edge j
    crosses = np.cross(np.swapaxes(A, 1, 2)[:, :, None, :], edges[:, None, :, :])
    L = np.concatenate([tnormal[:, None], np.swapaxes(A, 1, 2), crosses.reshape(-1, 9, 3)],
                       axis=1)  # (R, 13, 3)
    L, length = _unit(L, 0.0)
    c = np.einsum("pi,pai->pa", centre, L)
    r = np.einsum("pk,pak->pa", half, np.abs(np.einsum("pik,pai->pak", A, L)))
    proj = np.einsum("pji,pai->paj", corners, L)  # (R, 13, 3)
    sep = np.maximum(proj.min(axis=2) - (c + r), (c - r) - proj.max(axis=2))
    return np.where(length > 1e-9, sep, -np.inf).max(axis=1)


def _box_triangle_distance(local, pair, corners):
    """(R,) m: the distance of boxes and triangles that are apart: the least over the
    box's corners to the triangle, the triangle's corners to the box and the box's edges
    to the triangle's edges (the closest points of two convex polyhedra lie on such a
    pair of features)."""
    R = len(pair)
    box_corners = _box_corners(local, pair)  # (R, 8, 3); all features at once
    tri8 = np.repeat(corners, 8, axis=0)
    d = point_triangle_distance(box_corners.reshape(-1, 3), tri8[:, 0], tri8[:, 1],
                                tri8[:, 2]).reshape(R, 8).min(axis=1)
    A, half, centre = local.axes[pair], local.half[pair], local.centre[pair]
    lv = np.einsum("pji,pkj->pki", A, corners - centre[:, None])
    d = np.minimum(d, box_sdf(lv, half[:, None]).min(axis=1))
    b0, b1, _ = _box_edges(local, pair)  # (R, 12, 3)
    e0 = np.repeat(corners, 12, axis=1)  # (R, 36, 3): triangle edge j, box edge k
    e1 = np.repeat(np.roll(corners, -1, axis=1), 12, axis=1)
    p0, p1 = np.tile(b0, (1, 3, 1)), np.tile(b1, (1, 3, 1))
    flat = [x.reshape(-1, 3) for x in (p0, p1, e0, e1)]
    s, t = closest_segment_points(*flat)
    w = flat[0] + s[:, None] * (flat[1] - flat[0]) - (flat[2] + t[:, None] * (flat[3] -
                                                                              flat[2]))
    return np.minimum(d, np.linalg.norm(w, axis=1).reshape(R, 36).min(axis=1))


def row_gaps(cm, local, ib, pair, tri, corners, tnormal) -> np.ndarray:
    """(R,) m: the signed gap of each row (pair, triangle): the exact distance when apart,
    <= 0 when they touch or overlap (spheres and capsules: the distance of the centre or
    axis minus the radius; boxes: the separating-axis overlap), continuous in the poses,
    and a lower bound of the distance, as conservative advancement needs."""
    kind = cm.geom_type[ib[pair]]
    g = np.full(len(pair), np.inf)
    a, b, c = corners[:, 0], corners[:, 1], corners[:, 2]
    sph = np.flatnonzero(kind == SPHERE)
    if len(sph):
        g[sph] = point_triangle_distance(local.centre[pair[sph]], a[sph], b[sph], c[sph]) - \
            local.radius[pair[sph]]
    cap = np.flatnonzero(kind == CAPSULE)
    if len(cap):
        g[cap] = segment_triangle_distance(local.p0[pair[cap]], local.p1[pair[cap]], a[cap],
                                           b[cap], c[cap], tnormal[cap]) - \
            local.radius[pair[cap]]
    box = np.flatnonzero(kind == BOX)
    if len(box):
        p = pair[box]
        sep = _box_triangle_separation(local.centre[p], local.axes[p], local.half[p],
                                       corners[box], tnormal[box])
        apart = np.flatnonzero(sep > 0.0)
        g[box] = sep
        if len(apart):
            g[box[apart]] = _box_triangle_distance(local, p[apart], corners[box[apart]])
    return g


def gap(cm, world, ia, ib) -> np.ndarray:
    """(P,) m: the signed gap of pairs (mesh ia, sphere, capsule or box ib), the least of
    `row_gaps` over the triangles that can hold it."""
    ia, ib = np.asarray(ia, np.int64), np.asarray(ib, np.int64)
    out = np.full(len(ia), np.inf)
    if not len(ia):
        return out
    local = _Local(cm, world, ia, ib)
    pair, tri, corners, tnormal = _rows(cm, ia, local, np.inf)
    if len(pair):
        np.minimum.at(out, pair, row_gaps(cm, local, ib, pair, tri, corners, tnormal))
    return out


def rows_near(cm, world, ia, ib, margin):
    """The bodies of pairs (mesh ia, body ib) in their meshes' frames (`_Local`) and the
    rows (pair, triangle, corners, normal) of the triangles within `margin` of them."""
    local = _Local(cm, world, ia, ib)
    return local, _rows(cm, ia, local, margin)


def triangles_of(cm, ia, pair, tri):
    """corners (R, 3, 3) and normals (R, 3) of triangles `tri` of meshes ia[pair]."""
    corners = np.zeros((len(tri), 3, 3))
    normal = np.zeros((len(tri), 3))
    for g in np.unique(ia[pair]).tolist():
        sel = np.flatnonzero(ia[pair] == g)
        topo = _topology(cm, g)
        corners[sel], normal[sel] = topo.corners[tri[sel]], topo.normal[tri[sel]]
    return corners, normal


def row_contacts(cm, world, ia, ib, tri, margin):
    """Contacts (pair, point, normal, depth) of pairs (mesh ia, body ib) (P,) with one
    triangle each, `tri` (P,), within `margin`."""
    local = _Local(cm, world, ia, ib)
    pair = np.arange(len(ia))
    corners, tnormal = triangles_of(cm, ia, pair, tri)
    rows = []
    for kind, make in ((BOX, _boxes), (None, _segments)):
        sel = np.flatnonzero((cm.geom_type[ib] == BOX) == (kind == BOX))
        if len(sel):
            rows += make(cm, ia, local, margin, pair[sel], tri[sel], corners[sel],
                         tnormal[sel])
    if not rows:
        return no_pair_contacts()
    return _finish(cm, ia, local, rows, margin,
                   _deepest(cm, local, ib, pair, tri, corners, tnormal))


KINDS = (SPHERE, CAPSULE, BOX)  # the body types `gap` and the pair functions take
