"""Scene queries for navigation (slide 5.1 walking, terrain, walls), meshes included:
`ray_cast` (terrain height under the observer) and `sphere_cast` (the observer's sphere
moving against walls). Analytic shapes use `vrsim_cli.geometry`; meshes are exact
triangle queries in numpy (`meshes.ray_mesh`, `meshes.point_mesh_distance`).
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths import geometry
from vrsim_cli.maths.spatial import quat_conjugate, quat_rotate

MAX_ITERATIONS = 100  # sphere-cast advancement steps (each at least `tolerance` long)
_MESHES: dict = {}  # (path, scale) -> (vertices, faces): one load per file per process


def mesh_arrays(shape: dict):
    """(vertices (V, 3), faces (F, 3)) of a mesh shape, in the body frame (scaled)."""
    key = (shape["path"], float(shape.get("scale", 1.0)))
    if key not in _MESHES:
        from vrsim_cli.maths.meshes import load_mesh

        mesh = load_mesh(*key)
        _MESHES[key] = (np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64))
    return _MESHES[key]


def ray_cast(shape: dict, pos, quat, origin, direction) -> float | None:
    """Distance along the unit `direction` from `origin` to the shape's surface (0 inside
    an analytic solid; a mesh counts its first triangle), None when the ray misses."""
    if shape["type"] != "mesh":
        return geometry.ray_cast(shape, pos, quat, origin, direction)
    from vrsim_cli.maths.meshes import ray_mesh

    inv = quat_conjugate(quat)
    o = quat_rotate(inv, np.asarray(origin, float) - np.asarray(pos, float))
    return ray_mesh(o, quat_rotate(inv, np.asarray(direction, float)), *mesh_arrays(shape))


def distance(shape: dict, pos, quat, point) -> float:
    """Distance m from `point` to the shape: signed for analytic solids, unsigned (to the
    surface) for meshes."""
    if shape["type"] != "mesh":
        return geometry.signed_distance(shape, pos, quat, point)[0]
    from vrsim_cli.maths.meshes import point_mesh_distance

    local = quat_rotate(quat_conjugate(quat), np.asarray(point, float) - np.asarray(pos, float))
    return float(point_mesh_distance(local[None], *mesh_arrays(shape))[0])


def sphere_cast(shape: dict, pos, quat, origin, direction, radius: float,
                max_distance: float, tolerance: float = 1e-4) -> float | None:
    """How far a sphere of `radius` at `origin` moves along the unit `direction` before it
    comes within `tolerance` of the shape (sphere tracing: each step is the current gap,
    which the sphere can always move without touching); None when it travels
    `max_distance` freely. 0 when it already touches."""
    origin = np.asarray(origin, float)
    direction = np.asarray(direction, float)
    t = 0.0
    for _ in range(MAX_ITERATIONS):
        gap = distance(shape, pos, quat, origin + t * direction) - radius
        if gap <= tolerance:
            return t
        t += gap
        if t > max_distance:
            return None
    return None  # grazing: the sphere keeps its gap along the whole path checked
