"""Collision geoms placed in the world: poses and bounding boxes at one instant.

The geoms themselves (types, sizes, proxies) are compiled once into the model
(`model.collision.CollisionModel`); these pure functions place them at a state's body
poses for the broad and narrow phase.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.products import matmul

from vrsim_cli.maths.spatial import quat_multiply, quat_to_matrix
from vrsim_cli.model.collision import CAPSULE, CONVEX, MESH, PLANE, CollisionModel


@dataclass(frozen=True)
class WorldGeoms:
    """Geoms placed in the world at one instant.

    pos: (n_geom, 3) m; rot: (n_geom, 3, 3) local -> world; half: (n_geom, 3) m
    (as geom_half, but aabb proxies get their current world extents)."""

    pos: np.ndarray
    rot: np.ndarray
    half: np.ndarray


def place(cm: CollisionModel, body_pos, body_quat) -> WorldGeoms:
    """World poses of all geoms from body poses (n_body, 3), (n_body, 4)."""
    bq = np.asarray(body_quat, dtype=float)[cm.geom_body]
    brot = quat_to_matrix(bq)
    pos = np.asarray(body_pos, dtype=float)[cm.geom_body] + \
        np.einsum("gij,gj->gi", brot, cm.geom_local_pos)
    # Most geoms sit unturned in their body: then the body's rotation is theirs.
    turned = np.any(cm.geom_local_quat[:, 1:] != 0.0, axis=1)
    rot = brot.copy()
    if turned.any():
        rot[turned] = quat_to_matrix(quat_multiply(bq[turned], cm.geom_local_quat[turned]))
    half = cm.geom_half
    if cm.geom_world_aabb.any():
        half = half.copy()
        for g in np.flatnonzero(cm.geom_world_aabb):
            world = matmul(cm.geom_vertices[g], brot[g].T)
            lo, hi = world.min(axis=0), world.max(axis=0)
            half[g] = 0.5 * (hi - lo)
            pos[g] = pos[g] - matmul(brot[g], cm.geom_local_pos[g]) + 0.5 * (hi + lo)
            rot[g] = np.eye(3)
    planes = cm.geom_type == PLANE
    if planes.any():  # half-spaces are given in the world frame
        pos[planes] = cm.geom_plane_normal[planes] * cm.geom_plane_offset[planes, None]
        rot[planes] = np.eye(3)
    return WorldGeoms(pos, rot, half)


def aabbs(cm: CollisionModel, world: WorldGeoms) -> tuple[np.ndarray, np.ndarray]:
    """World axis-aligned bounding boxes (lo, hi), each (n_geom, 3) m; planes are infinite."""
    extent = np.einsum("gij,gj->gi", np.abs(world.rot), world.half)
    kind = cm.geom_type
    caps = kind == CAPSULE
    extent[caps] += cm.geom_radius[caps, None]
    lo, hi = world.pos - extent, world.pos + extent
    for g in np.flatnonzero((kind == CONVEX) | (kind == MESH)):
        v = matmul(cm.geom_vertices[g], world.rot[g].T)
        lo[g], hi[g] = world.pos[g] + v.min(axis=0), world.pos[g] + v.max(axis=0)
    planes = kind == PLANE
    lo[planes], hi[planes] = -np.inf, np.inf
    return lo, hi


def subset(cm: CollisionModel, idx) -> CollisionModel:
    """The geoms `idx` (m,) as a model of their own, each its own body (geom_body =
    0..m-1), sharing the parent's fcl cache."""
    idx = np.asarray(idx, dtype=np.int64)
    return CollisionModel(
        tolerance=cm.tolerance, broad_phase=cm.broad_phase, continuous=cm.continuous,
        geom_body=np.arange(len(idx)), geom_type=cm.geom_type[idx],
        geom_geometry=tuple(cm.geom_geometry[i] for i in idx),
        geom_world_aabb=cm.geom_world_aabb[idx], geom_local_pos=cm.geom_local_pos[idx],
        geom_local_quat=cm.geom_local_quat[idx], geom_radius=cm.geom_radius[idx],
        geom_half=cm.geom_half[idx], geom_plane_normal=cm.geom_plane_normal[idx],
        geom_plane_offset=cm.geom_plane_offset[idx], geom_rbound=cm.geom_rbound[idx],
        geom_vertices=tuple(cm.geom_vertices[i] for i in idx),
        geom_faces=tuple(cm.geom_faces[i] for i in idx), cache=cm.cache)
