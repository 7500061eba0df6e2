"""Frames on disk: `vrsim run --frames`, the PNG encoder, the scene key, a missing OSMesa."""

from __future__ import annotations

import math
from pathlib import Path

import json
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

from conftest import REPO
from vrsim_cli.writers.frames import encode_png


def read_png(data: bytes) -> np.ndarray:
    """A minimal PNG decoder written from the specification (8-bit RGB, no interlace, all
    five filter types), independent of the encoder under test. Checks every CRC."""
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF, kind
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    width, height, depth, colour, _, _, interlace = header
    assert (depth, colour, interlace) == (8, 2, 0)
    raw = zlib.decompress(idat)
    stride, bpp = 3 * width, 3
    out = np.zeros((height, stride), dtype=np.int64)
    for y in range(height):
        kind, line = raw[y * (stride + 1)], raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)]
        prev = out[y - 1] if y else np.zeros(stride, dtype=np.int64)
        row = out[y]
        for x in range(stride):
            a = row[x - bpp] if x >= bpp else 0
            b, c = prev[x], (prev[x - bpp] if x >= bpp else 0)
            if kind == 0:
                pred = 0
            elif kind == 1:
                pred = a
            elif kind == 2:
                pred = b
            elif kind == 3:
                pred = (a + b) // 2
            else:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
            row[x] = (line[x] + pred) % 256
    return out.reshape(height, width, 3).astype(np.uint8)


def test_png_round_trips_through_an_independent_decoder():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, (7, 11, 3), dtype=np.uint8)
    image[3:] = image[2]  # flat rows, where the Up filter gives zeros
    np.testing.assert_array_equal(read_png(encode_png(image)), image)


def test_png_refuses_non_rgb_arrays():
    with pytest.raises(ValueError, match="height, width, 3"):
        encode_png(np.zeros((4, 4), dtype=np.uint8))


STATIC = """
vrsim: 1
name: still
duration: 0.5
frame_rate: 20
bodies:
  - {name: ball, type: static, shape: {type: sphere, radius: 0.3}, position: [0, 1, 0],
     color: [1, 0, 0]}
output:
  frames: {every: 3, width: 64, height: 48}
"""


@pytest.mark.osmesa
def test_run_with_frames_writes_every_nth_frame_at_the_asked_size(invoke, write_scene,
                                                                   tmp_path):
    out = tmp_path / "frames"
    scene = write_scene(STATIC.replace("duration: 0.5", "duration: 1"))
    assert invoke("run", scene, "--frames", out, "-q").exit_code == 0  # 7 images
    scene = write_scene(STATIC)  # the same scene file, run shorter
    result = invoke("run", scene, "--frames", out, "--profile")
    assert result.exit_code == 0, result.output
    # 10 loop frames after the initial state; images at frames 0, 3, 6, 9; the longer
    # run's images 4 to 6 are gone, so the folder holds one run's frames.
    names = sorted(p.name for p in out.iterdir())
    assert names == ["frame_000000.png", "frame_000001.png", "frame_000002.png",
                     "frame_000003.png"]
    for name in names:
        image = read_png((out / name).read_bytes())
        assert image.shape == (48, 64, 3)
        assert image[24, 32, 0] > 100 and image[24, 32, 1] == 0  # the ball, seen by default
    assert f"frames: 4 images of 64x48 px -> {out}" in result.stdout
    assert "\nrender " in result.stdout  # its own stage in the profile


@pytest.mark.osmesa
def test_scene_frames_dir_is_relative_to_the_current_folder(invoke, write_scene, tmp_path):
    scene = write_scene(STATIC.replace("every: 3", "every: 5, dir: shots"))
    assert invoke("run", scene, "-q").exit_code == 0
    assert sorted(p.name for p in (tmp_path / "shots").iterdir()) == [
        "frame_000000.png", "frame_000001.png", "frame_000002.png"]


@pytest.mark.parametrize("frames,message", [
    ("{dir: ../up}", "output.frames.dir: path '../up' leaves the current folder"),
    ("{camera: {position: [1, 2, 3], look_at: [1, 2, 3]}}",
     "output.frames.camera: the camera's position and look_at point coincide"),
    ("{camera: {position: [0, 5, 0], look_at: [0, 0, 0]}}",
     "output.frames.camera: the camera's up direction is parallel to its line of sight"),
    ("{widht: 100}", "unknown key 'widht' (did you mean 'width'?)"),
    ("{width: 8}", "output.frames.width: must be >= 16, got 8"),
])
def test_bad_frames_settings_are_located(invoke, write_scene, frames, message):
    text = STATIC.replace("  frames: {every: 3, width: 64, height: 48}", f"  frames: {frames}")
    result = invoke("validate", write_scene(text))
    assert result.exit_code == 2 and message in result.stderr, result.stderr


MISSING_OSMESA = """
import ctypes, sys
real_init = ctypes.CDLL.__init__
def no_osmesa(self, name, *args, **kwargs):
    if name and "OSMesa" in str(name):
        raise OSError(f"{name}: cannot open shared object file: No such file or directory")
    return real_init(self, name, *args, **kwargs)
ctypes.CDLL.__init__ = no_osmesa  # as on a machine without libosmesa6
from vrsim_cli.cli import main
sys.argv = ["vrsim", "run", sys.argv[1], "--frames", sys.argv[2], "-o", sys.argv[3]]
main()
"""


def test_missing_osmesa_fails_at_once_with_how_to_install(write_scene, tmp_path):
    scene = write_scene(STATIC.replace("duration: 0.5", "duration: 1000"))
    frames, traj = tmp_path / "frames", tmp_path / "traj.csv"
    proc = subprocess.run([sys.executable, "-c", MISSING_OSMESA, str(scene), str(frames),
                           str(traj)], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert "the OSMesa library (libOSMesa.so) was not found" in proc.stderr
    assert "apt-get install libosmesa6" in proc.stderr
    assert "pip install 'vrsim-cli[render]'" in proc.stderr
    assert "Traceback" not in proc.stderr
    assert not frames.exists() and not traj.exists()  # nothing simulated, nothing written


def test_frames_settings_without_a_folder_never_import_opengl(write_scene, tmp_path):
    scene = write_scene(STATIC)  # output.frames without dir: settings for --frames only
    code = f"""
import json, sys
from vrsim_cli.cli import main
sys.argv = ["vrsim", "run", {str(scene)!r}, "-q", "-o", {str(tmp_path / 'o.csv')!r}]
try:
    main()
except SystemExit as exc:
    assert exc.code in (0, None), exc.code
print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in ("OpenGL", "trimesh"))))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=REPO, check=True)
    assert json.loads(out.stdout) == []


@pytest.mark.osmesa
def test_a_frame_that_cannot_be_written_fails_the_run_cleanly(invoke, write_scene, tmp_path,
                                                              monkeypatch):
    from vrsim_cli.errors import OutputError
    from vrsim_cli.writers.atomic import AtomicFile

    def full_disk(self, data):
        raise OutputError(f"cannot write {self.path}: No space left on device")

    monkeypatch.setattr(AtomicFile, "write", full_disk)
    out = tmp_path / "frames"
    result = invoke("run", write_scene(STATIC), "--frames", out)
    assert result.exit_code == 1
    assert "frame_000000.png: No space left on device" in result.stderr
    assert "Traceback" not in result.output
    assert list(out.iterdir()) == []  # no half-written image, no temporary file


def _tree(folder: Path) -> dict:
    """name -> (kind, bytes or link target) of everything in `folder`."""
    import os
    import stat

    out = {}
    for path in sorted(folder.iterdir()):
        mode = os.lstat(path).st_mode
        if stat.S_ISLNK(mode):
            out[path.name] = ("link", os.readlink(path))
        elif stat.S_ISFIFO(mode):
            out[path.name] = ("fifo", None)
        else:
            out[path.name] = ("file", path.read_bytes())
    return out


@pytest.mark.parametrize("theirs", [
    {"frame_000003.png": "mine, frame 3", "frame_000099.png": "mine, frame 99"},
    {"notes.txt": "mine"},
    {"frame_000001.png": "fifo"},
    {"frame_000002.png": "link"},
])
def test_frames_never_touch_files_this_tool_did_not_write(invoke, write_scene, tmp_path,
                                                          theirs):
    """Issue 53: the user's own frame_000003.png was overwritten and frame_000099.png
    deleted (exit 0); a FIFO or link named like a frame failed the run only after the
    whole simulation (exit 1), the trajectory not written. Now any folder holding what
    vrsim did not write is refused before the run simulates (exit 2), untouched."""
    import os

    out = tmp_path / "renders"
    out.mkdir()
    (tmp_path / "elsewhere.png").write_bytes(b"the link's target")
    for name, what in theirs.items():
        if what == "fifo":
            os.mkfifo(out / name)
        elif what == "link":
            os.symlink(tmp_path / "elsewhere.png", out / name)
        else:
            (out / name).write_text(what)
    before = _tree(out)
    traj = tmp_path / "traj.csv"
    result = invoke("run", write_scene(STATIC), "--frames", out, "-o", traj)
    assert result.exit_code == 2, result.output
    assert f"frames folder '{out}' holds '{sorted(theirs)[0]}'" in result.stderr
    assert "empty or new folder" in result.stderr
    assert "Traceback" not in result.output
    assert "simulated" not in result.output  # refused before the run
    assert not traj.exists()
    assert _tree(out) == before
    assert (tmp_path / "elsewhere.png").read_bytes() == b"the link's target"


@pytest.mark.osmesa
def test_frames_of_another_scene_are_not_this_runs_to_replace(invoke, write_scene,
                                                              tmp_path):
    out = tmp_path / "frames"
    other = write_scene(STATIC, name="other.yaml")
    assert invoke("run", other, "--frames", out, "-q").exit_code == 0
    before = _tree(out)
    result = invoke("run", write_scene(STATIC), "--frames", out)
    assert result.exit_code == 2, result.output
    assert "'frame_000000.png' (not a frame of this scene)" in result.stderr
    assert _tree(out) == before


def test_frames_into_a_folder_that_cannot_be_written_is_a_usage_error(invoke, write_scene,
                                                                     tmp_path):
    """sysfs refuses new files even to root (whose permission bits pass every check)."""
    traj = tmp_path / "traj.csv"
    result = invoke("run", write_scene(STATIC), "--frames", "/sys/vrsim-frames", "-o", traj)
    assert result.exit_code == 2, result.output
    assert "cannot be created: folder '/sys' is not writable" in result.stderr
    assert "Traceback" not in result.output and not traj.exists()


def test_frames_must_be_a_folder(invoke, write_scene, tmp_path):
    (tmp_path / "taken").write_text("a file")
    result = invoke("run", write_scene(STATIC), "--frames", tmp_path / "taken")
    assert result.exit_code == 2 and "is a file" in result.stderr


@pytest.mark.osmesa
def test_same_scene_gives_identical_frames(invoke, write_scene, tmp_path):
    scene = write_scene(STATIC)
    for folder in ("a", "b"):
        assert invoke("run", scene, "--frames", tmp_path / folder, "-q").exit_code == 0
    a = sorted((tmp_path / "a").iterdir())
    b = sorted((tmp_path / "b").iterdir())
    assert [p.name for p in a] == [p.name for p in b]
    assert all(x.read_bytes() == y.read_bytes() for x, y in zip(a, b))


@pytest.mark.osmesa
def test_the_observer_is_the_default_camera(invoke, write_scene, tmp_path):
    # The observer stands at (2, 1, 5) looking along -z; the red sphere at (0, 1, 0) is 2 m
    # to its left at 5 m depth, so the pinhole camera puts its centre at
    # u = w/2 - f * 2/5 px with f = (h/2) / tan(fov/2). The image centre is background (the
    # renderer's own default camera would centre the only body).
    scene = write_scene("""
        vrsim: 1
        duration: 0.5
        frame_rate: 2
        dt: 0.5
        observer: {mode: fly, position: [2, 1, 5], direction: [0, 0, -1], fov_deg: 40}
        bodies:
          - {name: red, type: static, shape: {type: sphere, radius: 0.3}, position: [0, 1, 0],
             color: [1, 0, 0]}
        """)
    out = tmp_path / "frames"
    result = invoke("run", scene, "--frames", out)
    assert result.exit_code == 0, result.output
    image = read_png((out / "frame_000000.png").read_bytes())
    h, w, _ = image.shape
    f = (h / 2) / math.tan(math.radians(20))
    u = round(w / 2 - f * 2 / 5)
    assert image[h // 2, u][0] > 150 and image[h // 2, u][1] == 0  # red
    assert image[h // 2, w // 2][1] > 200  # background, not red


@pytest.mark.osmesa
def test_frames_show_keyframed_colours_and_scales(invoke, write_scene, tmp_path):
    # A sphere keyframed from red (t = 0) to green (t = 1 s), and scaled by 2: the centre
    # pixel is red in the first image and green in the last; twice the radius covers a
    # pixel that the unscaled sphere would not.
    scene = write_scene("""
        vrsim: 1
        duration: 1
        frame_rate: 2
        dt: 0.5
        bodies:
          - name: lamp
            type: kinematic
            shape: {type: sphere, radius: 0.3}
            position: [0, 1, 0]
            color: [1, 0, 0]
            keyframes:
              color: {times: [0, 1], values: [[1, 0, 0], [0, 1, 0]]}
              scale: {times: [0, 1], values: [2, 2]}
        output:
          frames: {camera: {position: [0, 1, 5], look_at: [0, 1, 0], fov_deg: 40}}
        """)
    out = tmp_path / "frames"
    assert invoke("run", scene, "--frames", out).exit_code == 0
    first, last = (read_png((out / f"frame_{k:06d}.png").read_bytes()) for k in (0, 2))
    h, w, _ = first.shape
    assert first[h // 2, w // 2][0] > 150 and first[h // 2, w // 2][1] == 0
    assert last[h // 2, w // 2][1] > 150 and last[h // 2, w // 2][0] == 0
    # 0.45 m off-centre at 5 m: inside the scaled sphere (0.6 m), outside the unscaled one
    f = (h / 2) / math.tan(math.radians(20))
    u = round(w / 2 + f * 0.45 / 5)
    assert first[h // 2, u][0] > 100 and first[h // 2, u][1] == 0


class _Blank:
    """A renderer that draws black images (no OpenGL needed)."""

    def render(self, state, overlay=None, camera=None, trails=()):
        return np.zeros((8, 8, 3), dtype=np.uint8)

    def close(self):
        pass


def _frames_run(folder, seconds: float):
    from vrsim_cli.loop import run
    from vrsim_cli.model.frames import FramesSpec
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.writers.frames import FramesWriter

    model = compile_model(parse_scene(
        f"vrsim: 1\nduration: {seconds}\nframe_rate: 100\ndt: 0.01\n"
        "bodies: [{name: a, mass: 1, velocity: [1, 0, 0]}]\n"))
    frames = FramesWriter(model, FramesSpec(folder, 1, 8, 8), _Blank())
    run(model, make_state(model), render=frames)
    frames.close()
    return frames.images


@pytest.mark.parametrize("seconds", [0.1, 1.0])
def test_writing_frames_lists_their_folder_a_fixed_number_of_times(tmp_path, seconds):
    """Stale temporary files are swept once per run, not once per frame: a sweep per frame
    lists the folder, whose size grows with every frame (quadratic in the frames: 7 % of a
    500-frame run, minutes for a long one)."""
    import os
    from unittest import mock

    folder = tmp_path / "frames"
    listed = []
    real = os.listdir

    def counting(path="."):
        if Path(path) == folder:
            listed.append(path)
        return real(path)

    with mock.patch("os.listdir", counting):
        images = _frames_run(folder, seconds)
    assert images == round(seconds * 100) + 1
    assert len(listed) <= 2, len(listed)  # the sweep, and the end's clean-up of old frames


def test_frames_sweep_only_the_temporary_files_of_dead_runs(tmp_path):
    """A frame's temporary file left by a killed run (unlocked, untouched for a minute)
    goes; a young one (a run writing now) and the user's files stay."""
    import os
    import time

    folder = tmp_path / "frames"
    folder.mkdir()
    old = folder / ".frame_000003.png.ab12cd34.partial"
    young = folder / ".frame_000004.png.zz99yy88.partial"
    mine = folder / "frame_notes.partial"
    for path in (old, young, mine):
        path.write_bytes(b"x")
    hour_ago = time.time() - 3600
    os.utime(old, (hour_ago, hour_ago))
    os.utime(mine, (hour_ago, hour_ago))
    assert _frames_run(folder, 0.05) == 6
    assert not old.exists() and young.exists() and mine.exists()
