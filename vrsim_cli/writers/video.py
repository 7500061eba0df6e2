"""A video of the rendered frames (`vrsim run --frames DIR --video OUT.mp4|OUT.gif`).

Layer 6. MP4: imageio's ffmpeg plugin (H.264), imported only when an MP4 is asked for
(`pip install 'vrsim-cli[video]'`). GIF: Pillow (a core dependency), streamed: each image
is quantised to its own 256 colours and written at once (Pillow's `GifImagePlugin.getheader`
and `getdata`), so memory stays at one image whatever the length; Pillow's `save_all`
would hold every frame until the end.

GIF frame delays are whole centiseconds, and browsers stretch delays under 20 ms to
100 ms (a 100 Hz run would play ten times too slowly). So a GIF keeps every k-th image,
k the smallest whole number with k / fps >= 20 ms, and its delays are rounded
cumulatively (image i shows until round(100 t_(i+1)) cs), so the video keeps real time.

Either file is written to a temporary file beside the target and renamed into place when
the run ends, like every output: a failed run leaves any previous video untouched.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

from vrsim_cli.errors import InputError, OutputError
from vrsim_cli.writers.atomic import _umask

VIDEO_SUFFIXES = (".mp4", ".gif")
VIDEO_HINT = "pip install 'vrsim-cli[video]'"
MP4_QUALITY = 8  # imageio-ffmpeg's 0..10 scale; 8 keeps the grid lines crisp
GIF_MIN_DELAY_S = 0.02  # browsers play shorter GIF delays as 100 ms


def check_video(path: Path) -> None:
    """Raise InputError (exit 2) before the run when `path` cannot be written as a video."""
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"--video: cannot tell the format of '{path}': use .mp4 or .gif")
    if not path.parent.is_dir():
        raise InputError(f"--video: folder '{path.parent}' does not exist")
    if path.suffix.lower() == ".gif":
        return  # Pillow is a core dependency
    try:
        import imageio.v2  # noqa: F401
        import imageio_ffmpeg  # noqa: F401
    except ImportError as exc:
        package = {"imageio_ffmpeg": "imageio-ffmpeg"}.get(
            (exc.name or "").split(".")[0], (exc.name or "imageio").split(".")[0])
        raise InputError(f"--video needs {package}, which is not installed: "
                         f"{VIDEO_HINT}") from None


def gif_plan(fps: float) -> tuple[int, float]:
    """(k, seconds per kept image): keep every k-th image so a GIF's delays are >= 20 ms."""
    keep = max(1, math.ceil(GIF_MIN_DELAY_S * fps - 1e-9))
    return keep, keep / fps


class VideoWriter:
    """Appends (height, width, 3) uint8 images at `fps` frames per second to `path`.

    MP4 sizes are made even (H.264 with 4:2:0 chroma needs it) by imageio's resizing.
    `keep_every` and `note` say what a GIF leaves out.
    """

    def __init__(self, path: Path, fps: float):
        self.path = Path(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.",
                                   suffix=f".partial{self.path.suffix}", dir=self.path.parent)
        os.close(fd)
        self.tmp_path = Path(tmp)
        self.frames = 0  # images given
        self.written = 0  # images in the video
        self.keep_every = 1
        self.note = ""
        if self.path.suffix.lower() == ".mp4":
            import imageio.v2 as imageio

            self.writer = imageio.get_writer(self.tmp_path, format="FFMPEG", fps=fps,
                                             codec="libx264", quality=MP4_QUALITY,
                                             macro_block_size=2)
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
            self.writer.append_data(image)
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
            else:
                self.writer.close()
            os.chmod(self.tmp_path, 0o666 & ~_umask())  # mkstemp made it private
            os.replace(self.tmp_path, self.path)
        except (OSError, RuntimeError) as exc:  # ffmpeg reports its failures as either
            self.abort()
            raise OutputError(f"cannot write {self.path}: {exc}") from None

    def abort(self) -> None:
        try:
            if self.gif is not None:
                self.gif.close()
            elif self.writer is not None:
                self.writer.close()
        except Exception:  # noqa: BLE001 - the run already failed; keep its error
            pass
        self.tmp_path.unlink(missing_ok=True)
