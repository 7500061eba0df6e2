"""Mass properties (slide 5.3) and `vrsim mass-properties`, against independent truth:
the slide's cube formula (with its erratum corrected), trimesh's mass properties of
polygonal primitives, and fine particle grids for 2D laminae."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh

from vrsim_cli.errors import InputError
from vrsim_cli.model.mass_properties import (body_mass_properties, cube_inertia_formula,
                                       grid_particles, particle_properties, shape_inertia,
                                       shape_volume)
from vrsim_cli.model.model import compile_model
from vrsim_cli.scene.spec import parse_scene

# ----------------------------------------------------------------------------- slide cube


@pytest.mark.parametrize("n", [1, 2, 10])
def test_particle_cube_inertia_is_m_times_one_sixth_plus_one_over_3n(n):
    # Slide 5.3.2 with the erratum corrected: (n+1)^3 particles at (i/n, j/n, k/n) of
    # mass m/(n+1)^3 give I = m (1/6 + 1/(3n)) E about the centre (1/2, 1/2, 1/2).
    # Round-off of a sum of <= 1331 terms: 1e-13 relative.
    m = 3.0
    pos, masses = grid_particles(n, 1.0, m, 3)
    assert len(pos) == (n + 1) ** 3
    mass, com, inertia = particle_properties(pos, masses)
    assert mass == pytest.approx(m, rel=1e-14)
    assert com == pytest.approx([0.5, 0.5, 0.5], abs=1e-14)
    expected = m * (1 / 6 + 1 / (3 * n))
    assert inertia == pytest.approx(expected * np.eye(3), rel=1e-13, abs=1e-13)
    assert cube_inertia_formula(n, m) == pytest.approx(expected, rel=1e-15)
    slide_as_printed = m * (1 / 6 - 1 / (3 * n))
    assert inertia[0, 0] != pytest.approx(slide_as_printed)  # the erratum


def test_n1_cube_is_eight_corners_with_half_m():
    pos, masses = grid_particles(1, 1.0, 1.0, 3)
    _, _, inertia = particle_properties(pos, masses)
    assert inertia[0, 0] == pytest.approx(0.5, rel=1e-15)  # slide as printed: -1/6


def test_cube_inertia_tends_to_the_solid_cube():
    # I(n) - m/6 = m/(3n) exactly, so the limit n -> infinity is the solid cube's m/6.
    for n in (10, 20, 40):
        _, _, inertia = particle_properties(*grid_particles(n, 1.0, 1.0, 3))
        assert inertia[0, 0] - 1 / 6 == pytest.approx(1 / (3 * n), rel=1e-11)


def test_grid_size_scales_inertia_with_its_square():
    _, com, inertia = particle_properties(*grid_particles(3, 2.0, 1.0, 3))
    assert com == pytest.approx([1, 1, 1])
    assert inertia[1, 1] == pytest.approx(4 * cube_inertia_formula(3, 1.0), rel=1e-13)


# ----------------------------------------------------------------------------- shapes


SWAP_YZ = np.array([[1, 0, 0], [0, 0, 1], [0, 1, 0]])  # trimesh's axis z -> vrsim's y


@pytest.mark.parametrize("shape,mesh,rel,rel_volume", [
    # Error of the polygonal stand-in: an N-gon misses (2 pi/N)^2 / 6 of a circle's area
    # (2.5e-5 at N = 512; twice that, 2e-4, for the capsule's caps, faceted in latitude
    # and longitude at N = 256); the icosphere (subdivision 5, edge ~ r/40) misses
    # ~(edge/r)^2/4 ~ 3e-4. The normalised moments err less (measured 8e-6, 2e-5, 4e-4);
    # boxes are exact.
    ({"type": "sphere", "radius": 0.3}, lambda: trimesh.creation.icosphere(5, 0.3), 1e-3, 1e-3),
    ({"type": "box", "size": [0.2, 0.5, 1.1]},
     lambda: trimesh.creation.box(extents=[0.2, 0.5, 1.1]), 1e-12, 1e-12),
    ({"type": "cylinder", "radius": 0.3, "length": 1.2},
     lambda: trimesh.creation.cylinder(radius=0.3, height=1.2, sections=512), 1e-4, 5e-5),
    ({"type": "capsule", "radius": 0.3, "length": 1.2},
     lambda: trimesh.creation.capsule(radius=0.3, height=1.2, count=[256, 256]), 1e-4, 3e-4),
])
def test_closed_forms_match_trimesh(shape, mesh, rel, rel_volume):
    mesh = mesh()
    mesh.density = 1.0
    reference = mesh.moment_inertia / mesh.mass
    if shape["type"] in ("cylinder", "capsule"):
        reference = SWAP_YZ @ reference @ SWAP_YZ
    mine = shape_inertia(shape, 1.0, 3)
    assert np.abs(mine - reference).max() <= rel * np.abs(mine).max()
    assert shape_volume(shape, 3) == pytest.approx(mesh.volume, rel=rel_volume)


def lamina(inside, half: float, h: float = 0.002):
    """Izz of a unit-mass lamina {inside(x, y)} by a midpoint grid of spacing h."""
    ticks = np.arange(-half + h / 2, half, h)
    x, y = np.meshgrid(ticks, ticks)
    keep = inside(x, y)
    r2 = x[keep] ** 2 + y[keep] ** 2
    return r2.mean(), keep.sum() * h * h


@pytest.mark.parametrize("shape,inside,half", [
    ({"type": "sphere", "radius": 0.4}, lambda x, y: x * x + y * y <= 0.16, 0.45),
    ({"type": "box", "size": [0.6, 0.3]}, lambda x, y: (abs(x) <= 0.3) & (abs(y) <= 0.15), 0.35),
    ({"type": "cylinder", "radius": 0.2, "length": 0.8},
     lambda x, y: (abs(x) <= 0.2) & (abs(y) <= 0.4), 0.45),
    ({"type": "capsule", "radius": 0.2, "length": 0.8},
     lambda x, y: ((abs(x) <= 0.2) & (abs(y) <= 0.4))
     | (x * x + (abs(y) - 0.4) ** 2 <= 0.04), 0.65),
])
def test_2d_laminae_match_a_fine_particle_grid(shape, inside, half):
    # Midpoint grid at h = 2 mm: the boundary cells err by O(h / size) ~ 1 %, so 2 %.
    izz, area = lamina(inside, half)
    assert shape_inertia(shape, 1.0, 2)[2, 2] == pytest.approx(izz, rel=2e-2)
    assert shape_volume(shape, 2) == pytest.approx(area, rel=2e-2)


def test_2d_particles_give_sum_of_m_p0_squared():
    # Slide 5.3.1: I = sum m |p0|^2 about the centre of mass.
    body = {"particles": [{"position": [0, 0], "mass": 1}, {"position": [2, 0], "mass": 3},
                          {"position": [0, 1], "mass": 2}]}
    props = body_mass_properties(body, 2)
    com = (np.array([0, 0]) * 1 + np.array([2, 0]) * 3 + np.array([0, 1]) * 2) / 6
    expected = sum(m * np.sum((np.array(p) - com) ** 2)
                   for p, m in (([0, 0], 1), ([2, 0], 3), ([0, 1], 2)))
    assert props.mass == 6 and props.com[:2] == pytest.approx(com)
    assert props.inertia[2, 2] == pytest.approx(expected, rel=1e-14)


def test_density_gives_mass_and_explicit_inertia_replaces_the_tensor():
    props = body_mass_properties({"density": 1000, "shape": {"type": "box",
                                                              "size": [0.1, 0.2, 0.3]}}, 3)
    assert props.mass == pytest.approx(6.0, rel=1e-12)
    props = body_mass_properties({"mass": 2, "inertia": [1, 2, 2.5],
                                  "shape": {"type": "sphere", "radius": 1}}, 3)
    assert np.array_equal(props.inertia, np.diag([1.0, 2.0, 2.5]))
    moments, axes = props.principal()
    assert moments.tolist() == [1, 2, 2.5] and np.linalg.det(axes) == pytest.approx(1)


def test_principal_axes_of_a_rotated_tensor():
    # A diagonal tensor turned by 30 degrees about z: the axes come back.
    c, s = math.cos(math.pi / 6), math.sin(math.pi / 6)
    Rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    tensor = Rz @ np.diag([1.0, 2.0, 2.5]) @ Rz.T
    props = body_mass_properties({"mass": 1, "inertia": tensor.tolist()}, 3)
    moments, axes = props.principal()
    assert moments == pytest.approx([1, 2, 2.5], rel=1e-12)
    assert abs(axes[:, 0] @ Rz[:, 0]) == pytest.approx(1, rel=1e-12)


def test_mesh_mass_properties_through_trimesh(tmp_path):
    # A box mesh whose own origin is off its centre: its centre of mass is reported, and
    # the tensor equals the box's closed form (exact for a box, up to STL's float32
    # vertices: 1.2e-7 relative per coordinate, so 1e-6).
    box = trimesh.creation.box(extents=[0.2, 0.4, 0.6])
    box.apply_translation([1.0, 0.0, 0.0])
    box.export(tmp_path / "box.stl")
    props = body_mass_properties({"mass": 3, "shape": {"type": "mesh", "file": "box.stl"}},
                                 3, str(tmp_path / "box.stl"))
    assert props.com == pytest.approx([1, 0, 0], abs=1e-6)
    expected = shape_inertia({"type": "box", "size": [0.2, 0.4, 0.6]}, 3.0, 3)
    assert props.inertia == pytest.approx(expected, rel=1e-6, abs=1e-12)


# ----------------------------------------------------------------------------- problems


def compile_problems(text: str) -> list[str]:
    with pytest.raises(InputError) as info:
        compile_model(parse_scene(text, "F"))
    return info.value.lines()


def test_collinear_particles_are_refused_with_a_hint():
    out = compile_problems("""vrsim: 1
duration: 1
bodies:
  - name: rod
    particles: [{position: [0, 0, 0], mass: 1}, {position: [1, 0, 0], mass: 1}]
""")
    assert len(out) == 1 and out[0].startswith("F:5:16: bodies[0].particles: the inertia "
                                               "tensor is not positive definite")
    assert "particles on one line" in out[0]


def test_impossible_inertia_is_refused():
    out = compile_problems("vrsim: 1\nduration: 1\nbodies: [{name: b, mass: 1, inertia: "
                           "[1, 1, 3]}]\n")
    assert out == ["F:3:38: bodies[0].inertia: no rigid body has these principal moments "
                   "(1, 1, 3 kg m^2) (each moment must be <= the sum of the other two "
                   "(triangle inequality))"]


@pytest.mark.parametrize("body,message", [
    ("{name: b, mass: 1, particles: {grid: {n: 2, mass: 1}}}", "'mass' comes from the particles"),
    ("{name: b, mass: 1, angular_velocity: [0, 1, 0]}", "a point mass cannot spin"),
    ("{name: b, density: 3}", "density needs a shape with a volume"),
    ("{name: b, mass: 1, forces: [{force: [1, 0, 0], point: [0, 1, 0]}]}",
     "a force at a point turns the body, but this body is a point mass"),
    ("{name: b, mass: 1, torques: [{torque: [0, 0, 1]}]}", "a torque needs a body that can rotate"),
    ("{name: b, mass: 1, inertia: 2, shape: {type: sphere, radius: 1}}",
     "inertia is [x, y, z] in a 3D scene"),
])
def test_rigid_keys_are_checked(body, message):
    with pytest.raises(InputError) as info:
        parse_scene(f"vrsim: 1\nduration: 1\nbodies: [{body}]\n", "F")
    assert any(message in line for line in info.value.lines()), info.value.lines()


def test_spring_to_an_unknown_body_suggests_a_name():
    with pytest.raises(InputError) as info:
        parse_scene("vrsim: 1\nduration: 1\nbodies: [{name: ball, mass: 1}]\n"
                    "springs: [{body: bal, anchor: [0, 1, 0], stiffness: 3}]\n", "F")
    assert info.value.lines() == ["F:4:18: springs[0].body: no body named 'bal' (did you mean "
                                  "'ball'?)"]


# ----------------------------------------------------------------------------- CLI

CUBE = """
vrsim: 1
duration: 1
bodies:
  - name: cube
    particles: {grid: {n: 2, size: 1.0, mass: 6.0}}
  - {name: ball, mass: 1}
  - {name: floor, type: static}
"""


def test_cli_prints_the_slide_cube(invoke, write_scene):
    result = invoke("mass-properties", write_scene(CUBE))
    assert result.exit_code == 0, result.output
    out = result.stdout
    assert "cube: mass 6 kg, particles: grid n=2 ((n+1)^3 = 27 particles)" in out
    assert "centre of mass [0.5, 0.5, 0.5] m" in out
    assert "    [2, 0, 0]\n    [0, 2, 0]\n    [0, 0, 2]\n" in out  # 6 (1/6 + 1/6) = 2
    assert "principal moments [2, 2, 2] kg m^2" in out
    assert "I = m (1/6 + 1/(3n)) E = 2 kg m^2" in out and "erratum" in out
    assert "ball: mass 1 kg, point mass (no rotation)" in out
    assert "floor: static" in out


def test_cli_json(invoke, write_scene):
    result = invoke("mass-properties", write_scene(CUBE), "--json")
    rows = json.loads(result.stdout)
    assert rows[0]["slide_cube"]["value"] == pytest.approx(2.0)
    assert rows[0]["principal_moments"] == pytest.approx([2, 2, 2])


def test_cli_2d_prints_the_planar_moment(invoke, write_scene):
    result = invoke("mass-properties", write_scene(
        "vrsim: 1\ndimension: 2\nduration: 1\nbodies: [{name: disc, mass: 2, "
        "shape: {type: sphere, radius: 0.5}}]\n"))
    assert "moment of inertia about z: 0.25 kg m^2" in result.stdout  # m r^2 / 2


def test_cli_bad_body_exits_2(invoke, write_scene):
    result = invoke("mass-properties", write_scene(
        "vrsim: 1\nduration: 1\nbodies: [{name: b, mass: 1, inertia: [1, 1, 3]}]\n"))
    assert result.exit_code == 2 and "triangle inequality" in result.stderr


def test_kinematic_spin_and_a_drive_do_not_mix():
    with pytest.raises(InputError) as info:
        parse_scene("vrsim: 1\nduration: 1\nbodies: [{name: car, type: kinematic, "
                    "angular_velocity: [0, 1, 0], drive: {speed: 1}}]\n", "F")
    assert any("orientation comes from its drive" in line for line in info.value.lines())
