"""`vrsim run --frames DIR --video OUT.mp4|OUT.gif`: the frames as one video file."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from test_frames import STATIC, read_png


@pytest.mark.osmesa
@pytest.mark.parametrize("name", ["run.mp4", "run.gif"])
def test_video_holds_every_image_at_the_frame_rate(invoke, write_scene, tmp_path, name):
    import imageio.v2 as imageio

    video = tmp_path / name
    result = invoke("run", write_scene(STATIC), "--frames", tmp_path / "f", "--video", video)
    assert result.exit_code == 0, result.output
    assert f"video {video}" in result.stdout
    frames = imageio.mimread(video)
    assert len(frames) == 4  # the images of frames 0, 3, 6 and 9, as in the folder
    assert frames[0].shape[:2] == (48, 64)
    png = read_png((tmp_path / "f" / "frame_000000.png").read_bytes())
    if name.endswith(".gif"):
        # GIF is paletted: the ball's red survives within a palette step. 3 images per
        # 1/20 s frame -> 150 ms per image, stored in whole centiseconds.
        assert np.abs(frames[0][..., :3].astype(int) - png).mean() < 3
        from PIL import Image
        assert Image.open(video).info["duration"] == 150
    else:
        # H.264 is lossy (4:2:0 chroma, quality 8): the mean error stays a few levels.
        assert np.abs(frames[0].astype(int) - png).mean() < 8
        assert imageio.get_reader(video).get_meta_data()["fps"] == pytest.approx(20 / 3,
                                                                               rel=1e-3)
    assert [p.name for p in tmp_path.iterdir() if "partial" in p.name] == []


@pytest.mark.parametrize("args,message", [
    (["--video", "out.mp4"], "--video needs frames: add --frames DIR"),
    (["--frames", "f", "--video", "out.avi"], "cannot tell the format of 'out.avi'"),
    (["--frames", "f", "--video", "/nonexistent-dir/out.mp4"], "does not exist"),
])
def test_video_usage_errors_exit_2(invoke, write_scene, args, message):
    result = invoke("run", write_scene(STATIC), *args)
    assert result.exit_code == 2 and message in result.stderr, result.stderr


def test_missing_imageio_ffmpeg_is_reported_before_the_run(invoke, write_scene, tmp_path,
                                                           monkeypatch):
    # as if the extra were not installed
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)
    out = tmp_path / "traj.csv"
    result = invoke("run", write_scene(STATIC), "--frames", tmp_path / "f", "--video",
                    tmp_path / "v.mp4", "-o", out)
    assert result.exit_code == 2
    assert "--video needs imageio-ffmpeg, which is not installed: pip install " \
        "'vrsim-cli[video]'" in result.stderr
    assert not out.exists() and not (tmp_path / "f").exists()


# An encoder that fails as ffmpeg does on a full disk: it reads its input, writes part of
# the file, says why on stderr and exits with 1.
FULL_DISK_FFMPEG = """#!/bin/sh
for last; do :; done
cat > /dev/null
printf 'truncated' > "$last"
echo "[out#0/mp4] Error writing trailer: No space left on device" >&2
exit 1
"""


@pytest.mark.osmesa
def test_a_failing_encoder_fails_the_run_and_keeps_the_previous_video(invoke, write_scene,
                                                                      tmp_path, monkeypatch):
    """Issue 53: on a full disk ffmpeg said "No space left", vrsim exited 0 and replaced
    the previous out.mp4 by a truncated file."""
    fake = tmp_path / "ffmpeg"
    fake.write_text(FULL_DISK_FFMPEG)
    fake.chmod(0o755)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(fake))  # imageio-ffmpeg's own override
    video = tmp_path / "out.mp4"
    video.write_bytes(b"the previous video")
    result = invoke("run", write_scene(STATIC), "--frames", tmp_path / "f", "--video", video)
    assert result.exit_code == 1, result.output
    assert f"cannot write {video}: the video encoder (ffmpeg) failed: [out#0/mp4] Error " \
        "writing trailer: No space left on device" in result.stderr
    assert "Traceback" not in result.output
    assert video.read_bytes() == b"the previous video"
    assert [p.name for p in tmp_path.iterdir() if "partial" in p.name] == []


@pytest.mark.parametrize("name", ["out.mp4", "out.gif"])
def test_a_video_into_a_folder_that_cannot_be_written_is_a_usage_error(invoke, write_scene,
                                                                       tmp_path, name):
    """Issue 53: an OSError traceback. sysfs refuses new files even to root."""
    traj = tmp_path / "traj.csv"
    result = invoke("run", write_scene(STATIC), "--frames", tmp_path / "f", "--video",
                    f"/sys/{name}", "-o", traj)
    assert result.exit_code == 2, result.output
    assert "--video: folder '/sys' is not writable" in result.stderr
    assert "Traceback" not in result.output
    assert not traj.exists() and not (tmp_path / "f").exists()


@pytest.mark.osmesa
def test_a_100_hz_gif_keeps_one_image_in_two_with_20_ms_delays(invoke, write_scene, tmp_path):
    """Browsers play GIF delays under 20 ms as 100 ms: at 100 Hz the GIF keeps every second
    image, 20 ms each, so it plays in real time (and says so)."""
    from PIL import Image

    scene = write_scene(STATIC.replace("frame_rate: 20", "frame_rate: 100")
                        .replace("every: 3, ", ""))
    video = tmp_path / "run.gif"
    result = invoke("run", scene, "--frames", tmp_path / "f", "--video", video)
    assert result.exit_code == 0, result.output
    assert "the GIF keeps one image in 2" in result.stdout
    gif = Image.open(video)
    delays = []
    for i in range(gif.n_frames):
        gif.seek(i)
        delays.append(gif.info["duration"])
    assert len(delays) == 26  # images 0, 2, ..., 50 of the 51 frames (0.5 s at 100 Hz)
    assert set(delays) == {20}
    assert len(list((tmp_path / "f").iterdir())) == 51  # the folder keeps every image


@pytest.mark.parametrize("fps", [15.0, 30.0, 45.0, 60.0, 100.0, 240.0])
def test_gif_delays_are_at_least_20_ms_and_keep_real_time(tmp_path, fps):
    from PIL import Image

    from vrsim_cli.writers.video import VideoWriter

    path = tmp_path / "v.gif"
    writer = VideoWriter(path, fps=fps)
    images = 90
    rng = np.random.default_rng(0)
    sizes = []
    for _ in range(images):
        writer.append(rng.integers(0, 256, (12, 16, 3), dtype=np.uint8))
        sizes.append(writer.tmp_path.stat().st_size)
    assert sizes[-1] > sizes[len(sizes) // 2] > 0  # streamed to disk as it goes
    writer.close()
    gif = Image.open(path)
    delays = []
    for i in range(gif.n_frames):
        gif.seek(i)
        delays.append(gif.info["duration"])
    assert min(delays) >= 20
    # the kept images span the same time as all images: within one centisecond
    kept = -(-images // writer.keep_every)
    assert len(delays) == kept
    assert abs(sum(delays) - 1e3 * kept * writer.keep_every / fps) <= 10


@pytest.fixture
def read_only_folder(tmp_path):
    """A folder no file can be made in: a read-only tmpfs as root (whom permission bits do
    not stop), else a folder without write permission."""
    import os
    import subprocess

    folder = tmp_path / "ro"
    folder.mkdir()
    if os.geteuid() == 0:
        proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs",
                               str(folder)], capture_output=True, text=True)
        if proc.returncode != 0:
            pytest.skip(f"cannot mount a read-only tmpfs here: {proc.stderr.strip()}")
        try:
            yield folder
        finally:
            subprocess.run(["umount", str(folder)], check=False)
        return
    folder.chmod(0o555)
    try:
        yield folder
    finally:
        folder.chmod(0o755)


@pytest.mark.parametrize("what", ["video.mp4", "video.gif", "frames"])
def test_a_read_only_folder_is_a_usage_error_before_the_run(invoke, write_scene, tmp_path,
                                                            read_only_folder, what):
    """Issue 53: --video into a read-only folder was an OSError traceback (EROFS from the
    temporary file), frames there a run failure (exit 1). A folder where no file can be
    made is refused before the run, exit 2, and nothing is written."""
    traj = tmp_path / "traj.csv"
    args = (["--frames", read_only_folder / "f"] if what == "frames" else
            ["--frames", tmp_path / "f", "--video", read_only_folder / what])
    result = invoke("run", write_scene(STATIC), *args, "-o", traj)
    assert result.exit_code == 2, result.output
    assert f"folder '{read_only_folder}' is not writable" in result.stderr
    assert "Traceback" not in result.output and "simulated" not in result.output
    assert not traj.exists() and not (tmp_path / "f").exists()
    assert list(read_only_folder.iterdir()) == []
