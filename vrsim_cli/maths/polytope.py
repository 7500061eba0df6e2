"""The faces of a convex polytope given as a triangulated hull: its facets (coplanar
triangles merged into one polygon), for contact manifolds (`stages/collision/cylinder_pairs`)
and a body's thinness (`model/collision.thinnest`).

A hull read from a file is triangles: a box's face is two of them, a prism's cap many.
Clipping one face against another needs the whole face, or a box resting on a hull rests
on one triangle's corner. Triangles belong to one facet when their normals agree to
COPLANAR_COS and their planes to PLANE_TOL of the hull's size.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.maths import trig

COPLANAR_COS = 1.0 - 1e-9  # normals this close (~4.5e-5 rad) are one facet's
PLANE_TOL = 1e-9  # of the hull's size: vertices this close to a facet's plane are on it


class Facets:
    """normals (F, 3) unit, outward; offsets (F,) m (max of normal . vertex over the hull,
    so every vertex lies on the inner side); loops: F int arrays, each facet's vertex
    indices in counter-clockwise order seen from outside."""

    __slots__ = ("normals", "offsets", "loops")

    def __init__(self, normals, offsets, loops):
        self.normals, self.offsets, self.loops = normals, offsets, loops


def _cross(u, v):
    return np.array([u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2],
                     u[0] * v[1] - u[1] * v[0]])


def _dot(u, v) -> float:
    return float(u[0] * v[0] + u[1] * v[1] + u[2] * v[2])


def facets(vertices, faces) -> Facets:
    """The facets of the convex hull whose triangles are `faces` (T, 3) over `vertices`
    (V, 3). Each facet's normal is that of its largest triangle (the best conditioned);
    written out in Python floats, so the result does not depend on the CPU's BLAS."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces, np.int64)
    size = float(np.abs(v).max()) if len(v) else 0.0
    tol = PLANE_TOL * max(size, 1e-300)
    tris = []
    for a, b, c in f.tolist():
        n = _cross(v[b] - v[a], v[c] - v[a])
        area2 = math.sqrt(_dot(n, n))
        if area2 > 0.0:
            tris.append((area2, n / area2, a))
    tris.sort(key=lambda t: -t[0])  # largest first: each facet takes its best normal
    normals, offsets = np.zeros((len(tris), 3)), np.zeros(len(tris))
    count = 0
    for _, n, a in tris:
        o = _dot(n, v[a])
        # (numpy's own loops over the facets so far: an icosphere has 1280)
        same = (np.einsum("fi,i->f", normals[:count], n) >= COPLANAR_COS) & \
            (np.abs(offsets[:count] - o) <= tol)
        if same.any():
            continue
        normals[count], offsets[count] = n, o
        count += 1
    normals = normals[:count]
    proj = np.einsum("fi,vi->fv", normals, v)  # numpy's own loops: no BLAS
    top = proj.max(axis=1)
    loops = []
    for k, n in enumerate(normals):
        on = np.flatnonzero(proj[k] >= top[k] - tol)
        loops.append(_ordered(v, on, n))
    return Facets(normals, top, tuple(loops))


def _ordered(v, idx, n):
    """The vertices idx of one facet (normal n) in counter-clockwise order about n."""
    if len(idx) < 3:
        return idx
    centre = v[idx].mean(axis=0)
    u = v[idx[0]] - centre
    u = u / math.sqrt(_dot(u, u))
    w = _cross(n, u)
    # trig.atan2, not libm's: a tie within an ulp would order the vertices by CPU
    angle = trig.atan2([_dot(v[i] - centre, w) for i in idx],
                       [_dot(v[i] - centre, u) for i in idx])
    return idx[np.argsort(angle, kind="stable")]


def widths(vertices, normals) -> np.ndarray:
    """(F,) m: the extent of `vertices` (V, 3) along each unit normal (F, 3). Over a
    convex polytope's facet normals the least is its thickness wherever a facet
    supports it (a plate, a prism, a box); otherwise an upper bound on it (two
    opposite edges can set the least width, as in a tetrahedron: 0.71 against 0.82 of
    its edge)."""
    v = np.asarray(vertices, float)
    n = np.asarray(normals, float)
    proj = np.einsum("fi,vi->fv", n, v)
    return proj.max(axis=1) - proj.min(axis=1)
