"""Checks of keyframe tracks, drives and parents that a JSON Schema cannot express.

Layer 1: plain Python over plain dicts (no numpy, so `vrsim --help` stays light). Each
check yields `(key path, message, hint)`; `scene` turns them into located problems and
`keyframes.compile_track` raises them as `TrackError` for callers that build tracks in code.
"""

from __future__ import annotations

import math
from typing import Iterator

from vrsim_cli.errors import did_you_mean

# Track kinds: what the values are and which interpolations make sense for them.
VECTOR, ROTATION, COLOR = "vector", "rotation", "color"
VECTOR_MODES = ("step", "linear", "catmull-rom", "kochanek-bartels", "hermite")
ROTATION_MODES = ("step", "linear", "slerp", "squad")  # linear on rotations means slerp (glTF)
MODES = {VECTOR: VECTOR_MODES, COLOR: VECTOR_MODES, ROTATION: ROTATION_MODES}
DEFAULT_MODE = {VECTOR: "linear", COLOR: "linear", ROTATION: "slerp"}
EXTRAPOLATIONS = ("clamp", "loop", "ping-pong")
EASES = ("none", "in", "out", "in-out")
KB_KEYS = ("tension", "continuity", "bias")
HERMITE_KEYS = ("in_tangents", "out_tangents")

POSE_TRACKS = ("position", "orientation", "angle_deg")

Issue = tuple  # (key path, message, hint)


MAX_KEY_VALUE = 1e12


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _length(value) -> int | None:
    """1 for a number, n for a list of n numbers, None for anything else."""
    if _is_number(value):
        return 1
    if isinstance(value, list) and value and all(_is_number(v) for v in value):
        return len(value)
    return None


def track_issues(spec: dict, kind: str = VECTOR, *, width: int | tuple | None = None,
                 arc_length_ok: bool = True) -> Iterator[Issue]:
    """Problems of one track spec; paths are relative to the track.

    width: the value length every key must have (an int, a tuple of allowed lengths, or
    None: any length, the same for every key).
    """
    times = spec.get("times")
    if not isinstance(times, list) or not times or not all(_is_number(t) for t in times):
        yield ("times",), "expected a non-empty list of numbers (s)", None
        return
    for i in range(1, len(times)):
        if not times[i] > times[i - 1]:
            yield (("times", i), f"key times must increase strictly: {times[i]} follows "
                   f"{times[i - 1]}", "every key needs its own, later time")
            return
    mode = spec.get("interpolation", DEFAULT_MODE[kind])
    if mode not in MODES[kind]:
        what = {ROTATION: "an orientation", COLOR: "a colour"}.get(kind, "this track")
        other = [k for k in MODES if k != kind and mode in MODES[k]]
        hint = "use one of " + ", ".join(MODES[kind])
        if not other:
            hint = did_you_mean(mode, MODES[kind]) or hint
        yield ("interpolation",), f"'{mode}' is not available for {what}", hint
    value_key = "values"
    if kind == ROTATION:
        given = [k for k in ("values", "euler_deg") if k in spec]
        if len(given) != 1:
            yield ((), "give the keys as 'values' (quaternions [w, x, y, z]) or as "
                   "'euler_deg' ([x, y, z] degrees), exactly one of them", None)
            return
        value_key = given[0]
        width = 4 if value_key == "values" else 3
    elif "euler_deg" in spec:
        yield ("euler_deg",), "'euler_deg' keys are for orientation tracks", None
    values = spec.get(value_key)
    yield from _value_list(values, (value_key,), len(times), width)
    if kind == ROTATION and value_key == "values" and isinstance(values, list):
        for i, q in enumerate(values):
            if _length(q) == 4 and not any(q):
                yield (value_key, i), "a quaternion must not be zero", None
    for key in KB_KEYS:
        if key in spec and mode != "kochanek-bartels":
            yield ((key,), f"'{key}' is a kochanek-bartels parameter",
                   "set interpolation: kochanek-bartels")
        elif key in spec and not _is_number(spec[key]):
            yield from _value_list(spec[key], (key,), len(times), 1)
    for key in HERMITE_KEYS:
        if mode == "hermite" and key not in spec:
            yield ((), f"missing '{key}' for hermite interpolation",
                   "glTF CUBICSPLINE: one in- and one out-tangent (value per second) per key")
        elif key in spec and mode != "hermite":
            yield (key,), f"'{key}' is for interpolation: hermite", None
        elif key in spec:
            yield from _value_list(spec[key], (key,), len(times), _length(values[0])
                                   if isinstance(values, list) and values else width)
    extrap = spec.get("extrapolation", "clamp")
    for side, value in (extrap.items() if isinstance(extrap, dict) else [(None, extrap)]):
        if side not in (None, "before", "after") or value not in EXTRAPOLATIONS:
            path = ("extrapolation",) + ((side,) if side else ())
            yield (path, f"expected {' or '.join(EXTRAPOLATIONS)} (or before/after), got "
                   f"{value!r}", did_you_mean(str(value), EXTRAPOLATIONS))
    for key, allowed in (("ease", EASES), ("space", ("rgb", "hsv"))):
        if key in spec and spec[key] not in allowed:
            yield ((key,), f"expected one of {', '.join(allowed)}, got {spec[key]!r}",
                   did_you_mean(str(spec[key]), allowed))
    if "space" in spec and kind != COLOR:
        yield ("space",), "'space' (rgb or hsv) is for colour tracks", None
    if spec.get("arc_length"):
        if not arc_length_ok:
            yield ("arc_length",), "arc-length reparametrisation is for position tracks", None
        elif mode == "step":
            yield ("arc_length",), "a step track has no path to move along", None


def _value_list(values, path: tuple, count: int, width) -> Iterator[Issue]:
    if not isinstance(values, list):
        yield path, "expected a list with one value per key time", None
        return
    if len(values) != count:
        yield path, f"expected {count} values (one per key time), got {len(values)}", None
        return
    first = None
    for i, value in enumerate(values):
        n = _length(value)
        if n is None:
            yield path + (i,), "expected a number or a list of numbers", None
            return
        if isinstance(width, int) and n != width:
            yield path + (i,), f"expected {width} numbers, got {n}", None
            return
        if isinstance(width, tuple) and n not in width:
            yield (path + (i,), f"expected {' or '.join(map(str, width))} numbers, got {n}",
                   None)
            return
        if first is None:
            first = n
        elif n != first:
            yield path + (i,), f"every key needs {first} numbers like the first, got {n}", None
            return
        numbers = value if isinstance(value, list) else [value]
        if any(not math.isfinite(v) for v in numbers):
            yield path + (i,), "must be finite", None
        elif any(abs(v) > MAX_KEY_VALUE for v in numbers):
            # spline tangents and arc-length tables multiply and square key values: keep
            # them where that arithmetic stays finite (1e12 m is 7 times the Sun's distance)
            yield path + (i,), f"must lie within +-{MAX_KEY_VALUE:.0e}", None


def body_issues(bodies: list, dim: int) -> Iterator[Issue]:
    """Problems of keyframes, drive and parent over all bodies; absolute key paths."""
    names = {b.get("name"): i for i, b in enumerate(bodies) if isinstance(b, dict)}
    for i, body in enumerate(bodies):
        at = ("bodies", i)
        keyframes = body.get("keyframes") or {}
        yield from _track_set(keyframes, at + ("keyframes",), dim)
        if not is_node(body):
            continue
        if body.get("type", "dynamic") != "kinematic":
            yield (at + ("type",), "a body with a position or orientation track, a drive or "
                   "a parent is moved by its animation, not by forces", "add type: kinematic")
        if "velocity" in body:
            yield (at + ("velocity",), "the velocity of an animated body comes from its "
                   "motion", "remove velocity")
        if "drive" in body:
            for key in ("position", "orientation", "angle_deg"):
                if key in keyframes:
                    what = key.replace("_deg", "")
                    yield (at + ("keyframes", key), f"a driven body gets its {what} from the "
                           "drive", "remove the track or the drive")
        parent = body.get("parent")
        if parent is not None and parent not in names:
            yield (at + ("parent",), f"no body named '{parent}'",
                   did_you_mean(parent, names) or "parent names a body of this scene")
    yield from _cycles(bodies, names)


def is_node(body: dict) -> bool:
    """A scene-graph node: a body whose pose comes from tracks, a drive or a parent.
    (Colour, scale and attribute tracks alone leave a body's motion alone.)"""
    frames = body.get("keyframes") or {}
    return "drive" in body or "parent" in body or any(k in frames for k in POSE_TRACKS)


def _track_set(keyframes: dict, at: tuple, dim: int) -> Iterator[Issue]:
    vector_width = 3 if dim == 3 else 2
    tracks = {"position": (VECTOR, vector_width, True), "scale": (VECTOR, (1, 3), False),
              "color": (COLOR, (3, 4), False)}
    if dim == 3:
        tracks["orientation"] = (ROTATION, 4, False)
        wrong = "angle_deg"
    else:
        tracks["angle_deg"] = (VECTOR, 1, False)
        wrong = "orientation"
    if wrong in keyframes:
        yield (at + (wrong,), f"'{wrong}' tracks are for {'2D' if dim == 3 else '3D'} scenes",
               f"use {'orientation' if dim == 3 else 'angle_deg'}")
    for key, (kind, width, arc_ok) in tracks.items():
        if key in keyframes:
            for path, message, hint in track_issues(keyframes[key], kind, width=width,
                                                    arc_length_ok=arc_ok):
                yield at + (key,) + path, message, hint
    for name, spec in (keyframes.get("attributes") or {}).items():
        for path, message, hint in track_issues(spec, VECTOR, arc_length_ok=False):
            yield at + ("attributes", name) + path, message, hint


MAX_PARENT_DEPTH = 64  # bodies from a root to the deepest child; each level is a pass


def _cycles(bodies: list, names: dict) -> Iterator[Issue]:
    """Each parent cycle once, reported at the parent key of its first body in file order;
    then every body deeper than MAX_PARENT_DEPTH below its root. Linear in the number of
    bodies: each body is walked once (a 2000-long chain took hours with a walk per body)."""
    parent = [names.get(b.get("parent")) if b.get("parent") is not None else None
              for b in bodies]
    state = [0] * len(bodies)  # 0 unseen, 1 on the current walk, 2 done
    depth = [0] * len(bodies)  # bodies from the root down to this one (1: a root)
    cycles = []
    for i in range(len(bodies)):
        walk, j = [], i
        while j is not None and state[j] == 0:
            state[j] = 1
            walk.append(j)
            j = parent[j]
        if j is not None and state[j] == 1:  # the walk met itself: a cycle
            cycle = walk[walk.index(j):]
            cycles.append(cycle)
            for k in cycle:
                state[k], depth[k] = 2, 0
            walk = walk[:walk.index(j)]
            j = None
        below = depth[j] if j is not None else 0
        for k in reversed(walk):
            state[k] = 2
            below = depth[k] = below + 1 if below or parent[k] is None else 0
    for cycle in sorted(cycles, key=min):
        first = min(cycle)
        loop = cycle[cycle.index(first):] + cycle[:cycle.index(first)] + [first]
        shown = " -> ".join(bodies[k]["name"] for k in loop)
        if len(loop) > 12:
            shown = " -> ".join(bodies[k]["name"] for k in loop[:5]) + \
                f" -> ... ({len(loop) - 7} more) -> " + \
                " -> ".join(bodies[k]["name"] for k in loop[-2:])
        yield (("bodies", first, "parent"), f"parents form a cycle: {shown}",
               "a scene graph is a tree: some body must have no parent")
    deep = [k for k in range(len(bodies)) if depth[k] > MAX_PARENT_DEPTH]
    if deep:
        k = min(deep, key=lambda k: (depth[k] != MAX_PARENT_DEPTH + 1, k))
        yield (("bodies", k, "parent"), f"'{bodies[k]['name']}' is at level {depth[k]} of "
               f"the scene graph (a body without a parent is level 1); at most "
               f"{MAX_PARENT_DEPTH} levels are allowed",
               "each level is one pass of the scene-graph stage per frame")
