"""A video of the rendered frames (`vrsim run --frames DIR --video OUT.mp4|OUT.gif`).

Layer 6. MP4: the ffmpeg that imageio-ffmpeg ships (H.264), driven here through a pipe
so its exit status is checked: imageio's writer ignores it, and a full disk gave a
truncated file, renamed into place, and exit 0. Imported only when an MP4 is asked for
(`pip install 'vrsim-cli[video]'`). GIF: Pillow (a core dependency), streamed: each image
is quantised to its own 256 colours and written at once (Pillow's `GifImagePlugin.getheader`
and `getdata`), so memory stays at one image whatever the length; Pillow's `save_all`
would hold every frame until the end.

GIF frame delays are whole centiseconds, and browsers stretch delays under 20 ms to
100 ms (a 100 Hz run would play ten times too slowly). So a GIF keeps every k-th image,
k the smallest whole number with k / fps >= 20 ms, and its delays are rounded
cumulatively (image i shows until round(100 t_(i+1)) cs), so the video keeps real time.

Either file is written to a temporary file beside the target and renamed into place when
the run ends, like every output: a failed run, or an encoder that fails (exit status not
0), leaves any previous video untouched and fails the run (exit 1).
"""

from __future__ import annotations

import collections
import math
import os
import subprocess
import tempfile
import threading
from pathlib import Path

from vrsim_cli.errors import InputError, OutputError
from vrsim_cli.scene.files import folder_write_problem
from vrsim_cli.writers.atomic import _umask

VIDEO_SUFFIXES = (".mp4", ".gif")
VIDEO_HINT = "pip install 'vrsim-cli[video]'"
MP4_CRF = 10  # x264's 0..51, lower is better: imageio's quality 8, crisp grid lines
GIF_MIN_DELAY_S = 0.02  # browsers play shorter GIF delays as 100 ms


def check_video(path: Path) -> None:
    """Raise InputError (exit 2) before the run when `path` cannot be written as a video."""
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"--video: cannot tell the format of '{path}': use .mp4 or .gif")
    if not path.parent.is_dir():
        raise InputError(f"--video: folder '{path.parent}' does not exist")
    unwritable = folder_write_problem(path.parent)
    if unwritable is not None:
        raise InputError(f"--video: {unwritable}")
    if path.suffix.lower() == ".gif":
        return  # Pillow is a core dependency
    try:
        import imageio_ffmpeg
    except ImportError as exc:
        package = {"imageio_ffmpeg": "imageio-ffmpeg"}.get(
            (exc.name or "").split(".")[0], (exc.name or "imageio").split(".")[0])
        raise InputError(f"--video needs {package}, which is not installed: "
                         f"{VIDEO_HINT}") from None
    try:
        imageio_ffmpeg.get_ffmpeg_exe()
    except RuntimeError as exc:  # no ffmpeg for this platform, or IMAGEIO_FFMPEG_EXE wrong
        raise InputError(f"--video: no ffmpeg to encode the MP4 ({exc})") from None


def gif_plan(fps: float) -> tuple[int, float]:
    """(k, seconds per kept image): keep every k-th image so a GIF's delays are >= 20 ms."""
    keep = max(1, math.ceil(GIF_MIN_DELAY_S * fps - 1e-9))
    return keep, keep / fps


class VideoWriter:
    """Appends (height, width, 3) uint8 images at `fps` frames per second to `path`.

    MP4 sizes are made even (H.264 with 4:2:0 chroma needs it) by ffmpeg's scaling.
    `keep_every` and `note` say what a GIF leaves out.
    """

    def __init__(self, path: Path, fps: float):
        self.path = Path(path)
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.",
                                       suffix=f".partial{self.path.suffix}",
                                       dir=self.path.parent)
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror}") from None
        os.close(fd)
        self.tmp_path = Path(tmp)
        self.frames = 0  # images given
        self.written = 0  # images in the video
        self.keep_every = 1
        self.note = ""
        self.fps = fps
        if self.path.suffix.lower() == ".mp4":
            self.writer = None  # the ffmpeg process, started by the first image (its size)
            self.gif = None
        else:
            self.keep_every, self.period_s = gif_plan(fps)
            if self.keep_every > 1:
                self.note = (f"GIF frame delays must be >= {1e3 * GIF_MIN_DELAY_S:g} ms, "
                             f"so {1e3 * self.period_s:.3g} ms per image")
            self.writer = None
            self.gif = open(self.tmp_path, "wb")

    def append(self, image) -> None:
        if self.gif is None:
            if self.writer is None:
                self.writer = _Ffmpeg(self.tmp_path, self.fps, image.shape[1], image.shape[0])
            self.writer.write(image, self.path)
            self.written += 1
        elif self.frames % self.keep_every == 0:
            self._gif_frame(image)
        self.frames += 1

    def _gif_frame(self, image) -> None:
        from PIL import GifImagePlugin, Image

        frame = Image.fromarray(image, "RGB").quantize(colors=256)
        # delays in whole centiseconds, rounded on the running time: real time overall
        i = self.written
        delay_cs = round(100 * (i + 1) * self.period_s) - round(100 * i * self.period_s)
        try:
            if i == 0:
                header, _ = GifImagePlugin.getheader(frame, info={"loop": 0,
                                                                  "duration": 10 * delay_cs})
                self.gif.write(b"".join(header))
            self.gif.write(b"".join(GifImagePlugin.getdata(
                frame, duration=10 * delay_cs, include_color_table=True)))
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror}") from None
        self.written += 1

    def close(self) -> None:
        """Finish the file and move it into place."""
        try:
            if self.gif is not None:
                self.gif.write(b";")  # the GIF trailer
                self.gif.close()
            elif self.writer is None:
                raise OSError("no images to encode")
            else:
                self.writer.close(self.path)
            os.chmod(self.tmp_path, 0o666 & ~_umask())  # mkstemp made it private
            os.replace(self.tmp_path, self.path)
        except OutputError:
            self.abort()
            raise
        except OSError as exc:
            self.abort()
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}; any "
                              f"previous file there is untouched") from None

    def abort(self) -> None:
        try:
            if self.gif is not None:
                self.gif.close()
            elif self.writer is not None:
                self.writer.kill()
        except Exception:  # noqa: BLE001 - the run already failed; keep its error
            pass
        self.tmp_path.unlink(missing_ok=True)


class _Ffmpeg:
    """An ffmpeg process encoding raw RGB images from its stdin to H.264 in `out`. Its
    stderr is read by a thread (a full pipe would block it) and kept for the error."""

    def __init__(self, out: Path, fps: float, width: int, height: int):
        from fractions import Fraction

        import imageio_ffmpeg

        rate = Fraction(fps).limit_denominator()
        command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-v", "error",
                   "-f", "rawvideo", "-vcodec", "rawvideo", "-s", f"{width}x{height}",
                   "-pix_fmt", "rgb24", "-r", str(rate), "-i", "-", "-an",
                   "-vcodec", "libx264", "-pix_fmt", "yuv420p", "-crf", str(MP4_CRF)]
        if width % 2 or height % 2:  # 4:2:0 chroma needs even sizes
            command += ["-vf", f"scale={width + width % 2}:{height + height % 2}"]
        command += ["-f", "mp4", str(out)]
        self.size = (height, width)
        self.lines = collections.deque(maxlen=8)
        try:
            # its own session: a Ctrl-C meant for vrsim (which finalises) does not kill it
            self.process = subprocess.Popen(command, stdin=subprocess.PIPE,
                                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                            start_new_session=True)
        except OSError as exc:
            raise OutputError(f"cannot start ffmpeg to encode {out}: "
                              f"{exc.strerror or exc}") from None
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.process.stderr:
            self.lines.append(line.decode("utf-8", "replace").strip())

    def write(self, image, path: Path) -> None:
        import numpy as np

        if image.shape[:2] != self.size:
            raise ValueError(f"image of {image.shape[:2]} in a video of {self.size}")
        try:
            self.process.stdin.write(np.ascontiguousarray(image, dtype=np.uint8).tobytes())
        except OSError:  # ffmpeg stopped reading: it failed, and says why on exit
            self.close(path)
            raise OutputError(f"cannot write {path}: the video encoder (ffmpeg) stopped "
                              f"reading") from None

    def close(self, path: Path) -> None:
        """Wait for ffmpeg; OutputError (with its last words) unless it exited with 0."""
        try:
            self.process.stdin.close()
        except OSError:
            pass
        code = self.process.wait()
        self.reader.join(timeout=5)
        if code != 0:
            said = "; ".join(line for line in self.lines if line) or f"exit status {code}"
            raise OutputError(f"cannot write {path}: the video encoder (ffmpeg) failed: "
                              f"{said}; any previous file there is untouched")

    def kill(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
        self.process.wait()
