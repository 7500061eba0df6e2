"""MCAP output of collision contacts: `/vrsim/contacts` to see, `/vrsim/contacts/raw` to read.

Used by `mcap_writer` when the scene has a collision block. At every sample with contacts
(`State.contacts`, found by loop stage 2.3 at that step):
- `/vrsim/contacts` (`foxglove.SceneUpdate`): one entity `contacts` in frame `scene`, a
  dot at each contact point P^K and an arrow along each normal n^K (red: penetrating,
  yellow: a gap within the tolerance, magenta: found by continuous detection); it
  replaces the previous sample's entity;
- `/vrsim/contacts/raw` (`vrsim.Contacts`, see vrsim_messages.py): the same contacts as
  numbers, with the impulse of each when the scene has a collision response.
"""

from __future__ import annotations

import math

from vrsim_cli.maths.spatial import quat_rotating
from vrsim_cli.writers.foxglove_scene import SCENE, color, fox, pose, stamp, vec
from vrsim_cli.writers.vrsim_messages import message_class

COLORS = {"penetrating": (0.9, 0.1, 0.1, 1.0), "gap": (1.0, 0.85, 0.1, 1.0),
          "swept": (0.9, 0.1, 0.9, 1.0)}
DOT = 0.02  # m, diameter of the dot at a contact point
ARROW = 0.15  # m, length of a contact normal's arrow


def contacts_entity(contacts, ns: int):
    """One foxglove.SceneEntity in frame `scene` with a dot and a normal arrow per contact."""
    m = fox()
    spheres, arrows = [], []
    for point, normal, depth, toi in zip(contacts.point.tolist(), contacts.normal.tolist(),
                                         contacts.depth.tolist(), contacts.toi.tolist()):
        kind = "swept" if toi == toi else ("penetrating" if depth >= 0.0 else "gap")
        rgba = color(COLORS[kind])
        spheres.append(m.SpherePrimitive(pose=pose(point), size=vec([DOT] * 3), color=rgba))
        arrows.append(m.ArrowPrimitive(pose=pose(point, quat_rotating([1, 0, 0], normal)),
                                       shaft_length=0.7 * ARROW, shaft_diameter=0.3 * DOT,
                                       head_length=0.3 * ARROW, head_diameter=0.8 * DOT,
                                       color=rgba))
    return m.SceneEntity(timestamp=stamp(ns), frame_id=SCENE, id="contacts",
                         lifetime=m.Duration(0, 0), frame_locked=False,
                         metadata=[m.KeyValuePair(key="count", value=str(len(spheres)))],
                         spheres=spheres, arrows=arrows)


def contacts_message(model, state):
    """The vrsim.Contacts message of a state (toi NaN: a contact of the end-of-step state)."""
    c = state.contacts
    names = model.body_name
    impulse = getattr(state, "contact_impulse", None)
    impulses = impulse.tolist() if impulse is not None else [[]] * len(c.depth)
    Contact = message_class("Contact")
    return message_class("Contacts")(t=float(state.t), step=int(state.step), contacts=[
        Contact(body_a=names[a], body_b=names[b], point=p, normal=n, depth=d,
                toi=toi if toi == toi else math.nan, impulse=j)
        for a, b, p, n, d, toi, j in zip(c.body_a.tolist(), c.body_b.tolist(),
                                         c.point.tolist(), c.normal.tolist(), c.depth.tolist(),
                                         c.toi.tolist(), impulses)])


class ContactsChannel:
    """Publishes the contacts of `owner` (an McapWriter) at each of its samples."""

    def __init__(self, owner):
        self.owner = owner

    def write(self, ns: int, state) -> None:
        if state.contacts is None:  # the first sample, before any step
            return
        update = fox().SceneUpdate(entities=[contacts_entity(state.contacts, ns)])
        self.owner.log("/vrsim/contacts", update.encode(), ns)
        self.owner.log("/vrsim/contacts/raw",
                       contacts_message(self.owner.model, state).SerializeToString(), ns)
