"""One run of a compiled scene inside a worker: the unit of work of `vrsim sweep` and
`vrsim regress`, the same whichever executor runs it (tools/executors.py).

Layer 7. A `Job` carries the model compiled once by the parent, pickled (with the
read-only flags of its arrays, which pickling drops: `pack_model`): a worker never
reads scene or mesh files, never parses YAML and never compiles, so a job behaves the
same in this process, in a local worker process or on a Ray node that has nothing but
vrsim installed. (Should a model ever not pickle, the job carries the validated scene
instead and the worker compiles it, caching the model per worker; then the scene's
files must be reachable from the worker at the same paths.)

A worker runs jobs one after another and keeps its imports (and any compiled kernels
warmed up by the first run) between them: `execute` has no state but two small caches,
and every job starts from a fresh copy of its model, so results never depend on which
worker ran what before.

The run goes through the public pipeline only: `compile_model` (in the parent),
`make_state`, `loop.run`. Its samples are recorded in memory (`Recorder`), at the
scene's output rate, and turned into a `tools.trajectory.Trajectory`, which
`tools.compare.compare` measures against a reference or a golden.
"""

from __future__ import annotations

import dataclasses
import math
import pickle
import time
import traceback
from collections import OrderedDict
from dataclasses import dataclass, field

from vrsim_cli import __version__

# What a job sends back besides its figures.
KEEP_NONE = "none"  # figures only (sweep runs)
KEEP_TRAJECTORY = "trajectory"  # the whole recorded trajectory (references)

MODEL_CACHE_SIZE = 4  # models compiled in a worker (fallback path), per worker


@dataclass(frozen=True)
class Job:
    """One run. `model`: the pickled Model; `scene`: (file, text, base_dir, data) of the
    validated variant, used only when the model did not pickle. `compare`: what to do with
    the shared object passed beside the job: "errors" (sweep: per-entity errors against a
    reference trajectory), "golden" (regress: compare within `tolerance`, a
    compare.TolerancePlan, and return the thinned CSV), or None."""

    key: str
    label: str  # for messages: scene and parameters
    model: bytes | None = None
    scene: tuple | None = None
    compare: str | None = None
    tolerance: object = None  # compare.TolerancePlan for "golden"
    keep: str = KEEP_NONE
    golden_samples: int = 21  # "golden": sample times kept in the thinned CSV
    version: str = __version__


@dataclass
class Outcome:
    """What a job sends back. status: "ok", "failed" (the simulation failed: a blow-up,
    named by body and time), "error" (anything else: a bug, a crashed worker, a version
    mismatch). Times in s; errors per entity as dicts of compare.EntityResult figures."""

    key: str
    status: str
    message: str = ""
    steps: int = 0
    dt_s: float = math.nan
    integrator: str = ""
    wall_s: float = math.nan  # the simulation loop, recording excluded
    task_s: float = math.nan  # the whole job in the worker: unpickle, run, compare
    cpu_s: float = math.nan  # CPU time of this process in the loop, recording included:
    # unlike wall time, barely changed by other work on a shared machine
    task_cpu_s: float = math.nan  # CPU time of the whole job
    state_sha256: str = ""
    entities: list = field(default_factory=list)  # [{entity, pos_err_m, ...}]
    report: dict | None = None  # "golden": compare.Report.as_dict()
    report_lines: list = field(default_factory=list)  # "golden": compare.format_report
    ok: bool | None = None  # "golden": within tolerance
    csv: str | None = None  # "golden": the thinned CSV text
    trajectory: object = None  # KEEP_TRAJECTORY: tools.trajectory.Trajectory


def crashed(job_key: str, why: str) -> Outcome:
    return Outcome(job_key, "error", why)


# ----------------------------------------------------------------------------- recording


class Recorder:
    """A writer for `loop.run` that keeps every sample in memory: t (n,) s and the entity
    rows (n, n_entity, 13) of `writers.entity_arrays`, in the CSV column order."""

    def __init__(self, model):
        from vrsim_cli.writers import entity_arrays, entity_names

        self.model = model
        self.names = entity_names(model)
        self._rows = entity_arrays
        self.t: list[float] = []
        self.samples: list = []

    def write(self, state) -> None:
        self.t.append(float(state.t))
        self.samples.append(self._rows(self.model, state))

    def trajectory(self, source: str):
        """The samples as a tools.trajectory.Trajectory (format "memory")."""
        import numpy as np

        from vrsim_cli.tools.trajectory import Track, Trajectory

        traj = Trajectory(source, "memory")
        if not self.samples:
            return traj
        t = np.asarray(self.t, dtype=float)
        data = np.stack(self.samples)  # (n, n_entity, 13)
        for i, name in enumerate(self.names):
            rows = data[:, i, :]
            traj.tracks[name] = Track(t, rows[:, 0:3], rows[:, 3:7], rows[:, 7:10],
                                      rows[:, 10:13])
        return traj

    def thinned_csv(self, keep: int) -> str:
        """The CSV `vrsim run -o X.csv` writes (same columns, same shortest round-trip
        numbers), with only `keep` evenly strided sample times, always the first and the
        last: the golden files' form."""
        from vrsim_cli.writers import CSV_COLUMNS

        lines = [",".join(CSV_COLUMNS) + "\n"]
        for i in thinned_indices(self.t, keep):
            t = repr(self.t[i])
            for name, row in zip(self.names, self.samples[i].tolist()):
                lines.append(f"{t},{name},{','.join(map(repr, row))}\n")
        return "".join(lines)


def thinned_indices(times: list[float], keep: int) -> list[int]:
    """Indices of at most `keep` evenly strided samples (by distinct time), always the
    first and the last time."""
    distinct = sorted(set(times))
    if not distinct:
        return []
    stride = max(1, math.ceil((len(distinct) - 1) / max(keep - 1, 1)))
    kept = set(distinct[::stride]) | {distinct[-1]}
    return [i for i, t in enumerate(times) if t in kept]


# ----------------------------------------------------------------------------- models


def model_arrays(value) -> list:
    """Every numpy array reachable from `value` through dataclass fields, tuples, lists
    and dict values, once each, in a fixed depth-first order (the same before pickling
    and after). Collision's fcl `cache` (filled during runs) is left out."""
    import numpy as np

    found: list = []
    seen: set = set()
    todo = [value]
    while todo:
        item = todo.pop()
        if isinstance(item, (str, int, float, bytes)) or item is None or id(item) in seen:
            continue
        seen.add(id(item))
        if isinstance(item, np.ndarray):
            found.append(item)
        elif dataclasses.is_dataclass(item) and not isinstance(item, type):
            todo.extend(getattr(item, f.name) for f in reversed(dataclasses.fields(item))
                        if f.name != "cache")
        elif isinstance(item, (tuple, list)):
            todo.extend(reversed(item))
        elif isinstance(item, dict):
            todo.extend(reversed(list(item.values())))
    return found


def pack_model(model) -> bytes | None:
    """The model pickled for a worker, with the indices (in `model_arrays` order) of its
    read-only arrays: pickling drops numpy's flag, and a worker's copy must accept and
    refuse writes exactly where the parent's does. None when something does not pickle."""
    read_only = [i for i, a in enumerate(model_arrays(model)) if not a.flags.writeable]
    try:
        return pickle.dumps((model, read_only), protocol=pickle.HIGHEST_PROTOCOL)
    except (pickle.PicklingError, TypeError, AttributeError):
        return None


def unpack_model(blob: bytes):
    """The model of `pack_model`, its read-only arrays read-only again."""
    model, read_only = pickle.loads(blob)
    arrays = model_arrays(model)
    for i in read_only:
        arrays[i].flags.writeable = False
    return model


_models: OrderedDict = OrderedDict()  # job key -> Model compiled in this worker (fallback)


def _model_of(job: Job):
    if job.model is not None:
        return unpack_model(job.model)
    cached = _models.get(job.key)
    if cached is None:
        from vrsim_cli.model.model import compile_model
        from vrsim_cli.scene.spec import Scene

        file, text, base_dir, data = job.scene
        cached = compile_model(Scene(file, base_dir, text, data))
        _models[job.key] = cached
        while len(_models) > MODEL_CACHE_SIZE:
            _models.popitem(last=False)
    # A cached model is reused as the file would be recompiled: its only mutable part,
    # the collision fcl cache, is keyed by geometry and holds no state of a run.
    return cached


# ----------------------------------------------------------------------------- running


def execute(job: Job, shared=None, should_stop=None) -> Outcome:
    """Run `job`; never raises (but KeyboardInterrupt). `shared`: the reference
    Trajectory ("errors"), the golden Trajectory ("golden"), or None. `should_stop`: polled
    once per frame (in-process runs); a run stopped by it returns status "interrupted"."""
    start, cpu_start = time.perf_counter(), time.process_time()
    if job.version != __version__:
        return Outcome(job.key, "error", f"this worker has vrsim {__version__}, the sweep "
                                         f"was planned with {job.version}: install the same "
                                         f"version on every node")
    try:
        out = _execute(job, shared, should_stop, start)
        out.task_cpu_s = time.process_time() - cpu_start
        return out
    except KeyboardInterrupt:
        raise
    except Exception as exc:  # a bug, or a missing library: report it with the run
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return Outcome(job.key, "error", f"{type(exc).__name__}: {exc} (at "
                                         f"{where.filename}:{where.lineno})",
                       task_s=time.perf_counter() - start)


def _execute(job: Job, shared, should_stop, start: float) -> Outcome:
    from vrsim_cli.errors import SimulationError
    from vrsim_cli.loop import run
    from vrsim_cli.model.state import make_state, state_hash

    model = _model_of(job)
    out = Outcome(job.key, "ok", dt_s=model.dt, integrator=model.integrator)
    recorder = Recorder(model)
    cpu = time.process_time()
    try:
        result = run(model, make_state(model), recorder, should_stop=should_stop)
    except SimulationError as exc:
        out.status, out.message = "failed", str(exc)
        out.task_s = time.perf_counter() - start
        return out
    if result.interrupted:
        out.status = "interrupted"
        return out
    out.cpu_s = time.process_time() - cpu
    out.steps = int(result.state.step)
    out.wall_s = result.wall_s - result.profile.get("output", 0.0)
    out.state_sha256 = state_hash(result.state)
    if job.compare == "errors" and shared is not None:
        out.entities = errors_against(recorder.trajectory(job.label), shared)
    elif job.compare == "golden":
        _against_golden(out, job, recorder, shared)
    if job.keep == KEEP_TRAJECTORY:
        out.trajectory = recorder.trajectory(job.label)
    out.task_s = time.perf_counter() - start
    return out


def errors_against(run, reference) -> list[dict]:
    """Per entity of `reference`, the largest errors of `run` against it over their shared
    sample times: the measures of `vrsim compare` (tools/compare.py). An entity the run
    lacks, or one without shared sample times, gets NaN errors and a note."""
    from vrsim_cli.tools.compare import TolerancePlan, compare

    report = compare(run, reference, TolerancePlan(), allow_missing_entities=True)
    rows = []
    for e in report.entities:
        rows.append({"entity": e.name, "pos_err_m": _nan_if(e, e.pos_err),
                     "angle_err_rad": _nan_if(e, e.angle_err),
                     "vel_err_m_s": _nan_if(e, e.vel_err),
                     "angvel_err_rad_s": _nan_if(e, e.angvel_err),
                     "note": e.span_mismatch or ""})
    for name in report.only_in_b:
        rows.append({"entity": name, "pos_err_m": math.nan, "angle_err_rad": math.nan,
                     "vel_err_m_s": math.nan, "angvel_err_rad_s": math.nan,
                     "note": "not in this run"})
    return rows


def _nan_if(entity, value) -> float:
    """NaN for a missing figure or an entity compared at no common time."""
    return math.nan if value is None or entity.compared == 0 else float(value)


def _against_golden(out: Outcome, job: Job, recorder: Recorder, golden) -> None:
    from vrsim_cli.tools.compare import compare, format_report

    out.csv = recorder.thinned_csv(job.golden_samples)
    if golden is None:
        return
    report = compare(recorder.trajectory(job.label), golden, job.tolerance)
    out.ok = report.ok
    out.report = report.as_dict()
    out.report_lines = format_report(report)
