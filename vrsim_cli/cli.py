"""Layer 8: the `vrsim` command. Thin click commands; errors become exit codes.

Exit codes: 0 ok, 1 the run failed, 2 usage or input error, 130/143 interrupted by
SIGINT/SIGTERM (the output is finalised first).
"""

from __future__ import annotations

import contextlib
import gc
import json
import math
import signal
import sys
import time
from functools import wraps
from pathlib import Path

import click

from vrsim_cli import __version__, interrupts
from vrsim_cli.errors import EXIT_INPUT, InputError, SimulationError, VrsimError, printable
from vrsim_cli.scene.spec import scene_schema

# Choices come from the shipped schema (cheap to read), so `vrsim --help` need not import
# numpy; tests check that the model and integrators agree with it.
INTEGRATORS = tuple(scene_schema()["$defs"]["integrator"]["enum"])
OUTPUT_FORMATS = tuple(scene_schema()["$defs"]["output"]["properties"]["format"]["enum"])


def start_collector() -> None:
    """The end of start-up: the garbage collector, paused by `__main__.main` while the
    imports run, is on again; what start-up created is frozen out of its passes (it
    lives as long as the process). Idempotent."""
    if not gc.isenabled():
        gc.freeze()
        gc.enable()


def _reports_errors(command=None, *, starts_collector: bool = True):
    """Turn VrsimError into a message on stderr and its exit code: never a traceback.
    `starts_collector=False`: the command calls `start_collector` itself once its own
    start-up (kernels) is done."""
    if command is None:
        return lambda c: _reports_errors(c, starts_collector=starts_collector)

    @wraps(command)
    def wrapper(*args, **kwargs):
        if starts_collector:
            start_collector()
        try:
            return command(*args, **kwargs)
        except InputError as exc:
            for line in exc.lines():
                click.echo(f"error: {line}", err=True)
            sys.exit(exc.exit_code)
        except VrsimError as exc:
            click.echo(f"error: {printable(str(exc))}", err=True)  # may quote a name
            sys.exit(exc.exit_code)
        except KeyboardInterrupt:  # Ctrl-C outside the loop: nothing was written yet
            click.echo("interrupted", err=True)
            sys.exit(128 + signal.SIGINT)

    return wrapper


class _Finite(click.ParamType):
    """A finite number within optional bounds (click's FloatRange lets nan and inf in)."""

    name = "number"

    def __init__(self, low=None, high=None, low_open=False):
        self.low, self.high, self.low_open = low, high, low_open

    def convert(self, value, param, ctx):
        try:
            number = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(number):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        if self.low is not None and (number < self.low or (self.low_open and number == self.low)):
            self.fail(f"{value} must be {'>' if self.low_open else '>='} {self.low:g}", param, ctx)
        if self.high is not None and number > self.high:
            self.fail(f"{value} must be <= {self.high:g}", param, ctx)
        return number


POSITIVE = _Finite(low=0.0, low_open=True)


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="vrsim")
def cli():
    """vrsim: run real-time animation and simulation scenarios headless.

    Scenes are YAML files (see `vrsim schema` and docs/scene-format.md); trajectories go to
    MCAP (Foxglove), CSV or TUM.
    """


# ----------------------------------------------------------------------------- run


class _Signals(contextlib.AbstractContextManager):
    """SIGINT/SIGTERM become a flag the loop polls once per frame, so the output is
    finalised instead of cut off; a second signal discards it (see `interrupts`). The
    `vrsim` entry point has installed the handlers already; in-process callers (tests)
    get them here, and their own back afterwards."""

    def __enter__(self):
        self.previous = interrupts.install()
        self.block = interrupts.deferred()
        self.block.__enter__()
        return self

    @property
    def received(self) -> int | None:
        return interrupts.received

    def __exit__(self, *exc):
        self.block.__exit__(*exc)
        interrupts.restore(self.previous)
        return False


class _RunProgress:
    """The run's progress bar (text.Progress): simulated time, real-time factor, time
    left; on a terminal, for runs longer than ~2 s, never with -q, --json or --live."""

    def __init__(self, model, enabled: bool):
        from vrsim_cli.text import Progress

        self.model = model
        self.bar = Progress(model.duration, enabled=enabled)

    def __call__(self, state) -> None:
        if not self.bar.enabled:
            return
        from vrsim_cli.text import significant

        elapsed = self.bar.clock() - self.bar.start
        factor = f", {significant(state.t / elapsed)}x real time" if elapsed > 0 else ""
        self.bar.update(state.t, f"t = {state.t:.3g} / {self.model.duration:g} s{factor}")

    def clear(self) -> None:
        self.bar.clear()


def _output_target(output: str | None, fmt: str | None):
    """(path, format) from -o/--format, or None. Usage errors exit 2. `-o -` writes CSV
    (or MCAP with --format mcap) to standard output."""
    from vrsim_cli.model.model import output_format_for
    from vrsim_cli.scene.files import STDOUT, about, file_target_problem, tum_folder_problem

    if output is None:
        if fmt:
            raise click.UsageError("--format needs -o/--output")
        return None
    if output == STDOUT:
        if fmt == "tum":
            raise click.UsageError("-o - writes csv or mcap to standard output; tum output "
                                   "is a folder")
        return Path(STDOUT), fmt or "csv"
    path = Path(output)
    fmt = output_format_for(path, fmt)
    shown = printable(output)
    if fmt is None:
        raise click.UsageError(f"cannot tell the format of '{shown}': use a .mcap or .csv "
                               f"suffix, or --format tum with a folder")
    try:
        if fmt == "tum" and path.exists() and not path.is_dir() and not path.is_symlink():
            raise click.UsageError(f"'{shown}' is a file; --format tum writes a folder")
    except (OSError, ValueError):
        pass  # a name too long or holding NUL: said below
    problem = tum_folder_problem(path) if fmt == "tum" else file_target_problem(path)
    if problem is not None:
        raise click.UsageError(printable(about(output, problem)))
    return path, fmt


@cli.command()
@click.argument("scene_file", type=click.Path(dir_okay=False))
@click.option("-o", "--output", type=click.Path(), help="Trajectory file: .mcap or .csv, a "
              "folder with --format tum, or - for standard output. Overrides the scene's "
              "output.file.")
@click.option("--format", "fmt", type=click.Choice(OUTPUT_FORMATS), help="Output format "
              "(default: from the suffix).")
@click.option("--duration", type=POSITIVE, help="Simulated time in s (overrides the scene).")
@click.option("--dt", type=POSITIVE, help="Largest physics step in s (overrides the scene).")
@click.option("--integrator", type=click.Choice(INTEGRATORS), help="Integrator (overrides "
              "the scene).")
@click.option("--realtime", is_flag=True, help="Pace the loop to the wall clock and report "
              "missed frame deadlines.")
@click.option("--profile", is_flag=True, help="Print the time spent in each loop stage.")
@click.option("-q", "--quiet", is_flag=True, help="Print nothing but errors.")
@click.option("--frames", "frames_dir", type=click.Path(file_okay=False), help="Render PNG "
              "frames into this folder (off-screen, OSMesa). Overrides output.frames.dir.")
@click.option("--video", type=click.Path(dir_okay=False), help="Also make a video of the "
              "frames: .mp4 (pip install 'vrsim-cli[video]') or .gif (needs frames).")
@click.option("--tolerance", type=click.FloatRange(0, 1, min_open=True), help="Error "
              "tolerance per step of --integrator dopri5 (overrides the scene).")
@click.option("--live", is_flag=True, help="Serve the run to Foxglove over its WebSocket "
              "protocol at real-time pace (ws://localhost:8765); waits for a client first. "
              "With -o the file is written too.")
@click.option("--live-port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="Port of --live on 127.0.0.1 (0: any free port).")
@click.option("--json", "as_json", is_flag=True, help="Print a machine-readable summary of "
              "the run (and nothing else on stdout).")
@click.option("--set", "settings", multiple=True, metavar="KEY=V", help="Set a scene key "
              "(repeatable), as vrsim sweep --set: bodies.ball.mass=2, gravity=[0,-1.62,0].")
@_reports_errors(starts_collector=False)  # its start-up ends after the kernels load
def run(scene_file, output, fmt, duration, dt, integrator, realtime, profile, quiet,
        frames_dir, video, tolerance, live, live_port, as_json, settings):
    """Run SCENE_FILE and write its trajectory."""
    from vrsim_cli.loop import prepare as prepare_kernels
    from vrsim_cli.loop import run as run_loop
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.writers import open_writer

    target = _output_target(output, fmt)
    if target is not None and str(target[0]) != "-" and \
            target[0].resolve() == Path(scene_file).resolve():
        raise click.UsageError("the output would overwrite the scene file")
    scene = load_scene(scene_file)
    if settings:  # key paths first: the named options below win over them
        from vrsim_cli.tools.sweep import override, parse_assignment

        scene = override(scene, [parse_assignment(text) for text in settings])
    scene = scene.with_overrides({
        ("duration",): (duration, "--duration"), ("dt",): (dt, "--dt"),
        ("integrator",): (integrator, "--integrator"),
        ("output", "frames", "dir"): (frames_dir, "--frames"),
        ("tolerance",): (tolerance, "--tolerance")})
    unwritten = None
    if live and target is None and scene.get(("output", "file")) is not None:
        # --live shows the run; a file is kept only when asked for with -o (as documented),
        # so watching a scene never replaces the file an earlier run wrote
        unwritten = scene.get(("output", "file"))
        scene = scene.without(("output", "file"))
    model = compile_model(scene, output_override=target)
    _refuse_start_overlaps(scene, model)  # before kernels compile or outputs open
    _check_frame_targets(model, video, scene_file)  # likewise
    to_stdout = model.output.path is not None and str(model.output.path) == "-"
    # With the trajectory on standard output, the summary goes to stderr.
    say = (lambda *a, **k: None) if quiet else \
        (lambda text, err=False: click.echo(text, err=err or to_stdout))
    for note in model.notes:
        say(f"note: {printable(note)}", err=True)
    if unwritten is not None:
        say(f"note: --live writes no file; output.file '{printable(str(unwritten))}' is "
            f"left alone (add -o {printable(str(unwritten))} to keep the run too)", err=True)
    if as_json and to_stdout:
        raise click.UsageError("--json prints the summary on standard output; -o - writes "
                               "the trajectory there: give -o a file")
    from vrsim_cli.streams import stdout_closed
    if stdout_closed() and (to_stdout or as_json):  # before anything is simulated
        raise click.UsageError(f"{'-o -' if to_stdout else '--json'} writes to standard "
                               f"output, which is closed; give -o a file")
    with interrupts.held():  # numba calls back into Python: a signal waits for the end
        prepare_kernels(model, say)  # compiled once after an install; before any output
    start_collector()
    server = None
    if live:
        from vrsim_cli.writers.live import LiveServer
        server = LiveServer(model.name)
    progress = _RunProgress(model, enabled=not quiet and not live and not as_json)
    from vrsim_cli.tools import pass_through

    # shapes without a collision block pass through each other: say which and when
    watch = None if quiet and not as_json else pass_through.watch(scene, model)

    def on_frame(state):
        progress(state)
        if watch is not None:
            watch(state)
    state = make_state(model)
    failure = None
    writer = frames = None
    closed = []  # what was finalised or discarded already

    def abort() -> None:
        """Discard what is not finalised yet (any previous output stays)."""
        progress.clear()
        for sink in (writer, frames, server):
            if sink is not None and sink not in closed:
                closed.append(sink)
                if sink is server:
                    sink.close(linger=False)
                else:
                    sink.abort()

    with _Signals() as signals:  # from before the first output file is opened
        stop = lambda: signals.received is not None  # noqa: E731
        try:
            try:
                # before simulating: a missing OSMesa fails at once
                try:
                    frames = _open_frames(model, video, scene_file)
                except InputError as exc:  # OSMesa missing: located at what asked for frames
                    if type(exc).__name__ != "RenderUnavailable":  # (the scene or --frames)
                        raise
                    raise InputError([scene.problem(("output", "frames", "dir"), p.message)
                                      for p in exc.problems]) from None
                writer = open_writer(model, model.output.path, model.output.format,
                                     live=server)
                if server is not None:
                    server.start(live_port, on_refused=lambda reason: click.echo(
                        f"live: {printable(reason)}", err=True))  # after the channels
                    click.echo(f"live: serving {printable(model.name)} on {server.url} "
                               f"(Foxglove: Open connection, Foxglove WebSocket); waiting for "
                               f"a client, Ctrl-C to stop", err=True)
                    if not server.wait_for_client(stop):  # no client came: nothing to keep
                        abort()
                        click.echo("interrupted before a client connected; nothing written",
                                   err=True)
                        sys.exit(128 + signals.received)
                result = run_loop(model, state, writer, realtime=realtime or live,
                                  should_stop=stop, on_frame=on_frame, render=frames,
                                  coarse_callbacks=watch is None)  # the watch: every frame
            except SimulationError as exc:
                failure = exc  # finalise the output up to the last good state, then report
            finally:
                progress.clear()
            if server is not None:
                server.close(linger=failure is None)
                closed.append(server)
            # still under the handlers: a signal now cannot cut the output off
            if frames is not None:
                if len(frames.states) > 1 and not as_json:  # drawn now: the camera needs the run
                    say(f"rendering {len(frames.states)} frames ...", err=True)
                frames.close()
                closed.append(frames)
            if writer is not None:
                writer.close()
                closed.append(writer)
        except interrupts.Interrupted as exc:  # a second signal: discard, keep the previous
            abort()
            click.echo(f"interrupted twice by {interrupts.name(exc.signum)}: output "
                       f"discarded, any previous output kept", err=True)
            sys.exit(exc.exit_code)
        except BaseException:  # an output error, or a bug: keep any previous file
            abort()
            raise
    from vrsim_cli.text import plural
    from vrsim_cli.tools.run_report import failure_summary, format_run, run_summary

    if failure is not None:
        kept = f"; output up to the last good state kept in {_shown_path(model)}" \
            if model.output.path is not None else ""
        click.echo(f"error: {printable(str(failure))}{kept}", err=True)  # names a body
        if as_json:
            click.echo(json.dumps(failure_summary(model, failure), indent=2))
        sys.exit(failure.exit_code)
    interrupted = signal.Signals(signals.received).name if signals.received else None
    passed = watch.found if watch is not None else None
    report = run_summary(model, result, frames=frames, interrupted_by=interrupted,
                         live_url=server.url if server is not None else None,
                         passes_through=passed.as_dict() if passed else None)
    if passed is not None and not as_json:
        say(f"note: {printable(passed.note())}", err=True)
    if as_json:
        click.echo(json.dumps(report, indent=2))
    else:
        for line in format_run(report, profile, realtime or live):
            say(line)
    if frames is not None and not as_json:
        say(f"frames: {plural(frames.images, 'image')} of {model.frames.width}x"
            f"{model.frames.height} px -> {printable(str(model.frames.dir))}"
            + (f", video {printable(video)}" if video else "") + _subsampled(frames))
    if signals.received is not None:  # during the loop, or while the output was finalised
        click.echo(f"interrupted by {interrupted} at t = {result.state.t:.6g} s; output "
                   f"finalised", err=True)
        sys.exit(128 + signals.received)


def _shown_path(model) -> str:
    path = str(model.output.path)
    return "standard output" if path == "-" else printable(path)


def _open_frames(model, video: str | None, scene_file: str):
    """The frames writer of the run (stage 3), or None. Raises RenderUnavailable (exit 2)
    when OSMesa or PyOpenGL is missing; OpenGL is imported here and nowhere else. The
    targets were checked before (`_check_frame_targets`)."""
    if model.frames is None:
        return None
    from vrsim_cli.render import open_renderer, time_label
    from vrsim_cli.writers.frames import FramesWriter, frames_tag

    spec = model.frames
    renderer = open_renderer(model, spec.width, spec.height, spec.camera)
    sink = None
    if video is not None:
        from vrsim_cli.writers.video import VideoWriter
        sink = VideoWriter(Path(video), fps=model.frame_rate / spec.every)
    return FramesWriter(model, spec, renderer, label=time_label, video=sink,
                        tag=frames_tag(scene_file))


def _check_frame_targets(model, video: str | None, scene_file: str) -> None:
    """Usage errors (exit 2) before anything is simulated: the frames folder must be vrsim's
    own (`frames_folder_problem`), the video a writable regular-file target."""
    if model.frames is None:
        if video is not None:
            raise click.UsageError("--video needs frames: add --frames DIR (or "
                                   "output.frames.dir in the scene)")
        return
    from vrsim_cli.writers.frames import frames_folder_problem, frames_tag

    spec = model.frames
    problem = frames_folder_problem(spec.dir, frames_tag(scene_file))
    if problem is not None:
        raise click.UsageError(printable(f"frames folder '{spec.dir}' {problem}"))
    if video is not None:
        from vrsim_cli.model.budget import MAX_RUN_MB, gif_mb
        from vrsim_cli.scene.files import about, file_target_problem
        from vrsim_cli.writers.video import check_video

        problem = file_target_problem(Path(video))  # not a device, FIFO, link or folder
        if problem is not None:
            raise click.UsageError(printable(f"--video {about(video, problem)}"))
        check_video(Path(video))
        if Path(video).suffix.lower() == ".gif":  # Pillow keeps a GIF's images in memory
            images = -(-model.n_frames // spec.every) + 1
            held = gif_mb(images, spec.width * spec.height)
            if held > MAX_RUN_MB / 2:
                raise click.UsageError(
                    f"--video {printable(video)}: a GIF keeps every image in memory until "
                    f"the run ends: {images} images of {spec.width}x{spec.height} px take "
                    f"about {held:.0f} MB (vrsim runs up to {MAX_RUN_MB} MB); use .mp4 "
                    f"(streamed), fewer images (output.frames.every) or smaller frames")


def _subsampled(frames) -> str:
    """A note when the video keeps fewer images than the frames folder (GIF delays)."""
    video = getattr(frames, "video", None)
    keep = getattr(video, "keep_every", 1)
    return f" (the GIF keeps one image in {keep}: {video.note})" if keep > 1 else ""


# ----------------------------------------------------------------------------- validate


@cli.command()
@click.argument("scene_files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("-q", "--quiet", is_flag=True, help="Print only problems.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object per file (a "
              "list), problems and notes included, and nothing else.")
def validate(scene_files, quiet, as_json):
    """Check scene files; report every problem with FILE:LINE:COL."""
    start_collector()
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.text import plural

    failed = False
    reports = []
    for file in scene_files:
        try:
            scene = load_scene(file)
            model = compile_model(scene)
            _refuse_start_overlaps(scene, model)
        except InputError as exc:
            failed = True
            reports.append(_validation_report(file, None, exc.problems))
            if not as_json:
                for line in exc.lines():
                    click.echo(f"error: {line}", err=True)
            continue
        reports.append(_validation_report(file, model, [], _validate_notes(scene)))
        if not quiet and not as_json:
            impacts = (f", {model.response.impacts} impacts ({model.response.impacts_why})"
                       if model.response else "")
            click.echo(f"{printable(file)}: ok ({plural(model.n_body, 'body')}, "
                       f"{model.duration:g} s in {plural(model.n_steps, 'step')} of "
                       f"{model.dt:.6g} s, "
                       f"{model.integrator}{impacts})")
            for note in model.notes + _validate_notes(scene):
                click.echo(f"note: {printable(file)}: {printable(note)}", err=True)
    if as_json:
        click.echo(json.dumps(reports, indent=2))
    sys.exit(EXIT_INPUT if failed else 0)


def _validate_notes(scene) -> tuple:
    """Notes only `validate` gives (`run` says them more precisely, after the run)."""
    from vrsim_cli.tools.pass_through import validate_note

    note = validate_note(scene.data)
    return () if note is None else (note,)


def _validation_report(file: str, model, problems, notes=()) -> dict:
    """One file's result for `validate --json`: what the text says, as data (SI units)."""
    from vrsim_cli.errors import format_key_path

    report = {"file": file, "ok": model is not None,
              "problems": [{"file": p.file, "line": p.line, "column": p.col,
                            "key": None if p.path is None else format_key_path(p.path),
                            "message": p.message, "hint": p.hint} for p in problems]}
    if model is not None:
        report.update(
            name=model.name, bodies=int(model.n_body), duration_s=float(model.duration),
            steps=int(model.n_steps), dt_s=float(model.dt), integrator=model.integrator,
            impacts=model.response.impacts if model.response else None,
            impacts_why=model.response.impacts_why if model.response else None,
            notes=list(model.notes) + list(notes))
    return report


def _refuse_start_overlaps(scene, model) -> None:
    """InputError (exit 2) when bodies start inside each other (`loop.overlap_problems`)."""
    if model.collision is None or model.response is None:
        return  # nothing to check: no numpy, no collision stage imported
    from vrsim_cli.loop import overlap_problems
    from vrsim_cli.model.state import make_state

    problems = overlap_problems(scene, model, make_state(model))
    if problems:
        raise InputError(problems)


# ----------------------------------------------------------------------------- mass-properties


@cli.command("mass-properties")
@click.argument("scene_file", type=click.Path(dir_okay=False))
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@_reports_errors
def mass_properties(scene_file, as_json):
    """Mass, centre of mass, inertia tensor, principal moments and axes of each body."""
    from vrsim_cli.model.mass_properties import format_report, scene_report
    from vrsim_cli.scene.spec import load_scene

    scene = load_scene(scene_file)
    rows = scene_report(scene)
    if as_json:
        click.echo(json.dumps(rows, indent=2))
    else:
        for line in format_report(rows, int(scene.data.get("dimension", 3))).splitlines():
            click.echo(printable(line))  # body names come from the scene


# ----------------------------------------------------------------------------- cache


@cli.command()
@click.option("--clear", is_flag=True, help="Remove every compiled kernel (the next run "
              "compiles again, ~1-2 min for contact scenes).")
@_reports_errors
def cache(clear):
    """Where compiled kernels are cached and how much they take; --clear removes them.

    The folder: $VRSIM_CACHE_DIR, else $NUMBA_CACHE_DIR, else ~/.cache/vrsim/numba. A
    damaged entry is found and compiled again by itself; --clear is for a cache you no
    longer want (or a full disk)."""
    from vrsim_cli.kernels import jit

    if clear:
        base, removed, freed = jit.clear_cache()
        click.echo(f"cache: removed {removed} files ({freed / 1e6:.1f} MB) from "
                   f"{printable(str(base))}")
        return
    base, files, size = jit._default_dir(), 0, 0
    for folder in sorted(base.glob("src-*")) if base.is_dir() else []:
        for path in folder.rglob("*"):
            with contextlib.suppress(OSError):
                if path.is_file():
                    files, size = files + 1, size + path.stat().st_size
    click.echo(f"cache: {printable(str(base))}: {files} files, {size / 1e6:.1f} MB"
               + ("" if jit.cache_note() is None else f" ({jit.cache_note()})"))


# ----------------------------------------------------------------------------- schema


@cli.command()
def schema():
    """Print the JSON Schema of scene files (for editors and yaml-language-server)."""
    click.echo(json.dumps(scene_schema(), indent=2))


# ----------------------------------------------------------------------------- info


@cli.command()
@click.argument("trajectory_file", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@_reports_errors
def info(trajectory_file, as_json):
    """Summarise a trajectory file: entities, duration, samples, channels.

    Exit 0 when it holds trajectories, 1 when it holds none vrsim can read, 2 when it
    cannot be read at all."""
    from vrsim_cli.tools.trajectory import format_summary, read_trajectory, summary

    info_ = summary(read_trajectory(trajectory_file), trajectory_file)
    if as_json:
        click.echo(json.dumps(info_, indent=2))
    else:  # names, topics and metadata come from the file: format_summary escapes them
        for line in format_summary(info_):
            click.echo(line)
    if not info_["entities"]:  # a CI step reading it must not pass on an empty reading
        click.echo(f"error: {printable(trajectory_file)}: no trajectory vrsim can read "
                   f"(vrsim's /vrsim/state, foxglove.FrameTransforms or ROS 2 "
                   f"tf2_msgs/msg/TFMessage)", err=True)
        sys.exit(1)


# ----------------------------------------------------------------------- collision-proxies


@cli.command("collision-proxies")
@click.argument("scene_file", type=click.Path(dir_okay=False))
@click.option("--samples", type=click.IntRange(min=10), default=2000, show_default=True,
              help="Points sampled on each surface.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
@_reports_errors
def collision_proxies(scene_file, samples, as_json):
    """The error each collision proxy makes against a body's render mesh (slide 5.4.1).

    Per mesh body and proxy (sphere, aabb, obb, hull, mesh): the Hausdorff distance
    between the proxy's and the mesh's surfaces (sampled, a lower bound; both one-sided
    distances too) and the proxy's volume over the mesh's."""
    from vrsim_cli.model.collision import scene_proxy_report
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene

    try:
        report = scene_proxy_report(compile_model(load_scene(scene_file)), samples)
    except ValueError as exc:  # a flat mesh has no hull, so no proxies to compare
        raise InputError(f"{scene_file}: {exc}") from None
    if as_json:
        click.echo(json.dumps(report, indent=2))
        return
    if not report:
        click.echo(f"{printable(scene_file)}: no mesh bodies, nothing to compare")
        return
    for body in report:
        click.echo(printable(f"{body['body']} ({Path(body['file']).name}, "
                             f"{body['triangles']} triangles, uses {body['geometry']}):"))
        click.echo(f"  {'proxy':<7} {'hausdorff m':>12} {'proxy->mesh':>12} "
                   f"{'mesh->proxy':>12} {'volume ratio':>13}")
        for row in body["proxies"]:
            click.echo(f"  {row['proxy']:<7} {row['hausdorff_m']:>12.4g} "
                       f"{row['proxy_to_mesh_m']:>12.4g} {row['mesh_to_proxy_m']:>12.4g} "
                       f"{row['volume_ratio']:>13.4g}")


class _Numbers(click.ParamType):
    """A comma-separated list of numbers, e.g. `-1,-0.99,-0.96`."""

    name = "numbers"

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        try:
            numbers = tuple(float(x) for x in str(value).split(",") if x.strip())
        except ValueError:
            self.fail(f"expected comma-separated numbers, got {value!r}", param, ctx)
        if not numbers:
            self.fail("give at least one number", param, ctx)
        return numbers


@cli.command("walk-table")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False),
              help="Take the walk from this scene file instead of the slide's parameters.")
@click.option("--format", "fmt", type=click.Choice(["markdown", "csv"]), default="markdown",
              show_default=True)
@click.option("--exact", is_flag=True, help="Full precision instead of truncation toward zero.")
@click.option("--v-max", type=_Finite(low=0.0), default=200.0, show_default=True, help="m/s")
@click.option("--gamma-max", type=_Finite(low=0.0), default=100.0, show_default=True,
              help="deg/s")
@click.option("--dt", type=_Finite(low=1e-6, high=10.0), default=0.1, show_default=True,
              help="Frame interval in s.")
@click.option("--position", nargs=2, type=_Finite(), default=(300.0, 300.0),
              show_default=True, metavar="Z X", help="Start position V in the slide's (z, x) "
              "coordinates.")
@click.option("--direction", nargs=2, type=_Finite(), default=(100.0, 100.0),
              show_default=True, metavar="Z X", help="Start direction d in (z, x); not "
              "normalised.")
@click.option("--alpha", type=_Numbers(), help="Alpha per frame, comma-separated "
              "(default: the slide's -1,-0.99,...,0).")
@click.option("--beta", type=_Numbers(), help="Beta per frame (default: equal to alpha, as on "
              "the slide).")
@_reports_errors
def walk_table_command(scene_file, fmt, exact, v_max, gamma_max, dt, position, direction,
                       alpha, beta):
    """Print the walk table of slide 5.1, computed by the walk code of `vrsim run`."""
    from vrsim_cli.scene.spec import load_scene, parse_scene
    from vrsim_cli.tools.walk_table import SLIDE_ALPHAS, format_table, slide_scene_text, walk_table

    for name, values in (("--alpha", alpha), ("--beta", beta)):
        if values is not None and not all(abs(v) <= 1.0 for v in values):
            raise click.BadParameter("values must lie in [-1, 1]", param_hint=name)
    if not any(direction):
        raise click.BadParameter("the direction must not be zero", param_hint="--direction")
    if alpha is not None and beta is not None and len(alpha) != len(beta):
        raise click.BadParameter(f"{len(alpha)} alpha values but {len(beta)} beta values",
                                 param_hint="--beta")
    if scene_file is not None:
        scene = load_scene(scene_file)
    else:
        alphas = alpha if alpha is not None else SLIDE_ALPHAS
        text = slide_scene_text(position_zx=position, direction_zx=direction, v_max=v_max,
                                gamma_max=gamma_max, dt=dt, alphas=alphas,
                                betas=beta if beta is not None else alphas)
        scene = parse_scene(text, "<walk-table options>")
    click.echo(format_table(walk_table(scene), fmt, exact), nl=False)


@cli.command()
@click.option("--quick", is_flag=True, help="Fewer step sizes, bodies and repeats, for a first "
              "look (a progress bar shows the time left on a terminal).")
@click.option("--peers", is_flag=True, help="Also run MuJoCo and PyBullet when installed "
              "(pip install 'vrsim-cli[bench]').")
@click.option("--problem", "names", multiple=True, help="Run only this problem (repeatable).")
@click.option("--repeats", type=click.IntRange(min=1), help="Timed repeats per run (best of).")
@click.option("-o", "--output", "folder", type=click.Path(file_okay=False), default="bench",
              show_default=True, help="Folder for bench.md, bench.json and the plots.")
@_reports_errors
def bench(quick, peers, names, repeats, folder):
    """Work-precision benchmark: wall time together with error, against MuJoCo/PyBullet."""
    from vrsim_cli.tools.bench import report as bench_module
    from vrsim_cli.writers.atomic import AtomicFile

    known = bench_module.problems()
    for name in names:
        if name not in known:
            raise click.BadParameter(f"unknown problem '{name}' (known: {', '.join(known)})",
                                     param_hint="--problem")
    import threading

    from vrsim_cli.text import Progress

    # On a terminal, after ~2 s: the problem at work and the time left. A problem can take
    # a minute, so a thread redraws the bar (elapsed time, estimate) in between.
    bar, now, done = Progress(1.0), [0.0, ""], threading.Event()

    def step(finished, total, what):
        now[:] = [finished / total, what]
        bar.update(*now)

    def tick():
        while not done.wait(0.5):
            bar.update(*now)

    ticker = threading.Thread(target=tick, daemon=True)
    ticker.start()
    try:
        results = bench_module.run_bench(list(names) or None, quick=quick, peers=peers,
                                         repeats=repeats, on_progress=step)
    finally:
        done.set()
        ticker.join()
        bar.clear()
    reps = repeats or (2 if quick else 5)
    note = (f"one warm-up run, then the best of {reps} timed runs (fewer once the timed "
            f"runs of one setting have taken {bench_module.REPEAT_BUDGET_S:g} s); only the "
            f"stepping is timed (model building, output and the per-step sampling of "
            f"measures are not)")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    report = bench_module.markdown(results, note)
    for name, text in (("bench.md", report), ("bench.json", bench_module.to_json(results))):
        target = AtomicFile(out / name)
        target.write(text.encode())
        target.commit()
    plots = bench_module.plot(results, out)
    click.echo(report)
    click.echo(f"wrote {out / 'bench.md'}, {out / 'bench.json'}"
               + (f" and {len(plots)} plot(s)" if plots else
                  " (no plots: pip install 'vrsim-cli[bench]' for matplotlib)"))


# ----------------------------------------------------------------------------- sweep


def _executor(jobs, ray_address):
    """The executor of --jobs / --ray (tools/executors.py)."""
    from vrsim_cli.tools.executors import make_executor

    return make_executor(jobs, ray_address)


def _ray_address(ctx, param, value):
    """--ray [ADDRESS] takes the next word when it is not an option: refuse a scene file
    there (`vrsim sweep --ray scene.yaml`) with the fix, not a missing-argument error."""
    if value and Path(value).suffix in (".yaml", ".yml") and Path(value).exists():
        raise click.BadParameter(f"'{value}' was taken as the cluster address: put --ray "
                                 f"after the scene files, or write --ray=ADDRESS")
    return value


def _executor_options(command):
    """--jobs N and --ray [ADDRESS], shared by sweep and regress."""
    command = click.option(
        "--ray", "ray_address", is_flag=False, flag_value="", default=None,
        metavar="[ADDRESS]", callback=_ray_address, help="Run on Ray: a local instance, or "
        "the cluster at ADDRESS (pip install 'vrsim-cli[ray]').")(command)
    return click.option("--jobs", type=click.IntRange(min=1), help="Worker processes "
                        "(default: the machine's cores; 1: in this process).")(command)


def _echo_escaped(text="", **kwargs) -> None:
    """click.echo with every line escaped (`printable`): sweep, regress and plot print scene
    file names, entity names and reasons that come from files vrsim did not write."""
    click.echo("\n".join(printable(line) for line in str(text).split("\n")), **kwargs)


@cli.command()
@click.argument("scene_files", nargs=-1, required=True, type=click.Path(dir_okay=False))
@click.option("--set", "settings", multiple=True, metavar="KEY=V1,V2,...", help="Values of "
              "a scene key to sweep (repeatable: the runs are the cartesian product). KEY "
              "is a path: dt, integrator, tolerance, bodies.ball.material.restitution "
              "(list items by name or [index]). Values are YAML; lin:A:B:N and log:A:B:N "
              "give N spaced values.")
@click.option("--reference", "reference", multiple=True, metavar="'KEY=V ...'|FILE",
              help="Measure each run's error against the run with these values on top "
                   "(e.g. 'integrator=dopri5 tolerance=1e-12'), or against a trajectory "
                   "file.")
@click.option("-o", "--output", "folder", type=click.Path(file_okay=False), default="sweep",
              show_default=True, help="Folder for runs.csv, entities.csv, sweep.md, plots.")
@_executor_options
@click.option("--resume", is_flag=True, help="Continue the sweep in the output folder, "
              "skipping the runs its table already holds.")
@click.option("-q", "--quiet", is_flag=True, help="Print only failures and the summary.")
@_reports_errors
def sweep(scene_files, settings, reference, folder, jobs, ray_address, resume, quiet):
    """Run variants of scenes and measure speed against error (docs/sweep.md).

    Exit 0 when every run finished, 1 when a run failed (the others still run), 2 on
    bad input (found before anything runs).
    """
    from vrsim_cli.tools import sweep as sweep_module
    from vrsim_cli.tools.executors import describe

    parsed = [sweep_module.parse_setting(text) for text in settings]
    pairs, ref_file = sweep_module.parse_reference(reference)
    plan = sweep_module.plan_sweep(list(scene_files), parsed, pairs, ref_file)
    for note in plan.notes:
        _echo_escaped(f"note: {note}", err=True)
    executor = _executor(jobs, ray_address)
    total = len(plan.runs) + len(plan.references)
    count = [0]
    from vrsim_cli.text import Progress

    bar = Progress(total)  # on a terminal, after ~2 s: runs done and the time left

    def on_run(run, outcome):
        count[0] += 1
        line = sweep_module.progress_line(run, outcome, count[0], total)
        bar.clear()
        if outcome is None or outcome.status != "ok":
            _echo_escaped(f"error: {line}", err=True)
        elif not quiet:
            _echo_escaped(line)
        bar.update(count[0], f"{count[0]}/{total} runs")

    out = Path(folder)
    with _Signals() as signals:
        try:
            result = sweep_module.run_sweep(
                plan, out, executor, resume=resume, on_run=on_run,
                should_stop=lambda: signals.received is not None)
        finally:
            bar.clear()
            executor.close()
        written = sweep_module.write_report(plan, out, describe(executor))
    skipped = f", {result.skipped} already in the table" if result.skipped else ""
    runs = f"{result.done} run" + ("" if result.done == 1 else "s")
    _echo_escaped(f"sweep: {runs} in {result.wall_s:.3g} s {describe(executor)}"
               f"{skipped}; {len(result.failed)} failed")
    for line in sweep_module.fronts_summary(plan, out):
        _echo_escaped(line)
    plots = len(written) - 1
    _echo_escaped(f"wrote {out / sweep_module.RUNS_CSV}, {out / sweep_module.ENTITIES_CSV}, "
               f"{written[0]}" + (f" and {plots} plot(s)" if plots else
                                  " (no plot: no errors, or pip install matplotlib)"))
    if signals.received is not None:
        name = signal.Signals(signals.received).name
        _echo_escaped(f"interrupted by {name}: the finished runs are in the table; rerun with "
                   f"--resume to do the rest", err=True)
        sys.exit(128 + signals.received)
    sys.exit(1 if result.failed else 0)


# ----------------------------------------------------------------------------- compare


class _ToleranceOverride(click.ParamType):
    """`PATTERN=ATOL[,ANGLE_TOL]`: a per-entity tolerance (fnmatch pattern, e.g. 'drop.*')."""

    name = "PATTERN=ATOL[,ANGLE_TOL]"

    def convert(self, value, param, ctx):
        pattern, sep, numbers = value.partition("=")
        parts = numbers.split(",")
        try:
            if not sep or not pattern or len(parts) > 2:
                raise ValueError
            tols = [float(x) for x in parts]
            if not all(0.0 <= x < float("inf") for x in tols):
                raise ValueError
        except ValueError:
            self.fail(f"'{value}' is not PATTERN=ATOL or PATTERN=ATOL,ANGLE_TOL with "
                      f"finite numbers >= 0 (e.g. ball=1e-6 or 'drop.*=1e-3,1e-4')", param, ctx)
        return pattern, tols


_TOL = _Finite(low=0.0)


@cli.command()
@click.argument("a", type=click.Path())
@click.argument("b", type=click.Path())
@click.option("--atol", type=_TOL, default=1e-9, show_default=True, help="Absolute "
              "tolerance, in each quantity's SI unit (m, m/s, rad/s).")
@click.option("--rtol", type=_TOL, default=0.0, show_default=True, help="Relative "
              "tolerance, times the norm of B's value.")
@click.option("--angle-tol", type=_TOL, default=1e-9, show_default=True, help="Orientation "
              "tolerance in rad.")
@click.option("--tol", "overrides", type=_ToleranceOverride(), multiple=True, help="Per-entity "
              "ATOL (and angle tolerance), for entities matching PATTERN (shell-style); "
              "repeatable, the last match wins.")
@click.option("--allow-missing-entities", is_flag=True, help="Pass when the entity sets "
              "differ, comparing the shared entities only.")
@click.option("--all", "show_all", is_flag=True, help="List every entity, not only failing "
              "ones, in long tables.")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable report.")
@_reports_errors
def compare(a, b, atol, rtol, angle_tol, overrides, allow_missing_entities, show_all, as_json):
    """Compare trajectory A with the reference B (MCAP, CSV, CSV.GZ or TUM, any pair).

    Exit 0 when every entity is within tolerance, 1 when not, 2 on unreadable input.
    """
    from vrsim_cli.tools.compare import Tolerance, TolerancePlan, compare as compare_files
    from vrsim_cli.tools.compare import format_report
    from vrsim_cli.tools.trajectory import read_trajectory

    default = Tolerance(atol, rtol, angle_tol)
    plan = TolerancePlan(default, tuple(
        (pattern, Tolerance(tols[0], rtol, tols[1] if len(tols) > 1 else angle_tol))
        for pattern, tols in overrides))
    report = compare_files(read_trajectory(a), read_trajectory(b), plan,
                           allow_missing_entities=allow_missing_entities)
    if as_json:
        click.echo(json.dumps(report.as_dict(), indent=2))
    else:
        for line in format_report(report, show_all=show_all):
            click.echo(printable(line))  # entity names come from the files
    sys.exit(0 if report.ok else 1)


# ----------------------------------------------------------------------------- regress


@cli.command()
@click.argument("folder", type=click.Path(file_okay=False))
@click.argument("names", nargs=-1)
@click.option("--golden", "golden", type=click.Path(file_okay=False), required=True,
              help="Folder of the goldens NAME.csv.gz (and hashes.json, tolerances.yaml).")
@click.option("--update", is_flag=True, help="Rewrite the goldens and this platform's "
              "state-hash pins from this run (review and commit them).")
@click.option("--junit", "junit", type=click.Path(dir_okay=False), help="Also write the "
              "result as JUnit XML (one testcase per scene).")
@_executor_options
@click.option("--atol", type=_TOL, help="Default absolute tolerance (m, m/s, rad/s), "
              "replacing tolerances.yaml's default atol.")
@click.option("--rtol", type=_TOL, help="Default relative tolerance (likewise).")
@click.option("--angle-tol", type=_TOL, help="Default orientation tolerance in rad "
              "(likewise).")
@click.option("--tol", "overrides", type=_ToleranceOverride(), multiple=True,
              help="[SCENE:]PATTERN=ATOL[,ANGLE_TOL]: per-entity tolerance (shell-style "
                   "patterns), for the scenes matching SCENE (default all); the last match "
                   "wins, after tolerances.yaml's.")
@click.option("--tolerances", "tolerances_file", type=click.Path(dir_okay=False),
              help="Tolerances file (default: GOLDEN/tolerances.yaml when present).")
@click.option("--no-pins", is_flag=True, help="Do not check the state-hash pins "
              "(hashes.json), only the trajectories.")
@click.option("--samples", type=click.IntRange(min=2), default=21, show_default=True,
              help="--update: sample times kept per golden.")
@click.option("-q", "--quiet", is_flag=True, help="Print only failures and the summary.")
@_reports_errors
def regress(folder, names, golden, update, junit, jobs, ray_address, atol, rtol, angle_tol,
            overrides, tolerances_file, no_pins, samples, quiet):
    """Run every scene in FOLDER (or the NAMES given) and compare it with its golden.

    Exit 0 when every scene matches, 1 when one does not (or its run fails), 2 on bad
    input. Tolerances and goldens: docs/regression.md.
    """
    from vrsim_cli.tools import regress as regress_module
    from vrsim_cli.tools.executors import describe

    folder_path, golden_path = Path(folder), Path(golden)
    if junit and not Path(junit).resolve().parent.is_dir():
        raise click.BadParameter(f"folder '{Path(junit).parent}' does not exist",
                                 param_hint="--junit")
    file = Path(tolerances_file) if tolerances_file else golden_path / regress_module.TOLERANCES
    if tolerances_file and not file.exists():
        raise click.BadParameter(f"no such file '{tolerances_file}'", param_hint="--tolerances")
    tolerances = regress_module.tolerances_from_options(file, atol, rtol, angle_tol, overrides)
    plan = regress_module.plan_regress(folder_path, golden_path, names, update=update,
                                       tolerances=tolerances, check_pins=not no_pins,
                                       samples=samples)
    for note in plan.notes:
        _echo_escaped(f"note: {note}", err=True)
    command = f"vrsim regress {folder} --golden {golden} --update"

    def on_case(case):
        if update:
            return
        if case.status == "passed":
            if not quiet:
                _echo_escaped(f"{case.name}: ok")
            return
        _echo_escaped(f"{case.name}: {case.status.upper()}: " + "; ".join(case.reasons))
        for line in case.lines:
            _echo_escaped(f"  {line}")

    executor = _executor(jobs, ray_address)
    with _Signals() as signals:
        try:
            result = regress_module.run_regress(
                plan, executor, on_case=on_case, update_command=command,
                should_stop=lambda: signals.received is not None)
        finally:
            executor.close()
        if signals.received is not None:
            name = signal.Signals(signals.received).name
            _echo_escaped(f"interrupted by {name}: nothing written", err=True)
            sys.exit(128 + signals.received)
        if update:
            not_written = regress_module.update_goldens(result, say=_echo_escaped)
        if junit:
            regress_module.write_junit(result, Path(junit))
    counts = result.counts()
    passed = counts["tests"] - counts["failures"] - counts["errors"]
    if update:
        _echo_escaped(f"regress --update: {len(result.cases) - len(not_written)} goldens "
                   f"written or unchanged in {golden}, {len(not_written)} not written "
                   f"({result.wall_s:.3g} s {describe(executor)})")
        sys.exit(1 if not_written else 0)
    _echo_escaped(f"regress: {counts['tests']} scenes, {passed} passed, {counts['failures']} "
               f"failed, {counts['errors']} errors ({result.wall_s:.3g} s "
               f"{describe(executor)})" + (f"; JUnit XML in {junit}" if junit else ""))
    sys.exit(0 if result.ok else 1)


# ----------------------------------------------------------------------------- plot


@cli.command()
@click.argument("trajectory_file", type=click.Path())
@click.option("-o", "--output", type=click.Path(dir_okay=False), help="PNG to write "
              "(default: FILE's name with .png, in the current folder).")
@click.option("--entity", "patterns", multiple=True, help="Plot the entities matching this "
              "shell-style pattern (repeatable; default: all, at most 10).")
@click.option("--scene", "scene_file", type=click.Path(dir_okay=False), help="The scene of "
              "the run, for the masses behind the energy (vrsim's MCAP files carry theirs).")
@_reports_errors
def plot(trajectory_file, output, patterns, scene_file):
    """Plot position, speed and energy over time per entity (PNG; needs matplotlib:
    pip install 'vrsim-cli[plot]')."""
    from vrsim_cli.tools.plot import draw, model_of, series
    from vrsim_cli.tools.trajectory import read_trajectory

    out = Path(output) if output else Path(Path(trajectory_file).name).with_suffix(".png")
    if out.suffix.lower() != ".png":
        raise click.UsageError(f"'{out}': vrsim plot writes PNG; use a .png name")
    if not out.parent.is_dir():
        raise click.UsageError(f"folder '{out.parent}' does not exist")
    traj = read_trajectory(trajectory_file)
    if not traj.tracks:
        raise InputError(f"{trajectory_file}: holds no trajectory to plot")
    model = model_of(traj, scene_file)
    data = series(traj, model, patterns)
    note = None
    if model is None:
        note = "energy needs the masses: give the scene with --scene"
    elif not any(s["energy"] is not None for s in data["entities"].values()):
        note = "no body with a finite mass and velocities among these entities"
    draw(data, f"{Path(trajectory_file).name}", out, note)
    _echo_escaped(f"wrote {out}: position, speed and energy of "
               f"{', '.join(data['entities'])}")


def main() -> None:
    """The `vrsim` command (see `vrsim_cli.__main__.main`, which installs the signal
    handlers before importing this module)."""
    interrupts.install()
    try:
        cli(prog_name="vrsim")
    except interrupts.Interrupted as exc:
        interrupted(exc)


def interrupted(exc: "interrupts.Interrupted") -> None:
    """Report a signal that arrived while nothing was being written, and exit."""
    if sys.stderr is not None:  # None under `2>&-`
        sys.stderr.write(f"interrupted by {interrupts.name(exc.signum)}; nothing was "
                         f"written\n")
    sys.exit(exc.exit_code)


if __name__ == "__main__":
    main()
