"""tools/pass_through.py: without a collision block shapes pass through each other, and
vrsim says so: `validate` names the bodies, `run` the first pair and when they meet."""

from __future__ import annotations

import json
import math

import pytest

CRATE = """
vrsim: 1
name: crate
duration: 1.0
bodies:
  - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 0]}}
  - {name: crate, mass: 5, shape: {type: box, size: [0.5, 0.5, 0.5]}, position: [0, 2, 0]}
"""


def test_run_names_the_bodies_and_the_first_frame_they_overlap(invoke, write_scene, tmp_path):
    out = tmp_path / "o.csv"
    result = invoke("run", write_scene(CRATE), "-o", out)
    assert result.exit_code == 0, result.output
    notes = [line for line in result.stderr.splitlines() if "pass through" in line]
    assert len(notes) == 1
    t = float(notes[0].split("from t = ")[1].split(" s")[0])
    # free fall of the crate's bottom (1.75 m) to 1 mm below the floor (the tolerance
    # counted as overlap): the first frame at or after it, 60 frames a second; symplectic
    # Euler at dt 1/1020 s falls 0.5 g dt t ~ 3 mm further by then: within one frame too
    fall = math.sqrt(2 * (1.75 + 0.001) / 9.81)
    assert fall <= t + 1e-9 <= fall + 1 / 60 + 1e-9
    assert "'floor' and 'crate'" in notes[0] and "add `collision: {}`" in notes[0]
    assert "no collision block" not in result.stdout  # notes go to stderr


def test_the_run_itself_is_untouched(invoke, write_scene, tmp_path):
    """The watch reads states; the trajectory is that of the same scene without shapes
    meeting (the crate falls freely through the floor, as before)."""
    from vrsim_cli.tools.trajectory import read_trajectory

    out = tmp_path / "o.csv"
    assert invoke("run", write_scene(CRATE), "-o", out).exit_code == 0
    y = read_trajectory(out).tracks["crate"].pos[-1, 1]
    assert y == pytest.approx(2 - 9.81 / 2, abs=0.01)  # 1 s of free fall: through the floor


def test_json_reports_it(invoke, write_scene, tmp_path):
    result = invoke("run", write_scene(CRATE), "-o", tmp_path / "o.csv", "--json")
    report = json.loads(result.stdout)
    assert report["passes_through"]["bodies"] == ["floor", "crate"]
    assert report["passes_through"]["t_s"] == pytest.approx(0.6, abs=1 / 60)


@pytest.mark.parametrize("scene", [
    CRATE + "collision: {enabled: false}\n",  # the user said so
    CRATE.replace("position: [0, 2, 0]", "position: [0, 20, 0]"),  # never meet in 1 s
    CRATE.replace("  - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 0]}}\n",
                  ""),  # nothing to meet
])
def test_no_note_when_nothing_passes_through_or_the_user_chose(invoke, write_scene, tmp_path,
                                                               scene):
    result = invoke("run", write_scene(scene), "-o", tmp_path / "o.csv")
    assert result.exit_code == 0 and "pass through" not in result.stderr


def test_validate_names_the_bodies(invoke, write_scene):
    result = invoke("validate", write_scene(CRATE))
    assert result.exit_code == 0
    assert "no collision block: the shapes of floor, crate pass through each other" \
        in result.stderr


def test_point_masses_and_kinematic_shapes_alone_are_not_watched():
    from vrsim_cli.tools.pass_through import candidates

    assert candidates({"bodies": [{"name": "a", "mass": 1}, {"name": "b", "mass": 1}]}) == []
    kinematic = {"bodies": [{"name": "door", "type": "kinematic", "shape": {"type": "box"}},
                            {"name": "wall", "type": "static", "shape": {"type": "box"}}]}
    assert candidates(kinematic) == []
    kinematic["bodies"].append({"name": "crate", "shape": {"type": "box"}})
    assert candidates(kinematic) == ["door", "wall", "crate"]


def test_a_watch_that_breaks_is_dropped_and_the_run_goes_on(write_scene, monkeypatch):
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene
    import importlib

    from vrsim_cli.tools.pass_through import watch

    detect = importlib.import_module("vrsim_cli.stages.collision.detect")  # the module
    scene = load_scene(write_scene(CRATE))
    found = watch(scene, compile_model(scene))

    def broken(*args):
        raise RuntimeError("a detection bug")

    monkeypatch.setattr(detect, "start_overlaps", broken)
    state = make_state(compile_model(scene))
    found(state.replace(body_pos=state.body_pos * 0.0))  # the crate in the floor: detected
    # (no exception)
    assert found.probe is None and found.found is None


def test_large_scenes_are_not_watched(write_scene):
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.tools.pass_through import WATCH_MAX_SHAPES, watch

    boxes = "\n".join(f"  - {{name: b{i}, mass: 1, shape: {{type: sphere, radius: 0.1}}, "
                      f"position: [{i}, 1, 0]}}" for i in range(WATCH_MAX_SHAPES))
    scene = load_scene(write_scene(CRATE + boxes + "\n"))
    assert watch(scene, compile_model(scene)) is None
    small = load_scene(write_scene(CRATE, "small.yaml"))
    assert watch(small, compile_model(small)) is not None


def test_the_bounding_test_never_hides_an_overlap(write_scene):
    """Bounds.near skips the detection when no bounding spheres meet: it must be True
    wherever the detection finds an overlap (seeded random poses of a box, a capsule, a
    cylinder and a sphere over a plane and each other)."""
    import numpy as np

    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.stages.collision.detect import start_overlaps
    from vrsim_cli.tools.pass_through import Bounds, watch

    scene = load_scene(write_scene("""
        vrsim: 1
        duration: 1
        bodies:
          - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 1], offset: 0.1}}
          - {name: box, mass: 1, shape: {type: box, size: [0.6, 0.2, 0.4]}}
          - {name: pill, mass: 1, shape: {type: capsule, radius: 0.1, length: 0.5}}
          - {name: can, mass: 1, shape: {type: cylinder, radius: 0.2, length: 0.3}}
          - {name: ball, type: kinematic, shape: {type: sphere, radius: 0.25}}
        """))
    model = compile_model(scene)
    probe = watch(scene, model).probe
    bounds = Bounds(scene.data)
    rng = np.random.default_rng(52)
    state = make_state(model)
    found = 0
    for _ in range(400):
        quat = rng.normal(size=(5, 4))
        quat /= np.linalg.norm(quat, axis=1, keepdims=True)
        pos = rng.uniform(-0.6, 0.6, size=(5, 3))
        pos[0] = 0.0
        s = state.replace(body_pos=pos, body_quat=quat)
        if start_overlaps(probe, s, 5):
            found += 1
            assert bounds.near(pos, probe.collision.tolerance)
    assert found > 100  # the draws do overlap often


def test_a_keyframed_door_through_a_static_wall_is_not_reported(invoke, write_scene, tmp_path):
    """Only pairs with a dynamic body: a collision block would not stop a kinematic door."""
    scene = write_scene("""
        vrsim: 1
        duration: 1
        bodies:
          - {name: wall, type: static, shape: {type: box, size: [0.2, 2, 2]}}
          - name: door
            type: kinematic
            shape: {type: box, size: [1, 2, 0.05]}
            position: [-2, 0, 0]
            velocity: [4, 0, 0]
          - {name: crate, mass: 1, shape: {type: box, size: [0.5, 0.5, 0.5]}, position: [5, 5, 5]}
        gravity: [0, 0, 0]
        """)
    result = invoke("run", scene, "-o", tmp_path / "o.csv")
    assert result.exit_code == 0 and "pass through" not in result.stderr
