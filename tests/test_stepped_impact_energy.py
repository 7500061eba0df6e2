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
# with turning locked). These two still gain a little (3e-7 to 7e-4 J) after landing,
# eps 0. Traced (round 6), not fixed: the worst, body 2 of the mu 0.3 scene, spins at
# ~30 rad/s on one end cap and nutates (its axis's vertical component 0.33-0.99); its cap
# stays 0.2-2.5 mm below the plane for 20 steps; the two gaining steps (+7.4e-4 J at
# t = 0.58 and 0.59 s) are the two where that depth shrinks (2.55 -> 2.44 -> 2.25 mm),
# i.e. where the body is moved out of a penetration built up over earlier steps. A
# likely cause (not confirmed by a fix): the solve predicts a contact's gap to first
# order in the step's turn, and at 0.3 rad per step with the cap ~0.2 m from the centre
# of mass the second-order sinking (|w|^2 r dt^2 / 2) is millimetres per step, which
# the position pass takes out over later steps. The bound of this test stays.
KNOWN = {("capsule", 0.0, 0.0, 0), ("capsule", 0.0, 0.3, 0)}
PARAMS = [pytest.param(*p, marks=[pytest.mark.xfail(
    strict=True, reason="a capsule spinning on its end cap stays up to 2.5 mm deep (its "
    "gap likely predicted to first order in a 0.3 rad turn per step); the steps that "
    "move it out add up to 7e-4 J")]
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
