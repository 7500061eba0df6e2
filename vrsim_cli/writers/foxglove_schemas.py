"""JSON Schemas of the Foxglove message types vrsim writes, and vrsim's own state schema.

Foxglove picks the 3D panel's renderer by schema *name* (`foxglove.FrameTransforms`,
`foxglove.SceneUpdate`); the schema text documents the fields. These are written from
Foxglove's published message definitions, restricted to the fields vrsim uses.
"""

from __future__ import annotations

import json


def _obj(title: str, props: dict, required=None) -> dict:
    return {"title": title, "type": "object", "properties": props,
            "required": list(required if required is not None else props)}


def _numbers(title: str, keys: str) -> dict:
    return _obj(title, {k: {"type": "number"} for k in keys})


TIME = _obj("time", {"sec": {"type": "integer", "minimum": 0},
                     "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}})
DURATION = _obj("duration", {"sec": {"type": "integer"},
                             "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}})
VECTOR3 = _numbers("foxglove.Vector3", "xyz")
QUATERNION = _numbers("foxglove.Quaternion", "xyzw")
COLOR = _numbers("foxglove.Color", "rgba")
POSE = _obj("foxglove.Pose", {"position": VECTOR3, "orientation": QUATERNION})


def _array(items: dict) -> dict:
    return {"type": "array", "items": items}


FRAME_TRANSFORMS = _obj("foxglove.FrameTransforms", {"transforms": _array(_obj(
    "foxglove.FrameTransform",
    {"timestamp": TIME, "parent_frame_id": {"type": "string"},
     "child_frame_id": {"type": "string"}, "translation": VECTOR3, "rotation": QUATERNION}))})

_SIZED = {"pose": POSE, "size": VECTOR3, "color": COLOR}
SCENE_UPDATE = _obj("foxglove.SceneUpdate", {
    "deletions": _array(_obj("foxglove.SceneEntityDeletion",
                             {"timestamp": TIME, "type": {"type": "integer", "enum": [0, 1]},
                              "id": {"type": "string"}})),
    "entities": _array(_obj("foxglove.SceneEntity", {
        "timestamp": TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
        "lifetime": DURATION, "frame_locked": {"type": "boolean"},
        "metadata": _array(_obj("foxglove.KeyValuePair",
                                {"key": {"type": "string"}, "value": {"type": "string"}})),
        "arrows": _array(_obj("foxglove.ArrowPrimitive", {
            "pose": POSE, "shaft_length": {"type": "number"},
            "shaft_diameter": {"type": "number"}, "head_length": {"type": "number"},
            "head_diameter": {"type": "number"}, "color": COLOR})),
        "spheres": _array(_obj("foxglove.SpherePrimitive", _SIZED)),
        "cubes": _array(_obj("foxglove.CubePrimitive", _SIZED)),
        "cylinders": _array(_obj("foxglove.CylinderPrimitive",
                                 {**_SIZED, "bottom_scale": {"type": "number"},
                                  "top_scale": {"type": "number"}})),
        "models": _array(_obj("foxglove.ModelPrimitive", {
            "pose": POSE, "scale": VECTOR3, "color": COLOR, "override_color": {"type": "boolean"},
            "url": {"type": "string"}, "media_type": {"type": "string"},
            "data": {"type": "string", "contentEncoding": "base64"}})),
    }, required=["timestamp", "frame_id", "id", "lifetime", "frame_locked"])),
})

_STATE_COLUMNS = ("px", "py", "pz", "qw", "qx", "qy", "qz", "vx", "vy", "vz", "wx", "wy", "wz")
VRSIM_STATE = {
    "title": "vrsim.State",
    "description": "Full state of every entity at one sample: the columns of vrsim's CSV "
                   "output. Positions m, quaternion [w, x, y, z], velocities m/s, angular "
                   "velocities rad/s (world frame).",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "simulated time, s"},
        "step": {"type": "integer", "description": "physics step index"},
        "entities": _array(_obj("vrsim.EntityState", {
            "name": {"type": "string"}, **{c: {"type": "number"} for c in _STATE_COLUMNS}})),
    },
    "required": ["t", "step", "entities"],
}
STATE_COLUMNS = _STATE_COLUMNS

VRSIM_INPUT = {
    "title": "vrsim.Input",
    "description": "Sensor values of one frame (loop stage 1): mouse alpha, beta, pitch in "
                   "[-1, 1], and the head-tracker pose [px, py, pz, qw, qx, qy, qz] when "
                   "tracked. A later run replays them with input.replay.",
    "type": "object",
    "properties": {
        "t": {"type": "number", "description": "frame start time, s"},
        "frame": {"type": "integer"},
        "alpha": {"type": "number"}, "beta": {"type": "number"}, "pitch": {"type": "number"},
        "pose": {"type": "array", "items": {"type": "number"}, "minItems": 7, "maxItems": 7},
    },
    "required": ["t", "frame", "alpha", "beta", "pitch"],
}


def schema_bytes(schema: dict) -> bytes:
    return json.dumps(schema, separators=(",", ":")).encode()
