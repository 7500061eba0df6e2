"""No output ever removes or replaces anything but its own target file or a folder it made.

- TUM output never swaps or empties a folder: a folder holding anything but TUM files (the
  scene's own folder, the working directory) is refused, and so are `.tum` files of other
  entities; a missing folder is created with the usual permissions.
- Device nodes, FIFOs, sockets, symbolic links and folders are refused as file targets
  (from -o and from a scene), before the run and again right before the rename; `-o -`
  writes to standard output on purpose.
- Temporary files of killed runs are removed by a later run: only ours (by name, owner,
  age and lock).
- Fault injection: runs killed with SIGINT, SIGTERM and SIGKILL at chosen points of each
  writer (opened, after sample k, flushing, before and after the rename), at random times,
  and with a file-size limit that fails writes like a full disk at a random byte: the
  previous output and every other file in the folder stay intact, and the target is
  always either the previous output or a complete trajectory (a prefix of the full run,
  bit for bit, when a signal finalised it).
"""

from __future__ import annotations

import os
import random
import resource
import signal
import socket
import stat
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO
from vrsim_cli.errors import OutputError
from vrsim_cli.scene import files
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.writers.atomic import AtomicFile

SCENE = """vrsim: 1
name: drop
duration: 1.0
frame_rate: 50
dt: 0.01
bodies: [{name: ball, mass: 1, position: [0, 10, 0], velocity: [1, 0, 0]},
         {name: box, mass: 2, shape: {type: box, size: [1, 1, 1]}, angular_velocity: [0, 1, 2]}]
"""
FORMATS = ("csv", "mcap", "tum")


def snapshot(folder: Path) -> dict:
    """Every entry under `folder` (not following links): kind, and content of files."""
    out = {}
    for path in sorted(folder.rglob("*")):
        st = os.lstat(path)
        content = path.read_bytes() if stat.S_ISREG(st.st_mode) else \
            os.readlink(path) if stat.S_ISLNK(st.st_mode) else None
        out[str(path.relative_to(folder))] = (stat.S_IFMT(st.st_mode), content)
    return out


def target_of(folder: Path, fmt: str) -> tuple[Path, list]:
    return (folder / "out", ["--format", "tum"]) if fmt == "tum" else \
        (folder / f"out.{fmt}", [])


# ----------------------------------------------------------------------------- TUM folders


def test_tum_output_into_the_scene_folder_is_refused_and_removes_nothing(invoke, tmp_path):
    """The issue's case: `output: {file: ., format: tum}` passed validate and the run
    deleted the scene's folder, scene included."""
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE + "output: {file: ., format: tum}\n")
    (tmp_path / "notes.txt").write_text("mine\n")
    before = snapshot(tmp_path)
    for command in ("validate", "run"):
        result = invoke(command, scene)
        assert result.exit_code == 2, result.output
        assert "output.file: '.' holds the scene file 'scene.yaml'; tum output needs a " \
               "folder of its own" in result.stderr
    assert snapshot(tmp_path) == before
    assert stat.S_IMODE(os.stat(tmp_path).st_mode) != 0o700 or before == snapshot(tmp_path)


@pytest.mark.parametrize("content", [["notes.txt"], ["sub/"], ["ball.tum", "readme.md"],
                                     ["link.tum->notes"]])
def test_tum_output_into_a_folder_with_other_files_is_refused(invoke, write_scene, tmp_path,
                                                              content):
    """`vrsim run scene.yaml -o "$PWD" --format tum` wiped the working directory."""
    folder = tmp_path / "work"
    folder.mkdir()
    (tmp_path / "notes").write_text("outside\n")
    for entry in content:
        if entry.endswith("/"):
            (folder / entry).mkdir()
        elif "->" in entry:
            name, to = entry.split("->")
            (folder / name).symlink_to(tmp_path / to)
        else:
            (folder / entry).write_text(f"{entry}\n")
    scene = write_scene(SCENE)
    before = snapshot(tmp_path)
    result = invoke("run", scene, "-o", folder, "--format", "tum")
    assert result.exit_code == 2 and "besides TUM trajectories" in result.stderr
    assert snapshot(tmp_path) == before


def test_tum_output_creates_a_missing_folder_with_the_usual_mode(invoke, write_scene,
                                                                 tmp_path):
    out = tmp_path / "new"
    assert invoke("run", write_scene(SCENE), "-o", out, "--format", "tum").exit_code == 0
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o777 & ~mask  # not mkdtemp's 0700
    assert sorted(p.name for p in out.iterdir()) == ["ball.tum", "box.tum"]


def test_tum_output_replaces_its_own_files_in_place(invoke, write_scene, tmp_path):
    """A second run replaces the files of the first, in the same folder (same inode: the
    folder is never swapped, so a shell sitting in it or a link to it keeps working)."""
    out = tmp_path / "out"
    scene = write_scene(SCENE)
    assert invoke("run", scene, "-o", out, "--format", "tum").exit_code == 0
    inode = os.stat(out).st_ino
    (out / "ball.tum").write_text("previous\n")
    assert invoke("run", scene, "-o", out, "--format", "tum").exit_code == 0
    assert os.stat(out).st_ino == inode
    assert len(read_trajectory(out).tracks["ball"].t) == 51


def test_tum_output_is_limited_to_256_entities(invoke, write_scene, tmp_path):
    scene = write_scene(SCENE + "emitters: [{name: e, count: 300, rate: 100, speed: 1, "
                                "mass: 1}]\n")
    result = invoke("run", scene, "-o", tmp_path / "out", "--format", "tum")
    assert result.exit_code == 2
    assert "tum output writes one file per entity, at most 256; this scene has 302" in \
        result.stderr
    assert not (tmp_path / "out").exists()


# ----------------------------------------------------------------------------- special files


def make_special(folder: Path, kind: str) -> Path:
    """A target of `kind` in `folder` (links point at a file 'victim' beside it)."""
    victim = folder / "victim"
    victim.write_text("victim\n")
    path = folder / "target"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(path))
        sock.close()
    elif kind == "link-to-file":
        path.symlink_to(victim)
    elif kind == "dangling-link":
        path.symlink_to(folder / "nowhere")
    elif kind == "link-to-dev-null":
        path.symlink_to("/dev/null")
    elif kind == "folder":
        path.mkdir()
        (path / "inside").write_text("inside\n")
    return path


SPECIAL = ["fifo", "socket", "link-to-file", "dangling-link", "link-to-dev-null", "folder"]


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
@pytest.mark.parametrize("kind", SPECIAL)
def test_special_targets_are_refused_on_the_command_line(invoke, write_scene, tmp_path, fmt,
                                                         kind):
    target = make_special(tmp_path, kind)
    scene = write_scene(SCENE)
    before = snapshot(tmp_path)
    result = invoke("run", scene, "-o", target, "--format", fmt)
    assert result.exit_code == 2, result.output
    assert "'" + str(target) + "' is " in result.stderr
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("kind", SPECIAL)
def test_special_targets_are_refused_in_a_scene(invoke, tmp_path, kind):
    target = make_special(tmp_path, kind)
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE + f"output: {{file: {target.name}, format: csv}}\n")
    before = snapshot(tmp_path)
    for command in ("validate", "run"):
        result = invoke(command, scene)
        assert result.exit_code == 2, result.output
        assert "output.file: " in result.stderr
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("device", ["/dev/null", "/dev/full", "/dev/stdout", "/dev/zero"])
def test_device_targets_stay_devices(invoke, write_scene, device):
    """As root, `-o /dev/full --format csv` exited 0 and made /dev/full a regular file."""
    before = os.lstat(device)
    result = invoke("run", write_scene(SCENE), "-o", device, "--format", "csv")
    assert result.exit_code == 2
    if device == "/dev/stdout":
        assert "use -o - to write to standard output" in result.stderr
    after = os.lstat(device)
    assert (after.st_mode, after.st_ino, after.st_rdev) == (before.st_mode, before.st_ino,
                                                            before.st_rdev)


def test_a_target_that_changes_kind_during_the_run_is_not_replaced(tmp_path):
    """Checked before the run and again right before the rename."""
    path = tmp_path / "out.csv"
    out = AtomicFile(path)
    out.write(b"data\n")
    os.mkfifo(path)  # someone puts a FIFO there while the run goes on
    with pytest.raises(OutputError, match="FIFO"):
        out.commit()
    assert stat.S_ISFIFO(os.lstat(path).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_a_replaced_file_keeps_its_permissions(invoke, write_scene, tmp_path):
    out = tmp_path / "out.csv"
    out.write_text("previous\n")
    out.chmod(0o600)
    assert invoke("run", write_scene(SCENE), "-o", out).exit_code == 0
    assert stat.S_IMODE(os.stat(out).st_mode) == 0o600
    assert out.read_text().startswith("t,entity,")


def test_a_file_name_too_long_for_the_file_system_is_a_usage_error(invoke, write_scene,
                                                                   tmp_path):
    """A 300-character name gave an OSError traceback."""
    result = invoke("run", write_scene(SCENE), "-o", tmp_path / ("a" * 300 + ".csv"))
    assert result.exit_code == 2
    assert "the file name is 304 bytes long; at most 237 fit" in result.stderr
    limit = files.name_max(tmp_path) - files.PARTIAL_OVERHEAD
    assert invoke("run", write_scene(SCENE), "-o",
                  tmp_path / ("b" * (limit - 4) + ".csv")).exit_code == 0


# ----------------------------------------------------------------------------- standard output


def vrsim(*args, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vrsim_cli", *map(str, args)], cwd=REPO,
                          capture_output=True, timeout=120, **kwargs)


@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_dash_writes_the_trajectory_to_standard_output(write_scene, tmp_path, fmt):
    scene = write_scene(SCENE)
    piped = vrsim("run", scene, "-o", "-", "--format", fmt)
    assert piped.returncode == 0, piped.stderr
    assert b"-> standard output" in piped.stderr  # the summary moves to stderr
    (tmp_path / f"piped.{fmt}").write_bytes(piped.stdout)
    assert vrsim("run", scene, "-o", tmp_path / f"file.{fmt}", "-q").returncode == 0
    if fmt == "csv":
        assert piped.stdout == (tmp_path / "file.csv").read_bytes()
    a, b = read_trajectory(tmp_path / f"piped.{fmt}"), read_trajectory(tmp_path / f"file.{fmt}")
    for name in ("ball", "box"):
        np.testing.assert_array_equal(a.tracks[name].pos, b.tracks[name].pos)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"file.{fmt}", f"piped.{fmt}",
                                                          "scene.yaml"]


def test_dash_refuses_tum_and_a_closed_pipe_is_a_clean_failure(invoke, write_scene):
    result = invoke("run", write_scene(SCENE), "-o", "-", "--format", "tum")
    assert result.exit_code == 2 and "-o - writes csv or mcap" in result.stderr
    proc = subprocess.run(f"{sys.executable} -m vrsim_cli run {write_scene(SCENE)} -o - "
                          f"--duration 20 | head -c 10", shell=True, cwd=REPO,
                          capture_output=True, timeout=120)
    assert b"Traceback" not in proc.stderr and b"Exception ignored" not in proc.stderr
    assert proc.stdout == b"t,entity,p"


# ----------------------------------------------------------------------------- stale partials


def age(path: Path, seconds: float) -> None:
    then = time.time() - seconds
    os.utime(path, (then, then), follow_symlinks=False)


def test_stale_partials_of_killed_runs_are_removed_and_nothing_else(invoke, write_scene,
                                                                    tmp_path):
    import fcntl

    scene = write_scene(SCENE)
    out = tmp_path / "out.csv"
    stale = tmp_path / ".out.csv.abcd1234.partial"  # a killed run's, a minute and more ago
    fresh = tmp_path / ".out.csv.fresh123.partial"  # a run that may still be going
    locked = tmp_path / ".out.csv.locked12.partial"  # a live writer holds its lock
    other = tmp_path / ".other.csv.abcd1234.partial"  # another target's
    unlike = tmp_path / ".out.csv.partial"  # not a name vrsim makes
    link = tmp_path / ".out.csv.link1234.partial"  # a link is never ours
    for path in (stale, fresh, locked, other, unlike):
        path.write_text("x")
    link.symlink_to(tmp_path / "scene.yaml")
    for path in (stale, locked, other, unlike, link):
        age(path, 120)
    holder = os.open(locked, os.O_RDONLY)
    fcntl.flock(holder, fcntl.LOCK_EX)
    try:
        assert invoke("run", scene, "-o", out, "-q").exit_code == 0
    finally:
        os.close(holder)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        p.name for p in (fresh, locked, other, unlike, link, out, scene))


def test_stale_partials_in_a_tum_folder_are_removed(invoke, write_scene, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "ball.tum").write_text("previous\n")
    stale = out / ".gone.tum.abcd1234.partial"  # an entity of an earlier run
    stale.write_text("x")
    age(stale, 120)
    assert invoke("run", write_scene(SCENE), "-o", out, "--format", "tum").exit_code == 0
    assert sorted(p.name for p in out.iterdir()) == ["ball.tum", "box.tum"]


# ----------------------------------------------------------------------------- fault injection

# The child: `vrsim run` with one point patched to send the process a signal at its k-th
# pass. Points: open (the temporary file was just made), sample (the writer got sample k),
# sync (flushing to disk), rename (before os.replace), renamed (after it; TUM: between
# two files). `none` runs unpatched (optionally under a file-size limit).
CHILD = r"""
import os, resource, signal, sys
from vrsim_cli.writers import atomic, csv_writer, mcap_writer, tum_writer
point, sig, k, fsize = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
passes = [0]
def hit():
    passes[0] += 1
    if passes[0] == k:
        os.kill(os.getpid(), getattr(signal, sig))
def patch(owner, name, after):
    real = getattr(owner, name)
    def wrapper(*args, **kwargs):
        if not after:
            hit()
        result = real(*args, **kwargs)
        if after:
            hit()
        return result
    setattr(owner, name, wrapper)
if point == "open":
    patch(atomic.AtomicFile, "__init__", after=True)
elif point == "sample":
    for cls in (csv_writer.CsvWriter, mcap_writer.McapWriter, tum_writer.TumWriter):
        patch(cls, "write", after=True)
elif point == "sync":
    patch(atomic.AtomicFile, "sync", after=False)
elif point in ("rename", "renamed"):
    patch(atomic.os, "replace", after=point == "renamed")
if fsize >= 0:  # writes past fsize bytes fail with EFBIG, like a full disk
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))
sys.argv = ["vrsim"] + sys.argv[5:]
from vrsim_cli.__main__ import main
main()
"""
POINTS = {"open": 1, "sample": None, "sync": 1, "rename": 1, "renamed": 1}
SAMPLES = 51  # 1 s at 50 Hz, both ends
RNG = random.Random(19)  # derandomised: CI sees the same points every run


def child(tmp_path, fmt, point="none", sig="SIGINT", k=0, fsize=-1, extra=()):
    out, opts = target_of(tmp_path / "w", fmt)
    return subprocess.run([sys.executable, "-c", CHILD, point, sig, str(k), str(fsize),
                           "run", str(tmp_path / "w" / "scene.yaml"), "-o", str(out), "-q",
                           *opts, *extra], cwd=REPO, capture_output=True, text=True,
                          timeout=120)


@pytest.fixture(scope="module")
def references(tmp_path_factory):
    """The full, uninterrupted run's output in each format (and its bytes)."""
    root = tmp_path_factory.mktemp("reference")
    (root / "w").mkdir()
    (root / "w" / "scene.yaml").write_text(SCENE)
    refs = {}
    for fmt in FORMATS:
        proc = child(root, fmt)
        assert proc.returncode == 0, proc.stderr
        out, _ = target_of(root / "w", fmt)
        refs[fmt] = (read_trajectory(out), snapshot(root / "w") if fmt == "tum" else None,
                     out.read_bytes() if fmt != "tum" else None)
    return refs


def prepare(tmp_path: Path, fmt: str) -> tuple[Path, dict]:
    """A folder with the scene, a file of the user's and a previous output (TUM: the
    previous files in the output folder); returns (target, snapshot of it all)."""
    work = tmp_path / "w"
    work.mkdir()
    (work / "scene.yaml").write_text(SCENE)
    (work / "notes.txt").write_text("the user's own file\n")
    out, _ = target_of(work, fmt)
    if fmt == "tum":
        out.mkdir()
        for name in ("ball", "box"):
            (out / f"{name}.tum").write_text(f"0 0 0 0 0 0 0 1 previous {name}\n")
    else:
        out.write_bytes(b"previous output\n")
    return out, snapshot(work)


def check_outcome(tmp_path, fmt, before, reference, finalised: bool, killed: bool):
    """The user's files are untouched; each output file is the previous one or complete."""
    work = tmp_path / "w"
    after = snapshot(work)
    partials = [name for name in after if files.is_partial(Path(name).name)]
    assert killed or not partials, partials  # only SIGKILL may leave temporary files
    for name in ("scene.yaml", "notes.txt"):
        assert after[name] == before[name]
    assert set(after) - set(partials) == set(before), sorted(after)
    out, _ = target_of(work, fmt)
    traj_ref, _, bytes_ref = reference
    entity_files = [out / f"{n}.tum" for n in ("ball", "box")] if fmt == "tum" else [out]
    for path in entity_files:
        name = str(path.relative_to(work))
        if after[name] == before[name]:
            continue  # the previous output, untouched
        traj = read_trajectory(path)
        for entity, track in traj.tracks.items():
            full = traj_ref.tracks[entity]
            n = len(track.t)
            assert 1 <= n <= SAMPLES
            assert finalised or n == SAMPLES  # a kill never leaves a short file
            np.testing.assert_array_equal(track.t, full.t[:n])
            np.testing.assert_array_equal(track.pos, full.pos[:n])
            np.testing.assert_array_equal(track.quat, full.quat[:n])
        if fmt == "csv" and len(traj.tracks["ball"].t) == SAMPLES:
            assert path.read_bytes() == bytes_ref
    return partials


def rerun_cleans_up(tmp_path, fmt, partials, reference):
    """After a SIGKILL, the next run (once the leftovers are a minute old) removes them
    and writes the whole output."""
    for name in partials:
        age(tmp_path / "w" / name, 120)
    proc = child(tmp_path, fmt)
    assert proc.returncode == 0, proc.stderr
    after = snapshot(tmp_path / "w")
    assert not [n for n in after if files.is_partial(Path(n).name)]
    out, _ = target_of(tmp_path / "w", fmt)
    assert len(read_trajectory(out).tracks["ball"].t) == SAMPLES


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM", "SIGKILL"])
@pytest.mark.parametrize("point", list(POINTS))
def test_a_signal_at_any_point_of_a_writer_loses_nothing(tmp_path, references, fmt, sig,
                                                         point):
    k = POINTS[point] or RNG.randint(1, SAMPLES)
    if point == "renamed" and fmt == "tum":
        k = 1  # between the renames of ball.tum and box.tum
    out, before = prepare(tmp_path, fmt)
    proc = child(tmp_path, fmt, point, sig, k)
    expected = {"SIGINT": 130, "SIGTERM": 143, "SIGKILL": -9}[sig]
    assert proc.returncode == expected, (k, proc.stderr)
    assert "Traceback" not in proc.stderr
    if sig != "SIGKILL":
        assert f"interrupted by {sig} at t = " in proc.stderr, proc.stderr
    partials = check_outcome(tmp_path, fmt, before, references[fmt],
                             finalised=sig != "SIGKILL", killed=sig == "SIGKILL")
    if sig == "SIGKILL":
        rerun_cleans_up(tmp_path, fmt, partials, references[fmt])


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_full_disk_at_a_random_byte_keeps_the_previous_output(tmp_path, references, fmt):
    """RLIMIT_FSIZE makes every write past the limit fail with EFBIG, the way a full disk
    fails with ENOSPC: at three random sizes up to the full output's."""
    _, tum_files, bytes_ref = references[fmt]
    size = len(bytes_ref) if bytes_ref is not None else max(
        len(c) for n, (_, c) in tum_files.items() if n.endswith(".tum"))
    for trial in range(3):
        case = tmp_path / str(trial)
        case.mkdir()
        out, before = prepare(case, fmt)
        limit = RNG.randint(0, size - 1)
        proc = child(case, fmt, fsize=limit)
        assert proc.returncode == 1, (limit, proc.stderr)
        assert "File too large" in proc.stderr and "Traceback" not in proc.stderr
        assert snapshot(case / "w") == before, limit


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("part", [0.1, 0.3, 0.6])
def test_a_full_disk_is_said_once(tmp_path, references, fmt, part):
    """Issue 53: MCAP on a full disk kept the previous file and exited 1, but the SDK
    logged each later message's failure: ~42 000 lines of "error logging message:
    McapError(...)" for a long run (~2000 for this 20 s one: the SDK writes whole chunks,
    so a 1 s run fails only once). Every writer now says it once: -q leaves exactly the
    one error line, and the run stops at the failed write."""
    _, tum_files, bytes_ref = references[fmt]
    size = len(bytes_ref) if bytes_ref is not None else max(
        len(c) for n, (_, c) in tum_files.items() if n.endswith(".tum"))
    _, before = prepare(tmp_path, fmt)
    proc = child(tmp_path, fmt, fsize=int(part * size), extra=("--duration", "20"))
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: cannot write "), proc.stderr[:2000]
    assert "File too large" in lines[0]
    assert snapshot(tmp_path / "w") == before


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_a_signal_at_a_random_time_loses_nothing(tmp_path, references, fmt, sig):
    """Sent from outside at a random time of a 1 s realtime run: during start-up, scene
    loading, the run, or finalising. (From 0.15 s on: before that Python itself starts,
    ~40 ms here, where no program's handler can run yet.)"""
    out, before = prepare(tmp_path, fmt)
    path, opts = target_of(tmp_path / "w", fmt)
    proc = subprocess.Popen([sys.executable, "-m", "vrsim_cli", "run",
                             str(tmp_path / "w" / "scene.yaml"), "-o", str(path), "-q",
                             "--realtime", *opts], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(RNG.uniform(0.15, 2.0))
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode in (0, 128 + sig, -signal.SIGKILL), stderr
    assert "Traceback" not in stderr
    partials = check_outcome(tmp_path, fmt, before, references[fmt],
                             finalised=proc.returncode != -signal.SIGKILL,
                             killed=sig == signal.SIGKILL)
    if sig == signal.SIGKILL:
        rerun_cleans_up(tmp_path, fmt, partials, references[fmt])


# ----------------------------------------------------------------------------- start-up


IMPORT_SIGNAL = r"""
import importlib.abc, os, signal, sys
sig, module = getattr(signal, sys.argv[1]), sys.argv[2]
class Tripwire(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == module:  # the signal arrives while the command is being imported
            sys.meta_path.remove(self)
            os.kill(os.getpid(), sig)
        return None
sys.meta_path.insert(0, Tripwire())
sys.argv = ["vrsim"] + sys.argv[3:]
from vrsim_cli.__main__ import main
main()
"""


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("module", ["click", "yaml", "numpy", "vrsim_cli.loop"])
def test_a_signal_during_start_up_is_a_clean_exit(write_scene, tmp_path, sig, module):
    """Before: SIGTERM killed silently, SIGINT gave a KeyboardInterrupt traceback, and a
    signal between opening the output and installing the handlers left a .partial."""
    proc = subprocess.run([sys.executable, "-c", IMPORT_SIGNAL, sig, module, "run",
                           str(write_scene(SCENE)), "-o", str(tmp_path / "out.csv")],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == {"SIGINT": 130, "SIGTERM": 143}[sig], proc.stderr
    assert proc.stderr == f"interrupted by {sig}; nothing was written\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.yaml"]


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("module", ["vrsim_cli.interrupts", "threading"])
def test_a_signal_before_the_handlers_are_installed_is_a_clean_exit(write_scene, tmp_path,
                                                                    sig, module):
    """Issue 53: Ctrl-C in the first milliseconds gave a KeyboardInterrupt traceback. The
    entry point's first lines install a handler from the C module before they import
    `interrupts` (and its threading, enum): from vrsim's first instruction on, a signal is
    a clean exit. (Python's own start-up before it, site and .pth files, is Python's.)"""
    proc = subprocess.run([sys.executable, "-c", IMPORT_SIGNAL, sig, module, "run",
                           str(write_scene(SCENE)), "-o", str(tmp_path / "out.csv")],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == {"SIGINT": 130, "SIGTERM": 143}[sig], proc.stderr
    assert proc.stderr == f"interrupted by {sig}; nothing was written\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.yaml"]


def _closed_run(fds: str, *args):
    """`vrsim ARGS` with the descriptors `fds` closed, as `2>&-` or a daemon starts it;
    returns (exit code, stdout, stderr) of whatever remains open."""
    read_out, write_out = os.pipe()
    read_err, write_err = os.pipe()
    closing = [int(fd) for fd in fds.split(",")]

    def close():  # in the child, before Python starts: as the shell's `2>&-` does
        for fd in closing:
            os.close(fd)

    proc = subprocess.Popen([sys.executable, "-m", "vrsim_cli", *map(str, args)], cwd=REPO,
                            stdout=write_out, stderr=write_err, preexec_fn=close)
    os.close(write_out)
    os.close(write_err)
    with os.fdopen(read_out) as out, os.fdopen(read_err) as err:
        stdout, stderr = out.read(), err.read()
    return proc.wait(timeout=120), stdout, stderr


def test_a_run_with_stderr_closed_still_writes_its_output(write_scene, tmp_path):
    """Issue 53: with stderr closed (`2>&-`) a run exited 1, wrote nothing and said nothing
    (the progress bar asked `sys.stderr.isatty()` of None). Now the notes are dropped and
    the run goes on; its output is whole and the summary is on stdout."""
    out = tmp_path / "out.csv"
    code, stdout, _ = _closed_run("2", "run", write_scene(SCENE), "-o", out)
    assert code == 0
    assert stdout.startswith("drop: simulated 1 s") and "state sha256:" in stdout
    assert len(read_trajectory(out).tracks["ball"].t) == SAMPLES


@pytest.mark.parametrize("args,said", [(["-o", "-"], "-o - writes to standard output"),
                                       (["-o", "out.csv", "--json"], "--json writes to")])
def test_a_run_with_stdout_closed_that_needs_it_is_a_usage_error(write_scene, tmp_path, args,
                                                                 said):
    """Issue 53: `-o -` with stdout closed was an AttributeError traceback."""
    code, _, stderr = _closed_run("1", "run", write_scene(SCENE), *args)
    assert code == 2, stderr
    assert f"Error: {said}" in stderr and "standard output, which is closed" in stderr
    assert "Traceback" not in stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.yaml"]


def test_closed_stdout_and_stderr_still_run_and_keep_files_off_fds_1_and_2(write_scene,
                                                                        tmp_path):
    """Both closed: nothing can be said, the exit code says it; and a file opened during
    the run never takes descriptor 1 or 2 (whatever went to stderr would land in it)."""
    out = tmp_path / "out.csv"
    code, _, _ = _closed_run("1,2", "run", write_scene(SCENE), "-o", out)
    assert code == 0
    assert out.read_text().startswith("t,entity,")
    code, _, _ = _closed_run("1,2", "run", write_scene(SCENE), "-o", "-")
    assert code == 2


@pytest.fixture
def tiny_disk(tmp_path):
    """A 128 KiB tmpfs: a real file system that fills up (needs root; skipped otherwise)."""
    mount = tmp_path / "disk"
    mount.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=128k", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=False)


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_really_full_disk_keeps_the_previous_output(tiny_disk, references, fmt):
    """On a file system that really runs out of space (ENOSPC from the kernel, not a
    patched call), at a point that depends on how much the previous output and the other
    files take: every format fails with exit 1, and nothing of the user's changes."""
    out, before = prepare(tiny_disk, fmt)
    # fill the disk so that only part of the new output fits
    _, tum_files, bytes_ref = references[fmt]
    size = len(bytes_ref) if bytes_ref is not None else sum(
        len(c) for n, (_, c) in tum_files.items() if n.endswith(".tum"))
    free = os.statvfs(tiny_disk).f_bavail * os.statvfs(tiny_disk).f_frsize
    (tiny_disk / "filler").write_bytes(b"x" * max(0, free - size // 2))
    before = snapshot(tiny_disk / "w")
    proc = child(tiny_disk, fmt)
    assert proc.returncode == 1, proc.stderr
    assert "No space left on device" in proc.stderr and "Traceback" not in proc.stderr
    assert snapshot(tiny_disk / "w") == before


@pytest.mark.parametrize("kind", ["fifo", "link-to-file", "link-to-dev-null", "folder"])
def test_special_video_targets_are_refused(invoke, write_scene, tmp_path, kind):
    """The video is renamed over its target too: the same kinds are refused."""
    target = make_special(tmp_path, kind).rename(tmp_path / "v.mp4")
    scene = write_scene(SCENE)
    before = snapshot(tmp_path)
    result = invoke("run", scene, "--frames", tmp_path / "f", "--video", target)
    assert result.exit_code == 2 and "--video" in result.stderr  # (click refuses folders)
    assert f"'{target}' is " in result.stderr or "is a directory" in result.stderr
    assert snapshot(tmp_path) == before


HELD_SIGNAL = r"""
import os, signal, sys
from vrsim_cli import interrupts
interrupts.install()
done = []
try:
    with interrupts.held():
        os.kill(os.getpid(), getattr(signal, sys.argv[1]))  # lands inside the block
        done.append("block finished")
except interrupts.Interrupted as exc:
    print(done, exc.exit_code)
"""


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_a_signal_while_kernels_load_waits_for_the_end_of_the_block(sig):
    """A SIGTERM that arrived while numba was loading a kernel from its disk cache was
    raised inside llvmlite's C callback: printed as "Exception ignored ... Traceback" and
    lost (found by the random-signal test above). Inside `interrupts.held()` the signal
    waits for the block to end and then acts as in immediate mode."""
    proc = subprocess.run([sys.executable, "-c", HELD_SIGNAL, sig], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert proc.stdout.split() == ["['block", "finished']",
                                   str(128 + getattr(signal, sig))], proc.stdout
