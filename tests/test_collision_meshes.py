"""Meshes: loading every format, the error each proxy makes (against closed forms), the
contact error of a proxy bounded by its reported Hausdorff distance, and mesh queries
(ray cast, sphere cast) against the analytic shapes they approximate."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from vrsim_cli.maths import geometry
from vrsim_cli.maths import queries
from vrsim_cli.maths.meshes import load_mesh, proxy_errors
from vrsim_cli.maths.spatial import quat_from_axis_angle, quat_normalize
from vrsim_cli.model.collision import analytic_geom, table
from vrsim_cli.model.collision import mesh_geom
from vrsim_cli.stages.collision.detect import narrow_phase
from vrsim_cli.stages.collision.shapes import place

I = np.array([1.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def box_file(tmp_path_factory):
    """A 2 x 1 x 0.5 m box mesh (volume 1 m^3) as OBJ."""
    path = tmp_path_factory.mktemp("meshes") / "box.obj"
    trimesh.creation.box(extents=[2.0, 1.0, 0.5]).export(path)
    return str(path)


@pytest.mark.parametrize("suffix", ["obj", "stl", "ply", "glb"])
def test_every_format_loads_the_same_box(tmp_path, suffix):
    path = tmp_path / f"box.{suffix}"
    trimesh.creation.box(extents=[2.0, 1.0, 0.5]).export(path)
    mesh = load_mesh(str(path), scale=2.0)
    assert len(mesh.faces) == 12
    assert mesh.volume == pytest.approx(8.0, rel=1e-12)  # scale 2: 8 times 1 m^3


def test_unreadable_mesh_is_a_value_error(tmp_path):
    path = tmp_path / "broken.stl"
    path.write_text("solid nothing\nendsolid nothing\n")
    with pytest.raises(ValueError, match="broken.stl"):
        load_mesh(str(path))


def test_proxy_errors_of_a_box_against_closed_forms(box_file):
    rows = {r["proxy"]: r for r in proxy_errors(load_mesh(box_file))}
    radius = math.sqrt(1.0 + 0.25 + 0.0625)  # half the box's diagonal
    # The sphere's farthest point from the box is on the z axis: radius - 0.25 away.
    assert rows["sphere"]["hausdorff_m"] == pytest.approx(radius - 0.25, abs=1e-9)
    assert rows["sphere"]["volume_ratio"] == pytest.approx(4 / 3 * math.pi * radius ** 3,
                                                           rel=1e-9)
    for name in ("aabb", "obb", "hull", "mesh"):  # all of them are the box itself
        assert rows[name]["hausdorff_m"] < 1e-9
        assert rows[name]["volume_ratio"] == pytest.approx(1.0, rel=1e-9)


def test_a_turned_box_shows_the_aabb_error_and_not_the_obb_error():
    mesh = trimesh.creation.box(extents=[2.0, 1.0, 0.5])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 6, [0, 1, 0]))
    rows = {r["proxy"]: r for r in proxy_errors(mesh)}
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    aabb_volume = (2 * c + 0.5 * s) * 1.0 * (2 * s + 0.5 * c)
    assert rows["aabb"]["volume_ratio"] == pytest.approx(aabb_volume, rel=1e-9)
    assert rows["obb"]["volume_ratio"] == pytest.approx(1.0, rel=1e-6)
    # The AABB's corner (c + s/4, s + c/4) in x-z lies, in the box's own frame, at
    # z = s (c + s/4) + c (s + c/4) = 2 s c + 1/4 with |x| < 1: 2 s c off the long face.
    assert rows["aabb"]["proxy_to_mesh_m"] == pytest.approx(2 * s * c, rel=1e-9)


def _ground_depth(row, quat, height):
    cm = table([analytic_geom(0, {"type": "plane", "normal": [0, 1, 0], "offset": 0.0}),
                row])
    world = place(cm, np.array([[0.0, 0, 0], [0.0, height, 0]]), np.array([I, quat]))
    _, _, _, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), np.inf)
    return depth.max()


def test_a_proxys_contact_depth_is_off_by_at_most_its_hausdorff_distance(tmp_path):
    """Against the ground, depth = offset - min over the solid of n.p, the support
    function; two surfaces a Hausdorff distance h apart have supports at most h apart.
    So |depth(proxy) - depth(mesh)| <= h for every orientation (aabb: at the mesh's own
    orientation, where its error is reported)."""
    mesh = trimesh.creation.torus(major_radius=0.3, minor_radius=0.08, major_sections=16,
                                  minor_sections=8)
    path = tmp_path / "ring.obj"
    mesh.export(path)
    shape = {"type": "mesh", "path": str(path), "scale": 1.0}
    errors = {r["proxy"]: r["hausdorff_m"] for r in proxy_errors(load_mesh(str(path)))}
    rng = np.random.default_rng(5)
    exact = mesh_geom(1, shape, "exact")
    for name in ("sphere", "obb", "hull", "aabb"):
        proxy = mesh_geom(1, shape, name)
        for k in range(20):
            quat = I if name == "aabb" else quat_normalize(rng.normal(size=4))
            d_mesh = _ground_depth(exact, quat, 0.1)
            d_proxy = _ground_depth(proxy, quat, 0.1)
            assert d_proxy >= d_mesh - 1e-12  # a proxy encloses the mesh
            # The estimate samples 2000 points per surface (a lower bound of h), so
            # allow the sample spacing: sqrt(area / 2000) < 1.5 cm for this ring.
            assert d_proxy - d_mesh <= errors[name] + 0.015, name


@pytest.mark.parametrize("origin, direction", [
    ([0.0, 3.0, 0.0], [0.0, -1.0, 0.0]), ([5.0, 0.1, 0.1], [-1.0, 0.0, 0.0]),
    ([3.0, 3.0, 1.0], [-0.6, -0.8, 0.0]), ([3.0, 3.0, 3.0], [0.0, 1.0, 0.0])])
def test_mesh_ray_and_sphere_casts_match_the_analytic_box(box_file, origin, direction):
    pos, quat = np.array([0.2, 0.5, -0.1]), quat_from_axis_angle([0, 1, 0], 0.4)
    mesh = {"type": "mesh", "path": box_file, "scale": 1.0}
    box = {"type": "box", "size": [2.0, 1.0, 0.5]}
    hit = queries.ray_cast(mesh, pos, quat, origin, direction)
    truth = geometry.ray_cast(box, pos, quat, origin, direction)
    assert (hit is None) == (truth is None)
    if truth is not None:
        assert hit == pytest.approx(truth, abs=1e-12)
    # Sphere cast: stops within the tolerance of the first touch; agrees with the
    # analytic box's sphere cast to that tolerance.
    a = queries.sphere_cast(mesh, pos, quat, origin, direction, 0.2, 10.0, 1e-6)
    b = queries.sphere_cast(box, pos, quat, origin, direction, 0.2, 10.0, 1e-6)
    assert (a is None) == (b is None)
    if b is not None:
        assert a == pytest.approx(b, abs=2e-6)
        gap = queries.distance(box, pos, quat, np.add(origin, a * np.asarray(direction)))
        assert 0.2 - 1e-12 <= gap <= 0.2 + 1e-6  # never inside (round-off aside)
