"""Compile the scene's keyframes, drives and parents into a frozen `Animation`.

Layer 2, beside `model` (which calls `compile_animation` and keeps the result in
`Model.animation`; None when the scene animates nothing, so other scenes pay nothing).

Nodes are the bodies with a position or orientation track, a `drive` or a `parent`. Their
`position` and `orientation` in the scene are local: relative to the parent's frame (the
world for a body without a parent). Nodes are sorted into levels: level 0 has no parent, a node one
level below its parent when the parent is a node, else level 1; the scene graph stage
composes level by level, so a parent's world pose is always known before its children's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vrsim_cli.errors import Problem
from vrsim_cli.model.keyframes import TrackError, compile_track, evaluate
from vrsim_cli.scene.animation import COLOR, ROTATION, VECTOR, is_node

LOCAL_TRACKS = (("position", VECTOR), ("orientation", ROTATION), ("angle_deg", VECTOR))


@dataclass(frozen=True)
class Animation:
    """Constants of the animated part of a run. n_node nodes (see module docstring).

    node_body: (n_node,) int64 body index of each node
    node_parent: (n_node,) int64 body index of the parent, -1 for none
    levels: tuple of (k,) int64 arrays of node indices, level 0 first
    node_pos0: (n_node, 3) m, local position when no track or drive sets it
    node_quat0: (n_node, 4) local orientation [w, x, y, z] when no track or drive sets it
    pos_tracks: ((node, Track), ...) local position, m and m/s
    rot_tracks: ((node, Track, is_angle), ...) local orientation; is_angle: a 2D angle_deg
        track (degrees about z), else a quaternion track
    drive_node: (n_drive,) int64; drive_speed (n_drive,) m/s; drive_heading0 (n_drive,)
        rad; drive_yaw_rate (n_drive,) rad/s. Heading is about the up axis (y in 3D, z in
        2D); the forward direction at heading 0 is +z in 3D (the walk plane of slide 5.1)
        and +x in 2D.
    color_tracks, scale_tracks: ((body, Track), ...); attr_tracks: ((body, name, Track), ...)
    """

    dimension: int
    node_body: np.ndarray
    node_parent: np.ndarray
    levels: tuple
    node_pos0: np.ndarray
    node_quat0: np.ndarray
    pos_tracks: tuple
    rot_tracks: tuple
    drive_node: np.ndarray
    drive_speed: np.ndarray
    drive_heading0: np.ndarray
    drive_yaw_rate: np.ndarray
    color_tracks: tuple
    scale_tracks: tuple
    attr_tracks: tuple

    @property
    def has_motion(self) -> bool:
        """True when some body's pose comes from the animation (the loop runs the stage)."""
        return len(self.node_body) > 0

    @property
    def has_appearance(self) -> bool:
        """True when colours, scales or attributes change over time (outputs show them)."""
        return bool(self.color_tracks or self.scale_tracks or self.attr_tracks)


def compile_animation(scene, dim: int, pos0, quat0, problems: list[Problem]):
    """Animation of the scene's bodies, or None when nothing is animated.

    pos0 (n_body, 3) and quat0 (n_body, 4): the bodies' positions and orientations as the
    model read them (local for nodes). Track problems are appended to `problems`.
    """
    bodies = scene.data.get("bodies") or []
    index = {b["name"]: i for i, b in enumerate(bodies)}
    nodes = [i for i, b in enumerate(bodies) if is_node(b)]
    appearance = [i for i, b in enumerate(bodies)
                  if {"color", "scale", "attributes"} & set(b.get("keyframes") or {})]
    if not nodes and not appearance:
        return None

    def track(i, key, kind, path=()):
        spec = bodies[i]["keyframes"]
        for part in (key,) + path:
            spec = spec[part]
        try:
            return compile_track(spec, kind)
        except TrackError as exc:
            for sub, message, hint in exc.issues:
                problems.append(scene.problem(("bodies", i, "keyframes", key) + path + sub,
                                              message, hint))
            return None

    node_of = {b: k for k, b in enumerate(nodes)}
    parent = [index.get(bodies[i].get("parent"), -1) if "parent" in bodies[i] else -1
              for i in nodes]
    level = [None] * len(nodes)

    def depth(k):  # parents are acyclic (checked in scene); memoised
        if level[k] is None:
            p = parent[k]
            level[k] = 0 if p < 0 else (depth(node_of[p]) + 1 if p in node_of else 1)
        return level[k]

    for k in range(len(nodes)):
        depth(k)
    levels = tuple(np.flatnonzero(np.array(level) == d) for d in range(max(level, default=-1)
                                                                        + 1))
    pos_tracks, rot_tracks, drives = [], [], []
    for k, i in enumerate(nodes):
        frames = bodies[i].get("keyframes") or {}
        for key, kind in LOCAL_TRACKS:
            if key in frames:
                compiled = track(i, key, kind)
                if compiled is not None and key == "position":
                    pos_tracks.append((k, compiled))
                elif compiled is not None:
                    rot_tracks.append((k, compiled, key == "angle_deg"))
        if "drive" in bodies[i]:
            d = bodies[i]["drive"]
            drives.append((k, float(d.get("speed", 0.0)),
                           math.radians(float(d.get("heading_deg", 0.0))),
                           math.radians(float(d.get("yaw_rate_deg", 0.0)))))
    colors, scales, attrs = [], [], []
    for i in appearance:
        frames = bodies[i]["keyframes"]
        for key, kind, out in (("color", COLOR, colors), ("scale", VECTOR, scales)):
            if key in frames and (compiled := track(i, key, kind)) is not None:
                out.append((i, compiled))
        for name in frames.get("attributes") or {}:
            if (compiled := track(i, "attributes", VECTOR, (name,))) is not None:
                attrs.append((i, name, compiled))
    drive = np.array(drives, dtype=float).reshape(-1, 4)
    body = np.array(nodes, dtype=np.int64)
    return Animation(
        dimension=dim, node_body=body, node_parent=np.array(parent, dtype=np.int64),
        levels=levels, node_pos0=np.asarray(pos0, dtype=float)[body].reshape(-1, 3),
        node_quat0=np.asarray(quat0, dtype=float)[body].reshape(-1, 4),
        pos_tracks=tuple(pos_tracks), rot_tracks=tuple(rot_tracks),
        drive_node=drive[:, 0].astype(np.int64), drive_speed=drive[:, 1],
        drive_heading0=drive[:, 2], drive_yaw_rate=drive[:, 3],
        color_tracks=tuple(colors), scale_tracks=tuple(scales), attr_tracks=tuple(attrs))


def appearance(animation: Animation, t: float) -> dict:
    """Animated looks at time t: {body: {'color': RGBA list, 'scale': [sx, sy, sz],
    'attributes': {name: value}}} with only the keys that are animated."""
    out: dict = {}
    for body, track in animation.color_tracks:
        out.setdefault(body, {})["color"] = evaluate(track, t)[0].tolist()
    for body, track in animation.scale_tracks:
        value = np.broadcast_to(evaluate(track, t)[0], (3,))
        out.setdefault(body, {})["scale"] = value.tolist()
    for body, name, track in animation.attr_tracks:
        value = evaluate(track, t)[0]
        out.setdefault(body, {}).setdefault("attributes", {})[name] = value.tolist()
    return out
