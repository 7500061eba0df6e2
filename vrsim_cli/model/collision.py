"""Collision geometry: compile the scene's shapes and proxies into one frozen table.

Layer 2 helper (called by `model.compile_model` only when the scene has a top-level
`collision` block; imports numpy and, for mesh bodies only, trimesh). One geom per body
that has a shape and takes part in collision; arrays are over geoms (n_geom).

Geometries (`collision.geometry` of a body, slide 5.4.1: collision geometry may differ
from the render geometry):
- exact: the body's own shape (sphere, box, plane, capsule, cylinder; a mesh body is
  tested as its triangle mesh);
- for mesh bodies, proxies computed from the render mesh: sphere (the smallest enclosing
  sphere), aabb (the world-axis-aligned box around the mesh at the body's current
  orientation, recomputed every step), obb (the smallest oriented box, fixed in the body),
  hull (the convex hull), mesh (the triangle mesh, same as exact).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vrsim_cli.maths.polytope import facets, widths
from vrsim_cli.maths.products import norm

from vrsim_cli.maths.meshes import PROXY_SAMPLES, load_mesh, proxy, proxy_errors

SPHERE, PLANE, BOX, CAPSULE, CYLINDER, CONVEX, MESH = range(7)
TYPE_NAMES = ("sphere", "plane", "box", "capsule", "cylinder", "convex", "mesh")
GEOMETRIES = ("exact", "sphere", "aabb", "obb", "hull", "mesh")
BROAD_PHASES = ("grid", "sap", "brute")
DEFAULT_TOLERANCE = 1e-3  # m, the slide's epsilon
# ... or this share of the thinnest dynamic body's thinnest extent, when less: with 1 mm
# against plates of 0.2-0.6 mm, stepped stacks of them fell over (corners within the
# tolerance of a face's far side became contacts); at a tenth they stand to 1e-16 m.
TOLERANCE_SHARE = 0.1
_ANALYTIC_TYPE = {"sphere": SPHERE, "plane": PLANE, "box": BOX, "capsule": CAPSULE,
                  "cylinder": CYLINDER}


@dataclass(frozen=True)
class CollisionModel:
    """Constants of collision detection. n_geom geoms, one per colliding body.

    geom_body: (n_geom,) int64 body index
    geom_type: (n_geom,) int64 SPHERE | PLANE | BOX | CAPSULE | CYLINDER | CONVEX | MESH
    geom_geometry: (n_geom,) str, the scene's `collision.geometry` (exact, sphere, ...)
    geom_world_aabb: (n_geom,) bool, box re-fitted to the world axes every step (aabb proxy)
    geom_local_pos: (n_geom, 3) m, geom origin in the body frame
    geom_local_quat: (n_geom, 4) geom orientation in the body frame [w, x, y, z]
    geom_radius: (n_geom,) m, sphere, capsule and cylinder radius
    geom_half: (n_geom, 3) m, box half extents; capsule/cylinder: [r, length/2, r]
    geom_plane_normal: (n_geom, 3) world-frame unit normal of a half-space n.p <= offset
    geom_plane_offset: (n_geom,) m
    geom_rbound: (n_geom,) m, largest distance of a geom point from its body's origin
        (inf for planes); bounds how fast rotation moves the surface
    geom_vertices: (n_geom,) tuple of (V, 3) arrays, body frame (convex, mesh, aabb) or None
    geom_faces: (n_geom,) tuple of (F, 3) int arrays or None
    """

    tolerance: float  # m
    broad_phase: str
    continuous: bool
    geom_body: np.ndarray
    geom_type: np.ndarray
    geom_geometry: tuple
    geom_world_aabb: np.ndarray
    geom_local_pos: np.ndarray
    geom_local_quat: np.ndarray
    geom_radius: np.ndarray
    geom_half: np.ndarray
    geom_plane_normal: np.ndarray
    geom_plane_offset: np.ndarray
    geom_rbound: np.ndarray
    geom_vertices: tuple
    geom_faces: tuple
    cache: dict = field(default_factory=dict, compare=False, repr=False)  # fcl objects

    @property
    def n_geom(self) -> int:
        return len(self.geom_body)


def compile_collision(scene, shapes: list, dim: int, problems: list):
    """The CollisionModel of a scene with a top-level `collision` block, or None when it is
    disabled. Bad mesh files become located problems."""
    top = scene.data.get("collision") or {}
    if not top.get("enabled", True):
        return None
    rows = []
    for i, (body, shape) in enumerate(zip(scene.data.get("bodies") or [], shapes)):
        spec = body.get("collision") or {}
        if shape is None or not spec.get("enabled", True):
            continue
        at = ("bodies", i, "collision", "geometry")
        geometry = spec.get("geometry", "exact")
        if shape["type"] == "mesh":
            if shape.get("path") is None:
                continue  # the missing file is already a problem
            try:
                rows.append(mesh_geom(i, shape, geometry))
            except ValueError as exc:
                problems.append(scene.problem(("bodies", i, "shape", "file"), str(exc),
                                              "vrsim reads OBJ, STL, PLY, GLB and glTF"))
            continue
        if geometry != "exact":
            problems.append(scene.problem(at, f"'{geometry}' is a proxy computed from a "
                                          f"render mesh; this body is a {shape['type']}",
                                          "use geometry: exact (analytic shapes are tested "
                                          "exactly)"))
            continue
        rows.append(analytic_geom(i, shape, dim))
    # Emitted particles (bodies after the scene's list) collide as the spheres they are.
    for i in range(len(scene.data.get("bodies") or []), len(shapes)):
        rows.append(analytic_geom(i, shapes[i], dim))
    return _table(rows, top)


def analytic_geom(body: int, shape: dict, dim: int = 3) -> dict:
    """One geom row for an analytic shape (see CollisionModel for the fields)."""
    kind = _ANALYTIC_TYPE[shape["type"]]
    row = _row(body, kind, "exact")
    if kind == SPHERE:
        row["radius"] = r = float(shape["radius"])
        row["half"] = np.full(3, r)
        row["rbound"] = r
    elif kind == BOX:
        half = 0.5 * np.asarray(shape["size"], dtype=float)
        if dim == 2:  # planar boxes get a z depth that never decides a contact
            half[2] = max(half[0], half[1], 0.5)
        row["half"] = half
        row["rbound"] = float(norm(half))
    elif kind == PLANE:
        row["plane_normal"] = np.asarray(shape["normal"], dtype=float)
        row["plane_offset"] = float(shape["offset"])
        row["rbound"] = math.inf
    else:
        r, h = float(shape["radius"]), 0.5 * float(shape["length"])
        row["radius"], row["half"] = r, np.array([r, h, r])
        row["rbound"] = h + r if kind == CAPSULE else math.hypot(h, r)
    return row


def thinnest(cm: "CollisionModel", dynamic) -> tuple[float, int]:
    """(m, body): the least extent of a dynamic body's collision shape across its thinnest
    direction, and that body ((inf, -1) without one). `dynamic`: (n_body,) bool. A
    sphere or capsule: its diameter; a box: its shortest side; a cylinder: the lesser of
    its diameter and length; a hull or mesh: its least extent along its faces' normals
    (`_mesh_thinness`)."""
    best, body = math.inf, -1
    for g in range(len(cm.geom_body)):
        b = int(cm.geom_body[g])
        if not dynamic[b] or int(cm.geom_type[g]) == PLANE:
            continue
        extent = geom_thinness(cm, g)
        if extent < best:
            best, body = extent, b
    return best, body


def geom_thinness(cm: "CollisionModel", g: int) -> float:
    """The least extent (m) of geom g across its thinnest direction (`thinnest`); a
    plane's is infinite."""
    kind = int(cm.geom_type[g])
    half = cm.geom_half[g]
    if kind == PLANE:
        return math.inf
    if kind in (SPHERE, CAPSULE):
        return 2.0 * float(cm.geom_radius[g])
    if kind == CYLINDER:
        return 2.0 * min(float(cm.geom_radius[g]), float(half[1]))
    if kind == BOX:
        return 2.0 * float(half.min())
    return _mesh_thinness(cm.geom_vertices[g], cm.geom_faces[g], kind)


def body_thinness(cm: "CollisionModel", n_body: int) -> np.ndarray:
    """(n_body,) m: each body's thinnest geom (`geom_thinness`; a triangle mesh, which
    collides on both sides of its surface, and a body without geoms: infinite). Cached."""
    key = ("body thinness", n_body)
    if key not in cm.cache:
        out = np.full(n_body, math.inf)
        for g in range(len(cm.geom_body)):
            if int(cm.geom_type[g]) != MESH:
                b = int(cm.geom_body[g])
                out[b] = min(out[b], geom_thinness(cm, g))
        cm.cache[key] = out
    return cm.cache[key]


THIN_NORMALS = 1024  # a mesh's triangle normals are tried this many at a time


def _mesh_thinness(vertices, faces, kind) -> float:
    """A hull's or mesh's least extent (m) along its faces' normals: exact for a plate,
    prism or box in any pose within its file (the shortest side of the vertices' box
    read 36.8 mm for a 2 mm plate turned 45 deg in its file: an independent review); an
    upper bound otherwise (`maths.polytope.widths`). Without faces, that box's side."""
    v = np.asarray(vertices, float) if vertices is not None else np.zeros((0, 3))
    if not len(v):
        return math.inf
    extent = float((v.max(axis=0) - v.min(axis=0)).min())
    if faces is None or not len(faces):
        return extent
    if kind == CONVEX:
        normals = facets(v, faces).normals
    else:  # a mesh: its triangles' distinct normals (a plate has few)
        tri = v[np.asarray(faces, np.int64)]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.sqrt(np.einsum("ij,ij->i", n, n))
        n = n[length > 0.0] / length[length > 0.0, None]
        normals = np.unique(np.round(n, 12), axis=0)
    for start in range(0, len(normals), THIN_NORMALS):
        extent = min(extent, float(widths(v, normals[start:start + THIN_NORMALS]).min()))
    return extent


def _row(body: int, kind: int, geometry: str) -> dict:
    return {"body": body, "type": kind, "geometry": geometry, "world_aabb": False,
            "local_pos": np.zeros(3), "local_quat": np.array([1.0, 0.0, 0.0, 0.0]),
            "radius": 0.0, "half": np.zeros(3), "plane_normal": np.zeros(3),
            "plane_offset": 0.0, "rbound": 0.0, "vertices": None, "faces": None}


def _frozen(values, shape, dtype=float) -> np.ndarray:
    out = np.array(values, dtype=dtype).reshape(shape)
    out.flags.writeable = False
    return out


def _table(rows: list[dict], top: dict) -> CollisionModel:
    n = len(rows)
    col = {k: [r[k] for r in rows] for k in _row(0, 0, "").keys()}
    return CollisionModel(
        tolerance=float(top.get("tolerance", DEFAULT_TOLERANCE)),
        broad_phase=str(top.get("broad_phase", "grid")),
        continuous=bool(top.get("continuous", True)),
        geom_body=_frozen(col["body"], (n,), np.int64),
        geom_type=_frozen(col["type"], (n,), np.int64),
        geom_geometry=tuple(col["geometry"]),
        geom_world_aabb=_frozen(col["world_aabb"], (n,), bool),
        geom_local_pos=_frozen(col["local_pos"], (n, 3)),
        geom_local_quat=_frozen(col["local_quat"], (n, 4)),
        geom_radius=_frozen(col["radius"], (n,)),
        geom_half=_frozen(col["half"], (n, 3)),
        geom_plane_normal=_frozen(col["plane_normal"], (n, 3)),
        geom_plane_offset=_frozen(col["plane_offset"], (n,)),
        geom_rbound=_frozen(col["rbound"], (n,)),
        geom_vertices=tuple(col["vertices"]),
        geom_faces=tuple(col["faces"]),
    )


def table(rows: list[dict], tolerance: float = DEFAULT_TOLERANCE, broad_phase: str = "grid",
          continuous: bool = True) -> CollisionModel:
    """A CollisionModel from geom rows (tests and benchmarks build scenes this way)."""
    return _table(rows, {"tolerance": tolerance, "broad_phase": broad_phase,
                         "continuous": continuous})


def mesh_geom(body: int, shape: dict, geometry: str) -> dict:
    """The geom row (see CollisionModel) of a mesh body for `geometry`."""
    mesh = load_mesh(shape["path"], float(shape.get("scale", 1.0)))
    geometry = "mesh" if geometry == "exact" else geometry
    p = proxy(mesh, geometry)  # a flat mesh has its triangles, but no hull
    if geometry == "sphere":
        row = _row(body, SPHERE, geometry)
        row["local_pos"], row["radius"] = p["centre"], p["radius"]
        row["half"] = np.full(3, p["radius"])
        row["rbound"] = float(norm(p["centre"])) + p["radius"]
        return row
    if geometry == "obb":
        row = _row(body, BOX, geometry)
        row["local_pos"], row["local_quat"], row["half"] = p["centre"], p["quat"], p["half"]
        row["rbound"] = float(norm(p["centre"]) + norm(p["half"]))
        return row
    row = _row(body, {"aabb": BOX, "hull": CONVEX, "mesh": MESH}[geometry], geometry)
    row["vertices"] = p["vertices"]
    row["faces"] = p.get("faces")
    row["world_aabb"] = geometry == "aabb"
    row["rbound"] = float(np.linalg.norm(p["vertices"], axis=1).max())
    return row


def mesh_pair_notes(data: dict, cm: CollisionModel) -> tuple:
    """Notes for triangle meshes (geometry mesh) that can meet a cylinder, a hull or
    another mesh (one of the two bodies not static): those pairs go to python-fcl, whose
    contacts against triangles are not checked for tunnelling (spheres, capsules, boxes
    and planes are: closed forms, stages/collision/mesh_pairs.py)."""
    bodies = data.get("bodies") or []
    static = [i < len(bodies) and bodies[i].get("type") == "static"
              for i in range(int(cm.geom_body.max(initial=-1)) + 1)]
    meshes = np.flatnonzero(cm.geom_type == MESH)
    others = np.flatnonzero(np.isin(cm.geom_type, (CYLINDER, CONVEX, MESH)))
    for g in meshes.tolist():
        for h in others.tolist():
            a, b = int(cm.geom_body[g]), int(cm.geom_body[h])
            if a != b and not (static[a] and static[b]):
                kind = {CYLINDER: "cylinder", CONVEX: "convex hull", MESH: "triangle mesh"}
                return (f"bodies[{a}] collides as a triangle mesh with bodies[{b}], a "
                        f"{kind[int(cm.geom_type[h])]}: that pair goes to python-fcl, "
                        f"whose contacts are not checked against tunnelling (meshes meet "
                        f"spheres, capsules, boxes and planes in closed form, and so do the "
                        f"obb and sphere proxies; docs/collision.md)",)
    return ()


def scene_proxy_report(model, samples: int = PROXY_SAMPLES) -> list[dict]:
    """`proxy_errors` for every mesh body of a compiled model, with the geometry the body
    collides with (its collision.geometry, or 'none' without a collision block)."""
    report = []
    for i, shape in enumerate(model.body_shape):
        if shape is None or shape["type"] != "mesh" or shape.get("path") is None:
            continue
        mesh = load_mesh(shape["path"], float(shape.get("scale", 1.0)))
        geometry = "none"
        cm = model.collision
        if cm is not None and i in cm.geom_body.tolist():
            geometry = cm.geom_geometry[cm.geom_body.tolist().index(i)]
        report.append({"body": model.body_name[i], "file": shape["path"],
                       "triangles": int(len(mesh.faces)), "geometry": geometry,
                       "proxies": proxy_errors(mesh, samples)})
    return report
