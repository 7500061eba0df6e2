"""Pairs that go through fcl (cylinders against cylinders, boxes and capsules) when they
touch or overlap by less than fcl's collide resolves.

libccd's GJK/EPA in fcl misses overlaps of such pairs up to ~1e-6 m (65 % of random poses
at 1e-9 m); fcl's distance then returns -1 (its "in collision") without points, or 0 with
NaN points when the shapes exactly touch. vrsim took the -1 for a gap and reported a
depth of 1 m (a cylinder flush against a box was refused as "interpenetrating by 1 m",
and one in a run was thrown), and the NaN points for a contact (two cylinders standing
side by side, exactly touching: NaN in the first step). Truth here: the construction.
B is placed along a direction u at the offset where it just touches A (closed form for
axis-aligned poses; else bisection on fcl's distance, which is reliable while the shapes
are apart), then moved back by a known overlap.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vrsim_cli.maths.spatial import quat_from_euler_deg, quat_normalize
from vrsim_cli.model.collision import analytic_geom, table
from vrsim_cli.stages.collision.detect import narrow_phase
from vrsim_cli.stages.collision.shapes import place

I = [1.0, 0.0, 0.0, 0.0]
CYL = {"type": "cylinder", "radius": 0.1, "length": 0.4}
SHAPES = {"cylinder": CYL, "box": {"type": "box", "size": [0.4, 0.3, 0.2]},
          "capsule": {"type": "capsule", "radius": 0.08, "length": 0.3}}
OVERLAPS = (0.0, 1e-12, 1e-9, 1e-7)  # m: all below what fcl's collide resolves reliably
# Near touching, vrsim measures such a pair by pushing it 1e-4 m (or more) together, where
# libccd's EPA works, and subtracting the push: EPA's own accuracy there (its depth off by
# up to 2.7e-7 m, its normal by up to 3.1e-3 rad for cylinders side by side and 1e-3 rad
# for capsules, measured on the poses of EXACT at 1e-4 m, where fcl is used unchanged)
# plus the push's second-order term (1e-4^2 / 0.08 m ~ 1.3e-7 m) bound the results.
DEPTH_TOL = 1e-6
NORMAL_TOL = 1e-2

def setup(shape_b, pos_b, quat_a=I, quat_b=I):
    cm = table([analytic_geom(0, CYL), analytic_geom(1, shape_b)])
    return cm, place(cm, np.array([[0.0, 0.0, 0.0], pos_b], float),
                     np.array([quat_a, quat_b], float))


def contacts(shape_b, pos_b, quat_a=I, quat_b=I, margin=1e-3):
    cm, world = setup(shape_b, pos_b, quat_a, quat_b)
    _, point, normal, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), margin)
    return point, normal, depth


# Axis-aligned poses with their touching offset in closed form: (B, direction, offset).
EXACT = [
    ("cylinder", [1.0, 0.0, 0.0], 0.2),  # standing side by side (the user's scene)
    ("cylinder", [0.0, 0.0, 1.0], 0.2),
    ("cylinder", [0.0, 1.0, 0.0], 0.4),  # end on end
    ("box", [1.0, 0.0, 0.0], 0.3),  # flush against a side face
    ("box", [0.0, 1.0, 0.0], 0.35),  # standing on (under) a face
    ("capsule", [1.0, 0.0, 0.0], 0.18),
]


@pytest.mark.parametrize("overlap", OVERLAPS)
@pytest.mark.parametrize("kind, direction, offset", EXACT)
def test_axis_aligned_touching_pairs_get_their_exact_contact(kind, direction, offset,
                                                              overlap):
    u = np.array(direction)
    point, normal, depth = contacts(SHAPES[kind], (offset - overlap) * u)
    assert len(depth) >= 1 and np.isfinite(point).all() and np.isfinite(normal).all()
    assert depth.max() == pytest.approx(overlap, abs=DEPTH_TOL)
    deepest = int(np.argmax(depth))
    assert np.linalg.norm(normal[deepest] - u) <= NORMAL_TOL


def _touching_offset(shape_b, u, quat_a, quat_b) -> float:
    """Offset along u at which B just touches A: bisection on fcl's distance (> 0 apart)."""
    from vrsim_cli.stages.collision import fcl_adapter

    lo, hi = 0.0, 2.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        cm, world = setup(shape_b, mid * u, quat_a, quat_b)
        d = fcl_adapter.distance(fcl_adapter.collision_object(cm, world, 0),
                                 fcl_adapter.collision_object(cm, world, 1))[0]
        if d > 0.0:
            hi = mid
        else:
            lo = mid
    return hi


def _unit_quat(rng):
    return quat_normalize(rng.normal(size=4))


@pytest.mark.parametrize("kind", sorted(SHAPES))
def test_randomly_posed_touching_pairs_never_report_a_made_up_contact(kind):
    """120 poses per kind (random orientations and directions), each at the overlaps
    above: one finite contact at least, unit normals on u's side, never the 1 m of fcl's
    -1, and a depth as accurate as fcl's own contact where its collide works: the error
    against the overlap along the normal, ov (n . u), over all poses and tiny overlaps is
    at most the largest error of fcl's contacts at 1e-4 m on the same poses (libccd's EPA
    on curved shapes: up to 2.4e-5 m measured) plus 1e-6 m."""
    rng = np.random.default_rng({"cylinder": 1, "box": 2, "capsule": 3}[kind])
    ours, fcls = [], []
    for _ in range(120):
        qa, qb = _unit_quat(rng), _unit_quat(rng)
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        s = _touching_offset(SHAPES[kind], u, qa, qb)
        for overlap in OVERLAPS + (1e-4,):
            point, normal, depth = contacts(SHAPES[kind], (s - overlap) * u, qa, qb)
            assert len(depth) >= 1, (qa, qb, u, overlap)
            assert np.isfinite(point).all() and np.isfinite(normal).all()
            assert not np.isclose(depth, 1.0).any()  # fcl's -1 taken for a gap
            np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-12)
            k = int(np.argmax(depth))
            assert normal[k] @ u > 0.0
            (fcls if overlap == 1e-4 else ours).append(depth[k] - overlap * (normal[k] @ u))
            # where it touches: on A's surface (the cylinder at the origin), within half
            # the largest push
            assert _cylinder_distance(point[k], qa) == pytest.approx(0.0, abs=1e-3)
    assert np.abs(ours).max() <= np.abs(fcls).max() + 1e-6


def _cylinder_distance(p, quat):
    """Signed distance of world point p from the cylinder CYL at the origin."""
    from vrsim_cli.maths.spatial import quat_to_matrix

    q = quat_to_matrix(np.asarray(quat, float)).T @ p
    dr, dy = math.hypot(q[0], q[2]) - CYL["radius"], abs(q[1]) - CYL["length"] / 2
    if dr > 0.0 or dy > 0.0:
        return math.hypot(max(dr, 0.0), max(dy, 0.0))
    return max(dr, dy)


SCENE = """
vrsim: 1
duration: 0.5
frame_rate: 60
dt: {dt}
integrator: {integrator}
collision: {{}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}}}
  - {{name: c0, mass: 1, position: [0, 0.2, 0], euler_deg: [0, {turn}, 0],
     shape: {{type: cylinder, radius: 0.1, length: 0.4}}}}
  - {{name: b, mass: 1, position: {pos}, euler_deg: [0, {turn}, 0], shape: {shape}}}
"""


@pytest.mark.parametrize("integrator, dt", [("symplectic-euler", 1 / 60), ("rk4", 1 / 240)])
@pytest.mark.parametrize("turn", [0.0, 30.0])
@pytest.mark.parametrize("neighbour", ["cylinder", "box"])
def test_a_cylinder_flush_against_a_neighbour_on_the_ground_stays_at_rest(neighbour, turn,
                                                                          integrator, dt):
    """The user's scenes: two cylinders standing exactly side by side (before: NaN in the
    first step), a cylinder flush against a box's side (before: refused, "interpenetrate
    by 1 m"). Nothing pushes them: they stay where they are to round-off."""
    from conftest import simulate

    c, s = math.cos(math.radians(turn)), math.sin(math.radians(turn))
    side = 0.2 if neighbour == "cylinder" else 0.3  # centre distance when touching
    shape = ("{type: cylinder, radius: 0.1, length: 0.4}" if neighbour == "cylinder"
             else "{type: box, size: [0.4, 0.4, 0.4]}")
    # euler y turns local x to (cos, 0, -sin): the neighbour stays flush across x
    pos = [side * c, 0.2, -side * s]
    _, states, final = simulate(SCENE.format(dt=dt, integrator=integrator, turn=turn,
                                             pos=pos, shape=shape))
    assert np.abs(final.body_vel[1:]).max() <= 1e-12
    assert np.abs(final.body_angvel[1:]).max() <= 1e-12
    np.testing.assert_allclose(final.body_pos[2], pos, atol=1e-12)


def test_quat_helper_is_what_the_scenes_use():
    """The turned scene's flush placement relies on euler y turning local x to
    (cos, 0, -sin)."""
    from vrsim_cli.maths.spatial import quat_to_matrix

    R = quat_to_matrix(np.asarray(quat_from_euler_deg([0.0, 30.0, 0.0]), float))
    np.testing.assert_allclose(R[:, 0], [math.cos(math.radians(30)), 0.0,
                                         -math.sin(math.radians(30))], atol=1e-15)
