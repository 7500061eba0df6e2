"""Keyframes, drives and parents in scene files: every problem located as FILE:LINE:COL."""

from __future__ import annotations

import pytest

from conftest import SCENARIOS
from vrsim_cli.errors import InputError
from vrsim_cli.model.model import compile_model
from vrsim_cli.scene.spec import load_scene


def problems(write_scene, text: str) -> list[str]:
    path = write_scene(text)
    with pytest.raises(InputError) as info:
        compile_model(load_scene(path))
    return [line.replace(str(path), "F") for line in info.value.lines()]


@pytest.mark.parametrize("name", ["keyframes.yaml", "car.yaml"])
def test_shipped_scenarios_validate(name):
    model = compile_model(load_scene(SCENARIOS / name))
    assert model.animation is not None and model.animation.has_motion


def test_times_must_increase_strictly_located_at_the_offending_key(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - name: a
            type: kinematic
            keyframes:
              position: {times: [0, 1, 1, 2], values: [[0,0,0], [1,0,0], [2,0,0], [3,0,0]]}
        """)
    assert out == ["F:7:32: bodies[0].keyframes.position.times[2]: key times must increase "
                   "strictly: 1 follows 1 (every key needs its own, later time)"]


def test_value_count_and_width(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - name: a
            type: kinematic
            keyframes:
              position: {times: [0, 1], values: [[0, 0, 0]]}
              color: {times: [0, 1], values: [[1, 0], [0, 1, 0]]}
        """)
    assert out == [
        "F:7:41: bodies[0].keyframes.position.values: expected 2 values (one per key time), "
        "got 1",
        "F:8:39: bodies[0].keyframes.color.values[0]: expected 3 or 4 numbers, got 2"]


def test_unknown_parent_with_a_did_you_mean_and_cycles(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - {name: car, type: kinematic}
          - {name: wheel, type: kinematic, parent: cra}
          - {name: a, type: kinematic, parent: b}
          - {name: b, type: kinematic, parent: c}
          - {name: c, type: kinematic, parent: a}
          - {name: selfish, type: kinematic, parent: selfish}
        """)
    assert out == [
        "F:5:44: bodies[1].parent: no body named 'cra' (did you mean 'car'?)",
        "F:6:40: bodies[2].parent: parents form a cycle: a -> b -> c -> a (a scene graph is "
        "a tree: some body must have no parent)",
        "F:9:46: bodies[5].parent: parents form a cycle: selfish -> selfish (a scene graph "
        "is a tree: some body must have no parent)"]


def test_animated_bodies_must_be_kinematic_and_have_no_velocity(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - name: a
            mass: 1
            velocity: [1, 0, 0]
            drive: {speed: 1}
        """)
    assert out == [
        "F:4:5: bodies[0].type: a body with a position or orientation track, a drive or a "
        "parent is moved by its animation, not by forces (add type: kinematic)",
        "F:6:15: bodies[0].velocity: the velocity of an animated body comes from its motion "
        "(remove velocity)"]


def test_mode_and_kind_mismatches(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - name: a
            type: kinematic
            drive: {speed: 1}
            keyframes:
              position: {times: [0, 1], values: [[0,0,0], [1,0,0]], interpolation: slerp}
              orientation: {times: [0, 1], values: [[1,0,0,0], [0,0,0,0]]}
              scale: {times: [0, 1], values: [1, 2], space: hsv}
        """)
    assert out == [
        "F:8:17: bodies[0].keyframes.position: a driven body gets its position from the "
        "drive (remove the track or the drive)",
        "F:8:76: bodies[0].keyframes.position.interpolation: 'slerp' is not available for "
        "this track (use one of step, linear, catmull-rom, kochanek-bartels, hermite)",
        "F:9:20: bodies[0].keyframes.orientation: a driven body gets its orientation from "
        "the drive (remove the track or the drive)",
        "F:9:56: bodies[0].keyframes.orientation.values[1]: a quaternion must not be zero",
        "F:10:53: bodies[0].keyframes.scale.space: 'space' (rgb or hsv) is for colour "
        "tracks"]


def test_dimension_specific_tracks_and_schema_errors(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        dimension: 2
        duration: 1
        bodies:
          - name: a
            type: kinematic
            keyframes:
              orientation: {times: [0], values: [[1, 0, 0, 0]]}
              position: {times: [0], values: [[0, 0]], extrapolation: bounce}
        """)
    assert out[0].startswith("F:9:63: bodies[0].keyframes.position.extrapolation:")
    assert out == [out[0]]  # schema problems are reported before semantic ones
    out = problems(write_scene, """
        vrsim: 1
        dimension: 2
        duration: 1
        bodies:
          - name: a
            type: kinematic
            keyframes:
              orientation: {times: [0], values: [[1, 0, 0, 0]]}
        """)
    assert out == ["F:8:20: bodies[0].keyframes.orientation: 'orientation' tracks are for "
                   "3D scenes (use angle_deg)"]


def test_hermite_needs_tangents_and_kb_parameters_need_kb(write_scene):
    out = problems(write_scene, """
        vrsim: 1
        duration: 1
        bodies:
          - name: a
            type: kinematic
            keyframes:
              position:
                times: [0, 1]
                values: [[0, 0, 0], [1, 0, 0]]
                interpolation: hermite
                in_tangents: [[0, 0, 0], [1, 0]]
                tension: 0.5
        """)
    assert out == [
        "F:8:9: bodies[0].keyframes.position: missing 'out_tangents' for hermite "
        "interpolation (glTF CUBICSPLINE: one in- and one out-tangent (value per second) per "
        "key)",
        "F:11:34: bodies[0].keyframes.position.in_tangents[1]: expected 3 numbers, got 2",
        "F:12:18: bodies[0].keyframes.position.tension: 'tension' is a kochanek-bartels "
        "parameter (set interpolation: kochanek-bartels)"]


@pytest.mark.parametrize("extra,message", [
    ("position: {times: [0, 1, 2], values: [[0, 0, 0], [1.0e300, 0, 0], [0, 0, 0]], "
     "interpolation: catmull-rom}", "must lie within +-1e+12"),
    ("position: {times: [0, 1, 2], values: [[0, 0, 0], [1, 0, 0], [0, 0, 0]], "
     "interpolation: kochanek-bartels, tension: 5}", "must be <= 1"),
])
def test_extreme_keyframe_parameters_are_input_errors(invoke, write_scene, extra, message):
    scene = write_scene("vrsim: 1\nduration: 1\nbodies:\n  - name: k\n    type: kinematic\n"
                        f"    keyframes:\n      {extra}\n")
    result = invoke("validate", scene)
    assert result.exit_code == 2 and message in result.stderr, result.stderr


def test_a_kinematic_runaway_is_not_blamed_on_the_integrator(invoke, write_scene):
    # at 2.9e8 m/s the car passes 1e12 m after ~3450 s: one step per second gets there
    scene = write_scene("vrsim: 1\nduration: 5000\nframe_rate: 1\ndt: 1\nbodies:\n"
                        "  - {name: car, type: kinematic, drive: {speed: 2.9e8}}\n")
    result = invoke("run", scene)
    assert result.exit_code == 1
    assert "body 'car'" in result.stderr and "prescribed motion" in result.stderr
    assert "integration" not in result.stderr
