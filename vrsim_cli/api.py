"""The Python API: scenes in, states and trajectories out, for people who script.

Layer 8, beside the CLI, and reached as `vrsim_cli.load`, `vrsim_cli.simulate`, ... (the
package imports this module on first use, so `import vrsim_cli` stays cheap)::

    import vrsim_cli

    model = vrsim_cli.load("scenarios/projectile.yaml")    # or YAML text
    sim = vrsim_cli.simulate(model)
    for state in sim:                                      # every output sample
        print(state.t, state.body_pos[0])                  # s, (n_body, 3) m
    traj = vrsim_cli.simulate(model).run()                 # all samples at once
    traj.position[:, traj.index("ball")]                   # (k, 3) m
    traj.to_dataframe()                                    # pandas, the CSV's columns

`Model` and `State` are vrsim's own (`vrsim_cli.model.model.Model`,
`vrsim_cli.model.state.State`): read-only numpy arrays named `body_<quantity>`, with shape
and unit in their docstrings and in docs/api.md.

How it uses the loop: only `loop.run(model, state, writer, should_stop=, on_frame=,
resume=)`, its public entry point. A Simulation advances by calling it from the current
state with a `should_stop` that ends it after the frames asked for; the loop starts at
`state.step // steps_per_frame`, samples through the writer and, with `resume=True`, does
not set up the first state again, so running in pieces gives the same states, bit for
bit, as one run (tested). Nothing else of the loop's insides is used.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vrsim_cli.errors import InputError
from vrsim_cli.loop import UNIT_TOLERANCE, RunResult, overlap_problems, run as run_loop
from vrsim_cli.maths.spatial import quat_to_matrix
from vrsim_cli.model.model import (BODY_DYNAMIC, BODY_KINEMATIC, BODY_STATIC, Model,
                                   compile_model)
from vrsim_cli.model.state import State, make_state, state_hash
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.writers.entities import CSV_COLUMNS, entity_arrays, entity_names

__all__ = ["Model", "Simulation", "State", "Trajectory", "load", "simulate", "state_hash",
           "read_trajectory"]

# Scene keys that load() and simulate() accept as keyword overrides, as on the command line.
OVERRIDES = {"duration": ("duration",), "dt": ("dt",), "integrator": ("integrator",),
             "tolerance": ("tolerance",)}


def load(source: str | os.PathLike, set=None, **overrides) -> Model:  # noqa: A002
    """The compiled Model of a scene: `source` is a path (str or PathLike) to a scene file,
    or the YAML text itself (a str with a newline, or one that names no file).

    `set`: values by key path, as `vrsim run --set` and `vrsim sweep --set` take them: a
    mapping `{"bodies.ball.material.restitution": 0.5, "gravity": [0, -1.62, 0]}` or
    strings `["dt=0.01", "bodies[0].position=[0, 2, 0]"]` (values read as YAML). Keys
    the scene's schema does not know raise InputError with a did-you-mean.
    Keyword overrides as on the command line: duration (s), dt (s), integrator,
    tolerance (applied after `set`). Problems raise `vrsim_cli.errors.InputError` with file:line:col, key path
    and hint (its `.problems`), bodies that start inside each other included. A scene's `output` keys are kept as settings only: the
    API writes no files.
    """
    unknown = {*overrides} - {*OVERRIDES}  # (`set` is the argument here)
    if unknown:
        raise TypeError(f"load() got unknown overrides {sorted(unknown)}; known: "
                        f"{sorted(OVERRIDES)}")
    if isinstance(source, os.PathLike) or ("\n" not in source and Path(source).exists()):
        scene = load_scene(source)
    elif "\n" not in source and source.endswith((".yaml", ".yml")):
        raise InputError(f"{source}: no such file")
    else:
        scene = parse_scene(source, "<text>", base_dir=Path.cwd())
    if set:
        from vrsim_cli.tools.sweep import override

        scene = override(scene, _settings(set), "set")
    scene = scene.with_overrides({OVERRIDES[k]: (v, k) for k, v in overrides.items()})
    model = compile_model(scene)
    # as `vrsim run` and `vrsim validate`: bodies that start inside each other are an
    # input error here, not a blow-up later
    problems = overlap_problems(scene, model, make_state(model))
    if problems:
        raise InputError(problems)
    return model


def _settings(given) -> list[tuple[str, object]]:
    """load()'s `set`: a mapping of key paths to values, or KEY=VALUE strings."""
    if isinstance(given, str):
        given = [given]
    if isinstance(given, dict):
        return [(str(k), v) for k, v in given.items()]
    from vrsim_cli.tools.sweep import parse_assignment

    pairs = []
    for item in given:
        if not isinstance(item, str):
            raise TypeError(f"set= takes a mapping {{key path: value}} or 'KEY=VALUE' "
                            f"strings, not {type(item).__name__}")
        pairs.append(parse_assignment(item, "set"))
    return pairs


@dataclass(frozen=True, repr=False)
class Trajectory:
    """The samples of a run, as arrays over (sample, entity).

    names: (n,) entity names: the bodies in model order, then 'observer' if the scene
        has one (the entities of every output file)
    t: (k,) s
    position: (k, n, 3) m, world (scene) frame
    orientation: (k, n, 4) unit quaternion [w, x, y, z]
    velocity: (k, n, 3) m/s
    angular_velocity: (k, n, 3) rad/s, world frame
    """

    names: tuple
    t: np.ndarray
    position: np.ndarray
    orientation: np.ndarray
    velocity: np.ndarray
    angular_velocity: np.ndarray

    def __repr__(self) -> str:
        shown = ", ".join(self.names[:6]) + (", ..." if len(self.names) > 6 else "")
        span = f"t = {self.t[0]:g} to {self.t[-1]:g} s" if len(self.t) else "no samples"
        return (f"<Trajectory: {_count(len(self.t), 'sample')}, {span}; "
                f"{_count(len(self.names), 'entity', 'entities')} ({shown})>")

    def _repr_png_(self) -> bytes | None:
        """Jupyter: the plot of `plot()`, as PNG; None without matplotlib (the repr is
        shown instead)."""
        try:
            figure = self.plot()
        except ImportError:
            return None
        import io

        import matplotlib.pyplot as plt

        buffer = io.BytesIO()
        figure.savefig(buffer, format="png")
        plt.close(figure)
        return buffer.getvalue()

    def plot(self, entities=None):
        """A matplotlib Figure: position (x solid, y dashed, z dotted) and speed over time
        of `entities` (names; default: those that move, at most 10). Needs matplotlib
        (`pip install 'vrsim-cli[plot]'`)."""
        try:
            import matplotlib
        except ImportError:
            raise ImportError("Trajectory.plot needs matplotlib: pip install "
                              "'vrsim-cli[plot]'") from None
        if "matplotlib.pyplot" not in __import__("sys").modules:
            matplotlib.use("Agg")  # no display needed; a notebook has chosen its own
        import matplotlib.pyplot as plt

        if entities is None:
            moving = [j for j in range(len(self.names)) if len(self.t) and
                      np.ptp(np.nan_to_num(self.position[:, j]), axis=0).max() > 0.0]
            picked = (moving or list(range(len(self.names))))[:10]
        else:
            picked = [self.index(n) for n in entities]
        figure, (ax_p, ax_v) = plt.subplots(2, 1, sharex=True, figsize=(7, 5), dpi=80)
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for k, j in enumerate(picked):
            c = colors[k % len(colors)]
            for axis, style in zip(range(3), ("-", "--", ":")):
                ax_p.plot(self.t, self.position[:, j, axis], style, color=c,
                          label=self.names[j] if axis == 0 else None)
            ax_v.plot(self.t, np.linalg.norm(self.velocity[:, j], axis=1), color=c)
        ax_p.set_ylabel("position m\n(x solid, y dashed, z dotted)")
        ax_v.set_ylabel("speed m/s")
        ax_v.set_xlabel("t s")
        for ax in (ax_p, ax_v):
            ax.grid(True, alpha=0.3)
        if picked:
            ax_p.legend(fontsize=8, loc="best")
        figure.tight_layout()
        return figure

    def index(self, name: str) -> int:
        """The entity axis index of `name`."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no entity '{name}' (entities: {', '.join(self.names)})") from None

    def to_dataframe(self):
        """A pandas DataFrame in the CSV output's long format: one row per entity per
        sample, columns t, entity, px, py, pz, qw, qx, qy, qz, vx, vy, vz, wx, wy, wz.
        Needs pandas (`pip install 'vrsim-cli[pandas]'`)."""
        try:
            import pandas as pd
        except ImportError:
            raise ImportError("Trajectory.to_dataframe needs pandas: pip install "
                              "'vrsim-cli[pandas]'") from None
        k, n = len(self.t), len(self.names)
        numbers = np.concatenate([self.position, self.orientation, self.velocity,
                                  self.angular_velocity], axis=2).reshape(k * n, 13)
        frame = pd.DataFrame(numbers, columns=list(CSV_COLUMNS[2:]))
        frame.insert(0, "entity", np.tile(np.array(self.names, dtype=object), k))
        frame.insert(0, "t", np.repeat(self.t, n))
        return frame

    @classmethod
    def from_states(cls, model: Model, states: list[State]) -> "Trajectory":
        rows = np.stack([entity_arrays(model, s) for s in states]) if states else \
            np.zeros((0, len(entity_names(model)), 13))
        return cls(entity_names(model), np.array([s.t for s in states], dtype=float),
                   rows[..., 0:3], rows[..., 3:7], rows[..., 7:10], rows[..., 10:13])


def read_trajectory(path: str | os.PathLike) -> Trajectory:
    """A trajectory file (MCAP, CSV, CSV.GZ, TUM folder) as a Trajectory. Entities must
    share their sample times (true of vrsim's files); columns a format lacks are NaN."""
    from vrsim_cli.tools.trajectory import read_trajectory as read

    traj = read(path)
    names = tuple(traj.tracks)
    times = traj.times
    k, n = len(times), len(names)
    arrays = {f: np.full((k, n, w), np.nan) for f, w in (("pos", 3), ("quat", 4), ("vel", 3),
                                                        ("angvel", 3))}
    for j, name in enumerate(names):
        track = traj.tracks[name]
        where = np.searchsorted(times, track.t)
        for f in arrays:
            arrays[f][where, j] = getattr(track, f)
    return Trajectory(names, times, arrays["pos"], arrays["quat"], arrays["vel"],
                      arrays["angvel"])


class _Collect:
    """The loop's writer: keeps each sampled state once."""

    def __init__(self):
        self.states: list[State] = []

    def write(self, state: State) -> None:
        if not self.states or self.states[-1].step != state.step:
            self.states.append(state)


class Simulation:
    """A run of `model` that you advance yourself.

    `state` is the current State, readable and writable (`set_state` changes some arrays);
    `step(n)` advances n loop frames (1 / frame_rate each); `apply_force` and
    `apply_impulse` push bodies between steps; `reset()` goes back to t = 0; iterating
    yields the State of every output sample (at `output.rate`) from the start to the end
    of the run, the same samples a file output holds; `run()` goes to the end and returns
    the Trajectory of all samples since the start.

    User input enters at one point, between loop frames (as MuJoCo's between mj_step1 and
    mj_step2): a new state or an impulse replaces the state the next frame starts from;
    held forces are extra constant force rows of the model the loop runs.
    """

    def __init__(self, model: Model, state: State | None = None):
        self.model = model
        self._state = make_state(model) if state is None else state
        self.samples: list[State] = []  # every output sample so far
        self.result: RunResult | None = None
        self.started = False  # the loop has set up the first state (see loop.run resume)
        self._applied: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # body: (F, tau)
        self._driven: Model | None = None  # model + the applied forces (built on demand)

    def __repr__(self) -> str:
        return (f"<Simulation {self.model.name!r}: t = {self.t:g} of "
                f"{self.model.duration:g} s, {_count(self.model.n_body, 'body', 'bodies')}"
                f"{', done' if self.done else ''}>")

    # ------------------------------------------------------------------ state

    @property
    def state(self) -> State:
        """The current State. Assign a State (e.g. `sim.state.replace(body_vel=v)`, or
        one saved earlier from this simulation) to continue from it; see `set_state`."""
        return self._state

    @state.setter
    def state(self, new: State) -> None:
        self._set(new)

    @property
    def t(self) -> float:
        """s, the simulated time of `state`."""
        return float(self._state.t)

    @property
    def done(self) -> bool:
        return self._state.step >= self.model.n_steps

    def set_state(self, position=None, orientation=None, velocity=None,
                  angular_velocity=None) -> State:
        """Replace arrays of the current state, over all bodies (model order): position
        (n_body, 3) m (centres of mass), orientation (n_body, 4) unit quaternions
        [w, x, y, z], velocity (n_body, 3) m/s, angular_velocity (n_body, 3) rad/s
        (world frame). 2D scenes take (n_body, 2) positions and velocities too. Only
        dynamic bodies may change; the run goes on from the new state at the same time.
        Returns the new state."""
        given = {"body_pos": position, "body_quat": orientation, "body_vel": velocity,
                 "body_angvel": angular_velocity}
        changes = {k: _plane_pad(self.model, k, v) for k, v in given.items() if v is not None}
        self._set(self._state.replace(**changes))
        return self._state

    def _set(self, new: State) -> None:
        self._state = self._checked(new)
        if self.samples and self.samples[-1].step > self._state.step:  # went back
            self.samples = [s for s in self.samples if s.step <= self._state.step]
        if self._state.step == 0:
            # back at the start: the loop sets it up as a run's first state (kinematic
            # poses, the observer on its body); doing that twice changes nothing
            self.started = False

    def _checked(self, new: State) -> State:
        """`new` validated (shapes, finite values, unit quaternions, bodies that may
        change, a frame boundary), with the rotation state the dynamics integrates (R and
        L) made to follow its orientations and angular velocities."""
        model, now = self.model, self._state
        if not isinstance(new, State):
            raise TypeError(f"a Simulation's state is a State (sim.state.replace(...) or "
                            f"sim.set_state(...)), not {type(new).__name__}")
        n = model.n_body
        arrays = {}
        for name, width in (("body_pos", 3), ("body_vel", 3), ("body_quat", 4),
                            ("body_angvel", 3)):
            value = np.array(getattr(new, name), dtype=float)  # a copy: ours from here on
            if value.shape != (n, width):
                raise ValueError(f"{name} must have shape ({n}, {width}) (bodies in model "
                                 f"order: {_names(model)}), not {value.shape}")
            bad = ~np.isfinite(value).all(axis=1)
            if bad.any():
                raise ValueError(f"{name} of body '{model.body_name[int(np.argmax(bad))]}' "
                                 f"is not finite: {value[int(np.argmax(bad))].tolist()}")
            arrays[name] = value
        q = arrays["body_quat"]
        norm2 = np.einsum("ij,ij->i", q, q)
        if (np.abs(norm2 - 1.0) > QUAT_TOLERANCE).any():
            i = int(np.argmax(np.abs(norm2 - 1.0)))
            raise ValueError(f"body_quat of body '{model.body_name[i]}' is not a unit "
                             f"quaternion (|q| = {np.sqrt(norm2[i]):.9g}); [w, x, y, z] with "
                             f"w^2 + x^2 + y^2 + z^2 = 1")
        off = np.abs(norm2 - 1.0) > UNIT_TOLERANCE  # the loop's check: normalise those
        q[off] /= np.sqrt(norm2[off])[:, None]
        if model.dimension == 2:
            tilted = (np.abs(arrays["body_pos"][:, 2] - model.body_pos0[:, 2]) > 0) | \
                (np.abs(arrays["body_vel"][:, 2]) > 0) | \
                (np.abs(arrays["body_angvel"][:, :2]) > 0).any(axis=1) | \
                (np.abs(q[:, 1:3]) > 0).any(axis=1)
            if tilted.any():
                raise ValueError(f"body '{model.body_name[int(np.argmax(tilted))]}' leaves "
                                 f"the plane of a 2D scene: z position, z velocity, x and y "
                                 f"angular velocity and tilts must stay as they are")
        step = int(new.step)
        if not 0 <= step <= model.n_steps or (step % model.steps_per_frame and
                                              step != model.n_steps):
            raise ValueError(f"state.step {step} is not a loop frame of this run "
                             f"(multiples of {model.steps_per_frame} up to {model.n_steps})")
        same = step == now.step
        if same:  # bodies whose motion the scene prescribes keep it
            fixed = model.body_type != BODY_DYNAMIC
            fixed |= model.body_emit_step > step  # waiting at its nozzle
            for name, value in arrays.items():
                moved = fixed & (value != getattr(now, name)).any(axis=1)
                if moved.any():
                    i = int(np.argmax(moved))
                    why = ("is waiting to be emitted" if model.body_emit_step[i] > step else
                           f"is {_TYPE_NAMES[int(model.body_type[i])]}: the scene "
                           f"prescribes its motion")
                    raise ValueError(f"{name} of body '{model.body_name[i]}' cannot change: "
                                     f"it {why}")
        new = new.replace(step=step, t=step * model.dt, **arrays)
        rigid = model.rigid
        if rigid is not None and rigid.n_rot:
            idx = rigid.rot_index
            if same:  # rows that changed follow; the others keep R and L bit for bit
                turned = (arrays["body_quat"][idx] != now.body_quat[idx]).any(axis=1)
                spun = turned | (arrays["body_angvel"][idx] != now.body_angvel[idx]).any(axis=1)
                R, L = np.array(now.rot_matrix), np.array(now.rot_angmom)
            elif new.rot_matrix is not None and new.rot_angmom is not None:
                turned = spun = np.zeros(len(idx), dtype=bool)  # a state of this run
                R, L = np.array(new.rot_matrix), np.array(new.rot_angmom)
            else:
                turned = spun = np.ones(len(idx), dtype=bool)
                R, L = np.zeros((len(idx), 3, 3)), np.zeros((len(idx), 3))
            # as make_state: R from the quaternion, L = R I R^T omega (model/rigid.py)
            R_q = quat_to_matrix(arrays["body_quat"][idx])
            R[turned] = R_q[turned]
            L_w = np.einsum("rij,rjk,rlk,rl->ri", R, rigid.rot_inertia, R,
                            arrays["body_angvel"][idx])
            L_w[rigid.rot_kinematic] = 0.0
            L[spun] = L_w[spun]
            new = new.replace(rot_matrix=R, rot_angmom=L)
        changed = not same or any((value != getattr(now, name)).any()
                                  for name, value in arrays.items())
        if not changed or (not same and new.rot_energy0 is not None):
            return new  # nothing new, or a state of this run with its own baseline
        return self._rebased(new)

    def _rebased(self, new: State) -> State:
        """`new` with the energy guard's baseline at its own energy: a state set by hand
        (an impulse, a push) changes the energy the guard watches."""
        rigid = self.model.rigid
        if rigid is None or not rigid.energy_guard or rigid.energy0_body is None:
            return new
        from vrsim_cli.stages.dynamics.motion import energy

        return new.replace(rot_energy0=energy(self.model, new)[0])

    # ------------------------------------------------------------------ pushes

    def _body(self, body) -> int:
        """The index of `body` (a name or an index), which must be dynamic and present."""
        model = self.model
        if isinstance(body, str):
            try:
                i = model.body_name.index(body)
            except ValueError:
                from vrsim_cli.errors import did_you_mean

                hint = did_you_mean(body, list(model.body_name))
                raise KeyError(f"no body '{body}'" + (f"; {hint}" if hint else
                                                      f" (bodies: {_names(model)})")) from None
        elif isinstance(body, (int, np.integer)) and -model.n_body <= body < model.n_body:
            i = int(body) % model.n_body
        else:
            raise KeyError(f"no body {body!r}: give a name ({_names(model)}) or an index")
        if model.body_type[i] != BODY_DYNAMIC:
            raise ValueError(f"body '{model.body_name[i]}' is "
                             f"{_TYPE_NAMES[int(model.body_type[i])]}: only dynamic bodies "
                             f"take forces and impulses")
        if model.body_emit_step[i] > self._state.step:
            raise ValueError(f"body '{model.body_name[i]}' is not emitted yet")
        return i

    def _vector(self, value, what: str, unit: str) -> np.ndarray:
        v = np.array(value, dtype=float).reshape(-1)
        if v.shape == (2,) and self.model.dimension == 2:
            v = np.append(v, 0.0)
        if v.shape != (3,):
            raise ValueError(f"{what} must be 3 numbers ({unit}; 2 in a 2D scene), "
                             f"not {np.shape(value)}")
        if not np.isfinite(v).all():
            raise ValueError(f"{what} must be finite, not {v.tolist()}")
        if self.model.dimension == 2 and v[2] != 0.0 and what != "point":
            raise ValueError(f"{what} of a 2D scene has no z component, not {v[2]:g}")
        return v

    def _moment(self, i: int, vector: np.ndarray, point, what: str) -> np.ndarray:
        """(point - centre of mass) x vector, world frame; zero without a point. A body
        that does not rotate (a point mass) refuses a moment."""
        if point is None:
            return np.zeros(3)
        arm = self._vector(point, "point", "m, world frame") - self._state.body_pos[i]
        if self.model.dimension == 2:
            arm[2] = 0.0
        moment = np.cross(arm, vector)
        rotates = _slot(self.model, i) >= 0
        if not rotates and np.abs(moment).max() > 0.0:
            raise ValueError(f"body '{self.model.body_name[i]}' does not rotate (a point "
                             f"mass: no shape, particles or inertia), so a {what} off its "
                             f"centre of mass cannot turn it; leave out point")
        return moment

    def apply_impulse(self, body, impulse, point=None) -> State:
        """Give `body` (a name or index) the impulse J (3,) N s, world frame, at `point`
        (3,) m, world frame (default: its centre of mass), now: v += J / m and
        L += (point - centre of mass) x J, so omega changes by I^-1 (r x J) with I the
        world inertia. Returns the new state; the run goes on from it."""
        i = self._body(body)
        J = self._vector(impulse, "impulse", "N s, world frame")
        moment = self._moment(i, J, point, "impulse")
        s = self._state
        vel = s.body_vel.copy()
        vel[i] += J * self.model.body_inv_mass[i]
        changes = {"body_vel": vel}
        rigid = self.model.rigid
        if _slot(self.model, i) >= 0:
            k = _slot(self.model, i)
            L = s.rot_angmom.copy()
            L[k] += moment
            R = s.rot_matrix[k]
            angvel = s.body_angvel.copy()
            angvel[i] = R @ rigid.rot_inv_inertia[k] @ R.T @ L[k]  # omega = I_world^-1 L
            changes.update(rot_angmom=L, body_angvel=angvel)
        self._state = self._rebased(s.replace(**changes))
        return self._state

    def apply_force(self, body, force, point=None) -> None:
        """Push `body` (a name or index) with the force F (3,) N, world frame, at `point`
        (3,) m, world frame (default: its centre of mass), from now on: it is held, the
        same world force and torque (point - centre of mass now) x F at every step, until
        you call apply_force for that body again (it replaces it), with `None` (removes
        it) or `clear_forces()`, as MuJoCo's xfrc_applied. For one frame only: apply,
        step(), clear. The scene's own forces act as well."""
        i = self._body(body)
        if force is None:
            self._applied.pop(i, None)
        else:
            F = self._vector(force, "force", "N, world frame")
            self._applied[i] = (F, self._moment(i, F, point, "force"))
        self._forces_changed()

    def clear_forces(self) -> None:
        """Remove every force given by apply_force."""
        self._applied.clear()
        self._forces_changed()

    @property
    def applied_forces(self) -> dict:
        """{body name: (force (3,) N, torque (3,) N m)}, world frame: the held forces."""
        return {self.model.body_name[i]: (F.copy(), tau.copy())
                for i, (F, tau) in self._applied.items()}

    def _forces_changed(self) -> None:
        self._driven = None
        if not self._applied:  # the scene's energy guard watches again, from here
            self._state = self._rebased(self._state)

    def _running_model(self) -> Model:
        """The model the loop runs: the scene's, plus the held forces as constant force
        (and torque) rows acting from t = 0 on; built once per change of the forces."""
        if not self._applied:
            return self.model
        if self._driven is None:
            self._driven = _with_forces(self.model, self._applied)
        return self._driven

    # ------------------------------------------------------------------ running

    def reset(self) -> State:
        """Back to t = 0: the scene's initial state (bit for bit what `simulate` starts
        from), no samples, no held forces. Returns the state."""
        self._state = make_state(self.model)
        self.samples = []
        self.result = None
        self.started = False
        self._applied.clear()
        self._driven = None
        return self._state

    def step(self, frames: int = 1) -> State:
        """Advance `frames` loop frames (fewer at the end of the run); returns the state.
        Raises `vrsim_cli.errors.SimulationError` on a numerical blow-up (the samples
        up to the last good state are kept)."""
        if frames < 0:
            raise ValueError("frames must be >= 0")
        if frames == 0 or self.done:
            return self._state
        done = [0]

        def count(_state):
            done[0] += 1

        collect = _Collect()
        failed = True
        try:
            self.result = run_loop(self._running_model(), self._state, collect,
                                   should_stop=lambda: done[0] >= frames, on_frame=count,
                                   resume=self.started)
            self.started = True
            self._state = self.result.state
            failed = False
        finally:
            # The loop samples the state it starts and stops at; keep only the samples a
            # single run would write: the output grid, the end, and on a blow-up the last
            # good state. Each once.
            every, end = self.model.output.every_steps, self.model.n_steps
            last = collect.states[-1].step if collect.states else None
            for s in collect.states:
                on_grid = s.step % every == 0 or s.step == end or (failed and s.step == last)
                if on_grid and (not self.samples or s.step > self.samples[-1].step):
                    self.samples.append(s)
        return self._state

    def __iter__(self):
        """Yield every output sample, from the first (t = 0) to the end of the run."""
        yielded = 0
        if not self.samples:
            self._sample_start()
        while True:
            while yielded < len(self.samples):
                yield self.samples[yielded]
                yielded += 1
            if self.done:
                return
            self.step(1)

    def _sample_start(self) -> None:
        """The first sample (the loop writes it when it starts; here before any step)."""
        collect = _Collect()
        run_loop(self._running_model(), self._state, collect, should_stop=lambda: True,
                 resume=self.started)
        self.samples.extend(collect.states[:1])

    def run(self) -> Trajectory:
        """Run to the end; the Trajectory of every output sample since the start."""
        self.step(self.model.n_frames)
        return self.trajectory()

    def trajectory(self) -> Trajectory:
        """The Trajectory of the output samples so far."""
        return Trajectory.from_states(self.model, self.samples)

    # ------------------------------------------------------------------ pictures

    def render(self, width: int = 640, height: int = 480, camera=None) -> np.ndarray:
        """The image of the current state, (height, width, 3) uint8 RGB, as `vrsim run
        --frames` draws it (the scene's camera, else the observer's, else the default
        camera over the samples so far). Raises `vrsim_cli.render.RenderUnavailable`
        without OSMesa or PyOpenGL (docs/rendering.md)."""
        from vrsim_cli.model.frames import FramesSpec
        from vrsim_cli.render import open_renderer, time_label
        from vrsim_cli.writers.frames import pictures

        spec = self.model.frames
        camera = camera if camera is not None else getattr(spec, "camera", None)
        # the samples so far and the state now: the default camera frames their motion
        states = [s for s in self.samples if s.step < self._state.step] + [self._state]
        renderer = open_renderer(self.model, width, height, camera)
        try:
            spec = FramesSpec(Path("."), 1, width, height, camera)
            (image,) = pictures(self.model, states, spec, renderer, time_label,
                                last_only=True)
            return image
        finally:
            renderer.close()

    def _repr_png_(self) -> bytes | None:
        """Jupyter: the current frame; None (the text repr is shown) without OSMesa."""
        from vrsim_cli.render import RenderUnavailable
        from vrsim_cli.writers.frames import encode_png

        try:
            return encode_png(self.render())
        except RenderUnavailable:
            return None

    def _repr_html_(self) -> str:
        """Jupyter: the repr over the current frame, or the reason there is no frame."""
        import base64
        import html

        from vrsim_cli.render import RenderUnavailable
        from vrsim_cli.writers.frames import encode_png

        head = f"<p><code>{html.escape(repr(self))}</code></p>"
        try:
            png = encode_png(self.render())
        except RenderUnavailable as exc:
            return head + f"<p><i>no picture: {html.escape(str(exc))}</i></p>"
        return head + ('<img src="data:image/png;base64,'
                       + base64.b64encode(png).decode("ascii") + '"/>')


QUAT_TOLERANCE = 1e-6  # |q|^2 - 1 a user's quaternion may be off by; it is normalised
_TYPE_NAMES = {BODY_DYNAMIC: "dynamic", BODY_KINEMATIC: "kinematic", BODY_STATIC: "static"}


def _count(n: int, one: str, many: str | None = None) -> str:
    return f"{n} {one if n == 1 else (many or one + 's')}"


def _names(model: Model) -> str:
    names = list(model.body_name)
    return ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")


def _plane_pad(model: Model, name: str, value) -> np.ndarray:
    """2D scenes: (n, 2) positions and velocities are the plane's; z as it is."""
    value = np.asarray(value, dtype=float)
    if model.dimension == 2 and name in ("body_pos", "body_vel") and value.ndim == 2 \
            and value.shape[1] == 2:
        z = model.body_pos0[:, 2:3] if name == "body_pos" else np.zeros((len(value), 1))
        value = np.concatenate([value, z[:len(value)]], axis=1)
    return value


def _slot(model: Model, i: int) -> int:
    """Body i's row in the rotating bodies' arrays, -1 when it does not rotate (a point
    mass, an emitted particle: the rigid arrays cover the scene's bodies only)."""
    rigid = model.rigid
    if rigid is None or i >= len(rigid.rot_slot):
        return -1
    return int(rigid.rot_slot[i])


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.flags.writeable = False
    return a


def _with_forces(model: Model, applied: dict) -> Model:
    """`model` with the held forces of a Simulation as extra rows: a world force at the
    centre of mass acting from t = 0 on (and a world torque for a force off the centre of
    a rotating body). The energy guard is off while they act: they inject energy."""
    import dataclasses

    bodies = sorted(applied)
    F = np.array([applied[b][0] for b in bodies]).reshape(-1, 3)
    k = len(bodies)
    zeros, forever = np.zeros(k), np.full(k, np.inf)
    changes = dict(
        force_body=_frozen(np.concatenate([model.force_body, np.array(bodies, np.int64)])),
        force_vec=_frozen(np.concatenate([model.force_vec, F])),
        force_start=_frozen(np.concatenate([model.force_start, zeros])),
        force_end=_frozen(np.concatenate([model.force_end, forever])))
    rigid = model.rigid
    if rigid is not None:
        turned = [b for b in bodies if _slot(model, b) >= 0 and applied[b][1].any()]
        T = np.array([applied[b][1] for b in turned]).reshape(-1, 3)
        m = len(turned)
        no = np.zeros(k, dtype=bool)
        changes["rigid"] = dataclasses.replace(
            rigid,
            force_vec=_frozen(np.concatenate([rigid.force_vec, F])),
            force_point=_frozen(np.concatenate([rigid.force_point, np.zeros((k, 3))])),
            force_has_point=_frozen(np.concatenate([rigid.force_has_point, no])),
            force_in_body=_frozen(np.concatenate([rigid.force_in_body, no])),
            torque_body=_frozen(np.concatenate([rigid.torque_body,
                                                np.array(turned, np.int64)])),
            torque_vec=_frozen(np.concatenate([rigid.torque_vec, T])),
            torque_start=_frozen(np.concatenate([rigid.torque_start, np.zeros(m)])),
            torque_end=_frozen(np.concatenate([rigid.torque_end, np.full(m, np.inf)])),
            torque_in_body=_frozen(np.concatenate([rigid.torque_in_body,
                                                   np.zeros(m, dtype=bool)])),
            energy_guard=False)
    return dataclasses.replace(model, **changes)


def simulate(model: Model | str | os.PathLike, **overrides) -> Simulation:
    """A Simulation of `model` (a Model, or what `load` takes, with its overrides)."""
    if not isinstance(model, Model):
        model = load(model, **overrides)
    elif overrides:
        raise TypeError("overrides apply to a scene, not to a compiled Model: "
                        "vrsim_cli.simulate(path_or_text, duration=...)")
    return Simulation(model)
