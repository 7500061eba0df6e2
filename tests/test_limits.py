"""Numbers vrsim cannot simulate are refused at validation with the range that works
(issue 19, items 4 and 7's input part); values at the edge of a range are accepted and
run without NaN. The ranges are the documented table (docs/scene-format.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vrsim_cli.tools.trajectory import read_trajectory

HEAD = "vrsim: 1\nduration: 0.05\nframe_rate: 100\ndt: 0.01\n"

# (scene text with {v}, key path of v, the largest or smallest accepted value, a value
# just past it, the range as the hint states it)
EDGES = [
    ("bodies: [{{name: a, mass: {v}}}]", "bodies[0].mass", 1e12, 1.0001e12,
     "a mass must lie between 1e-09 and 1e+12 kg"),
    ("bodies: [{{name: a, mass: {v}}}]", "bodies[0].mass", 1e-9, 0.9999e-9,
     "a mass must lie between 1e-09 and 1e+12 kg"),
    ("bodies: [{{name: a, mass: 1, shape: {{type: sphere, radius: {v}}}}}]",
     "bodies[0].shape.radius", 1e-6, 0.999e-6, "a length must lie between 1e-06 and 1e+06 m"),
    ("bodies: [{{name: a, mass: 1, shape: {{type: box, size: [1, {v}, 1]}}}}]",
     "bodies[0].shape.size[1]", 1e6, 1.001e6, "a length must lie between 1e-06 and 1e+06 m"),
    ("bodies: [{{name: a, density: {v}, shape: {{type: sphere, radius: 1}}}}]",
     "bodies[0].density", 1e6, 1.001e6, "a density must lie between 1e-06 and 1e+06 kg/m^3"),
    ("bodies: [{{name: a, type: kinematic, position: [0, {v}, 0]}}]",
     "bodies[0].position[1]", -9.99e11, -1e12, "a coordinate must lie within +-1e+12 m"),
    ("bodies: [{{name: a, type: kinematic, velocity: [{v}, 0, 0]}}]",
     "bodies[0].velocity[0]", 2.99e8, 299792458, "a velocity component must lie within "
     "+-299792458 m/s"),
    ("bodies: [{{name: a, mass: 1, forces: [{{force: [0, {v}, 0], end: 0.02}}]}}]",
     "bodies[0].forces[0].force", 1e15, 1.01e15, "the length of a force must be at most "
     "1e+15 N"),
    ("bodies: [{{name: a, mass: 1, forces: [{{force: [1, 0, 0], end: {v}}}]}}]",
     "bodies[0].forces[0].end", 1e9, 1.0e308, "a time must be at most 1e+09 s"),
    ("bodies: [{{name: a, mass: 1, shape: {{type: sphere, radius: 1}}, "
     "angular_velocity: [0, {v}, 0]}}]", "bodies[0].angular_velocity", 1e6, 1.01e6,
     "the length of an angular speed must be at most 1e+06 rad/s"),
    ("gravity: [0, {v}, 0]\nbodies: [{{name: a, mass: 1}}]", "gravity", -1e9, -1.1e9,
     "the length of an acceleration must be at most 1e+09 m/s^2"),
    ("bodies: [{{name: a, mass: 1}}]\nsprings: [{{body: a, anchor: [0, 1, 0], "
     "stiffness: {v}}}]", "springs[0].stiffness", 1e15, 1.1e15,
     "a stiffness must be at most 1e+15 N/m"),
    ("observer: {{mode: fly, direction: [{v}, 0, 0]}}", "observer.direction", 1e-9, 1e-300,
     "the length of a direction must lie between 1e-09 and 1e+12"),
    ("bodies: [{{name: a, type: kinematic, keyframes: {{position: {{times: [0, {v}], "
     "values: [[0, 0, 0], [1, 0, 0]]}}}}}}]", "bodies[0].keyframes.position.times[1]", 1e-9,
     5e-324, "keys must be at least 1e-09 s apart"),
]


@pytest.mark.parametrize("text,path,edge,beyond,hint", EDGES)
def test_values_past_a_range_are_refused_with_the_range(invoke, write_scene, tmp_path, text,
                                                        path, edge, beyond, hint):
    refused = write_scene(HEAD + text.format(v=repr(beyond)) + "\n", "beyond.yaml")
    result = invoke("validate", refused)
    assert result.exit_code == 2
    assert f"{path}: " in result.stderr and f"({hint})" in result.stderr, result.stderr
    assert len(result.stderr.splitlines()) == 1
    accepted = write_scene(HEAD + text.format(v=repr(edge)) + "\n", "edge.yaml")
    out = tmp_path / "o.csv"
    result = invoke("run", accepted, "-o", out, "-q")
    assert result.exit_code in (0, 1), result.output  # 1: a named blow-up, never NaN rows
    if out.exists():
        for track in read_trajectory(out).tracks.values():
            assert np.isfinite(track.pos).all() and np.isfinite(track.quat).all()


@pytest.mark.parametrize("text,message", [
    # the silent failures: NaN orientations in every sample, exit 0
    ("observer: {mode: walk, direction: [1.0e-300, 0, 0]}",
     "observer.direction: a length of 1e-300 is outside the range vrsim can simulate"),
    ("observer: {mode: examine, position: [0, 1, 0], look_at: [0, 1, 1.0e-300]}",
     "observer.look_at: look_at must differ from the observer's position by at least 1e-09 m"),
    ("bodies: [{name: a, type: kinematic, keyframes: {position: {times: [0, 5.0e-324], "
     "values: [[0, 0, 0], [1, 0, 0]]}}}]",
     "bodies[0].keyframes.position.times[1]: key time 4.94066e-324 s is only 4.94e-324 s "
     "after the previous one"),
    ("bodies: [{name: a, type: kinematic, keyframes: {orientation: {times: [0, 1.0e-300], "
     "values: [[1, 0, 0, 0], [0, 1, 0, 0]], interpolation: squad}}}]",
     "bodies[0].keyframes.orientation.times[1]: key time 1e-300 s is only 1e-300 s"),
])
def test_inputs_that_made_nan_orientations_are_refused(invoke, write_scene, text, message):
    result = invoke("validate", write_scene(HEAD + text + "\n"))
    assert result.exit_code == 2 and message in result.stderr, result.stderr


@pytest.mark.parametrize("scale", [1e-200, 1e-20, 1.0, 1e11])  # key values <= 1e12
def test_a_quaternion_key_of_any_length_is_its_rotation(invoke, write_scene, tmp_path, scale):
    """A key [1e-200, 0, 0, 0] made NaN orientations (its plain norm underflows to 0): keys
    are normalised scaled, so any length is the rotation it points to. Truth: a slerp from
    the identity to 90 degrees about y, at t = 0.5 s halfway (45 degrees), in closed form."""
    half = math.sqrt(0.5)
    scene = write_scene(HEAD.replace("duration: 0.05", "duration: 1") +
                        "bodies: [{name: a, type: kinematic, keyframes: {orientation: {times: "
                        f"[0, 1], values: [[{scale!r}, 0, 0, 0], [{half * scale!r}, 0, "
                        f"{half * scale!r}, 0]]}}}}}}]\n")
    out = tmp_path / "o.csv"
    assert invoke("run", scene, "-o", out, "-q").exit_code == 0
    track = read_trajectory(out).tracks["a"]
    middle = track.quat[np.argmin(np.abs(track.t - 0.5))]
    angle = math.radians(45.0)
    np.testing.assert_allclose(middle, [math.cos(angle / 2), 0, math.sin(angle / 2), 0],
                               atol=1e-12)
