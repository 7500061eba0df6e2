"""Compile the scene's `output.frames` key: where rendered frames go, how often, how big.

Layer 2 (a helper of `model.compile_model`). Frames are rendered only when a folder is
known: `output.frames.dir` in the scene or `vrsim run --frames DIR` (which sets it as a
command-line override). Without one the other keys are kept as settings for `--frames`,
and `FramesSpec` is None: the run never touches OpenGL.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from vrsim_cli.errors import Problem
from vrsim_cli.maths.camera import DEFAULT_FOV_DEG, WORLD_UP, Camera
from vrsim_cli.scene.spec import Scene

DEFAULT_FRAME_WIDTH = 640  # px
DEFAULT_FRAME_HEIGHT = 480  # px
DEFAULT_FRAME_EVERY = 1  # render every loop frame


@dataclass(frozen=True)
class FramesSpec:
    """dir: folder of the PNGs; every: render one image every this many loop frames;
    width, height: px; camera: None means the renderer's default camera."""

    dir: Path
    every: int
    width: int
    height: int
    camera: Camera | None = None


def compile_frames(scene: Scene, problems: list[Problem]) -> FramesSpec | None:
    """The frames plan, or None when no frame folder is given. Appends located problems."""
    frames = (scene.data.get("output") or {}).get("frames")
    if not frames:
        return None
    at = ("output", "frames")
    camera = None
    if "camera" in frames:
        spec = frames["camera"]
        try:
            camera = Camera.looking_at(spec["position"], spec["look_at"],
                                       spec.get("up", WORLD_UP),
                                       spec.get("fov_deg", DEFAULT_FOV_DEG))
        except ValueError as exc:
            problems.append(scene.problem(at + ("camera",), str(exc),
                                          "move look_at, or give another up direction"))
    if "dir" not in frames:
        return None
    folder = scene.resolve_path(at + ("dir",), problems, output=True)
    if folder is None:
        return None
    if os.path.lexists(folder) and not folder.is_dir():  # found now, not after the run
        problems.append(scene.problem(at + ("dir",), f"'{scene.get(at + ('dir',))}' is a "
                                      f"file, not a folder", "frames go to a folder"))
        return None
    return FramesSpec(dir=folder, every=int(frames.get("every", DEFAULT_FRAME_EVERY)),
                      width=int(frames.get("width", DEFAULT_FRAME_WIDTH)),
                      height=int(frames.get("height", DEFAULT_FRAME_HEIGHT)), camera=camera)
