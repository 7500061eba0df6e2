"""MCAP output of animated looks: colour and scale on `/scene`, values on `/vrsim/animation`.

Used by `mcap_writer` when the scene has colour, scale or attribute tracks. At every
sample the looks are evaluated at the sample's time (they are pure functions of time, so
the state need not carry them):
- `/scene` (`foxglove.SceneUpdate`): the entities whose colour or scale changed since they
  were last published, so Foxglove draws the animation and a still colour costs nothing;
- `/vrsim/animation` (`vrsim.Animation`, see vrsim_messages.py): per animated body its
  colour, scale and named attributes, to plot in Foxglove or read back.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.model.animation import appearance
from vrsim_cli.writers.foxglove_scene import scene_entity
from vrsim_cli.writers.vrsim_messages import message_class


def animation_message(t: float, names, looks: dict):
    """The vrsim.Animation message of the looks {body: {color?, scale?, attributes?}}."""
    Look, Attribute = message_class("Look"), message_class("Attribute")
    return message_class("Animation")(t=float(t), entities=[
        Look(name=names[body], color=look.get("color", []), scale=look.get("scale", []),
             attributes=[Attribute(name=k, value=np.ravel(v).tolist())
                         for k, v in look.get("attributes", {}).items()])
        for body, look in sorted(looks.items())])


class AnimationChannel:
    """Publishes the animated looks of `owner` (an McapWriter) at each of its samples."""

    def __init__(self, owner):
        self.owner = owner
        self.anim = owner.model.animation
        model = owner.model
        self.shown = {b: (list(map(float, model.body_color[b])), [1.0, 1.0, 1.0])
                      for b, *_ in self.anim.color_tracks + self.anim.scale_tracks}

    def write(self, ns: int, t: float) -> None:
        owner = self.owner
        model, names = owner.model, owner.names
        looks = appearance(self.anim, t)
        changed = {}
        for body, look in looks.items():
            if body not in self.shown or not owner.shown[body]:
                continue  # not animated, or an emitted particle that does not exist yet
            looks_now = (look.get("color", self.shown[body][0]),
                         look.get("scale", self.shown[body][1]))
            if looks_now != self.shown[body]:
                self.shown[body] = looks_now
                changed[names[body]] = scene_entity(names[body], model.body_shape[body],
                                                    looks_now[0], ns, scale=looks_now[1])
        owner.publish_entities(changed, ns)
        owner.log("/vrsim/animation", animation_message(t, names, looks).SerializeToString(),
                  ns)
