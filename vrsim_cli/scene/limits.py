"""The numbers vrsim can simulate: every physical quantity of a scene within a range.

Layer 1, plain Python over plain dicts (no numpy). Called from `spec._semantic_problems`
once the document matches the schema; each value outside its range becomes a located
problem that gives the range (exit 2), instead of an overflow, a NaN or a traceback
later. The ranges are generous for anything physical and keep every product the
simulation forms finite: masses up to 1e12 kg times lengths up to 1e6 m squared times
angular speeds up to 1e6 rad/s squared stay below 1e50; the smallest (1e-9 kg, 1e-6 m)
keep inverses below 1e30.

Positions and speeds share their limits with the run's blow-up check (`loop.py`): a
coordinate of 1e12 m or a speed of light along an axis is a blow-up at once.
"""

from __future__ import annotations

import math
from typing import Iterator

C = 299_792_458.0  # m/s, the speed of light

# kind: (smallest magnitude, largest magnitude, unit, what the hint calls it)
RANGES = {
    "length": (1e-6, 1e6, "m", "a length"),
    "offset": (0.0, 1e12, "m", "a distance"),
    "coordinate": (0.0, 1e12, "m", "a coordinate"),
    "speed": (0.0, C, "m/s", "a speed"),
    "velocity": (0.0, C, "m/s", "a velocity component"),
    "angular": (0.0, 1e6, "rad/s", "an angular speed"),
    "angular_deg": (0.0, math.degrees(1e6), "deg/s", "a turn rate"),
    "mass": (1e-9, 1e12, "kg", "a mass"),
    "density": (1e-6, 1e6, "kg/m^3", "a density"),
    "force": (0.0, 1e15, "N", "a force"),
    "torque": (0.0, 1e15, "N m", "a torque"),
    "acceleration": (0.0, 1e9, "m/s^2", "an acceleration"),
    "inertia": (0.0, 1e36, "kg m^2", "an inertia entry"),
    "stiffness": (0.0, 1e15, "N/m", "a stiffness"),
    "spring_damping": (0.0, 1e15, "N s/m", "a damping"),
    "rate_damping": (0.0, 1e6, "1/s", "a damping rate"),
    "time": (0.0, 1e9, "s", "a time"),
    "direction": (1e-9, 1e12, "", "the length of a direction"),
    "friction": (0.0, 1e6, "", "a friction coefficient"),
}
MIN_KEY_INTERVAL_S = 1e-9  # key times closer than this divide by almost nothing

# (key path with "*" for every list item, kind, how: "each" component, "norm" of the
# vector, or "value" for a number). Pure directions (plane normals, emitter directions, up
# vectors, orientations) are normalised without overflow whatever their length, so only
# the observer's direction, whose length the walk keeps (slide 5.1), has a range.
CHECKS = [
    (("gravity",), "acceleration", "norm"),
    (("bodies", "*", "mass"), "mass", "value"),
    (("bodies", "*", "density"), "density", "value"),
    (("bodies", "*", "position"), "coordinate", "each"),
    (("bodies", "*", "velocity"), "velocity", "each"),
    (("bodies", "*", "angular_velocity"), "angular", "norm"),
    (("bodies", "*", "shape", "radius"), "length", "value"),
    (("bodies", "*", "shape", "length"), "length", "value"),
    (("bodies", "*", "shape", "size"), "length", "each"),
    (("bodies", "*", "shape", "offset"), "offset", "value"),
    (("bodies", "*", "shape", "scale"), "length", "value"),
    (("bodies", "*", "particles", "*", "position"), "coordinate", "each"),
    (("bodies", "*", "particles", "*", "mass"), "mass", "value"),
    (("bodies", "*", "particles", "grid", "size"), "length", "value"),
    (("bodies", "*", "particles", "grid", "mass"), "mass", "value"),
    (("bodies", "*", "inertia"), "inertia", "entries"),
    (("bodies", "*", "damping", "linear"), "rate_damping", "value"),
    (("bodies", "*", "damping", "angular"), "rate_damping", "value"),
    (("bodies", "*", "forces", "*", "force"), "force", "norm"),
    (("bodies", "*", "forces", "*", "point"), "coordinate", "each"),
    (("bodies", "*", "forces", "*", "start"), "time", "value"),
    (("bodies", "*", "forces", "*", "end"), "time", "value"),
    (("bodies", "*", "torques", "*", "torque"), "torque", "norm"),
    (("bodies", "*", "torques", "*", "start"), "time", "value"),
    (("bodies", "*", "torques", "*", "end"), "time", "value"),
    (("bodies", "*", "material", "friction"), "friction", "value"),
    (("bodies", "*", "drive", "yaw_rate_deg"), "angular_deg", "value"),
    (("springs", "*", "stiffness"), "stiffness", "value"),
    (("springs", "*", "damping"), "spring_damping", "value"),
    (("springs", "*", "rest_length"), "offset", "value"),
    (("springs", "*", "point"), "coordinate", "each"),
    (("springs", "*", "to_point"), "coordinate", "each"),
    (("springs", "*", "anchor"), "coordinate", "each"),
    (("emitters", "*", "position"), "coordinate", "each"),
    (("emitters", "*", "speed"), "speed", "value"),
    (("emitters", "*", "mass"), "mass", "value"),
    (("emitters", "*", "radius"), "length", "value"),
    (("collision", "pairs", "*", "friction"), "friction", "value"),
    (("observer", "position"), "coordinate", "each"),
    (("observer", "look_at"), "coordinate", "each"),
    (("observer", "direction"), "direction", "norm"),
    (("observer", "v_max"), "speed", "value"),
    (("observer", "gamma_max"), "angular_deg", "value"),
    (("observer", "delta_max"), "angular_deg", "value"),
    (("observer", "pitch_max"), "angular_deg", "value"),
    (("observer", "eye_height"), "length", "value"),
    (("observer", "step_height"), "offset", "value"),
    (("observer", "radius"), "offset", "value"),
    (("input", "mouse", "*", "t"), "time", "value"),
    (("output", "frames", "camera", "position"), "coordinate", "each"),
    (("output", "frames", "camera", "look_at"), "coordinate", "each"),
]


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _expand(node, pattern: tuple, at: tuple = ()) -> Iterator[tuple[tuple, object]]:
    """(path, value) for every value the pattern names in `node`."""
    if not pattern:
        yield at, node
        return
    head, rest = pattern[0], pattern[1:]
    if head == "*":
        if isinstance(node, list):
            for i, item in enumerate(node):
                yield from _expand(item, rest, at + (i,))
    elif isinstance(node, dict) and head in node:
        yield from _expand(node[head], rest, at + (head,))


def _norm(values) -> float:
    """|v| without overflow or underflow (scaled by the largest component)."""
    big = max(abs(float(v)) for v in values)
    if big == 0.0:
        return 0.0
    return big * math.sqrt(sum((float(v) / big) ** 2 for v in values))


SIGNED = ("coordinate", "velocity", "offset")  # a number of either sign, not a magnitude


def _range_text(kind: str, how: str) -> str:
    low, high, unit, what = RANGES[kind]
    unit = f" {unit}" if unit else ""
    if how == "norm":
        what = f"the length of {what}" if kind != "direction" else what
    if low > 0:
        return f"{what} must lie between {low:g} and {high:g}{unit}"
    if kind in SIGNED and how != "norm":
        return f"{what} must lie within +-{_num(high)}{unit}"
    return f"{what} must be at most {_num(high)}{unit}"


def _num(x: float) -> str:
    return "299792458" if x == C else f"{x:g}"  # c in full, not 2.99792e+08


def limit_issues(data: dict) -> Iterator[tuple[tuple, str, str]]:
    """(key path, message, hint) of every value outside the range vrsim simulates."""
    for pattern, kind, how in CHECKS:
        low, high, unit, _what = RANGES[kind]
        for path, value in _expand(data, pattern):
            # (where, magnitude, as shown)
            if how == "value" and _number(value):
                items = [(path, abs(float(value)), f"{float(value):.4g}")]
            elif how == "each" and isinstance(value, list):
                items = [(path + (i,), abs(float(v)), f"{float(v):.4g}")
                         for i, v in enumerate(value) if _number(v)]
            elif how == "norm" and isinstance(value, list) and value and \
                    all(_number(v) for v in value):
                size = _norm(value)
                items = [(path, size, f"a length of {size:.4g}")]
            elif how == "norm" and _number(value):
                items = [(path, abs(float(value)), f"{float(value):.4g}")]
            elif how == "entries":
                flat = [value] if _number(value) else [
                    v for row in value for v in (row if isinstance(row, list) else [row])]
                size = max((abs(float(v)) for v in flat if _number(v)), default=0.0)
                items = [(path, size, f"an entry of {size:.4g}")]
            else:
                continue
            for where, size, shown in items:
                # "each" and "norm" allow zero (a vector at rest); a lower bound applies
                # to sizes that must not vanish
                too_small = low > 0 and size < low and not (how == "each" and size == 0.0)
                too_large = size > high or (kind in ("coordinate", "velocity", "speed")
                                            and size >= high)
                if too_small or too_large:
                    yield (where, f"{shown}{(' ' + unit) if unit else ''} is outside the "
                           f"range vrsim can simulate", _range_text(kind, how))
    yield from _key_time_issues(data)


def _key_time_issues(data: dict) -> Iterator[tuple[tuple, str, str]]:
    """Keyframe times: within +-1e9 s and at least MIN_KEY_INTERVAL_S apart (closer keys
    divide a value step by almost nothing: 5e-324 s apart gave NaN orientations)."""
    for i, body in enumerate(data.get("bodies") or []):
        if not isinstance(body, dict):
            continue
        keyframes = body.get("keyframes") or {}
        tracks = [((k,), v) for k, v in keyframes.items() if k != "attributes"]
        tracks += [(("attributes", k), v) for k, v in (keyframes.get("attributes") or {}).items()]
        for key, track in tracks:
            times = track.get("times") if isinstance(track, dict) else None
            if not isinstance(times, list) or not all(_number(t) for t in times):
                continue
            at = ("bodies", i, "keyframes") + key + ("times",)
            for j, t in enumerate(times):
                if abs(t) > RANGES["time"][1]:
                    yield (at + (j,), f"key time {t:g} s is outside the range vrsim can "
                           f"simulate", "key times must lie within +-1e9 s")
                    break
                if j and 0 < t - times[j - 1] < MIN_KEY_INTERVAL_S:
                    yield (at + (j,), f"key time {t:g} s is only {t - times[j - 1]:.3g} s "
                           f"after the previous one", f"keys must be at least "
                           f"{MIN_KEY_INTERVAL_S:g} s apart")
                    break
