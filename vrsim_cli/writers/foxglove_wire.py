"""Protobuf bytes of the two per-sample messages, written with numpy.

Layer 6. Every other message vrsim writes is built by a library: the Foxglove SDK's own
message classes (`foxglove.messages`) for scenes and the static frame, the protobuf
runtime for vrsim's low-rate types. Two messages grow with the number of bodies and go
out at every sample: `/tf` (`foxglove.FrameTransforms`, one transform per entity) and
`/vrsim/state`. Built through the SDK's Python objects, the transforms of 1000 bodies cost
1.3 ms per sample, more than the whole output budget (1 ms per sample for 1000 bodies);
written here they cost about 0.2 ms (`benchmarks/output_cost.py`).

Nothing here copies a schema. The field numbers and types are read from the schema the
SDK ships (`FrameTransforms.get_schema()`, a FileDescriptorSet) and from vrsim's own
(`vrsim_messages`), and the encoders refuse to start when a field is not what they write.
Tests decode every message with the protobuf runtime against the SDK's schema and compare
with the SDK's own encoder (tests/test_foxglove_output.py).

Protobuf facts used (https://protobuf.dev/programming-guides/encoding/): a field is a
varint key `number << 3 | wire type` then its value; wire type 1 is 8 little-endian bytes
(double), 2 is a varint length then that many bytes (strings, sub-messages, packed
arrays), 0 a varint; a repeated message field is one length-delimited record per element;
fields may come in any order.
"""

from __future__ import annotations

from collections import OrderedDict
from functools import lru_cache

import numpy as np

WIRE_VARINT, WIRE_I64, WIRE_LEN = 0, 1, 2


def varint(value: int) -> bytes:
    """The base-128 varint of a non-negative integer."""
    if value < 0:
        raise ValueError("varint of a negative number")
    out = bytearray()
    while True:
        low, value = value & 0x7F, value >> 7
        if value:
            out.append(low | 0x80)
        else:
            out.append(low)
            return bytes(out)


def key(number: int, wire: int) -> bytes:
    return varint(number << 3 | wire)


def len_field(number: int, payload: bytes) -> bytes:
    return key(number, WIRE_LEN) + varint(len(payload)) + payload


def packed_doubles(number: int, values: np.ndarray) -> bytes:
    """A packed repeated double field (empty arrays are left out, as proto3 does)."""
    data = np.ascontiguousarray(values, dtype="<f8").tobytes()
    return len_field(number, data) if data else b""


@lru_cache(maxsize=None)
def _sdk_pool():
    """The SDK's FrameTransforms schema as a protobuf descriptor pool."""
    from foxglove.messages import FrameTransforms
    from google.protobuf import descriptor_pb2, descriptor_pool

    fds = descriptor_pb2.FileDescriptorSet.FromString(FrameTransforms.get_schema().data)
    pool = descriptor_pool.DescriptorPool()
    pending = {f.name: f for f in fds.file}

    def add(proto):
        for dependency in proto.dependency:
            if dependency in pending:
                add(pending.pop(dependency))
        pool.Add(proto)

    while pending:
        add(pending.popitem()[1])
    return pool


def _field(message, name: str, kind: int, message_type: str | None = None) -> int:
    """The number of `message.name`, checked to have protobuf type `kind`."""
    field = message.fields_by_name.get(name)
    if field is None or field.type != kind or (
            message_type and field.message_type.full_name != message_type):
        raise RuntimeError(f"the Foxglove SDK's {message.full_name} changed: field '{name}' "
                           f"is not what vrsim writes; update vrsim_cli/writers/foxglove_wire.py")
    return field.number


@lru_cache(maxsize=None)
def frame_transform_layout() -> dict:
    """Field numbers of foxglove.FrameTransforms as the installed SDK defines them."""
    from google.protobuf.descriptor import FieldDescriptor as F

    pool = _sdk_pool()
    tfs = pool.FindMessageTypeByName("foxglove.FrameTransforms")
    tf = pool.FindMessageTypeByName("foxglove.FrameTransform")
    vec = pool.FindMessageTypeByName("foxglove.Vector3")
    quat = pool.FindMessageTypeByName("foxglove.Quaternion")
    stamp = tf.fields_by_name["timestamp"].message_type
    layout = {
        "transforms": _field(tfs, "transforms", F.TYPE_MESSAGE, "foxglove.FrameTransform"),
        "timestamp": _field(tf, "timestamp", F.TYPE_MESSAGE, "google.protobuf.Timestamp"),
        "parent": _field(tf, "parent_frame_id", F.TYPE_STRING),
        "child": _field(tf, "child_frame_id", F.TYPE_STRING),
        "translation": _field(tf, "translation", F.TYPE_MESSAGE, "foxglove.Vector3"),
        "rotation": _field(tf, "rotation", F.TYPE_MESSAGE, "foxglove.Quaternion"),
        "seconds": _field(stamp, "seconds", F.TYPE_INT64),
        "nanos": _field(stamp, "nanos", F.TYPE_INT32),
    }
    layout.update({f"v{c}": _field(vec, c, F.TYPE_DOUBLE) for c in "xyz"})
    layout.update({f"q{c}": _field(quat, c, F.TYPE_DOUBLE) for c in "xyzw"})
    return layout


def timestamp_payload(ns: int, layout: dict) -> bytes:
    """A google.protobuf.Timestamp of `ns` nanoseconds >= 0 (zero fields left out)."""
    seconds, nanos = divmod(int(ns), 1_000_000_000)
    return ((key(layout["seconds"], WIRE_VARINT) + varint(seconds) if seconds else b"")
            + (key(layout["nanos"], WIRE_VARINT) + varint(nanos) if nanos else b""))


def _numbers_block(fields: list[int]) -> tuple[bytes, list[int]]:
    """A sub-message of doubles: its template bytes and where each double goes."""
    body, offsets = b"", []
    for number in fields:
        body += key(number, WIRE_I64)
        offsets.append(len(body))
        body += bytes(8)
    return body, offsets


class FrameTransformsEncoder:
    """`foxglove.FrameTransforms` bytes for a fixed list of child frames under one parent.

    Each transform is the record: translation, rotation, timestamp, parent, child. Records
    whose child names have the same length have the same layout, so the transforms are
    written in groups of equal name length (a FrameTransforms message is a set: order does
    not matter; children of equal name length keep their order): per group a (k, L) byte
    template built once per (timestamp length, subset of children), into which each
    sample copies its numbers column by column.
    """

    CACHE = 16  # layouts kept: timestamp lengths (1 to 11 bytes) and subsets of children

    def __init__(self, parent: str, children: list[str]):
        self.layout = lay = frame_transform_layout()
        vec, vec_at = _numbers_block([lay["vx"], lay["vy"], lay["vz"]])
        quat, quat_at = _numbers_block([lay["qx"], lay["qy"], lay["qz"], lay["qw"]])
        # translation then rotation, as one block of fixed length per transform
        self.block = len_field(lay["translation"], vec) + len_field(lay["rotation"], quat)
        vec_start = len(key(lay["translation"], WIRE_LEN) + varint(len(vec)))
        quat_start = len(len_field(lay["translation"], vec)) + \
            len(key(lay["rotation"], WIRE_LEN) + varint(len(quat)))
        # byte offsets in the block of x y z (translation) and x y z w (rotation)
        self.number_at = [vec_start + o for o in vec_at] + [quat_start + o for o in quat_at]
        parent_field = len_field(lay["parent"], parent.encode())
        self.tails = [parent_field + len_field(lay["child"], name.encode())
                      for name in children]
        self.tail_len = np.array([len(t) for t in self.tails], dtype=np.int64)
        self.n = len(children)
        self._cache: OrderedDict = OrderedDict()

    def _groups(self, stamp_len: int, rows: np.ndarray | None):
        """[(rows of the group, template (k, L) uint8, number columns, stamp columns)]."""
        cache_key = (stamp_len, None if rows is None else rows.tobytes())
        hit = self._cache.get(cache_key)
        if hit is not None:
            self._cache.move_to_end(cache_key)
            return hit
        lay = self.layout
        rows = np.arange(self.n) if rows is None else rows
        stamp_key = key(lay["timestamp"], WIRE_LEN) + varint(stamp_len)
        fixed = len(self.block) + len(stamp_key) + stamp_len
        record_key = key(lay["transforms"], WIRE_LEN)
        groups = []
        lengths = self.tail_len[rows]
        for tail_len in dict.fromkeys(lengths.tolist()):  # in order of first appearance
            members = rows[lengths == tail_len]
            head = record_key + varint(fixed + tail_len)
            template = np.frombuffer(b"".join(head + self.block + stamp_key + bytes(stamp_len)
                                              + self.tails[i] for i in members.tolist()),
                                     dtype=np.uint8).reshape(len(members), -1)
            # the seven doubles of a record as fields of one (unaligned) numpy record
            numbers = np.dtype({"names": [f"f{j}" for j in range(7)], "formats": ["<f8"] * 7,
                                "offsets": [len(head) + at for at in self.number_at],
                                "itemsize": template.shape[1]})
            stamp_at = len(head) + len(self.block) + len(stamp_key)
            everyone = len(members) == self.n and bool((members == np.arange(self.n)).all())
            groups.append((None if everyone else members, template, numbers, stamp_at))
        self._cache[cache_key] = groups
        if len(self._cache) > self.CACHE:
            self._cache.popitem(last=False)
        return groups

    def encode(self, ns: int, pos: np.ndarray, quat_wxyz: np.ndarray,
               rows: np.ndarray | None = None) -> bytes:
        """The transforms of children `rows` (all when None) at time `ns`: positions
        (n, 3) m and orientations (n, 4) [w, x, y, z] of all children (rows picks)."""
        if rows is not None:
            rows = np.asarray(rows, dtype=np.int64)
            if len(rows) == 0:
                return b""
        stamp = timestamp_payload(ns, self.layout)
        stamp_bytes = np.frombuffer(stamp, dtype=np.uint8)
        # x y z of the translation, x y z w of the rotation: Foxglove's order, w last
        columns = (pos[:, 0], pos[:, 1], pos[:, 2], quat_wxyz[:, 1], quat_wxyz[:, 2],
                   quat_wxyz[:, 3], quat_wxyz[:, 0])
        out = []
        for members, template, numbers, stamp_at in self._groups(len(stamp), rows):
            block = template.copy()
            records = block.view(numbers).reshape(len(block))
            for j, column in enumerate(columns):
                records[f"f{j}"] = column[:self.n] if members is None else column[members]
            if len(stamp):
                block[:, stamp_at:stamp_at + len(stamp)] = stamp_bytes
            out.append(block.tobytes())
        return b"".join(out)


class StateEncoder:
    """`vrsim.State` bytes: time, step, the entity names, four packed arrays."""

    def __init__(self, names: list[str]):
        from vrsim_cli.writers.vrsim_messages import field_number

        number = lambda field: field_number("State", field)  # noqa: E731
        self.t_key = key(number("t"), WIRE_I64)
        self.step_key = key(number("step"), WIRE_VARINT)
        self.names = b"".join(len_field(number("entity"), n.encode()) for n in names)
        self.arrays = [number(f) for f in ("position", "orientation", "velocity",
                                           "angular_velocity")]

    def encode(self, t: float, step: int, pos, quat, vel, angvel) -> bytes:
        parts = [self.t_key + np.float64(t).astype("<f8").tobytes() if t else b"",
                 self.step_key + varint(int(step)) if step else b"", self.names]
        parts += [packed_doubles(n, a) for n, a in zip(self.arrays, (pos, quat, vel, angvel))]
        return b"".join(parts)
