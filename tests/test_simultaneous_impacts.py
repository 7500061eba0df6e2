"""Impacts at several points at once are solved together (issue 15, item 2), in the default
located mode: a box landing flat on any face, and a box or bar landing on an edge.
(Mirror images of whole scenes do not stay mirror images yet: the box-box narrow phase
picks its reference face from the first body, and resting contact is solved in
Gauss-Seidel order.)

Before, the points of one impact were resolved one corner after another: a 0.4 m cube
dropped flat with eps = 0.5 came back at 1.01 m/s instead of 2.21 m/s, spinning at
(0.78, 0, -0.78) rad/s. Truths here are closed forms written in the tests (free fall,
Newton's restitution, the planar rigid-body impact) and symmetry.

Tolerances: flights under constant gravity are exact for rk4 and verlet, and the impact
time is located to 1e-13 of a step, so velocities are right to ~1e-13 m/s and spins to
~1e-13 rad/s; 1e-9 leaves room for accumulation over many poses, and is what the issue
asks for.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from conftest import simulate

G = 9.81


def axis_aligned_rotations() -> list[np.ndarray]:
    """The 24 rotations that map the coordinate axes onto the coordinate axes."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            R = np.zeros((3, 3))
            for row, (col, sign) in enumerate(zip(perm, signs)):
                R[row, col] = sign
            if np.linalg.det(R) > 0:
                out.append(R)
    assert len(out) == 24
    return out


def quat_of(R: np.ndarray) -> list[float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return [float(w), float(x), float(y), float(z)]


CASES = [(i, eps, mu, integ, dt) for i, (eps, mu, integ, dt) in zip(
    range(24), itertools.cycle(itertools.product((0.0, 0.5, 1.0), (0.0, 0.5),
                                                 ("rk4", "verlet"), (0.01, 1 / 60))))]


def drop_flat(pose, eps, mu, integrator, dt, collision: str, steps_after: int):
    """(impact time t_i s, final state) of a 0.4 x 0.3 x 0.2 m box, 1.3 kg, in axis-aligned
    pose `pose`, dropped from rest with its lowest face 0.8 m above a ground plane, run
    until steps_after - 1 to steps_after steps after t_i. `collision`: the scene's
    collision block (YAML flow)."""
    R = axis_aligned_rotations()[pose]
    size = np.array([0.4, 0.3, 0.2])
    half_height = float(0.5 * abs(R @ size)[1])
    d = 0.8
    t_i = math.sqrt(2 * d / G)
    duration = (math.floor(t_i / dt) + steps_after) * dt
    _, _, s = simulate(f"""
vrsim: 1
duration: {duration!r}
frame_rate: {1 / dt!r}
dt: {dt!r}
integrator: {integrator}
gravity: [0, -{G}, 0]
collision: {collision}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}},
     material: {{restitution: {eps}, friction: {mu}}}}}
  - {{name: box, mass: 1.3, position: [0.1, {half_height + d!r}, -0.2],
     orientation: {quat_of(R)}, shape: {{type: box, size: {size.tolist()}}},
     material: {{restitution: {eps}, friction: {mu}}}}}
""")
    return t_i, s


@pytest.mark.parametrize("pose,eps,mu,integrator,dt", CASES)
def test_a_box_dropped_flat_rebounds_straight_without_spin(pose, eps, mu, integrator, dt):
    """A 0.4 x 0.3 x 0.2 m box in one of its 24 axis-aligned poses, dropped from rest
    with its lowest face d = 0.8 m above the ground: it meets the ground at t_i =
    sqrt(2 d / g) with v = g t_i and leaves at eps v straight up, without turning (the
    four corners are one impact). Checked one step after the impact: v_y = eps v -
    g (t - t_i) (0 for eps = 0: it rests), no horizontal velocity, no spin."""
    t_i, s = drop_flat(pose, eps, mu, integrator, dt, "{impacts: located}", 2)
    v = G * t_i
    expected = eps * v - G * (s.t - t_i) if eps > 0 else 0.0
    assert s.body_vel[1, 1] == pytest.approx(expected, abs=1e-9)
    assert np.abs(s.body_vel[1, [0, 2]]).max() <= 1e-9
    assert np.abs(s.body_angvel[1]).max() <= 1e-9


@pytest.mark.parametrize("seed", range(12))
def test_a_box_landing_on_an_edge_matches_the_planar_rigid_impact(seed):
    """A box turned by phi about z (its lowest feature is the edge along z: two corners)
    falls at v0 without spin onto the ground, no gravity, no friction. Closed form of the
    planar impact at the edge, arm r from the centre to it: relative normal velocity
    v_n = -v0, impulse j = (1 + eps) v0 / (1/m + r_x^2 / I_z), then v_y = -v0 + j / m and
    omega_z = r_x j / I_z (the torque (r x j e_y)_z = r_x j). Both corners of the edge are
    one impact: solved one after the other they would also turn the box about x. Cases in
    which another corner would reach the ground before the checked sample are redrawn
    (the closed form is that of one impact)."""
    rng = np.random.default_rng(seed)
    dt, gap = 0.01, 0.01
    while True:  # draw until the box does not touch again before the sample we check
        a, b, c = (float(x) for x in rng.uniform(0.2, 1.0, 3))  # box size along x, y, z (m)
        m = float(rng.uniform(0.5, 5.0))
        phi = float(rng.uniform(5.0, 40.0) * rng.choice([-1.0, 1.0]))
        eps = float(rng.choice([0.0, 0.3, 0.5, 1.0]))
        v0 = float(rng.uniform(0.5, 20.0))
        th = math.radians(phi)
        corners = [(sx * a / 2, sy * b / 2) for sx in (-1, 1) for sy in (-1, 1)]
        world = [(x * math.cos(th) - y * math.sin(th), x * math.sin(th) + y * math.cos(th))
                 for x, y in corners]
        rx, ry = min(world, key=lambda p: p[1])  # the lowest corner's arm (x, y)
        height = -ry + gap
        t_i = gap / v0
        I_z = m * (a * a + b * b) / 12.0
        j = (1 + eps) * v0 / (1 / m + rx * rx / I_z)
        vy = -v0 + j / m
        wz = rx * j / I_z
        duration = (math.floor(t_i / dt) + 1) * dt
        # after the impact the motion is free: every corner must stay above the ground
        # (the impacting ones leave, or rest for eps = 0) until the checked sample
        lowest = min(-ry + vy * tau + (x * math.sin(wz * tau) + y * math.cos(wz * tau))
                     for tau in np.linspace(0.0, duration - t_i, 200)[1:] for x, y in world)
        if lowest > -1e-12:
            break
    _, _, s = simulate(f"""
vrsim: 1
duration: {duration!r}
frame_rate: 100
dt: {dt}
integrator: rk4
gravity: [0, 0, 0]
collision: {{impacts: located}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}},
     material: {{restitution: {eps}, friction: 0}}}}
  - {{name: box, mass: {m!r}, position: [0, {height!r}, 0], euler_deg: [0, 0, {phi!r}],
     velocity: [0, {-v0!r}, 0], shape: {{type: box, size: [{a!r}, {b!r}, {c!r}]}},
     material: {{restitution: {eps}, friction: 0}}}}
""")
    assert s.body_vel[1, 1] == pytest.approx(vy, abs=1e-9 * max(1.0, v0))
    assert s.body_angvel[1, 2] == pytest.approx(wz, abs=1e-9 * max(1.0, v0))
    assert abs(s.body_vel[1, 0]) <= 1e-9 * v0 and abs(s.body_vel[1, 2]) <= 1e-9 * v0
    assert np.abs(s.body_angvel[1, :2]).max() <= 1e-9 * v0


def _face_down(rng):
    """A box of random size, mass and turn about the vertical lying on a random face:
    (mass kg, world inertia (3, 3), the face's corners (4, 3) m from the centre)."""
    size, m, R, corners = _face_down_pose(rng)
    return m, _box_inertia(size, m, R), corners


def _face_down_pose(rng):
    """`_face_down`'s box as (size (3,) m, mass kg, rotation R (3, 3), the face's corners
    (4, 3) m from the centre)."""
    from scipy.spatial.transform import Rotation

    size = rng.uniform(0.05, 1.0, 3)
    m = float(rng.uniform(0.1, 10.0))
    axis = int(rng.integers(3))
    down = np.zeros(3)
    down[axis] = rng.choice([-1.0, 1.0])
    # a random rotation, then the shortest turn taking the face's normal down
    R = Rotation.random(random_state=int(rng.integers(2 ** 31))).as_matrix()
    d, t = R @ down, np.array([0.0, -1.0, 0.0])
    R = Rotation.align_vectors([t], [d])[0].as_matrix() @ R
    others = [i for i in range(3) if i != axis]
    corners = []
    for s1 in (-1.0, 1.0):
        for s2 in (-1.0, 1.0):
            p = down * size / 2
            p[others[0]], p[others[1]] = s1 * size[others[0]] / 2, s2 * size[others[1]] / 2
            corners.append(R @ p)
    return size, m, R, np.array(corners)


def _box_inertia(size, m, R):
    """World inertia (3, 3) of a box of size (3,) m and mass m kg turned by R."""
    a, b, c = size
    return R @ np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) @ R.T * m / 12.0


def _impact(m, I, points, vel, angvel, eps, mu):
    """(v, w) after `solver.resolve_impacts` of a box at the origin on a fixed ground
    (normal +y) at `points`."""
    from vrsim_cli.stages.collision import solver

    k = len(points)
    bodies = solver.Bodies(np.array([0.0, 1.0 / m]), np.stack([np.zeros((3, 3)),
                                                               np.linalg.inv(I)]),
                           np.stack([np.zeros(3), vel]), np.stack([np.zeros(3), angvel]),
                           np.zeros((2, 3)))
    c = solver.prepare(bodies, np.zeros(k, np.int64), np.ones(k, np.int64), points,
                       np.repeat([[0.0, 1.0, 0.0]], k, axis=0), np.zeros(k), np.full(k, eps),
                       np.full(k, mu))
    solver.resolve_impacts(bodies, c, 0.0)
    return bodies.vel[1].copy(), bodies.angvel[1].copy()


def test_points_up_to_two_tolerances_out_of_plane_impact_like_a_face():
    """The corners of a landing face are reported up to two collision tolerances apart
    along the normal (an impact is located when a landing corner is the tolerance below a
    resting one, which may itself be the tolerance deep). A 2 mm change of the points
    must change the impact's outcome by little: the velocities after (v and w L, L the
    face's longest corner arm) differ from those of the same impact at the exact face by
    at most 20 (delta / L) (|v| + |w| L), delta the largest offset.

    Independent truth: continuity of the impact in its geometry (the same solve at the
    exact face is the reference; the friction of the offset points must not vanish).
    1000 seeded cases: random boxes on random faces, landing at 0.5-5 m/s, sliding at up
    to 2 m/s, spinning at up to 2 rad/s, eps in {0, 0.5, 1}, mu in {0, 0.3, 1, 3}, offsets
    uniform in [0, 2 mm]. Measured: at most 7.6 (delta / L) over 3000 cases; before
    friction acted at the points levelled onto their mean plane (`solver._levelled`), up
    to 540 (delta / L), 86 % of the speed: the friction of a cube landing flat after
    tipping over with mu = 1 came out 0 and it slid on at 0.6 m/s."""
    tolerance = 1e-3
    rng = np.random.default_rng(2026)
    worst = []
    for trial in range(1000):
        m, I, corners = _face_down(rng)
        u = rng.uniform(0.5, 5.0)
        slide = rng.normal(size=2) * rng.uniform(0.0, 2.0)
        vel = np.array([slide[0], -u, slide[1]])
        angvel = rng.normal(size=3) * rng.uniform(0.0, 2.0)
        eps = float(rng.choice([0.0, 0.5, 1.0]))
        mu = float(rng.choice([0.0, 0.3, 1.0, 3.0]))
        delta = rng.uniform(0.0, 2 * tolerance, 4)
        lowered = corners - np.outer(delta, [0.0, 1.0, 0.0])
        L = float(np.linalg.norm(corners, axis=1).max())
        v0, w0 = _impact(m, I, corners, vel, angvel, eps, mu)
        v1, w1 = _impact(m, I, lowered, vel, angvel, eps, mu)
        change = max(np.abs(v1 - v0).max(), np.abs(w1 - w0).max() * L)
        scale = np.linalg.norm(vel) + np.linalg.norm(angvel) * L
        if change > 20.0 * delta.max() / L * scale:
            worst.append((trial, eps, mu, change / scale / (delta.max() / L)))
    assert not worst, f"{len(worst)} of 1000 impacts jumped (trial, eps, mu, ratio): " \
                      f"{worst[:10]}"


def _edge_landing(rng):
    """A box lying on a random face (`_face_down`), turning about one edge of that face
    (the pivot, at rest) so that the opposite edge lands: (m, I, the face's corners (4, 3)
    from the centre, pivot (2,) and landing (2,) corner indices, omega (3,) rad/s)."""
    m, I, corners = _face_down(rng)
    pairs = [(0, 1), (2, 3), (0, 2), (1, 3)]  # the face's edges (corners s1, s2 = +-1)
    pivot = pairs[int(rng.integers(4))]
    landing = tuple(i for i in range(4) if i not in pivot)
    axis = corners[pivot[1]] - corners[pivot[0]]
    axis /= np.linalg.norm(axis)
    # the sense that brings the landing edge down: (w x (p_land - p_pivot)).y < 0
    arm = corners[landing[0]] - corners[pivot[0]]
    sense = -1.0 if np.cross(axis, arm)[1] > 0 else 1.0
    omega = sense * axis * float(np.exp(rng.uniform(np.log(0.1), np.log(20.0))))
    return m, I, corners, pivot, landing, omega


@pytest.mark.parametrize("pivoting", [True, False], ids=["from-a-pivot", "in-flight"])
@pytest.mark.parametrize("seed", range(40))
def test_a_box_landing_on_an_edge_with_friction_matches_the_planar_impact(seed, pivoting):
    """A box lands on an edge of one of its faces, in planar motion (turning about an
    axis along the edge, moving across it), with friction. `from-a-pivot`: it pivots on
    the opposite edge of the face and lands flat (the landing of
    `tests/test_tipping_landing.py`, in the instant of the impact: both edges touch, the
    pivot's corners at rest); `in-flight`: it falls turning and only the landing edge
    touches. The closed form is that of one planar impact at the landing edge, solved
    here: the impulse P (normal and across the edge, none along it) makes the landing
    edge's velocity (0, eps v_n) when it sticks (|P_t| <= mu P_n), (free, eps v_n) with
    P_t = 0 when mu = 0; a pivot edge then leaves (its normal velocity >= 0: no impulse
    there, as the LCP's complementarity demands; cases where it would not are redrawn).
    For eps = 0 and sticking it is Housner's rocking block (1963): the angular momentum
    about the landing edge is kept and the box turns about it. Tolerance: 1e-9 of the
    pre-impact speed scale (round-off of the solve). On the tree before
    `solver._sticking_round` 15 of the 40 pivot cases failed and 15 of the 40 in flight
    (friction after the normal impulses: with eps = 0.5 a box lost its whole bounce,
    3.19 J -> 0.003 J where the planar impact leaves 0.80 J, and with eps = 0 one left the
    ground at 1.1 m/s)."""
    rng = np.random.default_rng(7000 + seed + 100 * (not pivoting))
    eps = float((0.0, 0.3, 0.5, 1.0)[seed % 4])
    sticking = seed % 8 < 4
    n = np.array([0.0, 1.0, 0.0])
    while True:
        m, I, corners, pivot, landing, omega = _edge_landing(rng)
        p_pivot = 0.5 * (corners[pivot[0]] + corners[pivot[1]])
        p_land = 0.5 * (corners[landing[0]] + corners[landing[1]])
        t = (p_land - p_pivot) - n * ((p_land - p_pivot) @ n)
        t /= np.linalg.norm(t)  # along the face, across the edges
        if pivoting:
            vel = np.cross(omega, -p_pivot)  # the centre (origin) turning about the pivot
        else:  # any planar motion: turning about the edge's direction, moving across it
            omega = omega * float(rng.uniform(-2.0, 2.0))
            vel = (n * float(rng.uniform(-5.0, 0.0)) + t * float(rng.uniform(-3.0, 3.0)))
        Iinv = np.linalg.inv(I)

        def point_velocity_change(P, at):
            dv, dw = P / m, Iinv @ np.cross(at, P)
            return dv + np.cross(dw, at), dv, dw

        u = vel + np.cross(omega, p_land)  # landing edge velocity (its mid-point)
        vn = float(u @ n)
        if vn >= -1e-3:
            continue  # not landing
        if sticking:  # solve the 2 x 2 for (P_n, P_t): landing velocity (.t, .n) = (0, -eps vn)
            K = np.array([[point_velocity_change(d1, p_land)[0] @ d2 for d1 in (n, t)]
                          for d2 in (n, t)])
            P_n, P_t = np.linalg.solve(K, np.array([-eps * vn - vn, -(u @ t)]))
            mu = 2.0 * abs(P_t) / P_n + 0.1  # enough to stick
        else:
            P_n = (-eps * vn - vn) / (point_velocity_change(n, p_land)[0] @ n)
            P_t, mu = 0.0, 0.0
        P = P_n * n + P_t * t
        _, dv, dw = point_velocity_change(P, p_land)
        v_after, w_after = vel + dv, omega + dw
        pivot_after = (v_after + np.cross(w_after, p_pivot)) @ n
        if P_n > 0.0 and (not pivoting or pivot_after >= 1e-6 * abs(vn)):
            break
    v, w = _impact(m, I, corners if pivoting else corners[list(landing)], vel, omega, eps,
                   mu)
    scale = abs(vn) + 1e-300

    def energy(v, w):
        return 0.5 * m * float(v @ v) + 0.5 * float(w @ I @ w)

    if sticking and energy(v_after, w_after) > energy(vel, omega) * (1.0 + 1e-12):
        # Newton's law with sticking adds energy here (Kane's paradox; seen with eps = 1):
        # no law of impact may, so the truth left is that none is added, the landing
        # edge sticks, and it does not sink back (restitution scaled down, not dropped)
        u_after = v + np.cross(w, p_land)
        assert energy(v, w) <= energy(vel, omega) * (1.0 + 1e-12)
        assert abs(u_after @ t) <= 1e-9 * scale and u_after @ n >= -1e-9 * scale
        return
    assert np.abs(v - v_after).max() <= 1e-9 * scale, (v, v_after)
    assert np.abs(w - w_after).max() * max(np.abs(corners).max(), 1e-3) <= 1e-9 * scale, \
        (w, w_after)


def _landing_scene(rng, pivoting):
    """A box about to land on an edge of a face, in planar motion, drawn as in
    `_edge_landing` but posed for a whole scene: (R, size, mass, world inertia, the
    face's corners (4, 3) from the centre, pivot and landing corner indices, omega
    (3,) rad/s about the edge, landing edge down). `pivoting`: the face lies on the
    ground (both edges touch); else the box is turned by 0.05-0.6 rad about the edge's
    direction so the landing edge alone touches."""
    from scipy.spatial.transform import Rotation

    size, m, R, corners = _face_down_pose(rng)
    pivot = [(0, 1), (2, 3), (0, 2), (1, 3)][int(rng.integers(4))]
    landing = tuple(i for i in range(4) if i not in pivot)
    edge = corners[landing[1]] - corners[landing[0]]
    edge /= np.linalg.norm(edge)
    across = corners[pivot[0]] - corners[landing[0]]
    if not pivoting:  # turn about the edge's direction (through the centre) so the pivot rises
        sense = 1.0 if np.cross(edge, across)[1] > 0 else -1.0
        tilt = Rotation.from_rotvec(sense * float(rng.uniform(0.05, 0.6)) * edge).as_matrix()
        corners, R = corners @ tilt.T, tilt @ R
    I = _box_inertia(size, m, R)
    w0 = float(np.exp(rng.uniform(np.log(0.1), np.log(20.0))))
    omega = (1.0 if np.cross(edge, across)[1] > 0 else -1.0) * w0 * edge  # landing edge down
    return R, size, m, I, corners, pivot, landing, omega


def _landing_motion(rng, pivoting):
    """`_landing_scene` with its motion: turning about the pivot (`pivoting`) or any
    planar motion (turning about the edge's direction, moving across it): (R, size, m, I,
    corners, pivot, landing, omega, vel, t the direction across the edges, the landing
    edge's mid-point, change(P, at) -> (velocity change at `at`, dv, dw) of an impulse P
    there)."""
    n = np.array([0.0, 1.0, 0.0])
    R, size, m, I, corners, pivot, landing, omega = _landing_scene(rng, pivoting)
    p_land = 0.5 * (corners[landing[0]] + corners[landing[1]])
    p_pivot = 0.5 * (corners[pivot[0]] + corners[pivot[1]])
    t = (p_land - p_pivot) - n * ((p_land - p_pivot) @ n)
    t /= np.linalg.norm(t)
    if pivoting:
        vel = np.cross(omega, -p_pivot)
    else:
        omega = omega * float(rng.uniform(-2.0, 2.0))
        vel = n * float(rng.uniform(-5.0, 0.0)) + t * float(rng.uniform(-3.0, 3.0))
    Iinv = np.linalg.inv(I)

    def change(P, at):
        dv, dw = P / m, Iinv @ np.cross(at, P)
        return dv + np.cross(dw, at), dv, dw

    return R, size, m, I, corners, pivot, landing, omega, vel, t, p_land, change


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("pivoting", [True, False], ids=["from-a-pivot", "in-flight"])
@pytest.mark.parametrize("seed", range(40))
def test_a_whole_step_of_an_edge_landing_matches_the_planar_impact(seed, pivoting, mode):
    """The edge landings of the test above as whole scenes, in both impact modes: one
    step of 1 ms without gravity from the instant the landing edge touches (tilted by up
    to 0.6 rad when in flight), checked against the planar impact at the landing edge,
    solved here (sticking: the edge's velocity (0, eps v_n) across and along the normal;
    mu = 0: P_t = 0). Cases where Newton's law with sticking would add energy (Kane's
    paradox, checked in located mode above) and pivots that would not leave are redrawn.
    Tolerance 1e-9 of the approach speed, as above (round-off of the solves).

    On the tree before, the stepped mode failed 12 of these 80 (errors 5e-9 to 0.48 of
    the approach speed): `kernels.stepped.impact_pair`'s Gauss-Seidel sweeps over the
    face's four corners, whose Delassus matrix is singular, stopped after 100 sweeps
    short of convergence (with 1000, one case was still 3e-8 off)."""
    rng = np.random.default_rng(9100 + seed + 100 * (not pivoting))
    eps = float((0.0, 0.3, 0.5, 1.0)[seed % 4])
    sticking = seed % 8 < 4
    n = np.array([0.0, 1.0, 0.0])
    for _ in range(1000):
        R, size, m, I, corners, pivot, landing, omega, vel, t, p_land, change = \
            _landing_motion(rng, pivoting)
        u, vn, (P_n, P_t) = _sticking_edge(change, p_land, t, vel, omega, eps)
        if vn >= -0.05:
            continue  # not landing (or too slowly to be an impact: rest_speed)
        if sticking:
            mu = float(2.0 * abs(P_t) / P_n + 0.1)
        else:
            P_n = (-eps * vn - vn) / (change(n, p_land)[0] @ n)
            P_t, mu = 0.0, 0.0
        _, dv, dw = change(P_n * n + P_t * t, p_land)
        v_after, w_after = vel + dv, omega + dw
        pivot_after = min((v_after + np.cross(w_after, corners[i])) @ n for i in pivot)

        def energy(v, w):
            return 0.5 * m * float(v @ v) + 0.5 * float(w @ I @ w)

        if P_n > 0.0 and (not pivoting or pivot_after >= 1e-6 * abs(vn)) and not (
                sticking and energy(v_after, w_after) > energy(vel, omega) * (1 + 1e-12)):
            break
    else:
        pytest.fail("no landing drawn in 1000 tries")
    _lands_as(mode, eps, mu, m, R, size, corners, vel, omega, abs(vn), v_after, w_after)


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("pivoting", [True, False], ids=["from-a-pivot", "in-flight"])
@pytest.mark.parametrize("seed", range(24))
def test_a_whole_step_of_an_edge_landing_sliding_matches_the_planar_impact(seed, pivoting,
                                                                           mode):
    """The edge landings above with too little friction to stop the edge: mu is 0.1 to
    0.9 of what sticking would need, so the landing edge slides through the impact. Truth:
    the planar impact at the landing edge with Coulomb friction at its limit against the
    slip, solved here: P = P_n (n + sigma mu t) with sigma the sense sticking would push
    in, P_n from Newton's law along n; the draw is kept when that is consistent (P_n > 0,
    the edge still slipping against the friction afterwards, by more than 1e-6 of the
    approach speed, so sticking is not also a solution) and, as above, when the pivot
    leaves and no energy is gained. Each landing corner then takes half of P (the box is
    symmetric about the plane through its centre across the edge). Tolerance 1e-9 of the
    approach speed, as above. On the tree before, located mode failed 38 of its 48 (an
    impact whose points could not all stick was solved as normal impulses, then friction:
    with eps = 1 one left at 1.48 m/s instead of 1.80), stepped mode none."""
    rng = np.random.default_rng(9700 + seed + 100 * (not pivoting))
    eps = float((0.0, 0.3, 0.5, 1.0)[seed % 4])
    n = np.array([0.0, 1.0, 0.0])
    for _ in range(1000):
        R, size, m, I, corners, pivot, landing, omega, vel, t, p_land, change = \
            _landing_motion(rng, pivoting)
        u, vn, (P_n, P_t) = _sticking_edge(change, p_land, t, vel, omega, eps)
        if vn >= -0.05:
            continue  # not landing (or too slowly to be an impact: rest_speed)
        if not P_n > 0.0 or abs(P_t) <= 1e-3 * P_n:
            continue  # no friction needed to stick: nothing slides
        sigma = 1.0 if P_t > 0.0 else -1.0
        mu = float(rng.uniform(0.1, 0.9) * abs(P_t) / P_n)
        d = n + sigma * mu * t
        P_n = (-eps * vn - vn) / (change(d, p_land)[0] @ n)
        slip = float((u + change(P_n * d, p_land)[0]) @ t)
        _, dv, dw = change(P_n * d, p_land)
        v_after, w_after = vel + dv, omega + dw
        pivot_after = min((v_after + np.cross(w_after, corners[i])) @ n for i in pivot)

        def energy(v, w):
            return 0.5 * m * float(v @ v) + 0.5 * float(w @ I @ w)

        if P_n > 0.0 and sigma * slip < -1e-6 * abs(vn) and (
                not pivoting or pivot_after >= 1e-6 * abs(vn)) and \
                energy(v_after, w_after) <= energy(vel, omega) * (1 - 1e-12):
            break
    else:
        pytest.fail("no landing drawn in 1000 tries")
    _lands_as(mode, eps, mu, m, R, size, corners, vel, omega, abs(vn), v_after, w_after)


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("seed", range(24))
def test_a_whole_step_of_a_flat_landing_with_sticking_friction(seed, mode):
    """A box lands flat on a face (random size, mass, turn about the vertical), sliding
    at up to half its approach speed, no spin, mu = 3, one 1 ms step without gravity.
    Truth: Newton's law and sticking at every corner, which a flat face allows when the
    friction's moment about the centre, h m |u_t|, is within half of what the normal
    impulses can balance, (1 + eps) m |v_n| times the face's smaller half-width (drawn
    so): the box leaves at (0, -eps v_n, 0) without spin. Tolerance 1e-9 of the approach
    speed (round-off of the solves). A review found the class left short in stepped mode
    (its 4 of 16 on 3d5071e and on 2952280; these 24: 2 stepped failed on 2952280, by
    1.7e-8 and 2.3e-4 of |v_n|): the impact's sweeps stopped before converging; now such
    an impact is solved at once (`kernels.stepped._direct_impact`)."""
    rng = np.random.default_rng(9500 + seed)
    eps = float((0.0, 0.3, 0.5, 1.0)[seed % 4])
    for _ in range(1000):
        size, m, R, corners = _face_down_pose(rng)
        h = float(-corners[:, 1].min())
        half = 0.5 * min(np.linalg.norm(corners[1] - corners[0]),
                         np.linalg.norm(corners[2] - corners[0]))
        vn = -float(rng.uniform(0.1, 5.0))
        ut = rng.normal(size=2)
        ut *= float(rng.uniform(0.0, 0.5)) * abs(vn) / np.linalg.norm(ut)
        if h * np.linalg.norm(ut) <= 0.5 * (1.0 + eps) * abs(vn) * half:
            break
    else:
        pytest.fail("no landing drawn in 1000 tries")
    s = _one_step_on_ground(mode, eps, 3.0, m, R, size, h, np.array([ut[0], vn, ut[1]]),
                            np.zeros(3))
    scale = abs(vn)
    assert np.abs(s.body_vel[1] - [0.0, -eps * vn, 0.0]).max() <= 1e-9 * scale, s.body_vel[1]
    assert np.abs(s.body_angvel[1]).max() * np.abs(corners).max() <= 1e-9 * scale, \
        s.body_angvel[1]


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("seed", range(40))
def test_a_whole_step_of_a_flat_landing_that_friction_stops(seed, mode):
    """A box lands flat on a face (random size, mass, turn about the vertical) sliding in
    a random direction at 0.2-0.98 of what friction can stop, mu 0.05-1.5, no spin, one
    1 ms step without gravity. Truth: every corner sticks and leaves at -eps v_n: the box
    at (0, -eps v_n, 0) without spin, when the normal impulses can balance the
    friction's moment: their centre lies h |u_t| / ((1 + eps) |v_n|) from the face's
    centre along the slip, drawn within 0.8 of the face. Tolerance 1e-9 of the approach
    speed. The test above (mu 3, slip <= half the approach, centre within half the face)
    passed; a review's draws nearer the limits found located mode wrong in 22 of 100 (up
    to 0.63 of |v_n|, spun) and stepped mode in 5 (up to 9e-4): the minimum-norm share
    of the friction among the corners left the lightly loaded trailing corners' cones,
    and the impact was solved as sliding (now `solver._inside_cones`,
    `kernels.stepped._inside_cones`). On the tree before: located failed 10, stepped 4
    of these 40."""
    rng = np.random.default_rng(9300 + seed)
    eps = float((0.0, 0.3, 0.5, 1.0)[seed % 4])
    size, m, R, corners, h, vn, mu, s, ut = _flat_landing(
        rng, eps, 1.5, (0.2, 0.98), lambda h, mu, ut, vn: h * float(np.linalg.norm(ut)) /
        ((1.0 + eps) * abs(vn)), 0.8)
    st = _one_step_on_ground(mode, eps, mu, m, R, size, h, np.array([ut[0], vn, ut[1]]),
                             np.zeros(3))
    scale = abs(vn)
    assert np.abs(st.body_vel[1] - [0.0, -eps * vn, 0.0]).max() <= 1e-9 * scale, \
        st.body_vel[1]
    assert np.abs(st.body_angvel[1]).max() * np.abs(corners).max() <= 1e-9 * scale, \
        st.body_angvel[1]


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("seed", range(24))
def test_a_whole_step_of_a_flat_landing_sliding_on(seed, mode):
    """A box lands flat on a face (random size, mass, turn about the vertical) sliding
    faster than friction can stop, no spin, mu 0.05-1, one 1 ms step without gravity.
    Truth: every corner leaves at -eps v_n and slides on against mu times its normal
    impulse: the box leaves at u_t - mu (1 + eps) |v_n| s along the slip s, at -eps v_n
    along the normal, without spin, when the slip does not stop (|u_t| > mu (1 + eps)
    |v_n|, by 1e-3 of it at least) and the normal impulses can balance the friction's
    moment about the centre: their centre lies h mu from the face's centre along s
    (h the centre's height), drawn within half of the face. Every solution of the
    impact (the corners' share of the normal impulse is not unique) gives these
    velocities. Tolerance 1e-9 of the approach speed (round-off of the solves). On the
    tree before, located mode failed all 24 (normal impulses, then friction) and
    stepped mode 4 (its sweeps over the four corners stopped short)."""
    rng = np.random.default_rng(9900 + seed)
    eps = float((0.0, 0.3, 0.5, 1.0)[seed % 4])
    size, m, R, corners, h, vn, mu, s, ut = _flat_landing(
        rng, eps, 1.0, (1.001, 3.0), lambda h, mu, ut, vn: h * mu, 0.5)
    stop = mu * (1.0 + eps) * abs(vn)
    s_ = _one_step_on_ground(mode, eps, mu, m, R, size, h, np.array([ut[0], vn, ut[1]]),
                             np.zeros(3))
    after = ut - stop * s
    scale = abs(vn)
    assert np.abs(s_.body_vel[1] - [after[0], -eps * vn, after[1]]).max() <= 1e-9 * scale, \
        (s_.body_vel[1], after)
    assert np.abs(s_.body_angvel[1]).max() * np.abs(corners).max() <= 1e-9 * scale, \
        s_.body_angvel[1]


def _sticking_edge(change, p_land, t, vel, omega, eps):
    """The landing edge's velocity u, its normal part v_n, and the planar impact (P_n,
    P_t) that leaves it at (0, -eps v_n) across and along the normal (+y)."""
    n = np.array([0.0, 1.0, 0.0])
    u = vel + np.cross(omega, p_land)
    vn = float(u @ n)
    K = np.array([[change(d1, p_land)[0] @ d2 for d1 in (n, t)] for d2 in (n, t)])
    return u, vn, np.linalg.solve(K, np.array([-eps * vn - vn, -(u @ t)]))


def _lands_as(mode, eps, mu, m, R, size, corners, vel, omega, speed, v_after, w_after):
    """One step of the landing (`_one_step_on_ground`, the face's corners on the ground)
    leaves the box at v_after, w_after, to 1e-9 of the approach speed."""
    s = _one_step_on_ground(mode, eps, mu, m, R, size, float(-corners[:, 1].min()), vel,
                            omega)
    assert np.abs(s.body_vel[1] - v_after).max() <= 1e-9 * speed, (s.body_vel[1], v_after)
    assert np.abs(s.body_angvel[1] - w_after).max() * np.abs(corners).max() <= 1e-9 * speed, \
        (s.body_angvel[1], w_after)


def _flat_landing(rng, eps, mu_top, shares, centre, within):
    """A box about to land flat on a face (`_face_down_pose`), sliding: (size, m, R,
    corners, h its centre's height, v_n, mu log-uniform in [0.05, mu_top], s the slip's
    unit direction (x, z), u_t (x, z) at `shares` of the slip friction stops, mu (1 +
    eps) |v_n|), drawn again until the normal impulses' centre, centre(h, mu, u_t, v_n)
    from the face's centre along s, lies within `within` of the face."""
    for _ in range(1000):
        size, m, R, corners = _face_down_pose(rng)
        h = float(-corners[:, 1].min())
        e1, e2 = corners[1] - corners[0], corners[2] - corners[0]
        vn = -float(rng.uniform(0.1, 5.0))
        mu = float(np.exp(rng.uniform(np.log(0.05), np.log(mu_top))))
        s = rng.normal(size=2)
        s /= np.linalg.norm(s)
        ut = s * mu * (1.0 + eps) * abs(vn) * float(rng.uniform(*shares))
        d = centre(h, mu, ut, vn) * np.array([s[0], 0.0, s[1]])
        if all(abs(d @ e) <= within / 2 * (e @ e) for e in (e1, e2)):
            return size, m, R, corners, h, vn, mu, s, ut
    pytest.fail("no landing drawn in 1000 tries")


def _one_step_on_ground(mode, eps, mu, m, R, size, height, vel, omega):
    """The final state of one 1 ms step, no gravity, symplectic Euler, impacts `mode`,
    of a box (mass m, rotation R, size) with its centre `height` above a ground plane,
    moving at vel and omega (world), both with restitution eps and friction mu."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    dt = 1e-3
    _, _, s = simulate(f"""
vrsim: 1
duration: {dt!r}
frame_rate: {1 / dt!r}
dt: {dt!r}
integrator: symplectic-euler
gravity: [0, 0, 0]
collision: {{impacts: {mode}}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}},
     material: {{restitution: {eps}, friction: {mu!r}}}}}
  - {{name: box, mass: {m!r}, position: [0, {height!r}, 0],
     orientation: {[float(w), float(x), float(y), float(z)]},
     velocity: {[float(c) for c in vel]}, angular_velocity: {[float(c) for c in omega]},
     shape: {{type: box, size: {size.tolist()}}},
     material: {{restitution: {eps}, friction: {mu!r}}}}}
""")
    return s
