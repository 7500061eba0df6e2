"""Read trajectory files back: MCAP, CSV or TUM, into one in-memory form.

Layer 7, used by `vrsim info` (and `vrsim compare`). Unreadable files raise InputError
with the file and, where known, the line.
"""

from __future__ import annotations

import csv
import gzip
import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vrsim_cli.errors import InputError, Problem
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
    def from_rows(cls, t: list, rows: list) -> "Track":
        data = np.asarray(rows, dtype=float).reshape(len(rows), 13)
        return cls(np.asarray(t, dtype=float), data[:, 0:3], data[:, 3:7], data[:, 7:10],
                   data[:, 10:13])


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


def read_trajectory(path: str | Path) -> Trajectory:
    path = Path(path)
    if path.is_dir():
        return _read_tum_folder(path)
    if not path.exists():
        raise InputError([Problem(str(path), 0, 0, (), "no such file")])
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
    times: dict[str, list] = {}
    rows: dict[str, list] = {}
    try:
        opener = gzip.open if compressed else open
        with opener(path, "rt", newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
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
                times.setdefault(name, []).append(t)
                rows.setdefault(name, []).append(values)
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


def _read_tum_file(path: Path) -> Track:
    t, rows = [], []
    try:
        with open(path, encoding="utf-8") as f:
            for line_no, line in enumerate(f, start=1):
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
                rows.append([tx, ty, tz, qw, qx, qy, qz] + [np.nan] * 6)
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
    times: dict[str, list] = {}
    rows: dict[str, list] = {}
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
                    times.setdefault(name, []).append(float(sample["t"]))
                    rows.setdefault(name, []).append([entity[c] for c in STATE_COLUMNS])
    except InputError:
        raise
    except OSError as exc:
        raise _fail(path, 0, f"cannot read: {exc.strerror}") from None
    except Exception as exc:  # the mcap library raises many types for corrupt files
        raise _fail(path, 0, f"not a readable MCAP file ({type(exc).__name__}: {exc})") from None
    for name in times:
        traj.tracks[name] = Track.from_rows(times[name], rows[name])
    return traj
