"""Blocks of boxes placed at rest stay at rest (located impacts, the default up to 32
bodies).

The audit's scene: a 2 x 2 block of 0.4 m cubes on the ground, defaults (dt 1/60 s,
mu 0.5): at t = 0.77 s the upper box facing away kicked to 0.17 m/s and turned. Cause,
traced: the located rest sweeps (more than 16 contacts) were warm-started from last
step's impulses; the block's contacts are statically indeterminate, the warm start
carried the self-balanced share (the upper boxes pushing each other apart, held by
friction below) into the next step, the sweeps added to it (its normal impulse grew
0.0017 -> 0.016 N s, the friction below to its cone), and friction gave way.

Truth: static equilibrium. Boxes in a block, on the ground or on an incline whose friction
holds them (tan theta at most 0.8 mu), touching exactly, start at rest: every body must stay
where it is. Random draws over block shape (1-3 x 1-3 x 2-3 boxes), box size, mass,
friction, dt, integrator and incline angle; 1 s each (the kick came after 0.77 s).

Blocks on an incline (seeds from INCLINED on): all 12 draws are held to 3e-15 m (draw
8 moved 1.4e-5 m until 2026-12-04). On e3fedb3 9 of the 12 moved (up to 2.3 cm),
4 were still moving after 1 s (up to 0.13 m/s). Causes found and fixed (docs/collision-response.md):
- the re-integration that takes back each step's slide g sin(th) h^2 / 2 down the slope
  (`response._drift`) skipped the span of all of a box's contact normals; the
  neighbours' normals along the slope span it, so the block crept (a 3 x 2 x 2 block on
  10 degrees, mu 0.5, 1/60 s: 0.1 m in 3 s). Now only its supports' normals are
  skipped: the contacts of aligned diagonal neighbours touch along
  an edge with a normal along the slope, and counted as supports they stopped it again
  (a support now counts when near the direction of the supports' summed normal impulse
  or carrying a quarter of it);
- the few sweeps from zero left junk in the velocities the per-body block solves start
  from (`solver._shock_velocities`, swept);
- the block solve's rounds ended on a cycle with impulses of other statuses, accepted
  with a box's four "sticking" corners slipping at 0.24 m/s: it turned at 1.6 rad/s
  (`solver._admissible`, stuck), and refused answers where its first rounds did not
  settle (`solver._support`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import simulate

INCLINED = 8  # seeds below: on flat ground; from 8: on an incline that friction holds
# flat: every dt (seed % 3) and integrator (seed // 3 % 3) once at least; seeds 4, 5
# and 7 (the three costliest, 15 s together) are left out for the suite's time
SEEDS = [0, 1, 2, 3, 6] + list(range(INCLINED, 20))

# Held bodies move by round-off only: what the rest solve leaves (<= ~1e-14 m/s per step
# for 0.1-0.5 m boxes) over 72-288 steps stays far below 1e-9; a kick is >= 1e-3.
SPEED_TOL = 1e-9  # m/s and rad/s
MOVE_TOL = 1e-9  # m


def draw(seed: int):
    rng = np.random.default_rng(seed)
    nx, ny, nz = int(rng.integers(1, 3)), int(rng.integers(2, 4)), int(rng.integers(1, 3))
    if nx * nz == 1:
        nz = 2  # side by side somewhere: a plain column is statically determinate
    size = float(rng.uniform(0.1, 0.5))
    mu = float(rng.uniform(0.3, 1.0))
    theta = 0.0 if seed < INCLINED else float(rng.uniform(0.2, 0.8)) * math.atan(mu)
    dt = (1 / 60, 1 / 100, 1 / 240)[seed % 3]
    integrator = ("symplectic-euler", "verlet", "rk4")[(seed // 3) % 3]
    c, s = math.cos(theta), math.sin(theta)
    along, normal = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    bodies = []
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                centre = (i - (nx - 1) / 2) * size * along + (j + 0.5) * size * normal + \
                    np.array([0.0, 0.0, (k - (nz - 1) / 2) * size])
                mass = float(rng.uniform(0.5, 5.0))
                bodies.append(
                    f"  - {{name: b{i}_{j}_{k}, mass: {mass!r}, position: "
                    f"[{float(centre[0])!r}, {float(centre[1])!r}, {float(centre[2])!r}], euler_deg: "
                    f"[0, 0, {math.degrees(theta)!r}], shape: {{type: box, size: "
                    f"[{size!r}, {size!r}, {size!r}]}}, material: {{friction: {mu!r}}}}}")
    text = f"""
vrsim: 1
duration: 1.0
frame_rate: 10
dt: {dt!r}
integrator: {integrator}
collision: {{}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [{-s!r}, {c!r}, 0]}},
     material: {{friction: {mu!r}}}}}
""" + "\n".join(bodies) + "\n"
    return text, (nx, ny, nz, size, mu, math.degrees(theta), dt, integrator)


@pytest.mark.parametrize("seed", SEEDS)
def test_a_block_of_boxes_at_rest_stays_at_rest(seed):
    text, case = draw(seed)
    model, _, final = simulate(text)
    assert np.abs(final.body_vel[1:]).max() <= SPEED_TOL, case
    assert np.abs(final.body_angvel[1:]).max() <= SPEED_TOL, case
    assert np.abs(final.body_pos - model.body_pos0).max() <= MOVE_TOL, case

