"""Elastic frictionless impacts in the compiled step never gain energy (issue 48/49).

Truth: without gravity, friction or damping, impacts with restitution 1 conserve the
kinetic energy sum(1/2 m v^2 + 1/2 I |w|^2); cubes and spheres have isotropic inertia
(I = m s^2 / 6, 2/5 m r^2), so between impacts w is constant and every integrator moves
them exactly: whatever the energy does is the contact response's doing. The energy is
computed here from the written states and the masses and sizes the test drew.

Three cubes (or two cubes and a sphere) in a closed box of six elastic planes,
`impacts: stepped`, random sizes, masses, velocities and spins, dt 1/60 or 1/120 s,
verlet or rk4, 20 s: no sample's energy exceeds the first's by more than 1e-9 relative.

Why it failed: the frictionless normal impulses of one impact, a linear complementarity
problem, were solved by Gauss-Seidel sweeps that stop when they make slow progress; two
corners of one edge have nearly parallel rows, and the sweeps stopped up to 2.5e-3 of the
scene's energy off, gains included (4 of 66 scenes drawn for this gained 3e-4 .. 1.5e-3;
of the 40 here, one gained 1.3e-3 on d504251).
Impacts of 2-4 frictionless points are now solved exactly
(`kernels.stepped._exact_normals`).

Not asserted, because it does not hold yet: that the energy is kept. An impact that
would turn a cube by more than pi/4 / sqrt(3) rad in the step is solved with turning
locked (the bodies meet as particles: docs/collision-response.md), which loses the
energy of the spin the impact should have made: about a third of these scenes lose 3-28 %
of their energy over 20 s that way (measured: every loss traced was such a locked impact).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import simulate

HALF = 1.0  # m: the box's half width
WALLS = [([1, 0, 0], [-HALF, 0, 0]), ([-1, 0, 0], [HALF, 0, 0]), ([0, 1, 0], [0, -HALF, 0]),
         ([0, -1, 0], [0, HALF, 0]), ([0, 0, 1], [0, 0, -HALF]), ([0, 0, -1], [0, 0, HALF])]


def closed_box(seed: int):
    rng = np.random.default_rng([48, 5, seed])
    dt = float(rng.choice([1 / 60, 1 / 120]))
    integrator = str(rng.choice(["verlet", "rk4"]))
    lines = [f"  - {{name: w{i}, type: static, position: {p}, shape: {{type: plane, "
             f"normal: {n}}}, material: {{restitution: 1.0, friction: 0.0}}}}"
             for i, (n, p) in enumerate(WALLS)]
    props, centres = [], []
    while len(props) < 3:
        s = float(rng.uniform(0.1, 0.35))
        c = rng.uniform(-HALF + s, HALF - s, 3)
        if any(np.linalg.norm(c - o) < s + so + 0.05 for o, so in centres):
            continue
        centres.append((c, s))
        mass = float(rng.uniform(0.5, 3.0))
        sphere = seed % 2 == 1 and len(props) == 2
        if sphere:
            shape, inertia = f"{{type: sphere, radius: {s / 2!r}}}", 0.4 * mass * (s / 2) ** 2
        else:
            shape, inertia = f"{{type: box, size: [{s!r}, {s!r}, {s!r}]}}", mass * s * s / 6
        v = rng.normal(size=3) * float(rng.uniform(0.5, 3.0))
        w = rng.normal(size=3) * float(rng.uniform(0.0, 8.0))
        lines.append(f"  - {{name: b{len(props)}, mass: {mass!r}, position: {c.tolist()}, "
                     f"velocity: {v.tolist()}, angular_velocity: {w.tolist()}, "
                     f"shape: {shape}, material: {{restitution: 1.0, friction: 0.0}}}}")
        props.append((mass, inertia))
    text = (f"vrsim: 1\nduration: 20.0\nframe_rate: 10\ndt: {dt!r}\n"
            f"integrator: {integrator}\ngravity: [0, 0, 0]\ncollision: {{impacts: stepped}}\n"
            "bodies:\n" + "\n".join(lines) + "\n")
    return text, props


def energy(state, props) -> float:
    """J: the kinetic energy of the moving bodies (rows 6 on, after the walls)."""
    return sum(0.5 * m * float(state.body_vel[6 + k] @ state.body_vel[6 + k])
               + 0.5 * i * float(state.body_angvel[6 + k] @ state.body_angvel[6 + k])
               for k, (m, i) in enumerate(props))


@pytest.mark.parametrize("seed", range(40))
def test_elastic_cubes_in_a_closed_box_never_gain_energy(seed):
    text, props = closed_box(seed)
    _, states, _ = simulate(text)
    e0 = energy(states[0], props)
    gain = max(energy(s, props) - e0 for s in states) / e0
    assert states[-1].t == pytest.approx(20.0)
    assert gain <= 1e-9, gain
