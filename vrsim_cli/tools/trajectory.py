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

from vrsim_cli.errors import InputError, Problem
from vrsim_cli.scene.files import input_file_problem
from vrsim_cli.writers.entities import CSV_COLUMNS
from vrsim_cli.writers.foxglove_schemas import STATE_COLUMNS


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

    @property
    def times(self) -> np.ndarray:
        if not self.tracks:
            return np.zeros(0)
        return np.unique(np.concatenate([tr.t for tr in self.tracks.values()]))


# Reading is bounded: text (a gzip file may expand a thousandfold) and numbers, kept as
# packed float64 (a short number such as "0," is 2 bytes of text but 8 in memory).
MAX_TRAJECTORY_BYTES = 128 * 1024 * 1024
MAX_TRAJECTORY_ROWS = 2_500_000  # entity samples: 14 float64 each, ~280 MB (compare reads 2)


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


def _read_mcap(path: Path) -> Trajectory:
    from mcap.reader import make_reader

    traj = Trajectory(str(path), "mcap")
    times: dict[str, array] = {}
    rows: dict[str, array] = {}
    count = 0
    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is None:
                raise _fail(path, 0, "MCAP file has no summary (was the run interrupted "
                                     "before vrsim 0.1?)")
            counts = summary.statistics.channel_message_counts if summary.statistics else {}
            for cid, channel in sorted(summary.channels.items()):
                schema = summary.schemas.get(channel.schema_id)
                traj.channels.append((channel.topic, schema.name if schema else "",
                                      counts.get(cid, 0)))
            for record in reader.iter_metadata():
                traj.metadata[record.name] = dict(record.metadata)
            for _schema, _channel, message in reader.iter_messages(topics=["/vrsim/state"]):
                sample = json.loads(message.data)
                for entity in sample["entities"]:
                    name = entity["name"]
                    if name not in times:
                        times[name], rows[name] = array("d"), array("d")
                    times[name].append(float(sample["t"]))
                    rows[name].extend([entity[c] for c in STATE_COLUMNS])
                    count += 1
                    if count > MAX_TRAJECTORY_ROWS:
                        raise _too_many(path)
    except InputError:
        raise
    except OSError as exc:
        raise _fail(path, 0, f"cannot read: {exc.strerror}") from None
    except Exception as exc:  # the mcap library raises many types for corrupt files
        raise _fail(path, 0, f"not a readable MCAP file ({type(exc).__name__}: {exc})") from None
    for name in times:
        traj.tracks[name] = Track.from_rows(times[name], rows[name])
    return traj
