"""What stepped impacts give on the ordinary scenes of issue 15 (item 5: stepped mode stays
within its documented error, docs/collision-response.md "The default mode's error on
the event-exact cases").

The located tests' random cases (tests/test_incline.py, tests/test_simultaneous_impacts.py)
run here with `collision: {impacts: stepped}`. Stepped mode takes impacts at the step's
start and applies the resting impulses as a constant wrench over the step, so the
draws' second-order integrators move a body in contact by the mean of its start and end
velocities (Moreau-Jean's theta = 1/2); islands of a few contacts are solved to
convergence. Truths:

- a box sliding down an incline at a = g (sin th - mu cos th) from rest has v = a t and
  x = x_0 + a t^2 / 2, exactly (before the islands converged, 8 sweeps stopped short of
  Coulomb's law: up to 1e-3 relative in the first steps; while contact bodies moved by
  symplectic Euler, x was a t (t + dt) / 2);
- a box dropped flat lands on its four corners at once: no spin, no sideways velocity,
  and it rebounds at eps times its speed less at most (1 + eps) g dt (the impact at the
  step's start of the step in which it lands).

Tolerances: the sliding box's position, velocity (relative) and turn (rad) to 1e-9 and a
held box's creep to 1e-9 m in 5 s, issue 48's bounds (before the islands converged:
1e-3, 1e-3, 7e-5 and 2.1e-5 m). Spin and sideways velocity after a
flat drop: 1e-9, the issue's bound (measured <= 3.2e-13).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from test_incline import box_on_slope, draw_holding, draw_sliding, turned
from test_simultaneous_impacts import CASES, G, drop_flat

STEPPED = "{impacts: stepped}"


@pytest.mark.parametrize("seed", range(10))
def test_a_stepped_box_that_friction_can_hold_does_not_creep(seed):
    rng, theta, th, yaw, size, mu = draw_holding(seed)
    position, _, states = box_on_slope(rng, th, yaw, size, mu, STEPPED)
    moved = max(float(np.linalg.norm(s.body_pos[1] - position)) for s in states)
    assert moved <= 1e-9, (theta, mu, moved)


@pytest.mark.parametrize("seed", range(12))
def test_a_stepped_box_slides_at_the_closed_form_under_coulomb_friction(seed):
    rng, theta, th, yaw, size, mu = draw_sliding(seed)
    position, q, states = box_on_slope(rng, th, yaw, size, mu, STEPPED)
    a = G * (math.sin(th) - mu * math.cos(th))
    down = np.array([-math.cos(th), -math.sin(th), 0.0])
    worst_x = worst_v = worst_turn = 0.0
    for s in states[1:]:
        t = s.t
        x = 0.5 * a * t * t
        err_x = float(np.linalg.norm(s.body_pos[1] - position - x * down)) / x
        err_v = float(np.linalg.norm(s.body_vel[1] - a * t * down)) / (a * t)
        worst_x, worst_v = max(worst_x, err_x), max(worst_v, err_v)
        worst_turn = max(worst_turn, turned(q, s.body_quat[1]))
    assert worst_x <= 1e-9 and worst_v <= 1e-9, (theta, mu, worst_x, worst_v)
    assert worst_turn <= 1e-9, (theta, mu, worst_turn)


@pytest.mark.parametrize("pose,eps,mu,integrator,dt", CASES)
def test_a_stepped_box_dropped_flat_rebounds_without_spin(pose, eps, mu, integrator, dt):
    t_i, s = drop_flat(pose, eps, mu, integrator, dt, STEPPED, 4)  # 3-4 steps after
    assert np.abs(s.body_angvel[1]).max() <= 1e-9
    assert np.abs(s.body_vel[1, [0, 2]]).max() <= 1e-9
    if eps == 0.0:
        assert abs(s.body_vel[1, 1]) <= 1e-9  # it rests
    else:
        expected = eps * G * t_i - G * (s.t - t_i)
        assert abs(s.body_vel[1, 1] - expected) <= (1 + eps) * G * dt, \
            (s.body_vel[1, 1], expected)
