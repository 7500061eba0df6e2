"""Cylinders against boxes and cylinders: contact manifolds (`cylinder_pairs`).

The audit's scenes: a cylinder standing on a box, a box on a standing cylinder's cap and
cylinders end on end rested on python-fcl's single deepest point and rocked (a 1 kg box
on a cylinder at 0.2-1.2 rad/s for 3 s, a can on a table at 0.15 rad/s). Each failing
test below fails on 30f01eb.

Truths:
- geometry, written here from the shapes (not from the code under test): a cylinder
  whose lower cap meets a box's face at a tilt th, in any pose of the whole pair, has its
  deepest point at the rim point lowest along the face normal; the manifold's normal is
  the face normal, its deepest depth is the lowest rim point's depth below the face, and
  every point lies on the cylinder's surface, inside the face's rectangle (and inside
  the cap's disc when the cap lies flat);
- statics: bodies placed at rest on each other, with their centres of mass over the
  contact area, stay at rest (every body within MOVE_TOL m and SPEED_TOL m/s after 1 s),
  in both impact modes, every integrator and dt;
- a cylinder standing on a box tilted by th (friction holding it) stays up when
  tan th <= 0.65 r / h and topples when tan th >= 1.15 r / h (statics of a rigid body on
  its rim, tan th = r / h at the threshold; below it the margin covers the 4 rim points
  kept, a square reaching 0.707 r in its worst direction). Between 0.707 and 1 the answer
  depends on the cylinder's turn about its axis, and near the threshold a resting
  cylinder can creep (docs/collision.md, Known limits).
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from conftest import simulate

from vrsim_cli.model.collision import BOX, CYLINDER
from vrsim_cli.stages.collision.narrowphase import narrow_phase
from vrsim_cli.stages.collision.shapes import WorldGeoms

SPEED_TOL = 1e-9  # m/s, rad/s: held bodies move by round-off only (~1e-15 per step)
MOVE_TOL = 1e-9  # m
GEOM_TOL = 1e-9  # m: the manifold's depths and points against the closed forms


def quat_to_matrix(q):
    """Rotation matrix of a unit quaternion (w, x, y, z), written here."""
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


class _Cm:
    """The collision model fields the pair functions read, for two geoms."""

    def __init__(self, types, radius, half):
        self.geom_type = np.array(types)
        self.geom_radius = np.array(radius, float)
        self.geom_half = np.array(half, float)
        self.geom_world_aabb = np.zeros(len(types), bool)
        self.cache = {}


def _rotation(rng):
    q = rng.normal(size=4)
    return quat_to_matrix(q / np.linalg.norm(q))


def _about(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def _cylinder_on_box(rng, tilt):
    """A box (half extents) and a cylinder (r, h) standing on the box's +y face, tilted
    by `tilt` rad about a random horizontal axis, its lowest rim point `depth` m below
    the face, all turned by a random rotation G. Returns the world poses, the radius
    array and the truths (face normal, deepest depth, face half extents, G, centre)."""
    half = rng.uniform(0.2, 1.0, 3)
    r, h = rng.uniform(0.05, 0.15), rng.uniform(0.05, 0.4)
    depth = rng.uniform(1e-6, 1e-3)
    yaw = rng.uniform(0, 2 * math.pi)
    axis_dir = rng.uniform(0, 2 * math.pi)
    Rc = _about((math.cos(axis_dir), 0, math.sin(axis_dir)), tilt) @ _about((0, 1, 0), yaw)
    a = Rc[:, 1]
    # the lowest rim point of the lower cap: centre - h a - r u, u the unit of the
    # vertical's part across the axis (any rim point when upright)
    up = np.array([0.0, 1.0, 0.0])
    low = h * a[1] + r * math.sqrt(max(0.0, 1.0 - a[1] ** 2))  # centre height over it
    offset = rng.uniform(-1, 1, 2) * max(0.0, min(half[0], half[2]) - r - h * math.sin(tilt) - 0.01)
    centre = np.array([offset[0], half[1] + low - depth, offset[1]])
    G = _rotation(rng)
    shift = rng.uniform(-2, 2, 3)
    pos = np.array([shift, G @ centre + shift])
    rot = np.array([G, G @ Rc])
    halves = np.array([half, (r, h, r)])
    world = WorldGeoms(pos, rot, halves)
    return world, _Cm([BOX, CYLINDER], [0.0, r], halves), {
        "normal": G @ up, "depth": depth, "half": half, "G": G, "shift": shift, "r": r,
        "h": h, "Rc": G @ Rc, "centre": pos[1]}


@pytest.mark.parametrize("seed", range(200))
def test_a_cylinder_on_a_box_face_gets_the_closed_form_manifold(seed):
    rng = np.random.default_rng(seed)
    tilt = 0.0 if seed % 4 == 0 else float(rng.uniform(0.0, 0.6)) if seed % 4 != 1 else 1e-4
    world, cm, truth = _cylinder_on_box(rng, tilt)
    margin = 0.0
    for swap in (False, True):  # box first and cylinder first: normals flip
        ia, ib = (np.array([1]), np.array([0])) if swap else (np.array([0]), np.array([1]))
        pair, point, normal, depth = narrow_phase(cm, world, ia, ib, margin)
        assert len(pair) >= 1
        n = -normal if swap else normal
        assert np.abs(n - truth["normal"]).max() <= 1e-12, (seed, n, truth["normal"])
        assert abs(depth.max() - truth["depth"]) <= GEOM_TOL, (seed, depth, truth["depth"])
        G, shift, half = truth["G"], truth["shift"], truth["half"]
        for p, d in zip(point, depth):
            # the witness point on the cylinder: the midpoint less half the depth along n
            on_cyl = p - 0.5 * d * truth["normal"]
            local = truth["Rc"].T @ (on_cyl - truth["centre"])
            radial = math.hypot(local[0], local[2])
            assert radial <= truth["r"] + GEOM_TOL and abs(local[1]) <= truth["h"] + GEOM_TOL
            on_face = G.T @ (p - shift)  # box frame: inside the +y face's rectangle
            assert abs(on_face[0]) <= half[0] + GEOM_TOL and abs(on_face[2]) <= half[2] + GEOM_TOL
            # depth below the face plane, measured here
            assert abs((half[1] - (G.T @ (on_cyl - shift))[1]) - d) <= GEOM_TOL
        if tilt == 0.0:
            # flat: the cap's 8 rim points, all at the same depth, around its centre
            assert len(depth) == 8
            assert np.abs(depth - truth["depth"]).max() <= GEOM_TOL
            below = truth["centre"] - truth["h"] * truth["Rc"][:, 1]
            spread = np.linalg.norm(point - 0.5 * truth["depth"] * truth["normal"] - below,
                                    axis=1)
            assert np.abs(spread - truth["r"]).max() <= GEOM_TOL
            assert np.linalg.norm(point.mean(axis=0) - 0.5 * truth["depth"] *
                                  truth["normal"] - below) <= 0.3 * truth["r"]


# ----------------------------------------------------------------------------- statics


def _scene(bodies, dt, integrator, mode, mu, duration=1.0, frame_rate=10):
    impacts = f"{{impacts: {mode}}}" if mode != "located" else "{}"
    return f"""
vrsim: 1
duration: {duration!r}
frame_rate: {frame_rate!r}
dt: {dt!r}
integrator: {integrator}
collision: {impacts}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}},
     material: {{friction: {mu!r}}}}}
""" + "\n".join(bodies) + "\n"


def _body(name, kind, pos, shape, mu, mass=None, euler=(0, 0, 0)):
    head = f"  - {{name: {name}, " + ("type: static, " if kind == "static" else
                                       f"mass: {mass!r}, ")
    return (head + f"position: [{pos[0]!r}, {pos[1]!r}, {pos[2]!r}], euler_deg: "
            f"[{euler[0]!r}, {euler[1]!r}, {euler[2]!r}], shape: {shape}, "
            f"material: {{friction: {mu!r}}}}}")


def _cyl(r, h):
    return f"{{type: cylinder, radius: {r!r}, length: {2 * h!r}}}"


def _box(hx, hy, hz):
    return f"{{type: box, size: [{2 * hx!r}, {2 * hy!r}, {2 * hz!r}]}}"


def stack_draw(seed: int):
    """A random resting stack with a cylinder pair in it (kind = seed % 6): a cylinder on
    a static or dynamic box, a box on a static or dynamic standing cylinder, two
    cylinders end on end, a cylinder lying on a box. Sizes, offsets (centres of mass over
    the contact area), yaw, masses, friction, dt, integrator and impact mode random."""
    rng = np.random.default_rng(1000 + seed)
    kind = seed % 6
    mu = float(rng.uniform(0.3, 1.0))
    dt = (1 / 60, 1 / 100, 1 / 240)[int(rng.integers(3))]
    integrator = ("symplectic-euler", "verlet", "rk4")[int(rng.integers(3))]
    mode = ("located", "stepped")[(seed // 6) % 2]
    r, h = float(rng.uniform(0.05, 0.2)), float(rng.uniform(0.05, 0.3))
    bx, by, bz = (float(x) for x in rng.uniform(0.15, 0.5, 3))
    yaw = float(rng.uniform(0, 360))
    m1, m2 = (float(x) for x in rng.uniform(0.2, 5.0, 2))
    bodies = []
    if kind in (0, 1):  # cylinder on a box (static, or dynamic on the ground)
        static = kind == 0
        bodies.append(_body("box", "static" if static else "dyn", (0.0, by, 0.0),
                            _box(bx, by, bz), mu, m1))
        off = rng.uniform(-1, 1, 2) * (np.array([bx, bz]) - r) * 0.9
        bodies.append(_body("cyl", "dyn", (float(off[0]), 2 * by + h, float(off[1])),
                            _cyl(r, h), mu, m2, (0, yaw, 0)))
    elif kind in (2, 3):  # box on a standing cylinder (static, or dynamic on the ground)
        static = kind == 2
        bodies.append(_body("post", "static" if static else "dyn", (0.0, h, 0.0),
                            _cyl(r, h), mu, m1, (0, yaw, 0)))
        off = rng.uniform(-1, 1, 2) * r * 0.4
        bodies.append(_body("lid", "dyn", (float(off[0]), 2 * h + by * 0.3, float(off[1])),
                            _box(bx, by * 0.3, bz), mu, m2, (0, float(rng.uniform(0, 90)), 0)))
    elif kind == 4:  # cylinders end on end
        r2, h2 = float(rng.uniform(0.05, 0.2)), float(rng.uniform(0.05, 0.3))
        bodies.append(_body("c1", "dyn", (0.0, h, 0.0), _cyl(r, h), mu, m1, (0, yaw, 0)))
        off = rng.uniform(-1, 1, 2) * min(r, r2) * 0.4
        bodies.append(_body("c2", "dyn", (float(off[0]), 2 * h + h2, float(off[1])),
                            _cyl(r2, h2), mu, m2, (0, float(rng.uniform(0, 360)), 0)))
    else:  # a cylinder lying on a box, its axis level at a random yaw
        bodies.append(_body("box", "static", (0.0, by, 0.0), _box(bx, by, bz), mu))
        h = min(h, 0.8 * min(bx, bz))
        bodies.append(_body("cyl", "dyn", (0.0, 2 * by + r, 0.0), _cyl(r, h), mu, m2,
                            (90, 0, yaw)))
    return _scene(bodies, dt, integrator, mode, mu), (kind, mode, dt, integrator, r, h)


# Stepped mode's envelope of the 30f01eb round (the stacks' settling then: up to 2.9e-5 m,
# 5.5e-6 m/s, 2.8e-5 rad/s after 1 s; every draw broke it on fcl's single point, up to 1
# cm and 0.67 rad/s). Since the shock levels are solved at once (kernels.stepped.
# _shock_direct) every draw also holds the strict 1e-9 truth above; the 8 stepped draws
# of KNOWN_STEPPED failed it on ef508f0 (strict xfails then).
STEPPED_MOVE, STEPPED_SPEED, STEPPED_TURN = 6e-5, 2e-5, 1e-4  # m, m/s, rad/s after 1 s


@functools.cache
def _stack_run(seed):
    """(model, final state, case) of `stack_draw(seed)` after its 1 s; run once per worker
    for both tests of the stepped draws (the file runs on one worker: --dist loadfile)."""
    text, case = stack_draw(seed)
    model, _, final = simulate(text)
    return model, final, case


@pytest.mark.parametrize("seed", range(24))
def test_resting_cylinder_stacks_stay_at_rest(seed):
    model, final, case = _stack_run(seed)
    moved = np.abs(final.body_pos - model.body_pos0).max()
    assert np.abs(final.body_vel).max() <= SPEED_TOL, case
    assert np.abs(final.body_angvel).max() <= SPEED_TOL, case
    assert moved <= MOVE_TOL, (case, moved)


@pytest.mark.parametrize("seed", [k for k in range(24) if (k // 6) % 2 == 1])
def test_stepped_cylinder_stacks_do_not_rock(seed):
    """Before, on fcl's single point, every one of these rocked (up to 0.67 rad/s, 1 cm)."""
    model, final, case = _stack_run(seed)
    assert np.abs(final.body_pos - model.body_pos0).max() <= STEPPED_MOVE, case
    assert np.abs(final.body_vel).max() <= STEPPED_SPEED, case
    assert np.abs(final.body_angvel).max() <= STEPPED_TURN, case


# ----------------------------------------------------------------------------- tipping


@pytest.mark.parametrize("seed", range(12))
def test_a_cylinder_on_a_tilted_box_stays_up_or_topples_as_statics_says(seed):
    rng = np.random.default_rng(2000 + seed)
    r, h = float(rng.uniform(0.05, 0.15)), float(rng.uniform(0.1, 0.4))
    stays = seed % 2 == 0
    # below: 0.85 r / h, inside the reach of the cap's 8 rim points (an octagon inscribed
    # in the disc reaches r cos 22.5 deg = 0.924 r in its worst direction); above:
    # 1.15 r / h
    tan = (0.85 if stays else 1.15) * r / h
    theta = math.atan(tan)
    mu = 2.0 * tan + 0.2  # friction holds it from sliding
    yaw = float(rng.uniform(0, 360))
    c, s = math.cos(theta), math.sin(theta)
    normal = np.array([-s, c, 0.0])
    half = (1.0, 0.2, 1.0)
    box_centre = np.zeros(3)
    top = box_centre + half[1] * normal
    centre = top + h * normal
    bodies = [_body("slab", "static", (0.0, 0.0, 0.0), _box(*half), mu,
                    euler=(0, 0, math.degrees(theta))),
              # turned about its own axis by `yaw` first (world x, y, z order): the rim
              # polygon's corners point anywhere around the slope
              _body("cyl", "dyn", tuple(float(x) for x in centre), _cyl(r, h), mu, 1.0,
                    (0, yaw, math.degrees(theta)))]
    # held: 1 s at 1/120 s is 120 steps of round-off; toppling: 1.5 s to fall past 0.3 rad
    text = _scene(bodies, 1 / 120 if stays else 1 / 240, "rk4", "located", mu,
                  duration=1.0 if stays else 1.5)
    model, _, final = simulate(text)
    q = final.body_quat[2]
    axis = quat_to_matrix(q / np.linalg.norm(q))[:, 1]
    lean = math.acos(min(1.0, abs(float(axis @ normal))))
    if stays:
        assert lean <= 1e-6 and np.abs(final.body_pos[2] - model.body_pos0[2]).max() <= 1e-6, \
            (seed, lean)
    else:
        assert lean >= 0.3, (seed, lean)


# ----------------------------------------------------------------------------- plane


@pytest.mark.parametrize("seed", range(24))
def test_plane_cylinder_is_the_same_in_both_detections_and_flat_caps_keep_their_points(seed):
    """A cylinder on the ground plane, tilted 0, 1e-6, 3e-3 (a flat cap: within 0.01 rad)
    or 0.2 rad: the stepped kernel's contacts equal the numpy detection's (points,
    normals, depths to 1e-12 m; tilted: the depths and the deepest point), and a flat
    cap's contacts are its four rim points at the body's local x and z and, once tilted,
    its lowest rim point, computed here."""
    from vrsim_cli.kernels import collide as kc
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.stages.collision import stepped as stage
    from vrsim_cli.stages.collision.detect import detect
    from vrsim_cli.stages.dynamics import motion as dynamics

    rng = np.random.default_rng(3000 + seed)
    r, h = float(rng.uniform(0.05, 0.2)), float(rng.uniform(0.01, 0.3))
    tilt = (0.0, 1e-6, 3e-3, 0.2)[seed % 4]
    sink = float(rng.uniform(0.0, 1e-3))
    euler = (math.degrees(tilt), float(rng.uniform(0, 360)), 0.5 * math.degrees(tilt))
    text = _scene([_body("c", "dyn", (0.1, h * math.cos(tilt) - sink, -0.2), _cyl(r, h),
                         0.5, 1.0, euler)], 0.01, "symplectic-euler", "stepped", 0.5)
    model = compile_model(parse_scene(text))
    state = make_state(model)
    ref = detect(model, state)
    tb = stage.tables(model, dynamics)
    S, RS = np.zeros_like(tb["S"]), np.zeros_like(tb["RS"])
    stage._rows(model, state, S, RS)
    k, C, _, _ = kc.detect(tb["gf"], S, 0, np.zeros(model.n_body), model.collision.tolerance,
                           False)
    want = np.concatenate([ref.point, ref.normal, ref.depth[:, None]], axis=1)
    got = np.concatenate([C[:k, kc.C_P:kc.C_P + 3], C[:k, kc.C_N:kc.C_N + 3],
                          C[:k, kc.C_D:kc.C_D + 1]], axis=1)
    assert got.shape == want.shape
    if tilt >= 0.01:
        # tilted: the 4 deepest of 8 rim points, where rim points of equal depth (to
        # round-off, computed in different orders) may be picked differently: the depths
        # and the deepest point agree
        assert np.abs(np.sort(got[:, 6]) - np.sort(want[:, 6])).max() <= 1e-12
        deepest = np.argmax(got[:, 6]), np.argmax(want[:, 6])
        assert np.abs(got[deepest[0]] - want[deepest[1]]).max() <= 1e-12
        return
    assert np.abs(got - want).max() <= 1e-12
    q = state.body_quat[1]
    R = quat_to_matrix(q / np.linalg.norm(q))
    axis = R[:, 1]
    bottom = state.body_pos[1] - h * axis * (1.0 if axis[1] > 0 else -1.0)
    radial = np.array([0.0, 1.0, 0.0]) - axis[1] * axis
    rims = [R[:, 0], R[:, 2], -R[:, 0], -R[:, 2]]
    if np.linalg.norm(radial) > 1e-9:
        rims.append(-radial / np.linalg.norm(radial))
    expect = np.array([bottom + r * d for d in rims])
    witness = ref.point - 0.5 * ref.depth[:, None] * ref.normal  # on the cylinder
    assert witness.shape == expect.shape
    assert np.abs(witness - expect).max() <= 1e-12
    assert np.abs(ref.depth - (-expect[:, 1])).max() <= 1e-12


# ----------------------------------------------------------------------------- touching


@pytest.mark.parametrize("seed", range(120))
def test_a_cylinder_touching_a_wide_face_anywhere_gets_the_face_normal(seed):
    """A cylinder standing on a wide box (up to 8 m) anywhere on its top face, touching
    it exactly or within 1e-9 m either way (where fcl's own tests do not resolve it and
    its probe answered with a normal across the face, 2.5 m from the centre: a can
    sliding there was stopped sideways in stepped mode), level (odd draws) or in any
    pose of the whole pair:
    every contact has the face's normal (1e-12) and the cap's depth (1e-9 m); the
    margin is a stepped step's at ~1 m/s (0.01 m)."""
    rng = np.random.default_rng(4000 + seed)
    half = np.array([rng.uniform(0.5, 4.0), rng.uniform(0.1, 0.5), rng.uniform(0.5, 4.0)])
    r, h = float(rng.uniform(0.05, 0.3)), float(rng.uniform(0.02, 0.3))
    gap = (0.0, 1e-12, -1e-12, 1e-9, -1e-9)[seed % 5]
    offset = rng.uniform(-1, 1, 2) * (half[[0, 2]] - r)
    Rc = _about((0, 1, 0), rng.uniform(0, 2 * math.pi))
    centre = np.array([offset[0], half[1] + h + gap, offset[1]])
    G, shift = _rotation(rng), rng.uniform(-3, 3, 3)
    if seed % 2:  # the usual scene: the box level and at the origin
        G, shift = np.eye(3), np.zeros(3)
    world = WorldGeoms(np.array([shift, G @ centre + shift]), np.array([G, G @ Rc]),
                       np.array([half, (r, h, r)]))
    cm = _Cm([BOX, CYLINDER], [0.0, r], world.half)
    pair, _, normal, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), 0.01)
    assert len(pair) >= 1
    assert np.abs(normal - G @ np.array([0.0, 1.0, 0.0])).max() <= 1e-12, (seed, normal)
    assert np.abs(depth + gap).max() <= 1e-9, (seed, depth, gap)


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("seed", range(3))
def test_a_cylinder_sliding_on_a_wide_box_stops_where_coulomb_says(mode, seed):
    """A cylinder sliding on its cap across a wide box, far from the box's centre: it
    slows at mu g and stops after v0^2 / (2 mu g) without turning. Located: the speed
    while it slides to 1e-6 of v0 (the issue's bound for sliding), the distance to 1e-4
    (a box in its place stops 6.9e-5 short in draw 1, and a cylinder on a plane 2.8e-5
    long: where the stop falls inside a step), no turning. Stepped: the distance within
    6 % (its sequential impulses; the same cylinder on a plane stops at 0.93-0.96 of it)
    and turning below 1e-3 rad/s (before the fix: 0.34 of the distance, 2 rad/s)."""
    rng = np.random.default_rng(5000 + seed)
    mu, v0 = float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.5, 1.5))
    r, h = float(rng.uniform(0.1, 0.25)), float(rng.uniform(0.04, 0.1))
    heading = float(rng.uniform(0, 2 * math.pi))
    vel = (v0 * math.cos(heading), 0.0, v0 * math.sin(heading))
    start = (float(rng.uniform(1.5, 2.5)), 0.5 + h, float(rng.uniform(-2.5, -1.5)))
    bodies = [_body("table", "static", (0.0, 0.25, 0.0), _box(3.5, 0.25, 3.5), mu),
              _body("can", "dyn", start, _cyl(r, h), mu, 0.6, (0, float(rng.uniform(0, 90)), 0))
              .replace("position:", f"velocity: [{vel[0]!r}, 0.0, {vel[2]!r}], position:")]
    model, states, final = simulate(_scene(bodies, 0.01, "rk4", mode, mu,
                                           duration=0.5 + v0 / (mu * 9.81)))
    slid = float(np.linalg.norm((final.body_pos[2] - model.body_pos0[2])[[0, 2]]))
    truth = v0 * v0 / (2.0 * mu * 9.81)
    spin = float(np.abs(final.body_angvel[2]).max())
    if mode == "located":
        for s in states:
            if 0.0 < s.t < 0.9 * v0 / (mu * 9.81):
                speed = float(np.linalg.norm(s.body_vel[2]))
                assert abs(speed - (v0 - mu * 9.81 * s.t)) <= 1e-6 * v0, (s.t, speed)
        assert abs(slid / truth - 1.0) <= 1e-4 and spin <= 1e-9, (slid, truth, spin)
    else:
        assert abs(slid / truth - 1.0) <= 0.06 and spin <= 1e-3, (slid, truth, spin)
