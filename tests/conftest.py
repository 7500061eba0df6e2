"""Shared helpers: scene files in a temporary folder, the CLI runner, the repo's paths."""

from __future__ import annotations

import json
import os
import textwrap
from functools import lru_cache
from pathlib import Path

import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parent.parent
SCENARIOS = REPO / "scenarios"

# ----------------------------------------------------------------------------- hypothesis
# No test verdict may depend on the machine's load (issue 53: test_alias_bombs failed on
# hypothesis's 5 s deadline at load 9-11): every property test runs without a deadline,
# this profile's default; tests/test_load_independence.py checks no test sets one.
from hypothesis import settings as _hypothesis_settings  # noqa: E402

_hypothesis_settings.register_profile("vrsim", deadline=None)
_hypothesis_settings.load_profile("vrsim")

# ----------------------------------------------------------------------------- OSMesa
# Tests marked `osmesa` render real frames. On a machine without libosmesa6 they skip with
# a reason naming the package, so the README's test command passes on a fresh machine; CI
# (.ci/run) installs libosmesa6 and sets REQUIRE_OSMESA=1, which turns that skip into a
# failure, so rendering stays tested. HIDE_OSMESA=1 makes this process behave as if the
# library were missing (tests/test_render_gate.py runs pytest that way).
REQUIRE_OSMESA = "VRSIM_REQUIRE_OSMESA"
HIDE_OSMESA = "VRSIM_TEST_HIDE_OSMESA"
OSMESA_PACKAGE = "libosmesa6"


def hide_osmesa() -> None:
    """Make every ctypes load of libOSMesa fail, as on a machine without libosmesa6."""
    import ctypes

    real = ctypes.CDLL.__init__

    def no_osmesa(self, name, *args, **kwargs):
        if name and "OSMesa" in str(name):
            raise OSError(f"{name}: cannot open shared object file: No such file or directory")
        real(self, name, *args, **kwargs)

    ctypes.CDLL.__init__ = no_osmesa


if os.environ.get(HIDE_OSMESA) == "1":
    hide_osmesa()


@lru_cache(maxsize=1)
def osmesa_problem() -> str | None:
    """Why frames cannot be rendered in this process (vrsim's own probe), or None."""
    from vrsim_cli.render import _probe

    return _probe()


def osmesa_gate(problem: str | None, required: bool) -> tuple[str, str] | None:
    """What a test that renders does here: None (run it), ('skip', reason) or ('fail',
    reason). The reason names the Debian package."""
    if problem is None:
        return None
    reason = f"rendering needs OSMesa: apt-get install {OSMESA_PACKAGE} ({problem})"
    if required:
        return "fail", f"{reason}; {REQUIRE_OSMESA}=1 (CI) makes this a failure, not a skip"
    return "skip", reason


def pytest_configure(config):
    config.addinivalue_line("markers", f"osmesa: renders frames through OSMesa ("
                                       f"{OSMESA_PACKAGE}); skipped without it unless "
                                       f"{REQUIRE_OSMESA}=1")


# The files that take longest (seconds of CPU with a warm kernel cache, most first:
# simulations, subprocesses, fuzzing), run first. xdist (`--dist loadfile
# --no-loadscope-reorder`, pyproject.toml) hands out whole files in collection order as
# workers free up, so long files first leaves only short ones for the end and the workers
# finish together, rather than one running a long file alone while the other idles.
# With two workers, gw0 is handed the 1st file and gw1 the 2nd, then each the next one
# when it has at most two tests left. On a fresh machine the stepped entry's first
# compile (~170 s of a helper process) runs beside both workers' tests (`warm_up`,
# IN_BACKGROUND); the 2nd file is a long one that needs no stepped entry, so gw1 does
# not wait for it. Measured 2026-12-07 (per-file CPU of a whole run, -n 2, warm cache):
# memory 85 s, located_tunnelling 75, data_loss 56, cpu_independence 43, hull_stacks 39,
# hostile_input 35, jit_cache 35, mesh_tunnelling 32, hostile_schema 29, docs 27,
# bench 26, action_camera 25, simultaneous_impacts 24, resting_blocks 23,
# collision_narrowphase 23, foxglove_output 22, coulomb 19, mirror_symmetry 19, loop 15,
# collision_continuous 14, stepped 14; every other file 13 s or less of CPU, but
# test_sweep.py takes ~20 s of wall (Ray's and the pool's worker processes, whose CPU
# getrusage does not count): run last, it kept one worker busy 19 s after the other.
LONGEST_FIRST = ("test_memory.py", "test_data_loss.py", "test_located_tunnelling.py",
                 "test_cpu_independence.py", "test_hull_stacks.py", "test_hostile_input.py",
                 "test_jit_cache.py", "test_mesh_tunnelling.py", "test_hostile_schema.py",
                 "test_docs.py", "test_bench.py", "test_action_camera.py",
                 "test_simultaneous_impacts.py", "test_resting_blocks.py",
                 "test_collision_narrowphase.py", "test_foxglove_output.py", "test_sweep.py",
                 "test_coulomb.py", "test_mirror_symmetry.py", "test_loop.py",
                 "test_collision_continuous.py", "test_stepped.py")


def pytest_collection_modifyitems(config, items):
    """Files of LONGEST_FIRST first, in that order; the order within a file and of the
    other files is kept (a stable sort)."""
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))


def pytest_runtest_setup(item):
    if item.get_closest_marker("osmesa") is None:
        return
    gate = osmesa_gate(osmesa_problem(), os.environ.get(REQUIRE_OSMESA) == "1")
    if gate is not None:
        (pytest.fail if gate[0] == "fail" else pytest.skip)(gate[1])


@pytest.fixture(autouse=True)
def _run_in_tmp_path(tmp_path, monkeypatch):
    """Every test runs in its own temporary folder: a scene's outputs are relative to the
    current folder, so no test writes into the checkout."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def write_scene(tmp_path):
    """write_scene(text, name='scene.yaml') -> Path of a dedented scene file in tmp_path."""

    def write(text: str, name: str = "scene.yaml") -> Path:
        path = tmp_path / name
        path.write_text(textwrap.dedent(text).lstrip("\n"), encoding="utf-8")
        return path

    return write


# ----------------------------------------------------------------------------- kernels
# On a fresh machine (CI) the kernel cache is empty and compiling is the suite's largest
# cost. The xdist workers share one cache folder (jit.cache_dir(), the user's default or
# $VRSIM_CACHE_DIR, inherited by every subprocess a test starts), so a kernel compiled
# once is loaded everywhere else; but workers that start at the same moment would all
# compile the same kernels side by side. So each worker first compiles the WARM_UP units
# (every integrator's kernel and every scenario's kernels, which the suite needs anyway)
# under one lock file per unit: a unit another worker holds is skipped and then waited
# for, so each unit is compiled once per session and the workers share the work. With a
# warm cache this only loads kernels (~2 s per worker). It also keeps two processes from
# writing different entries of one kernel's cache index at the same time (numba's index
# update is a read-modify-write without a lock: one entry can be lost or, at worst, one
# data file named for two entries).


def _warm_integrator(name: str) -> None:
    from vrsim_cli.loop import prepare
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import parse_scene

    prepare(compile_model(parse_scene(
        f"vrsim: 1\nname: warm\nduration: 0.1\ndt: 0.01\nintegrator: {name}\n"
        "bodies: [{name: b, mass: 1.0}]\n")))


def _warm_scenario(path: Path) -> None:
    """0.2 s of the scenario: the kernels of its whole run (they depend on the scene's
    kinds of bodies and pairs, not on its length), as test_cpu_independence runs it."""
    from vrsim_cli.api import load
    from vrsim_cli.loop import prepare, run
    from vrsim_cli.model.state import make_state

    model = load(path, duration=0.2)
    prepare(model)
    run(model, make_state(model), None)


def _warm_stepped() -> dict | None:
    """The stepped entry (every integrator's), compiled as `vrsim run` does it (a helper
    process, which leaves the marker that later runs look for), from a process of its own
    that reports its children's peak: the helper's alone (this worker's tests run
    meanwhile, `warm_up`, and their subprocesses would count in the worker's own
    RUSAGE_CHILDREN). When no kernel of kernels/stepped.py was in the cache before,
    returns the helper's peak resident memory {"peak_mb": ...}: a first compile's, which
    test_memory holds to its limit. The other workers fill the cache meanwhile, and the
    helper loads the kernels of theirs that the stepped entry calls."""
    import subprocess
    import sys

    from vrsim_cli.kernels import jit

    folder = jit.cache_dir()
    cold = folder is not None and not jit.JIT_DISABLED and \
        not any(folder.glob("kernels*/stepped.*.nbi"))
    code = ("import resource, sys\n"
            "from vrsim_cli.loop import _compile_apart\n"
            "_compile_apart()\n"
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=1800)
    if proc.returncode != 0:
        raise RuntimeError(f"the stepped entry's warm-up failed:\n{proc.stderr}")
    if not cold:
        return None
    return {"peak_mb": int(proc.stdout.split()[-1]) / 1024}


def warm_up_units() -> list:
    """(name, callable, prerequisite) of the kernels every session compiles up front: the
    stepped entry (~150 kernels, ~170 s of CPU once: compiled here once per session
    instead of by several workers and their subprocesses at once), every integrator's
    free-flight kernel, every scenario's kernels. A scenario's prerequisite is a callable
    (`_stepped_of`): the stepped entry, if the scenario runs on it."""
    from functools import partial

    from vrsim_cli.kernels.dynamics import INTEGRATOR_CODES

    return [("stepped", _warm_stepped, None)] + \
        [(f"integrator-{name}", partial(_warm_integrator, name), None)
         for name in INTEGRATOR_CODES] + \
        [(f"scenario-{path.stem}", partial(_warm_scenario, path), partial(_stepped_of, path))
         for path in sorted(SCENARIOS.glob("*.yaml"))]


def _stepped_of(path: Path) -> str | None:
    """The warm-up unit of the stepped entry if scenario `path` runs on it (its first
    compile is that unit's work, made under `loop._compile_apart`'s lock), or None."""
    from vrsim_cli.api import load
    from vrsim_cli.loop import _stepped

    model = load(path, duration=0.2)
    return "stepped" if _stepped(model) else None


def warm_up(lock_dir: Path, worker: int, workers: int, poll_s: float = 0.2) -> list[str]:
    """Compile (or load) every unit of `warm_up_units` that no other worker of this
    session has: each worker goes down the list (worker k starts k/n of the way down, so
    the workers start on different units) taking every unit whose lock is free and whose
    prerequisite is done; a unit of IN_BACKGROUND is built by a thread while the worker
    goes on. It returns (to its tests) once every unit left is being built (by another
    worker or this one's thread) or waits for a prerequisite being built: the scenarios
    on the stepped entry are then left to the tests that run them (the entry and every
    integrator's kernel are their kernels), and a test that needs the entry meanwhile
    waits for its compile (`loop._compile_apart`'s lock) rather than compiling it too.
    Returns the names this worker took."""
    import fcntl
    import threading
    import time

    units = warm_up_units()
    start = len(units) * worker // max(workers, 1)
    units = units[start:] + units[:start]
    lock_dir.mkdir(parents=True, exist_ok=True)
    after_of = {}

    def done(name):
        return (lock_dir / f"{name}.done").exists()

    def prerequisite(name, after):
        if name not in after_of:
            after_of[name] = after() if callable(after) else after
        return after_of[name]

    def held(name):  # being built by another worker now
        with open(lock_dir / f"{name}.lock", "a+") as lock:
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            return False  # closing the file releases the probe's lock

    def finish(name, build, lock):
        try:
            record = build()
            if record is not None:  # what the unit measured (`warm_up_record`)
                (lock_dir / f"{name}.json").write_text(json.dumps(record))
            (lock_dir / f"{name}.done").touch()
        finally:
            lock.close()  # releases the unit's lock

    ran = []
    while True:
        left = [unit for unit in units if not done(unit[0])]
        if not left:
            return ran
        others = True  # every unit left is another worker's (or waits for one of theirs)
        for name, build, after in left:
            after = prerequisite(name, after)
            if after is not None and not done(after):
                others = others and held(after)
                continue
            lock = open(lock_dir / f"{name}.lock", "a+")
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                lock.close()
                continue  # another worker builds it (or this one's thread)
            if done(name):
                lock.close()
                continue
            ran.append(name)
            if name in IN_BACKGROUND:  # a helper process compiles: this worker goes on
                threading.Thread(target=finish, args=(name, build, lock),
                                 name=f"warm-up {name}").start()
            else:
                finish(name, build, lock)
                others = False  # the list is read again: more may be free now
        if others:
            return ran
        time.sleep(poll_s)


# Units whose work is a helper process (the stepped entry's first compile: ~170 s of one
# core on an empty cache): built in a thread that waits for it, while the worker goes on
# to the other units and to its tests. Waiting in the foreground, the worker held a core
# idle and the other worker often waited too (its first tests needed the entry): on an
# empty cache both cores now work from the start, and only tests that need the entry
# wait for it (`loop._compile_apart`'s lock).
IN_BACKGROUND = {"stepped"}


WARM_UP_FOLDER = "vrsim-warm-up"  # in the session's temporary folder


@pytest.fixture(scope="session", autouse=True)
def _warm_up_workers(request, tmp_path_factory):
    """In an xdist worker of a session with several: every kernel of `warm_up_units` in
    the cache before this worker's first test, the workers sharing the work (`warm_up`;
    the lock files live in the session's temporary folder, the parent of each worker's
    own). One process (`-n 0`, a pytest that a test starts) compiles only what its tests
    use. (Not the PYTEST_XDIST_* variables: a child process inherits them.)"""
    worker = getattr(request.config, "workerinput", None)
    if worker is None or worker["workercount"] < 2:
        return
    warm_up(tmp_path_factory.getbasetemp().parent / WARM_UP_FOLDER,
            int(worker["workerid"].removeprefix("gw")), worker["workercount"])


@pytest.fixture(scope="session")
def warm_up_record(request, tmp_path_factory, _warm_up_workers):
    """warm_up_record(unit) -> what that unit of this session's warm-up measured (a dict),
    or None (no warm-up in this session, or the unit measured nothing)."""
    worker = getattr(request.config, "workerinput", None)
    folder = tmp_path_factory.getbasetemp().parent / WARM_UP_FOLDER

    def record(unit: str, timeout_s: float = 900.0) -> dict | None:
        if worker is None or worker["workercount"] < 2:
            return None
        import time

        # another worker may still build it (`warm_up` returns before every unit is done)
        deadline = time.monotonic() + timeout_s
        while not (folder / f"{unit}.done").exists():
            assert time.monotonic() < deadline, f"warm-up unit {unit} never finished"
            time.sleep(0.2)
        path = folder / f"{unit}.json"
        return json.loads(path.read_text()) if path.exists() else None

    return record


def first_compile_key(unit: str) -> str | None:
    """The pytest-cache key (`first_compile_record`) of what the first compile of warm-up
    unit `unit` measured, for this very compile: the kernels' sources (the cache folder's
    src-<digest>), the CPU and Python (`jit.host_key`), Python's, numba's and llvmlite's
    versions, and every source file of vrsim_cli (the helper process's own code and
    imports). None when kernels are not cached (then every run compiles)."""
    import hashlib
    import sys

    import llvmlite
    import numba

    import vrsim_cli
    from vrsim_cli.kernels import jit

    folder = jit.cache_dir()
    if folder is None or jit.JIT_DISABLED:
        return None
    h = hashlib.sha256(repr((folder.name, jit.host_key(), sys.version, numba.__version__,
                             llvmlite.__version__)).encode())
    package = Path(vrsim_cli.__file__).resolve().parent
    for path in sorted(package.rglob("*.py")):
        h.update(str(path.relative_to(package)).encode() + b"\0" + path.read_bytes() + b"\0")
    return f"vrsim/first-compile/{unit}-{h.hexdigest()[:16]}"


@pytest.fixture(scope="session")
def first_compile_record(request, warm_up_record):
    """first_compile_record(unit) -> (what the first compile of warm-up unit `unit`
    measured: a dict, where it comes from), or None.

    A first compile happens once per kernel source: on a fresh machine (CI) this session's
    warm-up makes it and measures it (`warm_up_record`); with a warm cache no process of
    the session compiles, and a test that needs the measurement makes the compile itself
    into an empty cache of its own (test_memory: ~2 min of a worker, ~60 s of it CPU,
    every session) unless an earlier session already measured this very compile: same
    kernels, vrsim sources, CPU, Python and numba (`first_compile_key`). Such a
    measurement is kept in pytest's cache (.pytest_cache) by `save_first_compile`; a
    change to any of those keys it out, and the next session measures again."""
    cache = getattr(request.config, "cache", None)  # None under -p no:cacheprovider

    def record(unit: str) -> tuple[dict, str] | None:
        found = warm_up_record(unit)
        if found is not None:
            save_first_compile(request.config, unit, found)
            return found, "this session's warm-up"
        key = first_compile_key(unit) if cache is not None else None
        kept = cache.get(key, None) if key is not None else None
        return (kept, "an earlier session (.pytest_cache)") if kept else None

    return record


def save_first_compile(config, unit: str, measured: dict) -> None:
    """Keep what the first compile of `unit` measured for later sessions of the same code
    (`first_compile_record`)."""
    cache = getattr(config, "cache", None)
    key = first_compile_key(unit) if cache is not None else None
    if key is not None:
        cache.set(key, measured)


@pytest.fixture(scope="session")
def _kernels_compiled(tmp_path_factory, _warm_up_workers):
    """Compile (or load from the cache) every integrator's kernel once, before the first CLI
    test: on a fresh machine the first run of each integrator prints a compile notice on
    stderr, which tests that read stderr line by line must not depend on. The notice itself
    is tested in test_cli.py."""
    for name, build, _ in warm_up_units():
        if name.startswith("integrator-"):
            build()


@pytest.fixture
def runner():
    return CliRunner()


@pytest.fixture
def invoke(runner, _kernels_compiled):
    """invoke(*args) -> click Result of `vrsim ARGS` run in-process."""
    from vrsim_cli.cli import cli

    def call(*args):
        return runner.invoke(cli, [str(a) for a in args], catch_exceptions=False)

    return call


class Steps:
    """Writer that keeps every sampled state."""

    def __init__(self):
        self.states = []

    def write(self, state):
        self.states.append(state)


def simulate(text: str):
    """(model, sampled states, final state) of a scene given as YAML text."""
    from vrsim_cli.loop import run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene

    model = compile_model(parse_scene(text))
    rec = Steps()
    result = run(model, make_state(model), rec)
    return model, rec.states, result.state


def on_ground(dt, eps, mu, integrator="rk4", duration=1.0, g=9.81):
    """YAML of a scene sampled every step, up to its ground plane's entry (restitution
    eps, friction mu); the caller appends its bodies."""
    return f"""
vrsim: 1
duration: {duration!r}
frame_rate: {1 / dt!r}
dt: {dt!r}
integrator: {integrator}
gravity: [0, -{g!r}, 0]
collision: {{}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}},
     material: {{restitution: {eps}, friction: {mu}}}}}
"""


def compiled_detect(model, state):
    """(k, C, nf) of the stepped step's compiled detection (kernels.collide.detect) of
    `state`: k contacts in the rows C[:k] (columns kernels.collide.C_*), nf non-finite."""
    import numpy as np

    from vrsim_cli.kernels import collide as kc
    from vrsim_cli.stages.collision import stepped as stage
    from vrsim_cli.stages.dynamics import motion as dynamics

    tb = stage.tables(model, dynamics)
    S, RS = np.zeros_like(tb["S"]), np.zeros_like(tb["RS"])
    stage._rows(model, state, S, RS)
    k, C, _, nf = kc.detect(tb["gf"], S, 0, np.zeros(model.n_body), model.collision.tolerance,
                            False)
    return k, C, nf
