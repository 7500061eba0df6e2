"""The observer's and the sensors' part of the model (slide 5.1, loop stage 1).

Layer 2, called by `model.compile_model`. Sensor files are read at compile time into
sample arrays, so a run never touches them again and is reproducible; `input_at` evaluates
the samples at a frame's start time (memory grows with the samples, not the frames):
- values (k, 3): alpha, beta, pitch in [-1, 1] at `times` (mouse, CSV file, replay), or one
  row per frame (`per_frame`);
- poses  (k, 7): px py pz qw qx qy qz at `times` (head tracker, or a replayed tracker).
Files named in a scene resolve against its folder and may not leave it.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vrsim_cli.errors import InputError, Problem
from vrsim_cli.maths.spatial import quat_normalize, quat_slerp, unit
from vrsim_cli.scene.files import MAX_SENSOR_BYTES
from vrsim_cli.scene.limits import RANGES
from vrsim_cli.scene.spec import Scene

# X3D NavigationInfo defaults: avatarSize [0.25, 1.6, 0.75], speed 1 m/s.
DEFAULT_RADIUS = 0.25  # m, collision radius
DEFAULT_EYE_HEIGHT = 1.6  # m above the ground
DEFAULT_STEP_HEIGHT = 0.75  # m, the highest step the walker climbs
DEFAULT_V_MAX = 1.0  # m/s
DEFAULT_TURN_DEG = 90.0  # deg/s for gamma_max, delta_max, pitch_max
DEFAULT_FOV_DEG = 60.0  # vertical field of view
TRACKER_COLUMNS = ("t", "px", "py", "pz", "qw", "qx", "qy", "qz")
INPUT_CHANNELS = ("alpha", "beta", "pitch")


@dataclass(frozen=True)
class ObserverModel:
    """Constants of the observer. Angles in rad, angular rates in rad/s."""

    mode: str  # walk | fly | examine | tracked
    position0: np.ndarray  # (3,) m, V at t = 0
    direction0: np.ndarray  # (3,) d at t = 0, as given (its length is kept, slide 5.1)
    look_at: np.ndarray  # (3,) m, L (examine keeps it fixed)
    up: np.ndarray  # (3,) unit, the fixed up vector u
    v_max: float  # m/s
    gamma_max: float  # rad/s: yaw rate (walk, fly); rotation about x (examine)
    delta_max: float  # rad/s: rotation about y (examine)
    pitch_max: float  # rad/s: pitch rate (fly, third input channel)
    examine_axes: str  # world (the slide's) | view
    eye_height: float  # m
    step_height: float  # m
    radius: float  # m, collision radius
    walls: str  # slide | stop (slide 5.4.2)
    fov_deg: float
    body: int = -1  # attached: index of the body the observer rides on


@dataclass(frozen=True)
class InputModel:
    source: str  # none | mouse | per_frame | file | tracker | replay
    times: np.ndarray  # (k,) s, strictly increasing (unused for per_frame)
    values: np.ndarray  # (k, 3) alpha, beta, pitch
    poses: np.ndarray | None = None  # (k, 7) tracker poses at `times`, or None
    linear: bool = False  # interpolate between samples instead of holding


NO_INPUT = InputModel("none", np.zeros(0), np.zeros((0, 3)))


def input_at(inputs: InputModel, frame: int, t: float):
    """Sensor values of `frame` starting at time t: ((alpha, beta, pitch), pose or None)."""
    if inputs.source == "per_frame":
        row = inputs.values[frame] if frame < len(inputs.values) else np.zeros(3)
        return row, None
    at = np.array([t])
    if inputs.poses is not None:
        return np.zeros(3), _sample_poses(inputs.times, inputs.poses, at, inputs.linear)[0]
    return _sample(inputs.times, inputs.values, at, inputs.linear)[0], None


def compile_observer(scene: Scene, gravity, problems: list[Problem],
                     body_names=()) -> ObserverModel | None:
    spec = scene.data.get("observer")
    if spec is None:
        return None
    position = np.array(spec.get("position", [0.0, DEFAULT_EYE_HEIGHT, 0.0]), dtype=float)
    if "look_at" in spec:
        look_at = np.array(spec["look_at"], dtype=float)
        direction = look_at - position
        # d = L - V is the view direction whose length the walk keeps (slide 5.1): the
        # same range as a given direction (a point 1e-300 m away gave NaN orientations)
        low = RANGES["direction"][0]
        if not np.abs(direction).max() >= low:
            problems.append(scene.problem(("observer", "look_at"), "look_at must differ from "
                                          f"the observer's position by at least {low:g} m"))
            direction = np.array([0.0, 0.0, -1.0])
    else:
        direction = np.array(spec.get("direction", [0.0, 0.0, -1.0]), dtype=float)
        look_at = position + unit(direction)
    up = np.array(spec.get("up", [0.0, 1.0, 0.0]), dtype=float)
    turn = math.radians
    return ObserverModel(
        mode=spec.get("mode", "walk"),
        position0=position,
        direction0=direction,
        look_at=look_at,
        up=unit(up),
        v_max=float(spec.get("v_max", DEFAULT_V_MAX)),
        gamma_max=turn(float(spec.get("gamma_max", DEFAULT_TURN_DEG))),
        delta_max=turn(float(spec.get("delta_max", DEFAULT_TURN_DEG))),
        pitch_max=turn(float(spec.get("pitch_max", DEFAULT_TURN_DEG))),
        examine_axes=spec.get("examine_axes", "view"),
        eye_height=float(spec.get("eye_height", DEFAULT_EYE_HEIGHT)),
        step_height=float(spec.get("step_height", DEFAULT_STEP_HEIGHT)),
        radius=float(spec.get("radius", DEFAULT_RADIUS)),
        walls=spec.get("walls", "slide"),
        fov_deg=float(spec.get("fov_deg", DEFAULT_FOV_DEG)),
        body=list(body_names).index(spec["body"]) if "body" in spec else -1,
    )


def compile_input(scene: Scene, observer: ObserverModel | None,
                  problems: list[Problem]) -> InputModel:
    """Read the scene's `input` into sample arrays."""
    spec = scene.data.get("input") or {}
    linear = spec.get("interpolation", "hold") == "linear"
    if "mouse" in spec:
        samples = spec["mouse"]
        times = np.array([s["t"] for s in samples], dtype=float)
        values = np.array([[s.get(c, 0.0) for c in INPUT_CHANNELS] for s in samples])
        return InputModel("mouse", times, values, None, linear)
    if "per_frame" in spec:
        rows = spec["per_frame"]
        values = np.zeros((len(rows), 3))
        for i, row in enumerate(rows):
            values[i, :len(row)] = row
        return InputModel("per_frame", np.zeros(0), values)
    for key in ("file", "tracker", "replay"):
        if key in spec:
            path = scene.input_path(("input", key), problems, MAX_SENSOR_BYTES)
            if path is None:
                return NO_INPUT
            if key == "file":
                times, values = _read_mouse_csv(scene, path, problems)
                return InputModel("file", times, values, None, linear)
            if key == "tracker":
                times, poses = _read_tracker_csv(scene, path, problems)
                return InputModel("tracker", times, np.zeros((len(times), 3)), poses, linear)
            return _read_replay(scene, path, observer, problems)
    return NO_INPUT


def _sample(times: np.ndarray, values: np.ndarray, at: np.ndarray, linear: bool) -> np.ndarray:
    """Sensor values at times `at`: zero before the first sample, the last one after the
    last; in between held (sample and hold) or linearly interpolated."""
    out = np.zeros((len(at), values.shape[1]))
    if len(times) == 0:
        return out
    idx = np.searchsorted(times, at, side="right") - 1  # last sample at or before t
    started = idx >= 0
    held = values[np.clip(idx, 0, None)]
    if linear:
        nxt = np.clip(idx + 1, 0, len(times) - 1)
        span = times[nxt] - times[np.clip(idx, 0, None)]
        frac = np.where(span > 0, (at - times[np.clip(idx, 0, None)]) / np.where(span > 0, span,
                                                                                  1.0), 0.0)
        held = held + frac[:, None] * (values[nxt] - held)
    out[started] = held[started]
    return out


def _sample_poses(times: np.ndarray, poses: np.ndarray, at: np.ndarray, linear: bool):
    """Tracker poses at times `at`: clamped to the first/last pose; held or lerp + slerp."""
    idx = np.clip(np.searchsorted(times, at, side="right") - 1, 0, len(times) - 1)
    out = poses[idx].copy()
    if linear:
        for k, t in enumerate(at):
            i = idx[k]
            if i + 1 < len(times) and t > times[i]:
                s = min(1.0, (t - times[i]) / (times[i + 1] - times[i]))
                out[k, :3] = poses[i, :3] + s * (poses[i + 1, :3] - poses[i, :3])
                out[k, 3:] = quat_slerp(poses[i, 3:], poses[i + 1, 3:], s)
    return out


def _csv_rows(scene: Scene, path: Path, key: tuple, columns: tuple, optional: tuple,
              problems: list[Problem]):
    """Rows of a sensor CSV as floats, with its header checked; None when unreadable."""
    shown = str(path)
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            allowed = {columns, columns + optional}
            if header is None or tuple(h.strip() for h in header) not in allowed:
                problems.append(Problem(shown, 1, 1, None, "unexpected header", "expected "
                                        + " or ".join(",".join(c) for c in sorted(allowed))))
                return None
            rows = []
            for line, row in enumerate(reader, start=2):
                if not row:
                    continue
                try:
                    values = [float(x) for x in row]
                except ValueError:
                    problems.append(Problem(shown, line, 1, None, "a column holds something "
                                            "that is not a number"))
                    return None
                if len(values) != len(header) or not all(map(math.isfinite, values)):
                    problems.append(Problem(shown, line, 1, None, f"expected {len(header)} finite"
                                            f" numbers, got {','.join(row)}"))
                    return None
                rows.append((line, values))
    except FileNotFoundError:
        problems.append(scene.problem(key, f"file '{scene.get(key)}' not found",
                                      f"paths are relative to {scene.base_dir}"))
        return None
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        problems.append(scene.problem(key, f"cannot read '{scene.get(key)}': "
                                      f"{getattr(exc, 'strerror', None) or exc}"))
        return None
    if not rows:
        problems.append(Problem(shown, 2, 1, None, "the file holds no samples"))
        return None
    for (line, prev), (_, cur) in zip(rows, rows[1:]):
        if cur[0] <= prev[0]:
            problems.append(Problem(shown, line + 1, 1, None, f"times must increase strictly: "
                                    f"{cur[0]} after {prev[0]}"))
            return None
    return rows


def _read_mouse_csv(scene, path, problems):
    rows = _csv_rows(scene, path, ("input", "file"), ("t", "alpha", "beta"), ("pitch",),
                     problems)
    if rows is None:
        return np.zeros(0), np.zeros((0, 3))
    for line, values in rows:
        if any(abs(v) > 1.0 for v in values[1:]):
            problems.append(Problem(str(path), line, 1, None, f"alpha, beta and pitch must lie in "
                                    f"[-1, 1], got {values[1:]}"))
            return np.zeros(0), np.zeros((0, 3))
    times = np.array([v[0] for _, v in rows])
    values = np.zeros((len(rows), 3))
    for i, (_, v) in enumerate(rows):
        values[i, :len(v) - 1] = v[1:]
    return times, values


def _read_tracker_csv(scene, path, problems):
    rows = _csv_rows(scene, path, ("input", "tracker"), TRACKER_COLUMNS, (), problems)
    if rows is None:
        return np.zeros(1), np.array([[0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])
    for line, values in rows:
        if not any(values[4:8]):
            problems.append(Problem(str(path), line, 1, None, "the quaternion is zero"))
    data = np.array([v for _, v in rows])
    poses = data[:, 1:].copy()
    poses[:, 3:] = quat_normalize(poses[:, 3:])
    return data[:, 0], poses


def _input_record(schema, channel, data: bytes) -> dict:
    """A /vrsim/input message as a dict: protobuf (vrsim.Input, decoded with the schema
    the file carries) or JSON (files of vrsim before 0.2)."""
    if channel.message_encoding == "json":
        return json.loads(data)
    from mcap_protobuf.decoder import DecoderFactory

    decode = DecoderFactory().decoder_for(channel.message_encoding, schema)
    if decode is None:
        raise ValueError(f"/vrsim/input has message encoding '{channel.message_encoding}'")
    message = decode(data)
    return {field.name: value for field, value in message.ListFields()} | {"t": message.t}


def _read_replay(scene, path, observer, problems) -> InputModel:
    """Sensor values recorded on `/vrsim/input` by an earlier run, held between samples, so
    a run at the same frame times sees exactly the recorded values."""
    key = ("input", "replay")
    try:
        from mcap.reader import make_reader

        with open(path, "rb") as f:
            times, values, poses = [], [], []
            for schema, channel, message in make_reader(f).iter_messages(
                    topics=["/vrsim/input"]):
                sample = _input_record(schema, channel, message.data)
                times.append(float(sample["t"]))
                values.append([float(sample.get(c, 0.0)) for c in INPUT_CHANNELS])
                if sample.get("pose"):
                    poses.append([float(x) for x in sample["pose"]])
    except FileNotFoundError:
        problems.append(scene.problem(key, f"file '{scene.get(key)}' not found",
                                      f"paths are relative to {scene.base_dir}"))
        return NO_INPUT
    except Exception as exc:  # the mcap library raises many types for corrupt files
        problems.append(scene.problem(key, f"cannot read recorded input: "
                                      f"{type(exc).__name__}: {exc}"))
        return NO_INPUT
    if not times:
        problems.append(scene.problem(key, "the file has no /vrsim/input messages",
                                      "record one with vrsim run ... -o FILE.mcap"))
        return NO_INPUT
    if any(b <= a for a, b in zip(times, times[1:])) or (poses and len(poses) != len(times)):
        problems.append(scene.problem(key, "the recorded input is not a valid sequence"))
        return NO_INPUT
    if poses:
        if observer is not None and observer.mode != "tracked":
            problems.append(scene.problem(("observer", "mode"), "the replayed input holds "
                                          "tracker poses", "use mode: tracked"))
        return InputModel("replay", np.array(times), np.array(values), np.array(poses))
    return InputModel("replay", np.array(times), np.array(values))
