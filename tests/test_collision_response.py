"""Collision response (slide 5.4.2) through the loop: exact bounces, conservation in
two-body impacts, Newton's cradle, friction turning sliding into rolling, stop and slide,
resting stacks, material combination, scene errors and the MCAP impulses."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vrsim_cli.errors import InputError
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.response import (DEFAULT_FRICTION, IMPULSE, NONE, SLIDE,
                                                STOP)
from vrsim_cli.scene.spec import parse_scene

import mcap_messages
from conftest import SCENARIOS, simulate

G = 9.81


def impacts(states, body_a, body_b):
    """[(time of impact, state at the end of that step)] of the pair, from contacts with
    a time of impact (the event rows), in order."""
    out = []
    for prev, s in zip(states, states[1:]):
        c = s.contacts
        rows = np.flatnonzero(~np.isnan(c.toi) & (c.body_a == body_a) & (c.body_b == body_b))
        out.extend((prev.t + c.toi[k], s) for k in rows)
    return out


def ball_scene(eps: float, dt: float, frame_rate: float, duration: float,
               integrator: str = "rk4", h0: float = 1.0, extra: str = "") -> str:
    return f"""
vrsim: 1
duration: {duration}
frame_rate: {frame_rate}
dt: {dt}
integrator: {integrator}
collision: {{{extra}}}
output: {{rate: {1.0 / dt!r}}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}}}
  - name: ball
    mass: 1
    position: [0, {h0 + 0.1}, 0]
    shape: {{type: sphere, radius: 0.1}}
    material: {{restitution: {eps}}}
"""


@pytest.mark.parametrize("eps", [0.0, 0.5, 0.8, 1.0])
@pytest.mark.parametrize("dt, frame_rate, integrator", [(0.01, 100, "rk4"),
                                                        (1 / 30, 30, "verlet"),
                                                        (1 / 300, 100, "rk4"),
                                                        (0.02, 50, "dopri5")])
def test_bounces_are_exact_at_any_dt(eps, dt, frame_rate, integrator):
    """A ball dropped from h0 = 1 m onto a plane: impact k at t_k = t_0 + sum 2 v_j / g with
    v_j = sqrt(2 g h0) eps^j, apex heights h_k = h0 eps^(2k). With an integrator exact for
    constant acceleration and the time of impact the root of the integrated motion,
    both hold to round-off; the bound 1e-9 (relative) is the issue's, and measured errors
    are ~1e-15. Bounces slower than rest_speed (sqrt(2 g tol) = 0.14 m/s) are plastic by
    design, so only faster ones are compared."""
    duration = 2.0
    model, states, _ = simulate(ball_scene(eps, dt, frame_rate, duration, integrator,
                                             extra="impacts: located"))
    hits = impacts(states, 0, 1)
    v, t, expected = math.sqrt(2 * G), math.sqrt(2 / G), []
    while t <= duration - 1e-6 and v >= model.response.rest_speed:
        expected.append((t, v))
        t += 2 * v * eps / G
        v *= eps
        if eps == 0.0:
            break
    assert len(hits) >= len(expected) >= 1
    for k, ((t_exact, _), (t_hit, after)) in enumerate(zip(expected, hits)):
        assert abs(t_hit - t_exact) <= 1e-9 * t_exact
        apex = after.body_pos[1, 1] - 0.1 + after.body_vel[1, 1] ** 2 / (2 * G)
        assert abs(apex - eps ** (2 * (k + 1))) <= 1e-9


def test_elastic_bounces_conserve_energy_to_round_off():
    """eps = 1 under rk4: E = m g (y - r) + m v^2 / 2 stays m g h0 at every sample (the
    flight is exact and the impulse only reverses v_n). Tolerance 1e-12 J (round-off of
    ~1e3 steps on O(10) J)."""
    _, states, _ = simulate(ball_scene(1.0, 0.01, 100, 3.0))
    energy = np.array([G * (s.body_pos[1, 1] - 0.1) + 0.5 * s.body_vel[1] @ s.body_vel[1]
                       for s in states])
    assert np.abs(energy - G * 1.0).max() <= 1e-12


def test_a_bouncing_ball_comes_to_rest_and_stays():
    """eps = 0.8: the bounces would go on forever (Zeno, t_inf = t_0 (1+eps)/(1-eps) =
    4.06 s); below rest_speed they become plastic, and afterwards the ball rests on the
    plane exactly: no jitter in velocity or height (round-off bounds)."""
    _, states, final = simulate(ball_scene(0.8, 0.01, 100, 5.0, integrator="verlet"))
    late = [s for s in states if s.t >= 4.5]
    assert max(abs(s.body_vel[1]).max() for s in late) <= 1e-12
    assert max(abs(s.body_pos[1, 1] - 0.1) for s in late) <= 1e-12


def test_newtons_cradle_passes_the_momentum_to_the_last_ball():
    """Five equal touching balls, eps = 1, the first arriving at 1 m/s: the impulses
    propagate along the chain in order and only the last ball leaves, at 1 m/s, at the
    exact time (the first ball hits at 0.5 s, the last travels 0.5 s). Round-off bounds."""
    balls = "".join(f"""
  - name: b{i}
    mass: 1
    position: [{-0.5 if i == 0 else 0.2 * i}, 0, 0]
    velocity: [{1.0 if i == 0 else 0.0}, 0, 0]
    shape: {{type: sphere, radius: 0.1}}
    material: {{restitution: 1, friction: 0}}""" for i in range(5))
    _, states, final = simulate(f"""
vrsim: 1
duration: 1.0
frame_rate: 100
dt: 0.01
integrator: verlet
gravity: [0, 0, 0]
collision: {{impacts: located}}
bodies:{balls}
""")
    assert np.abs(final.body_vel[:, 0] - [0, 0, 0, 0, 1]).max() <= 1e-12
    assert abs(final.body_pos[4, 0] - 1.3) <= 1e-12
    assert np.abs(final.body_pos[:4, 0] - [0.0, 0.2, 0.4, 0.6]).max() <= 1e-12


def test_oblique_two_body_impact_with_spin_conserves_momentum():
    """Two spinning boxes collide off-centre with restitution 0.6 and friction 0.4 in zero
    gravity: linear momentum and angular momentum (about the origin, orbital plus spin)
    are the same after the impact as before (impulses are equal and opposite at one
    point), to round-off (1e-12 relative)."""
    scene = """
vrsim: 1
duration: 0.6
frame_rate: 100
dt: 0.01
integrator: verlet
gravity: [0, 0, 0]
collision: {impacts: located, pairs: [{bodies: [a, b], restitution: 0.6, friction: 0.4}]}
bodies:
  - name: a
    mass: 2
    position: [-1, 0.3, 0.1]
    velocity: [3, 0, 0]
    angular_velocity: [0.5, 1.0, 2.0]
    shape: {type: box, size: [0.4, 0.3, 0.5]}
  - name: b
    mass: 3
    position: [0.5, 0, 0]
    velocity: [-1, 0.2, 0]
    angular_velocity: [0, -1.0, 0.3]
    shape: {type: box, size: [0.5, 0.5, 0.5]}
"""
    model, states, final = simulate(scene)
    assert impacts(states, 0, 1), "the boxes must collide"

    def momenta(s):
        p = model.body_mass[:, None] * s.body_vel
        l_orbit = np.cross(s.body_pos, p).sum(0)
        return p.sum(0), l_orbit + s.rot_angmom.sum(0)

    p0, l0 = momenta(states[0])
    p1, l1 = momenta(final)
    assert np.abs(p1 - p0).max() <= 1e-12 * np.abs(p0).max()
    assert np.abs(l1 - l0).max() <= 1e-12 * np.abs(l0).max()
    assert not np.allclose(final.body_vel, states[0].body_vel)  # something happened


def test_friction_turns_sliding_into_rolling_at_five_sevenths():
    """A solid ball (I = 2/5 m r^2) launched sliding at v0 without spin: friction slows
    it and spins it up until v = omega r; angular momentum about the contact line is
    conserved by every contact impulse, so v = 5/7 v0 exactly (round-off bound 1e-12),
    reached at t = 2 v0 / (7 mu g) (within one step)."""
    v0, mu, r = 3.0, 0.3, 0.1
    _, states, final = simulate(f"""
vrsim: 1
duration: 1.0
frame_rate: 100
dt: 0.01
integrator: verlet
collision: {{}}
output: {{rate: 100}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}, material: {{friction: {mu}}}}}
  - name: ball
    mass: 2
    position: [0, {r}, 0]
    velocity: [{v0}, 0, 0]
    shape: {{type: sphere, radius: {r}}}
    material: {{friction: {mu}}}
""")
    assert abs(final.body_vel[1, 0] - 5 / 7 * v0) <= 1e-12
    assert abs(final.body_angvel[1, 2] * r + 5 / 7 * v0) <= 1e-12  # rolls (w along -z)
    slip = [s.t for s in states if abs(s.body_vel[1, 0] + s.body_angvel[1, 2] * r) > 1e-9]
    assert abs(max(slip) - 2 * v0 / (7 * mu * G)) <= 0.01 + 1e-9


def test_stop_keeps_the_last_non_colliding_pose_and_slide_keeps_the_tangent():
    """stop: the ball halts at the time of impact, touching the plane (y = r), and stays.
    slide: v - (v.n) n removes only the normal velocity: the horizontal 2 m/s survives
    unchanged, the ball glides on the plane. Round-off bounds."""
    text = """
vrsim: 1
duration: 1.0
frame_rate: 100
dt: 0.01
integrator: rk4
collision: {impacts: located}
bodies:
  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0]}}
  - name: stopper
    mass: 1
    position: [0, 1.1, 0]
    velocity: [1, 0, 0]
    shape: {type: sphere, radius: 0.1}
    collision: {response: stop}
  - name: glider
    mass: 1
    position: [0, 1.1, 5]
    velocity: [2, 0, 0]
    shape: {type: sphere, radius: 0.1}
    collision: {response: slide}
"""
    _, states, final = simulate(text)
    t_hit = math.sqrt(2 / G)
    assert abs(final.body_pos[1, 1] - 0.1) <= 1e-12
    assert abs(final.body_pos[1, 0] - t_hit) <= 1e-12  # stopped where it touched
    assert np.abs(final.body_vel[1]).max() == 0.0
    assert abs(final.body_vel[2, 0] - 2.0) <= 1e-12
    assert abs(final.body_vel[2, 1]) <= 1e-12
    assert abs(final.body_pos[2, 1] - 0.1) <= 1e-12
    assert abs(final.body_pos[2, 0] - 2.0) <= 1e-12


def stack_scene(masses, duration: float) -> str:
    boxes, y = "", 0.0
    for i, m in enumerate(masses):
        boxes += f"""
  - name: box{i}
    mass: {m}
    position: [0, {y + 0.5}, 0]
    shape: {{type: box, size: [1, 1, 1]}}"""
        y += 1.0
    return f"""
vrsim: 1
duration: {duration}
frame_rate: 60
dt: {1 / 60!r}
integrator: verlet
collision: {{}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}}}{boxes}
"""


def test_a_ten_box_stack_stands_for_ten_seconds():
    """The issue's bound: the top box of a 10-box stack drifts < 1 mm over 10 s (here at
    60 Hz, 600 steps). Shock propagation holds every loaded contact exactly, so the
    measured drift is ~1e-13 m; horizontal drift and final speed are checked too."""
    model, states, final = simulate(stack_scene([1.0] * 10, 10.0))
    top = np.array([s.body_pos[10] for s in states])
    assert np.abs(top - [0.0, 9.5, 0.0]).max() < 1e-3
    assert np.abs(final.body_vel).max() < 1e-6


def test_a_heavy_box_on_a_light_one_holds():
    """100:1 mass ratio, where plain Gauss-Seidel converges at ~1 % per iteration: the
    heavy box stays within 1 mm of its place for 2 s (measured: 4e-16 m)."""
    _, states, final = simulate(stack_scene([1.0, 100.0], 2.0))
    heavy = np.array([s.body_pos[2] for s in states])
    assert np.abs(heavy - [0.0, 1.5, 0.0]).max() < 1e-3


def test_materials_combine_as_documented_and_pairs_override():
    """restitution: the larger; friction: the geometric mean; a value only one body sets
    is used as it is; a pair entry replaces both; modes: none < stop < slide < impulse."""
    model = compile_model(parse_scene("""
vrsim: 1
duration: 0.1
collision: {pairs: [{bodies: [c, a], friction: 0.05, response: slide}]}
bodies:
  - {name: a, mass: 1, shape: {type: sphere, radius: 0.1}, material: {restitution: 0.2, friction: 0.4}}
  - {name: b, mass: 1, shape: {type: sphere, radius: 0.1}, material: {restitution: 0.7, friction: 0.9}}
  - {name: c, mass: 1, shape: {type: sphere, radius: 0.1}, collision: {response: stop}}
  - {name: d, mass: 1, shape: {type: sphere, radius: 0.1}, collision: {response: none}}
"""))
    rm = model.response
    mode, eps, mu = rm.pair_values(np.array([0, 0, 1, 2]), np.array([1, 2, 2, 3]))
    assert eps.tolist() == [0.7, 0.2, 0.7, 0.0]
    assert mu[0] == pytest.approx(math.sqrt(0.4 * 0.9), rel=1e-15)
    assert mu[1:].tolist() == [0.05, 0.9, DEFAULT_FRICTION]
    assert mode.tolist() == [IMPULSE, SLIDE, STOP, NONE]


def test_unknown_pair_body_is_a_located_error():
    with pytest.raises(InputError) as err:
        compile_model(parse_scene("""
vrsim: 1
duration: 0.1
collision: {pairs: [{bodies: [a, ghost]}]}
bodies:
  - {name: a, mass: 1, shape: {type: sphere, radius: 0.1}}
"""))
    assert "collision.pairs[0].bodies" in str(err.value)
    assert "no body named 'ghost'" in str(err.value)


def test_scenarios_write_contact_impulses_to_mcap(invoke, tmp_path):
    """scenarios/bounce.yaml: the raw contacts channel carries each contact's impulse;
    the impulse of the first impact is m (1 + eps) v = 1 * 1.8 * sqrt(2 g h0)."""
    out = tmp_path / "b.mcap"
    result = invoke("run", SCENARIOS / "bounce.yaml", "-o", out, "-q")
    assert result.exit_code == 0, result.output
    raw = [m for _, m in mcap_messages.read(out, topics=["/vrsim/contacts/raw"])[0][
        "/vrsim/contacts/raw"]]
    hits = [c for m in raw for c in m["contacts"] if c["toi"] != "NaN"]  # NaN: not swept
    assert hits, "the first bounce is sampled"
    first = hits[0]
    assert first["impulse"][1] == pytest.approx(1.8 * math.sqrt(2 * G * 1.0), rel=1e-9)


def test_a_box_tumbles_down_the_stairs_and_settles_flat():
    """scenarios/stairs.yaml: the box ends at rest lying flat on the floor (centre at half
    its size, 0.15 m, to 1e-6 m) beyond the last step, and the mechanical energy never
    grows by more than the weight times the contact tolerance (position correction may
    lift a body out of a penetration no deeper than that)."""
    text = (SCENARIOS / "stairs.yaml").read_text().replace("output: {file: stairs.mcap", "#")
    model, states, final = simulate(text)
    box = model.body_index["box"]
    assert abs(final.body_pos[box, 1] - 0.15) <= 1e-6
    assert final.body_pos[box, 0] > 0.0
    assert np.abs(final.body_vel[box]).max() <= 1e-9
    m = model.body_mass[box]

    def energy(s):
        return m * G * s.body_pos[box, 1] + 0.5 * m * s.body_vel[box] @ s.body_vel[box] + \
            0.5 * s.rot_angmom[0] @ s.body_angvel[box]

    e = np.array([energy(s) for s in states])
    assert np.max(e - np.minimum.accumulate(e)) <= m * G * model.collision.tolerance
    assert e[-1] < 0.2 * e[0]


def test_a_kinematic_paddle_pushes_with_infinite_mass():
    """A kinematic box moving at 2 m/s hits a ball at rest, eps = 1, no gravity: against
    infinite mass the ball leaves at 2 * 2 - 0 = 4 m/s (its velocity reflected in the
    paddle's frame), and the paddle keeps its 2 m/s. Round-off bounds."""
    _, _, final = simulate("""
vrsim: 1
duration: 0.5
frame_rate: 100
dt: 0.01
integrator: verlet
gravity: [0, 0, 0]
collision: {}
bodies:
  - {name: paddle, type: kinematic, position: [-0.5, 0, 0], velocity: [2, 0, 0], shape: {type: box, size: [0.2, 1, 1]}}
  - {name: ball, mass: 1, position: [0.5, 0, 0], shape: {type: sphere, radius: 0.1}, material: {restitution: 1, friction: 0}}
""")
    assert abs(final.body_vel[1, 0] - 4.0) <= 1e-12
    assert np.abs(final.body_vel[1, 1:]).max() <= 1e-12
    assert final.body_vel[0, 0] == 2.0


def test_response_none_everywhere_is_detection_only():
    model = compile_model(parse_scene("""
vrsim: 1
duration: 0.1
collision: {response: none}
bodies:
  - {name: a, mass: 1, shape: {type: sphere, radius: 0.1}}
"""))
    assert model.collision is not None and model.response is None


def test_2d_contacts_stay_in_the_plane_and_a_disc_rolls_at_two_thirds():
    """In 2D a sphere is a disc (I = m r^2 / 2): launched sliding at v0 it rolls at
    v0 / (1 + 1/2) = 2/3 v0 (angular momentum about the contact point). A tumbling
    rectangle lands on its corners: nothing leaves the plane (z, and omega's x and y,
    stay at round-off), and it comes to rest on a side."""
    _, states, final = simulate("""
vrsim: 1
dimension: 2
duration: 2
frame_rate: 100
dt: 0.01
integrator: verlet
collision: {}
bodies:
  - {name: ground, type: static, shape: {type: plane, normal: [0, 1]}}
  - {name: box, mass: 1, position: [0, 1], velocity: [1, 0], angle_deg: 30, angular_velocity: 3, shape: {type: box, size: [0.4, 0.2]}, material: {restitution: 0.4}}
  - {name: disc, mass: 1, position: [2, 0.1], velocity: [1, 0], shape: {type: sphere, radius: 0.1}}
""")
    assert abs(final.body_vel[2, 0] - 2.0 / 3.0) <= 1e-12
    assert max(np.abs(s.body_pos[:, 2]).max() for s in states) <= 1e-12
    assert max(np.abs(s.body_angvel[:, :2]).max() for s in states) <= 1e-12
    # the box comes to rest on one of its sides (which one, the tumble decides: located
    # impacts lay it flat, the compiled step stands it on its 0.2 m end)
    assert min(abs(final.body_pos[1, 1] - 0.1), abs(final.body_pos[1, 1] - 0.2)) <= 1e-6
    assert max(np.abs(final.body_vel[1]).max(), np.abs(final.body_angvel[1]).max()) <= 1e-9


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("seed", range(4))
def test_nearly_parallel_elastic_capsules_keep_their_energy(seed, mode):
    """Two capsules meet side by side, nearly parallel (tilt 3e-6 to 9e-5 rad in the plane
    of their axes, so that their least distance lies at one capsule's end), ε = 1, μ = 0,
    no gravity. Truth: energy and momentum conserved (1e-12 relative; located mode's
    promise is ~4e-13 for elastic scenes). Until 2026-12-07 the least distance joined
    the overlap's two ends as a third contact, 5e-7 m from one of them with its normal
    turned by half the tilt: located mode gained up to 2.8e-7 of the energy (an
    independent review); now it replaces that end."""
    from conftest import simulate
    from vrsim_cli.maths.spatial import quat_to_matrix

    rng = np.random.default_rng(900 + seed)
    tilt = float(10.0 ** rng.uniform(math.log10(3e-6), math.log10(9e-5)))
    mass_b = float(rng.uniform(0.5, 3.0))
    offset = float(rng.uniform(-0.1, 0.1))
    q = [math.cos(tilt / 2), 0.0, 0.0, math.sin(tilt / 2)]
    text = f"""
vrsim: 1
duration: 0.3
frame_rate: 1000
dt: 0.001
gravity: [0, 0, 0]
collision: {{impacts: {mode}}}
bodies:
  - {{name: A, mass: 1.0, position: [-0.25, 0.0, 0.0], velocity: [1.0, 0.0, 0.0],
     shape: {{type: capsule, radius: 0.1, length: 1.0}}, material: {{restitution: 1, friction: 0}}}}
  - {{name: B, mass: {mass_b!r}, position: [0.0, {offset!r}, 0.0], orientation: {q!r},
     shape: {{type: capsule, radius: 0.1, length: 1.0}}, material: {{restitution: 1, friction: 0}}}}
"""
    model, states, final = simulate(text)

    def energy(s):
        total = 0.0
        for i in range(2):
            R = quat_to_matrix(s.body_quat[i])
            inertia = R @ model.rigid.rot_inertia[model.rigid.rot_slot[i]] @ R.T
            total += 0.5 * model.body_mass[i] * (s.body_vel[i] @ s.body_vel[i]) \
                + 0.5 * s.body_angvel[i] @ inertia @ s.body_angvel[i]
        return total

    assert final.body_vel[0, 0] < 1.0 - 1e-3  # they met
    assert abs(energy(final) - energy(states[0])) <= 1e-12 * energy(states[0]), tilt
    momentum = (model.body_mass[:, None] * (final.body_vel - states[0].body_vel)).sum(axis=0)
    assert np.abs(momentum).max() <= 1e-12, tilt
