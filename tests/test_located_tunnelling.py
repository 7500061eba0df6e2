"""No tunnelling in the default `located` impact mode (issue 15, item 1): a seeded property
test of fast bodies against thin boxes, static and dynamic.

Spheres, boxes and capsules at 10-1000 m/s (log-uniform, up to 10 % of it sideways) meet a
1 cm thick box at a random time (j + tau) dt, j in {0, 1, 2}, tau in (0.01, 0.99), dt 10 ms,
eps in {0, 0.5, 1}, frictionless, no gravity, no spin before the impact. A step's travel is
up to 10 m, 1000 times the wall's thickness. Two families (`impact_cases`, built like
the stepped mode's `test_stepped.bullet_cases`, whose helpers it uses, but keeping the
poses the truth needs):

- static walls (10 m x 10 m);
- dynamic plates (1-3 m square, 1 cm thick, 5-50 kg, moving at up to 50 m/s themselves),
  hit near their middle by the bullet: two free bodies against each other.

Truth, written here and independent of the code under test: before its first impact a
body translates at constant velocity (no gravity, no spin; symplectic Euler is exact), so
the first contact is the bullet's extreme point along -n (sphere: r n below the centre;
box: its lowest corner; capsule: the lowest end cap's pole) touching the face of normal n,
at the constructed time. The frictionless rigid impact at that point, arms r_A, r_B from
the centres of mass, relative normal velocity v_n < 0, gives the impulse

    j = -(1 + eps) v_n / (1/m_A + 1/m_B + n.((I_A^-1 (r_A x n)) x r_A)
                                        + n.((I_B^-1 (r_B x n)) x r_B))

(Newton's restitution at the contact point; a static wall has 1/m = 0, I^-1 = 0), with the
inertia tensors of uniform solids (box m/12 (b^2 + c^2), ...; capsule: cylinder plus two
hemispheres). Checked per case:
1. the bullet never ends up past the obstacle: at every step its centre stays on its own
   side of the obstacle's mid-plane (static wall) or outside the prism behind the plate's
   face (plate, in the plate's current frame);
2. the first impact is found at the constructed time and its impulse is j n to 1e-9
   relative (the impact time is located to 1e-13 of a step and the impulse is a closed
   form of round-off-exact positions: 1e-9 leaves room for the arms' round-off at
   positions up to 1 km from the origin). The time to 1e-9 s, except that it may come
   early by up to tolerance / closing speed: with many cases in one scene, another
   case's impact instant gives an impulse to every contact within the tolerance (1 mm)
   that approaches (j is then the closed form at that instant: the bullet's arm changes
   along n only, which leaves r x n alone, but a plate's arm moves with the sliding
   velocity), and late by 1e-6 m of travel (the capsule-box distance is found by a
   golden-section search). Orientations whose next vertex lies within twice the
   tolerance of the face at the touch are redrawn: detection would report both points,
   and the impact would be a two-point one;
3. when that impact is the bullet's only one and the pair never rests in contact (with
   eps = 0 a bullet may stay on a turning plate), the final velocity is v + j n / m and
   the final angular momentum (world; conserved in free flight) is r x j n, to 1e-9
   relative.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from conftest import simulate
from test_stepped import (SPACING, WALL_HALF_SIDE, WALL_HALF_THICKNESS, _rot, _unit_quat,
                          random_shape)

DT = 0.01
TOLERANCE = 1e-3  # m, collision.tolerance (default)
LATE = 1e-6  # m: the capsule-box distance is a golden-section search (narrowphase.py)


def inertia(kind, size, m=1.0) -> np.ndarray:
    """Body-frame inertia tensor (3, 3) kg m^2 of a uniform solid of mass m."""
    if kind == "sphere":
        return np.eye(3) * 0.4 * m * size[0] ** 2
    if kind == "box":
        a, b, c = size
        return np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 12.0
    r, length = size  # capsule along local y
    vc, vs = np.pi * r * r * length, 4.0 / 3.0 * np.pi * r ** 3
    mc, ms = m * vc / (vc + vs), m * vs / (vc + vs)
    axial = 0.5 * mc * r * r + 0.4 * ms * r * r
    perp = mc * (length ** 2 / 12.0 + r * r / 4.0) + \
        ms * (0.4 * r * r + length ** 2 / 4.0 + 3.0 * length * r / 8.0)
    return np.diag([perp, axial, perp])


def contact_arm(kind, size, R, n) -> np.ndarray:
    """Arm (3,) m from the centre to the bullet's first point of contact with a face of
    outward normal n (the bullet comes from the +n side): its extreme point along -n."""
    if kind == "sphere":
        return -size[0] * n
    if kind == "box":
        corners = [R @ (0.5 * np.array(size) * s) for s in
                   np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)]
        return min(corners, key=lambda c: float(n @ c))
    ends = [R @ np.array([0.0, 0.5 * size[1] * s, 0.0]) for s in (-1.0, 1.0)]
    return min(ends, key=lambda e: float(n @ e)) - size[0] * n


def second_point_gap(kind, size, R, n) -> float:
    """m: how much farther along n than the first point of contact the next vertex (box
    corner, capsule end cap) is: with it within the tolerance at the impact, detection
    reports both and the impact is at two points (not the one-point closed form)."""
    if kind == "sphere":
        return np.inf
    if kind == "box":
        heights = sorted(float(n @ (R @ (0.5 * np.array(size) * s))) for s in
                         np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3))
        return heights[1] - heights[0]
    return abs(float(n @ (R @ np.array([0.0, size[1], 0.0]))))


def effective_inverse_mass(inv_m, inv_I_world, r, n) -> float:
    return inv_m + float(n @ np.cross(inv_I_world @ np.cross(r, n), r))


def impact_cases(kind, eps, count, seed, plates, spin=None):
    """`count` cases in one scene, case c = bodies 2c (the obstacle) and 2c + 1 (the
    bullet, 1 kg, random size and orientation, no spin). Obstacle: a static 1 cm box wall
    10 m x 10 m (`plates` False), or a dynamic 1 cm plate, side 1-3 m, 5-50 kg, moving at
    up to 50 m/s without spin. The bullet closes on the obstacle's face at 10-1000 m/s
    (log-uniform) plus up to 10 % of that sideways, and its extreme point along -n touches
    the face at a random time (j + tau) dt, j in {0, 1, 2}, within 1 m (wall) or 0.2 m
    (plate) of its middle. Orientations whose next vertex is within twice the tolerance
    of the face at that time are redrawn (`second_point_gap`). `spin` (rad/s): the bullet
    also spins, at a log-uniform rate in [spin / 100, spin] about a random axis (drawn
    after everything else, so the cases are those without spin, spinning); its first
    contact is then near, not at, the constructed time. Returns (scene text, cases)."""
    rng = np.random.default_rng(seed)
    lines = [f"vrsim: 1\nduration: {4 * DT}\nframe_rate: {1 / DT}\ndt: {DT}\n"
             f"integrator: symplectic-euler\ngravity: [0, 0, 0]\n"
             f"collision: {{impacts: located}}\nbodies:"]
    cases = []
    side = int(np.ceil(count ** (1 / 3)))
    material = f"material: {{restitution: {eps}, friction: 0}}"
    for c in range(count):
        centre = SPACING * np.array([c % side, (c // side) % side, c // side ** 2], float)
        qp = _unit_quat(rng)
        n = _rot(qp)[:, 2]  # the obstacle's thin axis, towards the bullet
        if plates:
            half = float(rng.uniform(0.5, 1.5))
            mass = float(np.exp(rng.uniform(np.log(5.0), np.log(50.0))))
            plate_vel = rng.normal(size=3) * rng.uniform(0.0, 50.0) / np.sqrt(3.0)
            reach = 0.2
        else:
            half, mass, plate_vel, reach = WALL_HALF_SIDE, None, np.zeros(3), 1.0
        osize = [2 * half, 2 * half, 2 * WALL_HALF_THICKNESS]
        size, shape = random_shape(rng, kind)
        while True:  # one point of first contact: the next is beyond the tolerance
            qb = _unit_quat(rng)
            R = _rot(qb)
            if second_point_gap(kind, size, R, n) > 2.0 * TOLERANCE:
                break
        speed = float(np.exp(rng.uniform(np.log(10.0), np.log(1000.0))))
        tangent = np.cross(n, rng.normal(size=3))
        tangent /= np.linalg.norm(tangent)
        rel = -speed * n + rng.uniform(0.0, 0.1) * speed * tangent
        vel = plate_vel + rel
        when = (int(rng.integers(0, 3)) + float(rng.uniform(0.01, 0.99))) * DT
        arm = contact_arm(kind, size, R, n)
        lateral = np.cross(n, rng.normal(size=3))
        lateral *= rng.uniform(0.0, reach) / np.linalg.norm(lateral)
        plate_then = centre + plate_vel * when
        touch = plate_then + lateral + WALL_HALF_THICKNESS * n  # on the face at `when`
        pos = touch - arm - vel * when
        if plates:
            lines.append(f"  - {{name: p{c}, mass: {mass!r}, position: {centre.tolist()!r}, "
                         f"orientation: {qp.tolist()!r}, velocity: {plate_vel.tolist()!r}, "
                         f"shape: {{type: box, size: {osize!r}}}, {material}}}")
        else:
            lines.append(f"  - {{name: w{c}, type: static, position: {centre.tolist()!r}, "
                         f"orientation: {qp.tolist()!r}, shape: {{type: box, size: "
                         f"{osize!r}}}, {material}}}")
        omega = np.zeros(3)
        if spin is not None:
            axis = rng.normal(size=3)
            omega = axis / np.linalg.norm(axis) * float(
                np.exp(rng.uniform(np.log(spin / 100.0), np.log(spin))))
        lines.append(f"  - {{name: b{c}, mass: 1, position: {pos.tolist()!r}, orientation: "
                     f"{qb.tolist()!r}, velocity: {vel.tolist()!r}, angular_velocity: "
                     f"{omega.tolist()!r}, shape: {shape}, {material}}}")
        inv_I = R @ np.linalg.inv(inertia(kind, size)) @ R.T
        k = effective_inverse_mass(1.0, inv_I, arm, n)
        plate = None
        if plates:
            Rp = _rot(qp)
            plate = (1.0 / mass, Rp @ np.linalg.inv(inertia("box", osize, mass)) @ Rp.T,
                     touch - plate_then)

        def impulse(at, n=n, rel=rel, k=k, plate=plate, when=when):
            """The impulse (3,) N s on the bullet if the impact is at time `at` (within
            the tolerance of `when`): the plate's arm moves with the relative sliding."""
            kk = k if plate is None else k + effective_inverse_mass(
                plate[0], plate[1], plate[2] + rel * (at - when), n)
            return -(1.0 + eps) * float(n @ rel) / kk * n

        cases.append(dict(obstacle=2 * c, bullet=2 * c + 1, centre=centre, normal=n,
                          closing=-float(n @ rel), half=half, when=when, vel=vel,
                          speed=speed, impulse=impulse, arm=arm, size=size,
                          mass=1.0 if mass is None else mass, osize=osize))
    return "\n".join(lines) + "\n", cases


def impact_events(states, a, b):
    """Sorted times (s) of the impact events of the pair a < b over the run, the impulse
    (3,) N s on b at the first one (summed over its points), and whether the pair was
    ever in resting contact at a step's end (then it exchanged resting impulses too)."""
    times, first, resting = [], None, False
    t0 = 0.0
    for s in states[1:]:
        c = s.contacts
        pair = (c.body_a == a) & (c.body_b == b)
        rows = np.flatnonzero(pair & ~np.isnan(c.toi))
        resting |= bool((pair & np.isnan(c.toi)).any())
        for toi in sorted(set(c.toi[rows].tolist())):
            times.append(t0 + toi)
            if first is None:
                first = s.contact_impulse[rows[c.toi[rows] == toi]].sum(axis=0)
        t0 = s.t
    return times, first, resting


def run_cases(kind, eps, count, seed, plates):
    """Failures of the three checks (module docstring) over one scene of cases."""
    text, cases = impact_cases(kind, eps, count, seed, plates)
    model, states, final = simulate(text)
    assert model.response.impacts == "located"
    rot_row = {int(body): k for k, body in enumerate(model.rigid.rot_index)}
    through, wrong, motion = [], [], []
    for case in cases:
        o, b, n, h = case["obstacle"], case["bullet"], case["normal"], case["half"]
        for s in states:
            if plates:  # the bullet's centre in the plate's current frame
                local = s.rot_matrix[rot_row[o]].T @ (s.body_pos[b] - s.body_pos[o])
                past = abs(local[0]) < h and abs(local[1]) < h and -h < local[2] <= 0.0
            else:
                past = not float(n @ (s.body_pos[b] - case["centre"])) > 0.0
            if past:
                through.append((b, round(case["speed"], 1), round(s.t, 3)))
                break
        times, impulse, resting = impact_events(states, o, b)
        early = TOLERANCE / case["closing"] + 1e-9  # s
        late = LATE / case["closing"] + 1e-9
        if not times or not -early <= times[0] - case["when"] <= late:
            wrong.append((b, round(case["speed"], 1), times[:1], case["when"]))
            continue
        want = case["impulse"](times[0])
        scale = float(np.abs(want).max())
        if not np.abs(impulse - want).max() <= 1e-9 * scale:
            wrong.append((b, round(case["speed"], 1), times[0], impulse, want))
        elif len(times) == 1 and not resting:
            v = case["vel"] + want
            L = final.rot_angmom[rot_row[b]]
            if not (np.abs(final.body_vel[b] - v).max() <= 1e-9 * case["speed"] and
                    np.abs(L - np.cross(case["arm"], want)).max() <= 1e-9 * max(scale, 1)):
                motion.append((b, final.body_vel[b], v, L, np.cross(case["arm"], want)))
    return through, wrong, motion


# 1008 cases: static walls 3 kinds x 3 eps x 14 scenes x 6 = 756, plates 3 x 3 x 4 x 7
# = 252. A scene holds few cases: every impact cuts the step of all of them, and the
# march to the next impact steps as finely as its fastest spinning pair needs (after
# MARCH_STEPS it samples the rest of the step: see docs/collision-response.md).
WALLS, PLATES = (14, 6), (4, 7)  # (scenes, cases per scene)
SCENES = [(kind, eps, plates, k) for kind in ("sphere", "box", "capsule")
          for eps in (0.0, 0.5, 1.0) for plates, (count, _) in ((False, WALLS), (True, PLATES))
          for k in range(count)]
# Known failures (none of the 1008 cases), strict: the day they pass, the mark must go.
KNOWN: dict = {}
# The suite (CI) runs every third scene, the known failures among them (~1/3 of the
# ~2.5 min of CPU the whole set takes); VRSIM_SLOW_TESTS=1 runs all 1008 cases, as for
# the closing notes.
# Scenes that once failed always run: a capsule's impact found 0.1 mm late (the root of
# the least gap stopped unconverged, test_the_time_of_impact_root_converges_...), and a
# capsule at 661 m/s, eps 0, that tunnelled through a plate (it sank into it while
# spinning about its contact point: test_spinning_capsules_...).
ONCE_FAILED = {("capsule", 0.0, False, 13), ("capsule", 0.0, True, 1)}
FULL = os.environ.get("VRSIM_SLOW_TESTS") == "1"
RUN = [p for i, p in enumerate(SCENES) if FULL or i % 3 == 0 or p in KNOWN or p in ONCE_FAILED]


def _marks(p):
    if p in KNOWN:
        return [pytest.mark.xfail(strict=True, reason=KNOWN[p])]
    return []


PARAMS = [pytest.param(*p, marks=_marks(p)) for p in RUN]


@pytest.mark.parametrize("kind, eps, plates, k", PARAMS)
def test_fast_bodies_do_not_tunnel_and_obey_the_impact_law(kind, eps, plates, k):
    """Checks 1-3 of the module docstring over one scene of cases (6 walls or 7
    plates), seeded by the parameters."""
    count = (PLATES if plates else WALLS)[1]
    seed = 1000 * ("sphere", "box", "capsule").index(kind) + 100 * int(2 * eps) + \
        10 * int(plates) + k
    through, wrong, motion = run_cases(kind, eps, count, seed, plates)
    assert not through, f"{len(through)} of {count} went through: {through}"
    assert not wrong, f"{len(wrong)} of {count} broke the impact law: {wrong}"
    assert not motion, f"{len(motion)} of {count} left with the wrong motion: {motion}"


def test_the_cases_number_at_least_a_thousand():
    assert sum((PLATES if plates else WALLS)[1] for _, _, plates, _ in SCENES) == 1008


def test_the_time_of_impact_root_converges_on_a_kinked_least_gap():
    """`response._root` on G = min(resting gap, bullet gap): a pair resting 1e-13-1e-9 m
    apart (with round-off wobble) is the least gap until a bullet's gap, closing at
    10-1000 m/s, crosses it; the root is the bullet's touch, known in closed form. Plain
    Illinois regula falsi crawled here (each secant step ~ floor / speed) and stopped
    after its 200 steps up to 2e-7 s late (the '0.1 mm late' capsule of this file). The
    bound is the root's own tolerance, 1e-13 of the step, plus the time the bullet takes
    to close the floor (below it G is the floor, not the bullet's gap)."""
    from vrsim_cli.stages.collision.response import ROOT_TOLERANCE, _root

    rng = np.random.default_rng(15)
    late = []
    for _ in range(300):
        h = float(rng.uniform(1e-4, 1e-2))
        floor = float(np.exp(rng.uniform(np.log(1e-13), np.log(1e-9))))
        speed = float(np.exp(rng.uniform(np.log(10.0), np.log(1000.0))))
        touch = float(rng.uniform(0.01, 0.99)) * h
        phase = float(rng.uniform(0.0, 6.0))

        def gap(t, floor=floor, speed=speed, touch=touch, phase=phase):
            wobble = floor * (1.0 + 1e-3 * np.sin(1e9 * t + phase))
            return min(wobble, speed * (touch - t))

        hi = _root(gap, 0.0, gap(0.0), h, gap(h), h)
        if not (gap(hi) <= 0.0 and
                touch - 1.01 * floor / speed - ROOT_TOLERANCE * h <= hi <=
                touch + ROOT_TOLERANCE * h):
            late.append((h, floor, speed, touch, hi - touch))
    assert not late, f"{len(late)} of 300 roots off: {late[:5]}"



def kinetic_energy(kind, size, m, state, body) -> float:
    """J: 1/2 m v.v + 1/2 w.(R I R^T) w of one body, with the test's own inertia."""
    R = _rot(state.body_quat[body])
    w, v = state.body_angvel[body], state.body_vel[body]
    return 0.5 * m * float(v @ v) + 0.5 * float(w @ (R @ inertia(kind, size, m) @ R.T @ w))


def capsule_depth(case, state, plates) -> float:
    """m: how deep the bullet capsule's lowest point is below the obstacle's face on its
    own side (<= 0: not touching); for a plate only while both end caps are over the
    face (beyond its edge the face does not hold it)."""
    o, b = case["obstacle"], case["bullet"]
    r, length = case["size"]
    axis = _rot(state.body_quat[b])[:, 1]
    ends = [state.body_pos[b] + s * 0.5 * length * axis for s in (-1.0, 1.0)]
    if not plates:
        n = case["normal"]
        return max(r + WALL_HALF_THICKNESS - float(n @ (e - case["centre"])) for e in ends)
    Rp, h = _rot(state.body_quat[o]), case["half"]
    local = [Rp.T @ (e - state.body_pos[o]) for e in ends]
    if any(abs(p[0]) > h - r or abs(p[1]) > h - r for p in local):
        return -np.inf
    return max(r + WALL_HALF_THICKNESS - p[2] for p in local)


SPIN = 300.0  # rad/s: the bullets' largest spin (log-uniform down to 3 rad/s)
SPIN_SCENES = [(plates, k) for plates in (False, True) for k in range(12 if FULL else 4)]


@pytest.mark.parametrize("plates, k", SPIN_SCENES)
def test_spinning_capsules_with_eps_0_stay_out_of_thin_walls_and_plates(plates, k):
    """Capsules spinning at up to SPIN about random axes, 10-1000 m/s, random poses, eps 0,
    against 1 cm static walls or dynamic plates (`impact_cases` with spin; 4 per scene):
    after a plastic impact a spinning capsule turns about its contact point, which can
    curve into the face at |w|^2 r (a capsule at 240 rad/s sank 6.6 cm into a plate in one
    step and left through its far side). Checked at every step's end, against truth
    computed here: the centre stays on its own side (walls) or out of the prism behind
    the plate; the lowest end cap is no deeper below the face than the collision
    tolerance (the march's bound on a missed overlap; position correction at the step's
    end takes it out); the kinetic energy of bullet and plate (the test's own inertia)
    never exceeds its initial value (eps 0; free flight by the exact flow; 1e-12 relative
    for round-off, as in test_impact_energy)."""
    count = 4
    text, cases = impact_cases("capsule", 0.0, count, 7000 + 100 * int(plates) + k, plates,
                               spin=SPIN)
    # the exact torque-free flow: the default splitting changes a spinning capsule's
    # energy by ~1e-5 per step by itself, which would hide a gain from the response
    text = text.replace("bodies:", "rotation: {free_flow: exact}\nbodies:", 1)
    model, states, final = simulate(text)
    rot_row = {int(body): j for j, body in enumerate(model.rigid.rot_index)}
    bad = []
    for case in cases:
        o, b, n, h = case["obstacle"], case["bullet"], case["normal"], case["half"]

        def energy(s, case=case, o=o, b=b):
            e = kinetic_energy("capsule", case["size"], 1.0, s, b)
            return e + (kinetic_energy("box", case["osize"], case["mass"], s, o)
                        if plates else 0.0)

        e0 = energy(states[0])
        for s in states[1:]:
            if plates:
                local = s.rot_matrix[rot_row[o]].T @ (s.body_pos[b] - s.body_pos[o])
                past = abs(local[0]) < h and abs(local[1]) < h and -h < local[2] <= 0.0
            else:
                past = not float(n @ (s.body_pos[b] - case["centre"])) > 0.0
            depth = capsule_depth(case, s, plates)
            gain = energy(s) - e0
            if past or depth > TOLERANCE or gain > 1e-12 * e0:
                bad.append((b, round(case["speed"], 1), round(s.t, 3), past, depth, gain))
                break
    assert not bad, f"{len(bad)} of {count}: (bullet, speed, t, past, depth, gain) {bad}"
