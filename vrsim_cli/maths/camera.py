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
    clipping distances along forward; ortho: m, half the height an orthographic camera
    sees (glOrtho; 2D scenes), 0 for a perspective one (fov_deg then applies)."""

    eye: tuple
    forward: tuple
    up: tuple
    fov_deg: float = DEFAULT_FOV_DEG
    near: float = DEFAULT_NEAR
    far: float = DEFAULT_FAR
    ortho: float = 0.0

    @classmethod
    def looking_at(cls, eye, target, up=WORLD_UP, fov_deg: float = DEFAULT_FOV_DEG,
                   near: float = DEFAULT_NEAR, far: float = DEFAULT_FAR,
                   ortho: float = 0.0) -> "Camera":
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
                   float(far), float(ortho))

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
        """(4, 4) camera -> clip coordinates, as gluPerspective(fov_deg, aspect, near, far),
        or glOrtho(-aspect h, aspect h, -h, h, near, far) with h = ortho."""
        n, fa = self.near, self.far
        if self.ortho > 0.0:
            h = self.ortho
            proj = np.diag([1.0 / (aspect * h), 1.0 / h, -2.0 / (fa - n), 1.0])
            proj[2, 3] = -(fa + n) / (fa - n)
            return proj
        f = 1.0 / math.tan(math.radians(self.fov_deg) / 2.0)
        proj = np.zeros((4, 4))
        proj[0, 0], proj[1, 1] = f / aspect, f
        proj[2, 2], proj[2, 3] = (fa + n) / (n - fa), 2.0 * fa * n / (n - fa)
        proj[3, 2] = -1.0
        return proj


def framing_camera(points: np.ndarray, radii: np.ndarray, *, top_down_2d: bool = False,
                   fov_deg: float = DEFAULT_FOV_DEG, aspect: float = 4.0 / 3.0) -> Camera:
    """A camera that sees every sphere (points (n, 3) m, radii (n,) m) whole.

    It looks at the centre of their bounding box from above and in front (elevation 20
    degrees, azimuth 30 degrees from +z towards +x) at the distance where the bounding
    sphere of the box fits the narrower field of view (a sphere of radius R seen from
    distance d fills a half-angle asin(R / d)); 2D scenes: straight along -z, through an
    orthographic camera that holds the box. As small as the bodies are: a centimetre
    scene fills the image (at least MIN_VIEW_RADIUS_M).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    radii = np.asarray(radii, dtype=float).reshape(-1)
    if len(points) == 0:
        points, radii = np.zeros((1, 3)), np.ones(1)
    lo = (points - radii[:, None]).min(axis=0)
    hi = (points + radii[:, None]).max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), MIN_VIEW_RADIUS_M)
    distance = fitting_distance(radius, fov_deg, aspect)
    direction = view_direction(top_down_2d)
    near = max(1e-3, min(DEFAULT_NEAR, 0.01 * (distance - radius)))  # coins come close
    far = max(DEFAULT_FAR, 4.0 * (distance + radius))
    ortho = 0.0
    if top_down_2d:
        half = 0.5 * (hi - lo)
        ortho = 1.05 * max(half[1], half[0] / aspect, MIN_VIEW_RADIUS_M)
    return Camera.looking_at(centre + distance * direction, centre, WORLD_UP, fov_deg,
                             near, far, ortho)


MIN_VIEW_RADIUS_M = 1e-3  # m: no view is narrower than 2 mm


ACTION_WINDOW_S = 0.25  # s: the action camera smooths its motion over this before and after
ELEVATION_DEG, AZIMUTH_DEG = 20.0, 30.0  # its direction: above and in front, as framing_camera


def view_direction(top_down_2d: bool) -> np.ndarray:
    """Unit vector from the target towards the eye: elevation 20 deg, azimuth 30 deg from
    +z towards +x (y up); straight along +z for 2D scenes."""
    if top_down_2d:
        return np.array([0.0, 0.0, 1.0])
    elevation, azimuth = math.radians(ELEVATION_DEG), math.radians(AZIMUTH_DEG)
    return np.array([math.cos(elevation) * math.sin(azimuth), math.sin(elevation),
                     math.cos(elevation) * math.cos(azimuth)])


def fitting_distance(radius: float, fov_deg: float, aspect: float) -> float:
    """Distance at which a sphere of `radius` fits the narrower field of view, 5 % margin:
    a sphere of radius R seen from distance d fills a half-angle asin(R / d)."""
    half_v = math.radians(fov_deg) / 2.0
    half = min(half_v, math.atan(aspect * math.tan(half_v)))
    return 1.05 * radius / math.sin(half)


MAX_PATH_POINTS = 200  # times per image the path framing looks at (a stride beyond)


def action_cameras(centres: np.ndarray, radii: np.ndarray, shown: np.ndarray,
                   times: np.ndarray, *, top_down_2d: bool = False,
                   fov_deg: float = DEFAULT_FOV_DEG, aspect: float = 4.0 / 3.0,
                   window_s: float = ACTION_WINDOW_S, min_radius: float = 0.5,
                   path_s: float = 0.0) -> list[Camera]:
    """One camera per image that sees whole every sphere shown in that image, and where
    those spheres are `path_s` before and after (their path: inf frames the whole run).

    centres: (k, n, 3) m, the spheres' centres in each of k images; radii: (n,) m;
    shown: (k, n) bool, the spheres to frame in each image; times: (k,) s.

    The camera looks from a fixed direction (`view_direction`) at a target that follows
    the action: the middle of the box around the image's spheres (with their path),
    averaged over the images within `window_s` before and after (a smooth path, centred
    on the action). Its distance is the least at which every sphere of the image fits
    both the horizontal and the vertical field of view (5 % margin), or the median of
    that distance over the window when larger (the view widens and narrows smoothly, and
    a body that is there for a few images only does not widen the others), and at least
    the distance that shows a sphere of `min_radius`. So the image's own spheres are
    always inside, and the picture is not wasted. 2D scenes (`top_down_2d`) get an
    orthographic camera whose half-height is found the same way. Images with nothing to
    frame keep the previous camera (the first such: the origin).
    """
    centres = np.asarray(centres, dtype=float).reshape(len(times), -1, 3)
    radii = np.asarray(radii, dtype=float).reshape(-1)
    shown = np.asarray(shown, dtype=bool).reshape(centres.shape[:2])
    times = np.asarray(times, dtype=float)
    k = len(times)
    has = shown.any(axis=1)
    start = np.searchsorted(times, times - window_s - 1e-12, side="left")
    stop = np.searchsorted(times, times + window_s + 1e-12, side="right")
    p_start = np.searchsorted(times, times - path_s - 1e-12, side="left")
    p_stop = np.searchsorted(times, times + path_s + 1e-12, side="right")

    def spheres(i: int):
        """(centres (m, 3), radii (m,)) of image i's bodies along their path."""
        a, b = p_start[i], p_stop[i]
        picked = np.unique(np.concatenate([np.arange(a, b, max(1, (b - a) // MAX_PATH_POINTS)),
                                           [i, b - 1]]))
        mask = shown[picked] & shown[i][None, :]  # the path of the bodies shown now
        return centres[picked][mask], np.broadcast_to(radii, mask.shape)[mask]

    middle = np.full((k, 3), np.nan)
    for i in np.flatnonzero(has):
        c, r = spheres(i)
        middle[i] = 0.5 * ((c - r[:, None]).min(axis=0) + (c + r[:, None]).max(axis=0))
    back = view_direction(top_down_2d)  # from the target towards the eye
    right = np.cross(-back, WORLD_UP)
    right /= np.linalg.norm(right)
    up = np.cross(right, -back)
    half_v = math.radians(fov_deg) / 2.0
    half_h = math.atan(aspect * math.tan(half_v))
    shortest = fitting_distance(min_radius, fov_deg, aspect)
    target = np.full((k, 3), np.nan)
    need = np.full(k, np.nan)  # least distance (2D: half-height) that shows the image
    depth = np.zeros(k)  # 2D: how far the spheres reach towards the eye
    for i in np.flatnonzero(has):
        target[i] = np.nanmean(middle[start[i]:stop[i]], axis=0)
        c, r = spheres(i)
        rel = c - target[i]
        if top_down_2d:
            need[i] = 1.05 * max(float(np.max(np.abs(rel @ up) + r)),
                                 float(np.max(np.abs(rel @ right) + r)) / aspect,
                                 min_radius)
            depth[i] = float(np.max(rel @ back + r))
        else:
            need[i] = max(_fit(rel @ right, rel @ back, r, half_h),
                          _fit(rel @ up, rel @ back, r, half_v), shortest)
    cameras: list[Camera] = []
    aim, distance, ortho = np.zeros(3), shortest, 0.0
    for i in range(k):
        if has[i]:
            aim = target[i]
            size = max(need[i], float(np.nanmedian(need[start[i]:stop[i]])))
            if top_down_2d:  # orthographic: the eye's distance only sets the clipping
                ortho = size
                distance = fitting_distance(size, fov_deg, aspect) + max(depth[i], 0.0)
            else:
                distance = size
        near_clip = max(1e-3, min(DEFAULT_NEAR, 0.01 * distance))
        far_clip = max(DEFAULT_FAR, 8.0 * distance)
        cameras.append(Camera.looking_at(aim + distance * back, aim, WORLD_UP,
                                         fov_deg, near_clip, far_clip, ortho))
    return cameras


def _fit(across: np.ndarray, towards: np.ndarray, r: np.ndarray, half: float) -> float:
    """Least distance D of the eye from the target (along the view axis) at which spheres
    offset `across` the view and `towards` the eye, of radii r, lie within a field of
    half-angle `half` (5 % margin): |across| + r / cos(half) <= (D - towards) tan(half)."""
    slope = math.tan(half) / 1.05
    return float(np.max(towards + (np.abs(across) + r / math.cos(half)) / slope))


def project(camera: Camera, points: np.ndarray, width: int, height: int) -> tuple:
    """Pixel coordinates (n, 2) (x right, y down from the top-left corner) and depths (n,)
    in m along the view direction of world points (n, 3)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    eye = (camera.view_matrix() @ np.hstack([points, np.ones((len(points), 1))]).T).T
    clip = (camera.projection_matrix(width / height) @ eye.T).T
    depth = -eye[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        ndc = clip[:, :2] / clip[:, 3:4]
    pixels = np.column_stack([(ndc[:, 0] + 1.0) * 0.5 * width,
                              (1.0 - ndc[:, 1]) * 0.5 * height])
    return pixels, depth


def projected_radius_px(camera: Camera, radius: np.ndarray, depth: np.ndarray,
                        height: int) -> np.ndarray:
    """Pixels spanned by the radius of a sphere at `depth` m (small-angle: r / d times
    the focal length in pixels, height / (2 tan(fov / 2)))."""
    if camera.ortho > 0.0:  # orthographic: the same scale at every depth
        return np.where(np.asarray(depth) > 0, np.asarray(radius) * height / (2.0 * camera.ortho),
                        0.0)
    focal = height / (2.0 * math.tan(math.radians(camera.fov_deg) / 2.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(depth > 0, focal * np.asarray(radius) / depth, 0.0)
