"""Triangle meshes: loading (trimesh), proxies computed from the render mesh, the error a
proxy makes, and exact point/ray queries against triangles (numpy).

trimesh is imported here, inside functions, so only scenes with mesh bodies pay for it.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.maths.products import matmul

from vrsim_cli.maths.spatial import quat_from_matrix

PROXY_SAMPLES = 2000  # points sampled on each surface for the proxy error (plus vertices)
# What vrsim simulates (the scene's lengths have the same range, scene/limits.py): a mesh
# beyond these made qhull fail, scipy's bounding sphere report "Improper input", and a
# million triangles took minutes and gigabytes for collision and MCAP.
MAX_MESH_TRIANGLES = 100_000  # the obb proxy of 100000 takes ~7 s, of 200000 ~60 s
MIN_MESH_SIZE_M, MAX_MESH_SIZE_M = 1e-6, 1e6  # the mesh's largest extent, after scale
FLAT = 1e-9  # a mesh thinner than this fraction of its size in some direction is flat


def _trimesh():
    try:
        import trimesh
    except ImportError as exc:  # pragma: no cover - trimesh is a core dependency
        raise ValueError("mesh collision needs the 'trimesh' package") from exc
    return trimesh


def load_mesh(path: str, scale: float = 1.0):
    """The trimesh.Trimesh in a file (OBJ, STL, PLY, GLB/glTF; scenes are merged), scaled.
    Raises ValueError with a readable message when the file holds no triangles."""
    trimesh = _trimesh()
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise ValueError(f"cannot read mesh '{path}': {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"mesh '{path}' has no triangles")
    if scale != 1.0:
        mesh = mesh.copy()
        with np.errstate(over="ignore", invalid="ignore"):
            mesh.apply_scale(scale)
    problem = mesh_problem(mesh)
    if problem is not None:
        raise ValueError(f"mesh '{path}' {problem}")
    return mesh


def mesh_problem(mesh) -> str | None:
    """Why vrsim cannot simulate a loaded (and scaled) mesh, or None: too many triangles,
    a vertex that is not a finite number, or a size outside MIN/MAX_MESH_SIZE_M."""
    if len(mesh.faces) > MAX_MESH_TRIANGLES:
        return f"has {len(mesh.faces)} triangles; at most {MAX_MESH_TRIANGLES} are simulated"
    vertices = np.asarray(mesh.vertices, dtype=float)
    if not np.isfinite(vertices).all():
        return "has a vertex that is not a finite number (after scale)"
    used = vertices[np.unique(np.asarray(mesh.faces))]
    with np.errstate(over="ignore", invalid="ignore"):
        size = float((used.max(axis=0) - used.min(axis=0)).max())
    if not MIN_MESH_SIZE_M <= size <= MAX_MESH_SIZE_M:
        return (f"is {size:.4g} m across (after scale); vrsim simulates meshes from "
                f"{MIN_MESH_SIZE_M:g} to {MAX_MESH_SIZE_M:g} m")
    return None


def solid_problem(mesh) -> str | None:
    """Why a mesh has no solid convex hull (the hull, obb and sphere proxies need one), or
    None: all its points on one line or in one plane (qhull fails on them)."""
    points = np.asarray(mesh.vertices, dtype=float)[np.unique(np.asarray(mesh.faces))]
    centred = points - points.mean(axis=0)
    spread = np.linalg.svd(centred, compute_uv=False) if len(points) >= 3 else np.zeros(1)
    if len(spread) < 3 or spread[0] == 0.0 or spread[2] <= FLAT * spread[0]:
        what = "a point" if len(spread) == 0 or spread[0] == 0.0 else \
            "a line" if len(spread) < 2 or spread[1] <= FLAT * spread[0] else "a plane"
        return f"is flat (all its points lie on {what}): it has no solid hull"
    return None


def proxies(mesh) -> dict:
    """Every proxy of a mesh as a dict name -> geom parameters in the mesh (body) frame:
    sphere {centre, radius}; obb {centre, quat, half}; aabb {vertices}; hull {vertices,
    faces}; mesh {vertices, faces}. Raises ValueError (with the reason) for a flat mesh,
    which has none but `mesh`, or when qhull or scipy fail on it."""
    return _checked(mesh, ("sphere", "obb", "aabb", "hull", "mesh"))


def _checked(mesh, names) -> dict:
    problem = solid_problem(mesh)
    if problem is not None:
        raise ValueError(f"the mesh {problem}; use collision geometry 'mesh' (its triangles)")
    try:
        return _proxies(mesh, names)
    except (RuntimeError, ValueError, TypeError, ArithmeticError, IndexError,
            ImportError) as exc:  # QhullError is a RuntimeError
        detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"cannot compute the proxies of the mesh ({detail})") from None


def proxy(mesh, name: str) -> dict:
    """One proxy of `proxies`; the `mesh` itself needs no hull (a flat mesh is fine)."""
    if name == "mesh":
        vertices = np.asarray(mesh.vertices, float)
        faces = np.asarray(mesh.faces, np.int64)
        # fcl gives garbage contacts (different on every run, NaN at times) for triangles
        # without an area; they are no surface, so they are dropped
        faces = faces[has_area(vertices, faces)]
        if not len(faces):
            raise ValueError("the mesh has no triangle with an area (the corners of each "
                             "lie on a line or at a point): it has no surface to collide "
                             "with")
        return {"vertices": vertices, "faces": faces}
    return _checked(mesh, (name,))[name]


SLIVER = 1e-12  # a triangle thinner than this fraction of its longest edge has no area


def has_area(vertices, faces) -> np.ndarray:
    """(F,) bool: which triangles (F, 3) of `vertices` (V, 3) have an area, i.e. are not
    slivers whose normal would be rounding noise: |cross| > SLIVER * longest edge^2."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    edges = tri[:, [1, 2, 0]] - tri
    with np.errstate(over="ignore", invalid="ignore"):
        cross = np.linalg.norm(np.cross(edges[:, 0], -edges[:, 2]), axis=1)
        longest = (edges ** 2).sum(axis=2).max(axis=1)
        return cross > SLIVER * longest


def _proxies(mesh, names) -> dict:
    """The proxies in `names` only: the smallest enclosing sphere and the oriented box of
    a 200000-triangle mesh take tens of seconds each, and a body needs one of them."""
    out = {}
    if "sphere" in names:
        sphere = mesh.bounding_sphere.primitive
        out["sphere"] = {"centre": np.asarray(sphere.center, float),
                         "radius": float(sphere.radius)}
    if "obb" in names:
        obb = mesh.bounding_box_oriented.primitive
        out["obb"] = {"centre": np.asarray(obb.transform[:3, 3], float),
                      "quat": quat_from_matrix(obb.transform[:3, :3]),
                      "half": 0.5 * np.asarray(obb.extents, float)}
    if "aabb" in names or "hull" in names:
        hull = mesh.convex_hull
        out["aabb"] = {"vertices": np.asarray(hull.vertices, float)}
        out["hull"] = {"vertices": np.asarray(hull.vertices, float),
                       "faces": np.asarray(hull.faces, np.int64)}
    if "mesh" in names:
        out["mesh"] = {"vertices": np.asarray(mesh.vertices, float),
                       "faces": np.asarray(mesh.faces, np.int64)}
    return out


def proxy_surface(mesh, name: str, p: dict):
    """A trimesh of the proxy's surface, in the mesh frame (aabb: at identity orientation)."""
    trimesh = _trimesh()
    if name == "sphere":
        s = trimesh.creation.icosphere(subdivisions=3, radius=p["radius"])
        s.apply_translation(p["centre"])
        return s
    if name == "obb":
        return mesh.bounding_box_oriented.copy()
    if name == "aabb":
        return mesh.bounding_box.copy()
    if name == "hull":
        return mesh.convex_hull
    return mesh


def _box_surface_distance(points, centre, rot, half):
    local = matmul(points - centre, rot)
    q = np.abs(local) - half
    return np.abs(np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0))


def proxy_errors(mesh, samples: int = PROXY_SAMPLES) -> list[dict]:
    """Per proxy: its volume over the mesh's volume and the Hausdorff distance between the
    proxy's surface and the mesh's surface, estimated from `samples` area-uniform points on
    each surface plus all vertices (seeded: the same numbers every run). The estimate is a
    lower bound of the true Hausdorff distance that misses it by at most the spacing of
    the samples; for boxes and hulls the farthest points are usually vertices, which are
    always included. aabb is reported at the mesh's own orientation (at other
    orientations it is larger). Distances to the proxies are exact (analytic for sphere
    and boxes); distances to the mesh are exact point-triangle distances."""
    trimesh = _trimesh()
    table = proxies(mesh)
    mesh_volume = float(mesh.volume) if mesh.is_watertight else math.nan
    mesh_points = np.vstack([mesh.vertices, trimesh.sample.sample_surface(
        mesh, samples, seed=1)[0]])
    sphere = table["sphere"]
    obb = mesh.bounding_box_oriented.primitive
    lo, hi = mesh.bounds
    to_proxy = {
        "sphere": lambda p: np.abs(np.linalg.norm(p - sphere["centre"], axis=1)
                                   - sphere["radius"]),
        "aabb": lambda p: _box_surface_distance(p, 0.5 * (lo + hi), np.eye(3),
                                                0.5 * (hi - lo)),
        "obb": lambda p: _box_surface_distance(p, obb.transform[:3, 3],
                                               obb.transform[:3, :3], 0.5 * obb.extents),
        "hull": lambda p: point_mesh_distance(p, table["hull"]["vertices"],
                                              table["hull"]["faces"]),
    }
    out = []
    for name in ("sphere", "aabb", "obb", "hull"):
        surface = proxy_surface(mesh, name, table[name])
        volume = (4.0 / 3.0 * math.pi * sphere["radius"] ** 3 if name == "sphere" else
                  float(surface.volume))
        pts = np.vstack([surface.vertices, trimesh.sample.sample_surface(
            surface, samples, seed=2)[0]])
        out_dist = float(point_mesh_distance(pts, mesh.vertices, mesh.faces).max())
        in_dist = float(to_proxy[name](mesh_points).max())
        out.append({"proxy": name, "hausdorff_m": max(out_dist, in_dist),
                    "proxy_to_mesh_m": out_dist, "mesh_to_proxy_m": in_dist,
                    "volume_ratio": volume / mesh_volume if mesh_volume > 0 else math.nan})
    out.append({"proxy": "mesh", "hausdorff_m": 0.0, "proxy_to_mesh_m": 0.0,
                "mesh_to_proxy_m": 0.0, "volume_ratio": 1.0})
    return out


def _dot(u, v):
    return np.einsum("...i,...i->...", u, v)


def point_mesh_distance(points, vertices, faces) -> np.ndarray:
    """Unsigned distance (n,) m from points (n, 3) to a triangle mesh's surface: fcl's
    exact point-triangle distances over its bounding-volume hierarchy (~40 us a point;
    brute force in numpy is ~100x slower on a 4000-triangle mesh)."""
    import fcl

    bvh = fcl.BVHModel()
    bvh.beginModel(len(vertices), len(faces))
    bvh.addSubModel(np.asarray(vertices, float), np.asarray(faces, np.int64))
    bvh.endModel()
    mesh = fcl.CollisionObject(bvh, fcl.Transform())
    point = fcl.Sphere(0.0)
    request = fcl.DistanceRequest()
    out = np.empty(len(points))
    for k, p in enumerate(np.asarray(points, float)):
        out[k] = fcl.distance(mesh, fcl.CollisionObject(point, fcl.Transform(p)), request,
                              fcl.DistanceResult())
    return np.maximum(out, 0.0)


def ray_mesh(origin, direction, vertices, faces) -> float | None:
    """Distance along the unit `direction` to the first triangle hit, or None.
    Moeller-Trumbore, vectorised over triangles; both faces of a triangle count."""
    tri = np.asarray(vertices, float)[np.asarray(faces)]
    o = np.asarray(origin, float)
    d = np.asarray(direction, float)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    h = np.cross(d, e2)
    det = _dot(e1, h)
    ok = np.abs(det) > 1e-14
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = o - tri[:, 0]
    u = inv * _dot(s, h)
    q = np.cross(s, e1)
    v = inv * matmul(q, d)
    t = inv * _dot(e2, q)
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0)
    return float(t[hit].min()) if hit.any() else None
