"""A stack of boxes sliding to a stop on the floor stops where one box would (issue 48).

Truth: n equal boxes stacked, all moving at v0 along the floor, friction mu at the floor
and far more between the boxes (their pair's mu, the geometric mean of 5 and mu, is >=
1.2, so the boxes never slip on each other: each needs mu g of its own). Below the
tipping bound (the stack's centre of mass at height h_c over a half-width w/2 tips about
its front edge if mu g h_c > g w/2, so mu < w / (2 h_c)) the stack moves as one rigid
body under the floor's friction mu (n m) g: it decelerates at mu g and stops after
d = v0^2 / (2 mu g), in t = v0 / (mu g), whatever n. The compiled step is exact for one
box (tests/test_compiled_incline.py: a slide stops within a step with its two-piece
force, `kernels.stepped.slip_stops`), so the class asks the same of a stack: 1e-9 m,
that test's bound, and at rest after the stop (1e-9 m/s, tests/test_pile_rest.py's).
Until 2026-12-08 `slip_stops` placed stops in islands of one moving body only, and every
draw here stopped 8.7e-7 .. 2e-4 m off (the stack moved by the step's mean velocity);
now also in islands whose stopping contacts are all of one pair.

Draws: n = 2 or 3 cubes of 0.1 m and 0.2-2 kg each, turned about the vertical, sliding
in any direction of the floor; mu below the tipping bound, v0 0.1-1.5 m/s, dt 1/60,
1/120 or 1/240 s, verlet or rk4 (the integrators that move contact bodies by the mean
velocity; symplectic Euler's positions are first order, x = a t (t + dt) / 2).
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import simulate

G = 9.81
SIZE = 0.1  # m, cube edge


def _box(name, mass, position, velocity, friction, size=(SIZE,) * 3, q=(1.0, 0.0, 0.0, 0.0)):
    """A scene's line for a box, restitution 0."""
    return (f"  - {{name: {name}, mass: {mass!r}, position: {[float(c) for c in position]}, "
            f"orientation: {[float(c) for c in q]}, velocity: {[float(c) for c in velocity]}, "
            f"shape: {{type: box, size: {[float(c) for c in size]}}}, "
            f"material: {{friction: {friction!r}, restitution: 0}}}}")


def _run(boxes, ground_mu, duration, dt, integrator, normal=(0.0, 1.0, 0.0)):
    """The samples (10 Hz) of the boxes on a static plane through the origin."""
    src = (f"vrsim: 1\nduration: {duration!r}\nframe_rate: 10\ndt: {dt!r}\n"
           f"integrator: {integrator}\ngravity: [0, -{G}, 0]\ncollision: {{}}\nbodies:\n"
           f"  - {{name: ground, type: static, shape: {{type: plane, normal: "
           f"{[float(c) for c in normal]}}}, material: {{friction: {ground_mu!r}, "
           "restitution: 0}}\n" + "\n".join(boxes) + "\n")
    return simulate(src)[1]


def _fastest(states):
    """The fastest point of any box over the last three samples (m/s)."""
    return max(float(np.abs(st.body_vel[1:]).max() + np.abs(st.body_angvel[1:]).max() * SIZE)
               for st in states[-3:])


def _stack(n, v0, mu, dt, integrator, masses=None, heading=0.0, yaw=0.0):
    """The boxes' end positions along the slide, and the fastest point over the last
    three samples (m/s)."""
    masses = masses or [1.0] * n
    d = (np.cos(heading), 0.0, np.sin(heading))  # the slide's direction in the floor
    q = (np.cos(yaw / 2), 0.0, np.sin(yaw / 2), 0.0)  # turned about y
    boxes = [_box(f"b{i}", masses[i], (0.0, SIZE * (i + 0.5), 0.0), [v0 * c for c in d],
                  mu if i == 0 else 5.0, q=q) for i in range(n)]
    states = _run(boxes, mu, v0 / (mu * G) + 0.5, dt, integrator)
    return states[-1].body_pos[1:] @ np.array(d), _fastest(states)


def _draws():
    """(n, v0, mu, dt, integrator, masses, heading, yaw): mu below the stack's tipping
    bound (its centre of mass at h_c over the half-width w/2; a turned box's support
    reaches further along the slide, so w/2 is the smaller bound)."""
    rng = np.random.default_rng([48, 21])
    for _ in range(16):
        n = int(rng.integers(2, 4))
        masses = [float(m) for m in rng.uniform(0.2, 2.0, n)]
        h_c = SIZE * float(np.dot(masses, np.arange(n) + 0.5)) / sum(masses)
        mu = float(rng.uniform(0.1, 0.9) * (SIZE / 2) / h_c)
        yield (n, float(rng.uniform(0.1, 1.5)), mu,
               float(rng.choice([1 / 60, 1 / 120, 1 / 240])),
               str(rng.choice(["verlet", "rk4"])), masses,
               float(rng.uniform(0, 2 * np.pi)), float(rng.uniform(0, np.pi / 2)))


def test_one_box_of_the_same_draws_stops_at_the_closed_form():
    """The harness and the truth: one box of each draw stops at v0^2 / (2 mu g) (measured
    <= 1.5e-14 m) and is at rest, so the stack's misses below are the stack's."""
    for _, v0, mu, dt, integrator, masses, heading, yaw in _draws():
        x, speed = _stack(1, v0, mu, dt, integrator, masses[:1], heading, yaw)
        assert abs(x[0] - v0 * v0 / (2 * mu * G)) <= 1e-9 and speed <= 1e-9, \
            (v0, mu, dt, integrator, x[0], speed)


def test_a_stack_sliding_to_a_stop_stops_where_one_box_would():
    misses = []
    for n, v0, mu, dt, integrator, masses, heading, yaw in _draws():
        x, speed = _stack(n, v0, mu, dt, integrator, masses, heading, yaw)
        d = v0 * v0 / (2 * mu * G)
        off = float(np.abs(x - d).max())
        if off > 1e-9 or speed > 1e-9:
            misses.append((n, round(v0, 3), round(mu, 3), round(1 / dt), integrator,
                           f"off {off:.1e} m", f"speed {speed:.1e} m/s"))
    assert not misses, misses


def test_a_box_pushed_by_a_frictionless_one_stops_where_the_pair_would():
    """Another island with one stopping pair: a box sliding on the floor (mu) pushed by a
    box behind it that has no friction anywhere (both 0.1 m cubes, touching, the same
    start velocity). The two move as one body of mass m1 + m2 under the front box's
    friction mu m1 g (the push needs no friction; with mu < 1 the front cannot tip, as
    m2 a h/2 < m1 g w/2), so they stop after d = v0^2 (m1 + m2) / (2 mu m1 g). The
    pusher's frictionless contacts also end the stop step at zero slip; counted as stops
    of their own they hid the front box's (measured 6.6e-5 m off at dt 1/60 before
    `_slides_to_stop` left frictionless contacts out; found by an independent review)."""
    rng = np.random.default_rng([48, 22])
    misses = []
    for _ in range(8):
        m1, m2 = (float(m) for m in rng.uniform(0.2, 2.0, 2))
        mu, v0 = float(rng.uniform(0.1, 0.9)), float(rng.uniform(0.1, 1.5))
        dt = float(rng.choice([1 / 60, 1 / 120, 1 / 240]))
        integrator = str(rng.choice(["verlet", "rk4"]))
        states = _run([_box("front", m1, (0.0, SIZE / 2, 0.0), (v0, 0.0, 0.0), mu * mu),
                       _box("pusher", m2, (-SIZE, SIZE / 2, 0.0), (v0, 0.0, 0.0), 0.0)],
                      1.0, v0 * (m1 + m2) / (mu * m1 * G) + 0.5, dt, integrator)
        d = v0 * v0 * (m1 + m2) / (2 * mu * m1 * G)
        off = float(np.abs(states[-1].body_pos[1:, 0] - states[0].body_pos[1:, 0] - d).max())
        speed = float(np.abs(states[-1].body_vel[1:]).max())
        if off > 1e-9 or speed > 1e-9:
            misses.append((round(m1, 3), round(m2, 3), round(mu, 3), round(v0, 3),
                           round(1 / dt), integrator, f"off {off:.1e} m", f"{speed:.1e} m/s"))
    assert not misses, misses


def test_a_stack_sliding_to_a_stop_on_an_incline_stops_where_one_box_would():
    """The class on an incline of angle a (a plane through the origin, the stack turned
    with it): sliding up at v0 the stack decelerates at g (sin a + mu cos a), sliding
    down at g (mu cos a - sin a) (mu > tan a), and stops after v0^2 over twice that; it
    stays (mu > tan a holds it). While it slides, the friction on each box is mu times
    its normal load in both cases, so the tipping bound is the floor's, mu < w / (2 h_c),
    and at rest tan a < mu is below it too. (The review of 9057c72 found main 1e-6 ..
    1e-3 m off here, up and down.)"""
    rng = np.random.default_rng([48, 24])
    misses = []
    for _ in range(8):
        n = int(rng.integers(2, 4))
        mu = float(rng.uniform(0.3, 0.9) * (SIZE / 2) / (SIZE * n / 2))
        a = float(np.arctan(rng.uniform(0.2, 0.8) * mu))
        v0, up = float(rng.uniform(0.1, 1.2)), bool(rng.integers(0, 2))
        dt = float(rng.choice([1 / 60, 1 / 120, 1 / 240]))
        integrator = str(rng.choice(["verlet", "rk4"]))
        u = np.array([np.cos(a), np.sin(a), 0.0])  # uphill
        nrm = np.array([-np.sin(a), np.cos(a), 0.0])
        q = (np.cos(a / 2), 0.0, 0.0, np.sin(a / 2))
        vel = (v0 if up else -v0) * u
        decel = G * float(np.sin(a) + mu * np.cos(a) if up else mu * np.cos(a) - np.sin(a))
        boxes = [_box(f"b{i}", 1.0, SIZE * (i + 0.5) * nrm, vel, mu if i == 0 else 5.0, q=q)
                 for i in range(n)]
        states = _run(boxes, mu, v0 / decel + 0.5, dt, integrator, normal=nrm)
        along = (states[-1].body_pos[1:] - states[0].body_pos[1:]) @ u
        off = float(np.abs(along - (1 if up else -1) * v0 * v0 / (2 * decel)).max())
        speed = _fastest(states)
        if off > 1e-9 or speed > 1e-9:
            misses.append((n, round(v0, 3), round(mu, 3), round(float(np.degrees(a)), 2), up,
                           round(1 / dt), integrator, f"off {off:.1e} m", f"{speed:.1e}"))
    assert not misses, misses


@pytest.mark.xfail(strict=True, reason=(
    "measured 2026-12-08 on 0b47f65 (found by an independent review): stacks of 5-6 flat "
    "boxes (60-72 rows, above SMALL_ISLAND_ROWS = 48) stop 2.3e-5 .. 4.2e-3 m off v0^2 / "
    "(2 mu g) "
    "whatever the stop rule: the error builds up while they slide (the deceleration is "
    "off), not at the stop. Islands above 48 rows are swept 8 times and re-solved only "
    "for their normal rows (`unsettled_islands`), so their friction is not Coulomb's "
    "to round-off; issue 48's large islands"))
def test_a_tall_stack_sliding_to_a_stop_stops_where_one_box_would():
    """The first test's class beyond the small islands: 5 or 6 flat boxes (0.4 x 0.05 x
    0.4 m, so mu up to ~0.6 stays below the tipping bound w / (2 h_c) >= 1.3), turned
    about the vertical, sliding in any direction."""
    rng = np.random.default_rng([48, 23])
    misses = []
    for _ in range(4):
        n = int(rng.integers(5, 7))
        v0, mu = float(rng.uniform(0.2, 1.2)), float(rng.uniform(0.1, 0.6))
        dt = float(rng.choice([1 / 60, 1 / 120, 1 / 240]))
        integrator = str(rng.choice(["verlet", "rk4"]))
        heading, yaw = float(rng.uniform(0, 2 * np.pi)), float(rng.uniform(0, np.pi / 2))
        d = np.array([np.cos(heading), 0.0, np.sin(heading)])
        q = (np.cos(yaw / 2), 0.0, np.sin(yaw / 2), 0.0)
        boxes = [_box(f"b{i}", 1.0, (0.0, 0.05 * (i + 0.5), 0.0), v0 * d,
                      mu if i == 0 else 5.0, size=(0.4, 0.05, 0.4), q=q) for i in range(n)]
        states = _run(boxes, mu, v0 / (mu * G) + 0.5, dt, integrator)
        off = float(np.abs((states[-1].body_pos[1:] - states[0].body_pos[1:]) @ d
                           - v0 * v0 / (2 * mu * G)).max())
        if off > 1e-9:
            misses.append((n, round(v0, 3), round(mu, 3), round(1 / dt), integrator,
                           f"off {off:.1e} m"))
    assert not misses, misses
