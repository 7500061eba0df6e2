"""Layer 5: the simulation loop of slide 5.0, composed from the stages.

One frame (at `frame_rate`):
  1. read sensors                       (`sensors.read`: mouse or head tracker)
  2. simulate:
     2.2 sensor-driven motion           (`navigation.step`, once per frame)
     2.1 dynamic motion                 (`dynamics.step`, `steps_per_frame` steps of `dt`)
     2.3 collision                      (`collision.step`: detection, every step, when
                                         the scene has a collision block; with a response,
                                         `collision.response.step`: impacts located in
                                         time, resting contact solved; it integrates the
                                         cut steps with `dynamics.advance`)
  3. update the scene graph and render  (`scenegraph.step`; frames: `render`)
The scene graph stage (keyframes, drives, parents) runs after every physics step and once
at t = 0, not only once per frame: physics then sees kinematic nodes where they are, and
every output sample is exact (see scenegraph.py). Scenes without animation skip it.
Trajectory samples are taken at the output rate, on the physics-step grid; the final state
is always written. Between frame boundaries the observer moves at the frame's constant
velocity (`navigation.within_frame`), so samples at any rate are consistent. Each stage is
timed into `RunResult.profile`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from vrsim_cli.stages.dynamics import motion as dynamics

from vrsim_cli.stages import navigation

from vrsim_cli.stages.dynamics import rigid

from vrsim_cli.stages import scenegraph

from vrsim_cli.errors import SimulationError
from vrsim_cli.maths.products import norm
from vrsim_cli.model.model import BODY_KINEMATIC, Model
from vrsim_cli.model.state import State
from vrsim_cli.stages import sensors

# Beyond these a run has blown up numerically, not simulated anything physical.
MAX_POSITION_M = 1e12  # about 7 times the Earth-Sun distance
MAX_SPEED_M_S = 299_792_458.0  # the speed of light


@dataclass
class RunResult:
    state: State  # the last good state
    frames: int = 0
    samples: int = 0
    wall_s: float = 0.0
    interrupted: bool = False
    missed_deadlines: int = 0  # --realtime: frames finished after their wall-clock deadline
    worst_late_s: float = 0.0
    profile: dict = field(default_factory=dict)  # stage -> seconds


def check_state(model: Model, state: State) -> None:
    """Raise SimulationError naming the first body whose state is not finite or runs away."""
    if state.observer_pos is not None:
        values = np.concatenate([state.observer_pos, state.observer_vel])
        if not np.isfinite(values).all() or np.abs(state.observer_pos).max() >= MAX_POSITION_M:
            raise SimulationError("the observer's position or velocity blew up",
                                  body="observer", t=state.t)
        d = state.observer_dir
        if d is not None and not (np.isfinite(d).all() and np.abs(d).max() > 0.0):
            raise SimulationError("the observer's view direction is not finite or is zero",
                                  body="observer", t=state.t)
        q = state.observer_quat
        if q is not None and not _unit(np.asarray(q, dtype=float).reshape(1, 4)).all():
            raise SimulationError("the observer's orientation is not a unit quaternion",
                                  body="observer", t=state.t)
    if model.n_body == 0:
        return
    _check_translation(model, state)
    if model.rigid is not None:  # rotation not finite, or energy past its bound
        rigid.check(model, state)
    check_orientations(model, state)


# body-steps per compiled call when a signal check or progress bar waits between calls:
# ~0.1 s at the slowest kernels' ~0.5 us per body-step (rk4 boxes), ~2e5 per call is
# still thousands of times the ~20 us a call costs in Python
CALL_BODY_STEPS = 200_000
UNIT_TOLERANCE = 1e-9  # |q|^2 - 1: written orientations are normalised to ~1e-15


def _unit(v: np.ndarray) -> np.ndarray:
    """(k,) True where the rows of v are finite unit vectors (NaN fails the comparison)."""
    return np.abs(np.einsum("ij,ij->i", v, v) - 1.0) <= UNIT_TOLERANCE


def check_orientations(model: Model, state: State) -> None:
    """Every written orientation is a finite unit quaternion: a sample that is not names
    the body (a bug or a blow-up that the position checks did not see)."""
    unit = _unit(state.body_quat)
    if not unit.all():
        body = int(np.argmin(unit))
        q = state.body_quat[body]
        raise SimulationError(f"orientation is not a unit quaternion (|q| = "
                              f"{float(np.sqrt(np.einsum('i,i->', q, q))):.6g}): the rotation "
                              f"blew up; try a smaller dt or another integrator",
                              body=model.body_name[body], t=state.t)


def _check_translation(model: Model, state: State) -> None:
    pos, vel = state.body_pos, state.body_vel
    if np.abs(pos).max() < MAX_POSITION_M and np.abs(vel).max() < MAX_SPEED_M_S:
        return  # NaN fails both comparisons, so this one test also catches NaN
    finite = np.isfinite(pos).all(axis=1) & np.isfinite(vel).all(axis=1)
    if not finite.all():
        body = int(np.argmin(finite))
        raise SimulationError("position or velocity is not finite (NaN or Inf): the "
                              "integration blew up; try a smaller dt or another integrator",
                              body=model.body_name[body], t=state.t)
    far = np.abs(pos).max(axis=1) >= MAX_POSITION_M
    body = int(np.argmax(far)) if far.any() else int(np.argmax(np.abs(vel).max(axis=1)))
    what = (f"moved more than {MAX_POSITION_M:.0e} m from the origin" if far.any() else
            f"moves faster than light ({np.abs(vel[body]).max():.3g} m/s along an axis)")
    if model.body_type[body] == BODY_KINEMATIC:
        why = "its prescribed motion (velocity, keyframes or drive) leaves the simulated world"
    elif in_free_flight(model, state, body):
        why = (f"it has left the scene's numeric range in free flight (a fall or throw "
               f"that nothing stops for {state.t:.6g} s, not a numerical blow-up); add a "
               f"floor or shorten the run (duration)")
    else:
        why = "the integration blew up; try a smaller dt or another integrator"
    raise SimulationError(f"{what}: {why}", body=model.body_name[body], t=state.t)


# A body is in free flight when its speed is within this factor (+ 1 m/s) of what its
# start speed, gravity and its constant forces can give it by now: a fall or a throw
# (impacts with restitution <= 1 only slow it), not a blow-up, whose speed runs away.
FREE_FLIGHT_SLACK = 1.5


def in_free_flight(model: Model, state: State, body: int) -> bool:
    """Is `body`'s speed what a free flight from its start could reach by state.t?"""
    speed = norm(state.body_vel[body])
    if not np.isfinite(speed) or model.body_inv_mass[body] <= 0.0:
        return False
    accel = norm(model.gravity)
    mine = model.force_body == body
    if mine.any():
        accel += float(np.sqrt(np.einsum("ij,ij->i", model.force_vec[mine],
                                         model.force_vec[mine])).sum()
                       * model.body_inv_mass[body])
    v0 = norm(model.body_vel0[body])
    return speed <= FREE_FLIGHT_SLACK * (v0 + accel * state.t) + 1.0


def overlap_problems(scene, model: Model, state: State) -> list:
    """Located problems (scene.problem) for bodies that start inside each other, in a
    scene whose collision response would push them apart (`collision.start_overlaps`):
    which two bodies and by how much. Empty when there are none."""
    if model.collision is None or model.response is None:
        return []
    from vrsim_cli.stages.collision.detect import start_overlaps

    if model.animation is not None and model.animation.has_motion:
        state = scenegraph.step(model, state)  # kinematic bodies where the run starts them
    n_scene = len(scene.data.get("bodies") or [])
    problems = []
    for a, b, depth in start_overlaps(model, state, n_scene)[:5]:
        name_a, name_b = (model.body_name[i] for i in (a, b))  # Problem escapes them
        problems.append(scene.problem(
            ("bodies", b, "position"),
            f"overlap at start: bodies '{name_a}' and '{name_b}' interpenetrate by "
            f"{depth:.4g} m at t = 0 (more than collision.tolerance, "
            f"{model.collision.tolerance:g} m)",
            "move them apart: collision response would push them out at whatever speed "
            "the overlap asks for"))
    return problems


def prepare(model: Model, say: Callable[..., None] | None = None) -> None:
    """Load the compiled kernels the run of `model` needs (compiling them on the first run
    after an install, which `say` then reports with the time it took), before any output
    is opened: a run's first step pays nothing for them."""
    if model.n_body == 0:
        return
    from vrsim_cli.kernels import jit

    # the process total before and after: only what this run compiled is reported (an
    # API user or a test running many scenes in one process hears it once)
    before = jit.compile_report()
    if _stepped(model):  # the stepped stage integrates the bodies itself
        from vrsim_cli.stages.collision import stepped

        if not _compile_apart():
            return  # a signal came: the caller's `held` block acts on it
        stepped.prepare(model, dynamics)
    else:
        dynamics.prepare(model)
    seconds = jit.compile_report() - before
    if seconds > 0.0 and say is not None:
        note = jit.cache_note()  # why nothing is kept, and what to do about it
        say(f"vrsim: compiled in {seconds:.1f} s "
            + (f"(not kept: {note})" if note else "(kept for the next runs)"), err=True)


# A stepped scene's first compile is made by a helper process. The stepped kernels are
# one entry whatever the scene and its integrator (kernels/stepped.py), and numba keeps
# most of what a first compile of them builds (~0.4 GB: types, IR and LLVM modules of ~150
# kernels) until the process ends: compiled in the run's own process, it added to the
# memory of the scene (the largest particle scenes validation accepts peaked at 1.1-1.3
# GB). The helper compiles the entry on a small scene into the disk cache and exits,
# before this scene's state and contacts exist; the run then loads it (the entry's
# argument types depend neither on the scene nor on its integrator).
_COMPILE_SCENE = """vrsim: 1
duration: 0.03
frame_rate: 100
dt: 0.01
integrator: verlet
collision: {impacts: stepped}
bodies:
  - {name: floor, type: static, shape: {type: plane, normal: [0, 0, 1]}}
  - {name: box, mass: 1, position: [0, 0, 0.2], shape: {type: box, size: [0.2, 0.3, 0.4]}}
  - {name: ball, mass: 1, position: [0.5, 0, 0.1], shape: {type: sphere, radius: 0.1}}
"""


# said with the compile notice: the stepped entry is the largest compile (~260 kernels,
# every integrator's step; 171 s on an idle core of this project's 2-core AMD EPYC
# machine, see docs/benchmarks.md), and a user who hears nothing for a minute takes the
# run for hung
STEPPED_COMPILE_NOTE = "stepped impacts: about three minutes the first time"


def _compile_marker():
    """The file that says the stepped entry is in the disk cache for this CPU and Python;
    None when there is no cache folder or the JIT is off."""
    from vrsim_cli.kernels import jit

    folder = jit.cache_dir()
    if folder is None or jit.JIT_DISABLED:
        return None
    return folder / f"stepped-{jit.host_key()}.compiled"


def _compile_apart() -> bool:
    """Compile the stepped entry in a helper process, unless the cache has it. False when
    a signal came meanwhile (`interrupts.pending`: the helper is killed and the caller's
    `held` block acts on the signal). If the helper fails, the run compiles
    for itself, as it would without it."""
    import os

    from vrsim_cli.kernels import jit

    marker = _compile_marker()
    if marker is None or marker.exists() or os.environ.get("VRSIM_COMPILE_APART") == "0":
        return True
    jit.announce_compile(STEPPED_COMPILE_NOTE)
    started = time.perf_counter()
    lock = _compile_lock(marker)
    if lock is False:
        return False  # a signal came while another run compiled
    try:
        if marker.exists():  # compiled by the run we waited for: load it
            jit.compiled_apart(time.perf_counter() - started)
            return True
        return _compile_helper(started)
    finally:
        if lock is not None:
            os.close(lock)  # closing the file releases its lock


def _compile_lock(marker):
    """Wait for the lock of `marker`'s compile (a file beside it, locked with flock): one
    run compiles an entry, and other runs that start meanwhile on the same cache (a sweep's
    workers, parallel test workers) wait for it instead of compiling the same ~150 kernels
    side by side (~60 s of CPU and ~0.5 GB each). Returns the open locked file descriptor;
    None when the entry appeared meanwhile or no lock can be taken (no flock: Windows; a
    cache folder that refuses the file), so the run goes on as without a lock; False when
    a signal came (`interrupts.pending`). The kernel releases the lock when its holder dies,
    however it dies: a killed run leaves no lock behind."""
    import os

    from vrsim_cli import interrupts

    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        return None
    try:
        fd = os.open(marker.with_name(f".{marker.name}.lock"), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        return None
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            pass
        except OSError:
            os.close(fd)
            return None
        if marker.exists() or interrupts.pending() is not None:
            os.close(fd)
            return None if marker.exists() else False
        time.sleep(0.05)


def _compile_helper(started: float) -> bool:
    """`_compile_apart`'s helper process, waited for; False when a signal came."""
    import os
    import subprocess
    import sys

    from vrsim_cli import interrupts
    from vrsim_cli.kernels import jit

    proc = subprocess.Popen(  # it inherits the cache folder (jit exports its base)
        [sys.executable, "-c", "import sys; from vrsim_cli.loop import compile_main; "
         "sys.exit(compile_main(int(sys.argv[1])))", str(os.getpid())],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL, start_new_session=True)  # a terminal's ^C is ours
    try:
        while True:
            try:
                proc.wait(timeout=0.05)
                break
            except subprocess.TimeoutExpired:
                if interrupts.pending() is not None:
                    return False
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    jit.compiled_apart(time.perf_counter() - started)
    return True


def compile_main(parent: int | None = None) -> int:
    """The helper process of `_compile_apart`: run the small scene, then write the marker
    (atomically). Exit 0 when the entry is compiled and cached. `parent`: the run's pid,
    as the run passed it (a run killed while Python started here is already gone when
    this reads its parent, and would not be noticed)."""
    import gc
    import os
    import sys

    gc.disable()  # as `vrsim` starts: jit then compiles with its collector thresholds
    parent = os.getppid() if parent is None else parent
    # a run killed by SIGKILL cannot kill its helper: on Linux the kernel does it when the
    # run dies (PR_SET_PDEATHSIG), elsewhere the helper notices within 0.2 s (a thread)
    watched = False
    if sys.platform.startswith("linux"):
        import ctypes
        import signal

        try:
            watched = ctypes.CDLL(None).prctl(1, int(signal.SIGKILL)) == 0  # 1: PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the run died before that
        os._exit(1)

    def orphaned():
        while os.getppid() == parent:
            time.sleep(0.2)
        os._exit(1)

    if not watched:
        import threading

        threading.Thread(target=orphaned, daemon=True).start()

    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.stages.collision import stepped

    model = compile_model(parse_scene(_COMPILE_SCENE))
    if not (_stepped(model) and stepped.batched(model, dynamics)):
        return 1
    stepped.prepare(model, dynamics)  # the run kernel, and the step kernel it calls
    # and what a scene that steps one by one (Python's pairs, a scene graph) calls from
    # Python: the step kernel again, and the energy guard from the second step on
    from vrsim_cli.model.state import make_state

    state = make_state(model)
    for _ in range(3):
        state = stepped.step(model, state, state.replace(
            step=state.step + 1, t=(state.step + 1) * model.dt), dynamics)
        check_state(model, state)
    marker = _compile_marker()
    if marker is None:
        return 1
    partial = marker.with_name(f".{marker.name}.{os.getpid()}")
    partial.write_text("compiled\n")
    os.replace(partial, marker)
    return 0


def _stepped(model: Model) -> bool:
    """Stepped impacts: collision response integrates the whole step (one compiled call:
    contacts, impulses, the integrator, positions), so the loop's free-flight step is not
    made (`collision.stepped`)."""
    return model.response is not None and model.response.impacts == "stepped"


def run(model: Model, state: State, writer=None, *, realtime: bool = False,
        should_stop: Callable[[], bool] | None = None,
        on_frame: Callable[[State], None] | None = None,
        render: Callable[[State], None] | None = None,
        resume: bool = False, coarse_callbacks: bool = False) -> RunResult:
    """Run `model` from `state` to the end (or until `should_stop()` is true at a frame).

    `writer` receives samples; it is not closed here. On a blow-up the last good state is
    written (if it was not yet) before SimulationError propagates. `render` (stage 3, e.g.
    a `writers.frames.FramesWriter`) is called with the initial state and after every
    frame; it picks the frames it draws, so this module never imports OpenGL.

    Between two points where Python has work to do (an output sample, a frame with
    sensors, rendering, pacing or callbacks) the dynamics runs as one compiled call of
    many steps (`dynamics.run`, like `mj_step(nstep)`; with stepped impacts
    `collision.stepped.run`). Stages still written in Python per step (the scene graph of
    animated scenes, collision with located impacts or with Python's mesh and hull pairs)
    make the loop step by step.

    `resume`: `state` is where an earlier run of this model stopped (at a frame, through
    `should_stop`); the set-up of a run's first state (kinematic poses at t, attaching the
    observer to its body) is skipped, so running in pieces gives the states of one run,
    bit for bit (the Python API's Simulation.step relies on it).

    `coarse_callbacks`: `should_stop` and `on_frame` need not run at every frame, only
    between compiled calls (the command line's signal check and progress bar): a scene
    with nothing else to do per frame then makes one compiled call per output sample,
    cut at whole frames every CALL_BODY_STEPS body-steps so that a signal is answered
    within a fraction of a second.
    """
    clock = time.perf_counter
    profile = {"sensors": 0.0, "navigation": 0.0, "dynamics": 0.0, "checks": 0.0,
               "output": 0.0}
    record_input = getattr(writer, "write_input", None)
    frame_dt = model.steps_per_frame * model.dt
    result = RunResult(state=state, profile=profile)
    every = model.output.every_steps
    last_written = -1
    detect = respond = None
    if model.collision is not None:  # scenes without a collision block pay nothing
        from vrsim_cli.stages import collision
        detect = collision.step
        profile["collision"] = 0.0
        if model.response is not None:  # response detects for itself (impacts, rest)
            from vrsim_cli.stages.collision import response
            detect, respond = None, response.step
    stepped = _stepped(model)
    respond_with = dynamics.advance  # response integrates cut steps with it
    batched = False
    if stepped:  # many bodies: one compiled call makes the whole step, forces included,
        from vrsim_cli.stages.collision import stepped as stepped_stage  # with the
        respond, respond_with = stepped_stage.step, dynamics  # dynamics' packed model
        # and when no step needs Python, one compiled call makes many steps (`chunk`)
        batched = stepped_stage.batched(model, dynamics)
    # keyframes, drives or parents move bodies: the scene graph stage runs
    animate = model.animation is not None and model.animation.has_motion
    per_step = animate or detect is not None or (respond is not None and not batched)
    callbacks = on_frame is not None or should_stop is not None
    # sensors are read for the observer only (`sensors.read`): without one, no frame work
    sensing = model.inputs is not None and model.observer is not None
    frame_work = (sensing or render is not None or realtime
                  or (callbacks and not coarse_callbacks))
    if animate:
        profile["scenegraph"] = 0.0
    if animate and not resume:
        t0 = clock()
        state = scenegraph.step(model, state)  # 3. the first sample is exact too
        profile["scenegraph"] += clock() - t0
        result.state = state

    def sample(s: State) -> None:
        nonlocal last_written
        if writer is not None and last_written != s.step:
            t0 = clock()
            writer.write(s)
            profile["output"] += clock() - t0
            result.samples += 1
            last_written = s.step

    def observer_at(s: State, steps_done: int) -> State:
        """s with the observer moved `steps_done` steps into the current frame."""
        if frame_end is frame_start:
            return s
        t0 = clock()
        s = navigation.within_frame(model, s, frame_start, frame_end,
                                    steps_done / model.steps_per_frame)
        profile["navigation"] += clock() - t0
        return s

    def draw(s: State) -> None:
        if render is not None:
            t0 = clock()
            render(s)
            profile["render"] += clock() - t0

    def chunk(s: State, count: int) -> State:
        """count steps of the dynamics in one compiled call, checked."""
        if batched:
            return stepped_chunk(s, count)
        t0 = clock()
        good, failure = dynamics.run(model, s, count)
        profile["dynamics"] += clock() - t0
        result.state = good
        if failure is not None:
            raise_failure(model, failure)
        check_orientations(model, good)  # the kernel checked positions and velocities
        return good

    def stepped_chunk(s: State, count: int) -> State:
        """count stepped steps in compiled calls: the states `one_step` gives, and its
        checks' errors (the kernel stops at a state that may fail them, checked here)."""
        t0 = clock()
        end = s.step + count
        try:
            while s.step < end:
                good, bad, error = stepped_stage.run(model, s, end - s.step, dynamics)
                s = result.state = good
                if error is not None:
                    raise error
                if bad is None:
                    break
                check_state(model, bad)  # raises what one_step's check would
                s = result.state = bad  # the compiled test's margin: a good state after all
        finally:
            profile["collision"] += clock() - t0
        return s

    def one_step(s: State) -> State:
        t0 = clock()
        if stepped:  # 2.1 happens in 2.3: only the clock moves here
            new = s.replace(step=s.step + 1, t=(s.step + 1) * model.dt)
        else:
            new = dynamics.step(model, s)  # 2.1 dynamic motion
        t1 = clock()
        profile["dynamics"] += t1 - t0
        if animate:  # 2.1 kinematic motion and 3. scene graph at the new time
            new = scenegraph.step(model, new, tuple(a[k_in_frame] for a in motion))
            t2 = clock()
            profile["scenegraph"] += t2 - t1
            t1 = t2
        if respond is not None:  # 2.3 collision: detection and response
            new = respond(model, s, new, respond_with)
            t2 = clock()
            profile["collision"] += t2 - t1
            t1 = t2
        check_state(model, new)
        profile["checks"] += clock() - t1
        if detect is not None:  # 2.3 collision: contacts (detection only)
            t1 = clock()
            new = new.replace(contacts=detect(model, s, new))
            profile["collision"] += clock() - t1
        result.state = new
        return new

    if render is not None:
        profile["render"] = 0.0
    if model.observer is not None and model.observer.mode == "attached" and not resume:
        state = result.state = navigation.attach(model, state)  # on its body from t = 0
    frame_start = frame_end = state
    motion = ()
    k_in_frame = 0
    sample(state)
    draw(state)
    start = clock()
    # Overflow and NaN are detected by the checks, which name the body and time; numpy's
    # own warnings would only add noise.
    try:
        with np.errstate(all="ignore"):
            first_frame = state.step // model.steps_per_frame
            if not per_step and not frame_work:  # nothing to do between samples: one
                # compiled call per output sample (whole frames of at most CALL_BODY_STEPS
                # when someone waits for callbacks)
                cap = model.n_steps if not callbacks else model.steps_per_frame * max(
                    1, CALL_BODY_STEPS // (model.steps_per_frame * max(1, model.n_body)))
                while state.step < model.n_steps:
                    if should_stop is not None and should_stop():
                        result.interrupted = True
                        break
                    to_sample = every - state.step % every if writer is not None else \
                        model.n_steps
                    state = chunk(state, min(to_sample, model.n_steps - state.step, cap))
                    if state.step % every == 0:
                        sample(state)
                    if on_frame is not None:
                        on_frame(state)
                result.frames = -(-state.step // model.steps_per_frame) - first_frame
            for frame in range(state.step // model.steps_per_frame, model.n_frames):
                if state.step >= model.n_steps or result.interrupted:
                    break
                if should_stop is not None and should_stop():
                    result.interrupted = True
                    break
                t0 = clock()
                inputs = sensors.read(model, frame, state.t)  # 1. read sensors
                if inputs is not None and record_input is not None:
                    record_input(inputs)
                t1 = clock()
                profile["sensors"] += t1 - t0
                frame_start = frame_end = state
                if inputs is not None:  # 2.2 sensor-driven motion: the observer, once per frame
                    frame_end = navigation.step(model, state, inputs, frame_dt)
                    profile["navigation"] += clock() - t1
                steps = min(model.steps_per_frame, model.n_steps - state.step)
                if animate:  # keyframes and drives, read once per frame for its step times
                    t0 = clock()
                    times = (state.step + 1 + np.arange(steps)) * model.dt
                    motion = scenegraph.local_motion(model, times)
                    profile["scenegraph"] += clock() - t0
                done = 0
                while done < steps:
                    if per_step:
                        k_in_frame = done
                        state = one_step(state)
                        done += 1
                    else:
                        to_sample = every - state.step % every if writer is not None \
                            else steps
                        count = min(to_sample, steps - done)
                        state = chunk(state, count)
                        done += count
                    if state.step % every == 0:  # the observer only where a sample needs it
                        sample(observer_at(state, done))
                if inputs is not None:  # the frame's end (or a run's last, partial frame)
                    state = result.state = observer_at(state, steps)
                result.frames += 1
                # 3. scene graph: already at this time (after each step); render
                draw(state)
                if realtime:
                    _pace(model, start, state, result)
                if on_frame is not None:
                    on_frame(state)
    except SimulationError:
        sample(result.state)  # keep the output up to the last good state
        raise
    finally:
        result.wall_s = clock() - start
    sample(state)
    return result


def raise_failure(model: Model, failure) -> None:
    """Raise the SimulationError of a step that failed its compiled checks, with the
    message the Python checks give for the same state."""
    from vrsim_cli.kernels import dynamics as kd

    if failure.code == kd.BLOWUP_TRANSLATION:
        _check_translation(model, failure.state)
    if failure.code == kd.STEP_UNDERFLOW:
        raise SimulationError("the adaptive step size fell below round-off (the motion is "
                              "not smooth or not finite); try another integrator",
                              body=dynamics.body_of_component(model, failure.index),
                              t=failure.t)
    rigid.check(model, failure.state)
    raise SimulationError("the integration blew up; try a smaller dt or another integrator",
                          body=model.body_name[failure.index], t=failure.t)


def _pace(model: Model, start: float, state: State, result: RunResult) -> None:
    """Sleep until this frame's wall-clock deadline; count the frames that missed it."""
    deadline = start + state.t
    late = time.perf_counter() - deadline
    if late > 0.0:
        result.missed_deadlines += 1
        result.worst_late_s = max(result.worst_late_s, late)
    else:
        time.sleep(-late)
