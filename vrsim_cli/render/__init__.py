"""Loop stage 3, render: images of the bodies from a camera, off-screen through OSMesa.

Layer 4. This package module is light (no OpenGL): `open_renderer` imports the OpenGL
side (`render.osmesa`) only when frames are asked for, and turns a missing OSMesa or
PyOpenGL into `RenderUnavailable` (exit 2) with the commands that install them, before
anything is simulated.

What is drawn: every body's shape in its colour (spheres, boxes, capsules, cylinders,
planes as a square under the action, meshes through trimesh, particle bodies as their
particles joined by their hull, point masses at a size relative to the scene), springs
as lines, trails of the few moving bodies, lit by one light fixed to the camera; a ground
grid sized to the action (`stage_for`; 2D: flat, behind the bodies); the simulated time
in the top-left corner. Emitted particles appear from their emission on.
"""

from __future__ import annotations

import math
import sys

import numpy as np

from vrsim_cli.errors import InputError
from vrsim_cli.maths.camera import (MIN_VIEW_RADIUS_M, Camera, action_cameras,
                                    framing_camera, projected_radius_px)
from vrsim_cli.render.geometry import PLANE_EXTENT, Stage, body_radii

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
MAX_TRAILS = 12  # bodies: up to this many moving bodies get a trail and a path framing
VIEW_BODY_RATIO = 3.0  # the action camera sees at least this many radii of the largest
MIN_VIEW_M = 1.0  # moving body around its target (6 radii across), or 1 m across if less
PATH_WINDOWS_S = (math.inf, 4.0, 2.0, 1.0, 0.5, 0.25)  # s, the path framings tried
PATH_MIN_PX = 12.0  # px: a path framing keeps every framed body at least this wide ...
PATH_SHARE = 0.6  # ... or this share of its width in the following framing, if smaller
PATH_IMAGES = 0.97  # ... in this share of its images


def action_camera_path(model, states: list, width: int, height: int) -> list[Camera]:
    """The default camera of every image of `states` (the recorded states of a run): it
    keeps every body that moves in view (`camera.action_cameras`, `framed_bodies`), and
    shows their motion: with few moving bodies (MAX_TRAILS) it frames where they are and
    where they go, over the longest window of PATH_WINDOWS_S (the whole run first) that
    keeps them large enough (PATH_MIN_PX); a still ball over a moving floor shows no
    motion. The view is at least MIN_VIEW_M wide, or 2 VIEW_BODY_RATIO radii of the
    largest moving body when that is less (a coin stack fills the image). A scene in which nothing
    moves gets `default_camera` throughout."""
    framed = framed_bodies(model, states)
    if not framed.any():
        return [default_camera(model, width, height)] * len(states)
    pos = np.stack([s.body_pos for s in states])
    radii, inner = body_radii(model)
    times = np.array([s.t for s in states])
    aspect = width / height
    two_d = model.dimension == 2
    moving = np.flatnonzero(framed.any(axis=0))
    # at least a 1 m wide view (as before) unless the bodies are small: then a few times
    # the largest moving body (a coin stack is not 8 px)
    min_radius = max(MIN_VIEW_RADIUS_M, min(MIN_VIEW_M / 2, VIEW_BODY_RATIO *
                                            float(radii[moving].max())))

    # the world anchors of springs are framed too: a spring is seen whole, from the body
    # to where it holds (spheres of radius 0 after the bodies)
    anchors = spring_anchors(model)
    n = model.n_body
    framed_all = framed
    if len(anchors) and len(moving) <= MAX_TRAILS:
        pos = np.concatenate([pos, np.broadcast_to(anchors, (len(states), *anchors.shape))],
                             axis=1)
        radii = np.concatenate([radii, np.zeros(len(anchors))])
        held = np.broadcast_to(framed.any(axis=1, keepdims=True), (len(states), len(anchors)))
        framed_all = np.concatenate([framed, held], axis=1)

    def cameras(path_s: float) -> list[Camera]:
        return action_cameras(pos, radii, framed_all, times, top_down_2d=two_d,
                              aspect=aspect, min_radius=min_radius, path_s=path_s)

    following = cameras(0.0)
    if len(moving) > MAX_TRAILS:
        return following
    base = _widths(following, pos[:, :n], inner, framed, height)
    for window in PATH_WINDOWS_S:
        if window >= times[-1] - times[0] and window != PATH_WINDOWS_S[0]:
            continue  # as the whole run, tried first
        tried = cameras(window)
        wide = _widths(tried, pos[:, :n], inner, framed, height)
        good = (wide >= np.minimum(PATH_MIN_PX, PATH_SHARE * base)) & framed
        if (good.sum(axis=0)[moving] >= PATH_IMAGES * framed.sum(axis=0)[moving]).all():
            return tried  # every body large enough in nearly all its images
    return following


def spring_anchors(model) -> np.ndarray:
    """(a, 3) m: the distinct world anchors of the scene's springs."""
    rigid = model.rigid
    if rigid is None or not len(rigid.spring_b):
        return np.zeros((0, 3))
    world = np.asarray(rigid.spring_b) < 0
    return np.unique(np.asarray(rigid.spring_point_b)[world], axis=0).reshape(-1, 3)


def _widths(cameras: list, pos: np.ndarray, inner: np.ndarray, framed: np.ndarray,
            height: int) -> np.ndarray:
    """(k, n) px: how wide each body's thinnest side is in each image (0 behind the eye)."""
    out = np.zeros(framed.shape)
    for i, camera in enumerate(cameras):
        rel = pos[i] - np.asarray(camera.eye)
        depth = rel @ np.asarray(camera.forward)
        out[i] = 2.0 * projected_radius_px(camera, inner, depth, height)
    return out


def stage_for(model, states: list) -> Stage:
    """The ground of a run's images (`geometry.Stage`): centred under the action (every
    body at the start, planes aside, the moving bodies while they are in the scene, the
    observer), its grid spaced by the power of ten that gives about ten lines across it
    (a coin stack gets a centimetre grid) and wide enough to hold it, the square of a
    plane three times the action's width (at least 20 m): a thrown ball stays over it."""
    radii, _ = body_radii(model)
    solid = radii > 0
    framed = framed_bodies(model, states) if len(states) > 1 else None
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for k, s in enumerate(states):  # state by state: no (k, n, 3) copies of a large run
        keep = (framed[k] if framed is not None else np.zeros(len(radii), dtype=bool))
        if k == 0:
            keep = keep | ((model.body_emit_step <= s.step) & solid)
        if keep.any():
            lo = np.minimum(lo, (s.body_pos[keep] - radii[keep, None]).min(axis=0))
            hi = np.maximum(hi, (s.body_pos[keep] + radii[keep, None]).max(axis=0))
        if s.observer_pos is not None:
            lo, hi = np.minimum(lo, s.observer_pos), np.maximum(hi, s.observer_pos)
    if not np.isfinite(lo).all():
        return Stage()
    centre = 0.5 * (lo + hi)
    two_d = model.dimension == 2
    across = hi - lo
    extent = float(max((across[:2] if two_d else across).max(), 1e-3))  # m, its width
    step = 10.0 ** math.floor(math.log10(extent / 2.0))  # 2 to 20 cells across it
    step = min(max(step, 1e-3), 100.0)
    half = step * min(GRID_MAX_LINES, max(10, math.ceil(0.75 * extent / step) + 5))
    if two_d:
        return Stage(tuple(centre), half, step, "xy", float(lo[2]) - 0.01 * extent,
                     max(PLANE_EXTENT, 3.0 * extent))
    return Stage(tuple(centre), half, step, "xz", _ground_level(model),
                 max(PLANE_EXTENT, 3.0 * extent))


GRID_MAX_LINES = 60  # grid lines each side of the centre, at most


def _ground_level(model) -> float:
    """m: the height of the scene's ground, a plane that faces up (+y), else 0."""
    for shape in model.body_shape:
        if (shape or {}).get("type") == "plane":
            normal = np.asarray(shape["normal"], dtype=float)
            if normal[1] > 0.99 * np.linalg.norm(normal):
                return float(shape["offset"]) * float(normal[1])
    return 0.0


def trail_bodies(model, states: list) -> np.ndarray:
    """(m,) int: the bodies that get a trail (the path they have come along): those the
    action camera frames, when there are at most MAX_TRAILS of them."""
    if len(states) < 2:
        return np.zeros(0, dtype=np.int64)
    framed = framed_bodies(model, states).any(axis=0)
    observer = model.observer
    if observer is not None and observer.mode == "attached":
        framed[observer.body] = False  # the eye rides it: its trail is a line through it
    if framed.sum() > MAX_TRAILS:
        return np.zeros(0, dtype=np.int64)
    return np.flatnonzero(framed)


def framed_bodies(model, states: list) -> np.ndarray:
    """(k, n_body) bool: the bodies the action camera keeps in view in each of k states.

    A body is framed when it moves (its position or orientation changes during the run),
    from its emission on (an emitted particle), while it stays in the scene: within
    LET_GO_M of the box around every body present at the start (planes aside), a little
    more than the ground grid's half-width. A body beyond it has left (collision.yaml's bullet at
    500 m/s, the fountain's particles falling through the floor): following it would
    shrink everything else to nothing.
    """
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
