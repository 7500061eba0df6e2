"""Scene loading and validation: every kind of problem, located as FILE:LINE:COL."""

from __future__ import annotations

import time

import numpy as np
import pytest

from vrsim_cli.errors import InputError
from vrsim_cli.scene.spec import load_scene, parse_scene, scene_schema

GOOD = """
vrsim: 1
duration: 1.0
bodies:
  - name: ball
    shape: {type: sphere, radius: 0.1}
    mass: 1.0
    position: [0, 1, 0]
"""


def problems(write_scene, text: str) -> list[str]:
    path = write_scene(text)
    with pytest.raises(InputError) as info:
        from vrsim_cli.model.model import compile_model
        compile_model(load_scene(path))
    return [line.replace(str(path), "F") for line in info.value.lines()]


def test_good_scene_loads(write_scene):
    scene = load_scene(write_scene(GOOD))
    assert scene.data["bodies"][0]["name"] == "ball"
    assert scene.value_pos[("bodies", 0, "mass")] == (6, 11)


def test_unknown_key_is_located_at_the_key_with_a_did_you_mean(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1.0
        bodies:
          - name: ball
            mass: 1.0
            velocty: [0, 1, 0]
        """)
    assert out == ["F:6:5: bodies[0].velocty: unknown key 'velocty' (did you mean 'velocity'?)"]


def test_unknown_key_without_a_close_match_lists_the_allowed_keys(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: 1\nzzz: 3\n")
    assert out[0].startswith("F:3:1: zzz: unknown key 'zzz' (allowed here: vrsim, name,")


def test_missing_required_key(write_scene):
    out = problems(write_scene, "vrsim: 1\nbodies: []\n")
    assert out == ["F:1:1: (document): missing required key 'duration' (Simulated time in s.)"]


def test_wrong_type(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: ten\n")
    assert out == ["F:2:11: duration: expected a number, got a string 'ten'"]


def test_enum_with_did_you_mean(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: 1\nintegrator: rk5\n")
    assert out == ["F:3:13: integrator: expected one of 'euler', 'symplectic-euler', 'rk4', 'verlet', 'dopri5', "
                   "got 'rk5' (did you mean 'rk4'?)"]


def test_shape_type_typo(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - {name: b, mass: 1, shape: {type: sphre, radius: 1}}
        """)
    assert len(out) == 1
    assert out[0].startswith("F:4:38: bodies[0].shape.type: expected one of 'sphere'")
    assert out[0].endswith("(did you mean 'sphere'?)")


def test_shape_keys_depend_on_the_shape_type(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - name: b
            mass: 1
            shape: {type: box, radius: 1}
        """)
    assert out == [
        "F:6:12: bodies[0].shape: missing required key 'size' (Full edge lengths in m, "
        "[x, y, z] (2D: [x, y]).)",
        "F:6:24: bodies[0].shape.radius: unknown key 'radius' (allowed here: type, size)",
    ]


def test_const_version(write_scene):
    out = problems(write_scene, "vrsim: 2\nduration: 1\n")
    assert out == ["F:1:8: vrsim: expected 1, got 2"]


def test_minimum(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies: [{name: b, mass: -2}]
        """)
    assert out == ["F:3:26: bodies[0].mass: must be > 0, got -2"]


@pytest.mark.parametrize("size, want", [
    ("[-1, 1, 1]", "F:4:55: bodies[0].shape.size[0]: must be > 0, got -1"),
    ("[1, 0, 1]", "F:4:58: bodies[0].shape.size[1]: must be > 0, got 0"),
    ("[1, 1, -0.5]", "F:4:61: bodies[0].shape.size[2]: must be > 0, got -0.5")])
def test_a_box_needs_positive_sides(write_scene, size, want):
    """A box side of 0 or less gave a contact tolerance below zero and a traceback
    (math domain error) in compile_response; hypothesis's mutated stack scene found it in
    CI (2026-12-07). The schema now asks every side to be > 0, as radii and lengths."""
    out = problems(write_scene, f"""
        vrsim: 1
        duration: 1
        collision: {{}}
        bodies: [{{name: b, mass: 1, shape: {{type: box, size: {size}}}}}]
        """)
    assert out == [want]


def test_item_count(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies: [{name: b, mass: 1, position: [1]}]
        """)
    assert out == ["F:3:39: bodies[0].position: expected 2 or 3 items, got 1"]


def test_name_pattern(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies: [{name: "../etc/passwd", mass: 1}]
        """)
    assert out[0].startswith("F:3:17: bodies[0].name: '../etc/passwd' is not a valid name "
                             "(Letters, digits")


@pytest.mark.parametrize("value", [".nan", ".inf", "-.inf"])
def test_non_finite_numbers(write_scene, value):
    out = problems(write_scene, f"vrsim: 1\nduration: 1\ngravity: [0, {value}, 0]\n")
    assert out == [f"F:3:14: gravity[1]: must be a finite number, got "
                   f"{float(value.replace('.', '')) if 'nan' not in value else 'nan'}"]


def test_duplicate_key(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: 1\nduration: 2\n")
    assert out == ["F:3:1: duplicate key 'duration' (first at line 2)"]


def test_merge_keys_are_not_duplicates(write_scene):
    scene = load_scene(write_scene("""
        vrsim: 1
        duration: 1
        bodies:
          - &ball {name: a, mass: 1, position: [0, 1, 0]}
          - <<: *ball
            name: b
        """))
    assert [b["name"] for b in scene.data["bodies"]] == ["a", "b"]
    assert scene.data["bodies"][1]["position"] == [0, 1, 0]


@pytest.mark.parametrize("text,message", [
    ("output: {file: ''}", "F:3:16: output.file: must not be empty"),
    ("name: " + "x" * 201, "F:3:7: name: is longer than 200 characters"),
])
def test_string_length_limits(write_scene, text, message):
    assert problems(write_scene, f"vrsim: 1\nduration: 1\n{text}\n") == [message]


def test_too_many_particles(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        emitters:
          - {name: a, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: b, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: c, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: d, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: e, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: f, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: g, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: h, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: i, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: j, count: 100000, rate: 10, speed: 1, mass: 1}
          - {name: k, count: 100000, rate: 10, speed: 1, mass: 1}
        """)
    assert out == ["F:3:1: emitters: the scene has 1100000 bodies and particles; at most "
                   "400000 are allowed"]


@pytest.mark.parametrize("vector", ["[1.0e-320, 0, 0, 0]", "[1.0e300, 1.0e300, 0, 0]"])
def test_tiny_and_huge_quaternions_normalise(write_scene, vector):
    from vrsim_cli.model.model import compile_model
    model = compile_model(load_scene(write_scene(
        f"vrsim: 1\nduration: 1\nbodies: [{{name: a, mass: 1, orientation: {vector}}}]\n")))
    assert np.isfinite(model.body_quat0).all()
    assert np.linalg.norm(model.body_quat0[0]) == pytest.approx(1.0, abs=1e-15)


def test_non_string_key(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: 1\n3: x\n")
    assert out == ["F:3:1: (document): key '3' is not a string (quote it if it should be a name)"]


def test_yaml_syntax_error_is_located(write_scene):
    """An unclosed bracket is reported where it opens (line 2), not where PyYAML noticed it
    (line 3), with that place in the message."""
    out = problems(write_scene, "vrsim: 1\nduration: [1, 2\nbodies: []\n")
    assert out == ["F:2:11: (document): YAML: a flow sequence that starts here is not closed "
                   "(expected ',' or ']', but got ':', at line 3, column 7) (close the bracket "
                   "or quote)"]
    out = problems(write_scene, 'vrsim: 1\nname: "abc\nduration: 2\n')
    assert len(out) == 1 and out[0].startswith("F:2:7: (document): YAML: a quoted scalar that "
                                               "starts here is not closed")
    out = problems(write_scene, "vrsim: 1\nduration: 1: 2\n")  # not a bracket: where it is
    assert out == ["F:2:12: (document): YAML: mapping values are not allowed here"]


def test_empty_file(write_scene):
    assert problems(write_scene, "") == [
        "F:1:1: (document): the file is empty (a scene starts with 'vrsim: 1')"]


def test_document_must_be_a_mapping(write_scene):
    assert problems(write_scene, "- 1\n- 2\n") == [
        "F:1:1: (document): the document must be a mapping of keys to values "
        "(a scene starts with 'vrsim: 1')"]


def test_python_tags_are_refused(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: !!python/object/apply:os.system ['true']\n")
    assert len(out) == 1 and "YAML tag not allowed" in out[0] and out[0].startswith("F:2:11:")


def test_alias_bomb_is_refused_quickly(write_scene):
    lines = ["vrsim: 1", "duration: 1", "a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for i in range(1, 10):
        refs = ", ".join([f"*a{i - 1}"] * 10)
        lines.append(f"a{i}: &a{i} [{refs}]")
    start = time.process_time()  # CPU time, not wall: the same verdict under load
    out = problems(write_scene, "\n".join(lines) + "\n")
    assert time.process_time() - start < 10  # generous: the point is "not hours"
    assert len(out) == 1 and "expands to more than 200000 values" in out[0]


def test_recursive_alias_is_refused(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: 1\nx: &x [*x]\n")
    assert len(out) == 1 and ("nests deeper" in out[0] or "expands" in out[0])


def test_binary_junk(tmp_path):
    path = tmp_path / "junk.yaml"
    path.write_bytes(bytes(range(256)))
    with pytest.raises(InputError) as info:
        load_scene(path)
    assert "not UTF-8 text" in info.value.lines()[0]


def test_control_characters(tmp_path):
    path = tmp_path / "ctl.yaml"
    path.write_text("vrsim: 1\nduration: 1\x07\n")
    with pytest.raises(InputError) as info:
        load_scene(path)
    assert info.value.lines() == [f"{path}:2:12: (document): YAML: character U+0007 is not "
                                  "allowed (scene files are plain text)"]


def test_missing_file(tmp_path):
    with pytest.raises(InputError) as info:
        load_scene(tmp_path / "nope.yaml")
    assert info.value.lines() == [f"{tmp_path / 'nope.yaml'}: no such file"]


def test_all_problems_are_reported_at_once_in_file_order(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: -1
        bodies:
          - name: a
            mass: 1
            colour: [1, 0, 0]
        integrator: heun
        """)
    assert [o.split(": ")[0] for o in out] == ["F:2:11", "F:6:5", "F:7:13"]
    assert "did you mean 'color'?" in out[1]


# ----------------------------------------------------------------------------- semantics


def test_vector_length_must_match_dimension(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        dimension: 2
        duration: 1
        bodies: [{name: b, mass: 1, position: [0, 1, 0]}]
        """)
    assert out == ["F:4:39: bodies[0].position: expected 2 numbers [x, y] in a 2D scene, got 3"]


def test_dynamic_body_needs_mass(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: 1\nbodies: [{name: b}]\n")
    assert out == ["F:3:10: bodies[0]: missing required key 'mass' for a dynamic body "
                   "(mass in kg, or type: static / kinematic)"]


def test_plane_must_be_static(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies: [{name: floor, mass: 1, shape: {type: plane, normal: [0, 1, 0]}}]
        """)
    assert out[0].startswith("F:3:47: bodies[0].shape.type: a plane is an infinite half-space")


def test_names_are_unique_and_not_reserved(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - {name: a, mass: 1}
          - {name: a, mass: 1}
          - {name: observer, mass: 1}
        """)
    assert out == ["F:5:12: bodies[1].name: name 'a' is used twice (first at line 4)",
                   "F:6:12: bodies[2].name: 'observer' is reserved for vrsim's own entities"]


def test_zero_quaternion_and_both_orientations(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - {name: a, mass: 1, orientation: [0, 0, 0, 0]}
          - {name: b, mass: 1, orientation: [1, 0, 0, 0], euler_deg: [0, 0, 0]}
        """)
    assert out == ["F:4:37: bodies[0].orientation: a quaternion must not be zero",
                   "F:5:51: bodies[1].euler_deg: give orientation or euler_deg, not both"]


def test_force_window_and_static_velocity(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - name: a
            mass: 1
            forces: [{force: [1, 0, 0], start: 0.5, end: 0.2}]
          - {name: wall, type: static, velocity: [1, 0, 0]}
        """)
    assert out == ["F:6:50: bodies[0].forces[0].end: must be later than start",
                   "F:7:42: bodies[1].velocity: a static body cannot move (use type: "
                   "kinematic for a body that moves at a given velocity)"]


def test_output_path_must_stay_in_the_current_folder(write_scene):
    out = problems(write_scene, "vrsim: 1\nduration: 1\noutput: {file: ../../evil.csv}\n")
    assert out == ["F:3:16: output.file: path '../../evil.csv' leaves the current folder "
                   "(a scene writes only below the folder vrsim runs in; to write elsewhere "
                   "give the path on the command line (-o FILE, --frames DIR))"]


def test_a_mesh_outside_the_scene_folder_gets_a_hint_that_applies(write_scene):
    """Not the -o hint of outputs: a mesh is read, and -o changes nothing about it."""
    out = problems(write_scene, "vrsim: 1\nduration: 1\nbodies: [{name: m, type: static, "
                                "shape: {type: mesh, file: ../m.obj}}]\n")
    assert out == ["F:3:60: bodies[0].shape.file: path '../m.obj' leaves the scene file's "
                   "folder (a scene reads only files in its own folder or below it; copy the "
                   "file there: a link to it would be followed out of the folder and refused "
                   "too)"]


def test_output_rate_must_fit_the_step(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        frame_rate: 100
        dt: 0.01
        output: {rate: 30}
        """)
    assert out == ["F:5:16: output.rate: 1/rate = 0.0333333 s is not a whole number of physics "
                   "steps (dt = 0.01 s) (nearest rates that fit: 33.33333333, 25, 50, 100 "
                   "Hz)"]  # 33.3333 (6 digits) would be refused by this very check


def test_missing_mesh_file(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies: [{name: m, type: static, shape: {type: mesh, file: bunny.stl}}]
        """)
    assert len(out) == 1 and out[0].startswith(
        "F:3:60: bodies[0].shape.file: file 'bunny.stl' not found")


def test_parse_scene_from_text():
    scene = parse_scene(GOOD, "inline.yaml")
    assert scene.file == "inline.yaml"


def test_schema_declares_every_top_level_key_it_validates():
    schema = scene_schema()
    assert schema["additionalProperties"] is False
    assert {"vrsim", "duration", "bodies", "emitters", "output"} <= set(schema["properties"])


@pytest.mark.parametrize("text,value", [("1e-3", 1e-3), ("1.0e300", 1e300), ("2E+2", 200.0),
                                        ("-.5e1", -5.0), ("0.25", 0.25), ("3", 3)])
def test_exponent_floats_read_as_numbers(text, value):
    # PyYAML alone would read 1e-3 and 1.0e300 as strings (YAML 1.1). (An angle: a key
    # without a range, so that 1e300 passes validation.)
    scene = parse_scene(f"vrsim: 1\nduration: 1\nbodies: [{{name: c, type: kinematic, "
                        f"drive: {{heading_deg: {text}}}}}]\n")
    got = scene.data["bodies"][0]["drive"]["heading_deg"]
    assert got == value and type(got) is type(value)
