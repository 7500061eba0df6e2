"""The Camera value against an independent pinhole model, and the default framing."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vrsim_cli.maths.camera import Camera, framing_camera


def pinhole(eye, target, up, fov_deg, width, height, points):
    """Pixel coordinates (x right, y down, continuous) of world points, and their depth.

    Written from the pinhole model, not from the renderer's matrices: the focal length in
    pixels is (height / 2) / tan(fov / 2); x and y scale by focal / depth about the centre.
    """
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = np.asarray(points, float) - eye
    xc, yc, zc = d @ r, d @ u, d @ f
    focal = (height / 2) / math.tan(math.radians(fov_deg) / 2)
    return np.stack([width / 2 + focal * xc / zc, height / 2 - focal * yc / zc], -1), zc


def through_matrices(camera: Camera, width, height, points):
    """Pixel coordinates through view and projection matrices, as OpenGL computes them."""
    homo = np.hstack([points, np.ones((len(points), 1))])
    clip = homo @ (camera.projection_matrix(width / height) @ camera.view_matrix()).T
    ndc = clip[:, :3] / clip[:, 3:]
    return np.stack([(ndc[:, 0] + 1) / 2 * width, (1 - ndc[:, 1]) / 2 * height], -1), ndc[:, 2]


def test_matrices_agree_with_the_pinhole_model():
    rng = np.random.default_rng(1)
    eye, target, up = [3.0, 2.0, 4.0], [0.2, 0.5, -0.3], [0.0, 1.0, 0.0]
    camera = Camera.looking_at(eye, target, up, fov_deg=50.0, near=0.1, far=100.0)
    points = rng.uniform(-2, 2, (200, 3))
    expected, depth = pinhole(eye, target, up, 50.0, 320, 200, points)
    got, ndc_z = through_matrices(camera, 320, 200, points)
    # Both are a few float64 operations on numbers of order 1e3 px: 1e-9 px is round-off.
    np.testing.assert_allclose(got, expected, atol=1e-9)
    # Depth maps near -> -1 and far -> +1 (OpenGL), monotonically in between.
    assert np.all(np.diff(ndc_z[np.argsort(depth)]) > 0)
    on_axis = np.array(eye) + np.outer([0.1, 100.0], camera.forward)  # at near and far
    edges, z = through_matrices(camera, 320, 200, on_axis)
    np.testing.assert_allclose(edges, [[160, 100], [160, 100]], atol=1e-9)


def test_basis_is_orthonormal_and_up_is_kept_in_view():
    camera = Camera.looking_at([0, 5, 5], [0, 0, 0], up=[0, 2, 0])
    f, u = np.array(camera.forward), np.array(camera.up)
    assert np.linalg.norm(f) == pytest.approx(1, abs=1e-15)
    assert np.linalg.norm(u) == pytest.approx(1, abs=1e-15)
    assert f @ u == pytest.approx(0, abs=1e-15)
    assert u[1] > 0  # world up still points up in the image


@pytest.mark.parametrize("eye,target,up,message", [
    ([1, 1, 1], [1, 1, 1], [0, 1, 0], "coincide"),
    ([0, 5, 0], [0, 0, 0], [0, 1, 0], "parallel"),
])
def test_degenerate_cameras_are_refused(eye, target, up, message):
    with pytest.raises(ValueError, match=message):
        Camera.looking_at(eye, target, up)


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("top_down_2d", [False, True])
def test_framing_camera_sees_every_sphere_whole(seed, top_down_2d):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-5, 5, (30, 3)) * rng.uniform(0.01, 3, 3)
    if top_down_2d:
        centres[:, 2] = 0.0
    radii = rng.uniform(0, 0.5, 30)
    width, height = 640, 360
    camera = framing_camera(centres, radii, top_down_2d=top_down_2d, aspect=width / height)
    # The six extreme points of every sphere along the camera's axes stay inside the image.
    r_axis = np.cross(camera.forward, camera.up)
    offsets = np.array([r_axis, -r_axis, camera.up, -np.array(camera.up), camera.forward,
                        -np.array(camera.forward)])
    points = (centres[:, None, :] + radii[:, None, None] * offsets).reshape(-1, 3)
    if top_down_2d:  # orthographic along -z: `ortho` m from the image centre to its top
        assert camera.ortho > 0 and camera.forward == pytest.approx((0, 0, -1))
        rel = points - np.asarray(camera.eye)
        scale = (height / 2) / camera.ortho
        r_unit = r_axis / np.linalg.norm(r_axis)
        px = np.column_stack([width / 2 + scale * (rel @ r_unit),
                              height / 2 - scale * (rel @ np.asarray(camera.up))])
        depth = rel @ np.asarray(camera.forward)
    else:
        px, depth = pinhole(camera.eye, np.add(camera.eye, camera.forward), camera.up,
                            camera.fov_deg, width, height, points)
    assert np.all(depth > camera.near) and np.all(depth < camera.far)
    assert np.all((px >= 0) & (px <= [width, height]))


def test_an_orthographic_camera_maps_metres_to_pixels_at_any_depth():
    """glOrtho: a point (x, y) m from the view axis lands at (W/2 + x s, H/2 - y s) with
    s = (H/2) / ortho px per m, whatever its depth (2D scenes' flat view)."""
    from vrsim_cli.maths.camera import project

    camera = Camera.looking_at([1, 2, 10], [1, 2, 0], ortho=2.5, near=0.1, far=100)
    points = np.array([[1, 2, 0], [2, 2, 0], [1, 3.5, -30], [-1, 0, 5]], dtype=float)
    px, depth = project(camera, points, 640, 480)
    s = 240 / 2.5
    expected = np.column_stack([320 + s * (points[:, 0] - 1), 240 - s * (points[:, 1] - 2)])
    np.testing.assert_allclose(px, expected, atol=1e-9)
    np.testing.assert_allclose(depth, 10 - points[:, 2])
