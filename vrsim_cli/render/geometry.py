"""Triangle meshes of the unit primitives and the draw list of a model. numpy only.

Every body is drawn as one or more *parts*: a unit primitive (sphere of radius 1, cube of
edge 1, cylinder of radius 1 and height 1 along y, square of edge 1 in the xz plane)
placed in the body's frame by a local (4, 4) transform that scales and offsets it. A
capsule is a cylinder and two spheres: the hidden inner halves of the spheres cost less
than a separate hemisphere mesh. Normals under non-uniform scale are right because
fixed-function OpenGL transforms them by the inverse transpose (and GL_NORMALIZE rescales).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.spatial import quat_to_matrix
from vrsim_cli.model.model import BODY_KINEMATIC

SPHERE, BOX, CYLINDER, QUAD = "sphere", "box", "cylinder", "quad"
POINT_MASS_RADIUS = 0.025  # m, drawn size of a body without a shape (as in MCAP /scene)
PLANE_EXTENT = 20.0  # m, edge of the square that stands for an infinite plane
THIN = 1e-3  # m, thickness given to the zero z-size of 2D boxes


def unit_sphere(slices: int = 24, stacks: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of the unit sphere: vertices (n, 3) and normals (n, 3), float32."""
    theta = np.linspace(0.0, np.pi, stacks + 1)  # from +y down
    phi = np.linspace(0.0, 2.0 * np.pi, slices + 1)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    grid = np.stack([np.sin(t) * np.sin(p), np.cos(t), np.sin(t) * np.cos(p)], axis=-1)
    a, b = grid[:-1, :-1], grid[1:, :-1]
    c, d = grid[1:, 1:], grid[:-1, 1:]
    tris = np.concatenate([np.stack([a, b, c], -2), np.stack([a, c, d], -2)]).reshape(-1, 3)
    return tris.astype(np.float32), tris.astype(np.float32)


def unit_box() -> tuple[np.ndarray, np.ndarray]:
    """Triangles of the cube [-0.5, 0.5]^3 with flat face normals."""
    verts, norms = [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = (axis + 1) % 3, (axis + 2) % 3
            corners = []
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                corner = np.zeros(3)
                corner[axis], corner[u], corner[v] = 0.5 * sign, 0.5 * du, 0.5 * dv * sign
                corners.append(corner)
            quad = [corners[i] for i in (0, 1, 2, 0, 2, 3)]
            normal = np.zeros(3)
            normal[axis] = sign
            verts += quad
            norms += [normal] * 6
    return np.array(verts, np.float32), np.array(norms, np.float32)


def unit_cylinder(slices: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of the cylinder of radius 1, y in [-0.5, 0.5], with its two caps."""
    phi = np.linspace(0.0, 2.0 * np.pi, slices + 1)
    ring = np.stack([np.sin(phi), np.zeros_like(phi), np.cos(phi)], axis=-1)
    lo, hi = ring + [0.0, -0.5, 0.0], ring + [0.0, 0.5, 0.0]
    side = np.stack([lo[:-1], lo[1:], hi[1:], lo[:-1], hi[1:], hi[:-1]], axis=1)
    side_n = np.stack([ring[:-1], ring[1:], ring[1:], ring[:-1], ring[1:], ring[:-1]], axis=1)
    top_centre = np.broadcast_to([0.0, 0.5, 0.0], (slices, 3))
    top = np.stack([top_centre, hi[:-1], hi[1:]], axis=1)
    bottom = np.stack([top_centre - [0.0, 1.0, 0.0], lo[1:], lo[:-1]], axis=1)
    verts = np.concatenate([side.reshape(-1, 3), top.reshape(-1, 3), bottom.reshape(-1, 3)])
    norms = np.concatenate([side_n.reshape(-1, 3), np.tile([0.0, 1.0, 0.0], (3 * slices, 1)),
                            np.tile([0.0, -1.0, 0.0], (3 * slices, 1))])
    return verts.astype(np.float32), norms.astype(np.float32)


def unit_quad() -> tuple[np.ndarray, np.ndarray]:
    """Two triangles: the square [-0.5, 0.5]^2 in the xz plane, facing +y."""
    c = [[-0.5, 0, -0.5], [-0.5, 0, 0.5], [0.5, 0, 0.5], [0.5, 0, -0.5]]
    verts = np.array([c[i] for i in (0, 1, 2, 0, 2, 3)], np.float32)
    return verts, np.tile(np.float32([0.0, 1.0, 0.0]), (6, 1))


PRIMITIVES = {SPHERE: unit_sphere, BOX: unit_box, CYLINDER: unit_cylinder, QUAD: unit_quad}
UNIT_HALF_EXTENT = {SPHERE: (1.0, 1.0, 1.0), BOX: (0.5, 0.5, 0.5), CYLINDER: (1.0, 0.5, 1.0),
                    QUAD: (0.5, 0.0, 0.5)}


def _scale(sx, sy, sz, offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    local = np.diag([sx, sy, sz, 1.0])
    local[:3, 3] = offset
    return local


@dataclass(frozen=True)
class DrawList:
    """What to draw for a model, one row per part.

    part_body: (n_part,) int64 body index, -1 for parts fixed in the world (planes)
    part_mesh: (n_part,) str, a primitive name or a mesh file path
    part_local: (n_part, 4, 4) transform in the body frame (world frame for planes)
    part_color: (n_part, 4) RGBA in [0, 1]
    """

    part_body: np.ndarray
    part_mesh: tuple
    part_local: np.ndarray
    part_color: np.ndarray


def draw_list(model) -> DrawList:
    """The parts of every body of `model` (a `Model`), in body order."""
    bodies, meshes, locals_, colors = [], [], [], []

    def add(body: int, mesh: str, local: np.ndarray) -> None:
        bodies.append(body)
        meshes.append(mesh)
        locals_.append(local)
        colors.append(model.body_color[body])

    for i, shape in enumerate(model.body_shape):
        kind = (shape or {}).get("type")
        if kind is None:
            add(i, SPHERE, _scale(*[POINT_MASS_RADIUS] * 3))
        elif kind == "sphere":
            add(i, SPHERE, _scale(*[shape["radius"]] * 3))
        elif kind == "box":
            add(i, BOX, _scale(*[s if s > 0 else THIN for s in shape["size"]]))
        elif kind in ("cylinder", "capsule"):
            r, length = shape["radius"], shape["length"]
            add(i, CYLINDER, _scale(r, length, r))
            if kind == "capsule":
                for end in (-0.5 * length, 0.5 * length):
                    add(i, SPHERE, _scale(r, r, r, (0.0, end, 0.0)))
        elif kind == "plane":
            local = np.eye(4)
            local[:3, :3] = quat_to_matrix(shape["orientation"]) * PLANE_EXTENT
            local[:3, 3] = np.asarray(shape["normal"]) * shape["offset"]
            add(i, QUAD, local)
            bodies[-1] = -1  # a plane is the half-space itself, not placed by the body
        elif kind == "mesh":
            scale = float(shape.get("scale", 1.0))
            add(i, shape["path"], _scale(scale, scale, scale))
    return DrawList(np.array(bodies, dtype=np.int64), tuple(meshes),
                    np.reshape(locals_, (len(bodies), 4, 4)), np.reshape(colors, (len(bodies), 4)))


def body_transforms(pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """(n, 4, 4) body -> world transforms from positions (n, 3) m and quaternions (n, 4)."""
    out = np.zeros((len(pos), 4, 4))
    out[:, :3, :3] = quat_to_matrix(quat)
    out[:, :3, 3] = pos
    out[:, 3, 3] = 1.0
    return out


def bounding_spheres(model, dl: DrawList) -> tuple[np.ndarray, np.ndarray]:
    """Points (n, 3) m and radii (n,) m whose union holds every part at t = 0 that a
    camera should see: the two extreme corners of each part's world-aligned box.

    Planes are left out (they are infinite). Moving bodies add the points of
    `flight_points`: the fountain's spray, a thrown ball's apex and landing.
    """
    world = body_transforms(model.body_pos0, model.body_quat0)
    keep = dl.part_body >= 0
    placed = world[dl.part_body[keep]] @ dl.part_local[keep]
    # Half-extents of the unit primitives; a mesh is taken to span about its scale.
    half = np.array([UNIT_HALF_EXTENT.get(m, (1.0, 1.0, 1.0)) for m in dl.part_mesh],
                    dtype=float).reshape(-1, 3)[keep]
    reach = np.einsum("nij,nj->ni", np.abs(placed[:, :3, :3]), half)  # world-aligned box
    centres = np.concatenate([placed[:, :3, 3] - reach, placed[:, :3, 3] + reach])
    flight = flight_points(model)
    return np.concatenate([centres, flight]), np.zeros(len(centres) + len(flight))


def flight_points(model) -> np.ndarray:
    """(k, 3) m: where the moving bodies go if nothing but gravity acts on them.

    Dynamic bodies: the top of the free flight and the point where it comes back to the
    ground height (0 along the up direction -g, or the start height if lower), both within
    the run's duration. Kinematic bodies: their position at the end of the run. Height
    along up: h(t) = h0 + w t - |g| t^2 / 2 with w = v0 . up, so the top is at t = w / |g|
    and the landing at t = (w + sqrt(w^2 + 2 |g| (h0 - ground))) / |g|.
    """
    pos, vel, duration = model.body_pos0, model.body_vel0, model.duration
    kinematic = model.body_type == BODY_KINEMATIC
    points = [pos[kinematic] + vel[kinematic] * duration]
    g = np.asarray(model.gravity, dtype=float)
    g_norm = float(np.linalg.norm(g))
    dynamic = model.body_inv_mass > 0
    if g_norm > 0 and dynamic.any():
        up = -g / g_norm
        p0, v0 = pos[dynamic], vel[dynamic]
        h0, w = p0 @ up, v0 @ up
        ground = np.minimum(0.0, h0)
        t_top = np.clip(w / g_norm, 0.0, duration)
        t_land = np.clip((w + np.sqrt(w * w + 2.0 * g_norm * (h0 - ground))) / g_norm, 0.0,
                         duration)
        for t in (t_top, t_land):
            points.append(p0 + v0 * t[:, None] + 0.5 * g * t[:, None] ** 2)
    elif dynamic.any():
        points.append(pos[dynamic] + vel[dynamic] * duration)
    return np.concatenate(points).reshape(-1, 3)


def body_radii(model) -> tuple[np.ndarray, np.ndarray]:
    """(bounding (n_body,), inner (n_body,)) m: the radius of a sphere about each body's
    origin that holds all its parts, and the half-extent of its thinnest part (what is
    seen of it at least). Planes (infinite) get 0 for both."""
    dl = draw_list(model)
    bounding = np.zeros(model.n_body)
    inner = np.full(model.n_body, np.inf)
    half = np.array([UNIT_HALF_EXTENT.get(m, (1.0, 1.0, 1.0)) for m in dl.part_mesh],
                    dtype=float).reshape(-1, 3)
    for body, local, h in zip(dl.part_body.tolist(), dl.part_local, half):
        if body < 0:
            continue
        extents = np.abs(local[:3, :3]) @ h  # the part's box half-sizes, body-aligned
        reach = float(np.linalg.norm(local[:3, 3]) + np.linalg.norm(extents))
        bounding[body] = max(bounding[body], reach)
        inner[body] = min(inner[body], float(np.min(extents[extents > 0], initial=reach)))
    inner[~np.isfinite(inner)] = 0.0
    return bounding, inner
