"""A body that rests on one point and tips over lands on another one: the landing is an
impact located in the step (default `located` mode), not a penetration found at the step's
end (issue 15, items 1 and 2: "a second corner reaching a wall in the same step is treated
as resting contact").

The class: a box resting on one edge, released from rest, falls onto the face next to
that edge; a capsule resting on one end cap falls over onto the other. Random sizes,
masses, tilts, eps in {0, 0.5, 1}, mu in {0, 0.5, 1}, dt in {10 ms, 1/60 s}, rk4 or
verlet, gravity 9.81 m/s^2, a ground plane.

Before the fix the landing point went on falling while the resting point held the pair's
least gap at ~0, the event search never saw the gap open, and the landing was found at the
step's end up to |v| dt deep: 34 of these 36 cases landed 15-71 mm deep (a fast capsule
went through a 1 cm plate so: `test_located_tunnelling`).

Truths (independent of the code under test: geometry and the energy of a rigid body):
1. the landing (the first contact of a landing-side point: box, the far edge of the
   face; capsule, the upper cap) is either an impact located in the step or, if the
   point came no deeper by the step's end than a resting point can sink in a step
   (the bound of 2. at tau = dt: 3.9 mm at 10 ms, 5.7 mm at 1/60 s), a contact found
   there (depth before the position correction, as the state's contacts record it);
2. a located landing point, tau into its step, is at most 2 tolerance + rest_speed tau +
   g tau^2 / 2 deep: the event is found when the pair's least gap falls to the tolerance
   below the deepest a resting point can be by then (its start gap, within the tolerance
   of the surface after position correction; its start approach, below rest_speed
   = sqrt(2 g tolerance); free fall under g since);
3. the mechanical energy ½ m v² + ½ ω·Iω + m g y never exceeds its start by more than
   m g (2 tolerance) (position correction lifts a body by at most its depth) plus 1e-9
   relative: no impact, friction or correction adds energy (eps <= 1);
4. with eps < 1 the body comes to rest lying on its side: 1.0 s after release its speed
   and spin are below 1e-6 and its landing side is flat on the ground (the two lowest
   points of the box's face, or the capsule's axis, level to 2 tolerances).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest


G = 9.81
TOLERANCE = 1e-3  # m, collision.tolerance (default)
REST_SPEED = math.sqrt(2 * G * TOLERANCE)  # m/s, collision.rest_speed (default)
DURATION = 1.0  # s: every case has landed and (eps < 1) settled by then


def draw(seed):
    """One case: (YAML text, dict of what the checks need)."""
    rng = np.random.default_rng(seed)
    kind = ("box", "capsule")[seed % 2]
    eps = (0.0, 0.5, 1.0)[(seed // 2) % 3]
    mu = (0.0, 0.5, 1.0)[(seed // 6) % 3]
    dt = (0.01, 1 / 60)[(seed // 18) % 2]
    integrator = ("rk4", "verlet")[(seed // 2 + seed // 6 + seed // 18) % 2]
    m = float(rng.uniform(0.5, 5.0))
    if kind == "box":
        a, b, c = (float(x) for x in rng.uniform(0.2, 0.8, 3))  # along x, y, z (m)
        # resting on the edge through corner (-a/2, -b/2) at phi from the face (-b/2 side),
        # centre of mass beyond that edge towards the face: tan(phi) < a / b
        phi = float(rng.uniform(5.0, 0.8 * math.degrees(math.atan(a / b))))
        th = math.radians(phi)
        y0 = a / 2 * math.sin(th) + b / 2 * math.cos(th)
        shape = f"{{type: box, size: [{a!r}, {b!r}, {c!r}]}}"
        pose = f"position: [0, {y0!r}, 0], euler_deg: [0, 0, {phi!r}]"
        inertia = np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 12.0
        # landing side: the corners (a/2, -b/2, +-c/2); the face (-b/2) ends flat
        side = np.array([[a / 2, -b / 2, s * c / 2] for s in (-1.0, 1.0)])
        face = np.array([[sx * a / 2, -b / 2, sz * c / 2] for sx in (-1.0, 1.0)
                         for sz in (-1.0, 1.0)])
        dims = (a, b, c)
    else:
        r = float(rng.uniform(0.05, 0.2))
        length = float(rng.uniform(0.3, 1.0))  # of the cylinder, along local y
        beta = float(rng.uniform(10.0, 60.0))  # axis above the horizontal (deg)
        bt = math.radians(beta)
        # euler z = 90 - beta turns local y to (-cos beta, sin beta): the -y cap is lowest
        y0 = length / 2 * math.sin(bt) + r
        shape = f"{{type: capsule, radius: {r!r}, length: {length!r}}}"
        pose = f"position: [0, {y0!r}, 0], euler_deg: [0, 0, {90.0 - beta!r}]"
        vc, vs = math.pi * r * r * length, 4.0 / 3.0 * math.pi * r ** 3
        mc, ms = m * vc / (vc + vs), m * vs / (vc + vs)
        axial = 0.5 * mc * r * r + 0.4 * ms * r * r
        perp = mc * (length ** 2 / 12.0 + r * r / 4.0) + \
            ms * (0.4 * r * r + length ** 2 / 4.0 + 3.0 * length * r / 8.0)
        inertia = np.diag([perp, axial, perp])
        side = np.array([[0.0, length / 2, 0.0]])  # the upper cap's centre
        face = np.array([[0.0, s * length / 2, 0.0] for s in (-1.0, 1.0)])  # cap centres
        dims = (r, length)
    text = f"""
vrsim: 1
duration: {DURATION}
frame_rate: {1 / dt!r}
dt: {dt!r}
integrator: {integrator}
gravity: [0, -{G}, 0]
collision: {{}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}},
     material: {{restitution: {eps}, friction: {mu}}}}}
  - {{name: body, mass: {m!r}, {pose}, shape: {shape},
     material: {{restitution: {eps}, friction: {mu}}}}}
"""
    return text, dict(kind=kind, eps=eps, mu=mu, dt=dt, m=m, inertia=inertia, side=side,
                      face=face, dims=dims)


def lowest_of(case, R, centre, local):
    """World heights (n,) m of the lowest surface points at the body-frame points `local`
    (box corners; capsule cap centres less the radius)."""
    y = centre[1] + (local @ R.T)[:, 1]
    return y - case["dims"][0] if case["kind"] == "capsule" else y


def energy(case, s):
    v, w, R = s.body_vel[1], s.body_angvel[1], s.rot_matrix[0]
    return 0.5 * case["m"] * float(v @ v) + 0.5 * float(w @ (R @ case["inertia"] @ R.T) @ w) \
        + case["m"] * G * float(s.body_pos[1, 1])


# kind x eps x mu x dt = 36 combinations, each once; rk4 and verlet alternate among them
CASES = list(range(36))


@functools.lru_cache(maxsize=None)
def run(seed):
    """(case, sampled states, final state), the run's energy guard off: a scene of resting
    contact that gains energy is stopped by it (`test_...gains_no_energy` is about that),
    and the other checks are about the landing."""
    import dataclasses

    from vrsim_cli.loop import run as run_scene
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene

    from conftest import Steps

    text, case = draw(seed)
    model = compile_model(parse_scene(text))
    model = dataclasses.replace(model, rigid=dataclasses.replace(model.rigid,
                                                                 energy_guard=False))
    rec = Steps()
    final = run_scene(model, make_state(model), rec).state
    return case, rec.states, final


@pytest.mark.parametrize("seed", CASES)
def test_a_tipping_body_lands_in_a_located_impact(seed):
    """Checks 1, 2 and 4 of the module docstring."""
    case, states, final = run(seed)
    landing = None
    for s in states[1:]:
        c = s.contacts
        if c is None:
            continue
        # a landing-side point lies on the far side of the body from the resting one:
        # body frame +x (box) or +y (capsule); the body frame of the step's end is near
        # enough that of the impact for that
        here = (c.point - s.body_pos[1]) @ s.rot_matrix[0]
        side = here[:, 0 if case["kind"] == "box" else 1] > 0.0
        located = np.flatnonzero(side & ~np.isnan(c.toi))
        at_end = np.flatnonzero(side & np.isnan(c.toi))  # depths before the correction
        if len(located):
            tau = float(c.toi[located].min())
            depth = float(c.depth[side & (c.toi == tau)].max())
            landing = ("located", s.t, depth)
            # (the root is found to 1e-13 of the step: 1e-9 relative is its round-off)
            bound = 2 * TOLERANCE + REST_SPEED * tau + 0.5 * G * tau * tau
            assert depth <= bound * (1 + 1e-9), \
                f"landed {depth:.3g} m deep {tau:.4g} s into the step (bound {bound:.3g} m)"
            break
        if len(at_end):
            depth = float(c.depth[at_end].max())
            landing = ("at the step's end", s.t, depth)
            dt = case["dt"]
            bound = 2 * TOLERANCE + REST_SPEED * dt + 0.5 * G * dt * dt
            assert depth <= bound * (1 + 1e-9), \
                f"landed unlocated {depth:.3g} m deep in the step to t = {s.t:.4f} s"
            break
    assert landing is not None, "the body never landed"
    if case["eps"] < 1.0:
        assert np.abs(final.body_vel[1]).max() <= 1e-6
        assert np.abs(final.body_angvel[1]).max() <= 1e-6
        low = lowest_of(case, final.rot_matrix[0], final.body_pos[1], case["face"])
        assert np.ptp(low) <= 2 * TOLERANCE and np.abs(low).max() <= 2 * TOLERANCE


@pytest.mark.parametrize("seed", CASES)
def test_a_tipping_body_gains_no_energy(seed):
    """Check 3 of the module docstring."""
    case, states, _ = run(seed)
    E0 = energy(case, states[0])
    bound = case["m"] * G * 2 * TOLERANCE + 1e-9 * abs(E0)
    gain = max(energy(case, s) - E0 for s in states)
    assert gain <= bound, f"energy rose by {gain:.3g} J (bound {bound:.3g} J)"


# rk4 runs that the energy guard stopped while the body pivots on its resting edge or cap
# (seeds 0, 1, 4, 5, 20; strict xfails until 2026-12-04). Cause, measured (seed 0: +0.02 J,
# 0.3 % of the energy, over the 0.2 s of tipping): resting contact is solved at the step's
# end. In the step's free flight the resting point sinks by a_n dt^2 / 2; the impulse then
# takes (a_n dt)^2 m_eff / 2 of kinetic energy away, and position correction lifts the body
# by the depth, adding m g a_n dt^2 / 2 of potential energy: a net gain of
# a_n dt^2 (m g - m_eff a_n) / 2 per step wherever the contact's effective mass m_eff is
# below m, as it is for a pivot. That is first order in dt whatever the integrator; the
# guard's bound assumed rk4's fourth order, so a smaller dt tripped it sooner (7.6 times
# the bound at 1/240 s). With contacts the guard now assumes order 1
# (`motion.guard_order`); the gain itself stays (docs/collision-response.md, Known
# limits; truth 3 above bounds it).
@pytest.mark.parametrize("seed", CASES)
def test_a_tipping_body_is_not_stopped_by_the_energy_guard(seed):
    """As a user runs it (the energy guard on): the run ends without a SimulationError."""
    from conftest import simulate

    simulate(draw(seed)[0])


def test_a_smaller_dt_does_not_trip_the_guard_on_a_pivot():
    """The guard's hint says "try a smaller dt": on a tipping box with rk4 that made it
    trip sooner (order-4 bound against a first-order gain). Seed 0 (a box, rk4, 10 ms,
    stopped before) at 1/240 s runs through and keeps truth 3's energy bound."""
    from conftest import simulate

    text, case = draw(0)
    dt = 1.0 / 240.0
    text = text.replace(f"dt: {case['dt']!r}", f"dt: {dt!r}").replace(
        f"frame_rate: {1 / case['dt']!r}", f"frame_rate: {1 / dt!r}")
    assert f"dt: {dt!r}" in text
    _, states, _ = simulate(text)
    E0 = energy(case, states[0])
    gain = max(energy(case, s) - E0 for s in states)
    assert gain <= case["m"] * G * 2 * TOLERANCE + 1e-9 * abs(E0)


def test_the_energy_guard_names_the_pivot_limit_in_scenes_with_contacts():
    """Until the pivot's energy gain is fixed (above), a guard that trips in a scene with
    contacts says so, and that its bound is first order there, instead of only blaming
    the integrator."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.stages.dynamics.rigid import energy_message

    text = draw(0)[0]
    with_contacts = compile_model(parse_scene(text))
    without = compile_model(parse_scene(text.replace("collision: {}\n", "")))
    assert "pivoting on a resting edge" in energy_message(with_contacts, 1e-3, 1e-4)
    assert "pivoting" not in energy_message(without, 1e-3, 1e-4)
    assert "pivoting" not in energy_message(with_contacts, -1e-3, 1e-4)  # a loss
