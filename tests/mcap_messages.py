"""Read an MCAP file as the Foxglove SDK defines its messages: every message decoded with
the protobuf runtime against the SDK's own schema (Foxglove types) or vrsim's (vrsim
types), refusing unknown fields, and returned as plain dicts (protobuf's JSON mapping with
the .proto field names; floats stay floats).

The decoders are built from `foxglove.messages.<Type>.get_schema()`, not from the schema
the file carries, so a file whose schema drifted from the SDK's fails here; the file's
schema records are checked to be byte-equal to the SDK's too.
"""

from __future__ import annotations

from functools import lru_cache

import foxglove.messages
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.json_format import MessageToDict
from mcap.reader import make_reader

from vrsim_cli.writers import vrsim_messages


@lru_cache(maxsize=None)
def reference_schema(name: str) -> bytes:
    """The schema data a channel of type `name` must carry: the SDK's or vrsim's."""
    package, _, type_name = name.partition(".")
    if package == "foxglove":
        return getattr(foxglove.messages, type_name).get_schema().data
    if package == "vrsim":
        return vrsim_messages.schema_data()
    raise AssertionError(f"unexpected schema {name}")


@lru_cache(maxsize=None)
def message_type(name: str):
    """The protobuf class of `name` built from the reference schema (protobuf's own
    GetMessages orders the files by their dependencies)."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(reference_schema(name))
    return message_factory.GetMessages(list(fds.file), pool=descriptor_pool.DescriptorPool())[
        name]


def _no_unknown_fields(message, where: str) -> None:
    """Fail on fields the schema does not know, at any depth (a wrong field number)."""
    from google.protobuf.unknown_fields import UnknownFieldSet

    assert len(UnknownFieldSet(message)) == 0, f"{where}: fields the schema does not define"
    for field, value in message.ListFields():
        if field.type == field.TYPE_MESSAGE:
            for item in (value if field.is_repeated else [value]):
                _no_unknown_fields(item, f"{where}.{field.name}")


def decode(name: str, data: bytes, where: str = "") -> dict:
    message = message_type(name).FromString(data)
    _no_unknown_fields(message, where or name)
    return MessageToDict(message, preserving_proto_field_name=True,
                         always_print_fields_with_no_presence=True)


def read(path, topics=None) -> tuple[dict, dict]:
    """({topic: [(log_time ns, message dict)]}, {topic: schema name}) of an MCAP file,
    after checking every channel's encoding and schema record."""
    messages: dict = {}
    schemas: dict = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages(topics=topics):
            if channel.topic not in schemas:
                assert channel.message_encoding == "protobuf", channel
                assert schema.encoding == "protobuf", schema
                assert schema.data == reference_schema(schema.name), \
                    f"{channel.topic}: the schema record differs from the SDK's {schema.name}"
                schemas[channel.topic] = schema.name
            messages.setdefault(channel.topic, []).append(
                (message.log_time, decode(schema.name, message.data, channel.topic)))
    return messages, schemas


def seconds(stamp: str | dict) -> float:
    """Seconds of a google.protobuf.Timestamp in protobuf's JSON mapping (RFC 3339)."""
    from vrsim_cli.tools.trajectory import _rfc3339_seconds

    return _rfc3339_seconds(stamp)
