"""MCAP output that Foxglove's 3D panel shows without configuration.

Channels (JSON encoding, zstd-compressed chunks):
- `/tf` (`foxglove.FrameTransforms`): one transform `world` -> entity per entity per sample;
- `/scene` (`foxglove.SceneUpdate`): one frame-locked entity per body with its shape and
  colour, published at the first sample (planes are drawn as a 20 m square in `world`);
- `/vrsim/state` (`vrsim.State`): the full state, the same numbers as the CSV columns;
- `/vrsim/input` (`vrsim.Input`): the sensor values of every frame, when there is an
  observer, so a later run can replay them (`input.replay`);
- `/vrsim/contacts`, `/vrsim/contacts/raw`: collision contacts, when the scene has a
  collision block (see mcap_contacts.py).
Metadata record `vrsim`: the vrsim version, the scene file's name and text, dt, frame rate
and integrator, so a trajectory file always says how it was made.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

from vrsim_cli import __version__
from vrsim_cli.errors import OutputError
from vrsim_cli.maths.spatial import quat_rotating
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.writers.atomic import AtomicFile
from vrsim_cli.writers.entities import entity_arrays, entity_names
from vrsim_cli.writers.foxglove_schemas import (FRAME_TRANSFORMS, SCENE_UPDATE, STATE_COLUMNS,
                                                VRSIM_INPUT, VRSIM_STATE, schema_bytes)

POINT_MASS_DIAMETER = 0.05  # m, how a body without a shape is drawn
PLANE_EXTENT = 20.0  # m, side of the square that draws an infinite plane
MESH_MEDIA_TYPES = {".stl": "model/stl", ".glb": "model/gltf-binary",
                    ".gltf": "model/gltf+json", ".obj": "model/obj",
                    ".dae": "model/vnd.collada+xml"}
# Foxglove cylinders stand along their local z; vrsim's along the body's local y.
Z_TO_Y = [float(c) for c in quat_rotating([0, 0, 1], [0, 1, 0])]
# Foxglove arrows point along their local +x; the observer looks along its local -z.
X_TO_MINUS_Z = [float(c) for c in quat_rotating([1, 0, 0], [0, 0, -1])]
OBSERVER_COLOR = (1.0, 0.85, 0.1, 1.0)


def _time(ns: int) -> dict:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _vec(v) -> dict:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _quat_xyzw(q_wxyz) -> dict:
    return {"x": float(q_wxyz[1]), "y": float(q_wxyz[2]), "z": float(q_wxyz[3]),
            "w": float(q_wxyz[0])}


def _pose(position=(0.0, 0.0, 0.0), q_wxyz=(1.0, 0.0, 0.0, 0.0)) -> dict:
    return {"position": _vec(position), "orientation": _quat_xyzw(q_wxyz)}


def _color(rgba) -> dict:
    return {"r": float(rgba[0]), "g": float(rgba[1]), "b": float(rgba[2]), "a": float(rgba[3])}


def scene_entity(name: str, shape: dict | None, rgba, ns: int) -> dict:
    """The foxglove.SceneEntity drawing one body in its own frame."""
    color = _color(rgba)
    entity = {"timestamp": _time(ns), "frame_id": name, "id": name,
              "lifetime": {"sec": 0, "nsec": 0}, "frame_locked": True,
              "metadata": [{"key": "shape", "value": (shape or {}).get("type", "point")}],
              "arrows": [], "spheres": [], "cubes": [], "cylinders": [], "models": []}
    kind = (shape or {}).get("type")
    if kind == "observer":  # an arrow along the view direction and a small head
        entity["arrows"].append({"pose": _pose(q_wxyz=X_TO_MINUS_Z), "shaft_length": 0.3,
                                 "shaft_diameter": 0.03, "head_length": 0.1,
                                 "head_diameter": 0.08, "color": color})
        entity["spheres"].append({"pose": _pose(), "size": _vec([0.15] * 3), "color": color})
    elif kind is None:
        d = POINT_MASS_DIAMETER
        entity["spheres"].append({"pose": _pose(), "size": _vec([d, d, d]), "color": color})
    elif kind == "sphere":
        d = 2.0 * shape["radius"]
        entity["spheres"].append({"pose": _pose(), "size": _vec([d, d, d]), "color": color})
    elif kind == "box":
        size = [s if s > 0 else 1e-3 for s in shape["size"]]  # 2D boxes get a thin z
        entity["cubes"].append({"pose": _pose(), "size": _vec(size), "color": color})
    elif kind in ("cylinder", "capsule"):
        d, length = 2.0 * shape["radius"], shape["length"]
        entity["cylinders"].append({"pose": _pose(q_wxyz=Z_TO_Y), "size": _vec([d, d, length]),
                                    "bottom_scale": 1.0, "top_scale": 1.0, "color": color})
        if kind == "capsule":
            for end in (-0.5 * length, 0.5 * length):
                entity["spheres"].append({"pose": _pose([0.0, end, 0.0]),
                                          "size": _vec([d, d, d]), "color": color})
    elif kind == "plane":
        normal, offset = shape["normal"], shape["offset"]
        entity["frame_id"], entity["frame_locked"] = "world", False
        centre = [offset * c for c in normal]
        entity["cubes"].append({"pose": _pose(centre, shape["orientation"]),
                                "size": _vec([PLANE_EXTENT, 1e-3, PLANE_EXTENT]),
                                "color": color})
    elif kind == "mesh":
        path = Path(shape["path"])
        scale = float(shape.get("scale", 1.0))
        entity["models"].append({
            "pose": _pose(), "scale": _vec([scale] * 3), "color": color, "override_color": True,
            "url": "", "media_type": MESH_MEDIA_TYPES.get(path.suffix.lower(), "model/stl"),
            "data": base64.b64encode(path.read_bytes()).decode("ascii")})
    return entity


class McapWriter:
    def __init__(self, model: Model, path: Path):
        from mcap.writer import CompressionType, Writer  # only runs that write MCAP pay

        self.model = model
        self.names = entity_names(model)
        self.out = AtomicFile(path)
        self.samples = 0
        try:
            self.writer = Writer(self.out.file, compression=CompressionType.ZSTD)
            self.writer.start(profile="", library=f"vrsim {__version__}")
            tf = self.writer.register_schema("foxglove.FrameTransforms", "jsonschema",
                                             schema_bytes(FRAME_TRANSFORMS))
            scene = self.writer.register_schema("foxglove.SceneUpdate", "jsonschema",
                                                schema_bytes(SCENE_UPDATE))
            state = self.writer.register_schema("vrsim.State", "jsonschema",
                                                schema_bytes(VRSIM_STATE))
            inputs = self.writer.register_schema("vrsim.Input", "jsonschema",
                                                 schema_bytes(VRSIM_INPUT))
            self.tf_channel = self.writer.register_channel("/tf", "json", tf)
            self.scene_channel = self.writer.register_channel("/scene", "json", scene)
            self.state_channel = self.writer.register_channel("/vrsim/state", "json", state)
            self.input_channel = self.writer.register_channel("/vrsim/input", "json", inputs) \
                if model.observer is not None else None
            self.animation = None  # colour/scale/attribute tracks: see mcap_animation.py
            if model.animation is not None and model.animation.has_appearance:
                from vrsim_cli.writers.mcap_animation import AnimationChannel
                self.animation = AnimationChannel(self)
            self.contacts = None  # collision contacts: see mcap_contacts.py
            if getattr(model, "collision", None) is not None:
                from vrsim_cli.writers.mcap_contacts import ContactsChannel
                self.contacts = ContactsChannel(self, scene)
            self.writer.add_metadata("vrsim", {
                "version": __version__, "scene_file": Path(model.scene_file).name,
                "scene": model.scene_text, "dt": repr(model.dt),
                "frame_rate": repr(model.frame_rate), "integrator": model.integrator,
                "dimension": str(model.dimension)})
        except OSError as exc:
            self.out.discard()
            raise OutputError(f"cannot write {path}: {exc.strerror}") from None

    def _add(self, channel: int, ns: int, message: dict) -> None:
        data = json.dumps(message, separators=(",", ":")).encode()
        try:
            self.writer.add_message(channel, log_time=ns, data=data, publish_time=ns,
                                    sequence=self.samples)
        except OSError as exc:
            raise OutputError(f"cannot write {self.out.path}: {exc.strerror}") from None

    def write(self, state: State) -> None:
        ns = round(state.t * 1e9)
        rows = entity_arrays(self.model, state).tolist()
        if self.samples == 0:
            shapes = self.model.body_shape + ({"type": "observer"},)
            colors = self.model.body_color.tolist() + [OBSERVER_COLOR]
            entities = [scene_entity(name, shape, color, ns) for name, shape, color in
                        zip(self.names, shapes, colors)]
            self._add(self.scene_channel, ns, {"deletions": [], "entities": entities})
        if self.animation is not None:
            self.animation.write(ns, state.t, scene_entity)
        stamp = _time(ns)
        self._add(self.tf_channel, ns, {"transforms": [
            {"timestamp": stamp, "parent_frame_id": "world", "child_frame_id": name,
             "translation": {"x": r[0], "y": r[1], "z": r[2]},
             "rotation": {"x": r[4], "y": r[5], "z": r[6], "w": r[3]}}
            for name, r in zip(self.names, rows)]})
        self._add(self.state_channel, ns, {"t": float(state.t), "step": int(state.step),
                                           "entities": [{"name": name,
                                                         **dict(zip(STATE_COLUMNS, r))}
                                                        for name, r in zip(self.names, rows)]})
        if self.contacts is not None:
            self.contacts.write(ns, state, _pose, _vec, _color, _time)
        self.samples += 1

    def write_input(self, inputs) -> None:
        """Record one frame's sensor values on /vrsim/input (replayed by input.replay)."""
        if self.input_channel is not None:
            self._add(self.input_channel, round(inputs.t * 1e9), inputs.record())

    def close(self) -> None:
        try:
            self.writer.finish()
        except OSError as exc:
            self.out.discard()
            raise OutputError(f"cannot write {self.out.path}: {exc.strerror}") from None
        self.out.commit()

    def abort(self) -> None:
        self.out.discard()
