"""Triangle meshes of the unit primitives and the draw list of a model. numpy only.

Every body is drawn as one or more *parts*: a unit primitive (sphere of radius 1, cube of
edge 1, cylinder of radius 1 and height 1 along y, square of edge 1 in the xz plane)
placed in the body's frame by a local (4, 4) transform that scales and offsets it. A
capsule is a cylinder and two spheres: the hidden inner halves of the spheres cost less
than a separate hemisphere mesh. Normals under non-uniform scale are right because
fixed-function OpenGL transforms them by the inverse transpose (and GL_NORMALIZE rescales).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vrsim_cli.maths.spatial import quat_to_matrix
from vrsim_cli.model.model import BODY_KINEMATIC

SPHERE, BOX, CYLINDER, QUAD = "sphere", "box", "cylinder", "quad"
POINT_MASS_RADIUS = 0.025  # m, drawn size of a lone point mass (as in MCAP /scene)
POINT_MASS_FRACTION = 0.01  # a point mass is drawn with this fraction of the scene's size
PARTICLE_FRACTION = 0.15  # a body's particle: this fraction of its closest particle pair
HULL_ALPHA = 0.35  # the hull joining a body's particles is translucent: they show inside
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
class Stage:
    """The ground the bodies are drawn over, sized to the action of a run.

    centre: (3,) m, the middle of the action; half: m, half the side of the grid; step:
    m, the grid's spacing (a power of ten that gives about ten lines across the action);
    plane: "xz" (3D: the grid on the ground, at height `level` along y) or "xy" (2D: a
    flat grid behind the bodies, at z = `level`); plane_edge: m, the side of the square
    that stands for an infinite plane, centred under the action.
    """

    centre: tuple = (0.0, 0.0, 0.0)
    half: float = 10.0
    step: float = 1.0
    plane: str = "xz"
    level: float = 0.0
    plane_edge: float = PLANE_EXTENT

    def grid_lines(self) -> np.ndarray:
        """(m, 2, 3) m: the grid's line segments."""
        c = np.asarray(self.centre, dtype=float)
        n = int(round(self.half / self.step))
        u_axis, v_axis, w_axis = (0, 2, 1) if self.plane == "xz" else (0, 1, 2)
        u0 = round(c[u_axis] / self.step) * self.step  # lines on multiples of the step
        v0 = round(c[v_axis] / self.step) * self.step
        ticks = np.arange(-n, n + 1) * self.step
        out = []
        for along, across, base_a, base_b in ((u_axis, v_axis, u0, v0),
                                              (v_axis, u_axis, v0, u0)):
            for t in ticks:
                a, b = np.zeros(3), np.zeros(3)
                a[w_axis] = b[w_axis] = self.level
                a[along] = b[along] = base_a + t
                a[across], b[across] = base_b - n * self.step, base_b + n * self.step
                out.append((a, b))
        return np.array(out)


def sized_planes(dl: "DrawList", stage: Stage) -> np.ndarray:
    """(n_part, 4, 4): the parts' local transforms with every plane's square resized to
    stage.plane_edge and centred where the action's middle falls on the plane."""
    local = dl.part_local.copy()
    c = np.asarray(stage.centre, dtype=float)
    for j in np.flatnonzero(dl.part_body < 0):
        rot = local[j, :3, :3] / np.linalg.norm(local[j, :3, 0])  # unit axes of the square
        normal, origin = rot[:, 1], local[j, :3, 3]
        local[j, :3, :3] = rot * stage.plane_edge
        local[j, :3, 3] = c - ((c - origin) @ normal) * normal
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
    # meshes made here (the hull of a particle body): name -> (vertices (n, 3) float32,
    # normals (n, 3) float32), drawn from both sides
    meshes: dict = field(default_factory=dict)

    def half_extents(self) -> np.ndarray:
        """(n_part, 3): the half-size of each part's unit mesh along its local axes."""
        out = []
        for m in self.part_mesh:
            if m in self.meshes:
                out.append(np.abs(self.meshes[m][0]).max(axis=0) if len(self.meshes[m][0])
                           else np.zeros(3))
            else:  # a mesh file is taken to span about its scale
                out.append(UNIT_HALF_EXTENT.get(m, (1.0, 1.0, 1.0)))
        return np.array(out, dtype=float).reshape(-1, 3)


def draw_list(model) -> DrawList:
    """The parts of every body of `model` (a `Model`), in body order."""
    bodies, names, locals_, colors = [], [], [], []

    def add(body: int, mesh: str, local: np.ndarray) -> None:
        bodies.append(body)
        names.append(mesh)
        locals_.append(local)
        colors.append(model.body_color[body])

    meshes: dict = {}
    point_radius = point_mass_radius(model)
    for i, shape in enumerate(model.body_shape):
        kind = (shape or {}).get("type")
        particles = body_particles(model, i) if kind is None else None
        if particles is not None:  # each particle, and the hull that joins them
            r = particle_radius(particles, point_radius)
            for p in particles:
                add(i, SPHERE, _scale(r, r, r, p))
            hull = hull_triangles(particles, model.dimension == 2)
            if hull is not None:
                meshes[f"hull:{i}"] = hull
                add(i, f"hull:{i}", np.eye(4))
                colors[-1] = (*np.asarray(model.body_color[i])[:3],
                              HULL_ALPHA * float(np.asarray(model.body_color[i])[3]))
        elif kind is None:
            add(i, SPHERE, _scale(*[point_radius] * 3))
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
    return DrawList(np.array(bodies, dtype=np.int64), tuple(names),
                    np.reshape(locals_, (len(bodies), 4, 4)), np.reshape(colors, (len(bodies), 4)),
                    meshes)


def body_particles(model, i: int) -> np.ndarray | None:
    """(k, 3) m: the particles of body i in its body frame (relative to the centre of
    mass, turning with it), for a body made of two or more particles; else None."""
    rigid = model.rigid
    if rigid is None or i >= len(rigid.mass_properties) or rigid.mass_properties[i] is None:
        return None
    particles = rigid.mass_properties[i].particles
    if particles is None or len(particles) < 2:
        return None
    return np.asarray(particles, dtype=float).reshape(-1, 3)


def particle_radius(particles: np.ndarray, fallback: float) -> float:
    """m: the drawn radius of a body's particles, PARTICLE_FRACTION of the closest pair
    (they never touch); `fallback` when particles coincide."""
    gaps = np.linalg.norm(particles[:, None] - particles[None], axis=-1)
    gaps[np.diag_indices(len(particles))] = np.inf
    closest = float(gaps.min())
    return PARTICLE_FRACTION * closest if np.isfinite(closest) and closest > 0 else fallback


def point_mass_radius(model) -> float:
    """m: the drawn radius of a point mass, POINT_MASS_FRACTION of the scene's size (the
    diagonal of the box around the bodies at the start and where their free flights go);
    POINT_MASS_RADIUS for a scene of one point at rest."""
    keep = np.array([(s or {}).get("type") != "plane" for s in model.body_shape], dtype=bool)
    points = np.concatenate([np.asarray(model.body_pos0, dtype=float)[keep],
                             flight_points(model)]).reshape(-1, 3)
    if len(points) < 2:
        return POINT_MASS_RADIUS
    size = float(np.linalg.norm(points.max(axis=0) - points.min(axis=0)))
    return POINT_MASS_FRACTION * size if size > 0 else POINT_MASS_RADIUS


def hull_triangles(points: np.ndarray, planar: bool):
    """Triangles (vertices (n, 3), normals (n, 3), float32) of the convex hull of
    `points` (k, 3): for points in one plane (every 2D scene) the polygon around them in
    that plane, else the hull's faces (scipy's Qhull, when installed). None when the
    points span no area (two particles, a line) or, in 3D, scipy is missing (the
    particles are then drawn alone)."""
    centre = points.mean(axis=0)
    _, sv, axes = np.linalg.svd(points - centre)
    size = sv[0] if len(sv) else 0.0
    thin = len(sv) < 3 or sv[2] <= 1e-9 * max(size, 1e-300)
    if planar or thin:
        normal = np.array([0.0, 0.0, 1.0]) if planar else axes[2]
        u = axes[0] - normal * (axes[0] @ normal)
        u /= max(np.linalg.norm(u), 1e-300)
        v = np.cross(normal, u)
        ring = _hull_2d(np.column_stack([(points - centre) @ u, (points - centre) @ v]))
        if len(ring) < 3:
            return None
        middle = ring.mean(axis=0)
        fan = np.array([[middle, ring[j], ring[(j + 1) % len(ring)]]
                        for j in range(len(ring))]).reshape(-1, 2)
        verts = centre + fan[:, :1] * u + fan[:, 1:] * v
        return (verts.astype(np.float32),
                np.tile(normal.astype(np.float32), (len(verts), 1)))
    try:
        from scipy.spatial import ConvexHull
    except ImportError:
        return None
    try:
        hull = ConvexHull(points)
    except Exception:  # Qhull's precision errors on nearly flat sets: the particles alone
        return None
    tris = points[hull.simplices]  # (f, 3, 3)
    normals = hull.equations[:, :3]
    # wind each face counter-clockwise seen from outside
    flip = np.einsum("ij,ij->i", np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]),
                     normals) < 0
    tris[flip] = tris[flip][:, ::-1]
    return (tris.reshape(-1, 3).astype(np.float32),
            np.repeat(normals, 3, axis=0).astype(np.float32))


def _hull_2d(xy: np.ndarray) -> np.ndarray:
    """(m, 2): the convex hull of points (k, 2), counter-clockwise (Andrew's monotone
    chain); collinear points are left out."""
    pts = np.unique(xy, axis=0)
    if len(pts) < 3:
        return pts

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    lower, upper = [], []
    for p in pts:
        while len(lower) >= 2 and cross(lower[-2], lower[-1], p) <= 0:
            lower.pop()
        lower.append(p)
    for p in pts[::-1]:
        while len(upper) >= 2 and cross(upper[-2], upper[-1], p) <= 0:
            upper.pop()
        upper.append(p)
    return np.array(lower[:-1] + upper[:-1])


def spring_segments(model, state) -> np.ndarray:
    """(s, 2, 3) m: the two world ends of every spring in `state` (an end on a rotating
    body turns with it; an end on a body that does not rotate keeps its world lever arm;
    b < 0 is a world anchor), as the dynamics applies the spring force."""
    rigid = model.rigid
    if rigid is None or not len(rigid.spring_a):
        return np.zeros((0, 2, 3))
    R = quat_to_matrix(state.body_quat)

    def end(body, point):
        point = np.asarray(point, dtype=float)
        anchor = body < 0
        b = np.maximum(body, 0)
        turns = rigid.rot_slot[b] >= 0
        arm = np.where(turns[:, None], np.einsum("kij,kj->ki", R[b], point), point)
        return np.where(anchor[:, None], point, state.body_pos[b] + arm)

    return np.stack([end(rigid.spring_a, rigid.spring_point_a),
                     end(rigid.spring_b, rigid.spring_point_b)], axis=1)


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
    half = dl.half_extents()[keep]
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
    half = dl.half_extents()
    for body, local, h in zip(dl.part_body.tolist(), dl.part_local, half):
        if body < 0:
            continue
        extents = np.abs(local[:3, :3]) @ h  # the part's box half-sizes, body-aligned
        reach = float(np.linalg.norm(local[:3, 3]) + np.linalg.norm(extents))
        bounding[body] = max(bounding[body], reach)
        inner[body] = min(inner[body], float(np.min(extents[extents > 0], initial=reach)))
    inner[~np.isfinite(inner)] = 0.0
    return bounding, inner
