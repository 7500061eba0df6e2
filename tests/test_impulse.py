"""The impulse law of slide 5.4.2 (vrsim_cli/impulse.py) against hand computations and
the laws it must satisfy: the restitution condition and conservation of momentum."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.maths.impulse import (body_deltas, inverse_mass_along, point_velocity,
                               restitution_alpha)


def test_linear_form_two_equal_balls_exchange_velocities():
    """Slide: alpha = -(1+eps)(v_rel.n)/(1/m_A + 1/m_B). Head-on, m = 2 kg each, eps = 1:
    v_rel.n = -3 m/s, alpha = 2 * 3 / (1/2 + 1/2) = 6 N s: the balls swap velocities."""
    z = np.zeros((1, 3, 3))
    n = np.array([[1.0, 0.0, 0.0]])
    k = inverse_mass_along(np.array([0.5]), np.array([0.5]), z, z, -n, n, n)
    assert k[0] == 1.0
    alpha = restitution_alpha(np.array([-3.0]), 1.0, k)
    assert alpha[0] == 6.0
    v_a = 3.0 - alpha[0] / 2.0
    v_b = 0.0 + alpha[0] / 2.0
    assert (v_a, v_b) == (0.0, 3.0)


def test_rotational_term_by_hand():
    """A rod-like body B (I^-1 = diag(1, 2, 3) 1/(kg m^2), m = 1 kg) hit at arm p = (0, 1,
    0) along n = (1, 0, 0) by a static body: p x n = (0, 0, -1), I^-1 (p x n) = (0, 0, -3),
    (0, 0, -3) x p = (3, 0, 0), n . that = 3: K = 0 + 1 + 0 + 3 = 4 1/kg."""
    zero = np.zeros((1, 3, 3))
    inv_i = np.diag([1.0, 2.0, 3.0])[None]
    n = np.array([[1.0, 0.0, 0.0]])
    k = inverse_mass_along(np.zeros(1), np.ones(1), zero, inv_i, np.zeros((1, 3)),
                           np.array([[0.0, 1.0, 0.0]]), n)
    assert k[0] == 4.0
    # static-static: K = 0 and no impulse, not a division by zero
    assert restitution_alpha(np.array([-1.0]), 0.5, np.zeros(1))[0] == 0.0


vec = st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3)


@settings(max_examples=200, deadline=None)
@given(vec, vec, vec, vec, vec, vec, st.floats(0.2, 5.0), st.floats(0.2, 5.0),
       st.floats(0.0, 1.0), vec)
def test_restitution_law_and_momentum_for_random_rigid_bodies(va, vb, wa, wb, pa, pb, ma,
                                                              mb, eps, nrm):
    """For any two rigid bodies: after alpha n, n.v_rel_new = -eps n.v_rel (the slide's
    definition of eps) and the total linear and angular momentum about the contact point
    are unchanged. Tolerance 1e-9 relative: a handful of flops on O(1) numbers."""
    n = np.asarray(nrm, float)
    if np.linalg.norm(n) < 0.1:
        n = np.array([0.0, 1.0, 0.0])
    n = (n / np.linalg.norm(n))[None]
    rng = np.random.default_rng(0)
    inertia_a = np.diag(rng.uniform(0.5, 2.0, 3))
    inertia_b = np.diag(rng.uniform(0.5, 2.0, 3))
    ia, ib = np.linalg.inv(inertia_a)[None], np.linalg.inv(inertia_b)[None]
    pa, pb = np.array([pa]), np.array([pb])
    va, vb, wa, wb = (np.array([x], float) for x in (va, vb, wa, wb))
    v_rel = point_velocity(vb, wb, pb) - point_velocity(va, wa, pa)
    vn = (v_rel * n).sum(1)
    k = inverse_mass_along(np.array([1 / ma]), np.array([1 / mb]), ia, ib, pa, pb, n)
    alpha = restitution_alpha(vn, eps, k)
    impulse = alpha[:, None] * n
    dp, dl = body_deltas(2, np.array([0]), np.array([1]), pa, pb, impulse)
    va1, vb1 = va + dp[0] / ma, vb + dp[1] / mb
    wa1, wb1 = wa + (ia[0] @ dl[0]), wb + (ib[0] @ dl[1])
    vn1 = ((point_velocity(vb1, wb1, pb) - point_velocity(va1, wa1, pa)) * n).sum(1)
    scale = 1.0 + abs(vn[0])
    assert abs(vn1[0] + eps * vn[0]) <= 1e-9 * scale
    # linear momentum; angular momentum about a common point (the origin of the arms'
    # frame: body A's centre at -pa, B's at -pb, both relative to the contact point)
    p0 = ma * va + mb * vb
    p1 = ma * va1 + mb * vb1
    assert np.abs(p1 - p0).max() <= 1e-9 * (1 + np.abs(p0).max() + abs(alpha[0]))
    l0 = np.cross(-pa, ma * va) + np.cross(-pb, mb * vb) + wa @ inertia_a + wb @ inertia_b
    l1 = np.cross(-pa, ma * va1) + np.cross(-pb, mb * vb1) + wa1 @ inertia_a + \
        wb1 @ inertia_b
    assert np.abs(l1 - l0).max() <= 1e-9 * (1 + np.abs(l0).max() + 4 * abs(alpha[0]))
