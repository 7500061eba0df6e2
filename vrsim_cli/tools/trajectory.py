"""Read trajectory files back: MCAP, CSV or TUM, into one in-memory form.

Layer 7, used by `vrsim info` (and `vrsim compare`). Unreadable files raise InputError
with the file and, where known, the line.
"""

from __future__ import annotations

import csv
import gzip
import json
import zlib
from array import array
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vrsim_cli.errors import InputError, Problem, printable
from vrsim_cli.scene.files import input_file_problem
from vrsim_cli.text import plural, table
from vrsim_cli.writers.entities import CSV_COLUMNS

STATE_COLUMNS = CSV_COLUMNS[2:]  # px .. wz: the 13 numbers of an entity


@dataclass
class Track:
    """One entity's samples. t: (n,) s; pos: (n, 3) m; quat: (n, 4) [w, x, y, z];
    vel: (n, 3) m/s; angvel: (n, 3) rad/s. Columns a format lacks are NaN."""

    t: np.ndarray
    pos: np.ndarray
    quat: np.ndarray
    vel: np.ndarray
    angvel: np.ndarray

    @classmethod
    def from_rows(cls, t, rows) -> "Track":
        """t: n times; rows: n rows of 13 numbers, or a flat array('d') of 13 n."""
        # an array('d') is wrapped, not copied
        data = (np.frombuffer(rows, dtype=float) if isinstance(rows, array) else
                np.asarray(rows, dtype=float)).reshape(len(t), 13)
        times = np.frombuffer(t, dtype=float) if isinstance(t, array) else \
            np.asarray(t, dtype=float)
        return cls(times, data[:, 0:3], data[:, 3:7], data[:, 7:10], data[:, 10:13])


@dataclass
class Trajectory:
    source: str
    format: str
    tracks: dict = field(default_factory=dict)  # entity name -> Track, in file order
    channels: list = field(default_factory=list)  # (topic, schema name, message count)
    metadata: dict = field(default_factory=dict)
    frames: dict = field(default_factory=dict)  # child frame -> parent (MCAP transforms)
    source_channels: list = field(default_factory=list)  # topics the tracks came from

    @property
    def times(self) -> np.ndarray:
        if not self.tracks:
            return np.zeros(0)
        return np.unique(np.concatenate([tr.t for tr in self.tracks.values()]))


# Reading is bounded: text (a gzip file may expand a thousandfold) and numbers, kept as
# packed float64 (a short number such as "0," is 2 bytes of text but 8 in memory).
MAX_TRAJECTORY_BYTES = 128 * 1024 * 1024
MAX_TRAJECTORY_ROWS = 2_500_000  # entity samples: 14 float64 each, ~280 MB (compare reads 2)


def summary(traj: Trajectory, file: str) -> dict:
    """What `vrsim info` reports, as a JSON-ready dict."""
    times = traj.times
    return {
        "file": file, "format": traj.format,
        "entities": list(traj.tracks),
        "samples": int(len(times)),
        "start_s": float(times[0]) if len(times) else None,
        "end_s": float(times[-1]) if len(times) else None,
        "duration_s": float(times[-1] - times[0]) if len(times) else 0.0,
        "channels": [{"topic": t, "schema": s, "messages": n} for t, s, n in traj.channels],
        "tracks_from": traj.source_channels or (["/vrsim/state"] if traj.format == "mcap"
                                                and traj.tracks else []),
        "parent_frames": dict(traj.frames),
        "vrsim": {k: v for k, v in traj.metadata.get("vrsim", {}).items() if k != "scene"},
    }


def format_summary(info: dict) -> list[str]:
    """The lines of `vrsim info`, escaped: names, topics and metadata come from the file
    and may hold terminal control sequences (errors.printable)."""
    names = info["entities"]
    lines = [f"{info['file']}: {info['format']}, {plural(len(names), 'entity')}, "
             f"{plural(info['samples'], 'sample')}"]
    if info["samples"]:
        lines.append(f"time: {info['start_s']:.6g} .. {info['end_s']:.6g} s "
                     f"(duration {info['duration_s']:.6g} s)")
    shown = ", ".join(names[:10]) + (f", ... ({len(names) - 10} more)" if len(names) > 10
                                     else "")
    lines.append(f"entities: {shown}")
    if info["format"] == "mcap" and info["tracks_from"] != ["/vrsim/state"]:
        if info["tracks_from"]:
            parents = sorted(set(info["parent_frames"].values()))
            lines.append(f"tracks from {', '.join(info['tracks_from'])} (transforms): "
                         f"position and orientation of each frame in its parent "
                         f"({', '.join(parents)}); no velocities")
        else:
            lines.append("no trajectories: the file has no /vrsim/state, no "
                         "foxglove.FrameTransforms and no tf2_msgs/msg/TFMessage channel")
    if info["channels"]:
        lines.append("channels:")
        lines += table(["topic", "schema", "messages"],
                       [[printable(c["topic"]), printable(c["schema"]), c["messages"]]
                        for c in info["channels"]],
                       right={2}, indent="  ")
    made = info["vrsim"]
    if made:
        lines.append(f"made by vrsim {made.get('version', '?')} from "
                     f"{made.get('scene_file', '?')} (dt {made.get('dt', '?')} s, "
                     f"{made.get('integrator', '?')})")
    return [printable(line) for line in lines]


def read_trajectory(path: str | Path) -> Trajectory:
    path = Path(path)
    if path.is_dir():
        return _read_tum_folder(path)
    # a FIFO or device would block or never end; numbers are kept as packed float64
    problem = input_file_problem(path, MAX_TRAJECTORY_BYTES)
    if problem is not None:
        raise InputError([Problem(str(path), 0, 0, (), problem)])
    suffix = path.suffix.lower()
    if "".join(path.suffixes[-2:]).lower() == ".csv.gz":
        return _read_csv(path, compressed=True)
    if suffix == ".mcap":
        return _read_mcap(path)
    if suffix == ".csv":
        return _read_csv(path)
    if suffix == ".tum":
        traj = Trajectory(str(path), "tum")
        traj.tracks[path.stem] = _read_tum_file(path)
        return traj
    raise InputError([Problem(str(path), 0, 0, (), "unknown trajectory format",
                              "expected .mcap, .csv, .csv.gz, .tum or a folder of "
                              ".tum files")])


def _fail(path: Path, line: int, message: str, hint: str | None = None) -> InputError:
    return InputError([Problem(str(path), line, 1 if line else 0, None, message, hint)])


def _read_csv(path: Path, compressed: bool = False) -> Trajectory:
    """A vrsim CSV; `compressed`: gzip-compressed (.csv.gz, as the golden files are)."""
    traj = Trajectory(str(path), "csv.gz" if compressed else "csv")
    times: dict[str, array] = {}
    rows: dict[str, array] = {}
    try:
        opener = gzip.open if compressed else open
        with opener(path, "rt", newline="", encoding="utf-8") as f:
            reader = csv.reader(_limited(f, path))
            header = next(reader, None)
            if header is None or tuple(header) != CSV_COLUMNS:
                raise _fail(path, 1, "not a vrsim trajectory CSV",
                            "the header must be " + ",".join(CSV_COLUMNS))
            for line_no, row in enumerate(reader, start=2):
                if len(row) != len(CSV_COLUMNS):
                    raise _fail(path, line_no, f"expected {len(CSV_COLUMNS)} columns, "
                                               f"got {len(row)}")
                try:
                    values = [float(x) for x in row[2:]]
                    t = float(row[0])
                except ValueError:
                    raise _fail(path, line_no, "a number column holds something else") from None
                name = row[1]
                if name not in times:
                    times[name], rows[name] = array("d"), array("d")
                if line_no > MAX_TRAJECTORY_ROWS + 1:
                    raise _too_many(path)
                times[name].append(t)
                rows[name].extend(values)
    except UnicodeDecodeError:
        raise _fail(path, 0, "not UTF-8 text") from None
    except csv.Error as exc:  # e.g. a field longer than the csv module's limit
        raise _fail(path, 0, f"not a readable CSV file ({exc})") from None
    except (gzip.BadGzipFile, EOFError, zlib.error) as exc:
        raise _fail(path, 0, f"not a readable gzip file ({exc})") from None
    except OSError as exc:
        raise _fail(path, 0, f"cannot read: {exc.strerror}") from None
    for name in times:
        traj.tracks[name] = Track.from_rows(times[name], rows[name])
    return traj


def _too_many(path: Path) -> InputError:
    return _fail(path, 0, f"holds more than {MAX_TRAJECTORY_ROWS} entity samples; at most "
                          f"that many are read")


def _limited(lines, path: Path):
    """The lines of a text file, refused beyond MAX_TRAJECTORY_BYTES characters (a gzip
    file may expand a thousandfold)."""
    total = 0
    for line in lines:
        total += len(line)
        if total > MAX_TRAJECTORY_BYTES:
            raise _fail(path, 0, f"holds more than {MAX_TRAJECTORY_BYTES} bytes of text; at "
                                 f"most that much is read")
        yield line


def _read_tum_file(path: Path) -> Track:
    problem = input_file_problem(path, MAX_TRAJECTORY_BYTES)  # in a folder: any kind
    if problem is not None:
        raise _fail(path, 0, problem)
    t, rows = array("d"), array("d")
    try:
        with open(path, encoding="utf-8") as f:
            for line_no, line in enumerate(_limited(f, path), start=1):
                line = line.strip()
                if not line or line.startswith("#"):
                    continue
                parts = line.split()
                if len(parts) != 8:
                    raise _fail(path, line_no, f"expected 8 numbers 't tx ty tz qx qy qz qw', "
                                               f"got {len(parts)}")
                try:
                    tt, tx, ty, tz, qx, qy, qz, qw = map(float, parts)
                except ValueError:
                    raise _fail(path, line_no, "not a number") from None
                t.append(tt)
                rows.extend([tx, ty, tz, qw, qx, qy, qz] + [np.nan] * 6)
                if len(t) > MAX_TRAJECTORY_ROWS:
                    raise _too_many(path)
    except UnicodeDecodeError:
        raise _fail(path, 0, "not UTF-8 text") from None
    except OSError as exc:
        raise _fail(path, 0, f"cannot read: {exc.strerror}") from None
    return Track.from_rows(t, rows)


def _read_tum_folder(path: Path) -> Trajectory:
    traj = Trajectory(str(path), "tum")
    files = sorted(path.glob("*.tum"))
    if not files:
        raise _fail(path, 0, "folder holds no .tum files")
    for file in files:
        traj.tracks[file.stem] = _read_tum_file(file)
    return traj


# ROS 2's /tf and /tf_static (tf2_msgs/msg/TFMessage, CDR): `ros2 bag record` writes them
ROS2_TF = "tf2_msgs/msg/TFMessage"
TRANSFORM_SCHEMAS = ("foxglove.FrameTransforms", "foxglove.FrameTransform", ROS2_TF)


def _read_mcap(path: Path) -> Trajectory:
    """vrsim's own `/vrsim/state` when the file has it (every column, exactly); else the
    transforms of any `foxglove.FrameTransforms` or `foxglove.FrameTransform` channel, as
    another tool writes them, or of ROS 2's `tf2_msgs/msg/TFMessage` (/tf, /tf_static):
    positions and orientations of each child frame in its parent frame; velocities NaN.
    Protobuf, JSON and (for TFMessage) CDR messages are read."""
    from mcap.reader import make_reader

    traj = Trajectory(str(path), "mcap")
    samples = _Samples(path)
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise _fail(path, 0, "MCAP file has no summary (was the run interrupted "
                                     "before vrsim 0.1?)")
            counts = summary.statistics.channel_message_counts if summary.statistics else {}
            schema_of = {}
            for cid, channel in sorted(summary.channels.items()):
                schema = summary.schemas.get(channel.schema_id)
                schema_of[channel.topic] = schema.name if schema else ""
                traj.channels.append((channel.topic, schema.name if schema else "",
                                      counts.get(cid, 0)))
            for record in reader.iter_metadata():
                traj.metadata[record.name] = dict(record.metadata)
            decode = _Decoders()
            if "/vrsim/state" in schema_of:
                for schema, channel, message in reader.iter_messages(topics=["/vrsim/state"]):
                    _state_rows(decode(schema, channel, message), samples)
            else:
                topics = [t for t, s in schema_of.items() if s in TRANSFORM_SCHEMAS]
                if topics:
                    traj.source_channels = topics
                for schema, channel, message in reader.iter_messages(topics=topics):
                    _transform_rows(decode(schema, channel, message), message.log_time,
                                    samples, traj.frames)
    except InputError:
        raise
    except OSError as exc:
        raise _fail(path, 0, f"cannot read: {exc.strerror}") from None
    except Exception as exc:  # the mcap library raises many types for corrupt files
        raise _fail(path, 0, f"not a readable MCAP file ({type(exc).__name__}: {exc})") from None
    for name in samples.times:
        traj.tracks[name] = Track.from_rows(samples.times[name], samples.rows[name])
    return traj


class _Samples:
    """Entity samples as they are read, packed float64 per entity (times[name]: n,
    rows[name]: 13 n), refused beyond MAX_TRAJECTORY_ROWS."""

    def __init__(self, path: Path):
        self.path = path
        self.times: dict[str, array] = {}
        self.rows: dict[str, array] = {}
        self.count = 0

    def add(self, name: str, t: float, row) -> None:
        if name not in self.times:
            self.times[name], self.rows[name] = array("d"), array("d")
        self.count += 1
        if self.count > MAX_TRAJECTORY_ROWS:
            raise _too_many(self.path)
        self.times[name].append(t)
        self.rows[name].extend(row)


class _Decoders:
    """Decodes a message by its channel's encoding: protobuf (with the schema the file
    carries, through mcap-protobuf-support) into a message object, JSON into a dict."""

    def __init__(self):
        self.cache: dict = {}

    def __call__(self, schema, channel, message):
        decode = self.cache.get(channel.id)
        if decode is None:
            decode = self.cache[channel.id] = self._decoder(schema, channel)
        return decode(message.data)

    @staticmethod
    def _decoder(schema, channel):
        if channel.message_encoding == "json":
            return json.loads
        if channel.message_encoding == "cdr" and schema is not None and \
                schema.name == ROS2_TF:
            return _ros2_tf
        if channel.message_encoding == "protobuf":
            from mcap_protobuf.decoder import DecoderFactory

            decode = DecoderFactory().decoder_for("protobuf", schema)
            if decode is not None:
                return decode
        raise ValueError(f"channel {channel.topic} has message encoding "
                         f"'{channel.message_encoding}', which vrsim cannot read (protobuf or "
                         f"json)")


def _state_rows(sample, samples: _Samples) -> None:
    """Rows of one vrsim.State: the packed arrays of the protobuf message, or the
    per-entity objects of the JSON one (vrsim before 0.2)."""
    if isinstance(sample, dict):  # JSON
        t = float(sample["t"])
        for entity in sample["entities"]:
            samples.add(entity["name"], t, [float(entity[c]) for c in STATE_COLUMNS])
        return
    t = float(sample.t)
    names = list(sample.entity)
    n = len(names)
    columns = np.hstack([np.asarray(getattr(sample, field), dtype=float).reshape(n, width)
                         for field, width in (("position", 3), ("orientation", 4),
                                              ("velocity", 3), ("angular_velocity", 3))])
    for name, row in zip(names, columns.tolist()):
        samples.add(name, t, row)


def _transform_rows(message, log_time: int, samples: _Samples, frames: dict) -> None:
    """Rows of a FrameTransforms (or one FrameTransform) message, protobuf or in
    Foxglove's JSON field names; a transform without a timestamp takes the log time."""
    if not isinstance(message, dict):
        from google.protobuf.json_format import MessageToDict

        message = MessageToDict(message, preserving_proto_field_name=True)
    transforms = message.get("transforms", [message] if "child_frame_id" in message else [])
    for tf in transforms:
        name = tf.get("child_frame_id", "")
        stamp = tf.get("timestamp") or {}
        if isinstance(stamp, str):  # protobuf JSON form of google.protobuf.Timestamp
            t = _rfc3339_seconds(stamp)
        else:
            seconds = stamp.get("sec", stamp.get("seconds", 0))
            nanos = stamp.get("nsec", stamp.get("nanos", 0))
            t = int(seconds) + int(nanos) * 1e-9 if (seconds or nanos) else log_time * 1e-9
        p, q = tf.get("translation") or {}, tf.get("rotation") or {}
        frames[name] = tf.get("parent_frame_id", "")
        samples.add(name, t, [float(p.get(c, 0.0)) for c in "xyz"]
                    + [float(q.get(c, 0.0)) for c in "wxyz"] + [np.nan] * 6)


def _ros2_tf(data: bytes) -> dict:
    """A ROS 2 tf2_msgs/msg/TFMessage in CDR (XCDR1, as rosbag2 writes it) as the dict
    `_transform_rows` reads. Layout: a 4-byte encapsulation header (byte 1: 1 little-,
    0 big-endian), then `sequence<geometry_msgs/TransformStamped>`: a uint32 count, and
    per transform header.stamp (int32 sec, uint32 nanosec), header.frame_id and
    child_frame_id (uint32 length with the NUL, bytes), translation x y z and rotation
    x y z w (float64). Every primitive is aligned to its size, counted from after the
    encapsulation header."""
    import struct

    if len(data) < 4 or data[1] not in (0, 1):
        raise ValueError("not a CDR message")
    order = "<" if data[1] == 1 else ">"
    body, pos = memoryview(data)[4:], 0

    def take(fmt: str, size: int, count: int = 1):
        nonlocal pos
        pos += -pos % size
        values = struct.unpack_from(f"{order}{count}{fmt}", body, pos)
        pos += size * count
        return values

    def text() -> str:
        nonlocal pos
        (n,) = take("I", 4)
        raw = bytes(body[pos:pos + n])
        if n < 1 or len(raw) != n:
            raise ValueError("truncated string")
        pos += n
        return raw[:-1].decode("utf-8", "replace")

    transforms = []
    (count,) = take("I", 4)
    if count > len(body) // 64:  # each transform takes at least 64 bytes: a corrupt count
        raise ValueError(f"{count} transforms in {len(body)} bytes")
    for _ in range(count):
        sec, nsec = take("i", 4)[0], take("I", 4)[0]
        parent, child = text(), text()
        tx, ty, tz, qx, qy, qz, qw = take("d", 8, 7)
        transforms.append({"timestamp": {"sec": sec, "nsec": nsec}, "parent_frame_id": parent,
                           "child_frame_id": child,
                           "translation": {"x": tx, "y": ty, "z": tz},
                           "rotation": {"x": qx, "y": qy, "z": qz, "w": qw}})
    return {"transforms": transforms}


def _rfc3339_seconds(text: str) -> float:
    """Seconds since the epoch of an RFC 3339 time as protobuf's JSON mapping writes it."""
    from datetime import datetime, timezone

    head, _, frac = text.rstrip("Z").partition(".")
    whole = datetime.strptime(head, "%Y-%m-%dT%H:%M:%S").replace(tzinfo=timezone.utc)
    return whole.timestamp() + (float("0." + frac) if frac else 0.0)
