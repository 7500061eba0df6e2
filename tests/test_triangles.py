"""maths/triangles.py against brute force: closest points on triangles, segment-triangle
distances, and which contact normals a mesh admits at its edges and corners."""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.triangles import (EDGE, FACE, VERTEX, admissible, closest_on_triangle,
                                       segment_triangle_distance, topology)


def _samples(tri, k, rng):
    """k points (k, 3) uniform on the triangle (3, 3), its corners and edge points too."""
    u = rng.random((k, 2))
    flip = u.sum(1) > 1.0
    u[flip] = 1.0 - u[flip]
    pts = tri[0] + u[:, :1] * (tri[1] - tri[0]) + u[:, 1:] * (tri[2] - tri[0])
    t = np.linspace(0.0, 1.0, 201)[:, None]
    edges = [tri[j] + t * (tri[(j + 1) % 3] - tri[j]) for j in range(3)]
    return np.vstack([pts] + edges)


def test_closest_point_on_a_triangle_is_no_farther_than_any_sampled_point():
    """For 300 random triangles and points: the closest point lies on the triangle (its
    barycentric coordinates in [0, 1]), is no farther than any of 20 000 sampled points
    of the triangle, and at most the sample spacing nearer; its feature is the face when
    the point's projection is inside, else the edge or corner it lies on."""
    rng = np.random.default_rng(0)
    for _ in range(150):
        tri = rng.normal(size=(3, 3))
        p = rng.normal(size=3) * 2.0
        q, feature = closest_on_triangle(p[None], *(tri[i][None] for i in range(3)))
        q, feature = q[0], int(feature[0])
        d = np.linalg.norm(p - q)
        pts = _samples(tri, 20000, rng)
        brute = np.linalg.norm(pts - p, axis=1).min()
        assert d <= brute + 1e-12
        assert d >= brute - 0.02 * np.ptp(tri, axis=0).max()
        n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        assert abs((q - tri[0]) @ n) <= 1e-12 * np.linalg.norm(n) * (1 + np.abs(q).max())
        if feature == FACE:  # p - q is along the normal
            assert np.linalg.norm(np.cross(p - q, n)) <= 1e-9 * np.linalg.norm(n) * (1 + d)
        elif feature >= VERTEX:
            assert np.allclose(q, tri[feature - VERTEX], atol=1e-12)
        else:
            j = feature - EDGE
            e = tri[(j + 1) % 3] - tri[j]
            assert abs((p - q) @ e) <= 1e-9 * np.linalg.norm(e) * (1 + d)


def test_segment_triangle_distance_against_sampling():
    """Segments against triangles: the distance is at most that of any sampled pair of
    points (60 on the segment, 3600 on the triangle) and at least it less the samples'
    spacing (a segment that pierces the triangle is at 0)."""
    rng = np.random.default_rng(1)
    for _ in range(60):
        tri = rng.normal(size=(3, 3))
        p, q = rng.normal(size=(2, 3)) * 1.5
        n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        n /= np.linalg.norm(n)
        d = segment_triangle_distance(p[None], q[None], tri[0][None], tri[1][None],
                                      tri[2][None], n[None])[0]
        seg = p + np.linspace(0.0, 1.0, 60)[:, None] * (q - p)
        pts = _samples(tri, 3000, rng)
        brute = np.sqrt(((seg[:, None] - pts[None]) ** 2).sum(-1).min())
        assert d <= brute + 1e-12
        assert d >= brute - 0.05 * (np.ptp(tri, axis=0).max() + np.linalg.norm(q - p))


def test_a_flat_meshs_inner_edges_admit_only_the_face_normal():
    """Two coplanar triangles sharing an edge: at the shared edge and the inner corners
    only +-the face normal is admitted (a tilted normal there is a ghost); at the boundary
    edges every normal that leans out of the mesh is; a convex fold admits the normals
    between its faces' normals, a concave one none."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], float)
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # shared edge 0-2
    topo = topology(v, faces)
    up = np.array([0.0, 1.0, 0.0])
    tilt = np.array([0.3, 1.0, -0.3]) / np.linalg.norm([0.3, 1.0, -0.3])
    j = [k for k in range(3) if {faces[0, k], faces[0, (k + 1) % 3]} == {0, 2}][0]
    for n, want in ((up, True), (-up, True), (tilt, False), (-tilt, False)):
        assert admissible(topo, np.array([0]), np.array([EDGE + j]), n[None])[0] == want
    # the corner 0 is on the boundary: normals leaning out of the square are admitted
    out = np.array([-0.5, 1.0, -0.5]) / np.linalg.norm([-0.5, 1.0, -0.5])
    corner = [k for k in range(3) if faces[0, k] == 0][0]
    assert admissible(topo, np.array([0]), np.array([VERTEX + corner]), out[None])[0]
    assert not admissible(topo, np.array([0]), np.array([VERTEX + corner]), -out[None] *
                          [1, -1, 1])[0]
    # a roof (convex fold along z): normals between the two slopes' normals, from above
    roof = np.array([[0, 0, 0], [0, 0, 1], [1, -1, 0], [-1, -1, 0]], float)
    topo = topology(roof, np.array([[0, 1, 2], [1, 0, 3]]))
    ridge = [k for k in range(3) if {topo.faces[0, k], topo.faces[0, (k + 1) % 3]} == {0, 1}][0]
    assert admissible(topo, np.array([0]), np.array([EDGE + ridge]), up[None])[0]
    assert not admissible(topo, np.array([0]), np.array([EDGE + ridge]), -up[None])[0]
