"""Animated looks in MCAP: /scene re-published only on change, /vrsim/animation per sample."""

from __future__ import annotations

import mcap_messages
from conftest import SCENARIOS
from vrsim_cli.loop import run
from vrsim_cli.model.keyframes import evaluate
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.writers import open_writer
from vrsim_cli.writers.foxglove_scene import scene_entity


def messages(model, path):
    writer = open_writer(model, path, "mcap")
    run(model, make_state(model), writer)
    writer.close()
    return mcap_messages.read(path)[0]


def test_keyframes_scenario_animates_colour_scale_and_attributes(tmp_path):
    model = compile_model(load_scene(SCENARIOS / "keyframes.yaml"))
    topics = messages(model, tmp_path / "kf.mcap")
    anim = topics["/vrsim/animation"]
    assert len(anim) == len(topics["/tf"]) == 241  # one per sample
    (lamp_color,), (lamp_scale,) = model.animation.color_tracks, model.animation.scale_tracks
    (_, _, intensity), = model.animation.attr_tracks
    for ns, message in anim[::40]:
        t = message["t"]
        assert ns == round(t * 1e9)
        (lamp,) = message["entities"]
        assert lamp["name"] == "lamp"
        assert lamp["color"] == evaluate(lamp_color[1], t)[0].tolist()
        assert lamp["scale"] == [float(evaluate(lamp_scale[1], t)[0])] * 3
        assert lamp["attributes"] == [{"name": "intensity",
                                       "value": [float(evaluate(intensity, t)[0])]}]
    # /scene: every body once at the start, then only the lamp, each time it changed
    scene = topics["/scene"]
    assert [e["id"] for e in scene[0][1]["entities"]] == ["camera_rig", "lamp", "ground", "observer"]
    later = [e for _, m in scene[1:] for e in m["entities"]]
    assert later and {e["id"] for e in later} == {"lamp"}
    t, entity = scene[-1][0] / 1e9, later[-1]
    rgba = evaluate(lamp_color[1], t)[0]
    assert [entity["spheres"][0]["color"][c] for c in "rgba"] == rgba.tolist()
    diameter = 2 * 0.5 * float(evaluate(lamp_scale[1], t)[0])
    assert entity["spheres"][0]["size"]["x"] == diameter


def test_a_still_colour_is_published_once(tmp_path):
    model = compile_model(parse_scene("""
vrsim: 1
duration: 1
frame_rate: 10
dt: 0.01
bodies:
  - name: a
    mass: 1
    keyframes: {color: {times: [0, 0.35], values: [[1, 0, 0], [0, 0, 1]], interpolation: step}}
"""))
    topics = messages(model, tmp_path / "s.mcap")
    # base colour at t = 0, the key value red (a change from the palette), blue at 0.4
    times = [ns / 1e9 for ns, _ in topics["/scene"]]
    assert times == [0.0, 0.0, 0.4]


def test_scaled_cylinders_swap_y_and_z_sizes():
    entity = scene_entity("c", {"type": "cylinder", "radius": 0.5, "length": 2.0},
                          (1, 1, 1, 1), 0, scale=[2.0, 3.0, 5.0])
    decoded = mcap_messages.decode("foxglove.SceneEntity", entity.encode())
    size = decoded["cylinders"][0]["size"]
    # Foxglove's cylinder axis (its z) is the body's y: body scale (2, 3, 5) -> (2, 5, 3)
    assert (size["x"], size["y"], size["z"]) == (2.0, 5.0, 6.0)
