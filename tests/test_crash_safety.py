"""No run loses data, and no scene writes where the user did not ask: blow-ups, signals
(also while the output is being finalised), full disks, paths and symlinks, YAML tags."""

from __future__ import annotations

import errno
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import REPO
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.writers import atomic, tum_writer

BALL = """
vrsim: 1
name: drop
duration: 1.0
frame_rate: 50
dt: 0.01
bodies: [{name: ball, mass: 1, position: [0, 10, 0]}, {name: box, mass: 2}]
"""


def out_args(tmp_path, fmt: str):
    """(output path, extra options) for a format; TUM writes a folder."""
    if fmt == "tum":
        return tmp_path / "out", ["--format", "tum"]
    return tmp_path / f"out.{fmt}", []


# ----------------------------------------------------------------------------- blow-ups


@pytest.mark.parametrize("fmt", ["csv", "mcap", "tum"])
@pytest.mark.parametrize("body,message,last_good", [
    # 1e15 N on 1e-9 kg (the largest force, smallest mass vrsim takes): 1e20 m in a step
    ("{name: rocket, mass: 1.0e-9, forces: [{force: [1.0e15, 0, 0], start: 0.5}]}",
     "body 'rocket', t = 0.51 s: moved more than 1e+12 m from the origin", 0.5),
    # 1e8 m/s from 1e12 - 5e5 m crosses 1e12 m after 0.005 s: in the first step of 0.01 s
    ("{name: probe, type: kinematic, position: [9.999995e11, 0, 0], velocity: [1.0e8, 0, 0]}",
     "body 'probe', t = 0.01 s: moved more than 1e+12 m from the origin", 0.0),
])
def test_blow_up_exits_1_naming_body_and_time_and_keeps_the_output(
        invoke, write_scene, tmp_path, fmt, body, message, last_good):
    scene = write_scene(BALL.replace("bodies: [", f"bodies: [{body}, "))
    out, extra = out_args(tmp_path, fmt)
    result = invoke("run", scene, "-o", out, *extra)
    assert result.exit_code == 1
    assert result.stderr.startswith(f"error: {message}"), result.stderr
    assert f"output up to the last good state kept in {out}" in result.stderr
    traj = read_trajectory(out)
    name = body.split(",")[0].split(": ")[1]
    assert traj.tracks[name].t[-1] == pytest.approx(last_good, abs=1e-12)
    assert not [p for p in tmp_path.rglob("*.partial")]


# ----------------------------------------------------------------------------- signals

LONG = BALL.replace("duration: 1.0", "duration: 60")


def test_sigint_mid_run_finalises_a_tum_folder(write_scene, tmp_path):
    scene = write_scene(LONG)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "vrsim_cli", "run", str(scene), "-o",
                             str(out), "--format", "tum", "--realtime"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # TUM files appear only when the run ends, the folder when the writer opens: wait for
    # it (imports and kernel loading take from 0.5 s to many seconds on a loaded machine;
    # a signal before the writer opens exits at once, on purpose), run 1 s, interrupt
    deadline = time.monotonic() + 60
    while not out.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(1.0)
    assert proc.poll() is None
    proc.send_signal(signal.SIGINT)
    _stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 130, stderr
    traj = read_trajectory(out)
    times = traj.tracks["ball"].t
    assert 0.2 < times[-1] < 60 and len(times) == round(times[-1] * 50) + 1
    assert sorted(p.name for p in out.iterdir()) == ["ball.tum", "box.tum"]


# Runs `vrsim run` with the flush to disk of the output patched to signal the process
# itself first: the signal arrives while the output is being finalised, before it is in
# place (AtomicFile.sync: CSV and MCAP once, TUM once per entity file).
SIGNAL_IN_COMMIT = """
import os, signal, sys
from vrsim_cli.writers.atomic import AtomicFile
real_sync = AtomicFile.sync
sent = []
def sync(self):
    if not sent:  # once: a second signal would discard the output on purpose
        sent.append(os.kill(os.getpid(), signal.{sig}))
    real_sync(self)
AtomicFile.sync = sync
from vrsim_cli.cli import main
sys.argv = ["vrsim", "run", {scene!r}, "-o", {out!r}] + {extra!r}
main()
"""


@pytest.mark.parametrize("sig,fmt", [("SIGTERM", "mcap"), ("SIGINT", "csv"),
                                     ("SIGTERM", "tum")])
def test_signal_while_the_output_is_finalised(write_scene, tmp_path, sig, fmt):
    scene = write_scene(BALL)
    out, extra = out_args(tmp_path, fmt)
    code = SIGNAL_IN_COMMIT.format(sig=sig, scene=str(scene), out=str(out), extra=extra)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=REPO, timeout=60)
    assert proc.returncode == 128 + getattr(signal, sig), proc.stderr
    assert f"interrupted by {sig} at t = 1 s; output finalised" in proc.stderr
    assert len(read_trajectory(out).tracks["ball"].t) == 51  # the whole run
    assert not [p for p in tmp_path.rglob("*.partial")]


# ----------------------------------------------------------------------------- full disk


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_disk_full_at_fsync_leaves_the_previous_output(invoke, write_scene, tmp_path,
                                                       monkeypatch, fmt):
    """Some file systems report a full disk only when the data is flushed (fsync)."""
    out, extra = out_args(tmp_path, fmt)
    out.write_text("previous run\n")

    def no_space(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic.os, "fsync", no_space)
    result = invoke("run", write_scene(BALL), "-o", out, *extra)
    assert result.exit_code == 1 and "No space left on device" in result.stderr
    assert out.read_text() == "previous run\n"
    assert not [p for p in tmp_path.rglob("*.partial")]


def _disk_full_at(monkeypatch, file_name: str) -> None:
    """Make the flush to disk of `file_name`'s temporary file fail like a full disk."""
    real_fsync = atomic.os.fsync

    def fsync(fd):
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith(f".{file_name}."):
            raise OSError(errno.ENOSPC, "No space left on device")
        real_fsync(fd)

    monkeypatch.setattr(atomic.os, "fsync", fsync)


def test_tum_folder_is_not_half_replaced_when_a_later_file_fails(invoke, write_scene,
                                                                 tmp_path, monkeypatch):
    """When box.tum cannot be written, ball.tum (written first) must still be the previous
    one, and no temporary file is left beside them."""
    out = tmp_path / "out"
    out.mkdir()
    for name in ("ball", "box"):
        (out / f"{name}.tum").write_text(f"previous {name}\n")
    _disk_full_at(monkeypatch, "box.tum")
    result = invoke("run", write_scene(BALL), "-o", out, "--format", "tum")
    assert result.exit_code == 1 and "No space left on device" in result.stderr
    assert (out / "ball.tum").read_text() == "previous ball\n"
    assert (out / "box.tum").read_text() == "previous box\n"
    assert sorted(p.name for p in out.iterdir()) == ["ball.tum", "box.tum"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "scene.yaml"]


def test_failed_tum_run_leaves_no_folder_behind(invoke, write_scene, tmp_path, monkeypatch):
    _disk_full_at(monkeypatch, "ball.tum")
    out = tmp_path / "new"
    assert invoke("run", write_scene(BALL), "-o", out, "--format", "tum").exit_code == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.yaml"]


# ----------------------------------------------------------------------------- where a scene may write


@pytest.fixture
def folders(tmp_path, monkeypatch):
    """(scene folder, a folder outside it holding a file 'secret.txt'); the test runs in
    the scene folder (a scene's outputs are relative to the current folder)."""
    inside, outside = tmp_path / "scene", tmp_path / "outside"
    inside.mkdir()
    outside.mkdir()
    (outside / "secret.txt").write_text("secret\n")
    monkeypatch.chdir(inside)
    return inside, outside


def listing(folder):
    return sorted((str(p.relative_to(folder)), p.read_bytes() if p.is_file() else b"")
                  for p in folder.rglob("*"))


@pytest.mark.parametrize("target", ["../outside/out.csv", "{outside}/out.csv",
                                    "sub/../../outside/out.csv",
                                    "link/out.csv", "secret-link", "link"])
def test_scene_output_outside_its_folder_is_refused(invoke, folders, target):
    inside, outside = folders
    (inside / "link").symlink_to(outside, target_is_directory=True)
    (inside / "secret-link").symlink_to(outside / "secret.txt")
    before = listing(outside)
    target = target.format(outside=outside)
    fmt = ", format: tum" if target == "link" else (", format: csv" if "secret" in target
                                                      else "")
    scene = inside / "scene.yaml"
    scene.write_text(BALL + f"output: {{file: '{target}'{fmt}}}\n")
    result = invoke("run", scene)
    assert result.exit_code == 2
    assert "output.file: path" in result.stderr and "leaves the current folder" in \
        result.stderr
    assert listing(outside) == before


def test_a_tilde_is_not_the_home_folder_in_a_scene(invoke, folders):
    """`~` is expanded for -o (the user's shell habit) but not in a scene: there it is a
    folder name inside the current folder, which here does not exist."""
    inside, _outside = folders
    scene = inside / "scene.yaml"
    scene.write_text(BALL + "output: {file: ~/vrsim-test-out.csv}\n")
    result = invoke("run", scene)
    assert result.exit_code == 2
    assert f"output.file: folder '{inside}/~' does not exist" in result.stderr
    assert not os.path.exists(os.path.expanduser("~/vrsim-test-out.csv"))


def test_mesh_symlink_cannot_read_a_file_outside(invoke, folders):
    """A mesh is embedded in MCAP output: a link to a file outside would leak it."""
    inside, outside = folders
    (inside / "bunny.stl").symlink_to(outside / "secret.txt")
    scene = inside / "scene.yaml"
    scene.write_text(BALL.replace("bodies: [", "bodies: [{name: bunny, type: static, shape: "
                                               "{type: mesh, file: bunny.stl}}, "))
    result = invoke("run", scene, "-o", inside / "out.mcap")
    assert result.exit_code == 2 and "leaves the scene file's folder" in result.stderr
    assert not (inside / "out.mcap").exists()


def test_tum_output_refuses_a_planted_symlink_in_its_folder(invoke, folders):
    """A link named like an entity file is not a TUM trajectory vrsim wrote: refused, so
    neither the link nor the file it points to changes."""
    inside, outside = folders
    (inside / "out").mkdir()
    (inside / "out" / "ball.tum").symlink_to(outside / "secret.txt")
    scene = inside / "scene.yaml"
    scene.write_text(BALL + "output: {file: out, format: tum}\n")
    result = invoke("run", scene)
    assert result.exit_code == 2, result.output
    assert "output.file: 'out' holds 'ball.tum' besides TUM trajectories" in result.stderr
    assert (outside / "secret.txt").read_text() == "secret\n"
    assert (inside / "out" / "ball.tum").is_symlink()


@pytest.mark.parametrize("target,message", [
    ("scene.yaml", "the output would overwrite the scene file itself"),
    (".", "'.' is a folder; csv output is a file"),
])
def test_scene_output_may_not_destroy_the_scene_or_aim_at_a_folder(invoke, folders, target,
                                                                   message):
    inside, _outside = folders
    scene = inside / "scene.yaml"
    text = BALL + f"output: {{file: '{target}', format: csv}}\n"
    scene.write_text(text)
    result = invoke("run", scene)
    assert result.exit_code == 2 and f"output.file: {message}" in result.stderr
    assert scene.read_text() == text


@pytest.mark.parametrize("tag", [
    "!!python/object/apply:os.system ['touch {pwned}']",
    "!!python/object/new:os.system ['touch {pwned}']",
    "!!python/name:os.system",
    "!!python/module:os",
    "!!python/object/apply:subprocess.check_call [['touch', '{pwned}']]",
])
def test_python_yaml_tags_execute_nothing(invoke, folders, tag):
    inside, outside = folders
    pwned = outside / "pwned"
    scene = inside / "scene.yaml"
    scene.write_text(BALL + "description: " + tag.format(pwned=pwned) + "\n")
    for command in ("validate", "run"):
        result = invoke(command, scene)
        assert result.exit_code == 2 and "YAML tag not allowed" in result.stderr
    assert not pwned.exists()


def test_a_written_orientation_that_is_not_a_unit_quaternion_stops_the_run():
    """Issue 19, item 7: every sample's orientations are checked, not only positions and
    velocities. A state whose quaternion has drifted off the unit sphere (here set by
    hand, as a bug or an overflow would) stops with the body and time named; finite
    unit quaternions pass."""
    import numpy as np

    from vrsim_cli.errors import SimulationError
    from vrsim_cli.loop import check_orientations
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene

    model = compile_model(parse_scene(
        "vrsim: 1\nname: q\nduration: 0.1\nbodies:\n"
        "  - {name: a, mass: 1, shape: {type: box, size: [1, 1, 1]}}\n"
        "  - {name: b, mass: 1, shape: {type: box, size: [1, 2, 1]}}\n"))
    state = make_state(model)
    check_orientations(model, state)
    for bad in ([1.0, 1e-4, 0, 0], [np.nan, 0, 0, 0], [0.0, 0, 0, 0]):
        quat = state.body_quat.copy()
        quat[1] = bad
        with pytest.raises(SimulationError, match="orientation is not a unit quaternion") as e:
            check_orientations(model, state.replace(body_quat=quat))
        assert "'b'" in str(e.value) and "t = 0 s" in str(e.value)
