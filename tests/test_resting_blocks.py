"""Blocks of boxes placed at rest stay at rest (in the default mode: located impacts up
to 32 bodies until 2026-12-07, the compiled step since).

The audit's scene: a 2 x 2 block of 0.4 m cubes on the ground, defaults (dt 1/60 s,
mu 0.5): at t = 0.77 s the upper box facing away kicked to 0.17 m/s and turned. Cause,
traced: the located rest sweeps (more than 16 contacts) were warm-started from last
step's impulses; the block's contacts are statically indeterminate, the warm start
carried the self-balanced share (the upper boxes pushing each other apart, held by
friction below) into the next step, the sweeps added to it (its normal impulse grew
0.0017 -> 0.016 N s, the friction below to its cone), and friction gave way.

Truth: static equilibrium. Boxes in a block, on the ground or on an incline whose friction
holds them (tan theta at most 0.8 mu) and within whose base the weight's line falls (tan
theta at most 0.8 of half the base over the height of the centre of mass; seeds 9 and 14
broke that until 2026-12-07: see the blocks that must tip, below), touching exactly, start
at rest: every body must stay where it is. Random draws over block shape (1-3 x 1-3 x 2-3 boxes), box size, mass,
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
from vrsim_cli.kernels.stepped import SMALL_ISLAND_ROWS
from vrsim_cli.stages.collision.solver import EXACT_CONTACTS

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
    share = None if seed < INCLINED else float(rng.uniform(0.2, 0.8))
    dt = (1 / 60, 1 / 100, 1 / 240)[seed % 3]
    integrator = ("symplectic-euler", "verlet", "rk4")[(seed // 3) % 3]
    mass = np.array([float(rng.uniform(0.5, 5.0)) for _ in range(nx * ny * nz)])
    # held: friction (tan theta <= mu) and the block's weight within its base (tan theta
    # <= nx size / 2 / h: the resultant's line through the centre of mass, h above the
    # slope, must fall within the base's half-width of its centre)
    layers = mass.reshape(nx, ny, nz).sum(axis=(0, 2))
    height = float(layers @ ((np.arange(ny) + 0.5) * size) / layers.sum())
    theta = 0.0 if share is None else share * min(math.atan(mu),
                                                  math.atan(nx * size / 2 / height))
    c, s = math.cos(theta), math.sin(theta)
    along, normal = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
    bodies = []
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                centre = (i - (nx - 1) / 2) * size * along + (j + 0.5) * size * normal + \
                    np.array([0.0, 0.0, (k - (nz - 1) / 2) * size])
                bodies.append(
                    f"  - {{name: b{i}_{j}_{k}, mass: {float(mass[(i * ny + j) * nz + k])!r}, position: "
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


# The compiled step (the default since 2026-12-07; located impacts held all of these)
# leaves one draw moving: seed 16, a 2 x 3 x 2 block of 12 boxes (48 contacts, 144 rows:
# above SMALL_ISLAND_ROWS, so warm-started sweeps and shock levels, not a converged
# solve) on a 16.3 degree incline, jitters from t = 0.07 s at 1e-5 .. 1e-4 m/s (rk4 and
# verlet alike; sweeping such islands to convergence, 512 sweeps, did not hold it
# either). Issue 48, item 3: the large islands' resting solve. Strict: the mark goes
# the day it holds.
LARGE_ISLAND_JITTER = {16}


@pytest.mark.parametrize("seed", SEEDS)
def test_a_block_of_boxes_at_rest_stays_at_rest(seed, request):
    if seed in LARGE_ISLAND_JITTER:
        request.applymarker(pytest.mark.xfail(strict=True, reason=(
            "a 12-box block on an incline jitters in the compiled step's large-island "
            "solve (LARGE_ISLAND_JITTER)")))
    text, case = draw(seed)
    model, _, final = simulate(text)
    assert np.abs(final.body_vel[1:]).max() <= SPEED_TOL, case
    assert np.abs(final.body_angvel[1:]).max() <= SPEED_TOL, case
    assert np.abs(final.body_pos - model.body_pos0).max() <= MOVE_TOL, case



# ------------------------------------------------------------------ blocks that must tip
# Until 2026-12-07 two of the draws above (seeds 9 and 14: 1 x 3 x 2 blocks on 25.3 and
# 24.6 degrees, tan theta 0.47 and 0.46 > 0.38 and 0.33, half the base over the height of
# the centre of mass) asked a block to stay whose weight's line falls outside its base.
# No static equilibrium exists there (about the block's downhill edge the weight's moment
# and every compressive ground force's turn the same way, whatever the forces between the
# boxes), so "at rest" was no truth, yet both modes held them (to 1e-14 rad/s). Cause:
# above 16 contacts both rest by sweeps and then shock propagation, which solves each
# body against its lower neighbours frozen and replaces the sweeps' impulses (located:
# EXACT_CONTACTS, sweeps from zero; stepped: islands above SMALL_ISLAND_ROWS = 48 rows,
# warm-started sweeps, the shock levels): every box stands on the one below, and the
# upper boxes' tipping moment never reaches the ground. A column of 5 cubes (20
# contacts) stays at tan 0.25 > 1/5; of 4 (16, solved exactly or swept to convergence)
# it tips. The class, with its own truth; in located mode above 16 contacts strict xfails
# (it holds every one), until its resting solve is one converged method (issue 48, item
# 3). The compiled step held 5 of the 8 draws until an island whose shock levels leave
# a normal row unmet is swept to convergence and the levels solved again
# (`kernels.stepped.unsettled_islands`); it is held to 24 draws:

TIP_DRAWS = 8  # located (each 5-30 s)
TIP_DRAWS_COMPILED = 24


def tip_draw(seed: int):
    """A column of ny = 2 to 5 cubes of one mass (one wide along the slope; its centre of
    mass ny size / 2 above the slope), nz = 1 or 2 columns side by side across it, on an
    incline with 1.15 / ny <= tan theta <= 0.8 mu (friction holds against sliding, the
    weight falls outside the base), every dt and integrator."""
    rng = np.random.default_rng(500 + seed)
    ny, nz = int(rng.integers(2, 6)), 1 + seed % 2
    size = float(rng.uniform(0.1, 0.5))
    mass = float(rng.uniform(0.5, 5.0))
    mu = float(rng.uniform(0.9, 1.2))
    tan = float(rng.uniform(1.15 / ny, min(0.8 * mu, 1.5 / ny)))
    theta = math.atan(tan)
    dt = (1 / 60, 1 / 100, 1 / 240)[seed % 3]
    integrator = ("symplectic-euler", "verlet", "rk4")[(seed // 2) % 3]
    c, s = math.cos(theta), math.sin(theta)
    normal = np.array([-s, c, 0.0])
    bodies = []
    for j in range(ny):
        for k in range(nz):
            centre = (j + 0.5) * size * normal + np.array([0.0, 0.0, (k - (nz - 1) / 2) * size])
            bodies.append(
                f"  - {{name: b{j}_{k}, mass: {mass!r}, position: "
                f"{centre.tolist()!r}, euler_deg: [0, 0, {math.degrees(theta)!r}], shape: "
                f"{{type: box, size: [{size!r}, {size!r}, {size!r}]}}, material: "
                f"{{friction: {mu!r}}}}}")
    return ny, nz, size, mu, theta, dt, integrator, bodies


@pytest.mark.parametrize("seed, mode", [(seed, "located") for seed in range(TIP_DRAWS)]
                         + [(seed, "stepped") for seed in range(TIP_DRAWS_COMPILED)])
def test_a_block_whose_weight_falls_outside_its_base_tips_over(seed, mode, request):
    """Truth: statics (above) says the block cannot stay; dynamics bounds how fast it
    must go. Tipping about the downhill edge as one body (mass M, ny a high, a wide), the
    weight's moment is M g a cos(theta) (ny tan(theta) - 1) / 2 >= 0.075 M g a cos(theta)
    and the moment of inertia M a^2 (ny^2 + 1) / 3, so the angular acceleration starts at
    >= 0.225 g cos(theta) / (a (ny^2 + 1)) >= 0.16 rad/s^2 (a <= 0.5 m, ny <= 5, tan(theta)
    <= 1.5 / ny) and grows as the block leans; boxes above that slide or turn on their
    own move faster still. After 0.6 s some box turns at more than 0.02 rad/s (a fifth of
    the bound's 0.098) where a held block moves by round-off (1e-14 rad/s)."""
    ny, nz, size, mu, theta, dt, integrator, bodies = tip_draw(seed)
    contacts = 4 * ny * nz + 4 * ny * (nz - 1)  # ground, between layers, side by side
    if mode == "located" and contacts > EXACT_CONTACTS:
        request.applymarker(pytest.mark.xfail(strict=True, reason=(
            f"located mode: blocks of more than {EXACT_CONTACTS} contacts go through shock "
            "propagation, which holds them at rest (1e-14 rad/s) where statics forbids it: "
            "docs/collision-response.md, Known limits")))
    c, s = math.cos(theta), math.sin(theta)
    text = f"""
vrsim: 1
duration: 0.6
frame_rate: 10
dt: {dt!r}
integrator: {integrator}
collision: {{impacts: {mode}}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [{-s!r}, {c!r}, 0]}},
     material: {{friction: {mu!r}}}}}
""" + "\n".join(bodies) + "\n"
    _, _, final = simulate(text)
    case = (ny, nz, size, mu, math.degrees(theta), dt, integrator)
    assert np.abs(final.body_angvel[1:]).max() > 0.02, case
