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
from vrsim_cli.loop import RunResult, overlap_problems, run as run_loop
from vrsim_cli.model.model import Model, compile_model
from vrsim_cli.model.state import State, make_state, state_hash
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.writers.entities import CSV_COLUMNS, entity_arrays, entity_names

__all__ = ["Model", "Simulation", "State", "Trajectory", "load", "simulate", "state_hash",
           "read_trajectory"]

# Scene keys that load() and simulate() accept as keyword overrides, as on the command line.
OVERRIDES = {"duration": ("duration",), "dt": ("dt",), "integrator": ("integrator",),
             "tolerance": ("tolerance",)}


def load(source: str | os.PathLike, **overrides) -> Model:
    """The compiled Model of a scene: `source` is a path (str or PathLike) to a scene file,
    or the YAML text itself (a str with a newline, or one that names no file).

    Keyword overrides as on the command line: duration (s), dt (s), integrator,
    tolerance. Problems raise `vrsim_cli.errors.InputError` with file:line:col, key path
    and hint (its `.problems`), bodies that start inside each other included. A scene's `output` keys are kept as settings only: the
    API writes no files.
    """
    unknown = set(overrides) - set(OVERRIDES)
    if unknown:
        raise TypeError(f"load() got unknown overrides {sorted(unknown)}; known: "
                        f"{sorted(OVERRIDES)}")
    if isinstance(source, os.PathLike) or ("\n" not in source and Path(source).exists()):
        scene = load_scene(source)
    elif "\n" not in source and source.endswith((".yaml", ".yml")):
        raise InputError(f"{source}: no such file")
    else:
        scene = parse_scene(source, "<text>", base_dir=Path.cwd())
    scene = scene.with_overrides({OVERRIDES[k]: (v, k) for k, v in overrides.items()})
    model = compile_model(scene)
    # as `vrsim run` and `vrsim validate`: bodies that start inside each other are an
    # input error here, not a blow-up later
    problems = overlap_problems(scene, model, make_state(model))
    if problems:
        raise InputError(problems)
    return model


@dataclass(frozen=True)
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

    `state` is the current State; `step(n)` advances n loop frames (1 / frame_rate each);
    iterating yields the State of every output sample (at `output.rate`) from the start
    to the end of the run, the same samples a file output holds; `run()` goes to the end
    and returns the Trajectory of all samples since the start.
    """

    def __init__(self, model: Model, state: State | None = None):
        self.model = model
        self.state = make_state(model) if state is None else state
        self.samples: list[State] = []  # every output sample so far
        self.result: RunResult | None = None
        self.started = False  # the loop has set up the first state (see loop.run resume)

    @property
    def t(self) -> float:
        """s, the simulated time of `state`."""
        return float(self.state.t)

    @property
    def done(self) -> bool:
        return self.state.step >= self.model.n_steps

    def step(self, frames: int = 1) -> State:
        """Advance `frames` loop frames (fewer at the end of the run); returns the state.
        Raises `vrsim_cli.errors.SimulationError` on a numerical blow-up (the samples
        up to the last good state are kept)."""
        if frames < 0:
            raise ValueError("frames must be >= 0")
        if frames == 0 or self.done:
            return self.state
        done = [0]

        def count(_state):
            done[0] += 1

        collect = _Collect()
        failed = True
        try:
            self.result = run_loop(self.model, self.state, collect,
                                   should_stop=lambda: done[0] >= frames, on_frame=count,
                                   resume=self.started)
            self.started = True
            self.state = self.result.state
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
        return self.state

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
        run_loop(self.model, self.state, collect, should_stop=lambda: True)
        self.samples.extend(collect.states[:1])

    def run(self) -> Trajectory:
        """Run to the end; the Trajectory of every output sample since the start."""
        self.step(self.model.n_frames)
        return self.trajectory()

    def trajectory(self) -> Trajectory:
        """The Trajectory of the output samples so far."""
        return Trajectory.from_states(self.model, self.samples)


def simulate(model: Model | str | os.PathLike, **overrides) -> Simulation:
    """A Simulation of `model` (a Model, or what `load` takes, with its overrides)."""
    if not isinstance(model, Model):
        model = load(model, **overrides)
    elif overrides:
        raise TypeError("overrides apply to a scene, not to a compiled Model: "
                        "vrsim_cli.simulate(path_or_text, duration=...)")
    return Simulation(model)
