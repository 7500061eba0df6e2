"""Loop stage 2.3, detection (slide 5.4.1): broad phase -> narrow phase -> contacts.

Pure functions of model and state: `detect(model, state) -> Contacts` finds the contacts
of one state; `start_overlaps(model, state)` the bodies that start inside each other; `step(model, before, after) -> Contacts` is what the loop calls after each
physics step: the contacts of `after` plus, with `collision.continuous`, the pairs that
touched during the step but not at its end (`continuous.swept_contacts`).

Which pairs are tested: two geoms of different bodies, at least one body not static (a
kinematic body touching the ground is reported; two static bodies never are), and no
emitted particle still waiting at its nozzle. Contacts come sorted by (body_a, body_b).
"""

from __future__ import annotations

from vrsim_cli.stages.collision.broadphase import broad_phase
from vrsim_cli.stages.collision.contacts import Contacts, planar, to_contacts
from vrsim_cli.stages.collision.continuous import swept_contacts
from vrsim_cli.stages.collision.narrowphase import narrow_phase
from vrsim_cli.stages.collision.shapes import aabbs, place


def detect(model, state, margin: float | None = None, world=None) -> Contacts:
    """All contacts of `state` with depth >= -margin (default: collision.tolerance).
    `world`: the geoms already placed at `state` (shapes.place), if the caller has them."""
    cm = model.collision
    if cm is None or cm.n_geom == 0:
        return Contacts.empty()
    margin = cm.tolerance if margin is None else margin
    world = place(cm, state.body_pos, state.body_quat) if world is None else world
    ia, ib = broad_phase(model, *aabbs(cm, world), state.step)
    contacts = to_contacts(cm, ia, ib, *narrow_phase(cm, world, ia, ib, margin))
    return planar(contacts) if model.dimension == 2 else contacts


def start_overlaps(model, state, n_scene: int) -> list[tuple[int, int, float]]:
    """Pairs of the first n_scene bodies (the scene's, not emitted particles) that
    interpenetrate deeper than collision.tolerance in `state` (the run's first): (body
    a, body b, depth m), deepest first. Collision response would push them apart at
    whatever speed the overlap asks for: the scene is wrong, not the integration."""
    found = detect(model, state)
    deepest: dict = {}
    for a, b, d in zip(found.body_a.tolist(), found.body_b.tolist(), found.depth.tolist()):
        if a < n_scene and b < n_scene and d > model.collision.tolerance:
            deepest[(a, b)] = max(d, deepest.get((a, b), 0.0))
    return sorted(((a, b, d) for (a, b), d in deepest.items()), key=lambda x: -x[2])


def step(model, before, after) -> Contacts:
    """Loop stage 2.3 after one physics step from `before` to `after`: the contacts of
    `after` and, when continuous detection is on, the first touch of every pair that
    met during the step but touches neither at its end nor at its start (`before.contacts`,
    already reported): a body that would otherwise tunnel. Discrete contacts come first."""
    cm = model.collision
    if cm.n_geom == 0:
        return Contacts.empty()
    world = place(cm, after.body_pos, after.body_quat)
    contacts = detect(model, after, world=world)
    if not cm.continuous:
        return contacts
    exclude = contacts.pairs() | (before.contacts.pairs() if before.contacts is not None
                                  else set())
    swept = swept_contacts(model, before, after, exclude, world)
    if model.dimension == 2:
        swept = planar(swept)
    return Contacts.concatenate([contacts, swept])
