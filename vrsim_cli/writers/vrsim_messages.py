"""vrsim's own MCAP message types, as protobuf schemas defined here (the Foxglove types come
from the Foxglove SDK: see `foxglove_wire`).

Layer 6. One `FileDescriptorProto` (package `vrsim`) describes every message vrsim writes
besides the Foxglove ones; each channel's schema record carries it as a serialized
`FileDescriptorSet`, so any protobuf reader (Foxglove, `mcap-protobuf-support`) decodes
the messages without vrsim. Field names and units:

- `vrsim.State` (`/vrsim/state`, one per sample): `t` s, `step`, `entity` (names, in
  order) and per entity, row-major, `position` (n, 3) m, `orientation` (n, 4) [w, x, y, z],
  `velocity` (n, 3) m/s, `angular_velocity` (n, 3) rad/s, all in the scene's frame (the
  CSV columns, exactly). Packed arrays rather than one sub-message per entity: the file
  stays small and writing a sample of 1000 bodies costs microseconds.
- `vrsim.Input` (`/vrsim/input`, one per frame with an observer): `t` s, `frame`, the
  mouse values `alpha`, `beta`, `pitch` in [-1, 1], `pose` [px py pz qw qx qy qz] when
  tracked (empty otherwise).
- `vrsim.Contacts` (`/vrsim/contacts/raw`): `t`, `step` and per contact `body_a`,
  `body_b`, `point` (3) m, `normal` (3) from A to B, `depth` m (negative: a gap within the
  tolerance), `toi` s after the step's start (NaN: a contact of the end-of-step state),
  `impulse` (3) N s on body_b (empty without a response).
- `vrsim.Animation` (`/vrsim/animation`): `t` and per animated body `name`, `color`
  RGBA, `scale` [sx, sy, sz] (each empty when not animated) and `attributes` (name and
  values; a scalar attribute has one value).
"""

from __future__ import annotations

from functools import lru_cache

PACKAGE = "vrsim"
FILE_NAME = "vrsim/messages.proto"

# (message, [(field, number, type, repeated)]); types are FieldDescriptorProto.TYPE_* names.
MESSAGES = {
    "State": [("t", 1, "DOUBLE", False), ("step", 2, "UINT64", False),
              ("entity", 3, "STRING", True), ("position", 4, "DOUBLE", True),
              ("orientation", 5, "DOUBLE", True), ("velocity", 6, "DOUBLE", True),
              ("angular_velocity", 7, "DOUBLE", True)],
    "Input": [("t", 1, "DOUBLE", False), ("frame", 2, "UINT64", False),
              ("alpha", 3, "DOUBLE", False), ("beta", 4, "DOUBLE", False),
              ("pitch", 5, "DOUBLE", False), ("pose", 6, "DOUBLE", True)],
    "Contact": [("body_a", 1, "STRING", False), ("body_b", 2, "STRING", False),
                ("point", 3, "DOUBLE", True), ("normal", 4, "DOUBLE", True),
                ("depth", 5, "DOUBLE", False), ("toi", 6, "DOUBLE", False),
                ("impulse", 7, "DOUBLE", True)],
    "Contacts": [("t", 1, "DOUBLE", False), ("step", 2, "UINT64", False),
                 ("contacts", 3, "vrsim.Contact", True)],
    "Attribute": [("name", 1, "STRING", False), ("value", 2, "DOUBLE", True)],
    "Look": [("name", 1, "STRING", False), ("color", 2, "DOUBLE", True),
             ("scale", 3, "DOUBLE", True), ("attributes", 4, "vrsim.Attribute", True)],
    "Animation": [("t", 1, "DOUBLE", False), ("entities", 2, "vrsim.Look", True)],
}


@lru_cache(maxsize=None)
def file_descriptor():
    """The FileDescriptorProto of package `vrsim` (proto3)."""
    from google.protobuf import descriptor_pb2

    field_type = descriptor_pb2.FieldDescriptorProto
    proto = descriptor_pb2.FileDescriptorProto(name=FILE_NAME, package=PACKAGE,
                                               syntax="proto3")
    for name, fields in MESSAGES.items():
        message = proto.message_type.add(name=name)
        for field, number, kind, repeated in fields:
            entry = message.field.add(
                name=field, number=number,
                label=field_type.LABEL_REPEATED if repeated else field_type.LABEL_OPTIONAL)
            if kind.startswith(PACKAGE + "."):
                entry.type = field_type.TYPE_MESSAGE
                entry.type_name = "." + kind
            else:
                entry.type = getattr(field_type, "TYPE_" + kind)
    return proto


@lru_cache(maxsize=None)
def schema_data() -> bytes:
    """The serialized FileDescriptorSet every vrsim channel's schema record holds."""
    from google.protobuf import descriptor_pb2

    return descriptor_pb2.FileDescriptorSet(file=[file_descriptor()]).SerializeToString()


@lru_cache(maxsize=None)
def _pool():
    from google.protobuf import descriptor_pool

    pool = descriptor_pool.DescriptorPool()
    pool.Add(file_descriptor())
    return pool


@lru_cache(maxsize=None)
def message_class(name: str):
    """The protobuf message class of `vrsim.<name>` (e.g. 'Contacts'); one pool for all,
    so a Contacts message takes Contact messages."""
    from google.protobuf import message_factory

    return message_factory.GetMessageClass(_pool().FindMessageTypeByName(f"{PACKAGE}.{name}"))


def field_number(message: str, field: str) -> int:
    """The field number of `vrsim.<message>.<field>` (for the hand-packed State)."""
    for name, number, _kind, _repeated in MESSAGES[message]:
        if name == field:
            return number
    raise KeyError(f"vrsim.{message} has no field {field}")
