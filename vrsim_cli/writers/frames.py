"""Rendered frames as numbered PNG files: frame_000000.png, frame_000001.png, ...

Layer 6. Image k shows loop frame k * every, at t = k * every / frame_rate (image 0 is the
initial state). Each file is written atomically, so a viewer or video encoder never reads
half an image. When the run ends, frame files numbered beyond the last image of this run
(left over from an earlier, longer run) are removed, so the folder holds one run's frames.
"""

from __future__ import annotations

import re
from pathlib import Path

from vrsim_cli.errors import OutputError
from vrsim_cli.maths.camera import Camera
from vrsim_cli.maths.spatial import quat_rotate
from vrsim_cli.model.frames import FramesSpec
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.writers.atomic import AtomicFile
from vrsim_cli.writers.png import encode_png

FRAME_NAME = "frame_{:06d}.png"
FRAME_PATTERN = re.compile(r"frame_(\d{6})\.png")


class FramesWriter:
    """Called once per loop frame (and once for the initial state) with the state; renders
    and writes every `spec.every`-th frame. `renderer` has `render(state, overlay)` and
    `close()` (see `render.open_renderer`); `video`, if given, receives every image too
    (see `writers.video.VideoWriter`)."""

    def __init__(self, model: Model, spec: FramesSpec, renderer, label=None, video=None):
        self.model = model
        self.spec = spec
        self.renderer = renderer
        self.label = label
        self.video = video
        self.images = 0
        try:
            spec.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create the frames folder {spec.dir}: "
                              f"{exc.strerror}") from None

    def __call__(self, state: State) -> None:
        frame = -(-state.step // self.model.steps_per_frame)  # the last frame may be short
        if frame % self.spec.every:
            return
        image = self.renderer.render(state, self.label(state.t) if self.label else None,
                                     camera=self.camera(state))
        out = AtomicFile(self.spec.dir / FRAME_NAME.format(self.images))
        try:
            out.write(encode_png(image))
            out.commit()
        finally:
            out.discard()
        if self.video is not None:
            self.video.append(image)
        self.images += 1

    def camera(self, state: State) -> Camera | None:
        """The observer's camera when the scene has an observer and no frames camera (the
        observer looks along its local -z, local +y up); else None: the renderer's own."""
        observer = self.model.observer
        if observer is None or self.spec.camera is not None:
            return None
        return Camera(eye=tuple(state.observer_pos.tolist()),
                      forward=tuple(quat_rotate(state.observer_quat, [0.0, 0.0, -1.0]).tolist()),
                      up=tuple(quat_rotate(state.observer_quat, [0.0, 1.0, 0.0]).tolist()),
                      fov_deg=observer.fov_deg)

    def close(self) -> None:
        """Free the renderer, finish the video, remove stale frames of an earlier run."""
        self.renderer.close()
        if self.video is not None:
            self.video.close()
        for path in self.spec.dir.iterdir():
            match = FRAME_PATTERN.fullmatch(path.name)
            if match and int(match.group(1)) >= self.images:
                try:
                    path.unlink()
                except OSError:
                    pass  # a stale file we cannot remove is not worth failing the run for

    def abort(self) -> None:
        self.renderer.close()
        if self.video is not None:
            self.video.abort()


def frame_paths(folder: Path) -> list[Path]:
    """The frame files in `folder`, in order."""
    return sorted(p for p in folder.iterdir() if FRAME_PATTERN.fullmatch(p.name))
