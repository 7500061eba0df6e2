"""Bodies at rest in a pile report zero velocity (issue 48 (d)), a class of piles.

Truth: a pile of boxes on a floor, dropped with restitution 0, comes to rest (static
equilibrium with friction): each body's velocity and spin are then zero. Nothing in a
resting pile drives motion; a solver that lets a still body report a velocity, or keeps
one rocking, is wrong however small the pile looks. The theta = 1/2 step
(docs/collision-response.md) first made still boxes report an alternating 4 mm/s for
ever (a held pair's mean slip; now `end_stop`) and kept a box of 4 rocking at ~1 cm/s
for 11 s (a box lying across another's face with one contact point, at one rim; now
box_box's face points): this class catches both.

The class: 24 random piles of 3-6 boxes (random sizes 5-15 cm, masses 0.2-2 kg, random
orientations, dropped 1 cm apart onto each other), friction 0.3-1.0, the integrators
that move positions differently in contact (symplectic-euler, verlet, rk4) at dt 1/60,
1/120 and 1/240 s; and a pile of 20 boxes (the issue's pile) with each of the three.
All in the compiled step (`impacts: stepped`, the default since 2026-12-07; located
impacts are ~20 times slower here).

Tolerance: the fastest point of any body, |v| + |w| r (r the body's half diagonal),
at most 1e-9 m/s over the last 0.5 s of 6 s (8 s for 20 boxes). Velocities of a body at
rest are round-off of the solves, measured at ~1e-16 m/s in these piles; 1e-9 is the
issue's scale. A pile that settles later than that is not at rest when a user looks.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import simulate

SPEED = 1e-9  # m/s


def _pile(seed: int, n: int, integrator: str, dt: float, duration: float):
    rng = np.random.default_rng([48, 11, seed])
    mu = float(rng.uniform(0.3, 1.0))
    lines = [f"  - {{name: floor, type: static, shape: {{type: plane, normal: [0, 1, 0]}}, "
             f"material: {{friction: {mu!r}, restitution: 0}}}}"]
    radii, y = [], 0.0
    for i in range(n):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        m = float(rng.uniform(0.2, 2.0))
        size = rng.uniform(0.05, 0.15, 3)
        r = float(0.5 * np.linalg.norm(size))
        y += r + 0.01
        p = [float(rng.uniform(-0.05, 0.05)), y, float(rng.uniform(-0.05, 0.05))]
        y += r
        radii.append(r)
        lines.append(f"  - {{name: b{i}, mass: {m!r}, position: {p}, "
                     f"orientation: {[float(x) for x in q]}, "
                     f"shape: {{type: box, size: {[float(x) for x in size]}}}, "
                     f"material: {{friction: {mu!r}, restitution: 0}}}}")
    src = (f"vrsim: 1\nduration: {duration!r}\nframe_rate: 10\ndt: {dt!r}\n"
           f"integrator: {integrator}\ngravity: [0, -9.81, 0]\ncollision: {{impacts: stepped}}\n"
           "bodies:\n" + "\n".join(lines) + "\n")
    _, states, _ = simulate(src)
    r = np.array(radii)
    fastest = 0.0
    for s in states[-5:]:  # the last 0.5 s (samples at 10 Hz)
        v = np.linalg.norm(s.body_vel[1:], axis=1) + np.linalg.norm(s.body_angvel[1:], axis=1) * r
        fastest = max(fastest, float(v.max()))
    return fastest


@pytest.mark.parametrize("seed", range(24))
def test_a_pile_of_boxes_comes_to_rest(seed):
    integrator = ("verlet", "rk4", "symplectic-euler")[seed % 3]
    dt = (1 / 60, 1 / 120, 1 / 240)[seed // 3 % 3]
    n = int(np.random.default_rng([48, 12, seed]).integers(3, 7))
    fastest = _pile(seed, n, integrator, dt, 6.0)
    assert fastest <= SPEED, (seed, n, integrator, dt, fastest)


# With verlet this pile was still at 16 s and woke up by itself at 26-28 s (2e-5 m/s);
# with rk4 its boxes jittered at ~1e-2 m/s up to 8 s: a box lying across another's face
# had one contact point at one rim (collide.box_box; now test_collision_narrowphase's
# bar lying across a box face).
@pytest.mark.parametrize("integrator", ["verlet", "rk4", "symplectic-euler"])
def test_a_pile_of_20_boxes_comes_to_rest(integrator):
    fastest = _pile(100, 20, integrator, 1 / 120, 8.0)
    assert fastest <= SPEED, (integrator, fastest)
