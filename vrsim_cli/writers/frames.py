"""Rendered frames as numbered PNG files: frame_000000.png, frame_000001.png, ...

Layer 6. Image k shows loop frame k * every, at t = k * every / frame_rate (image 0 is the
initial state). The states to draw are kept during the run and drawn when it ends: the
default camera (`render.action_camera_path`) frames the moving bodies of the whole run,
so it needs all of it. Each file is PNG through Pillow, written atomically, so a viewer
or video encoder never reads half an image. When the run ends, frame files numbered
beyond the last image of this run (left over from an earlier, longer run) are removed, so
the folder holds one run's frames.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

from vrsim_cli.errors import OutputError
from vrsim_cli.maths.camera import Camera
from vrsim_cli.maths.spatial import quat_rotate
from vrsim_cli.model.frames import FramesSpec
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.scene.files import remove_stale_partials
from vrsim_cli.writers.atomic import AtomicFile

FRAME_NAME = "frame_{:06d}.png"
FRAME_PATTERN = re.compile(r"frame_(\d{6})\.png")


def encode_png(image) -> bytes:
    """PNG bytes of `image`: (height, width, 3) uint8 RGB, row 0 at the top (Pillow)."""
    import numpy as np
    from PIL import Image

    image = np.ascontiguousarray(image, dtype=np.uint8)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (height, width, 3) image, got shape {image.shape}")
    out = io.BytesIO()
    Image.fromarray(image, "RGB").save(out, format="PNG")
    return out.getvalue()


class FramesWriter:
    """Called once per loop frame (and once for the initial state) with the state; keeps
    every `spec.every`-th, and draws them all on `close()`. `renderer` has
    `render(state, overlay, camera)` and `close()` (see `render.open_renderer`); `video`,
    if given, receives every image too (see `writers.video.VideoWriter`)."""

    def __init__(self, model: Model, spec: FramesSpec, renderer, label=None, video=None):
        self.model = model
        self.spec = spec
        self.renderer = renderer
        self.label = label
        self.video = video
        self.images = 0
        self.states: list[State] = []
        try:
            spec.dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create the frames folder {spec.dir}: "
                              f"{exc.strerror}") from None

    def __call__(self, state: State) -> None:
        frame = -(-state.step // self.model.steps_per_frame)  # the last frame may be short
        if frame % self.spec.every == 0:
            self.states.append(state)

    def cameras(self) -> list[Camera]:
        """The camera of each kept state (`picture_cameras`)."""
        return picture_cameras(self.model, self.states, self.spec)

    def close(self) -> None:
        """Draw and write the kept states, finish the video, remove stale frames of an
        earlier run, free the renderer."""
        try:
            # temporary files of runs that died, once for the folder (not once per frame)
            remove_stale_partials(self.spec.dir)
            for image in pictures(self.model, self.states, self.spec, self.renderer,
                                  self.label):
                out = AtomicFile(self.spec.dir / FRAME_NAME.format(self.images),
                                 sweep_stale=False)
                try:
                    out.write(encode_png(image))
                    out.commit()
                finally:
                    out.discard()
                if self.video is not None:
                    self.video.append(image)
                self.images += 1
        except BaseException:
            self.abort()
            raise
        self.states = []
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
        self.states = []
        self.renderer.close()
        if self.video is not None:
            self.video.abort()


def picture_cameras(model: Model, states: list[State], spec: FramesSpec) -> list[Camera]:
    """The camera of each of `states`: the scene's frames camera if it has one, else the
    observer's (the observer looks along its local -z, local +y up), else the action
    camera that keeps every moving body in view (`render.action_camera_path`)."""
    if spec.camera is not None:
        return [spec.camera] * len(states)
    observer = model.observer
    if observer is not None:
        return [Camera(eye=tuple(s.observer_pos.tolist()),
                       forward=tuple(quat_rotate(s.observer_quat, [0.0, 0.0, -1.0]).tolist()),
                       up=tuple(quat_rotate(s.observer_quat, [0.0, 1.0, 0.0]).tolist()),
                       fov_deg=observer.fov_deg) for s in states]
    from vrsim_cli.render import action_camera_path

    return action_camera_path(model, states, spec.width, spec.height)


def pictures(model: Model, states: list[State], spec: FramesSpec, renderer, label=None,
             last_only: bool = False):
    """Yield the image of each of `states` (a run's kept states, or the API's samples and
    current state): the cameras of `picture_cameras`, the ground sized to their action
    (`render.stage_for`) and, for the few moving bodies of `render.trail_bodies`, the
    path each has come along so far. `last_only`: only the last state's image (the
    others still set the camera, ground and trails)."""
    if not states:
        return
    import numpy as np

    from vrsim_cli.render import framed_bodies, stage_for, trail_bodies

    cameras = picture_cameras(model, states, spec)
    if hasattr(renderer, "set_stage"):
        renderer.set_stage(stage_for(model, states))
    trailed = trail_bodies(model, states)
    pos = np.stack([s.body_pos[trailed] for s in states])
    # a trail runs where its body is in the scene (not after a bullet has left it)
    since = framed_bodies(model, states)[:, trailed] if len(trailed) else \
        np.zeros((len(states), 0), dtype=bool)
    for i, (state, camera) in enumerate(zip(states, cameras)):
        if last_only and i < len(states) - 1:
            continue
        trails = [(pos[:i + 1, k][since[:i + 1, k]], model.body_color[b][:3])
                  for k, b in enumerate(trailed)]
        yield renderer.render(state, label(state.t) if label else None, camera=camera,
                              trails=trails)


def frame_paths(folder: Path) -> list[Path]:
    """The frame files in `folder`, in order."""
    return sorted(p for p in folder.iterdir() if FRAME_PATTERN.fullmatch(p.name))
