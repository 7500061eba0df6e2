"""MCAP output and live view that Foxglove's 3D panel shows upright, without configuration.

Written through the Foxglove SDK (`foxglove-sdk`): its MCAP writer, its WebSocket server
(`vrsim run --live`, see `live.py`) and its message schemas, all protobuf. A run logs
each message once; every sink of the run (the file, the live server, or both) gets the
same channels and the same messages.

Frames: `world` is z-up, as Foxglove and ROS (REP 103) expect. The scene's own frame,
`scene`, hangs under it by a fixed rotation (`output.up`: a y-up scene, the default, is
turned +90 degrees about x, so its y becomes world z; a z-up scene is not turned). Every
entity is a frame under `scene`, so positions in the file are the scene's numbers, as in
the CSV output.

Channels (protobuf messages, lz4-compressed chunks):
- `/tf` (`foxglove.FrameTransforms`): at every sample `world` -> `scene` and `scene` ->
  entity for each entity that exists (an emitted particle from its emission on);
- `/scene` (`foxglove.SceneUpdate`): one frame-locked entity per body with its shape and
  colour, published at the sample where the body first exists (planes are drawn as a
  20 m square in `scene`);
- `/vrsim/state` (`vrsim.State`): the full state of every entity, the CSV's numbers;
- `/vrsim/input` (`vrsim.Input`): the sensor values of every frame, when there is an
  observer, so a later run can replay them (`input.replay`);
- `/vrsim/contacts`, `/vrsim/contacts/raw`: collision contacts, when the scene has a
  collision block (see mcap_contacts.py); `/vrsim/animation`: keyframed looks (see
  mcap_animation.py).
Metadata record `vrsim`: the vrsim version, the scene file's name and text, dt, frame rate,
integrator and up axis, so a trajectory file always says how it was made.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from vrsim_cli import __version__
from vrsim_cli.errors import OutputError
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.writers.atomic import AtomicFile
from vrsim_cli.writers.entities import entity_names
from vrsim_cli.writers.foxglove_scene import (OBSERVER_COLOR, SCENE, SCENE_TO_WORLD, SPRINGS,
                                              WORLD, drawn_shapes, fox, foxglove_schema,
                                              scene_entity, springs_entity, vrsim_schema)
from vrsim_cli.writers.foxglove_wire import FrameTransformsEncoder, StateEncoder

class Outlet:
    """The channels of one Foxglove context: an MCAP file's or a live server's."""

    def __init__(self, context):
        self.context = context
        self.channels: dict = {}

    def add(self, topic: str, schema) -> None:
        import foxglove

        self.channels[topic] = foxglove.Channel(topic, schema=schema,
                                                message_encoding="protobuf",
                                                context=self.context)

    def log(self, topic: str, data: bytes, ns: int) -> None:
        self.channels[topic].log(data, log_time=ns)


class _RecordingFile:
    """The file the SDK writes to, remembering the last OSError: the SDK reports a failed
    write as its own RuntimeError without the reason (e.g. 'No space left on device')."""

    def __init__(self, file):
        self.file = file
        self.error: OSError | None = None

    def _call(self, method, *args):
        try:
            return getattr(self.file, method)(*args)
        except OSError as exc:
            self.error = exc
            raise

    def write(self, data):
        return self._call("write", data)

    def seek(self, offset, whence=0):
        return self._call("seek", offset, whence)

    def tell(self):
        return self._call("tell")

    def flush(self):
        return self._call("flush")


class _SdkErrors(logging.Filter):
    """Holds back the SDK's "error logging message: McapError(...)" records (one per
    message once a write failed: 42 000 lines on stderr for a run on a full disk); the
    run stops at the first failed write instead and says why once (`McapWriter.log`).
    Installed on the SDK's logger for the writer's life."""

    LOGGER = "foxglove"

    def __init__(self):
        super().__init__()
        self.held = 0
        logging.getLogger(self.LOGGER).addFilter(self)
        for handler in logging.getLogger().handlers + [logging.lastResort]:
            if handler is not None:
                handler.addFilter(self)  # records of child loggers reach these unfiltered

    def filter(self, record) -> bool:
        if record.name.startswith(self.LOGGER) and "error logging message" in \
                record.getMessage():
            self.held += 1
            return False
        return True

    def remove(self) -> None:
        logging.getLogger(self.LOGGER).removeFilter(self)
        for handler in logging.getLogger().handlers + [logging.lastResort]:
            if handler is not None:
                handler.removeFilter(self)


class McapWriter:
    """Writes a run to an MCAP file (`path`), to a live server (`live`, a `live.LiveServer`),
    or to both, with the same channels and messages."""

    def __init__(self, model: Model, path: Path | None, live=None):
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.model = model
        self.names = entity_names(model)
        self.samples = 0
        self.out = AtomicFile(path).seekable() if path is not None else None
        self.path = path
        self.live = live
        self.outlets: list[Outlet] = []
        self.mcap = None
        self.file = None
        self.sdk_errors = _SdkErrors() if path is not None else None
        up = getattr(model.output, "up", "y")
        self.scene_rotation = SCENE_TO_WORLD[up]
        try:
            if self.out is not None:
                context = foxglove.Context()
                # lz4 chunks: twice as fast to write as zstd for the same data (1000
                # bodies: 0.6 against 1.2 ms per sample), files about 1.4 times larger;
                # one thread, so output never competes with the simulation for a core
                self.file = _RecordingFile(self.out.file)
                self.mcap = foxglove.open_mcap(self.file, context=context,
                                               writer_options=MCAPWriteOptions(
                                                   compression=MCAPCompression.Lz4,
                                                   compression_threads=0))
                self.outlets.append(Outlet(context))
            self.live_outlet = None
            if live is not None:
                self.live_outlet = Outlet(live.context)
                self.outlets.append(self.live_outlet)
            self._channels(model)
            if self.mcap is not None:
                self.mcap.write_metadata("vrsim", {
                    "version": __version__, "scene_file": Path(model.scene_file).name,
                    "scene": model.scene_text, "dt": repr(model.dt),
                    "frame_rate": repr(model.frame_rate), "integrator": model.integrator,
                    "dimension": str(model.dimension), "up": up})
        except (OSError, RuntimeError) as exc:  # the SDK's I/O errors are RuntimeErrors
            error = self._error(exc)
            self.abort()
            raise error from None
        n = len(self.names)
        self.tf = FrameTransformsEncoder(SCENE, list(self.names))
        self.root_tf = FrameTransformsEncoder(WORLD, [SCENE])
        self.state_encoder = StateEncoder(list(self.names))
        # which entities exist: bodies from their emission step on, the observer always
        self.emit_step = np.concatenate([model.body_emit_step,
                                         np.zeros(n - model.n_body, dtype=np.int64)])
        self.shown = np.zeros(n, dtype=bool)
        self.entities: dict = {}  # id -> the SceneEntity last published (live re-sends)
        # as in the rendered frames: particle bodies as their particles and hull, point
        # masses sized to the scene
        self.shapes = drawn_shapes(model) + [{"type": "observer"}] * (n - model.n_body)
        self.colors = model.body_color.tolist() + [OBSERVER_COLOR] * (n - model.n_body)
        # springs move with their bodies: one line list, replaced at every sample
        self.springs = model.rigid is not None and len(model.rigid.spring_a) > 0

    def _channels(self, model: Model) -> None:
        topics = {"/tf": foxglove_schema("FrameTransforms"),
                  "/scene": foxglove_schema("SceneUpdate"),
                  "/vrsim/state": vrsim_schema("State")}
        if model.observer is not None:
            topics["/vrsim/input"] = vrsim_schema("Input")
        self.animation = None  # colour/scale/attribute tracks: see mcap_animation.py
        if model.animation is not None and model.animation.has_appearance:
            from vrsim_cli.writers.mcap_animation import AnimationChannel
            self.animation = AnimationChannel(self)
            topics["/vrsim/animation"] = vrsim_schema("Animation")
        self.contacts = None  # collision contacts: see mcap_contacts.py
        if getattr(model, "collision", None) is not None:
            from vrsim_cli.writers.mcap_contacts import ContactsChannel
            self.contacts = ContactsChannel(self)
            topics["/vrsim/contacts"] = foxglove_schema("SceneUpdate")
            topics["/vrsim/contacts/raw"] = vrsim_schema("Contacts")
        self.topics = topics
        for outlet in self.outlets:
            for topic, schema in topics.items():
                outlet.add(topic, schema)

    def _error(self, exc: Exception) -> OutputError:
        """An OutputError with the operating system's reason when there is one."""
        cause = self.file.error if self.file is not None and self.file.error else exc
        return OutputError(f"cannot write {self.path}: {getattr(cause, 'strerror', None) or cause}")

    def log(self, topic: str, data: bytes, ns: int) -> None:
        """Send one encoded message to every sink of the run."""
        try:
            for outlet in self.outlets:
                outlet.log(topic, data, ns)
        except (OSError, RuntimeError) as exc:
            raise self._error(exc) from None
        if self.file is not None and self.file.error is not None:
            # the SDK only logs a failed write, and fails every later one: stop the run
            # now (the previous file stays) rather than at the end
            raise self._error(self.file.error)

    def publish_entities(self, entities: dict, ns: int) -> None:
        """A foxglove.SceneUpdate of `entities` {id: SceneEntity} on /scene; remembered for
        live re-sends (the SDK's messages do not expose their fields)."""
        if entities:
            self.log("/scene", fox().SceneUpdate(entities=list(entities.values())).encode(), ns)
            self.entities.update(entities)

    def write(self, state: State) -> None:
        ns = round(state.t * 1e9)
        pos, quat, vel, angvel = _entity_columns(self.model, state)
        exists = self.emit_step <= state.step
        new = np.flatnonzero(exists & ~self.shown)
        if len(new):  # bodies that exist from this sample on
            self.shown[new] = True
            self.publish_entities({self.names[i]: scene_entity(self.names[i], self.shapes[i],
                                                               self.colors[i], ns)
                                   for i in new.tolist()}, ns)
        if self.springs:
            from vrsim_cli.render.geometry import spring_segments

            self.publish_entities({SPRINGS: springs_entity(
                spring_segments(self.model, state), ns)}, ns)
        if self.live is not None and self.live.take_scene_request():
            self.live.resend_scene(self, ns)
        if self.animation is not None:
            self.animation.write(ns, state.t)
        root = self.root_tf.encode(ns, np.zeros((1, 3)), np.array([self.scene_rotation]))
        rows = None if exists.all() else np.flatnonzero(exists)
        self.log("/tf", root + self.tf.encode(ns, pos, quat, rows), ns)
        self.log("/vrsim/state", self.state_encoder.encode(state.t, state.step, pos, quat, vel,
                                                           angvel), ns)
        if self.contacts is not None:
            self.contacts.write(ns, state)
        self.samples += 1

    def write_input(self, inputs) -> None:
        """Record one frame's sensor values on /vrsim/input (replayed by input.replay)."""
        if "/vrsim/input" not in self.topics:
            return
        from vrsim_cli.writers.vrsim_messages import message_class

        record = inputs.record()
        message = message_class("Input")(t=record["t"], frame=record["frame"],
                                         alpha=record["alpha"], beta=record["beta"],
                                         pitch=record["pitch"], pose=record.get("pose", []))
        self.log("/vrsim/input", message.SerializeToString(), round(inputs.t * 1e9))

    def close(self) -> None:
        if self.mcap is not None:
            try:
                self.mcap.close()
                failed = self.file.error  # a write the SDK only logged
            except (OSError, RuntimeError) as exc:
                failed = exc
            self.mcap = None
            if failed is not None:
                error = self._error(failed)
                self.abort()
                raise error from None
        if self.out is not None:
            self.out.commit()
        self._release()

    def abort(self) -> None:
        if self.mcap is not None:
            try:
                self.mcap.close()
            except Exception:  # noqa: BLE001 - the run already failed; keep its error
                pass
            self.mcap = None
        if self.out is not None:
            self.out.discard()
        self._release()

    def _release(self) -> None:
        if self.sdk_errors is not None:
            self.sdk_errors.remove()
            self.sdk_errors = None


def _entity_columns(model: Model, state: State):
    """(pos (n, 3), quat (n, 4), vel (n, 3), angvel (n, 3)) of bodies then the observer."""
    if model.observer is None:
        return state.body_pos, state.body_quat, state.body_vel, state.body_angvel
    return (np.vstack([state.body_pos, state.observer_pos]),
            np.vstack([state.body_quat, state.observer_quat]),
            np.vstack([state.body_vel, state.observer_vel]),
            np.vstack([state.body_angvel, state.observer_angvel]))
