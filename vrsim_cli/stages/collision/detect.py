"""Loop stage 2.3, detection (slide 5.4.1): broad phase -> narrow phase -> contacts.

Pure functions of model and state: `detect(model, state) -> Contacts` finds the contacts
of one state; `step(model, before, after) -> Contacts` is what the loop calls after each
physics step: the contacts of `after` plus, with `collision.continuous`, the pairs that
touched during the step but not at its end (`continuous.swept_contacts`).

Which pairs are tested: two geoms of different bodies, at least one body not static (a
kinematic body touching the ground is reported; two static bodies never are), and no
emitted particle still waiting at its nozzle. Contacts come sorted by (body_a, body_b).
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.model.collision import aabbs, place
from vrsim_cli.model.model import BODY_STATIC
from vrsim_cli.stages.collision import broadphase, fcl_adapter
from vrsim_cli.stages.collision.contacts import Contacts, no_pair_contacts
from vrsim_cli.stages.collision.narrowphase import DISPATCH



def broad_phase(model, lo, hi, step: int):
    """Candidate geom pairs (ia, ib) among the world AABBs lo, hi (n_geom, 3): only geoms
    whose body is in the scene at `step` (particles waiting at a nozzle all sit at one
    point and would pair with each other), no pairs of one body or of two static bodies."""
    cm = model.collision
    idx = np.flatnonzero(model.body_emit_step[cm.geom_body] <= step)
    ia, ib = broadphase.candidate_pairs(lo[idx], hi[idx], cm.broad_phase)
    ia, ib = idx[ia], idx[ib]
    ba, bb = cm.geom_body[ia], cm.geom_body[ib]
    moves = np.asarray(model.body_type) != BODY_STATIC
    keep = (ba != bb) & (moves[ba] | moves[bb])
    return ia[keep], ib[keep]


def narrow_phase(cm, world, ia, ib, margin: float):
    """Contacts of candidate geom pairs (ia, ib): dispatch by type pair, swap when the
    table has (B, A), fcl when there is no closed form. Returns (pair, point, normal,
    depth) with `pair` indexing the candidates and normals from ia to ib."""
    ta, tb = cm.geom_type[ia], cm.geom_type[ib]
    parts = []
    codes = ta * 16 + tb
    for code in np.unique(codes):
        sel = np.flatnonzero(codes == code)
        key = (int(code) // 16, int(code) % 16)
        if key in DISPATCH:
            pair, point, normal, depth = DISPATCH[key](cm, world, ia[sel], ib[sel], margin)
        elif key[::-1] in DISPATCH:
            pair, point, normal, depth = DISPATCH[key[::-1]](cm, world, ib[sel], ia[sel],
                                                            margin)
            normal = -normal
        else:
            pair, point, normal, depth = fcl_adapter.pair_contacts(cm, world, ia[sel],
                                                                   ib[sel], margin)
        parts.append((sel[pair], point, normal, depth))
    if not parts:
        return no_pair_contacts()
    pair, point, normal, depth = (np.concatenate(x) for x in zip(*parts))
    order = np.argsort(pair, kind="stable")
    return pair[order], point[order], normal[order], depth[order]


def to_contacts(cm, ia, ib, pair, point, normal, depth, toi=None) -> Contacts:
    """Geom-pair results -> Contacts over bodies with body_a < body_b, sorted."""
    ba, bb = cm.geom_body[ia[pair]], cm.geom_body[ib[pair]]
    flip = ba > bb
    normal = np.where(flip[:, None], -normal, normal)
    a, b = np.minimum(ba, bb), np.maximum(ba, bb)
    toi = np.full(len(pair), np.nan) if toi is None else toi
    order = np.lexsort((b, a))
    return Contacts(a[order], b[order], point[order], normal[order], depth[order], toi[order])


def planar(contacts: Contacts) -> Contacts:
    """2D scenes: contacts in the z = 0 plane. Boxes are given a z depth for the 3D tests,
    so a corner touches at z = +-depth: drop z, then the duplicates this makes."""
    if not len(contacts):
        return contacts
    point = contacts.point * [1.0, 1.0, 0.0]
    normal = contacts.normal * [1.0, 1.0, 0.0]
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.where(length > 0.0, normal / np.where(length > 0.0, length, 1.0),
                      contacts.normal)
    key = np.column_stack([contacts.body_a, contacts.body_b, np.round(point[:, :2] * 1e9)])
    _, first = np.unique(key, axis=0, return_index=True)
    keep = np.sort(first)
    return Contacts(contacts.body_a[keep], contacts.body_b[keep], point[keep], normal[keep],
                    contacts.depth[keep], contacts.toi[keep])


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
    from vrsim_cli.stages.collision.continuous import swept_contacts

    exclude = contacts.pairs() | (before.contacts.pairs() if before.contacts is not None
                                  else set())
    swept = swept_contacts(model, before, after, exclude, world)
    if model.dimension == 2:
        swept = planar(swept)
    return Contacts.concatenate([contacts, swept])
