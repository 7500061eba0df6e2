"""A video of the rendered frames (`vrsim run --frames DIR --video OUT.mp4|OUT.gif`).

Layer 6. imageio writes it (MP4 through its ffmpeg plugin, H.264; GIF through Pillow),
imported only when a video is asked for. The video is written to a temporary file beside
the target and renamed into place when the run ends, like every output: a failed run
leaves any previous video untouched.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from vrsim_cli.errors import InputError, OutputError
from vrsim_cli.writers.atomic import _umask

VIDEO_SUFFIXES = (".mp4", ".gif")
VIDEO_HINT = "pip install 'vrsim-cli[video]'"
MP4_QUALITY = 8  # imageio-ffmpeg's 0..10 scale; 8 keeps the grid lines crisp


def check_video(path: Path) -> None:
    """Raise InputError (exit 2) before the run when `path` cannot be written as a video."""
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise InputError(f"--video: cannot tell the format of '{path}': use .mp4 or .gif")
    if not path.parent.is_dir():
        raise InputError(f"--video: folder '{path.parent}' does not exist")
    try:
        import imageio.v2  # noqa: F401
        if path.suffix.lower() == ".mp4":
            import imageio_ffmpeg  # noqa: F401
        else:
            import PIL  # noqa: F401
    except ImportError as exc:
        package = {"PIL": "Pillow", "imageio_ffmpeg": "imageio-ffmpeg"}.get(
            (exc.name or "").split(".")[0], (exc.name or "imageio").split(".")[0])
        raise InputError(f"--video needs {package}, which is not installed: "
                         f"{VIDEO_HINT}") from None


class VideoWriter:
    """Appends (height, width, 3) uint8 images at `fps` frames per second to `path`.

    MP4 sizes are made even (H.264 with 4:2:0 chroma needs it) by imageio's resizing; GIF
    keeps every image in memory until `close()` (Pillow writes a GIF at once), and its
    frame times are whole centiseconds.
    """

    def __init__(self, path: Path, fps: float):
        import imageio.v2 as imageio

        self.path = Path(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.",
                                   suffix=f".partial{self.path.suffix}", dir=self.path.parent)
        os.close(fd)
        self.tmp_path = Path(tmp)
        self.frames = 0
        if self.path.suffix.lower() == ".mp4":
            self.writer = imageio.get_writer(self.tmp_path, format="FFMPEG", fps=fps,
                                             codec="libx264", quality=MP4_QUALITY,
                                             macro_block_size=2)
        else:
            self.writer = imageio.get_writer(self.tmp_path, mode="I", loop=0,
                                             duration=1000.0 / fps)

    def append(self, image) -> None:
        self.writer.append_data(image)
        self.frames += 1

    def close(self) -> None:
        """Finish the file and move it into place."""
        try:
            self.writer.close()
            os.chmod(self.tmp_path, 0o666 & ~_umask())  # mkstemp made it private
            os.replace(self.tmp_path, self.path)
        except (OSError, RuntimeError) as exc:  # ffmpeg reports its failures as either
            self.abort()
            raise OutputError(f"cannot write {self.path}: {exc}") from None

    def abort(self) -> None:
        try:
            self.writer.close()
        except Exception:  # noqa: BLE001 - the run already failed; keep its error
            pass
        self.tmp_path.unlink(missing_ok=True)
