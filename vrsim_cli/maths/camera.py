"""A perspective pinhole camera: where it is, where it looks, how wide it sees.

Layer 0, numpy only. The renderer takes a `Camera` value; where the value comes from (the
scene's `output.frames.camera`, a default that frames the bodies, later the observer) is
not its concern.

Conventions (those of OpenGL's gluLookAt/gluPerspective): the camera looks along
`forward`; image right is `forward x up`, image up is `right x forward`; `fov_deg` is the
vertical field of view, the horizontal one follows from the image's aspect ratio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_FOV_DEG = 60.0  # vertical, degrees
DEFAULT_NEAR = 0.05  # m
DEFAULT_FAR = 1000.0  # m
WORLD_UP = (0.0, 1.0, 0.0)  # y is up, as on the slides


@dataclass(frozen=True)
class Camera:
    """eye: (3,) m, world position; forward, up: (3,) unit vectors (up is made
    perpendicular to forward); fov_deg: vertical field of view, degrees; near, far: m,
    clipping distances along forward."""

    eye: tuple
    forward: tuple
    up: tuple
    fov_deg: float = DEFAULT_FOV_DEG
    near: float = DEFAULT_NEAR
    far: float = DEFAULT_FAR

    @classmethod
    def looking_at(cls, eye, target, up=WORLD_UP, fov_deg: float = DEFAULT_FOV_DEG,
                   near: float = DEFAULT_NEAR, far: float = DEFAULT_FAR) -> "Camera":
        """A camera at `eye` looking at `target`. Raises ValueError when they coincide or
        `up` is parallel to the line of sight."""
        eye = np.asarray(eye, dtype=float)
        forward = np.asarray(target, dtype=float) - eye
        if np.linalg.norm(forward) < 1e-9:
            raise ValueError("the camera's position and look_at point coincide")
        forward /= np.linalg.norm(forward)
        up = np.asarray(up, dtype=float)
        right = np.cross(forward, up)
        if np.linalg.norm(right) < 1e-6 * max(np.linalg.norm(up), 1e-300):
            raise ValueError("the camera's up direction is parallel to its line of sight")
        right /= np.linalg.norm(right)
        true_up = np.cross(right, forward)
        return cls(tuple(eye), tuple(forward), tuple(true_up), float(fov_deg), float(near),
                   float(far))

    def view_matrix(self) -> np.ndarray:
        """(4, 4) world -> camera coordinates (x right, y up, looking along -z)."""
        f = np.asarray(self.forward, dtype=float)
        r = np.cross(f, self.up)
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = r, u, -f
        view[:3, 3] = -view[:3, :3] @ np.asarray(self.eye, dtype=float)
        return view

    def projection_matrix(self, aspect: float) -> np.ndarray:
        """(4, 4) camera -> clip coordinates, as gluPerspective(fov_deg, aspect, near, far)."""
        f = 1.0 / math.tan(math.radians(self.fov_deg) / 2.0)
        n, fa = self.near, self.far
        proj = np.zeros((4, 4))
        proj[0, 0], proj[1, 1] = f / aspect, f
        proj[2, 2], proj[2, 3] = (fa + n) / (n - fa), 2.0 * fa * n / (n - fa)
        proj[3, 2] = -1.0
        return proj


def framing_camera(points: np.ndarray, radii: np.ndarray, *, top_down_2d: bool = False,
                   fov_deg: float = DEFAULT_FOV_DEG, aspect: float = 4.0 / 3.0) -> Camera:
    """A camera that sees every sphere (points (n, 3) m, radii (n,) m) whole.

    It looks at the centre of their bounding box from above and in front (elevation 20
    degrees, azimuth 30 degrees from +z towards +x), or straight along -z for 2D scenes,
    at the distance where the bounding sphere of the box fits the narrower field of view:
    a sphere of radius R seen from distance d fills a half-angle asin(R / d).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    radii = np.asarray(radii, dtype=float).reshape(-1)
    if len(points) == 0:
        points, radii = np.zeros((1, 3)), np.ones(1)
    lo = (points - radii[:, None]).min(axis=0)
    hi = (points + radii[:, None]).max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.5)  # at least a 1 m wide view
    half_v = math.radians(fov_deg) / 2.0
    half = min(half_v, math.atan(aspect * math.tan(half_v)))
    distance = 1.05 * radius / math.sin(half)  # 5 % margin
    if top_down_2d:
        direction = np.array([0.0, 0.0, 1.0])
    else:
        elevation, azimuth = math.radians(20.0), math.radians(30.0)
        direction = np.array([math.cos(elevation) * math.sin(azimuth), math.sin(elevation),
                              math.cos(elevation) * math.cos(azimuth)])
    near = max(DEFAULT_NEAR, 0.01 * (distance - radius))
    far = max(DEFAULT_FAR, 4.0 * (distance + radius))
    return Camera.looking_at(centre + distance * direction, centre, WORLD_UP, fov_deg,
                             near, far)
