"""MCAP output of collision contacts: `/vrsim/contacts` to see, `/vrsim/contacts/raw` to read.

Used by `mcap_writer` when the scene has a collision block. At every sample with contacts
(`State.contacts`, found by loop stage 2.3 at that step):
- `/vrsim/contacts` (`foxglove.SceneUpdate`): one entity `contacts` in frame `world`, a
  dot at each contact point P^K and an arrow along each normal n^K (red: penetrating,
  yellow: a gap within the tolerance, magenta: found by continuous detection); it
  replaces the previous sample's entity;
- `/vrsim/contacts/raw` (`vrsim.Contacts`): the same contacts as numbers.
"""

from __future__ import annotations

from vrsim_cli.maths.spatial import quat_rotating
from vrsim_cli.writers.foxglove_schemas import schema_bytes

_NUMBERS3 = {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
VRSIM_CONTACTS = {
    "title": "vrsim.Contacts",
    "description": "Contacts found by collision detection (loop stage 2.3) at one sample: "
                   "per contact the two bodies, the point P^K (m, world), the unit normal "
                   "n^K from A to B, the penetration depth (m; negative: a gap within the "
                   "tolerance) and the time of impact after the step's start (s; null for "
                   "contacts of the end-of-step state).",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "simulated time, s"},
        "step": {"type": "integer"},
        "contacts": {"type": "array", "items": {
            "type": "object",
            "required": ["body_a", "body_b", "point", "normal", "depth", "toi"],
            "properties": {"body_a": {"type": "string"}, "body_b": {"type": "string"},
                           "point": _NUMBERS3, "normal": _NUMBERS3,
                           "depth": {"type": "number"},
                           "toi": {"type": ["number", "null"]},
                           "impulse": {**_NUMBERS3, "description":
                                       "N s, world: the impulse collision response gave "
                                       "body_b at this contact during the step (body_a "
                                       "got minus it); absent without a response"}}}},
    },
    "required": ["t", "step", "contacts"],
}
COLORS = {"penetrating": (0.9, 0.1, 0.1, 1.0), "gap": (1.0, 0.85, 0.1, 1.0),
          "swept": (0.9, 0.1, 0.9, 1.0)}
DOT = 0.02  # m, diameter of the dot at a contact point
ARROW = 0.15  # m, length of a contact normal's arrow


def contacts_entity(contacts, ns: int, pose, vec, color, time) -> dict:
    """One foxglove.SceneEntity in `world` with a dot and a normal arrow per contact
    (pose, vec, color, time: the MCAP writer's message helpers)."""
    entity = {"timestamp": time(ns), "frame_id": "world", "id": "contacts",
              "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": False,
              "metadata": [{"key": "count", "value": str(len(contacts))}],
              "arrows": [], "spheres": [], "cubes": [], "cylinders": [], "models": []}
    for point, normal, depth, toi in zip(contacts.point.tolist(), contacts.normal.tolist(),
                                         contacts.depth.tolist(), contacts.toi.tolist()):
        kind = "swept" if toi == toi else ("penetrating" if depth >= 0.0 else "gap")
        rgba = color(COLORS[kind])
        entity["spheres"].append({"pose": pose(point), "size": vec([DOT] * 3), "color": rgba})
        entity["arrows"].append({"pose": pose(point, quat_rotating([1, 0, 0], normal)),
                                 "shaft_length": 0.7 * ARROW, "shaft_diameter": 0.3 * DOT,
                                 "head_length": 0.3 * ARROW, "head_diameter": 0.8 * DOT,
                                 "color": rgba})
    return entity


def contacts_record(model, state) -> dict:
    """The vrsim.Contacts message of a state (body names, numbers as lists)."""
    c = state.contacts
    names = model.body_name
    record = {"t": float(state.t), "step": int(state.step), "contacts": [
        {"body_a": names[a], "body_b": names[b], "point": p, "normal": n, "depth": d,
         "toi": None if toi != toi else toi}
        for a, b, p, n, d, toi in zip(c.body_a.tolist(), c.body_b.tolist(), c.point.tolist(),
                                      c.normal.tolist(), c.depth.tolist(), c.toi.tolist())]}
    impulse = getattr(state, "contact_impulse", None)
    if impulse is not None:  # collision response: the impulse of each contact
        for entry, j in zip(record["contacts"], impulse.tolist()):
            entry["impulse"] = j
    return record


class ContactsChannel:
    """Publishes the contacts of `owner` (an McapWriter) at each of its samples."""

    def __init__(self, owner, scene_schema: int):
        self.owner = owner
        raw = owner.writer.register_schema("vrsim.Contacts", "jsonschema",
                                           schema_bytes(VRSIM_CONTACTS))
        self.drawn = owner.writer.register_channel("/vrsim/contacts", "json", scene_schema)
        self.raw = owner.writer.register_channel("/vrsim/contacts/raw", "json", raw)

    def write(self, ns: int, state, pose, vec, color, time) -> None:
        if state.contacts is None:  # the first sample, before any step
            return
        entity = contacts_entity(state.contacts, ns, pose, vec, color, time)
        self.owner._add(self.drawn, ns, {"deletions": [], "entities": [entity]})
        self.owner._add(self.raw, ns, contacts_record(self.owner.model, state))
