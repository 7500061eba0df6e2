"""Contacts: the output of collision detection, structure of arrays over k contacts.

Issue 7 (collision response) consumes this. Conventions (slide 5.4):
- `normal` n^K points from body A to body B (unit length, world frame);
- `point` P^K is the midpoint between the two witness points (the deepest point of each
  solid), so it lies halfway inside the overlap when the solids penetrate;
- `depth` is the penetration depth in m: > 0 penetrating, 0 touching, < 0 a gap (only
  contacts with depth >= -tolerance are reported);
- `toi` is NaN for a contact found at the end of the step; for a contact found by
  continuous detection (the pair touches during the step but not at its end: a fast body
  would tunnel) it is the time of impact in s after the step's start, and point, normal
  and depth are those of the configuration at that time (depth in [-tolerance, 0]).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.products import norm


@dataclass(frozen=True)
class Contacts:
    """body_a, body_b: (k,) int64 body indices, body_a < body_b
    point: (k, 3) m, world frame
    normal: (k, 3) unit, world frame, from A to B
    depth: (k,) m, penetration depth (negative: gap within the tolerance)
    toi: (k,) s after the step's start, NaN for contacts of the end-of-step state
    """

    body_a: np.ndarray
    body_b: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    depth: np.ndarray
    toi: np.ndarray

    def __len__(self) -> int:
        return len(self.depth)

    @staticmethod
    def empty() -> "Contacts":
        return Contacts(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)),
                        np.zeros((0, 3)), np.zeros(0), np.zeros(0))

    @staticmethod
    def concatenate(parts: list["Contacts"]) -> "Contacts":
        parts = [p for p in parts if len(p)]
        if not parts:
            return Contacts.empty()
        return Contacts(*(np.concatenate([getattr(p, f) for p in parts])
                          for f in ("body_a", "body_b", "point", "normal", "depth", "toi")))

    def pairs(self) -> set:
        """The distinct (body_a, body_b) pairs in contact."""
        return set(zip(self.body_a.tolist(), self.body_b.tolist()))


def no_pair_contacts():
    """The empty result of a pair function: (pair, point, normal, depth) with k = 0."""
    return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)


def reduce_manifold(points, depth, keep: int = 4):
    """At most `keep` well-spread points: the deepest, then farthest-point sampling."""
    unique = [0]
    for i in range(1, len(points)):
        if min(norm(points[i] - points[j]) for j in unique) > 1e-9:
            unique.append(i)
    if len(unique) <= keep:
        return unique
    chosen = [max(unique, key=lambda i: depth[i])]
    while len(chosen) < keep:
        chosen.append(max((i for i in unique if i not in chosen),
                          key=lambda i: min(norm(points[i] - points[j])
                                            for j in chosen)))
    return sorted(chosen)


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
