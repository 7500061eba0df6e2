"""Loop stage 3, render: images of the bodies from a camera, off-screen through OSMesa.

Layer 4. This package module is light (no OpenGL): `open_renderer` imports the OpenGL
side (`render.osmesa`) only when frames are asked for, and turns a missing OSMesa or
PyOpenGL into `RenderUnavailable` (exit 2) with the commands that install them, before
anything is simulated.

What is drawn: every body's shape in its colour (spheres, boxes, capsules, cylinders,
planes as a 20 m square, meshes through trimesh, point masses as 5 cm spheres), lit by one
light fixed to the camera; a 1 m ground grid on y = 0 from -10 to 10 m; the simulated time
in the top-left corner. Emitted particles appear from their emission on.
"""

from __future__ import annotations

import sys

from vrsim_cli.errors import InputError
import numpy as np

from vrsim_cli.maths.camera import Camera, action_cameras, framing_camera

INSTALL_HINT = ("install OSMesa and PyOpenGL: `apt-get install libosmesa6` and "
                "`pip install 'vrsim-cli[render]'`")


class RenderUnavailable(InputError):
    """Frames were asked for but cannot be rendered on this machine (exit 2)."""

    def __init__(self, reason: str):
        super().__init__(f"rendering frames needs off-screen OpenGL (OSMesa), which is not "
                         f"available: {reason}; {INSTALL_HINT}")


def default_camera(model, width: int, height: int) -> Camera:
    """The camera used when the scene gives none: it frames every body at t = 0 and the
    top of its free flight (see `camera.framing_camera`); 2D scenes are seen from +z."""
    from vrsim_cli.render.geometry import bounding_spheres, draw_list

    centres, radii = bounding_spheres(model, draw_list(model))
    return framing_camera(centres, radii, top_down_2d=model.dimension == 2,
                          aspect=width / height)


MOVED_M = 1e-6  # m: a body whose position changes more than this moves
TURNED = 1e-6  # a body whose quaternion changes more than this (per component) moves
LET_GO_M = 12.0  # m: this far from where the scene starts, a body has left it


def action_camera_path(model, states: list, width: int, height: int) -> list[Camera]:
    """The default camera of every image of `states` (the recorded states of a run): it
    keeps every body that moves in view (`camera.action_cameras`, `framed_bodies`). A
    scene in which nothing moves gets `default_camera` throughout."""
    from vrsim_cli.render.geometry import body_radii

    framed = framed_bodies(model, states)
    if not framed.any():
        return [default_camera(model, width, height)] * len(states)
    pos = np.stack([s.body_pos for s in states])
    radii, _ = body_radii(model)
    return action_cameras(pos, radii, framed, np.array([s.t for s in states]),
                          top_down_2d=model.dimension == 2, aspect=width / height)


def framed_bodies(model, states: list) -> np.ndarray:
    """(k, n_body) bool: the bodies the action camera keeps in view in each of k states.

    A body is framed when it moves (its position or orientation changes during the run),
    from its emission on (an emitted particle), while it stays in the scene: within
    LET_GO_M of the box around every body present at the start (planes aside), a little
    more than the ground grid's half-width. A body beyond it has left (collision.yaml's bullet at
    500 m/s, the fountain's particles falling through the floor): following it would
    shrink everything else to nothing.
    """
    from vrsim_cli.render.geometry import body_radii

    pos = np.stack([s.body_pos for s in states])
    quat = np.stack([s.body_quat for s in states])
    steps = np.array([s.step for s in states])
    exists = model.body_emit_step[None, :] <= steps[:, None]
    first = np.argmax(exists, axis=0)  # each body's first image
    every = np.arange(model.n_body)
    moved = (np.abs(pos - pos[first, every]).max(axis=(0, 2)) > MOVED_M) | \
        (np.abs(quat - quat[first, every]).max(axis=(0, 2)) > TURNED)
    moved &= exists.any(axis=0)
    lo, hi = start_box(model, states[0])
    outside = np.linalg.norm(np.maximum(lo - pos, 0.0) + np.maximum(pos - hi, 0.0), axis=-1)
    return exists & moved[None, :] & (outside <= LET_GO_M)


def start_box(model, state) -> tuple[np.ndarray, np.ndarray]:
    """(lo (3,), hi (3,)) m: the box around the bodies present in `state` (the first),
    each as its bounding sphere; planes are infinite and left out."""
    from vrsim_cli.render.geometry import body_radii

    radii, _ = body_radii(model)
    present = np.flatnonzero((model.body_emit_step <= state.step) & (radii > 0))
    if len(present) == 0:
        return np.zeros(3), np.zeros(3)
    return ((state.body_pos[present] - radii[present, None]).min(axis=0),
            (state.body_pos[present] + radii[present, None]).max(axis=0))


def time_label(t: float) -> str:
    """The overlay text for simulated time `t` s, e.g. `t = 1.250 s`."""
    return f"t = {t:.3f} s"


def open_renderer(model, width: int, height: int, camera: Camera | None = None):
    """An `OsmesaRenderer` for `model`; raises RenderUnavailable when OSMesa, PyOpenGL or
    (for mesh shapes) trimesh is missing."""
    if camera is None:
        camera = default_camera(model, width, height)
    loaded = getattr(sys.modules.get("OpenGL.platform"), "PLATFORM", None)
    if loaded is not None and "osmesa" not in type(loaded).__module__:
        raise RenderUnavailable("OpenGL was already loaded for another platform in this "
                                "process")
    problem = _probe()
    if problem:
        raise RenderUnavailable(problem)
    try:
        from vrsim_cli.render.osmesa import OsmesaRenderer, OsmesaUnavailable
    except (ImportError, AttributeError, OSError) as exc:  # PyOpenGL fails in several ways
        raise RenderUnavailable(_reason(exc)) from None
    try:
        return OsmesaRenderer(model, width, height, camera)
    except ImportError as exc:  # trimesh, for a mesh shape
        raise RenderUnavailable(_reason(exc)) from None
    except OsmesaUnavailable as exc:
        raise RenderUnavailable(str(exc)) from None


OSMESA_NAMES = ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so")  # Debian's, then any


def _probe() -> str | None:
    """Why OSMesa rendering cannot work here, or None. Checked before PyOpenGL is
    imported: without the library PyOpenGL fails late, with an AttributeError."""
    import ctypes
    import importlib.util

    if "OpenGL" not in sys.modules and importlib.util.find_spec("OpenGL") is None:
        return "PyOpenGL is not installed"
    for name in OSMESA_NAMES:
        try:
            ctypes.CDLL(name)
            return None
        except OSError:
            continue
    return "the OSMesa library (libOSMesa.so) was not found"


def _reason(exc: Exception) -> str:
    if getattr(exc, "name", None) == "OpenGL":
        return "PyOpenGL is not installed"
    if getattr(exc, "name", None) == "trimesh":
        return "trimesh (for mesh shapes) is not installed"
    if exc.args and "Unable to load OpenGL library" in str(exc.args[0]):
        return "the OSMesa library (libOSMesa.so) was not found"
    return f"{type(exc).__name__}: {exc}"
