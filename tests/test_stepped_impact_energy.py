"""No stepped-mode landing gains energy (issue 15, item 4): a seeded property test.

`collision.impacts: stepped` solves every contact at the step's start (kernels/stepped.py:
`impact_pair`, Newton's restitution per point with Coulomb friction, one Gauss-Seidel
solve per pair). With friction, Newton's law at several points (or at one point whose
slip reverses) can add kinetic energy (Kane's paradox; Stronge 2000, *Impact mechanics*):
a spinning box landing on a plane with eps = 1 and mu > 0 gained 0.6 J, and the energy
guard stopped the run.

Cases: boxes, capsules and spheres (1 kg, 0.05-0.5 m) dropped at 1-10 m/s onto a static
ground plane, random orientation, spinning at 1-50 rad/s about a random axis, sideways
speed up to 5 m/s, eps in {0, 0.5, 1}, mu in {0, 0.3, 0.8}; symplectic Euler (whose free
flight under gravity loses exactly m g^2 dt^2 / 2 per step) with the exact torque-free
flow (no energy change in free rotation), dt 10 ms, 0.6 s.

Truth, computed here from the body's own inertia (`test_located_tunnelling.inertia`):
E = 1/2 m |v|^2 + 1/2 w.(R I R^T) w + m g z at every step's end. No step may raise it by
more than round-off: 1e-9 of the body's energy scale (its E above the ground plus 1 J,
~1e4 ulps of its terms). A step whose contact impulses do not add kinetic energy does not
add total energy with symplectic Euler (kernels/stepped.py's docstring); the position
pass moves a body out of the plane (raising m g z) only by what it sank within a step,
which the same step's fall lost.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from conftest import simulate
from test_located_tunnelling import inertia
from test_stepped import SPACING, _rot, _unit_quat, random_shape

DT = 0.01
G = 9.81
REL = 1e-9
FULL = os.environ.get("VRSIM_SLOW_TESTS") == "1"
PER_SCENE = 6


def landing_scene(kind, eps, mu, seed):
    """(scene text, cases) of PER_SCENE bodies of `kind` landing on one ground plane."""
    rng = np.random.default_rng(seed)
    lines = [f"vrsim: 1\nduration: 0.6\nframe_rate: {1 / DT}\ndt: {DT}\n"
             f"integrator: symplectic-euler\ngravity: [0, 0, {-G}]\n"
             f"collision: {{impacts: stepped}}\nrotation: {{free_flow: exact}}\nbodies:",
             f"  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 0, 1]}}, "
             f"material: {{restitution: {eps}, friction: {mu}}}}}"]
    cases = []
    for c in range(PER_SCENE):
        size, shape = random_shape(rng, kind)
        if kind == "box":
            size = [0.5 * s + 0.05 for s in size]  # 0.06-0.3 m
            shape = f"{{type: box, size: {size!r}}}"
        q = _unit_quat(rng)
        reach = float(np.linalg.norm(size)) + 0.1
        pos = [SPACING * c, 0.0, reach + float(rng.uniform(0.0, 0.5))]
        down = float(rng.uniform(1.0, 10.0))
        side = rng.normal(size=2) * rng.uniform(0.0, 5.0) / np.sqrt(2.0)
        vel = [float(side[0]), float(side[1]), -down]
        axis = rng.normal(size=3)
        omega = axis / np.linalg.norm(axis) * float(np.exp(rng.uniform(0.0, np.log(50.0))))
        lines.append(f"  - {{name: b{c}, mass: 1, position: {pos!r}, orientation: "
                     f"{q.tolist()!r}, velocity: {vel!r}, angular_velocity: "
                     f"{omega.tolist()!r}, shape: {shape}, material: {{restitution: {eps}, "
                     f"friction: {mu}}}}}")
        cases.append(dict(body=c + 1, kind=kind, size=size))
    return "\n".join(lines) + "\n", cases


def energy(case, state) -> float:
    """J: kinetic (the body's own inertia) plus potential m g z of the 1 kg body."""
    b = case["body"]
    R = _rot(state.body_quat[b])
    w, v = state.body_angvel[b], state.body_vel[b]
    I = R @ inertia(case["kind"], case["size"]) @ R.T
    return 0.5 * float(v @ v) + 0.5 * float(w @ I @ w) + G * float(state.body_pos[b, 2])


SCENES = [(kind, eps, mu, k) for kind in ("box", "capsule", "sphere")
          for eps in (0.0, 0.5, 1.0) for mu in (0.0, 0.3, 0.8) for k in range(3 if FULL else 1)]
# Known failures, strict (the day they pass, the mark must go): on main 15 of the 27
# scenes failed (gains up to 107 J: friction with Newton's law per point, and impacts
# with turning locked). Two capsule scenes with eps 0 still gained 3e-7 to 7e-4 J while
# spinning on an end cap: the position pass measured the cap's end depth at its witness
# point carried with the body, which a turn theta lifts off the surface by
# r (1 - cos theta), so the cap stayed up to 2.5 mm deep and later steps pushed it out.
# Fixed (the cap's centre is carried: tests/test_stepped_separations.py); mu 0 passes.
# Left, traced: body 2 of the mu 0.3 scene spins at 33 rad/s and rocks on its cap (its
# axis's vertical component 0.6 -> 0.32 -> 0.6 over 0.1 s) at no depth, and gains
# 4e-4 to 1.5e-3 J per step (t = 0.25-0.34 s). Hypothesis (from the trace, not
# confirmed): the velocity solve keeps the cap's *linearised* end gap, but in the
# step's turn (up to 0.33 rad) the cap's centre also moves to second order, and the
# position pass lifts that out against gravity each step (1.5e-3 J is a lift of
# 0.15 mm of the 1 kg body). Tried and reverted: adding that second-order sinking
# (exp(dt w) r - r - dt w x r along n, with the kicked w) to the solve's target made
# three scenes gain (up to 3.6e-3 J) instead of one.
KNOWN = {("capsule", 0.0, 0.3, 0)}
PARAMS = [pytest.param(*p, marks=[pytest.mark.xfail(
    strict=True, reason="a capsule spinning at 33 rad/s and rocking on its end cap gains "
    "up to 1.5e-3 J per step; likely (not confirmed) the position pass lifting out what "
    "the step's 0.33 rad turn sinks it beyond the solve's first order")]
    if p in KNOWN else []) for p in SCENES]


@pytest.mark.parametrize("kind, eps, mu, k", PARAMS)
def test_no_stepped_landing_gains_energy(kind, eps, mu, k):
    seed = 9000 + 1000 * ("box", "capsule", "sphere").index(kind) + 100 * int(2 * eps) + \
        10 * int(10 * mu) + k
    text, cases = landing_scene(kind, eps, mu, seed)
    model, states, _ = simulate(text)
    assert model.response.impacts == "stepped"
    gains = []
    for case in cases:
        e = np.array([energy(case, s) for s in states])
        scale = float(e[0] - 0.0) + 1.0
        step = np.diff(e)
        worst = int(np.argmax(step))
        if step[worst] > REL * scale:
            gains.append((case["body"], round(states[worst + 1].t, 3), float(step[worst])))
    assert not gains, f"{len(gains)} of {len(cases)} gained energy (body, t, J): {gains}"
