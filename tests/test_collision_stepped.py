"""Stepped impacts (`collision.impacts: stepped`, kernels/stepped.py): speculative
contacts, impacts at the step's start, sequential impulses, one compiled call per step.
Checked against closed forms where one contact decides, conservation laws, and the sanity
of a pile of spheres in a closed box (what `vrsim bench`'s spheres problem runs). The old
numpy solver (projected Jacobi with mass splitting) is kept as tests/reference_jacobi.py:
its one-contact closed form is checked here, tests/test_stepped.py compares the kernel."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import parse_scene
import reference_jacobi as jacobi
from vrsim_cli.stages.collision.solver import Bodies

from conftest import Steps, simulate

G = 9.81


@settings(max_examples=40, deadline=None)
@given(m1=st.floats(0.1, 10.0), m2=st.floats(0.1, 10.0), v1=st.floats(0.1, 5.0),
       v2=st.floats(-5.0, 0.0), eps=st.floats(0.0, 1.0))
def test_one_head_on_contact_is_newtons_law_of_restitution(m1, m2, v1, v2, eps):
    """Two spheres meeting head on along x: one contact, so one Jacobi iteration gives the
    closed form of a 1D impact, v' = v_cm -+ eps m_other (v1 - v2) / (m1 + m2), and
    momentum is conserved; more iterations change nothing (round-off, 1e-12 relative)."""
    bodies = Bodies(np.array([1 / m1, 1 / m2]), np.zeros((2, 3, 3)),
                    np.array([[v1, 0.0, 0.0], [v2, 0.0, 0.0]]), np.zeros((2, 3)),
                    np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0]]))
    system = jacobi.System(bodies, np.array([0]), np.array([1]), np.array([[0.1, 0, 0]]),
                           np.array([[1.0, 0.0, 0.0]]), np.array([0.0]))
    jacobi.solve(bodies, system, np.array([eps]), np.array([0.0]), 0.01, 0.0, 5)
    vcm = (m1 * v1 + m2 * v2) / (m1 + m2)
    scale = max(abs(v1), abs(v2), 1.0)
    assert abs(bodies.vel[0, 0] - (vcm - eps * m2 * (v1 - v2) / (m1 + m2))) <= 1e-12 * scale
    assert abs(bodies.vel[1, 0] - (vcm + eps * m1 * (v1 - v2) / (m1 + m2))) <= 1e-12 * scale
    assert abs(m1 * bodies.vel[0, 0] + m2 * bodies.vel[1, 0] - (m1 * v1 + m2 * v2)) <= \
        1e-12 * scale * (m1 + m2)


def ball_scene(eps, impacts="stepped", friction=None, velocity=(0, 0, 0), y=1.1):
    material = f"{{restitution: {eps}" + (f", friction: {friction}}}" if friction is not None
                                          else "}")
    return f"""
vrsim: 1
duration: 1.0
frame_rate: 100
dt: 0.01
integrator: symplectic-euler
collision: {{impacts: {impacts}}}
output: {{rate: 100}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}, material: {material}}}
  - name: ball
    mass: 1
    position: [0, {y}, 0]
    velocity: {list(velocity)}
    shape: {{type: sphere, radius: 0.1}}
    material: {material}
"""


@pytest.mark.parametrize("eps", [0.0, 0.5, 0.8, 1.0])
def test_a_ball_turns_at_eps_times_its_speed_at_the_step_start(eps):
    """Stepped impacts are speculative (Box2D v3): the step whose free flight would take
    the ball into the ground turns it at the step's start, with Newton's restitution on
    its approach velocity v0 there; symplectic Euler then adds the step's gravity, so its
    vertical velocity after that step is exactly -eps v0 - g dt (one contact with a static
    body: round-off, 1e-12); eps = 0 lands it on the ground (the speculative bound closes
    the gap exactly), at rest from the next step on; it never goes below the ground (bottom >= -1e-12 m)."""
    model = compile_model(parse_scene(ball_scene(eps)))
    rec = Steps()
    run(model, make_state(model), rec)
    states = rec.states
    from vrsim_cli.stages.dynamics import motion as dynamics

    # the first step whose free flight would take the ball into the ground
    k = next(i for i in range(1, len(states))
             if dynamics.step(model, states[i - 1]).body_pos[1, 1] < 0.1)
    v0 = states[k - 1].body_vel[1, 1]
    assert v0 < -1.0
    if eps > 0.0:
        assert abs(states[k].body_vel[1, 1] - (-eps * v0 - G * model.dt)) <= 1e-12
    else:  # plastic: it ends that step on the ground and stays there, at rest
        for s in states[k:]:
            assert abs(s.body_pos[1, 1] - 0.1) <= 1e-12
        for s in states[k + 1:]:
            assert abs(s.body_vel[1, 1]) <= 1e-12
    assert min(s.body_pos[1, 1] for s in states) >= 0.1 - 1e-12


def test_sliding_turns_into_rolling_at_five_sevenths():
    """As for located impacts: every contact impulse acts at the contact point, so the
    angular momentum about the contact line is conserved and the ball ends rolling at
    v = 5/7 v0 (round-off, 1e-12 m/s) with v = omega r."""
    v0, r = 3.0, 0.1
    _, _, final = simulate(ball_scene(0.0, friction=0.3, velocity=(v0, 0, 0), y=r))
    assert abs(final.body_vel[1, 0] - 5 / 7 * v0) <= 1e-12
    assert abs(final.body_angvel[1, 2] * r + 5 / 7 * v0) <= 1e-12


def box_of_spheres(n: int, duration: float, impacts: str = "stepped") -> str:
    """n spheres (r = 5 cm, 0.1 kg, eps 0.5, mu 0.5) on a jittered lattice with random
    velocities, in a closed box of six planes (the bench's spheres problem, small)."""
    rng = np.random.default_rng(7)
    side = int(np.ceil(n ** (1 / 3)))
    half = 0.5 * (side * 0.12 + 0.1)
    walls = [("floor", [0, 0, 0], [0, 1, 0]), ("lid", [0, 4 * half, 0], [0, -1, 0]),
             ("w0", [-half, 0, 0], [1, 0, 0]), ("w1", [half, 0, 0], [-1, 0, 0]),
             ("w2", [0, 0, -half], [0, 0, 1]), ("w3", [0, 0, half], [0, 0, -1])]
    lines = [f"vrsim: 1\nduration: {duration}\nframe_rate: 100\ndt: 0.01\n"
             f"integrator: symplectic-euler\ncollision: {{impacts: {impacts}}}\nbodies:"]
    lines += [f"  - {{name: {name}, type: static, position: {p}, shape: {{type: plane, "
              f"normal: {nrm}}}}}" for name, p, nrm in walls]
    cells = [(i, j, k) for j in range(side) for i in range(side) for k in range(side)][:n]
    for s, (i, j, k) in enumerate(cells):
        p = [-half + 0.11 + 0.12 * i, 0.11 + 0.12 * j, -half + 0.11 + 0.12 * k]
        v = rng.normal(size=3).tolist()
        lines.append(f"  - {{name: s{s}, mass: 0.1, position: {p}, velocity: {v}, shape: "
                     f"{{type: sphere, radius: 0.05}}, material: {{restitution: 0.5, "
                     f"friction: 0.5}}}}")
    return "\n".join(lines) + "\n", half


def test_a_box_of_spheres_settles_without_escapes_or_energy_gain():
    """64 spheres thrown about in a closed box for 3 s:
    - none escapes: every centre stays inside every wall at every step;
    - penetration is bounded by what a post-step method lets in before it corrects: one
      step's travel at the fastest initial speed (max |v0| dt), and at rest (the last
      second) by 5 % of the radius, 2.5 mm: gravity alone sinks a resting sphere by
      g dt^2 = 1 mm per step, and the 16 position passes leave about 1.2 mm (8 left up
      to 4 mm);
    - the mechanical energy never exceeds the initial (restitution 0.5 and friction only
      take energy; 1 % allowance for the step's first-order gravity work);
    - the pile comes to rest (all speeds < 0.05 m/s)."""
    text, half = box_of_spheres(64, 3.0)
    model, states, final = simulate(text)
    assert model.response.impacts == "stepped"
    dyn = np.flatnonzero(model.body_type == 0)
    m = model.body_mass[dyn]

    def energy(s):
        return float((0.5 * m * (s.body_vel[dyn] ** 2).sum(1)).sum() +
                     (m * G * s.body_pos[dyn, 1]).sum() +
                     sum(0.5 * L @ L / (0.4 * 0.1 * 0.05 ** 2) for L in s.rot_angmom))

    e0 = energy(states[0])
    assert max(energy(s) for s in states) <= 1.01 * e0
    r = 0.05
    step_travel = np.linalg.norm(states[0].body_vel[dyn], axis=1).max() * model.dt
    for s in states:
        p = s.body_pos[dyn]
        assert (np.abs(p[:, [0, 2]]) < half).all() and (p[:, 1] > 0.0).all()
        assert (p[:, 1] < 4 * half).all()
        wall_gap = np.concatenate([half - np.abs(p[:, [0, 2]]).ravel(), p[:, 1],
                                   4 * half - p[:, 1]])
        assert r - wall_gap.min() <= step_travel
    for s in states:
        if s.t >= 2.0:  # at rest from 2 s on
            rest_gap = np.concatenate([half - np.abs(s.body_pos[dyn][:, [0, 2]]).ravel(),
                                       s.body_pos[dyn, 1]])
            assert r - rest_gap.min() <= 0.05 * r
    assert np.linalg.norm(final.body_vel[dyn], axis=1).max() < 0.05


@pytest.mark.parametrize("n", [1, 8, 32, 33, 64])
def test_auto_is_the_compiled_step_for_any_number_of_bodies(n):
    """No cliff: `auto` gives every scene the compiled step (it located impacts up to 32
    bodies until 2026-12-07); `located` set in the scene is kept."""
    text, _ = box_of_spheres(n, 0.1, impacts="auto")
    assert compile_model(parse_scene(text)).response.impacts == "stepped"
    located, _ = box_of_spheres(n, 0.1, impacts="located")
    assert compile_model(parse_scene(located)).response.impacts == "located"


def test_stepped_runs_are_bit_identical():
    text, _ = box_of_spheres(40, 0.5)
    a = simulate(text)[2]
    b = simulate(text)[2]
    assert a.body_pos.tobytes() == b.body_pos.tobytes()
    assert a.body_vel.tobytes() == b.body_vel.tobytes()


def test_validate_says_which_impacts_a_scene_gets(invoke, tmp_path):
    many, _ = box_of_spheres(33, 0.1, impacts="auto")
    path = tmp_path / "box.yaml"
    path.write_text(many)
    result = invoke("validate", path)
    assert result.exit_code == 0
    assert result.stdout.rstrip().endswith(
        "symplectic-euler, stepped impacts (auto: the compiled contact step, for every "
        "scene))")
    path.write_text(box_of_spheres(3, 0.1, impacts="stepped")[0])
    result = invoke("validate", path)
    assert result.stdout.rstrip().endswith("stepped impacts (set in the scene))")


def test_a_ball_ending_a_step_just_above_the_ground_bounces_its_full_speed():
    """A ball arriving at 2 m/s whose first step ends 0.5 mm above the ground (inside the
    1 mm tolerance): that step is free flight (it does not reach the ground), and the next
    turns it with its full speed, -eps v1 - g dt (round-off, 1e-12), instead of being
    slowed to gap/dt first and bouncing that (found by review)."""
    eps, dt, v0 = 0.8, 0.01, -2.0
    v1 = v0 - G * dt  # symplectic Euler: the velocity first
    y0 = 0.1 + 0.0005 - v1 * dt  # so the first step ends 0.5 mm above the ground
    model = compile_model(parse_scene(ball_scene(eps, velocity=(0, v0, 0), y=y0)))
    rec = Steps()
    run(model, make_state(model), rec)
    first, second = rec.states[1], rec.states[2]
    assert abs(first.body_vel[1, 1] - v1) <= 1e-12
    assert abs(first.body_pos[1, 1] - (0.1 + 0.0005)) <= 1e-12
    assert abs(second.body_vel[1, 1] - (-eps * v1 - G * dt)) <= 1e-12


@pytest.mark.parametrize("frame_rate", [60, 30])
def test_a_resting_ball_stays_at_rest_when_g_dt_exceeds_rest_speed(frame_rate):
    """At dt = 1/60 and 1/30 s a resting contact comes in at g dt = 0.16 and 0.33 m/s,
    above the default rest_speed (0.14 m/s): it must not bounce (the bounce speed is at
    least 2 g dt), so the ball's vertical velocity after every step is 0 to round-off
    and it stays on the ground (found by review)."""
    text = ball_scene(0.8, y=0.1).replace("frame_rate: 100\ndt: 0.01",
                                          f"frame_rate: {frame_rate}\ndt: {1 / frame_rate!r}")
    text = text.replace("output: {rate: 100}", f"output: {{rate: {frame_rate}}}")
    model, states, _ = simulate(text)
    assert model.dt == 1 / frame_rate
    assert max(abs(s.body_vel[1, 1]) for s in states) <= 1e-12
    assert max(abs(s.body_pos[1, 1] - 0.1) for s in states) <= 1e-12


def test_emitted_particles_count_for_auto():
    text = """
vrsim: 1
duration: 0.1
collision: {}
emitters: [{name: drop, position: [0, 0.5, 0], speed: 2, spread_deg: 30, count: 40,
            rate: 400, mass: 0.001, radius: 0.015, seed: 7}]
bodies:
  - {name: ground, type: static, shape: {type: plane, normal: [0, 1, 0]}}
"""
    assert compile_model(parse_scene(text)).response.impacts == "stepped"
