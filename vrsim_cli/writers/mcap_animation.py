"""MCAP output of animated looks: colour and scale on `/scene`, values on `/vrsim/animation`.

Used by `mcap_writer` when the scene has colour, scale or attribute tracks. At every
sample the looks are evaluated at the sample's time (they are pure functions of time, so
the state need not carry them):
- `/scene` (`foxglove.SceneUpdate`): the entities whose colour or scale changed since they
  were last published, so Foxglove draws the animation and a still colour costs nothing;
- `/vrsim/animation` (`vrsim.Animation`): `{t, entities: [{name, color?, scale?,
  attributes?}]}` for the animated bodies, to plot in Foxglove or read back.
"""

from __future__ import annotations

from vrsim_cli.model.animation import appearance
from vrsim_cli.writers.foxglove_schemas import schema_bytes

VRSIM_ANIMATION = {
    "title": "vrsim.Animation",
    "description": "Keyframed looks of the animated bodies at one sample: colour RGBA in "
                   "[0, 1], scale factors [sx, sy, sz], named attributes (numbers or lists).",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "simulated time, s"},
        "entities": {"type": "array", "items": {
            "type": "object", "required": ["name"],
            "properties": {"name": {"type": "string"},
                           "color": {"type": "array", "items": {"type": "number"}},
                           "scale": {"type": "array", "items": {"type": "number"}},
                           "attributes": {"type": "object"}}}},
    },
    "required": ["t", "entities"],
}


def scaled(entity: dict, scale) -> dict:
    """A foxglove.SceneEntity drawn `scale` = [sx, sy, sz] times larger in its body frame."""
    sx, sy, sz = scale
    for kind in ("spheres", "cubes", "cylinders"):
        for prim in entity[kind]:
            # vrsim cylinders stand along the body's y; Foxglove's along their own z, which
            # the primitive's pose turns to y: their x, y, z sizes are the body's x, z, y.
            fx, fy, fz = (sx, sz, sy) if kind == "cylinders" else (sx, sy, sz)
            size = prim["size"]
            size["x"], size["y"], size["z"] = size["x"] * fx, size["y"] * fy, size["z"] * fz
            pos = prim["pose"]["position"]
            pos["x"], pos["y"], pos["z"] = pos["x"] * sx, pos["y"] * sy, pos["z"] * sz
    for prim in entity["models"]:
        prim["scale"] = {"x": prim["scale"]["x"] * sx, "y": prim["scale"]["y"] * sy,
                         "z": prim["scale"]["z"] * sz}
    return entity


class AnimationChannel:
    """Publishes the animated looks of `owner` (an McapWriter) at each of its samples."""

    def __init__(self, owner):
        self.owner = owner
        self.anim = owner.model.animation
        schema = owner.writer.register_schema("vrsim.Animation", "jsonschema",
                                              schema_bytes(VRSIM_ANIMATION))
        self.channel = owner.writer.register_channel("/vrsim/animation", "json", schema)
        model = owner.model
        self.shown = {b: (list(map(float, model.body_color[b])), [1.0, 1.0, 1.0])
                      for b, *_ in self.anim.color_tracks + self.anim.scale_tracks}

    def write(self, ns: int, t: float, scene_entity) -> None:
        model, names = self.owner.model, self.owner.names
        looks = appearance(self.anim, t)
        changed = []
        for body, look in looks.items():
            if body not in self.shown:
                continue
            color = look.get("color", self.shown[body][0])
            scale = look.get("scale", self.shown[body][1])
            if (color, scale) != self.shown[body]:
                self.shown[body] = (color, scale)
                entity = scene_entity(names[body], model.body_shape[body], color, ns)
                changed.append(scaled(entity, scale) if scale != [1.0, 1.0, 1.0] else entity)
        if changed:
            self.owner._add(self.owner.scene_channel, ns, {"deletions": [],
                                                            "entities": changed})
        self.owner._add(self.channel, ns, {"t": float(t), "entities": [
            {"name": names[body], **look} for body, look in sorted(looks.items())]})

