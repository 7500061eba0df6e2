"""The `vrsim` command through click's CliRunner: exit codes, messages, options."""

from __future__ import annotations

import errno
import json

import pytest

from conftest import SCENARIOS
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.writers import tum_writer
from vrsim_cli.writers.atomic import AtomicFile

BALL = """
vrsim: 1
name: drop
duration: 1.0
frame_rate: 50
dt: 0.01
bodies: [{name: ball, mass: 1, position: [0, 10, 0]}]
"""


def test_run_writes_and_summarises(invoke, write_scene, tmp_path):
    out = tmp_path / "ball.csv"
    result = invoke("run", write_scene(BALL), "-o", out)
    assert result.exit_code == 0, result.output
    assert result.stdout.startswith("drop: simulated 1 s in 100 steps of 0.01 s, wall ")
    assert f"real time -> {out}" in result.stdout
    assert "state sha256:" in result.stdout
    assert len(read_trajectory(out).times) == 51


def test_run_without_output_writes_nothing_and_says_so(invoke, write_scene, tmp_path):
    result = invoke("run", write_scene(BALL))
    assert result.exit_code == 0 and "(no output: use -o FILE)" in result.stdout
    assert [p.name for p in tmp_path.iterdir()] == ["scene.yaml"]


def test_scene_output_file_is_relative_to_the_current_folder(invoke, write_scene, tmp_path,
                                                           monkeypatch):
    """Not beside the scene: `vrsim run scenarios/x.yaml` must not write into the
    checkout's scenarios folder."""
    (tmp_path / "scenes").mkdir()
    scene = write_scene(BALL + "output: {file: traj.mcap, rate: 10}\n", "scenes/s.yaml")
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    result = invoke("run", scene)
    assert result.exit_code == 0, result.output
    assert f"-> {tmp_path / 'work' / 'traj.mcap'}" in result.stdout
    assert len(read_trajectory(tmp_path / "work" / "traj.mcap").times) == 11
    assert sorted(p.name for p in (tmp_path / "scenes").iterdir()) == ["s.yaml"]
    escape = write_scene(BALL + "output: {file: ../traj.csv}\n", "scenes/e.yaml")
    result = invoke("run", escape)
    assert result.exit_code == 2
    assert "path '../traj.csv' leaves the current folder" in result.stderr
    assert "-o FILE" in result.stderr


def test_overrides(invoke, write_scene, tmp_path):
    out = tmp_path / "o.csv"
    result = invoke("run", write_scene(BALL), "-o", out, "--duration", "0.5", "--dt", "0.005",
                    "--integrator", "rk4")
    assert result.exit_code == 0, result.output
    assert "simulated 0.5 s in 100 steps of 0.005 s" in result.stdout
    traj = read_trajectory(out)
    assert traj.tracks["ball"].pos[-1, 1] == pytest.approx(10 - 9.81 * 0.125, abs=1e-12)


def test_dt_that_does_not_fit_the_frame_is_reduced_with_a_note(invoke, write_scene):
    result = invoke("run", write_scene(BALL.replace("dt: 0.01", "dt: 0.003")))
    assert result.exit_code == 0
    assert "note: dt = 0.003 s does not divide the frame interval 1/50 s; using dt = " \
           "0.00285714 s (7 steps per frame)" in result.stderr


def test_quiet_prints_nothing(invoke, write_scene):
    result = invoke("run", write_scene(BALL), "-q")
    assert result.exit_code == 0 and result.output == ""


def test_profile_lists_the_stages(invoke, write_scene):
    result = invoke("run", write_scene(BALL), "--profile")
    assert result.exit_code == 0
    for stage in ("dynamics", "checks", "output"):
        assert f"\n{stage} " in result.stdout


def test_realtime_paces_to_the_wall_clock(invoke, write_scene):
    import time
    start = time.perf_counter()
    result = invoke("run", write_scene(BALL.replace("duration: 1.0", "duration: 0.3")),
                    "--realtime")
    assert result.exit_code == 0
    assert time.perf_counter() - start >= 0.3
    assert "realtime: missed " in result.stdout and " of 15 frame deadlines" in result.stdout


def test_bad_scene_exits_2_with_located_errors(invoke, write_scene):
    path = write_scene("vrsim: 1\nduration: 1\nbodies: [{name: b, mass: 1, restitutoin: 1}]\n")
    result = invoke("run", path)
    assert result.exit_code == 2
    # The list of allowed keys grows with the format; its start and one line are fixed.
    assert result.stderr.startswith(f"error: {path}:3:29: bodies[0].restitutoin: unknown key "
                                    f"'restitutoin' (allowed here: name, type, shape, mass, "
                                    f"position, velocity, orientation, euler_deg, angle_deg, "
                                    f"color, material, forces")
    assert result.stderr.endswith(")\n") and result.stderr.count("\n") == 1
    assert "Traceback" not in result.output


def test_missing_scene_exits_2(invoke, tmp_path):
    result = invoke("run", tmp_path / "none.yaml")
    assert result.exit_code == 2 and "no such file" in result.stderr


@pytest.mark.parametrize("args,message", [
    (["-o", "x.txt"], "cannot tell the format of 'x.txt'"),
    (["-o", "/nonexistent-dir/x.csv"], "folder '/nonexistent-dir' does not exist"),
    (["--format", "csv"], "--format needs -o/--output"),
    (["--dt", "-1"], "Invalid value for '--dt'"),
    (["--integrator", "heun"], "Invalid value for '--integrator'"),
])
def test_usage_errors_exit_2(invoke, write_scene, args, message):
    result = invoke("run", write_scene(BALL), *args)
    assert result.exit_code == 2 and message in result.stderr


def test_blow_up_exits_1_and_keeps_the_output(invoke, write_scene, tmp_path):
    # the largest force on the smallest mass vrsim takes: 1e24 m/s^2 moves it 1e20 m in one
    # step (symplectic Euler)
    scene = write_scene(BALL.replace(
        "bodies: [", "bodies: [{name: rocket, mass: 1.0e-9, "
                     "forces: [{force: [1.0e15, 0, 0], start: 0.5}]}, "))
    out = tmp_path / "o.csv"
    result = invoke("run", scene, "-o", out)
    assert result.exit_code == 1
    assert result.stderr.startswith("error: body 'rocket', t = 0.51 s: moved more than 1e+12 "
                                    "m from the origin")
    assert f"output up to the last good state kept in {out}" in result.stderr
    traj = read_trajectory(out)
    assert traj.tracks["rocket"].t[-1] == pytest.approx(0.5)  # the last good state


class _SmallDisk:
    """A file that takes `room` bytes and then fails like a full disk."""

    def __init__(self, file, room: int):
        self._file, self._room = file, room

    def write(self, data):
        self._room -= len(data)
        if self._room < 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self._file.write(data)

    def __getattr__(self, name):
        return getattr(self._file, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._file.close()


@pytest.mark.parametrize("name", ["o.csv", "o.mcap", "o.tum"])
def test_disk_full_leaves_the_previous_output_untouched(invoke, write_scene, tmp_path,
                                                        monkeypatch, name):
    out = tmp_path / name
    args = ["--format", "tum"] if name.endswith(".tum") else []
    if name.endswith(".tum"):
        out.mkdir()
        (out / "ball.tum").write_text("previous run\n")
    else:
        out.write_text("previous run\n")
    real_init = AtomicFile.__init__

    def small_disk_init(self, path):
        real_init(self, path)
        self.file = _SmallDisk(self.file, room=300)

    def small_disk_open(*args, **kwargs):  # TUM writes its folder with plain open()
        return _SmallDisk(open(*args, **kwargs), room=30)

    monkeypatch.setattr(AtomicFile, "__init__", small_disk_init)
    monkeypatch.setattr(tum_writer, "open", small_disk_open, raising=False)
    result = invoke("run", write_scene(BALL), "-o", out, *args)
    assert result.exit_code == 1
    assert "No space left on device" in result.stderr and "Traceback" not in result.output
    if name.endswith(".tum"):
        assert (out / "ball.tum").read_text() == "previous run\n"
        assert [p.name for p in out.iterdir()] == ["ball.tum"]
    else:
        assert out.read_text() == "previous run\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, "scene.yaml"])


def test_validate(invoke, write_scene, tmp_path):
    good = write_scene(BALL, "good.yaml")
    bad = write_scene("vrsim: 1\nduration: x\n", "bad.yaml")
    result = invoke("validate", good)
    assert result.exit_code == 0
    assert result.stdout == f"{good}: ok (1 body, 1 s in 100 steps of 0.01 s, symplectic-euler)\n"
    result = invoke("validate", good, bad)
    assert result.exit_code == 2
    assert f"{good}: ok" in result.stdout
    assert f"error: {bad}:2:11: duration: expected a number" in result.stderr


def test_every_shipped_scenario_validates(invoke):
    files = sorted(SCENARIOS.glob("*.yaml"))
    assert files
    result = invoke("validate", *files)
    assert result.exit_code == 0, result.output


def test_schema_prints_the_json_schema(invoke):
    result = invoke("schema")
    schema = json.loads(result.stdout)
    assert schema["$schema"].endswith("2020-12/schema")
    assert "bodies" in schema["properties"]


def test_info(invoke, write_scene, tmp_path):
    out = tmp_path / "o.mcap"
    invoke("run", write_scene(BALL), "-o", out)
    result = invoke("info", out)
    assert result.exit_code == 0
    assert result.stdout.splitlines()[:3] == [
        f"{out}: mcap, 1 entity, 51 samples", "time: 0 .. 1 s (duration 1 s)",
        "entities: ball"]
    # a table whose columns fit the longest topic and schema, numbers right-aligned
    table = result.stdout.split("channels:\n")[1].splitlines()[:4]
    assert table[0].split() == ["topic", "schema", "messages"]
    assert sorted(line.split() for line in table[1:]) == [
        ["/scene", "foxglove.SceneUpdate", "1"], ["/tf", "foxglove.FrameTransforms", "51"],
        ["/vrsim/state", "vrsim.State", "51"]]
    assert len({line.index(" foxglove.") if " foxglove." in line else line.index(" vrsim.")
                for line in table[1:]}) == 1
    assert len({len(line) for line in table}) == 1
    data = json.loads(invoke("info", out, "--json").stdout)
    assert data["samples"] == 51 and data["vrsim"]["integrator"] == "symplectic-euler"


@pytest.mark.parametrize("content,message", [
    (b"garbage", "not a readable MCAP file"),
    (b"", "not a readable MCAP file"),
])
def test_info_on_a_broken_mcap_exits_2(invoke, tmp_path, content, message):
    path = tmp_path / "broken.mcap"
    path.write_bytes(content)
    result = invoke("info", path)
    assert result.exit_code == 2 and message in result.stderr


def test_info_on_a_broken_csv_exits_2(invoke, tmp_path):
    path = tmp_path / "broken.csv"
    path.write_text("t,entity,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz\n0,a,1,2\n")
    result = invoke("info", path)
    assert result.exit_code == 2
    assert result.stderr == f"error: {path}:2:1: expected 15 columns, got 4\n"


def test_version(invoke):
    from vrsim_cli import __version__
    assert invoke("--version").stdout.strip() == f"vrsim, version {__version__}"


def test_progress_bar_on_a_terminal_for_long_runs(write_scene, monkeypatch):
    import io
    import vrsim_cli.cli as cli_module
    from vrsim_cli import text
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.stages.dynamics.motion import step

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    terminal = Terminal()
    monkeypatch.setattr(text.sys, "stderr", terminal)
    monkeypatch.setattr(text, "PROGRESS_AFTER_S", 0.0)
    model = compile_model(load_scene(write_scene(BALL)))
    progress = cli_module._RunProgress(model, enabled=True)
    state = make_state(model)
    for _ in range(50):
        state = step(model, state)
    progress(state)
    assert "[##########          ]  50%  t = 0.5 / 1 s, " in terminal.getvalue()
    assert "x real time, " in terminal.getvalue() and " left" in terminal.getvalue()
    progress.clear()
    assert terminal.getvalue().endswith("\r")
    quiet = cli_module._RunProgress(model, enabled=False)
    quiet(state)
    assert terminal.getvalue().count("%") == 1


def test_tum_output_refuses_to_mix_runs_and_removes_nothing(invoke, write_scene, tmp_path):
    """A .tum file of an entity this run does not have is neither deleted nor left beside
    the new files: the run is refused before it starts, and the folder stays as it was."""
    out = tmp_path / "tum"
    out.mkdir()
    (out / "stale.tum").write_text("0 0 0 0 0 0 0 1\n")
    result = invoke("run", write_scene(BALL), "-o", out, "--format", "tum")
    assert result.exit_code == 2
    assert "holds 'stale.tum' of entities this run does not have" in result.stderr
    assert sorted(p.name for p in out.iterdir()) == ["stale.tum"]
    (out / "stale.tum").unlink()
    assert invoke("run", write_scene(BALL), "-o", out, "--format", "tum").exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == ["ball.tum"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.yaml", "tum"]


@pytest.mark.parametrize("args,message", [
    (["--duration", "nan"], "'nan' is not a finite number"),
    (["--duration", "inf"], "'inf' is not a finite number"),
    (["--dt", "1e-300"], "dt: must be >= 1e-09"),
    (["--duration", "1e300"], "duration: must be <= 1000000"),
    (["--duration", "1e-300"], "is shorter than one physics step"),
])
def test_extreme_option_values_are_input_errors(invoke, write_scene, args, message):
    result = invoke("run", write_scene(BALL), *args)
    assert result.exit_code == 2 and message in result.stderr, result.stderr
    assert "Traceback" not in result.output


def test_output_may_not_overwrite_the_scene(invoke, write_scene, tmp_path):
    scene = write_scene(BALL)
    result = invoke("run", scene, "-o", scene, "--format", "csv")
    assert result.exit_code == 2 and "would overwrite the scene file" in result.stderr
    assert invoke("run", scene, "-o", scene, "--format", "tum").exit_code == 2


ISSUE_EXAMPLE = """
vrsim: 1                 # format version
name: bouncing-ball
dimension: 3             # 2 or 3
duration: 4.0            # s
frame_rate: 90           # Hz
dt: 0.001                # s
integrator: symplectic-euler
gravity: [0, -9.81, 0]   # m/s^2
observer: {mode: walk, position: [0, 1.6, 0], direction: [0, 0, 1], v_max: 2.0, gamma_max: 100}
input:
  mouse: [{t: 0.0, alpha: 0.5, beta: 0.0}, {t: 1.0, alpha: 0.0, beta: -1.0}]
bodies:
  - name: ball
    type: dynamic
    shape: {type: sphere, radius: 0.1}
    mass: 1.0
    position: [0, 1.1, 0]
    velocity: [0, 0, 0]
    orientation: [1, 0, 0, 0]
    material: {restitution: 0.8, friction: 0.5}
    color: [0.9, 0.2, 0.2]
output: {file: ball.mcap, rate: 90}
"""


def test_the_foundation_issues_example_scene_runs_and_says_what_is_unused(invoke, write_scene,
                                                                          tmp_path):
    result = invoke("run", write_scene(ISSUE_EXAMPLE))
    assert result.exit_code == 0, result.stderr
    assert "note: material (restitution, friction) of 1 body, first bodies[0], has no " \
           "effect without a top-level collision block" in result.stderr
    assert "dt = 0.001 s does not divide the frame interval 1/90 s" in result.stderr
    assert set(read_trajectory(tmp_path / "ball.mcap").tracks) == {"ball", "observer"}


def test_compile_notice_reports_only_what_this_run_compiled(invoke, write_scene, tmp_path,
                                                             monkeypatch):
    """A process that compiled kernels earlier (an API user, this suite on a fresh machine)
    must not announce that compile again on every later run: the notice is the seconds
    compiled by this run's prepare, not the process total."""
    from vrsim_cli.kernels import jit

    scene = write_scene(BALL)
    assert invoke("run", scene, "-o", tmp_path / "warm.csv").exit_code == 0
    monkeypatch.setattr(jit._WATCH, "seconds", jit._WATCH.seconds + 31.0)  # an earlier compile
    result = invoke("run", scene, "-o", tmp_path / "o.csv")
    assert result.exit_code == 0
    assert "compiled in" not in result.stderr, result.stderr


def test_the_collector_is_paused_for_start_up_only(tmp_path):
    """`vrsim` (its entry point, `__main__.main`) pauses the garbage collector while
    numpy, numba and the kernels load, and `vrsim run` turns it on, with start-up's
    objects frozen, before the first step: a long run must not pile up cycles."""
    import subprocess
    import sys

    child = f"""
import gc, sys
import vrsim_cli.loop as loop
seen = []
original = loop.run
def spy(*args, **kwargs):
    seen.append((gc.isenabled(), gc.get_freeze_count() > 0))
    return original(*args, **kwargs)
loop.run = spy
sys.argv = ["vrsim", "run", {str(SCENARIOS / "projectile.yaml")!r}, "-q",
            "-o", {str(tmp_path / "p.csv")!r}]
from vrsim_cli.__main__ import main
assert gc.isenabled()
try:
    main()
except SystemExit as exc:
    assert not exc.code, exc.code
print(seen)
"""
    proc = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == "[(True, True)]"


# ----------------------------------------------------------------------------- issue 52


def test_default_dt_and_frame_rate_say_nothing(invoke, write_scene):
    """The defaults (1 ms, 60 Hz) do not divide: the note came on every scene. Now only a
    scene that writes both numbers hears it, once; the summary shows the dt used."""
    bare = BALL.replace("frame_rate: 50\ndt: 0.01\n", "")
    for text in (bare, bare + "dt: 0.001\n", bare + "frame_rate: 60\n"):
        result = invoke("run", write_scene(text))
        assert result.exit_code == 0
        assert "does not divide" not in result.stderr
        assert "steps of 0.000980392 s" in result.stdout
    result = invoke("run", write_scene(bare + "dt: 0.001\nframe_rate: 60\n"))
    assert result.stderr.count("does not divide") == 1
    result = invoke("run", write_scene(bare + "frame_rate: 60\n"), "--dt", "0.001")
    assert result.stderr.count("does not divide") == 1  # --dt is the user's number too


@pytest.mark.parametrize("gravity, up, note", [
    ("[0, 0, -9.81]", "z", "output.up is z, from gravity [0, 0, -9.81]"),
    ("[0, -9.81, 0]", "y", None),
    ("[0, 0, 0]", "y", None),
    ("[9.81, 0, 0]", "y", "points along neither -y nor -z"),
])
def test_output_up_follows_gravity_when_not_given(write_scene, gravity, up, note):
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene

    model = compile_model(load_scene(write_scene(BALL + f"gravity: {gravity}\n")))
    assert model.output.up == up
    said = [n for n in model.notes if "output.up" in n]
    assert (said[0].startswith(note) or note in said[0]) if note else not said
    written = compile_model(load_scene(write_scene(
        BALL + f"gravity: {gravity}\noutput: {{up: y}}\n")))
    assert written.output.up == "y" and not [n for n in written.notes if "output.up" in n]


def test_a_z_up_scene_stands_upright_in_the_mcap(invoke, write_scene, tmp_path):
    """The MCAP's scene frame hangs under Foxglove's z-up world without a turn when up is
    z: gravity [0, 0, -g] points down there (docs/outputs.md)."""
    from mcap.reader import make_reader

    out = tmp_path / "o.mcap"
    result = invoke("run", write_scene(BALL + "gravity: [0, 0, -9.81]\n"), "-o", out)
    assert result.exit_code == 0 and "output.up is z" in result.stderr
    with open(out, "rb") as f:
        meta = {r.name: dict(r.metadata) for r in make_reader(f).iter_metadata()}
    assert meta["vrsim"]["up"] == "z"


def test_validate_json(invoke, write_scene):
    good = write_scene(BALL)
    bad = write_scene(BALL.replace("mass: 1", "mass: -1"), "bad.yaml")
    result = invoke("validate", "--json", good, bad)
    assert result.exit_code == 2 and result.stderr == ""
    reports = json.loads(result.stdout)
    assert [r["ok"] for r in reports] == [True, False]
    assert reports[0]["bodies"] == 1 and reports[0]["steps"] == 100
    assert reports[0]["dt_s"] == 0.01 and reports[0]["integrator"] == "symplectic-euler"
    problem = reports[1]["problems"][0]
    assert problem["file"] == str(bad) and problem["line"] == 6
    assert problem["key"] == "bodies[0].mass" and "0" in problem["message"]
    text = invoke("validate", bad)
    assert f"{bad}:{problem['line']}:{problem['column']}" in text.stderr  # the same place
    assert invoke("validate", "--json", good).exit_code == 0
