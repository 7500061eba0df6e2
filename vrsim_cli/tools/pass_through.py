"""Shapes that pass through each other because the scene has no `collision:` block.

Layer 7. Without a collision block nothing collides (docs/scene-format.md, *Collision*):
a box dropped on a floor falls through it without a word. vrsim keeps that rule (turning
collision on behind the user's back would change the motion of every such scene, and
cost them the contact kernels' compile) and says so instead: `validate` names the bodies
whose shapes would pass through each other, and `run` watches for the first pair that
does, once per frame, and names the two bodies and the time.
"""

from __future__ import annotations

from dataclasses import dataclass

# Beyond this many shapes a detection per frame would cost a run more than the note is
# worth; `validate` still names them.
WATCH_MAX_SHAPES = 256

HOW_TO = "add `collision: {}` to the scene to make shapes collide (or `collision: " \
         "{enabled: false}` to say they should not)"


def candidates(data: dict) -> list[str]:
    """Names of the scene's bodies with shapes, when the scene has no collision block and
    at least one of them is dynamic and another has a shape too (else [])."""
    if "collision" in data:
        return []  # the user decided (`enabled: false` included)
    bodies = data.get("bodies") or []
    shaped = [b for b in bodies if b.get("shape") is not None]
    dynamic = [b for b in shaped if b.get("type", "dynamic") == "dynamic"]
    if not dynamic or len(shaped) < 2:
        return []
    return [str(b["name"]) for b in shaped]


def validate_note(data: dict) -> str | None:
    """What `validate` says of such a scene (it does not simulate, so no time)."""
    names = candidates(data)
    if not names:
        return None
    shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
    return (f"no collision block: the shapes of {shown} pass through each other wherever "
            f"they meet (`vrsim run` names the first pair and when); {HOW_TO}")


@dataclass(frozen=True)
class PassThrough:
    """The first pair found overlapping: body names, time (s), depth (m)."""

    body_a: str
    body_b: str
    t: float
    depth: float

    def note(self) -> str:
        return (f"'{self.body_a}' and '{self.body_b}' pass through each other from "
                f"t = {self.t:.6g} s ({self.depth:.3g} m deep at that frame): without a "
                f"collision block nothing collides; {HOW_TO}")

    def as_dict(self) -> dict:
        return {"bodies": [self.body_a, self.body_b], "t_s": self.t, "depth_m": self.depth}


class Watch:
    """on_frame callback of a run: checks each frame's state for shapes that interpenetrate
    by more than the collision tolerance, until the first pair is found (`found`).

    It detects with a collision model compiled from the same scene with `collision:
    {response: none}` (detection only), applied to the run's states: the run itself is
    untouched. `watch(scene)` gives None when the scene needs no watching."""

    def __init__(self, probe, n_scene: int, bounds=None):
        self.probe, self.n_scene, self.bounds = probe, n_scene, bounds
        self.found: PassThrough | None = None

    def __call__(self, state) -> None:
        if self.found is not None or self.probe is None:
            return
        if self.bounds is not None and not self.bounds.near(state.body_pos,
                                                            self.probe.collision.tolerance):
            return  # no two bounding spheres (or a sphere and a plane) meet: nothing to test
        from vrsim_cli.stages.collision.detect import start_overlaps

        try:
            pairs = start_overlaps(self.probe, state, self.n_scene)
        except Exception:  # noqa: BLE001 - a diagnostic must never stop the run it watches
            self.probe = None
            return
        # what a collision block would change: pairs with a dynamic body (a keyframed door
        # through a static wall is the scene's own motion, collision or not)
        from vrsim_cli.model.model import BODY_DYNAMIC

        dynamic = self.probe.body_type == BODY_DYNAMIC
        pairs = [p for p in pairs if dynamic[p[0]] or dynamic[p[1]]]
        if pairs:
            a, b, depth = pairs[0]
            self.found = PassThrough(self.probe.body_name[a], self.probe.body_name[b],
                                     float(state.t), float(depth))


def watch(scene, model) -> Watch | None:
    """A Watch for `scene` (compiled as `model`), or None: it has a collision block, no
    dynamic shape with another shape to meet, more than WATCH_MAX_SHAPES shapes, or its
    detection model cannot be built."""
    names = candidates(scene.data)
    if not names or len(names) > WATCH_MAX_SHAPES or model.collision is not None:
        return None
    from vrsim_cli.errors import InputError
    from vrsim_cli.model.model import compile_model

    try:
        probe_scene = scene.with_overrides(
            {("collision",): ({"response": "none", "continuous": False}, "pass-through check")})
        probe = compile_model(probe_scene)
    except (InputError, ValueError, ArithmeticError):  # e.g. a flat mesh has no hull to test
        return None
    if probe.collision is None or probe.n_body != model.n_body:
        return None
    return Watch(probe, len(scene.data.get("bodies") or []), Bounds(scene.data))


class Bounds:
    """A cheap test before the detection (which costs ~1 ms a frame): each shape's
    bounding sphere about its body's position (the centre of mass: a shape is centred
    there), planes as planes. When no sphere meets another or a plane, no shapes can
    overlap. Meshes have no radius here (inf: always tested)."""

    def __init__(self, data: dict):
        import math

        import numpy as np

        radius, planes, dynamic = [], [], []
        for i, body in enumerate(data.get("bodies") or []):
            dynamic.append(body.get("type", "dynamic") == "dynamic")
            shape = body.get("shape") or {}
            kind = shape.get("type")
            if kind == "plane":
                normal = np.zeros(3)
                normal[:len(shape["normal"])] = shape["normal"]
                planes.append((i, normal / np.linalg.norm(normal),
                               float(shape.get("offset", 0.0))))
                radius.append(math.nan)
                continue
            half = [0.5 * float(x) for x in shape.get("size", [])]
            r, length = float(shape.get("radius", 0.0)), float(shape.get("length", 0.0))
            radius.append({"sphere": r, "box": math.hypot(*half) if half else 0.0,
                           "capsule": 0.5 * length + r, "cylinder": math.hypot(0.5 * length, r)
                           }.get(kind, math.inf if kind is not None else math.nan))
        self.radius = np.array(radius, float)  # nan: no shape, or a plane
        self.planes = planes  # static (the schema's rule): only dynamic bodies can meet them
        self.shaped = np.flatnonzero(~np.isnan(self.radius))
        self.dynamic = np.array(dynamic, bool)[self.shaped]

    def near(self, body_pos, tolerance: float) -> bool:
        """Whether two bounding volumes with a dynamic body among them meet."""
        import numpy as np

        pos, r = body_pos[self.shaped], self.radius[self.shaped]
        for k, normal, offset in self.planes:
            if np.any(((pos - body_pos[k]) @ normal - offset < r + tolerance)
                      & self.dynamic):
                return True
        if len(pos) < 2:
            return False
        gap = np.linalg.norm(pos[:, None, :] - pos[None, :, :], axis=2) - r[:, None] - r[None, :]
        np.fill_diagonal(gap, np.inf)
        either = self.dynamic[:, None] | self.dynamic[None, :]
        return bool(np.any((gap < tolerance) & either))
