"""Rendered frames as numbered PNG files: frame_000000.png, frame_000001.png, ...

Layer 6. Image k shows loop frame k * every, at t = k * every / frame_rate (image 0 is the
initial state). The states to draw are kept during the run and drawn when it ends: the
default camera (`render.action_camera_path`) frames the moving bodies of the whole run,
so it needs all of it. Each file is PNG through Pillow, written atomically, so a viewer
or video encoder never reads half an image.

The folder is vrsim's alone: before the run simulates, `frames_folder_problem` refuses a
folder that holds anything but frames of an earlier run of the same scene file (each PNG
carries a `vrsim-scene` text chunk, a digest of the scene file's path, `frames_tag`) and
vrsim's own temporary files. So a run only ever replaces or removes its own frames: when
it ends, those numbered beyond its last image (from an earlier, longer run) are removed,
and the folder holds one run's frames.
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import stat
import struct
from pathlib import Path

from vrsim_cli.errors import InputError, OutputError
from vrsim_cli.maths.camera import Camera
from vrsim_cli.maths.spatial import quat_rotate
from vrsim_cli.model.frames import FramesSpec
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.scene.files import (folder_write_problem, is_partial, kind_of,
                                   remove_stale_partials)
from vrsim_cli.writers.atomic import AtomicFile

FRAME_NAME = "frame_{:06d}.png"
FRAME_PATTERN = re.compile(r"frame_(\d{6})\.png")
TAG_KEY = b"vrsim-scene"  # the PNG tEXt keyword naming the scene a frame was rendered from
TAG_READ_BYTES = 4096  # Pillow writes text chunks right after IHDR: within the first bytes


def frames_tag(scene_file: str | os.PathLike) -> str:
    """16 hex digits of sha256 over the scene file's resolved path: what marks a frame as
    rendered from this scene (the path itself may hold any bytes; a digest is ASCII)."""
    return hashlib.sha256(os.fsencode(Path(scene_file).resolve())).hexdigest()[:16]


def encode_png(image, tag: str | None = None) -> bytes:
    """PNG bytes of `image`: (height, width, 3) uint8 RGB, row 0 at the top (Pillow);
    `tag` (`frames_tag`) goes into a `vrsim-scene` tEXt chunk."""
    import numpy as np
    from PIL import Image, PngImagePlugin

    image = np.ascontiguousarray(image, dtype=np.uint8)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an (height, width, 3) image, got shape {image.shape}")
    info = None
    if tag is not None:
        info = PngImagePlugin.PngInfo()
        info.add_text(TAG_KEY.decode(), tag)
    out = io.BytesIO()
    Image.fromarray(image, "RGB").save(out, format="PNG", pnginfo=info)
    return out.getvalue()


def png_tag(path: Path) -> str | None:
    """The `vrsim-scene` tag of the PNG at `path` (a regular file), or None: read from its
    first chunks, never the whole image."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | os.O_NONBLOCK)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as handle:
        data = handle.read(TAG_READ_BYTES)
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    pos = 8
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        if kind == b"IDAT" or len(body) < length:
            return None
        if kind == b"tEXt" and body.startswith(TAG_KEY + b"\0"):
            return body[len(TAG_KEY) + 1:].decode("latin-1")
        pos += 12 + length
    return None


def frames_folder_problem(folder: Path, tag: str) -> str | None:
    """Why frames of the scene tagged `tag` cannot be written into `folder`, or None.

    The folder must be absent (it is created) or hold only regular `frame_NNNNNN.png`
    files carrying `tag` (frames of an earlier run of this scene, which this run replaces
    or removes) and vrsim's temporary files. Anything else (the user's own images, a
    frame of another scene, a link or FIFO named like a frame) is refused, because the run
    would overwrite or delete it."""
    try:
        st = os.lstat(folder)
    except FileNotFoundError:
        unwritable = folder_write_problem(folder)
        return None if unwritable is None else f"cannot be created: {unwritable}"
    except (OSError, ValueError) as exc:
        return f"cannot be used: {getattr(exc, 'strerror', None) or exc}"
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link; give the folder it points to"
    if not stat.S_ISDIR(st.st_mode):
        return f"is {kind_of(st.st_mode)}; frames go to a folder"
    if folder_write_problem(folder) is not None:
        return "is not writable"
    try:
        names = sorted(os.listdir(folder))
    except OSError as exc:
        return f"cannot list the folder: {exc.strerror or exc}"
    foreign = []
    for name in names:
        if is_partial(name):
            continue  # a temporary file of vrsim's (swept when stale)
        path = folder / name
        try:
            mode = os.lstat(path).st_mode
        except OSError:
            continue  # gone meanwhile
        if not FRAME_PATTERN.fullmatch(name):
            foreign.append(f"'{name}'")
        elif not stat.S_ISREG(mode):
            foreign.append(f"'{name}' ({kind_of(mode)})")
        elif png_tag(path) != tag:
            foreign.append(f"'{name}' (not a frame of this scene)")
    if foreign:
        listed = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more"
                                           if len(foreign) > 3 else "")
        return (f"holds {listed}; frames go to an empty or new folder, or one holding only "
                f"the frames of an earlier run of this scene (vrsim replaces and removes "
                f"frames there, and nothing else)")
    return None


class FramesWriter:
    """Called once per loop frame (and once for the initial state) with the state; keeps
    every `spec.every`-th, and draws them all on `close()`. `renderer` has
    `render(state, overlay, camera)` and `close()` (see `render.open_renderer`); `video`,
    if given, receives every image too (see `writers.video.VideoWriter`)."""

    def __init__(self, model: Model, spec: FramesSpec, renderer, label=None, video=None,
                 tag: str | None = None):
        """`tag`: `frames_tag` of the scene file, written into every frame; only frames
        carrying it are removed at the end (None: frames untagged, as those removed)."""
        self.model = model
        self.tag = tag
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
                    out.write(encode_png(image, self.tag))
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
                    # only a frame of this scene's earlier run (checked before the run,
                    # again now: the folder may have changed meanwhile)
                    if stat.S_ISREG(os.lstat(path).st_mode) and png_tag(path) == self.tag:
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
