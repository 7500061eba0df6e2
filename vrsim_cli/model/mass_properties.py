"""Mass, centre of mass and inertia tensor of a body (slide 5.3).

Layer 2 helper of `model.rigid` (numbers only; it never imports the scene module, trimesh only when a mesh
body needs it). A body's mass properties come from, in this order:

1. `particles`: point masses `m^i` at `p^i` (a list, or the generator
   `{grid: {n, size, mass}}` for the slide's cube). `m = sum m^i`,
   `S = (1/m) sum m^i p^i`, and the centre of mass becomes the origin of model
   coordinates: `p0^i = p^i - S`. `I = sum m^i (|p0^i|^2 E - p0^i p0^i^T)`, which is the
   slide's matrix `I^i` summed (slide 5.3.2), and `I = sum m^i |p0^i|^2` in 2D (5.3.1).
2. the shape with `mass` or `density`: closed forms (below), trimesh for meshes.
3. `inertia` given explicitly replaces the tensor of 1 or 2 (the mass stays).

All tensors are about the centre of mass, in body (model) coordinates, kg m^2.
2D bodies are laminae in the z = 0 plane (density in kg/m^2); their planar moment is
`inertia[2, 2]`.

Closed forms (3D; capsule and cylinder along the local y axis, `L` the length of the
cylindrical part, `r` the radius):
- sphere: `2/5 m r^2 E`
- box (a, b, c): `m/12 diag(b^2 + c^2, a^2 + c^2, a^2 + b^2)`
- cylinder: `Iyy = m r^2 / 2`, `Ixx = Izz = m (3 r^2 + L^2) / 12`
- capsule, cylinder part `mc`, the two hemispheres `ms` together:
  `Iyy = mc r^2/2 + ms 2 r^2/5`, `Ixx = Izz = mc (L^2/12 + r^2/4) + ms (2 r^2/5 + L^2/4 + 3 L r/8)`
  (each hemisphere's centroid lies 3r/8 from its flat face).
2D laminae: disc `Izz = m r^2/2`; rectangle (a, b) `m (a^2 + b^2)/12`; a 2D cylinder is
its side view, the rectangle 2r x L; a 2D capsule is a stadium, rectangle `mr` plus two
half-discs `md`: `Izz = mr ((2r)^2 + L^2)/12 + md (r^2/2 + L^2/4 + 4 r L/(3 pi))`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.eigen import det3, eigh3, principal_axes
from vrsim_cli.scene.files import MAX_MESH_BYTES

SHAPES_WITH_MASS = ("sphere", "box", "capsule", "cylinder", "mesh")


@dataclass(frozen=True)
class MassProperties:
    """mass: kg. com: (3,) m, centre of mass in the coordinates the geometry was given in
    (particles: their own frame; closed-form shapes: the shape's centre, 0; meshes: the
    mesh file's frame). inertia: (3, 3) kg m^2 about the com, body frame.
    particles: (k, 3) m, positions relative to the com (p0 of the slide), or None.
    grid_n: n of a grid generator, or None. source: where the numbers came from."""

    mass: float
    com: np.ndarray
    inertia: np.ndarray
    source: str
    particles: np.ndarray | None = None
    particle_mass: np.ndarray | None = None
    grid_n: int | None = None

    def principal(self) -> tuple[np.ndarray, np.ndarray]:
        """(moments (3,) ascending, axes (3, 3) with the axes as columns, right-handed).
        A tensor that is diagonal up to round-off keeps the body axes (a rotation would
        pick arbitrary axes inside a degenerate eigenspace, e.g. for the slide's cube);
        the others go through our Jacobi solver (`maths.eigen`: no LAPACK)."""
        inertia = self.inertia
        off = inertia - np.diag(np.diag(inertia))
        if np.abs(off).max() <= 1e-12 * np.abs(inertia).max():
            # moments equal up to round-off count as equal, so the body axes keep their order
            key = np.round(np.diag(inertia) / max(np.abs(inertia).max(), 1e-300), 12)
            order = np.argsort(key, kind="stable")
            axes = np.eye(3)[:, order]
            if det3(axes) < 0:
                axes[:, 2] = -axes[:, 2]
            return np.diag(inertia)[order], axes
        return principal_axes(inertia)


class MassPropertyError(ValueError):
    """A body's mass properties cannot be computed; `key` names the scene key at fault."""

    def __init__(self, key: tuple, message: str, hint: str | None = None):
        super().__init__(message)
        self.key, self.message, self.hint = key, message, hint


def _vec3(values, dim: int) -> np.ndarray:
    out = np.zeros(3)
    out[:len(values)] = values
    return out


def grid_particles(n: int, size: float, mass: float, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """The slide's cube [0, size]^3 from (n+1)^3 particles at size*(i/n, j/n, k/n), each of
    mass m/(n+1)^3 (a square of (n+1)^2 particles in 2D). Returns positions (k, 3), masses (k,)."""
    ticks = size * np.arange(n + 1) / n
    axes = [ticks] * dim + [np.zeros(1)] * (3 - dim)
    pos = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return pos, np.full(len(pos), mass / len(pos))


def particle_properties(pos: np.ndarray, mass: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Slide 5.3.2: (m, S, I) of point masses at `pos` (k, 3) with masses (k,)."""
    total = float(mass.sum())
    com = (mass[:, None] * pos).sum(0) / total
    p0 = pos - com
    sq = (p0 * p0).sum(1)
    inertia = (mass * sq).sum() * np.eye(3) - np.einsum("k,ki,kj->ij", mass, p0, p0)
    return total, com, inertia


def cube_inertia_formula(n: int, mass: float) -> float:
    """The diagonal of the slide's particle cube: m (1/6 + 1/(3n)) (the slide prints a minus
    sign: an erratum, see docs/slides.md)."""
    return mass * (1.0 / 6.0 + 1.0 / (3.0 * n))


def shape_volume(shape: dict, dim: int) -> float:
    """m^3 (3D) or m^2 (2D) of a closed-form shape."""
    kind = shape["type"]
    if kind == "sphere":
        r = shape["radius"]
        return math.pi * r * r if dim == 2 else 4.0 / 3.0 * math.pi * r ** 3
    if kind == "box":
        size = shape["size"]
        return float(np.prod(size[:dim]))
    r, length = shape["radius"], shape["length"]
    if kind == "cylinder":
        return 2 * r * length if dim == 2 else math.pi * r * r * length
    # capsule
    return 2 * r * length + math.pi * r * r if dim == 2 else \
        math.pi * r * r * length + 4.0 / 3.0 * math.pi * r ** 3


def shape_inertia(shape: dict, mass: float, dim: int) -> np.ndarray:
    """(3, 3) kg m^2 of a closed-form shape of uniform density (formulas in the module doc)."""
    kind = shape["type"]
    if kind == "sphere":
        r2 = shape["radius"] ** 2
        if dim == 2:
            return mass * np.diag([r2 / 4, r2 / 4, r2 / 2])
        return 0.4 * mass * r2 * np.eye(3)
    if kind == "box" or (kind == "cylinder" and dim == 2):
        # float(): a huge integer size (YAML 2**63) would make an object array of Python
        # ints; as a float it is caught as an overflow (OverflowError or inf) instead.
        a, b, c = (float(x) for x in ((shape["size"] + [0.0])[:3] if kind == "box" else
                                      (2 * shape["radius"], shape["length"], 0.0)))
        if dim == 2:
            c = 0.0
        return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    r, length = shape["radius"], shape["length"]
    if kind == "cylinder":
        side = mass * (3 * r * r + length * length) / 12.0
        return np.diag([side, mass * r * r / 2.0, side])
    # capsule: split the mass between the cylindrical part and the two end caps by volume
    vol = shape_volume(shape, dim)
    if dim == 2:
        mr = mass * 2 * r * length / vol
        md = mass - mr
        d = 4 * r / (3 * math.pi)  # centroid of a half-disc from its flat edge
        ixx = mr * length ** 2 / 12 + md * (length ** 2 / 4 + length * d + r * r / 4)
        iyy = mr * (2 * r) ** 2 / 12 + md * r * r / 4
        return np.diag([ixx, iyy, ixx + iyy])
    mc = mass * math.pi * r * r * length / vol
    ms = mass - mc
    side = mc * (length ** 2 / 12 + r * r / 4) + ms * (0.4 * r * r + length ** 2 / 4
                                                          + 3 * length * r / 8)
    return np.diag([side, mc * r * r / 2 + ms * 0.4 * r * r, side])


def mesh_properties(path: str, scale: float, mass: float | None, density: float | None):
    """(mass, com (3,), inertia (3, 3)) of a closed triangle mesh of uniform density."""
    from vrsim_cli.maths.meshes import load_mesh  # trimesh: only mesh bodies pay for it

    try:  # unreadable, too many triangles, not finite, too small or large
        mesh = load_mesh(path, scale)
    except ValueError as exc:
        raise MassPropertyError(("shape", "file"), str(exc).replace(f"mesh '{path}' ", "the "
                                                                     "mesh ")) from None
    if not mesh.is_watertight or mesh.volume <= 0:
        raise MassPropertyError(("shape", "file"), "the mesh is not a closed surface, so it "
                                "has no volume to weigh", "give `inertia` explicitly "
                                "(with `mass`)")
    mesh.density = 1.0
    unit_mass = float(mesh.mass)
    total = float(mass) if mass is not None else float(density) * unit_mass
    return total, np.array(mesh.center_mass, dtype=float), \
        np.array(mesh.moment_inertia, dtype=float) * (total / unit_mass)


def explicit_inertia(value, dim: int) -> np.ndarray:
    """`inertia:` as written (number in 2D, 3 numbers = diagonal, or 3x3) -> (3, 3)."""
    if isinstance(value, (int, float)):
        return np.diag([float(value)] * 3) if dim == 2 else float(value) * np.eye(3)
    arr = np.array(value, dtype=float)
    return np.diag(arr) if arr.ndim == 1 else arr


def body_mass_properties(body: dict, dim: int, mesh_path: str | None = None) \
        -> MassProperties | None:
    """The body's mass properties (see _body_mass_properties). Overflow and NaN from
    extreme inputs are caught by _check_inertia, which names the key; numpy's warnings
    about them would only add noise. Python's float `**` raises OverflowError instead (a
    sphere of radius 1e154 m: r^5 > 1.8e308), and eigvalsh can fail on such matrices: those
    become the same kind of located error."""
    try:
        with np.errstate(over="ignore", invalid="ignore"):
            return _body_mass_properties(body, dim, mesh_path)
    except (OverflowError, np.linalg.LinAlgError):
        raise _overflow(body) from None


def _overflow(body: dict) -> MassPropertyError:
    key = ("particles",) if "particles" in body else ("inertia",) if "inertia" in body \
        else ("shape",)
    return MassPropertyError(key, "the mass properties overflow the float range",
                             "use values of a realistic size")


def _body_mass_properties(body: dict, dim: int, mesh_path: str | None = None) \
        -> MassProperties | None:
    """Mass properties of a dynamic scene body, or None for a point mass (no particles,
    no shape with a volume, no inertia). Raises MassPropertyError for bodies that cannot rotate
    sensibly (e.g. all particles on one line and no explicit inertia)."""
    particles = body.get("particles")
    shape = body.get("shape")
    has_shape = shape is not None and shape["type"] in SHAPES_WITH_MASS
    if particles is None and "inertia" not in body and not has_shape:
        return None
    grid_n = None
    if particles is not None:
        if isinstance(particles, dict):
            grid = particles["grid"]
            grid_n = int(grid["n"])
            pos, masses = grid_particles(grid_n, float(grid.get("size", 1.0)),
                                         float(grid["mass"]), dim)
            source = f"particles: grid n={grid_n} ((n+1)^{dim} = {len(pos)} particles)"
        else:
            pos = np.array([_vec3(p["position"], dim) for p in particles])
            masses = np.array([float(p["mass"]) for p in particles])
            source = f"particles: {len(pos)}"
        mass, com, inertia = particle_properties(pos, masses)
        props = MassProperties(mass, com, inertia, source, pos - com, masses, grid_n)
    elif has_shape and shape["type"] == "mesh":
        mass, com, inertia = mesh_properties(mesh_path, float(shape.get("scale", 1.0)),
                                             body.get("mass"), body.get("density"))
        props = MassProperties(mass, com, inertia, "mesh (trimesh)")
    elif has_shape:
        mass = float(body["mass"]) if "mass" in body else \
            float(body["density"]) * shape_volume(shape, dim)
        props = MassProperties(mass, np.zeros(3), shape_inertia(shape, mass, dim),
                               f"{shape['type']} (closed form)")
    else:
        props = MassProperties(float(body["mass"]), np.zeros(3), np.zeros((3, 3)), "")
    if "inertia" in body:
        props = MassProperties(props.mass, props.com, explicit_inertia(body["inertia"], dim),
                               "inertia (explicit)", props.particles, props.particle_mass,
                               props.grid_n)
    _check_inertia(props, dim, "inertia" in body, body)
    return props


def _check_inertia(props: MassProperties, dim: int, explicit: bool, body: dict) -> None:
    source = ("particles", "density", "mass")
    key = ("inertia",) if explicit else next(((k,) for k in source if k in body), ("shape",))
    inertia = props.inertia
    if not (math.isfinite(props.mass) and np.isfinite(inertia).all()):
        raise MassPropertyError(key, "the mass properties overflow (mass "
                                f"{props.mass:.3g} kg)", "use values of a realistic size")
    scale = max(np.abs(inertia).max(), 1e-300)
    if dim == 2:
        if not inertia[2, 2] > 0.0:
            raise MassPropertyError(key, "the moment of inertia must be > 0",
                                    "a single particle cannot rotate; add particles or "
                                    "give inertia")
        return
    if np.abs(inertia - inertia.T).max() > 1e-9 * scale:
        raise MassPropertyError(key, "the inertia tensor must be symmetric")
    moments = eigh3(inertia)[0]
    if moments[0] <= 1e-12 * scale:
        hint = ("particles on one line have no inertia about that line; add a particle off "
                "the line or give inertia") if not explicit else \
            "principal moments must be > 0"
        raise MassPropertyError(key, f"the inertia tensor is not positive definite (principal "
                                f"moments {', '.join(f'{m:.6g}' for m in moments)} kg m^2)",
                                hint)
    if moments[0] + moments[1] < moments[2] * (1 - 1e-9):
        raise MassPropertyError(key, f"no rigid body has these principal moments "
                                f"({', '.join(f'{m:.6g}' for m in moments)} kg m^2)",
                                "each moment must be <= the sum of the other two "
                                "(triangle inequality)")


# ----------------------------------------------------------------------------- report


def scene_report(scene) -> list[dict]:
    """`vrsim mass-properties`: one record per body of a validated scene (JSON-ready).
    Raises InputError (located) when a body's mass properties cannot be computed."""
    from vrsim_cli.errors import InputError

    dim = int(scene.data.get("dimension", 3))
    rows, problems = [], []
    for i, body in enumerate(scene.data.get("bodies") or []):
        kind = body.get("type", "dynamic")
        row = {"name": body["name"], "type": kind}
        rows.append(row)
        if kind != "dynamic":
            row["note"] = f"{kind}: infinite mass, not moved by forces"
            continue
        mesh = None
        if (body.get("shape") or {}).get("type") == "mesh":
            resolved = scene.input_path(("bodies", i, "shape", "file"), problems,
                                        MAX_MESH_BYTES)
            mesh = str(resolved) if resolved is not None else None
            if mesh is None:
                continue
        try:
            props = body_mass_properties(body, dim, mesh)
        except MassPropertyError as exc:
            problems.append(scene.problem(("bodies", i) + exc.key, exc.message, exc.hint))
            continue
        if props is None:
            row.update(mass=float(body["mass"]), source="point mass (no rotation)")
            continue
        moments, axes = props.principal()
        row.update(mass=props.mass, source=props.source, com=props.com[:dim].tolist(),
                   inertia=props.inertia.tolist(), principal_moments=moments.tolist(),
                   principal_axes=axes.T.tolist())
        if dim == 2:
            row["inertia_z"] = float(props.inertia[2, 2])
        if props.grid_n is not None and dim == 3 and "inertia" not in body:
            n = props.grid_n
            size = float(body["particles"]["grid"].get("size", 1.0))
            row["slide_cube"] = {"n": n, "formula": "m (1/6 + 1/(3n)) size^2",
                                 "value": cube_inertia_formula(n, props.mass) * size ** 2}
    if problems:
        raise InputError(problems)
    return rows


def _fmt(values, scale: float = 0.0) -> str:
    """Numbers to 6 digits; entries below 1e-12 of `scale` (round-off) print as 0."""
    return "[" + ", ".join(f"{0.0 if abs(v) <= 1e-12 * scale else v:.6g}" for v in values) + "]"


def format_report(rows: list[dict], dim: int) -> str:
    """Human-readable text of `scene_report`."""
    lines = []
    for row in rows:
        if "note" in row:
            lines.append(f"{row['name']}: {row['note']}")
            continue
        lines.append(f"{row['name']}: mass {row['mass']:.6g} kg, {row['source']}")
        if "inertia" not in row:
            continue
        lines.append(f"  centre of mass {_fmt(row['com'])} m (in the coordinates the "
                     f"geometry is given in; it is the body's origin)")
        if dim == 2:
            lines.append(f"  moment of inertia about z: {row['inertia_z']:.6g} kg m^2")
        else:
            lines.append("  inertia tensor about the centre of mass, body frame (kg m^2):")
            scale = float(np.abs(row["inertia"]).max())
            lines.extend(f"    {_fmt(r, scale)}" for r in row["inertia"])
            lines.append(f"  principal moments {_fmt(row['principal_moments'])} kg m^2")
            lines.append("  principal axes (body frame): " +
                         ", ".join(_fmt(a, 1.0) for a in row["principal_axes"]))
        cube = row.get("slide_cube")
        if cube:
            lines.append(f"  slide 5.3.2 cube, n = {cube['n']}: I = m (1/6 + 1/(3n)) E = "
                         f"{cube['value']:.6g} kg m^2 (size^2 times; the slide prints "
                         f"1/6 - 1/(3n), an erratum: docs/slides.md)")
    return "\n".join(lines)
