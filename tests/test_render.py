"""The render stage draws real frames through OSMesa; checked against the pinhole model."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from test_camera import pinhole
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.render import RenderUnavailable, default_camera, open_renderer, time_label
from vrsim_cli.render.label import label_box
from vrsim_cli.scene.spec import parse_scene

W, H = 320, 240
BACKGROUND = np.array([0.92, 0.93, 0.95]) * 255  # the documented clear colour
# OpenGL converts a float colour to 8 bits "rounding to nearest" with one unit of leeway
# (GL spec, 2.3.5.2), so the background may be off by 1 per channel.
BACKGROUND_TOL = 1

EYE, TARGET, UP, FOV = [0.5, 1.0, 4.0], [1.0, 1.6, 0.0], [0.0, 1.0, 0.0], 50.0


def render(text: str, camera=True, width=W, height=H, overlay=None):
    if camera:
        text += (f"output: {{frames: {{camera: {{position: {EYE}, look_at: {TARGET}, "
                 f"fov_deg: {FOV}}}}}}}\n")
    model = compile_model(parse_scene(text))
    cam = None
    if camera:
        from vrsim_cli.maths.camera import Camera
        cam = Camera.looking_at(EYE, TARGET, UP, FOV)
    renderer = open_renderer(model, width, height, cam)
    try:
        return model, renderer.render(make_state(model), overlay)
    finally:
        renderer.close()


def scene(*bodies: str) -> str:
    return "vrsim: 1\nduration: 0.1\nframe_rate: 10\nbodies:\n" + "".join(
        f"  - {b}\n" for b in bodies)


RED_AT = [1.3, 1.9, -0.5]
RED_RADIUS = 0.25


@pytest.mark.osmesa
def test_red_sphere_appears_at_its_projected_pixel():
    _, image = render(scene(f"{{name: ball, type: static, shape: {{type: sphere, radius: "
                            f"{RED_RADIUS}}}, position: {RED_AT}, color: [1, 0, 0]}}"))
    assert image.shape == (H, W, 3) and image.dtype == np.uint8
    px, depth = pinhole(EYE, TARGET, UP, FOV, W, H, [RED_AT])
    x, y = px[0]
    centre = image[int(y), int(x)]
    assert centre[0] > 150 and centre[1] == 0 and centre[2] == 0  # lit red, nothing else
    red = (image[..., 0] > 40) & (image[..., 1] == 0) & (image[..., 2] == 0)
    rows, cols = np.nonzero(red)
    # The silhouette of an off-axis sphere is an ellipse whose centre lies about
    # focal * alpha^2 * tan(theta) ~ 0.3 px outward of the projected centre (angular radius
    # alpha ~ 0.06, off-axis angle theta ~ 0.2 here); the tessellation and the pixel grid
    # add less than 0.2 px. So the red centroid is within 1 px of the pinhole projection.
    assert abs(cols.mean() + 0.5 - x) < 1.0 and abs(rows.mean() + 0.5 - y) < 1.0
    # Its area is pi (focal r / depth)^2 up to the 24-gon's 0.989 and the ellipse's
    # stretch (< 2 % here): 5 % tells a wrong field of view (10 % off gives 20 %) apart.
    focal = (H / 2) / np.tan(np.radians(FOV) / 2)
    radius_px = focal * RED_RADIUS / np.sqrt(depth[0] ** 2 - RED_RADIUS ** 2)
    assert red.sum() == pytest.approx(np.pi * radius_px ** 2, rel=0.05)
    # Everything else is background: a ring 3 px outside the silhouette, and the corners.
    angles = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    ring_x = (x + (radius_px + 3) * np.cos(angles)).astype(int)
    ring_y = (y + (radius_px + 3) * np.sin(angles)).astype(int)
    for pixel in list(image[ring_y, ring_x]) + [image[0, -1], image[0, 0]]:
        np.testing.assert_allclose(pixel, BACKGROUND, atol=BACKGROUND_TOL)


@pytest.mark.osmesa
def test_a_camera_given_per_image_moves_the_view():
    from vrsim_cli.maths.camera import Camera
    model = compile_model(parse_scene(scene(
        f"{{name: ball, type: static, shape: {{type: sphere, radius: {RED_RADIUS}}}, "
        f"position: {RED_AT}, color: [1, 0, 0]}}")))
    renderer = open_renderer(model, W, H, Camera.looking_at(EYE, TARGET, UP, FOV))
    state = make_state(model)
    eye2, target2 = [-1.0, 2.5, 2.0], [0.8, 1.7, -0.2]
    moved = renderer.render(state, camera=Camera.looking_at(eye2, target2, UP, 40.0))
    kept = renderer.render(state)  # the last camera stays
    renderer.close()
    for image in (moved, kept):
        red = (image[..., 0] > 40) & (image[..., 1] == 0) & (image[..., 2] == 0)
        rows, cols = np.nonzero(red)
        (x, y), = pinhole(eye2, target2, UP, 40.0, W, H, [RED_AT])[0]
        # As in the test above: ellipse offset and pixel grid stay under 1 px.
        assert abs(cols.mean() + 0.5 - x) < 1.0 and abs(rows.mean() + 0.5 - y) < 1.0


@pytest.mark.osmesa
def test_box_capsule_and_cylinder_show_their_colours():
    bodies = {
        "box": ("{type: box, size: [0.4, 0.3, 0.5]}", [0.2, 1.3, 0.0], [0, 1, 0], 1),
        "pill": ("{type: capsule, radius: 0.12, length: 0.4}", [1.8, 1.7, -0.5], [0, 0, 1], 2),
        "can": ("{type: cylinder, radius: 0.15, length: 0.3}", [0.9, 2.1, -1.0], [1, 1, 0], 0),
    }
    text = scene(*(f"{{name: {n}, type: static, shape: {s}, position: {p}, color: {c}}}"
                   for n, (s, p, c, _) in bodies.items()))
    _, image = render(text)
    for name, (_, position, color, channel) in bodies.items():
        (x, y), = pinhole(EYE, TARGET, UP, FOV, W, H, [position])[0]
        pixel = image[int(y), int(x)].astype(int)
        off = [c for c in range(3) if color[c] == 0]
        assert pixel[channel] > 60, name  # lit in its colour
        assert all(pixel[c] == 0 for c in off), (name, pixel)


@pytest.mark.osmesa
def test_mesh_shapes_are_drawn_through_trimesh(tmp_path):
    stl = tmp_path / "tetra.stl"
    corners = np.array([[0.3, -0.2, 0.2], [-0.3, -0.2, 0.2], [0, -0.2, -0.3], [0, 0.3, 0]])
    faces = [(0, 2, 1), (0, 1, 3), (1, 2, 3), (2, 0, 3)]
    lines = ["solid t"]
    for a, b, c in faces:
        n = np.cross(corners[b] - corners[a], corners[c] - corners[a])
        lines += [f"facet normal {n[0]} {n[1]} {n[2]}", "outer loop"]
        lines += [f"vertex {v[0]} {v[1]} {v[2]}" for v in corners[[a, b, c]]]
        lines += ["endloop", "endfacet"]
    stl.write_text("\n".join(lines + ["endsolid t"]) + "\n")
    text = scene(f"{{name: tet, type: static, shape: {{type: mesh, file: tetra.stl, scale: 1.5}},"
                 f" position: {RED_AT}, color: [1, 0, 1]}}")
    text += (f"output: {{frames: {{camera: {{position: {EYE}, look_at: {TARGET}, "
             f"fov_deg: {FOV}}}}}}}\n")
    from vrsim_cli.maths.camera import Camera
    model = compile_model(parse_scene(text, base_dir=tmp_path))
    renderer = open_renderer(model, W, H, Camera.looking_at(EYE, TARGET, UP, FOV))
    image = renderer.render(make_state(model))
    renderer.close()
    (x, y), = pinhole(EYE, TARGET, UP, FOV, W, H, [RED_AT])[0]
    pixel = image[int(y), int(x)]
    assert pixel[0] > 60 and pixel[2] > 60 and pixel[1] == 0


@pytest.mark.parametrize("dimension,shape,position", [
    (3, "{type: sphere, radius: 0.3}", [2, 1, -1]),
    (2, "{type: box, size: [0.5, 0.5]}", [3, 4]),
])
@pytest.mark.osmesa
def test_default_camera_frames_a_lone_body_at_the_image_centre(dimension, shape, position):
    text = scene(f"{{name: b, type: static, shape: {shape}, position: {position}, "
                 f"color: [1, 0, 0]}}").replace("bodies:", f"dimension: {dimension}\nbodies:")
    model, image = render(text, camera=False)
    assert tuple(image[H // 2, W // 2]) != tuple(np.round(BACKGROUND))
    assert image[H // 2, W // 2, 0] > 100 and image[H // 2, W // 2, 1] == 0
    camera = default_camera(model, W, H)
    if dimension == 2:
        assert camera.forward == pytest.approx((0, 0, -1))


@pytest.mark.osmesa
def test_particles_appear_from_their_emission_on():
    text = scene("{name: wall, type: static, shape: {type: box, size: [0.1, 0.1, 0.1]}, "
                 "position: [0, 1, 0]}")
    text += ("emitters: [{name: p, position: [1.0, 1.6, 0], direction: [0, 1, 0], speed: 0, "
             "count: 2, rate: 1, mass: 1, radius: 0.3, color: [1, 0, 0]}]\n")
    from vrsim_cli.maths.camera import Camera
    model = compile_model(parse_scene(text))
    renderer = open_renderer(model, W, H, Camera.looking_at(EYE, TARGET, UP, FOV))
    state = make_state(model)
    second = model.body_index["p.0001"]
    emitted_at = int(model.body_emit_step[second])
    assert emitted_at == round(1.0 / model.dt)  # rate 1 per second: the second leaves at 1 s
    pos = state.body_pos.copy()
    pos[second] = [2.0, 1.6, -0.5]  # apart from the first, so each has its own pixels
    state = state.replace(body_pos=pos)
    red = lambda img: int(((img[..., 0] > 40) & (img[..., 1] == 0)).sum())  # noqa: E731
    before = red(renderer.render(state.replace(step=emitted_at - 1)))
    after = red(renderer.render(state.replace(step=emitted_at)))
    renderer.close()
    assert before > 100  # the first particle, emitted at t = 0
    assert after > 1.5 * before  # now the second one too


@pytest.mark.osmesa
def test_time_overlay_is_drawn_top_left_and_only_there():
    body = ("{name: b, type: static, shape: {type: sphere, radius: 0.2}, "
            "position: [1, 1.6, 0]}")
    model, plain = render(scene(body))
    _, labelled = render(scene(body), overlay=time_label(12.5))
    assert time_label(12.5) == "t = 12.500 s"
    changed_rows, changed_cols = np.nonzero((plain != labelled).any(axis=2))
    scale = H // 240
    left, top, right, bottom = label_box("t = 12.500 s", 4 * scale, 4 * scale, scale)
    # Changes stay inside the text's box, which starts near the top-left corner ...
    assert changed_rows.min() >= top and changed_rows.max() < bottom
    assert changed_cols.min() >= left and changed_cols.max() < right
    assert 0 <= left <= 4 * scale and 0 <= top <= 8 * scale and right < W // 2
    # ... and holds dark text on a light box: text pixels and box pixels both
    box = labelled[top:bottom, left:right].astype(int).sum(axis=2)
    assert (box < 3 * 80).sum() > 50 and (box > 3 * 200).sum() > 0.5 * box.size


def test_any_text_can_be_drawn():
    """Pillow's font has the letters the old 5x7 bitmap font lacked."""
    from vrsim_cli.render.label import draw_label

    image = np.full((40, 200, 3), 128, dtype=np.uint8)
    out = draw_label(image, "t = 1 h, Ω", 4, 4, 1)
    assert out.shape == image.shape and (out != image).any()



@pytest.mark.osmesa
def test_missing_pyopengl_is_reported_with_the_install_commands(monkeypatch):
    model = compile_model(parse_scene(scene("{name: b, mass: 1}")))
    monkeypatch.setitem(sys.modules, "OpenGL", None)  # as if PyOpenGL were not installed
    monkeypatch.delitem(sys.modules, "vrsim_cli.render.osmesa", raising=False)
    with pytest.raises(RenderUnavailable) as info:
        open_renderer(model, 32, 32)
    message = str(info.value)
    assert "PyOpenGL is not installed" in message
    assert "apt-get install libosmesa6" in message and "pip install 'vrsim-cli[render]'" in message
    assert info.value.exit_code == 2


def test_default_framing_follows_the_free_flight_in_closed_form():
    from vrsim_cli.render.geometry import flight_points

    model = compile_model(parse_scene(
        "vrsim: 1\nduration: 2\ngravity: [0, -10, 0]\nbodies:\n"
        "  - {name: ball, mass: 1, position: [0, 1, 0], velocity: [3, 4, 0]}\n"
        "  - {name: cart, type: kinematic, position: [1, 0, 0], velocity: [0, 0, 1]}\n"))
    # Kinematic: p0 + v t at t = 2. Ball: top at t = 4/10 -> (1.2, 1.8, 0); back on the
    # ground y = 0 at t = (4 + sqrt(16 + 2 * 10 * 1)) / 10 = 1 -> (3, 0, 0).
    np.testing.assert_allclose(flight_points(model),
                               [[1, 0, 2], [1.2, 1.8, 0], [3, 0, 0]], atol=1e-12)


# --------------------------------------------------------------------- showing the motion
# Truth: an orthographic projection written here (a 2D scene seen along -z: x right, y up,
# s = (H / 2) / ortho px per metre about the image centre) and the scene's own numbers.

L_BODY = """vrsim: 1
dimension: 2
duration: 0.1
frame_rate: 10
gravity: [0, 0]
bodies:
  - name: ell
    particles:
      - {position: [0, 0], mass: 1}
      - {position: [1, 0], mass: 1}
      - {position: [2, 0], mass: 1}
      - {position: [0, 1], mass: 1}
      - {position: [0, 2], mass: 1}
    color: [0, 0, 1]
  - {name: weight, mass: 1, position: [4, 1], color: [1, 0, 0]}
springs:
  - {body: ell, point: [0, 0], anchor: [-2, -1], stiffness: 1}
"""
ORTHO_EYE, ORTHO_HALF = np.array([1.0, 0.5, 10.0]), 3.0


def ortho_px(points) -> np.ndarray:
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    s = (H / 2) / ORTHO_HALF
    return np.column_stack([W / 2 + s * (points[:, 0] - ORTHO_EYE[0]),
                            H / 2 - s * (points[:, 1] - ORTHO_EYE[1])])


def ortho_image(model, state, trails=()):
    from vrsim_cli.maths.camera import Camera

    camera = Camera.looking_at(ORTHO_EYE, ORTHO_EYE - [0, 0, 10], ortho=ORTHO_HALF,
                               near=0.1, far=100)
    renderer = open_renderer(model, W, H, camera)
    try:
        return renderer.render(state, trails=trails)
    finally:
        renderer.close()


def colour_at(image, px) -> np.ndarray:
    x, y = np.round(px).astype(int)
    return image[y, x].astype(int)


@pytest.mark.osmesa
def test_a_particle_body_is_drawn_as_its_particles_joined_by_their_hull():
    """The issue's 5-particle L: each particle at its projected pixel, the hull between
    them translucent blue over the background, outside the hull the background; turned
    by 90 degrees, the particles are where the rotation puts them (rotation shows)."""
    from vrsim_cli.maths.spatial import quat_from_axis_angle

    model = compile_model(parse_scene(L_BODY))
    state = make_state(model)
    ell = model.body_index["ell"]
    local = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [0, 2, 0]], float)
    com = local.mean(axis=0)
    for angle in (0.0, np.pi / 2):
        quat = state.body_quat.copy()
        quat[ell] = quat_from_axis_angle([0, 0, 1], angle)
        c, s = np.cos(angle), np.sin(angle)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        world = state.body_pos[ell] + (local - com) @ R.T
        image = ortho_image(model, state.replace(body_quat=quat))
        for p in ortho_px(world):
            r, g, b = colour_at(image, p)
            assert b > 100 and r < 60 and g < 60  # an opaque blue particle
        # inside the hull, between the particles (triangle (0,0), (1,0), (0,1)'s centre):
        # blue blended over the background, lighter than a particle, bluer than grey
        inside = state.body_pos[ell] + (np.array([0.3, 0.3, 0]) - com) @ R.T
        r, g, b = colour_at(image, ortho_px(inside)[0])
        assert b > r + 30 and 100 < r < 220
        # beyond the L's hull (the corner the L leaves out): the background, or the grid
        outside = state.body_pos[ell] + (np.array([1.6, 1.6, 0]) - com) @ R.T
        r, g, b = colour_at(image, ortho_px(outside)[0])
        assert abs(b - r) < 30  # no blue there


@pytest.mark.osmesa
def test_springs_are_drawn_as_lines_between_their_ends():
    model = compile_model(parse_scene(L_BODY))
    state = make_state(model)
    ell = model.body_index["ell"]
    # the spring's body end: `point` [0, 0] in model coordinates is the centre of mass
    end = state.body_pos[ell]
    anchor = np.array([-2.0, -1.0, 0.0])
    image = ortho_image(model, state)
    for f in (0.5, 0.7, 0.85):  # along the segment, outside the L's hull
        p = ortho_px(end + f * (anchor - end))[0]
        dark = [colour_at(image, p + d).sum() for d in ((0, 0), (0, 1), (1, 0), (0, -1))]
        assert min(dark) < 3 * 90  # SPRING_COLOR (0.15, 0.15, 0.18), 2 px wide


def test_point_masses_are_sized_to_the_scene():
    from vrsim_cli.render.geometry import POINT_MASS_FRACTION, draw_list, point_mass_radius

    big = compile_model(parse_scene(
        "vrsim: 1\nduration: 0.1\ngravity: [0, 0, 0]\nbodies:\n"
        "  - {name: a, mass: 1, position: [0, 0, 0]}\n"
        "  - {name: b, mass: 1, position: [30, 40, 0]}\n"))  # 50 m apart
    assert point_mass_radius(big) == pytest.approx(POINT_MASS_FRACTION * 50)
    small = compile_model(parse_scene(
        "vrsim: 1\nduration: 0.1\ngravity: [0, 0, 0]\nbodies:\n"
        "  - {name: a, mass: 1, position: [0, 0, 0]}\n"
        "  - {name: b, mass: 1, position: [0.03, 0.04, 0]}\n"))  # 5 cm apart
    assert point_mass_radius(small) == pytest.approx(POINT_MASS_FRACTION * 0.05)
    assert draw_list(small).part_local[0, 0, 0] == pytest.approx(5e-4)  # not 2.5 cm


@pytest.mark.osmesa
def test_a_trail_is_drawn_through_the_path_points():
    model = compile_model(parse_scene(L_BODY))
    path = np.array([[-2.0, 2.0, 0.0], [-1.0, 2.5, 0.0], [0.0, 2.6, 0.0]])
    image = ortho_image(model, make_state(model), trails=[(path, (1.0, 0.0, 0.0))])
    middle = ortho_px(0.5 * (path[0] + path[1]))[0]
    reds = [colour_at(image, middle + (0, d)) for d in (-1, 0, 1)]
    assert any(r > 100 and g < 40 and b < 40 for r, g, b in reds)  # 0.6 x red


def test_the_ground_is_sized_to_the_action_and_its_grid_to_the_scale():
    """projectile.yaml's ball flew past the 20 m square's edge at x = 10; coins.yaml's
    centimetre stacks sat on a 1 m grid."""
    import vrsim_cli
    from vrsim_cli.render import stage_for

    from conftest import SCENARIOS

    sim = vrsim_cli.simulate(SCENARIOS / "projectile.yaml")
    traj = sim.run()
    stage = stage_for(sim.model, sim.samples)
    centre = np.asarray(stage.centre)
    ball = traj.position[:, traj.index("ball")]
    assert (np.abs(ball[:, [0, 2]] - centre[[0, 2]]) < stage.plane_edge / 2).all()
    assert (np.abs(ball[:, [0, 2]] - centre[[0, 2]]) < stage.half).all()  # grid under it
    assert stage.step == 1.0 and stage.plane == "xz" and stage.level == 0.0
    coins = vrsim_cli.simulate(SCENARIOS / "coins.yaml")
    coins.run()
    small = stage_for(coins.model, coins.samples)
    assert small.step == 0.01  # about ten lines across the 17 cm of coins and cards
    flat = vrsim_cli.simulate(SCENARIOS / "planar-push.yaml")
    flat.run()
    assert stage_for(flat.model, flat.samples).plane == "xy"  # a flat grid behind 2D


def test_2d_scenes_get_an_orthographic_camera():
    from conftest import SCENARIOS
    import vrsim_cli
    from vrsim_cli.render import action_camera_path

    sim = vrsim_cli.simulate(SCENARIOS / "planar-push.yaml")
    sim.run()
    cameras = action_camera_path(sim.model, sim.samples, 640, 480)
    assert all(c.ortho > 0 and c.forward == pytest.approx((0, 0, -1)) for c in cameras)
    assert default_camera(sim.model, 640, 480).ortho > 0


def test_a_3d_particle_bodys_hull_faces_point_outwards_through_its_particles():
    """The hull of a non-flat particle body: every triangle's corners are particles, every
    face's normal points away from the particles' centre, and the faces close the hull
    (their areas' normals sum to zero). A flat body in 3D gets its polygon instead."""
    from vrsim_cli.render.geometry import hull_triangles

    import scipy.spatial  # noqa: F401  (the test extra has it; without it no hull is drawn)
    points = np.array([[0, 0, 0], [0.2, 0, 0], [0.4, 0, 0], [0, 0.2, 0], [0, 0.4, 0.1],
                       [0.1, 0.1, 0.05]], dtype=float)
    verts, normals = hull_triangles(points, planar=False)
    tris = verts.reshape(-1, 3, 3).astype(float)
    assert all(np.min(np.linalg.norm(points - v, axis=1)) < 1e-6 for v in verts)
    centre = points.mean(axis=0)
    assert (np.einsum("ij,ij->i", normals[::3], tris.mean(axis=1) - centre) > 0).all()
    area = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    assert np.abs(area.sum(axis=0)).max() < 1e-6  # closed: the area vectors cancel
    assert (np.einsum("ij,ij->i", area, normals[::3]) > 0).all()  # wound outwards
    flat = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, 1], [0.5, 0, 0.5]], float)
    verts, normals = hull_triangles(flat, planar=False)
    assert np.allclose(np.abs(normals[:, 1]), 1) and np.allclose(verts[:, 1], 0)
    assert hull_triangles(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]], float), False) is None
