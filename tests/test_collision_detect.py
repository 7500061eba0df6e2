"""Detection as a loop stage: scene keys, the pipeline (broad phase choices agree), the
tunnelling case of slide 5.4 through a real run, contacts in MCAP, and the CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vrsim_cli.errors import InputError
from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.stages.collision import Contacts, detect, step

import mcap_messages
from conftest import SCENARIOS


def model_of(text: str, base_dir="."):
    return compile_model(parse_scene(text, base_dir=base_dir))


BULLET = """
vrsim: 1
duration: 0.05
frame_rate: 100
dt: 0.01
gravity: [0, 0, 0]
collision: {{tolerance: 0.001, continuous: {continuous}, response: none}}
bodies:
  - {{name: wall, type: static, shape: {{type: box, size: [0.01, 2, 2]}}, position: [3, 1, 0]}}
  - name: bullet
    shape: {{type: sphere, radius: 0.02}}
    mass: 0.005
    position: [-1.7, 1.2, 0]
    velocity: [500, 0, 0]
"""


def contacts_of_run(model):
    seen = []
    run(model, make_state(model), on_frame=lambda s: seen.append(s.contacts))
    return seen


def test_a_bullet_never_passes_a_thin_wall_unseen():
    """Slide 5.4: a 2 cm sphere at 500 m/s moves 5 m per 10 ms step; the wall is 1 cm
    thick. No state of the run overlaps the wall, yet the impact is reported: its time
    to within eps / speed, the gap at that time within [0, eps]."""
    steps = contacts_of_run(model_of(BULLET.format(continuous="true")))
    first = steps[0]
    assert first.pairs() == {(0, 1)}
    exact = (3.0 - 0.005 - 0.02 - (-1.7)) / 500.0  # s after the step's start
    assert exact - 0.001 / 500.0 <= first.toi[0] <= exact + 1e-15  # + round-off
    assert -0.001 <= first.depth[0] <= 1e-12  # a gap within eps (round-off aside)
    np.testing.assert_allclose(first.normal[0], [-1.0, 0.0, 0.0])  # wall -> bullet
    assert all(len(c) == 0 for c in steps[1:])
    # Without continuous detection the bullet tunnels: the failure this prevents.
    assert all(len(c) == 0 for c in contacts_of_run(
        model_of(BULLET.format(continuous="false"))))


PILE = """
vrsim: 1
duration: 0.01
dt: 0.01
frame_rate: 100
collision: {{broad_phase: {method}}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0], offset: 0}}}}
"""


def pile(method: str, n: int = 120):
    """Spheres, boxes and capsules dropped in a heap: many touching pairs."""
    rng = np.random.default_rng(3)
    text = PILE.format(method=method)
    shapes = ["{type: sphere, radius: 0.3}", "{type: box, size: [0.5, 0.4, 0.6]}",
              "{type: capsule, radius: 0.15, length: 0.5}"]
    for i in range(n):
        x, y, z = rng.uniform(0, 3, 3)
        e = rng.uniform(0, 90, 3)
        text += (f"  - {{name: b{i}, mass: 1, shape: {shapes[i % 3]}, position: [{x}, {y}, "
                 f"{z}], euler_deg: [{e[0]}, {e[1]}, {e[2]}]}}\n")
    return model_of(text)


def test_broad_phase_choices_give_identical_contacts():
    results = []
    for method in ("grid", "sap", "brute"):
        model = pile(method)
        c = detect(model, make_state(model))
        results.append(c)
    assert len(results[0]) > 100
    for other in results[1:]:
        for name in ("body_a", "body_b", "point", "normal", "depth"):
            np.testing.assert_array_equal(getattr(other, name), getattr(results[0], name))


def test_contacts_are_sorted_and_normals_point_from_the_lower_index():
    # The plane comes after the sphere: body_a is the sphere, the normal points down.
    model = model_of("""
vrsim: 1
duration: 0.01
collision: {}
bodies:
  - {name: ball, mass: 1, shape: {type: sphere, radius: 0.5}, position: [0, 0.4, 0]}
  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0], offset: 0}}
""")
    c = detect(model, make_state(model))
    assert c.body_a.tolist() == [0] and c.body_b.tolist() == [1]
    np.testing.assert_allclose(c.normal, [[0.0, -1.0, 0.0]])
    assert c.depth[0] == pytest.approx(0.1, abs=1e-12)


def test_scene_keys_enable_and_exclude():
    base = """
vrsim: 1
duration: 0.01
{top}
bodies:
  - {{name: a, mass: 1, shape: {{type: sphere, radius: 0.5}}}}
  - {{name: b, mass: 1, shape: {{type: sphere, radius: 0.5}}, position: [0.5, 0, 0]{extra}}}
  - {{name: c, mass: 1}}
"""
    assert model_of(base.format(top="", extra="")).collision is None
    assert model_of(base.format(top="collision: {enabled: false}", extra="")).collision \
        is None
    model = model_of(base.format(top="collision: {}", extra=""))
    assert model.collision.geom_body.tolist() == [0, 1]  # c has no shape
    assert detect(model, make_state(model)).pairs() == {(0, 1)}
    model = model_of(base.format(top="collision: {}", extra=", collision: {enabled: false}"))
    assert model.collision.geom_body.tolist() == [0]
    assert len(detect(model, make_state(model))) == 0


def test_a_proxy_on_an_analytic_shape_is_a_located_error():
    with pytest.raises(InputError) as err:
        model_of("""
vrsim: 1
duration: 1
collision: {}
bodies:
  - {name: a, mass: 1, shape: {type: sphere, radius: 0.5}, collision: {geometry: obb}}
""")
    line = err.value.lines()[0]
    assert "<scene>:6:" in line and "bodies[0].collision.geometry" in line
    assert "render mesh" in line


def test_static_pairs_and_waiting_particles_are_skipped():
    model = model_of("""
vrsim: 1
duration: 0.5
collision: {}
bodies:
  - {name: s1, type: static, shape: {type: box, size: [1, 1, 1]}}
  - {name: s2, type: static, shape: {type: box, size: [1, 1, 1]}, position: [0.5, 0, 0]}
emitters:
  - {name: jet, count: 3, rate: 10, speed: 0, mass: 0.1, radius: 0.1, position: [0, 0, 0]}
""")
    state = make_state(model)
    # Only particle 0 has left the nozzle; it overlaps both boxes. The waiting ones
    # (same place) and the static pair are not reported.
    assert detect(model, state).pairs() == {(0, 2), (1, 2)}


def test_run_profiles_collision_only_when_enabled_and_is_deterministic():
    model = compile_model(load_scene(SCENARIOS / "collision.yaml"))
    first = run(model, make_state(model))
    assert "collision" in first.profile
    again = run(model, make_state(model))
    for name in ("body_a", "body_b", "point", "normal", "depth", "toi"):
        np.testing.assert_array_equal(getattr(first.state.contacts, name),
                                      getattr(again.state.contacts, name))
    plain = compile_model(load_scene(SCENARIOS / "projectile.yaml"))
    assert "collision" not in run(plain, make_state(plain)).profile


def test_scenario_writes_contacts_foxglove_can_draw(invoke, tmp_path):
    out = tmp_path / "c.mcap"
    result = invoke("run", SCENARIOS / "collision.yaml", "-o", out, "-q")
    assert result.exit_code == 0, result.output
    messages = mcap_messages.read(out, topics=["/vrsim/contacts", "/vrsim/contacts/raw"])[0]
    raw = [m for _, m in messages["/vrsim/contacts/raw"]]
    drawn = [m for _, m in messages["/vrsim/contacts"]]
    assert len(raw) == len(drawn) == 100  # every sample after the first step
    swept = [c for m in raw for c in m["contacts"] if c["toi"] != "NaN"]  # NaN: not swept
    assert [(c["body_a"], c["body_b"]) for c in swept][:1] == [("wall", "bullet")]
    entity = drawn[0]["entities"][0]
    assert entity["frame_id"] == "scene"
    assert len(entity["arrows"]) == len(entity["spheres"]) == len(raw[0]["contacts"]) > 0


def test_collision_proxies_command(invoke):
    result = invoke("collision-proxies", SCENARIOS / "collision.yaml", "--samples", "200",
                    "--json")
    assert result.exit_code == 0, result.output
    report = {b["body"]: b for b in json.loads(result.output)}
    assert set(report) == {"rock", "ring"}
    assert report["ring"]["geometry"] == "mesh"
    ring = {r["proxy"]: r for r in report["ring"]["proxies"]}
    # A ring's hull closes the hole: a larger volume, a large surface error.
    assert ring["hull"]["volume_ratio"] > 1.5 and ring["hull"]["hausdorff_m"] > 0.1
    assert ring["mesh"]["hausdorff_m"] == 0.0
    text = invoke("collision-proxies", SCENARIOS / "projectile.yaml").output
    assert "no mesh bodies" in text


def test_step_reports_discrete_then_swept_contacts():
    model = model_of(BULLET.format(continuous="true"))
    s0 = make_state(model)
    s1 = s0.replace(step=1, t=0.01, body_pos=s0.body_pos + [[0, 0, 0], [5.0, 0, 0]])
    c = step(model, s0, s1)
    assert isinstance(c, Contacts) and len(c) == 1 and c.toi[0] == c.toi[0]


def test_2d_contacts_lie_in_the_plane():
    # A 1 x 0.5 box turned 20 deg, centre 0.2 m up: its lowest corner (-0.5, -0.25)
    # turned is at y = 0.2 - 0.5 sin 20 - 0.25 cos 20 below the ground; one contact.
    model = model_of("""
vrsim: 1
dimension: 2
duration: 0.01
collision: {}
bodies:
  - {name: ground, type: static, shape: {type: plane, normal: [0, 1], offset: 0}}
  - {name: a, mass: 1, shape: {type: box, size: [1, 0.5]}, position: [0, 0.2], angle_deg: 20}
""")
    c = detect(model, make_state(model))
    c20, s20 = math.cos(math.radians(20)), math.sin(math.radians(20))
    assert len(c) == 1
    assert c.depth[0] == pytest.approx(-(0.2 - 0.5 * s20 - 0.25 * c20), abs=1e-12)
    corner = [-0.5 * c20 + 0.25 * s20, 0.2 - 0.5 * s20 - 0.25 * c20]
    np.testing.assert_allclose(c.point[0], [corner[0], corner[1] + c.depth[0] / 2, 0.0],
                               atol=1e-12)
    np.testing.assert_allclose(c.normal[0], [0.0, 1.0, 0.0])
