"""Semantic checks for the rigid-body keys of a scene (what the JSON Schema cannot say).

Layer 1, called from `scene._semantic_problems`. Pure Python (no numpy: `vrsim validate`
stays light). Numeric checks that need the mass properties themselves (a positive
definite inertia tensor, a closed mesh) happen when the model is compiled, and are
reported at the same located keys.
"""

from __future__ import annotations

from typing import Iterator

VOLUME_SHAPES = ("sphere", "box", "capsule", "cylinder", "mesh")
ROTATING_HINT = "give the body a shape, particles or inertia"


def rotates(body: dict) -> bool:
    """A dynamic body rotates when it has particles, an inertia or a shape with a volume;
    anything else is a point mass and pays nothing for rotation."""
    shape = body.get("shape") or {}
    return body.get("type", "dynamic") == "dynamic" and (
        "particles" in body or "inertia" in body or shape.get("type") in VOLUME_SHAPES)


def needs_mass_key(body: dict) -> bool:
    """True when a dynamic body must say `mass` (its mass does not come from elsewhere)."""
    return "particles" not in body and "density" not in body


def rigid_problems(scene, dim: int) -> Iterator:
    """Located problems (scene.problem) of the rigid-body keys, bodies and springs."""
    bodies = scene.data.get("bodies") or []
    by_name = {b["name"]: b for b in bodies}
    for i, body in enumerate(bodies):
        yield from _body_problems(scene, ("bodies", i), body, dim)
    for i, spring in enumerate(scene.data.get("springs") or []):
        yield from _spring_problems(scene, ("springs", i), spring, by_name, dim)


def _length(scene, path: tuple, dim: int) -> Iterator:
    vec = scene.get(path)
    if isinstance(vec, list) and len(vec) != dim:
        axes = "[x, y]" if dim == 2 else "[x, y, z]"
        yield scene.problem(path, f"expected {dim} numbers {axes} in a {dim}D scene, "
                                  f"got {len(vec)}")


def _per_dimension(scene, path: tuple, dim: int, what: str) -> Iterator:
    """2D: a number (about z); 3D: [x, y, z]."""
    value = scene.get(path)
    if value is None:
        return
    if dim == 2 and not isinstance(value, (int, float)):
        yield scene.problem(path, f"{what} is a number (about z) in a 2D scene")
    if dim == 3 and isinstance(value, (int, float)):
        yield scene.problem(path, f"{what} is [x, y, z] in a 3D scene")


def _body_problems(scene, at: tuple, body: dict, dim: int) -> Iterator:
    kind = body.get("type", "dynamic")
    shape_type = (body.get("shape") or {}).get("type")
    spins = rotates(body)
    if "particles" in body:
        for key in ("mass", "density"):
            if key in body:
                yield scene.problem(at + (key,), f"'{key}' comes from the particles",
                                    "remove it, or remove particles", at_key=True)
        if isinstance(body["particles"], list):
            for j in range(len(body["particles"])):
                yield from _length(scene, at + ("particles", j, "position"), dim)
    if "density" in body:
        if "mass" in body:
            yield scene.problem(at + ("density",), "give mass or density, not both",
                                at_key=True)
        if shape_type not in VOLUME_SHAPES:
            yield scene.problem(at + ("density",), "density needs a shape with a volume "
                                "(sphere, box, capsule, cylinder, mesh)", at_key=True)
    if kind != "dynamic":
        for key in ("particles", "density", "inertia", "damping", "torques"):
            if key in body:
                yield scene.problem(at + (key,), f"'{key}' is for dynamic bodies; this body "
                                    f"is {kind}", at_key=True)
    if "inertia" in body:
        yield from _per_dimension(scene, at + ("inertia",), dim, "inertia")
    if "angular_velocity" in body:
        yield from _per_dimension(scene, at + ("angular_velocity",), dim, "angular_velocity")
        if kind == "static":
            yield scene.problem(at + ("angular_velocity",), "a static body cannot move",
                                "use type: kinematic for a body that turns at a given rate",
                                at_key=True)
        elif kind == "dynamic" and not spins:
            yield scene.problem(at + ("angular_velocity",), "a point mass cannot spin",
                                ROTATING_HINT, at_key=True)
        elif kind == "kinematic":
            driven = [key for key in ("keyframes", "drive", "parent") if key in body]
            if driven:
                yield scene.problem(at + ("angular_velocity",), f"this body's orientation "
                                    f"comes from its {driven[0]}", "give the rotation there, "
                                    "not as angular_velocity", at_key=True)
    for j, force in enumerate(body.get("forces") or []):
        if "point" in force:
            yield from _length(scene, at + ("forces", j, "point"), dim)
            if kind == "dynamic" and not spins:
                yield scene.problem(at + ("forces", j, "point"), "a force at a point turns "
                                    "the body, but this body is a point mass", ROTATING_HINT,
                                    at_key=True)
    for j, torque in enumerate(body.get("torques") or []):
        tat = at + ("torques", j)
        yield from _per_dimension(scene, tat + ("torque",), dim, "a torque")
        if kind == "dynamic" and not spins:
            yield scene.problem(tat, "a torque needs a body that can rotate", ROTATING_HINT)
        if "end" in torque and torque["end"] <= torque.get("start", 0.0):
            yield scene.problem(tat + ("end",), "must be later than start")


def _spring_problems(scene, at: tuple, spring: dict, by_name: dict, dim: int) -> Iterator:
    names = sorted(by_name)
    for key, point in (("body", "point"), ("to", "to_point")):
        if key not in spring:
            if point in spring:
                yield scene.problem(at + (point,), f"'{point}' needs '{key}'", at_key=True)
            continue
        name = spring[key]
        target = by_name.get(name)
        if target is None:
            from vrsim_cli.errors import did_you_mean
            yield scene.problem(at + (key,), f"no body named '{name}'",
                                did_you_mean(name, names))
            continue
        if key == "body" and target.get("type", "dynamic") != "dynamic":
            yield scene.problem(at + (key,), f"'{name}' is not dynamic",
                                "a spring acts on a dynamic body; fix the other end with "
                                "'to' or 'anchor'")
        if point in spring:
            yield from _length(scene, at + (point,), dim)
            kind = target.get("type", "dynamic")
            animated = [k for k in ("keyframes", "drive", "parent")
                        if k in target]
            if any(spring[point]) and kind == "dynamic" and not rotates(target):
                yield scene.problem(at + (point,), f"'{name}' is a point mass: a spring "
                                    "can only hold it at its centre of mass", ROTATING_HINT)
            elif any(spring[point]) and kind == "kinematic" and animated:
                yield scene.problem(at + (point,), f"'{name}' turns ({animated[0]}): a "
                                    "spring can only hold it at its centre",
                                    "attach the spring to a static body or a world anchor")
    if ("to" in spring) == ("anchor" in spring):
        yield scene.problem(at, "give exactly one of 'to' (a body) or 'anchor' (a world "
                                "point)")
    if spring.get("to") is not None and spring.get("to") == spring.get("body"):
        yield scene.problem(at + ("to",), "a spring needs two different bodies")
    if "anchor" in spring:
        yield from _length(scene, at + ("anchor",), dim)
