"""Compile a validated scene into a frozen model: constants of the run as numpy arrays.

Layer 2. Like MuJoCo's mjModel, the model never changes during a run; everything that
moves lives in `state.State`. Arrays are structure-of-arrays over bodies, named
`body_<property>`, with shape and unit in the field list below, and are read-only.

Time grid: `dt` in the scene is the largest physics step the user accepts. A frame must
hold a whole number of steps, so the step used is `1 / (frame_rate * k)` with the smallest
whole `k` that makes it <= dt (the requested value itself when it already fits to 1e-12).
Simulated time is always `step_index * dt`, never a running sum, so it does not drift.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vrsim_cli.maths import trig
from vrsim_cli.maths.products import dot

from vrsim_cli.errors import InputError, Problem, format_key_path
from vrsim_cli.maths.geometry import ANALYTIC
from vrsim_cli.maths.spatial import (IDENTITY_QUAT, quat_from_axis_angle, quat_from_euler_deg,
                               quat_normalize, quat_rotating, unit)
from vrsim_cli.model.animation import Animation, compile_animation
from vrsim_cli.model.frames import FramesSpec, compile_frames
from vrsim_cli.model.observer import InputModel, ObserverModel, compile_input, compile_observer
from vrsim_cli.model.rigid import ADAPTIVE, RigidModel, compile_rigid, rigid_notes
from vrsim_cli.scene.files import (MAX_MESH_BYTES, about, file_target_problem,
                                   tum_folder_problem)
from vrsim_cli.scene.spec import Scene
from vrsim_cli.text import plural

BODY_DYNAMIC, BODY_KINEMATIC, BODY_STATIC = 0, 1, 2
BODY_TYPES = {"dynamic": BODY_DYNAMIC, "kinematic": BODY_KINEMATIC, "static": BODY_STATIC}
INTEGRATORS = ("euler", "symplectic-euler", "rk4", "verlet", "dopri5")
# k in x1 = x0 + dt v0 + k a dt^2: the share of a constant acceleration a in one step's
# drift (stages/dynamics/integrators.py); stages other than dynamics read it here
DRIFT_SHARE = {"euler": 0.0, "symplectic-euler": 1.0, "rk4": 0.5, "verlet": 0.5, "dopri5": 0.5}
OUTPUT_FORMATS = ("mcap", "csv", "tum")

DEFAULT_FRAME_RATE = 60.0  # Hz
DEFAULT_DT = 0.001  # s
DEFAULT_GRAVITY = (0.0, -9.81, 0.0)  # m/s^2, y up as on the slides
DEFAULT_PARTICLE_RADIUS = 0.02  # m, drawn size of an emitted particle
MAX_STEPS = 2_000_000_000  # a run longer than this is a typo, not a plan
MAX_TUM_ENTITIES = 256  # TUM writes one file per entity (writers/tum_writer.py)

# Ten distinguishable colours for bodies without `color` (RGBA).
PALETTE = np.array([
    [0.12, 0.47, 0.71, 1], [1.00, 0.50, 0.05, 1], [0.17, 0.63, 0.17, 1],
    [0.84, 0.15, 0.16, 1], [0.58, 0.40, 0.74, 1], [0.55, 0.34, 0.29, 1],
    [0.89, 0.47, 0.76, 1], [0.50, 0.50, 0.50, 1], [0.74, 0.74, 0.13, 1],
    [0.09, 0.75, 0.81, 1]])


@dataclass(frozen=True)
class OutputSpec:
    """Where and how the trajectory is written. `path` None: the run writes nothing."""

    path: Path | None
    format: str | None
    every_steps: int  # one sample every this many physics steps
    up: str = "y"  # the scene's up axis, 'y' or 'z': MCAP turns it to Foxglove's z-up world


@dataclass(frozen=True)
class Model:
    """Constants of one run. Fields with a shape are read-only numpy arrays.

    n_body bodies, n_force forces. Positions in m, velocities in m/s, masses in kg,
    forces in N, times in s, quaternions [w, x, y, z].
    """

    name: str
    dimension: int  # 2 or 3; 2D bodies live in the z = 0 plane and rotate about z
    dt: float  # s, physics step actually used
    dt_requested: float  # s, the scene's (or --dt's) upper bound
    frame_rate: float  # Hz
    steps_per_frame: int
    n_steps: int  # the run ends at t = n_steps * dt
    integrator: str
    gravity: np.ndarray  # (3,) m/s^2
    body_name: tuple  # (n_body,) str
    body_type: np.ndarray  # (n_body,) int8: BODY_DYNAMIC | BODY_KINEMATIC | BODY_STATIC
    body_mass: np.ndarray  # (n_body,) kg; inf for kinematic and static bodies
    body_inv_mass: np.ndarray  # (n_body,) 1/kg; 0 for kinematic and static bodies
    body_pos0: np.ndarray  # (n_body, 3) m, initial centre of mass
    body_vel0: np.ndarray  # (n_body, 3) m/s, initial velocity (emitted: at emission)
    body_quat0: np.ndarray  # (n_body, 4) initial orientation
    body_color: np.ndarray  # (n_body, 4) RGBA in [0, 1]
    body_shape: tuple  # (n_body,) dict | None: the scene's shape, normalised
    body_emit_step: np.ndarray  # (n_body,) int64: step at which the body starts to move
    force_body: np.ndarray  # (n_force,) int64 body index
    force_vec: np.ndarray  # (n_force, 3) N, world frame, at the centre of mass
    force_start: np.ndarray  # (n_force,) s
    force_end: np.ndarray  # (n_force,) s (inf: never ends)
    output: OutputSpec
    scene_file: str = ""
    scene_text: str = ""
    has_emitters: bool = False
    body_index: dict = field(default_factory=dict)  # name -> index
    observer: ObserverModel | None = None  # None: the scene has no observer
    inputs: InputModel | None = None  # sensor values per frame (loop stage 1)
    observer_obstacles: tuple = ()  # body indices the observer collides with and walks on
    notes: tuple = ()  # things the user should know about this run (printed, not errors)
    frames: FramesSpec | None = None  # rendered PNG frames; None: the run renders nothing
    # Keyframes, drives and the scene graph (animation.Animation); None: nothing animated.
    # The pos0/quat0 of a body with a parent are local (relative to the parent's frame).
    animation: Animation | None = None
    rigid: RigidModel | None = None  # rotation, springs, torques (model/rigid.py); None: point masses only
    # model.collision.CollisionModel when the scene has a `collision` block, else None
    # (then stage 2.3 costs nothing).
    collision: object | None = None
    # model.response.ResponseModel: how contacts change the motion (slide
    # 5.4.2); None without a collision block or with `collision.response: none` for all.
    response: object | None = None
    # Arrays the compiled kernels take, built from the fields above on first use (not
    # part of the model's value: `dataclasses.replace` starts a fresh cache).
    cache: dict = field(default_factory=dict, compare=False, repr=False, init=False)

    @property
    def n_body(self) -> int:
        return len(self.body_name)

    @property
    def duration(self) -> float:
        """s, simulated time of the whole run."""
        return self.n_steps * self.dt

    @property
    def n_frames(self) -> int:
        return -(-self.n_steps // self.steps_per_frame)

    def __repr__(self) -> str:  # one line: a notebook echoing a model gets no arrays
        bodies = f"{self.n_body} bod{'y' if self.n_body == 1 else 'ies'}"
        return (f"<Model {self.name!r}: {bodies}, {self.dimension}D, {self.duration:g} s in "
                f"steps of {self.dt:g} s, {self.integrator}>")


def _frozen(array) -> np.ndarray:
    out = np.array(array, dtype=float if not np.issubdtype(np.asarray(array).dtype,
                                                             np.integer) else np.int64)
    out.flags.writeable = False
    return out


def _vec3(values, dim: int) -> list[float]:
    """A scene vector (2 or 3 numbers) as a 3-vector; 2D vectors get z = 0."""
    values = [float(v) for v in values]
    return values + [0.0] * (3 - len(values)) if dim == 2 else values


def _fit_steps(interval: float, dt: float) -> int:
    """Smallest whole k with interval / k <= dt (1e-9 slack for decimal round-off)."""
    return max(1, math.ceil(interval / dt - 1e-9))


def compile_model(scene: Scene, *, output_override: tuple[Path, str] | None = None) -> Model:
    """Scene spec -> frozen Model. Raises InputError with located problems."""
    data = scene.data
    problems: list[Problem] = []
    dim = int(data.get("dimension", 3))

    # --- time grid
    frame_rate = float(data.get("frame_rate", DEFAULT_FRAME_RATE))
    # An adaptive integrator chooses its own steps: by default the grid is the frame.
    dt_requested = float(data.get("dt", DEFAULT_DT if data.get("integrator") not in ADAPTIVE
                                  else 1.0 / frame_rate))
    frame_interval = 1.0 / frame_rate
    steps_per_frame = _fit_steps(frame_interval, dt_requested)
    dt = frame_interval / steps_per_frame
    if abs(dt - dt_requested) <= 1e-12 * dt_requested:
        dt = dt_requested
    # The defaults (dt 1 ms, 60 Hz) do not divide: 1 ms becomes 1/1020 s. That is said only
    # when the user wrote both numbers; otherwise the summary's "steps of ... s" shows it.
    time_notes = () if dt == dt_requested or "dt" not in data or "frame_rate" not in data \
        else (f"dt = {dt_requested:g} s does not divide the frame interval 1/{frame_rate:g} "
              f"s; using dt = {dt:.6g} s ({steps_per_frame} steps per frame)",)
    duration = float(data["duration"])
    ratio = duration / dt
    if not ratio <= MAX_STEPS:  # also catches inf and nan from extreme values
        raise InputError([scene.problem(("duration",), f"the run would take {ratio:.3g} steps "
                                        f"(more than {MAX_STEPS:.0e})", "use a larger dt or a "
                                        "shorter duration")])
    if ratio < 1.0 - 1e-9:
        raise InputError([scene.problem(("duration",), f"{duration:g} s is shorter than one "
                                        f"physics step ({dt:.6g} s)")])
    n_steps = round(ratio) if abs(ratio - round(ratio)) <= 1e-9 * max(1.0, ratio) else \
        math.ceil(ratio)

    window_notes = _force_windows(scene, dt, n_steps, problems)

    # --- output
    out = data.get("output") or {}
    rate = float(out.get("rate", frame_rate))
    every = (1.0 / rate) / dt
    every_steps = round(every) if every <= MAX_STEPS else 0
    if every_steps < 1 or abs(every - every_steps) > 1e-6 * every:
        problems.append(scene.problem(
            ("output", "rate"), f"1/rate = {1.0 / rate:.6g} s is not a whole number of physics "
            f"steps (dt = {dt:.6g} s)", "nearest rates that fit: "
            # to 10 digits: a rate cut to 6 (145.714 for 1020/7) is refused by this check
            + ", ".join(f"{r:.10g}" for r in _fitting_rates(rate, dt, frame_rate)) + " Hz"))
    up, up_notes = _up_axis(data, dim)
    output = _output_spec(scene, dict(out, up=up), output_override, max(every_steps, 1),
                          problems)
    frames = compile_frames(scene, problems)

    # --- bodies, then emitted particles
    names: list[str] = []
    triangles: list[tuple] = []  # (body index, triangles) of mesh bodies
    kinds, masses, pos0, vel0, quat0, colors, shapes, emit = [], [], [], [], [], [], [], []
    force_body, force_vec, force_start, force_end = [], [], [], []
    for i, body in enumerate(data.get("bodies") or []):
        at = ("bodies", i)
        kind = BODY_TYPES[body.get("type", "dynamic")]
        velocity = body.get("velocity")
        names.append(body["name"])
        kinds.append(kind)
        masses.append(float(body.get("mass", math.nan)) if kind == BODY_DYNAMIC else math.inf)
        pos0.append(_vec3(body.get("position", [0.0] * dim), dim))
        vel0.append(_vec3(velocity or [0.0] * dim, dim) if kind != BODY_STATIC else [0.0] * 3)
        quat0.append(_orientation(body))
        colors.append(_color(body.get("color"), len(colors)))
        shapes.append(_shape(body.get("shape"), dim, pos0[-1]))
        if shapes[-1] is not None and shapes[-1]["type"] == "mesh":
            shapes[-1]["path"] = _mesh_file(scene, at + ("shape",), problems, triangles)
        emit.append(0)
        for force in body.get("forces") or []:
            force_body.append(len(names) - 1)
            force_vec.append(_vec3(force["force"], dim))
            force_start.append(float(force.get("start", 0.0)))
            force_end.append(float(force.get("end", math.inf)))
    rigid = compile_rigid(scene, dim, len(names), kinds, masses, pos0, vel0, quat0,
                          [(s or {}).get("path") for s in shapes], problems)
    emitted = [_emit(emitter, dim, dt) for emitter in data.get("emitters") or []]
    if problems:  # report before building per-frame data: a bad scene must not cost memory
        raise InputError(problems)

    gravity = data.get("gravity", list(DEFAULT_GRAVITY[:dim]))
    observer = compile_observer(scene, gravity, problems, names)
    inputs = compile_input(scene, observer, problems)
    n_scene_bodies = len(data.get("bodies") or [])
    animation = compile_animation(scene, dim, pos0[:n_scene_bodies], quat0[:n_scene_bodies],
                                  problems)
    if problems:
        raise InputError(problems)

    for emitter, particles in zip(data.get("emitters") or [], emitted):
        count = len(particles["names"])
        names.extend(particles["names"])
        kinds.extend([BODY_DYNAMIC] * count)
        masses.extend([float(emitter["mass"])] * count)
        pos0.extend(particles["position"])
        vel0.extend(particles["velocity"])
        quat0.extend(np.tile(IDENTITY_QUAT, (count, 1)))
        colors.extend(_color(emitter.get("color"), len(colors) + k) for k in range(count))
        sphere = {"type": "sphere", "radius": float(emitter.get("radius",
                                                                DEFAULT_PARTICLE_RADIUS))}
        shapes.extend([sphere] * count)
        emit.extend(particles["emit_step"])

    problems.extend(_overwritten_inputs(scene, output, shapes))
    problems.extend(_memory_problems(scene, len(names), output, frames, triangles,
                                     _start_overlaps(scene, kinds, pos0, shapes, emit)))
    if problems:
        raise InputError(problems)
    if output.format == "tum" and output.path is not None:
        entities = names + (["observer"] if observer is not None else [])
        problems.extend(_tum_entity_problems(scene, output, output_override, entities))
        if problems:
            raise InputError(problems)

    collision = response = None
    mesh_notes = ()
    if data.get("collision") is not None:
        from vrsim_cli.model.collision import compile_collision, mesh_pair_notes
        collision = compile_collision(scene, shapes, dim, problems)  # only scenes that collide
        response = None
        if collision is not None:
            from vrsim_cli.model.collision import thinnest
            from vrsim_cli.model.response import THIN_FALLS, compile_response, thin_reason
            mesh_notes = mesh_pair_notes(data, collision)
            extent, body = thinnest(collision, np.array(kinds) == BODY_DYNAMIC)
            name = names[body] if body >= 0 else ""  # (no dynamic shape: extent is inf)
            collision, tolerance_notes = _thin_tolerance(data, collision, name, extent)
            mesh_notes = mesh_notes + tolerance_notes
            integrator = str(data.get("integrator", "symplectic-euler"))
            fall = max(DRIFT_SHARE.get(integrator, 1.0), 0.5) * \
                math.hypot(*_vec3(gravity, dim)) * dt * dt  # m in one step
            # a thin body that another may rest on (two dynamic bodies with a shape)
            shaped = sum(1 for shape, kind in zip(shapes, kinds)
                         if shape is not None and kind == BODY_DYNAMIC)
            thin = (name, extent, fall) if fall > 0.0 and shaped >= 2 and \
                extent < THIN_FALLS * fall + collision.tolerance else None
            response = compile_response(scene, len(names), _vec3(gravity, dim),
                                        collision.tolerance, problems)
            if response is not None and response.impacts == "located" and thin is not None:
                mesh_notes = mesh_notes + (
                    f"{thin_reason(thin)}: located impacts find resting contacts after the "
                    f"step, and a body resting on it may pass through; impacts: auto (the "
                    f"compiled step) or a smaller dt holds such stacks",)
            if response is not None and rigid is not None and (
                    BODY_KINEMATIC in kinds or _superelastic(response)):
                # a kinematic body that hits others does work on them, and so would an
                # impact with restitution > 1 (the schema allows <= 1): energy may grow;
                # other impacts only take energy away, the guard's bound stays the
                # integrator's
                rigid = dataclasses.replace(rigid, energy_guard=False)
        if problems:
            raise InputError(problems)

    n = len(names)
    mass = np.array(masses, dtype=float)
    return Model(
        name=str(data.get("name", Path(scene.file).stem)),
        dimension=dim,
        dt=dt,
        dt_requested=dt_requested,
        frame_rate=frame_rate,
        steps_per_frame=steps_per_frame,
        n_steps=n_steps,
        integrator=str(data.get("integrator", "symplectic-euler")),
        gravity=_frozen(_vec3(gravity, dim)),
        body_name=tuple(names),
        body_type=_frozen(np.array(kinds, dtype=np.int64)),
        body_mass=_frozen(mass),
        body_inv_mass=_frozen(np.where(np.isfinite(mass), 1.0 / mass, 0.0)),
        body_pos0=_frozen(np.reshape(pos0, (n, 3))),
        body_vel0=_frozen(np.reshape(vel0, (n, 3))),
        body_quat0=_frozen(np.reshape(quat0, (n, 4))),
        body_color=_frozen(np.reshape(colors, (n, 4))),
        body_shape=tuple(shapes),
        body_emit_step=_frozen(np.array(emit, dtype=np.int64)),
        force_body=_frozen(np.array(force_body, dtype=np.int64)),
        force_vec=_frozen(np.reshape(force_vec, (len(force_body), 3))),
        force_start=_frozen(np.array(force_start, dtype=float)),
        force_end=_frozen(np.array(force_end, dtype=float)),
        output=output,
        scene_file=scene.file,
        scene_text=scene.text,
        has_emitters=bool(data.get("emitters")),
        body_index={name: i for i, name in enumerate(names)},
        observer=observer,
        inputs=inputs,
        notes=time_notes + up_notes + _notes(data) + rigid_notes(data) + window_notes + mesh_notes,
        # Static and kinematic bodies with analytic shapes (meshes join with collision).
        observer_obstacles=tuple(i for i, (kind, shape) in enumerate(zip(kinds, shapes))
                                 if kind != BODY_DYNAMIC and shape is not None
                                 and shape["type"] in ANALYTIC) if observer else (),
        frames=frames,
        animation=animation,
        rigid=rigid,
        collision=collision,
        response=response,
    )


def output_format_for(path: Path, explicit: str | None) -> str | None:
    """The trajectory format: explicit, else from the suffix. None when unknown."""
    if explicit:
        return explicit
    suffix = path.suffix.lower()
    return {".mcap": "mcap", ".csv": "csv", ".tum": "tum"}.get(suffix)


def _output_spec(scene: Scene, out: dict, override, every_steps: int,
                 problems: list[Problem]) -> OutputSpec:
    up = out.get("up", "y")
    if override is not None:
        path, fmt = override
        return OutputSpec(Path(path), fmt, every_steps, up)
    if "file" not in out:
        return OutputSpec(None, None, every_steps, up)
    path = scene.resolve_path(("output", "file"), problems, output=True)
    if path is None:
        return OutputSpec(None, None, every_steps, up)
    # resolve_path follows links; the name the scene gives must not be one itself (the
    # output would replace the file it points to, or the link)
    named = os.path.normpath(Path.cwd().resolve() / out["file"])
    if os.path.islink(named):
        problems.append(scene.problem(("output", "file"), f"'{out['file']}' is a symbolic "
                                      f"link; give the file it points to"))
        return OutputSpec(None, None, every_steps, up)
    fmt = output_format_for(path, out.get("format"))
    if fmt is None:
        problems.append(scene.problem(("output", "file"), f"cannot tell the format of "
                                      f"'{out['file']}'", "use a .mcap or .csv suffix, or set "
                                      "output.format (tum writes a folder)"))
    problems.extend(_output_target_problems(scene, path, fmt))
    return OutputSpec(path, fmt, every_steps, up)


def _output_target_problems(scene: Scene, path: Path, fmt: str | None) -> list[Problem]:
    """What would fail only after the whole run, or destroy the input or anything else: a
    missing folder, a file format aimed at a folder, a TUM folder aimed at a file or at a
    folder holding other files (the scene's own, say), the scene file itself, a device,
    FIFO, socket or symbolic link (see scene.files)."""
    at = ("output", "file")
    if scene.file and path == Path(scene.file).resolve():
        return [scene.problem(at, "the output would overwrite the scene file itself")]
    name = file_target_problem(path) if fmt != "tum" else tum_folder_problem(path)
    if name is not None and ("name is" in name or "too long" in name):
        return [scene.problem(at, about(scene.get(at), name))]
    if not path.parent.is_dir():
        return [scene.problem(at, f"folder '{path.parent}' does not exist",
                              "output paths are relative to the current folder")]
    if fmt in ("csv", "mcap") and path.is_dir():
        return [scene.problem(at, f"'{scene.get(at)}' is a folder; {fmt} output is a file")]
    if fmt == "tum" and path.exists() and not path.is_dir():
        return [scene.problem(at, f"'{scene.get(at)}' is a file; tum output is a folder")]
    problem = tum_folder_problem(path, None, scene.file) if fmt == "tum" else \
        file_target_problem(path) if fmt is not None else None
    if problem is not None:
        return [scene.problem(at, about(scene.get(at), problem))]
    return []


def _tum_entity_problems(scene: Scene, output: OutputSpec, override, entities) -> list:
    """A TUM run writes one file per entity: at most MAX_TUM_ENTITIES, and no `.tum` files
    of other entities may stay beside them (a mix of two runs)."""
    where = (lambda message: Problem("command line (-o)", 0, 0, (), message)) \
        if override is not None else (lambda message: scene.problem(("output", "file"),
                                                                     message))
    if len(entities) > MAX_TUM_ENTITIES:
        return [where(f"tum output writes one file per entity, at most {MAX_TUM_ENTITIES}; "
                      f"this scene has {len(entities)} entities (use csv or mcap)")]
    problem = tum_folder_problem(output.path, set(entities), scene.file)
    if problem is not None:
        shown = str(output.path) if override is not None else scene.get(("output", "file"))
        return [where(about(shown, problem))]
    return []


def _overwritten_inputs(scene: Scene, output: OutputSpec, shapes) -> list[Problem]:
    """The output must not replace a file the scene reads (a mesh, a sensor file): the
    run would destroy its own input (as it may not the scene file itself)."""
    if output.path is None or str(output.path) == "-":
        return []
    try:
        target = output.path.resolve()
    except (OSError, RuntimeError):
        return []
    inputs = [(("bodies", i, "shape", "file"), shape.get("path"))
              for i, shape in enumerate(shapes) if shape and shape["type"] == "mesh"]
    spec = scene.data.get("input") or {}
    inputs += [(("input", key), scene.base_dir.resolve() / spec[key])
               for key in ("file", "tracker", "replay") if isinstance(spec.get(key), str)]
    for key, path in inputs:
        if path is None:
            continue
        try:
            same = Path(path).resolve() == target or (output.format == "tum" and Path(
                path).resolve().parent == target)
        except (OSError, RuntimeError, ValueError):
            continue
        if same:
            where = ("output", "file") if output.path is not None and ("output", "file") \
                in scene.value_pos else key
            return [scene.problem(where, f"the output would overwrite {format_key_path(key)} "
                                  f"('{scene.get(key)}'), which this scene reads")]
    return []


def _superelastic(response) -> bool:
    """Does any body or pair set a restitution above 1 (impacts that add energy)?"""
    values = np.concatenate([response.body_restitution, response.pair_restitution])
    return bool((values[np.isfinite(values)] > 1.0).any())


def _start_overlaps(scene: Scene, kinds, pos0, shapes, emit) -> int:
    """Pairs of colliding bodies that start at one point (budget.coincident_pairs): bodies
    at the same position, emitted particles released at the same step."""
    top = scene.data.get("collision")
    if top is None or not top.get("enabled", True):
        return 0
    from vrsim_cli.model.budget import coincident_pairs

    bodies = scene.data.get("bodies") or []
    keys, movable = [], []
    for i, (kind, shape) in enumerate(zip(kinds, shapes)):
        spec = (bodies[i].get("collision") or {}) if i < len(bodies) else {}
        if shape is None or shape["type"] == "plane" or not spec.get("enabled", True):
            continue
        keys.append((tuple(float(x) for x in pos0[i]), int(emit[i])))
        movable.append(kind != BODY_STATIC)
    return coincident_pairs(keys, movable)


def _memory_problems(scene: Scene, n_body: int, output: OutputSpec, frames, triangles,
                     pairs: int):
    """The run's memory estimate (model/budget.py) past its limit, located at what drives
    it: the emitters or bodies, the frames, the largest mesh, or bodies at one point."""
    from vrsim_cli.model.budget import budget_problem, estimate_mb

    pixels = frames.width * frames.height if frames is not None else 0
    terms = estimate_mb(n_body, output.format if output.path is not None else None, pixels,
                        True, sum(n for _, n in triangles), pairs)
    found = budget_problem(terms)
    if found is None:
        return []
    message, main = found
    data = scene.data
    if main == "frames":
        where, hint = ("output", "frames"), "render smaller frames (width x height)"
    elif main == "meshes":
        where = ("bodies", max(triangles, key=lambda t: t[1])[0], "shape", "file")
        hint = "use meshes with fewer triangles"
    elif main == "overlaps":
        where = ("emitters",) if data.get("emitters") else ("bodies",)
        hint = (f"{pairs} pairs of colliding bodies start at the same point: give them "
                f"positions of their own, or let emitters release fewer particles per step")
    else:
        where = ("emitters",) if data.get("emitters") else ("bodies",)
        hint = "use fewer bodies or particles" + (" (CSV output takes less than MCAP)"
                                                   if output.format == "mcap" else "")
    return [scene.problem(where, message, hint, at_key=main in ("bodies", "overlaps"))]


def _mesh_file(scene: Scene, at: tuple, problems: list[Problem], triangles: list) -> str | None:
    """The mesh file of the shape at `at`, checked once for every mesh body (also those
    only drawn or written to MCAP): a regular file that trimesh reads, with at most
    MAX_MESH_TRIANGLES triangles, finite vertices and a size vrsim simulates."""
    resolved = scene.input_path(at + ("file",), problems, MAX_MESH_BYTES)
    if resolved is None:
        return None
    from vrsim_cli.maths.meshes import load_mesh  # trimesh: only mesh scenes pay for it

    try:
        mesh = load_mesh(str(resolved), float(scene.get(at + ("scale",), 1.0)))
        triangles.append((at[1], len(mesh.faces)))
    except ValueError as exc:
        problems.append(scene.problem(at + ("file",), str(exc).replace(
            f"'{resolved}'", f"'{scene.get(at + ('file',))}'"), "vrsim reads OBJ, STL, PLY, "
            "GLB and glTF meshes"))
        return None
    return str(resolved)


def _orientation(body: dict) -> np.ndarray:
    if "orientation" in body:
        return quat_normalize(body["orientation"])
    if "euler_deg" in body:
        return quat_from_euler_deg(body["euler_deg"])
    if "angle_deg" in body:
        return quat_normalize(quat_from_axis_angle([0, 0, 1], math.radians(body["angle_deg"])))
    return IDENTITY_QUAT


def _color(color, index: int) -> np.ndarray:
    if color is None:
        return PALETTE[index % len(PALETTE)]
    return np.array(list(color) + [1.0] * (4 - len(color)), dtype=float)


def _shape(shape: dict | None, dim: int, position=(0.0, 0.0, 0.0)) -> dict | None:
    """The scene's shape with vectors made 3D and plane normals made unit length. A plane
    passes through its body's position shifted by `offset` along the normal: {p : n.(p -
    position) <= offset}, stored as the world-frame offset n.position + offset."""
    if shape is None:
        return None
    shape = dict(shape)
    if shape["type"] == "box":
        size = _vec3(shape["size"], dim)
        shape["size"] = size if dim == 3 else size[:2] + [0.0]
    if shape["type"] == "plane":
        shape["normal"] = unit(_vec3(shape["normal"], dim)).tolist()
        shape["offset"] = float(shape.get("offset", 0.0)) + \
            float(dot(shape["normal"], position))
        shape["orientation"] = list(quat_rotating([0, 1, 0], shape["normal"]))
    return shape


def _emit(emitter: dict, dim: int, dt: float) -> dict:
    """Particles of one emitter as arrays: deterministic for a seed on every platform
    (PCG64). Returns names, position (count, 3), velocity (count, 3), emit_step (count,)."""
    rng = np.random.Generator(np.random.PCG64(int(emitter.get("seed", 0))))
    count = int(emitter["count"])
    axis = unit(_vec3(emitter.get("direction", [0.0, 1.0, 0.0][:dim]), dim))
    spread = math.radians(float(emitter.get("spread_deg", 0.0)))
    jitter = float(emitter.get("speed_jitter", 0.0))
    speed = float(emitter["speed"]) * (1.0 + jitter * rng.uniform(-1.0, 1.0, count))
    if dim == 3:
        # Uniform over the spherical cap of half-angle `spread` around `axis`.
        # sin and cos of our own (maths/trig.py): libm's last bit depends on the CPU
        cos_theta = rng.uniform(trig.cos(spread), 1.0, count)
        phi = rng.uniform(0.0, 2.0 * math.pi, count)
        sin_theta = np.sqrt(np.maximum(0.0, 1.0 - cos_theta ** 2))
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
        u = unit(np.cross(axis, helper))
        w = np.cross(axis, u)
        sin_phi, cos_phi = trig.sin_cos(phi)
        dirs = (cos_theta[:, None] * axis + (sin_theta * cos_phi)[:, None] * u
                + (sin_theta * sin_phi)[:, None] * w)
    else:
        theta = rng.uniform(-spread, spread, count)
        s, c = trig.sin_cos(theta)
        dirs = np.stack([c * axis[0] - s * axis[1], s * axis[0] + c * axis[1],
                         np.zeros(count)], axis=1)
    nozzle = _vec3(emitter.get("position", [0.0] * dim), dim)
    width = max(4, len(str(count - 1)))
    # First step whose time is >= i / rate (1e-9 slack for decimal round-off). Start times
    # past any run (or infinite: a tiny rate) clamp to MAX_STEPS + 1 before the int cast.
    with np.errstate(over="ignore"):
        start = np.arange(count) / float(emitter["rate"]) / dt - 1e-9
    emit_step = np.maximum(0, np.ceil(np.minimum(start, MAX_STEPS + 1)))
    return {"names": [f"{emitter['name']}.{i:0{width}d}" for i in range(count)],
            "position": np.tile(nozzle, (count, 1)), "velocity": speed[:, None] * dirs,
            "emit_step": emit_step.astype(np.int64)}


def _fitting_rates(rate: float, dt: float, frame_rate: float) -> list[float]:
    """Output rates near `rate` whose period is a whole number of steps, and the frame rate."""
    k = max(1, round(1.0 / (rate * dt)))
    near = {1.0 / (dt * j) for j in (k - 1, k, k + 1) if j >= 1}
    return sorted(near | {frame_rate}, key=lambda r: abs(r - rate))[:4]


def _thin_tolerance(data: dict, collision, name: str, extent: float) -> tuple:
    """(collision, notes): the collision model with its default tolerance lowered to
    TOLERANCE_SHARE of the thinnest dynamic body's extent (m; `name` that body) where
    that is less than the default, and a note saying so. A tolerance the scene sets is
    kept."""
    from vrsim_cli.model.collision import DEFAULT_TOLERANCE, TOLERANCE_SHARE
    if "tolerance" in (data.get("collision") or {}):
        # a set tolerance is kept, but one of half a body's thinness or more reports
        # contacts across that body (0.3 mm cards at 1 mm ended 13.6 mm away; an
        # independent review): say so
        if collision.tolerance >= 0.5 * extent:
            return collision, (
                f"collision.tolerance {collision.tolerance * 1e3:.3g} mm is at least half "
                f"of body '{name}' ({extent * 1e3:.3g} mm thin): contacts may be "
                f"reported across it and stacks of it may not stand; without the key "
                f"the tolerance would be {TOLERANCE_SHARE * extent * 1e3:.3g} mm",)
        return collision, ()
    if not TOLERANCE_SHARE * extent < DEFAULT_TOLERANCE:
        return collision, ()
    tolerance = TOLERANCE_SHARE * extent
    note = (f"collision.tolerance is {tolerance * 1e3:.3g} mm, a tenth of body "
            f"'{name}' ({extent * 1e3:.3g} mm thin), not the default "
            f"{DEFAULT_TOLERANCE * 1e3:g} mm: set collision.tolerance to choose another")
    return dataclasses.replace(collision, tolerance=tolerance), (note,)


def _up_axis(data: dict, dim: int) -> tuple[str, tuple]:
    """(output.up, notes): the scene's up axis as written, else the one gravity points
    against. A z-up scene (gravity along -z) left at the default y would lie on its side
    in Foxglove; a newcomer who wrote gravity [0, 0, -9.81] has said which way is up."""
    out = data.get("output") or {}
    if "up" in out:
        return out["up"], ()
    g = [float(x) for x in data.get("gravity", DEFAULT_GRAVITY[:dim])]
    if dim != 3 or not any(g):
        return "y", ()
    axis = max(range(3), key=lambda i: abs(g[i]))
    shown = "[" + ", ".join(f"{x:g}" for x in g) + "]"
    if axis == 2 and g[2] < 0.0:
        return "z", (f"output.up is z, from gravity {shown} (down is -z): MCAP output and "
                     f"--live show the scene z-up; set output.up to choose",)
    if axis == 1 and g[1] < 0.0:
        return "y", ()
    return "y", (f"gravity {shown} points along neither -y nor -z: MCAP output and --live "
                 f"show the scene y-up, so it falls sideways there; output.up takes y or z",)


def _notes(data: dict) -> tuple:
    """Keys that are valid but have no effect in this version, said out loud."""
    with_material = [i for i, b in enumerate(data.get("bodies") or []) if "material" in b]
    if not with_material or data.get("collision") is not None:
        return ()
    return (f"material (restitution, friction) of {plural(len(with_material), 'body')}, first "
            f"bodies[{with_material[0]}], has no effect without a top-level collision "
            f"block: nothing collides",)


def _force_windows(scene: Scene, dt: float, n_steps: int, problems: list[Problem]) -> tuple:
    """Forces and torques act on whole steps: those whose start time lies in [start, end)
    (dynamics.active_forces). A window holding no step start would silently do nothing: that
    is an error. A window that does not cover whole steps acts longer or shorter than
    written: that is said in a note."""
    notes = []
    for i, body in enumerate(scene.data.get("bodies") or []):
        for key in ("forces", "torques"):
            for j, item in enumerate(body.get(key) or []):
                start, end = float(item.get("start", 0.0)), float(item.get("end", math.inf))
                if not math.isfinite(end):
                    continue
                first = max(0, math.ceil(start / dt - 1e-9))
                last = min(n_steps, math.ceil(end / dt - 1e-9))  # exclusive
                acting = max(0, last - first)
                written = min(end, n_steps * dt) - start
                if acting == 0 and written > 0:
                    problems.append(scene.problem(
                        ("bodies", i, key, j), f"acts on no physics step: no step starts in "
                        f"[{start:g}, {end:g}) s (dt = {dt:.6g} s)", "widen the window to at "
                        "least one step, or use a smaller dt"))
                elif written > 0 and abs(acting * dt - written) > 1e-9 * max(written, dt):
                    notes.append(f"bodies[{i}].{key}[{j}] acts on {acting} whole steps, "
                                 f"{acting * dt:.6g} s instead of {written:.6g} s (forces act "
                                 f"from step start to step start)")
    return tuple(notes)
