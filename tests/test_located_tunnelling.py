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
import re

import numpy as np
import pytest

from conftest import simulate
from test_stepped import (SPACING, WALL_HALF_SIDE, WALL_HALF_THICKNESS, _rot, _unit_quat,
                          dot, matvec, norm, random_shape)

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
        corners = [matvec(R, 0.5 * np.array(size) * s) for s in
                   np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)]
        return min(corners, key=lambda c: dot(n, c))
    ends = [matvec(R, np.array([0.0, 0.5 * size[1] * s, 0.0])) for s in (-1.0, 1.0)]
    return min(ends, key=lambda e: dot(n, e)) - size[0] * n


def second_point_gap(kind, size, R, n) -> float:
    """m: how much farther along n than the first point of contact the next vertex (box
    corner, capsule end cap) is: with it within the tolerance at the impact, detection
    reports both and the impact is at two points (not the one-point closed form)."""
    if kind == "sphere":
        return np.inf
    if kind == "box":
        heights = sorted(dot(n, matvec(R, 0.5 * np.array(size) * s)) for s in
                         np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3))
        return heights[1] - heights[0]
    return abs(dot(n, matvec(R, np.array([0.0, size[1], 0.0]))))


def effective_inverse_mass(inv_m, inv_I_world, r, n) -> float:
    return inv_m + float(n @ np.cross(inv_I_world @ np.cross(r, n), r))


def impact_cases(kind, eps, count, seed, plates):
    """`count` cases in one scene, case c = bodies 2c (the obstacle) and 2c + 1 (the
    bullet, 1 kg, random size and orientation, no spin). Obstacle: a static 1 cm box wall
    10 m x 10 m (`plates` False), or a dynamic 1 cm plate, side 1-3 m, 5-50 kg, moving at
    up to 50 m/s without spin. The bullet closes on the obstacle's face at 10-1000 m/s
    (log-uniform) plus up to 10 % of that sideways, and its extreme point along -n touches
    the face at a random time (j + tau) dt, j in {0, 1, 2}, within 1 m (wall) or 0.2 m
    (plate) of its middle. Orientations whose next vertex is within twice the tolerance
    of the face at that time are redrawn (`second_point_gap`). Returns (scene text,
    cases)."""
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
        tangent /= norm(tangent)
        rel = -speed * n + rng.uniform(0.0, 0.1) * speed * tangent
        vel = plate_vel + rel
        when = (int(rng.integers(0, 3)) + float(rng.uniform(0.01, 0.99))) * DT
        arm = contact_arm(kind, size, R, n)
        lateral = np.cross(n, rng.normal(size=3))
        lateral *= rng.uniform(0.0, reach) / norm(lateral)
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
        lines.append(f"  - {{name: b{c}, mass: 1, position: {pos.tolist()!r}, orientation: "
                     f"{qb.tolist()!r}, velocity: {vel.tolist()!r}, shape: {shape}, "
                     f"{material}}}")
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
                          speed=speed, impulse=impulse, arm=arm))
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


def nudged(text, seed, ulps=4):
    """The scene `text` with every nonzero position coordinate moved by a random whole
    number of ulps in [-ulps, ulps] (`seed`): the same scene to round-off."""
    rng = np.random.default_rng(seed)

    def move(match):
        values = [float(x) for x in match.group(1).split(",")]
        values = [float(v + np.spacing(v) * int(rng.integers(-ulps, ulps + 1))) if v else v
                  for v in values]
        return f"position: {values!r}"
    return re.sub(r"position: \[([^\]]*)\]", move, text)


def repeated_events(states) -> int:
    """Event contact rows that repeat within a step (same pair, point and time of impact):
    an impact found again at the instant it was solved."""
    repeats = 0
    for s in states[1:]:
        c = s.contacts
        seen = set()
        for row in np.flatnonzero(~np.isnan(c.toi)).tolist():
            key = (int(c.body_a[row]), int(c.body_b[row]), tuple(c.point[row].tolist()),
                   float(c.toi[row]))
            repeats += key in seen
            seen.add(key)
    return repeats


def run_cases(kind, eps, count, seed, plates, nudge=None, states_out=None):
    """Failures of the three checks (module docstring) over one scene of cases; `nudge`:
    the seed of `nudged` (the scene moved by ulps), `states_out`: a list that receives
    the run's states."""
    text, cases = impact_cases(kind, eps, count, seed, plates)
    if nudge is not None:
        text = nudged(text, nudge)
    model, states, final = simulate(text)
    if states_out is not None:
        states_out.extend(states)
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
# The suite (CI) runs every third scene and the two capsule scenes that failed before the
# event search watched touching pairs for sinking (~1/3 of the ~2.5 min of CPU the whole
# set takes); VRSIM_SLOW_TESTS=1 runs all 1008 cases, as for the closing notes.
FULL = os.environ.get("VRSIM_SLOW_TESTS") == "1"
# (a capsule at 661 m/s through a plate, eps 0: its touching end held the least gap at ~0
# while the other end came down; and a capsule's first impact found 0.1 mm late)
ONCE_FAILED = {("capsule", 0.0, True, 1), ("capsule", 0.0, False, 13)}
RUN = [p for i, p in enumerate(SCENES) if FULL or i % 3 == 0 or p in ONCE_FAILED]
PARAMS = [pytest.param(*p) for p in RUN]


@pytest.mark.parametrize("kind, eps, plates, k", PARAMS)
def test_fast_bodies_do_not_tunnel_and_obey_the_impact_law(kind, eps, plates, k):
    """Checks 1-3 of the module docstring over one scene of cases (6 walls or 7
    plates), seeded by the parameters; and no impact is found twice at one instant."""
    count = (PLATES if plates else WALLS)[1]
    seed = 1000 * ("sphere", "box", "capsule").index(kind) + 100 * int(2 * eps) + \
        10 * int(plates) + k
    states = []
    through, wrong, motion = run_cases(kind, eps, count, seed, plates, states_out=states)
    assert repeated_events(states) == 0  # (see test_an_impact_just_solved_...)
    assert not through, f"{len(through)} of {count} went through: {through}"
    assert not wrong, f"{len(wrong)} of {count} broke the impact law: {wrong}"
    assert not motion, f"{len(motion)} of {count} left with the wrong motion: {motion}"


def test_the_cases_number_at_least_a_thousand():
    assert sum((PLATES if plates else WALLS)[1] for _, _, plates, _ in SCENES) == 1008


# Scenes of box bullets (eps 0, static walls) whose plastic impacts at two corners, at
# 200 m from the origin, left the corners approaching at ~1e-11 m/s of round-off: the
# same impact was found again at tau = 0 until the step's 64 events ran out (124 and
# 427 repeated event rows), so later impacts in the step went unlocated (a bullet at
# 421 m/s passed through its wall in scene 12, two impacts broke the law in each).
# Each with a few ulps of nudges too: the outcome must not hinge on the last bits.
SOLVED_AGAIN = [("box", 0.0, False, k, nudge) for k in (5, 12) for nudge in (None, 1, 2)]


@pytest.mark.parametrize("kind, eps, plates, k, nudge", SOLVED_AGAIN)
def test_an_impact_just_solved_is_not_found_again(kind, eps, plates, k, nudge):
    """What an impact solve leaves of a contact's approach (round-off) is not a new impact
    at the same instant: no step holds the same event row twice, and checks 1-3 of the
    module docstring hold."""
    count = (PLATES if plates else WALLS)[1]
    seed = 1000 * ("sphere", "box", "capsule").index(kind) + 100 * int(2 * eps) + \
        10 * int(plates) + k
    states = []
    through, wrong, motion = run_cases(kind, eps, count, seed, plates,
                                       None if nudge is None else 10 * seed + nudge, states)
    assert repeated_events(states) == 0
    assert not through, f"{len(through)} of {count} went through: {through}"
    assert not wrong, f"{len(wrong)} of {count} broke the impact law: {wrong}"
    assert not motion, f"{len(motion)} of {count} left with the wrong motion: {motion}"


def test_more_impacts_in_a_step_than_the_fixed_budget_are_all_located():
    """80 box bullets (10-1000 m/s, ε = 0) hitting their 1 cm walls take up to 98 impact
    events in one step. With a fixed budget of 64 events per step (until 2026-12-05) the
    rest of the step went unlocated: 12 bullets passed through their walls and 19 broke
    the impact law (an independent review; also 100 and 125 bullets: 17 and 30 through).
    The budget grows with the dynamic bodies (`response.EVENTS_PER_BODY`): checks 1-3 of
    the module docstring hold for all 80."""
    states = []
    through, wrong, motion = run_cases("box", 0.0, 80, 8080, False, None, states)
    assert max(len(set(s.contacts.toi[~np.isnan(s.contacts.toi)].tolist()))
               for s in states[1:]) > 64  # the scene needs more than the old budget
    assert repeated_events(states) == 0
    assert not through, f"{len(through)} of 80 went through: {through}"
    assert not wrong, f"{len(wrong)} of 80 broke the impact law: {wrong}"
    assert not motion, f"{len(motion)} of 80 left with the wrong motion: {motion}"


TUMBLING_KNOWN = "a capsule tumbling and sliding at 55 m/s over the plate sinks a quarter of " \
    "the plate's thinness per event (`response.THROUGH_SHARE`), 14 events in one step: " \
    "through in the next (docs/collision-response.md, Known limits)"


@pytest.mark.parametrize("seed", [7102, 7116,
                                  pytest.param(7108, marks=pytest.mark.xfail(
                                      strict=True, reason=TUMBLING_KNOWN))])
def test_a_capsule_tumbling_on_a_dynamic_plate_stays_on_its_side(seed):
    """Capsules at 10-1000 m/s against 1 cm dynamic plates, ε = 0 (seeds outside the
    main test's): after the impact the capsule spins and slides over the plate, which
    spins too. Watching the pair for sinking, `_resting_fall`'s material bound measured
    the contact points along the plate's turning normal while they slid apart, and read
    metres of sinking in a step (1.2 m in a quarter step): the capsule's other end went
    through the plate unseen. Of seeds 7100-7129, 5 scenes had a capsule through its
    plate before (7102, 7108, 7116, 7118, 7124; an independent review found 7102), 1
    since the bound counts at most a quarter of the thinner body (7108, kept here as a
    strict xfail). Checks 1-3 of the module docstring."""
    states = []
    through, wrong, motion = run_cases("capsule", 0.0, 7, seed, True, None, states)
    assert repeated_events(states) == 0
    assert not through, f"{len(through)} of 7 went through: {through}"
    assert not wrong, f"{len(wrong)} of 7 broke the impact law: {wrong}"
    assert not motion, f"{len(motion)} of 7 left with the wrong motion: {motion}"
