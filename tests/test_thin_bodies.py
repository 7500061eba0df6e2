"""Thin bodies (plates, coins, cards) resting on each other.

Located mode detects resting contacts at the end of a step's free flight, in which a
resting body falls share |g| dt^2 (2.7 mm at dt 1/60 s under symplectic Euler). A body
thinner than that, under another, is passed through: measured before the rule, three
stacked 2 mm plates sank 1.33 mm into the ground, stacked coins slid 1-3 cm off each
other. `impacts: auto` is the compiled step (speculative contacts, found before the
step) for every scene since 2026-12-07 (it picked located mode up to 32 bodies unless a
body was this thin); a scene that sets `impacts: located` with a dynamic body thinner
than twice that fall plus the tolerance, and at least two dynamic bodies with shapes, is
told so (`validate` names the body and says why).

Truth: the stacks start touching, at rest, every centre above the one below's support,
so they stay at rest: positions and velocities after 1 s within 1e-9 m and m/s (their
round-off is ~1e-13 here).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import simulate
from vrsim_cli.model.collision import BOX, thinnest, table
from vrsim_cli.model.model import compile_model
from vrsim_cli.scene.spec import parse_scene

REST_TOL = 1e-9  # m and m/s: the truth is 0
INTEGRATORS = ("symplectic-euler", "verlet", "rk4")


def _stack(seed):
    """A stack of 2-4 thin plates (boxes or discs, 0.5-3 mm thick, random yaw, offsets of
    up to 1 mm) on the ground, at dt 1/60 s, 1/90 s or 1/120 s, under `impacts: auto`."""
    rng = np.random.default_rng(seed)
    dt = float(rng.choice([1 / 60, 1 / 90, 1 / 120]))
    integrator = INTEGRATORS[seed % 3]
    mu = float(rng.uniform(0.3, 1.0))
    lines = [f"vrsim: 1\nduration: 1.0\nframe_rate: 10\ndt: {dt!r}\n"
             f"integrator: {integrator}\ncollision: {{impacts: auto}}\nbodies:",
             f"  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}, "
             f"material: {{friction: {mu!r}}}}}"]
    y = 0.0
    discs = seed % 2 == 1
    for k in range(int(rng.integers(2, 5))):
        h = float(rng.uniform(0.0005, 0.003))
        off = [0.0, 0.0] if k == 0 else rng.uniform(-0.001, 0.001, 2).tolist()
        mass = float(rng.uniform(0.002, 0.05))
        if discs:
            shape = f"{{type: cylinder, radius: {float(rng.uniform(0.01, 0.03))!r}, length: {h!r}}}"
            pose = ""
        else:
            size = [float(rng.uniform(0.02, 0.06)), h, float(rng.uniform(0.02, 0.06))]
            shape = f"{{type: box, size: {size!r}}}"
            pose = f"euler_deg: [0.0, {float(rng.uniform(0, 90))!r}, 0.0], "
        lines.append(f"  - {{name: p{k}, mass: {mass!r}, position: [{off[0]!r}, "
                     f"{y + h / 2!r}, {off[1]!r}], {pose}shape: {shape}, "
                     f"material: {{friction: {mu!r}}}}}")
        y += h
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("seed", range(12))
def test_thin_stacks_stay_at_rest_under_auto(seed):
    """Random stacks of thin plates and discs: at rest after 1 s under `auto` (the
    compiled step; located runs of such stacks moved by up to a plate's thickness or
    slid off)."""
    text = _stack(seed)
    model, _, final = simulate(text)
    assert model.response.impacts == "stepped"
    moved = np.abs(final.body_pos - model.body_pos0).max()
    speed = max(np.abs(final.body_vel).max(), np.abs(final.body_angvel).max())
    assert moved <= REST_TOL and speed <= REST_TOL, (text, moved, speed)


RULE = "a resting body falls in one step"  # the note's words (response.thin_reason)


def _located(bodies, dt=1 / 60, integrator="symplectic-euler", gravity="[0, -9.81, 0]",
             impacts="located"):
    """(impacts, notes) of a scene with `impacts` (located by default)."""
    text = (f"vrsim: 1\nduration: 0.1\nframe_rate: 10\ndt: {dt!r}\nintegrator: {integrator}\n"
            f"gravity: {gravity}\ncollision: {{impacts: {impacts}}}\nbodies:\n"
            "  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0]}}\n"
            + "\n".join(bodies) + "\n")
    model = compile_model(parse_scene(text))
    return model.response.impacts, " ".join(model.notes)


def _plate(name, y, thickness, shape="box"):
    if shape == "box":
        s = f"{{type: box, size: [0.05, {thickness!r}, 0.05]}}"
    else:
        s = f"{{type: cylinder, radius: 0.02, length: {thickness!r}}}"
    return f"  - {{name: {name}, mass: 0.01, position: [0, {y!r}, 0], shape: {s}}}"


def test_the_rule_and_its_bound():
    """The bound: twice share |g| dt^2 plus the tolerance, which for bodies under 10 mm
    is a tenth of the thinnest (`test_the_default_tolerance_of_thin_bodies`): a plate
    of extent e is thin when e < 2 share |g| dt^2 + e / 10. symplectic Euler at 1/60 s:
    6.06 mm; rk4 (share 1/2): 3.03 mm. Located scenes below it are told; auto (the
    compiled step) needs no note."""
    g, dt = 9.81, 1 / 60
    for integrator, share in (("symplectic-euler", 1.0), ("rk4", 0.5)):
        bound = 2 * share * g * dt * dt / 0.9
        below, above = 0.99 * bound, 1.01 * bound
        impacts, notes = _located([_plate("a", below / 2, below),
                                   _plate("b", 1.5 * below, below)], integrator=integrator)
        assert impacts == "located" and "body 'a'" in notes and RULE in notes
        impacts, notes = _located([_plate("a", above / 2, above),
                                   _plate("b", 1.5 * above, above)], integrator=integrator)
        assert impacts == "located" and RULE not in notes
        impacts, notes = _located([_plate("a", below / 2, below),
                                   _plate("b", 1.5 * below, below)], integrator=integrator,
                                  impacts="auto")
        assert impacts == "stepped" and RULE not in notes


def test_one_thin_body_or_no_gravity_is_not_told():
    """A single body needs no other to rest on it (a thin plate on the ground is held
    by the plane's half-space), and without gravity nothing rests by falling."""
    assert RULE not in _located([_plate("a", 0.0005, 0.001)])[1]
    assert RULE not in _located([_plate("a", 0.0005, 0.001), _plate("b", 0.0015, 0.001)],
                                  gravity="[0, 0, 0]")[1]
    # a thin body and a thick one: the thin one may carry the thick one
    assert "body 'a'" in _located([_plate("a", 0.0005, 0.001, "disc"),
                                   _plate("b", 0.051, 0.1)])[1]


def test_set_in_the_scene_is_kept():
    text = ("vrsim: 1\nduration: 0.1\nframe_rate: 10\ndt: 0.01\ncollision: {impacts: located}\n"
            "bodies:\n  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0]}}\n"
            + _plate("a", 0.0005, 0.001) + "\n" + _plate("b", 0.0015, 0.001) + "\n")
    assert compile_model(parse_scene(text)).response.impacts == "located"


def _geom(body, kind, radius=0.0, half=(0.0, 0.0, 0.0), vertices=None):
    from vrsim_cli.model.collision import _row
    row = _row(body, kind, "exact")
    row["radius"], row["half"] = radius, np.array(half, float)
    row["vertices"] = vertices
    return row


def test_thinnest_per_shape():
    """Each kind's thinnest extent, written out: sphere and capsule the diameter, box the
    shortest side, cylinder min(diameter, length), a hull without faces the shortest
    side of its vertices' box; static bodies and planes do not count."""
    from vrsim_cli.model.collision import CAPSULE, CONVEX, CYLINDER, PLANE, SPHERE
    cube = np.array([[x, y, z] for x in (-0.1, 0.2) for y in (0.0, 0.007) for z in (0, 1)],
                    float)
    rows = [_geom(0, PLANE),
            _geom(1, SPHERE, 0.05, (0.05,) * 3),
            _geom(2, BOX, 0.0, (0.3, 0.02, 0.4)),
            _geom(3, CAPSULE, 0.03, (0.03, 0.5, 0.03)),
            _geom(4, CYLINDER, 0.2, (0.2, 0.011, 0.2)),
            _geom(5, CONVEX, 0.0, (0.0, 0.0, 0.0), cube),
            _geom(6, BOX, 0.0, (0.001, 0.001, 0.001))]
    cm = table(rows)
    dynamic = np.array([True, True, True, True, True, True, False])
    assert thinnest(cm, dynamic) == (pytest.approx(0.007, abs=1e-15), 5)
    for body, want in ((1, 0.1), (2, 0.04), (3, 0.06), (4, 0.022)):
        only = np.zeros(7, bool)
        only[body] = True
        assert thinnest(cm, only) == (pytest.approx(want, abs=1e-15), body)
    assert thinnest(cm, np.zeros(7, bool)) == (np.inf, -1)


@pytest.mark.parametrize("seed", range(8))
def test_thinnest_of_a_hull_or_mesh_turned_in_its_file(seed):
    """A plate (a box or a 3-8 sided prism, 0.5-5 mm thick, 2-20 cm wide) whose vertices
    are turned by a random rotation inside its file: its thinness is its thickness, as a
    hull and as a mesh (1e-12 relative: round-off of the turned vertices). The vertices'
    box read up to 18 times the thickness (a 2 mm plate at 45 deg: 36.8 mm, an
    independent review of 2026-12-05)."""
    import trimesh
    from vrsim_cli.model.collision import CONVEX, MESH
    rng = np.random.default_rng(seed)
    thick, wide = float(rng.uniform(5e-4, 5e-3)), float(rng.uniform(0.02, 0.2))
    sides = int(rng.integers(3, 9))
    if seed % 2:
        plate = trimesh.creation.box(extents=[wide, thick, wide * rng.uniform(0.5, 1.0)])
    else:
        plate = trimesh.creation.cylinder(radius=wide / 2, height=thick, sections=sides)
    q = rng.normal(size=4)
    plate.apply_transform(trimesh.transformations.quaternion_matrix(q / np.linalg.norm(q)))
    v, f = np.asarray(plate.vertices), np.asarray(plate.faces)
    boxed = float(np.ptp(v, axis=0).min())
    for kind in (CONVEX, MESH):
        row = _geom(0, kind, 0.0, (0.0, 0.0, 0.0), v)
        row["faces"] = f
        extent, body = thinnest(table([row]), np.array([True]))
        assert body == 0 and extent == pytest.approx(thick, rel=1e-12), (kind, boxed)


def test_the_default_tolerance_of_thin_bodies():
    """Under 10 mm the default tolerance is a tenth of the thinnest dynamic body (a note
    says so); a tolerance set in the scene, and scenes of thicker bodies, keep theirs (a
    set one of half a body's thinness or more with a note)."""
    def model(extra=""):
        text = ("vrsim: 1\nduration: 0.1\nframe_rate: 10\ndt: 0.01\n"
                f"collision: {{impacts: auto{extra}}}\nbodies:\n"
                "  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0]}}\n"
                + _plate("card", 0.00015, 0.0003) + "\n"
                + "  - {name: big, type: static, position: [1, 0, 0], shape: {type: box, "
                "size: [0.0001, 1, 1]}}\n")
        return compile_model(parse_scene(text))
    m = model()
    assert m.collision.tolerance == pytest.approx(3e-5, rel=1e-12)
    assert any("'card'" in n and "tolerance" in n for n in m.notes)
    m = model(", tolerance: 0.002")  # kept, with a warning: more than half the card
    assert m.collision.tolerance == 0.002
    assert any("at least half of body 'card'" in n for n in m.notes)
    m = model(", tolerance: 0.0001")  # a third of the card: kept, no note
    assert m.collision.tolerance == 0.0001 and not any("tolerance" in n for n in m.notes)
    r = compile_model(parse_scene(
        "vrsim: 1\nduration: 0.1\nframe_rate: 10\ndt: 0.01\ncollision: {}\nbodies:\n"
        "  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0]}}\n"
        + _plate("a", 0.05, 0.1) + "\n" + _plate("b", 0.15, 0.1) + "\n")).response
    assert r.rest_speed == pytest.approx((2 * 9.81 * 1e-3) ** 0.5, rel=1e-12)


@pytest.mark.parametrize("bodies", [
    "bodies: []\n",
    "bodies:\n  - {name: wall, type: static, shape: {type: box, size: [1, 1, 0.001]}}\n"])
def test_no_dynamic_body_no_thin_rule(bodies):
    """No dynamic body with a shape (none at all, or only a thin static one): the
    tolerance stays the default and nothing is called thin (hypothesis found the empty
    scene raising IndexError while the rule looked up the thinnest body's name)."""
    m = compile_model(parse_scene("vrsim: 1\nduration: 1.0\ncollision: {continuous: false}\n"
                                  + bodies))
    assert m.collision.tolerance == 1e-3
    assert not any("thin" in n for n in m.notes)
