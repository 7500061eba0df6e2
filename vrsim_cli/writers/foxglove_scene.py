"""Foxglove scene messages of vrsim's bodies, built with the Foxglove SDK's message classes.

Layer 6, shared by the MCAP writer (`mcap_writer`), its contacts and animation channels.
The SDK (`foxglove-sdk`) is imported on first use, so only runs that write MCAP or serve
a live view load it.
"""

from __future__ import annotations

import math
from pathlib import Path

from vrsim_cli.maths.spatial import quat_rotating

WORLD, SCENE = "world", "scene"  # z-up root frame; the scene's own frame under it
POINT_MASS_DIAMETER = 0.05  # m, a body without a shape when no drawn shape is given
HULL_ALPHA = 0.35  # a particle body's hull, as in rendered frames (render.geometry)
PLANE_EXTENT = 20.0  # m, side of the square that draws an infinite plane
MESH_MEDIA_TYPES = {".stl": "model/stl", ".glb": "model/gltf-binary",
                    ".gltf": "model/gltf+json", ".obj": "model/obj",
                    ".dae": "model/vnd.collada+xml"}
# Foxglove cylinders stand along their local z; vrsim's along the body's local y.
Z_TO_Y = [float(c) for c in quat_rotating([0, 0, 1], [0, 1, 0])]
# Foxglove arrows point along their local +x; the observer looks along its local -z.
X_TO_MINUS_Z = [float(c) for c in quat_rotating([1, 0, 0], [0, 0, -1])]
OBSERVER_COLOR = (1.0, 0.85, 0.1, 1.0)
# scene -> world rotation [w, x, y, z] per up axis of the scene: y-up turns +90 deg about x
# (scene y becomes world z, scene z becomes world -y); a z-up scene is not turned.
SCENE_TO_WORLD = {"y": (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0), "z": (1.0, 0.0, 0.0, 0.0)}


def fox():
    """The Foxglove SDK's message module (imported only by runs that write MCAP)."""
    import foxglove.messages

    return foxglove.messages


def stamp(ns: int):
    return fox().Timestamp(*divmod(int(ns), 1_000_000_000))


def vec(v):
    return fox().Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))


def pose(position=(0.0, 0.0, 0.0), q_wxyz=(1.0, 0.0, 0.0, 0.0)):
    m = fox()
    return m.Pose(position=vec(position), orientation=m.Quaternion(
        x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]), w=float(q_wxyz[0])))


def color(rgba):
    rgba = list(rgba) + [1.0] * (4 - len(rgba))
    return fox().Color(r=float(rgba[0]), g=float(rgba[1]), b=float(rgba[2]), a=float(rgba[3]))


def drawn_shapes(model) -> list:
    """The shape each body is drawn with, as in the rendered frames (`render.geometry`):
    the scene's shape; for a body without one, {"type": "particles", "points": (k, 3) m
    in the body frame, "radius": m, "hull": triangle vertices (3 m, 3) or None} when it is
    made of particles, else {"type": "point", "radius": m} sized to the scene."""
    from vrsim_cli.render import geometry

    point = geometry.point_mass_radius(model)
    out = []
    for i, shape in enumerate(model.body_shape):
        if shape is not None:
            out.append(shape)
            continue
        particles = geometry.body_particles(model, i)
        if particles is None:
            out.append({"type": "point", "radius": point})
            continue
        hull = geometry.hull_triangles(particles, model.dimension == 2)
        out.append({"type": "particles", "points": particles,
                    "radius": geometry.particle_radius(particles, point),
                    "hull": None if hull is None else hull[0]})
    return out


SPRING_COLOR = (0.15, 0.15, 0.18, 1.0)  # as in rendered frames (render.osmesa)
SPRINGS = "springs"  # the /scene entity of every spring, in the scene frame


def springs_entity(segments, ns: int):
    """The foxglove.SceneEntity of the springs: a line list through their two ends
    (segments (s, 2, 3) m, scene frame: `render.geometry.spring_segments`), 2 px wide,
    replaced at every sample (the ends move with their bodies)."""
    m = fox()
    points = [m.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2]))
              for p in segments.reshape(-1, 3)]
    line = m.LinePrimitive(type=m.LinePrimitiveLineType.LineList, pose=pose(),
                           thickness=2.0, scale_invariant=True, points=points,
                           color=color(SPRING_COLOR))
    return m.SceneEntity(timestamp=stamp(ns), frame_id=SCENE, id=SPRINGS,
                         lifetime=m.Duration(0, 0), frame_locked=False,
                         metadata=[m.KeyValuePair(key="shape", value="springs")],
                         lines=[line])


def scene_entity(name: str, shape: dict | None, rgba, ns: int, scale=(1.0, 1.0, 1.0)):
    """The foxglove.SceneEntity drawing one body in its own frame, `scale` = [sx, sy, sz]
    times larger along the body's axes (keyframed scale tracks)."""
    m = fox()
    sx, sy, sz = (float(s) for s in scale)
    c = color(rgba)
    parts = {"arrows": [], "spheres": [], "cubes": [], "cylinders": [], "models": [],
             "triangles": []}
    frame, locked = name, True

    def sized(kind, size, offset=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0), **extra):
        # Foxglove's cylinder axis (its z) is the body's y: body scale (sx, sy, sz) scales
        # its x, y, z sizes by (sx, sz, sy).
        fx, fy, fz = (sx, sz, sy) if kind == "cylinders" else (sx, sy, sz)
        prim = {"spheres": m.SpherePrimitive, "cubes": m.CubePrimitive,
                "cylinders": m.CylinderPrimitive}[kind]
        parts[kind].append(prim(pose=pose((offset[0] * sx, offset[1] * sy, offset[2] * sz), q),
                                size=vec((size[0] * fx, size[1] * fy, size[2] * fz)),
                                color=c, **extra))

    kind = (shape or {}).get("type")
    if kind == "observer":  # an arrow along the view direction and a small head
        parts["arrows"].append(m.ArrowPrimitive(pose=pose(q_wxyz=X_TO_MINUS_Z),
                                                shaft_length=0.3, shaft_diameter=0.03,
                                                head_length=0.1, head_diameter=0.08, color=c))
        sized("spheres", [0.15] * 3)
    elif kind is None:
        sized("spheres", [POINT_MASS_DIAMETER] * 3)
    elif kind == "point":  # sized to the scene (drawn_shapes)
        sized("spheres", [2.0 * shape["radius"]] * 3)
    elif kind == "particles":  # each particle, joined by their translucent hull
        for p in shape["points"]:
            sized("spheres", [2.0 * shape["radius"]] * 3, offset=p)
        if shape["hull"] is not None:
            rgb = list(rgba)[:3]
            alpha = HULL_ALPHA * (float(rgba[3]) if len(rgba) > 3 else 1.0)
            parts["triangles"].append(m.TriangleListPrimitive(
                pose=pose(), points=[m.Point3(x=float(v[0]) * sx, y=float(v[1]) * sy,
                                              z=float(v[2]) * sz) for v in shape["hull"]],
                color=color(rgb + [alpha])))
    elif kind == "sphere":
        sized("spheres", [2.0 * shape["radius"]] * 3)
    elif kind == "box":
        sized("cubes", [s if s > 0 else 1e-3 for s in shape["size"]])  # 2D boxes: thin z
    elif kind in ("cylinder", "capsule"):
        d, length = 2.0 * shape["radius"], shape["length"]
        sized("cylinders", [d, d, length], q=Z_TO_Y, bottom_scale=1.0, top_scale=1.0)
        if kind == "capsule":
            for end in (-0.5 * length, 0.5 * length):
                sized("spheres", [d, d, d], offset=(0.0, end, 0.0))
    elif kind == "plane":
        frame, locked = SCENE, False
        centre = [shape["offset"] * n for n in shape["normal"]]
        parts["cubes"].append(m.CubePrimitive(pose=pose(centre, shape["orientation"]),
                                              size=vec([PLANE_EXTENT, 1e-3, PLANE_EXTENT]),
                                              color=c))
    elif kind == "mesh":
        path = Path(shape["path"])
        s = float(shape.get("scale", 1.0))
        parts["models"].append(m.ModelPrimitive(
            pose=pose(), scale=vec([s * sx, s * sy, s * sz]), color=c, override_color=True,
            media_type=MESH_MEDIA_TYPES.get(path.suffix.lower(), "model/stl"),
            data=path.read_bytes()))
    return m.SceneEntity(timestamp=stamp(ns), frame_id=frame, id=name,
                         lifetime=m.Duration(0, 0), frame_locked=locked,
                         metadata=[m.KeyValuePair(key="shape", value=kind or "point")],
                         **parts)


def foxglove_schema(type_name: str):
    """The SDK's schema of foxglove.<type_name>."""
    return getattr(fox(), type_name).get_schema()


def vrsim_schema(type_name: str):
    import foxglove

    from vrsim_cli.writers.vrsim_messages import schema_data

    return foxglove.Schema(name=f"vrsim.{type_name}", encoding="protobuf", data=schema_data())
