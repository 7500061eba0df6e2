"""Closed-form pair functions: hand-computed contacts, and agreement with python-fcl
(GJK/EPA and fcl's own primitive tests, an independent implementation) on random poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from conftest import compiled_detect
from vrsim_cli.maths.spatial import quat_from_axis_angle, quat_from_euler_deg, quat_normalize
from vrsim_cli.model.collision import analytic_geom, table
from vrsim_cli.stages.collision import fcl_adapter
from vrsim_cli.stages.collision.detect import narrow_phase
from vrsim_cli.stages.collision.narrowphase import box_box_distance
from vrsim_cli.stages.collision.shapes import place

I = [1.0, 0.0, 0.0, 0.0]
R2 = math.sqrt(2.0)


def sphere(r):
    return {"type": "sphere", "radius": r}


def box(*size):
    return {"type": "box", "size": list(size)}


def capsule(r, length):
    return {"type": "capsule", "radius": r, "length": length}


def plane(normal, offset=0.0):
    n = np.asarray(normal, float)
    return {"type": "plane", "normal": list(n / np.linalg.norm(n)), "offset": offset}


def setup(shape_a, shape_b, pos_a, pos_b, quat_a=I, quat_b=I):
    cm = table([analytic_geom(0, shape_a), analytic_geom(1, shape_b)])
    world = place(cm, np.array([pos_a, pos_b], float), np.array([quat_a, quat_b], float))
    return cm, world


def contacts(*args, margin=0.0):
    """(points (k, 3), normals (k, 3), depths (k,)) of geom 0 against geom 1."""
    cm, world = setup(*args)
    _, point, normal, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), margin)
    order = np.lexsort(point.T[::-1])
    return point[order], normal[order], depth[order]


# Hand-computed contacts are exact up to a few ulps of the inputs (~1 m): 1e-12.
TOL = 1e-12


def test_sphere_sphere_on_a_diagonal():
    d = np.array([1.0, 2.0, 2.0]) / 3.0  # unit
    p, n, depth = contacts(sphere(1.0), sphere(0.5), [1, 1, 1], np.add([1, 1, 1], 1.2 * d))
    assert depth == pytest.approx([0.3], abs=TOL)
    np.testing.assert_allclose(n, [d], atol=TOL)
    # Midway between A's surface point (1 along n) and B's deepest point (1.2 - 0.5).
    np.testing.assert_allclose(p, [np.add([1, 1, 1], 0.85 * d)], atol=TOL)


def test_separated_spheres_report_nothing_but_a_gap_within_the_margin():
    assert len(contacts(sphere(1.0), sphere(1.0), [0, 0, 0], [2.01, 0, 0])[2]) == 0
    _, _, depth = contacts(sphere(1.0), sphere(1.0), [0, 0, 0], [2.01, 0, 0], margin=0.02)
    assert depth == pytest.approx([-0.01], abs=TOL)


def test_tilted_plane_and_sphere_normal_from_plane_to_sphere():
    n = np.array([0.0, 1.0, 1.0]) / R2
    centre = np.array([0.3, 0.5, 0.5])  # n.c = 1/sqrt(2) = 0.7071
    p, normal, depth = contacts(plane(n, 0.5), sphere(0.3), [0, 0, 0], centre)
    assert depth == pytest.approx([0.3 - (1 / R2 - 0.5)], abs=TOL)
    np.testing.assert_allclose(normal, [n], atol=TOL)
    np.testing.assert_allclose(p, [centre - n * (0.3 - depth[0] / 2)], atol=TOL)
    # Swapped order: the normal still points from A (now the sphere) to B (the plane).
    _, normal, depth2 = contacts(sphere(0.3), plane(n, 0.5), centre, [0, 0, 0])
    np.testing.assert_allclose(normal, [-n], atol=TOL)
    assert depth2 == pytest.approx(depth, abs=TOL)


@pytest.mark.parametrize("centre, depth, normal, surface", [
    ([0.7, 0.0, 0.0], 0.3, [1, 0, 0], [0.5, 0, 0]),                       # face region
    ([0.8, 0.9, 0.0], 0.5 - math.hypot(0.3, 0.4), [0.6, 0.8, 0], [0.5, 0.5, 0]),  # edge
    ([0.1, 0.45, 0.0], 0.5 + 0.05, [0, 1, 0], [0.1, 0.5, 0]),             # centre inside
])
def test_box_sphere_face_edge_and_inside(centre, depth, normal, surface):
    p, n, d = contacts(box(1, 1, 1), sphere(0.5), [0, 0, 0], centre)
    assert d == pytest.approx([depth], abs=TOL)
    np.testing.assert_allclose(n, [normal], atol=TOL)
    deepest = np.asarray(centre) - 0.5 * np.asarray(normal, float)
    np.testing.assert_allclose(p, [0.5 * (np.asarray(surface) + deepest)], atol=TOL)


@pytest.mark.parametrize("centre, depth, normal, surface", [
    ([0.0, 0.9, 0.3], 0.1, [0, 1, 0], [0.0, 0.5, 0.3]),                   # over the cap
    ([0.0, 0.2, 0.7], 0.3, [0, 0, 1], [0.0, 0.2, 0.5]),                   # beside the side
    ([0.8, 0.9, 0.0], 0.5 - math.hypot(0.3, 0.4), [0.6, 0.8, 0], [0.5, 0.5, 0.0]),  # rim
    ([0.0, 0.45, 0.1], 0.5 + 0.05, [0, 1, 0], [0.0, 0.5, 0.1]),           # centre inside
])
def test_cylinder_sphere_cap_side_rim_and_inside(centre, depth, normal, surface):
    cyl = {"type": "cylinder", "radius": 0.5, "length": 1.0}
    p, n, d = contacts(cyl, sphere(0.5), [0, 0, 0], centre)
    assert d == pytest.approx([depth], abs=TOL)
    np.testing.assert_allclose(n, [normal], atol=TOL)
    deepest = np.asarray(centre) - 0.5 * np.asarray(normal, float)
    np.testing.assert_allclose(p, [0.5 * (np.asarray(surface) + deepest)], atol=TOL)


def test_box_on_an_edge_on_the_ground_gives_the_two_corners_of_that_edge():
    q = quat_from_axis_angle([0, 0, 1], math.pi / 4)
    p, n, d = contacts(plane([0, 1, 0]), box(1, 1, 1), [0, 0, 0], [0, R2 / 2 - 0.01, 0],
                       I, q)
    assert d == pytest.approx([0.01, 0.01], abs=TOL)
    np.testing.assert_allclose(n, [[0, 1, 0]] * 2, atol=TOL)
    np.testing.assert_allclose(p, [[0, -0.005, -0.5], [0, -0.005, 0.5]], atol=TOL)


def test_box_flat_on_the_ground_gives_four_corners():
    _, _, d = contacts(plane([0, 1, 0]), box(2, 1, 1), [0, 0, 0], [0, 0.48, 0])
    assert d == pytest.approx([0.02] * 4, abs=TOL)


def test_capsule_sphere_side_and_end_cap():
    # Side: axis along y from -0.5 to 0.5; sphere centre at x = 0.25 beside it.
    p, n, d = contacts(capsule(0.1, 1.0), sphere(0.2), [0, 0, 0], [0.25, 0.2, 0])
    assert d == pytest.approx([0.05], abs=TOL)
    np.testing.assert_allclose(n, [[1, 0, 0]], atol=TOL)
    np.testing.assert_allclose(p, [[0.075, 0.2, 0]], atol=TOL)
    # End cap: the closest axis point is the end (0, 0.5, 0).
    _, n, d = contacts(capsule(0.1, 1.0), sphere(0.2), [0, 0, 0], [0.18, 0.74, 0])
    assert d == pytest.approx([0.3 - 0.3], abs=TOL)
    np.testing.assert_allclose(n, [[0.6, 0.8, 0]], atol=TOL)


def test_crossing_capsules():
    qx = quat_from_axis_angle([1, 0, 0], math.pi / 2)  # second axis along z
    p, n, d = contacts(capsule(0.1, 1.0), capsule(0.1, 1.0), [0, 0, 0], [0.15, 0.2, 0.1],
                       I, qx)
    assert d == pytest.approx([0.05], abs=TOL)
    np.testing.assert_allclose(n, [[1, 0, 0]], atol=TOL)
    np.testing.assert_allclose(p, [[0.075, 0.2, 0.0]], atol=TOL)


def test_parallel_capsules_side_by_side_touch_along_the_overlap():
    # Both along y, 0.15 apart in x, the second shifted up by 0.3: the axes overlap for
    # y in [-0.2, 0.5]; two contacts at the ends of the overlap, depth 0.2 - 0.15.
    p, n, d = contacts(capsule(0.1, 1.0), capsule(0.1, 1.0), [0, 0, 0], [0.15, 0.3, 0])
    assert d == pytest.approx([0.05, 0.05], abs=TOL)
    np.testing.assert_allclose(n, [[1, 0, 0]] * 2, atol=TOL)
    np.testing.assert_allclose(p, [[0.075, -0.2, 0], [0.075, 0.5, 0]], atol=TOL)


def test_capsule_on_the_ground_flat_and_tilted():
    qz = quat_from_axis_angle([0, 0, 1], math.pi / 2)  # axis along x
    p, _, d = contacts(plane([0, 1, 0]), capsule(0.1, 1.0), [0, 0, 0], [0, 0.08, 0], I, qz)
    assert d == pytest.approx([0.02, 0.02], abs=TOL)
    np.testing.assert_allclose(p, [[-0.5, -0.01, 0], [0.5, -0.01, 0]], atol=TOL)
    tilt = quat_from_axis_angle([0, 0, 1], math.pi / 6)  # lower end at y = c - 0.5 cos 30
    _, _, d = contacts(plane([0, 1, 0]), capsule(0.1, 1.0), [0, 0, 0], [0, 0.5, 0], I, tilt)
    assert d == pytest.approx([0.1 - (0.5 - 0.5 * math.cos(math.pi / 6))], abs=TOL)


def test_capsule_on_a_box_face_and_along_an_edge_gives_two_points():
    qz = quat_from_axis_angle([0, 0, 1], math.pi / 2)
    p, n, d = contacts(box(2, 1, 1), capsule(0.1, 1.0), [0, 0, 0], [0, 0.57, 0], I, qz)
    assert d == pytest.approx([0.03, 0.03], abs=TOL)
    np.testing.assert_allclose(n, [[0, 1, 0]] * 2, atol=TOL)
    np.testing.assert_allclose(p, [[-0.5, 0.485, 0], [0.5, 0.485, 0]], atol=TOL)
    # Axis along z beside the box's edge x = 1, y = 0.5 (offset 0.06, 0.08): the edge
    # touches the whole axis, so both ends are contacts, at distance 0.1 from the edge.
    qx = quat_from_axis_angle([1, 0, 0], math.pi / 2)
    centre = np.array([1.0 + 0.06, 0.5 + 0.08, 0.0])
    p, n, d = contacts(box(2, 1, 1), capsule(0.2, 0.6), [0, 0, 0], centre, I, qx)
    assert d == pytest.approx([0.1, 0.1], abs=TOL)
    np.testing.assert_allclose(n, [[0.6, 0.8, 0]] * 2, atol=TOL)
    # Each point is halfway between the edge and the capsule's surface point.
    np.testing.assert_allclose(p[:, 2], [-0.3, 0.3], atol=TOL)


def test_capsule_across_a_box_edge_gives_one_point():
    # Horizontal axis along (1, 0, 1)/sqrt(2) at y = 0.65 across the top face's edge x = 1:
    # over the face it is 0.15 above (depth 0.05); the far end is beyond the edge.
    q = quat_from_euler_deg([90, 45, 0])
    centre = np.array([1.0, 0.5 + 0.15, 0.0])
    p, n, d = contacts(box(2, 1, 1), capsule(0.2, 0.6), [0, 0, 0], centre, I, q)
    assert len(d) == 1
    assert d == pytest.approx([0.05], abs=1e-9)  # golden-section: 1e-10 of the length
    np.testing.assert_allclose(n, [[0, 1, 0]], atol=1e-9)


def test_stacked_boxes_face_manifold_is_the_overlap_rectangle():
    p, n, d = contacts(box(1, 1, 1), box(1, 1, 1), [0, 0, 0], [0.1, 0.9, 0.2])
    assert d == pytest.approx([0.1] * 4, abs=TOL)
    np.testing.assert_allclose(n, [[0, 1, 0]] * 4, atol=TOL)
    # Overlap of the faces: x in [-0.4, 0.5], z in [-0.3, 0.5]; points halfway in depth.
    expected = [[x, 0.45, z] for x in (-0.4, 0.5) for z in (-0.3, 0.5)]
    np.testing.assert_allclose(p, expected, atol=TOL)


def test_crossed_edges_of_two_boxes():
    # A turned 45 deg about z: top edge along z at y = sqrt(2)/2. B turned 45 deg about x:
    # bottom edge along x at y = 1.3 - sqrt(2)/2. The edges cross at x = z = 0.
    qa, qb = quat_from_axis_angle([0, 0, 1], math.pi / 4), quat_from_axis_angle([1, 0, 0],
                                                                                math.pi / 4)
    p, n, d = contacts(box(1, 1, 1), box(1, 1, 1), [0, 0, 0], [0, 1.3, 0], qa, qb)
    assert d == pytest.approx([R2 - 1.3], abs=TOL)
    np.testing.assert_allclose(n, [[0, 1, 0]], atol=TOL)
    np.testing.assert_allclose(p, [[0, 0.65, 0]], atol=TOL)


def test_box_resting_on_a_turned_box_keeps_the_face_normal():
    q = quat_from_euler_deg([0, 30, 0])
    p, n, d = contacts(box(1, 1, 1), box(1, 1, 1), [0, 0, 0], [0, 0.95, 0], I, q)
    assert len(d) == 4 and d == pytest.approx([0.05] * 4, abs=TOL)
    np.testing.assert_allclose(n, [[0, 1, 0]] * 4, atol=TOL)
    assert np.all(np.abs(p[:, [0, 2]]) <= 0.5 + TOL)  # inside the lower box's top face


# --------------------------------------------------------------- agreement with fcl

unit = st.floats(-1.0, 1.0, allow_nan=False)
size = st.floats(0.1, 1.0, allow_nan=False)
vec3 = st.tuples(unit, unit, unit)
quat = st.tuples(unit, unit, unit, unit).filter(lambda q: sum(c * c for c in q) > 0.01)

SHAPES = {
    "sphere": st.builds(sphere, size),
    "box": st.builds(lambda x, y, z: box(2 * x, 2 * y, 2 * z), size, size, size),
    "capsule": st.builds(lambda r, h: capsule(0.5 * r, 2 * h), size, size),
    "cylinder": st.builds(lambda r, h: {"type": "cylinder", "radius": 0.5 * r,
                                        "length": 2 * h}, size, size),
    "plane": st.builds(lambda n, o: plane(n, o), vec3.filter(
        lambda v: sum(c * c for c in v) > 0.01), st.floats(-0.5, 0.5)),
}
PAIRS = [("sphere", "sphere"), ("plane", "sphere"), ("box", "sphere"), ("capsule", "sphere"),
         ("plane", "box"), ("plane", "capsule"), ("capsule", "capsule"), ("box", "capsule"),
         ("box", "box"), ("sphere", "box"), ("cylinder", "sphere"), ("sphere", "cylinder")]
# fcl's GJK on a curved shape against a box (libccd) stops ~1e-4 m short of the true
# distance (measured: 8.7e-5 m on 1 m shapes); its other answers here are closed forms.
GJK_TOL = 2e-4


def _axis_points(world, g, count=2001):
    """`count` points along capsule g's axis (at most 2 m long: 1 mm apart)."""
    axis = world.rot[g][:, 1] * world.half[g][1]
    return np.linspace(-1, 1, count)[:, None] * axis + world.pos[g]


def _brute_capsule_depth(cm, world, kind_a):
    """Independent truth for a capsule (geom 1) against a box or a capsule (geom 0):
    (smallest signed distance of the axis to the other core, r_total minus it), from
    dense samples of the axis and the exact distance of each sample to a box or to a
    segment."""
    pts = _axis_points(world, 1)
    if kind_a == "box":
        local = (pts - world.pos[0]) @ world.rot[0]
        q = np.abs(local) - world.half[0]
        gap = (np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)).min()
        return gap, cm.geom_radius[1] - gap
    a = world.pos[0] - world.rot[0][:, 1] * world.half[0][1]
    ab = 2.0 * world.rot[0][:, 1] * world.half[0][1]
    t = np.clip((pts - a) @ ab / (ab @ ab), 0.0, 1.0)
    gap = np.linalg.norm(pts - (a + t[:, None] * ab), axis=1).min()
    return gap, cm.geom_radius[0] + cm.geom_radius[1] - gap


def _capsule_box_gap(cm, world):
    """Independent truth: the gap of a capsule (geom 1) apart from a box (geom 0), the
    least distance of its axis to the box less its radius (`_axis_gap`; the distance of
    a point to the box is exact: its local coordinates clamped to the box)."""
    def distance(point):
        local = (point - world.pos[0]) @ world.rot[0]
        return float(np.linalg.norm(local - np.clip(local, -world.half[0], world.half[0])))

    return _axis_gap(cm, world, distance)


def _capsule_capsule_gap(cm, world):
    """Independent truth: the gap of two capsules apart, the least distance of geom 1's
    axis to geom 0's axis less both radii (`_axis_gap`; the distance of a point to a
    segment is exact: its projection clamped to the segment)."""
    axis0 = world.rot[0][:, 1] * world.half[0][1]

    def distance(point):
        s = np.clip((point - world.pos[0]) @ axis0 / (axis0 @ axis0), -1.0, 1.0)
        return float(np.linalg.norm(point - world.pos[0] - s * axis0))

    return _axis_gap(cm, world, distance) - cm.geom_radius[0]


def _nearly_parallel_overlap(world):
    """Whether two capsules' axes (geoms 0 and 1) are within the narrow phase's
    PARALLEL_SIN of parallel but not exactly, and overlap along their length."""
    from vrsim_cli.stages.collision.narrowphase import PARALLEL_SIN

    u0, u1 = world.rot[0][:, 1], world.rot[1][:, 1]
    sin = float(np.linalg.norm(np.cross(u0, u1)))
    ends = [(world.pos[1] + e * u1 * world.half[1][1] - world.pos[0]) @ u0 for e in (-1, 1)]
    overlap = min(max(ends), world.half[0][1]) - max(min(ends), -world.half[0][1])
    return 0.0 < sin < PARALLEL_SIN and overlap > 0.0


def _axis_gap(cm, world, distance):
    """The least of distance(point) over capsule geom 1's axis, less its radius. The
    distance of an axis point to a convex set is convex along the axis, so the least over
    dense samples, refined by a bounded scalar search around it, is the minimum to
    round-off."""
    from scipy.optimize import minimize_scalar

    axis = world.rot[1][:, 1] * world.half[1][1]

    def along(s):
        return distance(world.pos[1] + s * axis)

    samples = np.linspace(-1.0, 1.0, 2001)
    best = samples[int(np.argmin([along(s) for s in samples]))]
    found = minimize_scalar(along, bounds=(max(-1.0, best - 1e-3), min(1.0, best + 1e-3)),
                            method="bounded", options={"xatol": 1e-14})
    return min(found.fun, along(best)) - cm.geom_radius[1]


@pytest.mark.parametrize("kind_a, kind_b", PAIRS)
@settings(max_examples=300, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(data=st.data())
def test_closed_forms_agree_with_fcl(kind_a, kind_b, data):
    """12 pair types x 300 poses: hit/miss, depth, and the gap of separated pairs."""
    shape_a, shape_b = data.draw(SHAPES[kind_a]), data.draw(SHAPES[kind_b])
    pa, pb = data.draw(vec3), data.draw(vec3)
    qa, qb = quat_normalize(data.draw(quat)), quat_normalize(data.draw(quat))
    cm, world = setup(shape_a, shape_b, pa, pb, qa, qb)
    ia, ib = np.array([0]), np.array([1])
    _, _, normal, depth = narrow_phase(cm, world, ia, ib, np.inf)
    ours = depth.max()  # with an infinite margin every pair reports its signed depth
    assume(abs(ours) > GJK_TOL)  # hit/miss is decided only beyond both sides' precision
    _, _, f_normal, f_depth = fcl_adapter.pair_contacts(cm, world, ia, ib, 0.0)
    assert (ours > 0) == bool(len(f_depth)), (ours, f_depth)
    pair = (kind_a, kind_b)
    if ours < 0:  # apart: compare the gap with fcl's distance (no fcl distance to planes)
        if "plane" in pair:
            return
        if pair == ("box", "box"):
            return  # gaps of manifold points are along the normal, not distances
        if pair == ("box", "capsule"):
            # fcl's GJK stops up to 2.4e-4 m short here (seen: 7.692e-3 for 7.457e-3):
            # the exact gap of the axis to the box instead
            assert -ours == pytest.approx(_capsule_box_gap(cm, world), abs=1e-9)
            return
        if pair == ("capsule", "capsule"):
            # fcl's GJK ends 8e-9 m off for capsules parallel to 4e-9 rad, 1 m apart
            # (seen: 0.2500000042 for 0.2499999958): the exact gap of the axes instead
            # (nearly parallel overlapping axes included: their least distance is in
            # the manifold since 2026-12-07)
            truth = _capsule_capsule_gap(cm, world)
            assert -ours == pytest.approx(truth, abs=1e-9)
            return
        gap = fcl_adapter.pair_distance(cm, world, 0, 1)
        assert -ours == pytest.approx(gap, abs=1e-9)
        return
    theirs = f_depth.max()
    if pair == ("box", "box"):
        # Both prefer a face axis unless an edge axis is 5 % shallower (ODE's fudge factor
        # 1.05; ours: edge if e < 0.95 f), so a kept face may be up to 1/0.95 - 1 = 5.3 %
        # deeper than the edge the other side reports.
        assert ours == pytest.approx(theirs, rel=0.053)
    elif kind_b == "capsule" and kind_a in ("box", "capsule"):
        # fcl's EPA for these is off by up to 5e-4 m even at 1 cm depth (measured), so
        # the truth is brute force: r minus the axis' smallest signed distance to the
        # other core. With the axis clear of it (by 1 cm) that minimum is smooth and
        # sampling 1 mm apart errs by O(h^2) ~ 1e-6; inside, the distance has kinks and
        # sampling errs by up to h/2 = 5e-4 m (slope <= 1).
        gap, truth = _brute_capsule_depth(cm, world, kind_a)
        assert ours == pytest.approx(truth, abs=1e-5 if gap > 1e-2 else 5e-4)
    else:
        # fcl has closed forms for these too, but treats a capsule within 1e-7 rad of
        # parallel to a plane as parallel (its half-space tolerance): up to 1e-7 m here.
        assert ours == pytest.approx(theirs, abs=1e-6)
        # Normals: deep inside, two directions can tie (a centre halfway between faces);
        # compare them for shallow contacts, below a quarter of the smallest size (0.1 m).
        if ours < 0.025:
            assert normal[np.argmax(depth)] @ f_normal[np.argmax(f_depth)] > 1.0 - 1e-9


def test_box_distance_of_flush_boxes_where_fcl_errs():
    # Aligned 0.4 x 0.2 x 0.3 boxes, the second turned 180 deg about z (the same box),
    # 1.5 m apart along x: 1.1 m between the faces. fcl's GJK says 1.118 m here.
    cm, world = setup(box(0.4, 0.2, 0.3), box(0.4, 0.2, 0.3), [0, 0, 0], [-1.5, 0, 0],
                      I, [0.0, 0.0, 0.0, 1.0])
    assert box_box_distance(world, np.array([0]), np.array([1])) == pytest.approx([1.1],
                                                                                 abs=1e-12)
    # Corner to corner along the diagonal: |(0.5, 0.6, 0.7)| between the nearest corners.
    cm, world = setup(box(0.4, 0.2, 0.3), box(0.4, 0.2, 0.3), [0, 0, 0], [0.9, 0.8, 1.0])
    assert box_box_distance(world, np.array([0]), np.array([1])) == pytest.approx(
        [math.sqrt(0.25 + 0.36 + 0.49)], abs=1e-12)


@settings(max_examples=200, derandomize=True, deadline=None)
@given(data=st.data())
def test_box_distance_agrees_with_fcl_on_turned_boxes(data):
    """fcl's GJK on polytopes is exact on generic poses but errs when a face or an edge of
    one box is parallel to a face of the other (see above), so those are left out: every
    entry of the relative rotation must be clear of 0 and of +-1 by 1e-3."""
    shape_a, shape_b = data.draw(SHAPES["box"]), data.draw(SHAPES["box"])
    pa, pb = data.draw(vec3), np.array(data.draw(vec3)) * 3.0
    qa, qb = quat_normalize(data.draw(quat)), quat_normalize(data.draw(quat))
    cm, world = setup(shape_a, shape_b, pa, pb, qa, qb)
    relative = np.abs(world.rot[0].T @ world.rot[1])
    assume(np.all(relative > 1e-3) and np.all(relative < 1.0 - 1e-3))
    gap = fcl_adapter.pair_distance(cm, world, 0, 1)
    assume(gap > 1e-6)
    assert box_box_distance(world, np.array([0]), np.array([1]))[0] == pytest.approx(
        gap, abs=1e-9)


def test_a_box_capsule_gap_where_fcls_gjk_stops_short():
    """The pose a fresh-clone run drew (2026-12-04), where fcl's GJK distance (7.692e-3 m)
    was 2.35e-4 m longer than the gap; ours against the exact one (`_capsule_box_gap`)."""
    cm, world = setup(box(1.0, 1.71875, 2.0), capsule(0.25, 0.65625), (0.0, 0.90625, 0.0),
                      (0.0, -0.90625, 0.328125),
                      quat_normalize((0.4140625, -0.259765625, 0.0, 0.0078125)),
                      quat_normalize((0.625, 0.0, 1.0, -0.21875)))
    _, _, _, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), np.inf)
    assert -depth.max() == pytest.approx(_capsule_box_gap(cm, world), abs=1e-9)
    assert -depth.max() == pytest.approx(7.4574e-3, abs=1e-7)


def test_a_capsule_capsule_gap_where_fcls_gjk_ends_off():
    """The pose hypothesis drew (2026-12-04): capsules (r 0.5 and 0.25, half length 1)
    parallel but for a tilt of 4e-9 rad, axes 1 m apart; fcl's GJK gave 0.2500000042 m,
    above the 0.25 m of exactly parallel axes, where the tilt brings one end 4e-9 m closer.
    Ours against the exact one (`_capsule_capsule_gap`)."""
    cm, world = setup(capsule(0.5, 2.0), capsule(0.25, 2.0), (0.0, 0.0, 1.0), (0.0, 0.0, 0.0),
                      quat_normalize((0.0, 0.0, 0.0, 1.0)),
                      quat_normalize((0.0, 0.0, 1.0, 2.087572321298175e-09)))
    _, _, _, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), np.inf)
    assert -depth.max() == pytest.approx(_capsule_capsule_gap(cm, world), abs=1e-9)
    assert -depth.max() == pytest.approx(0.25 - 4.175e-9, abs=1e-12)


def test_nearly_parallel_capsules_report_their_exact_gap():
    """The pose hypothesis drew (2026-12-04): capsules (r 0.5 and 0.25, half length 1),
    axes 1 m apart in z, one tilted by 1.2e-4 rad towards the other: the exact gap is
    that of the tilted axis' near end, 0.2498779296880 m; the two ends of the overlap
    alone gave 0.2498779315504 m (the least distance joins them as a third point)."""
    cm, world = setup(capsule(0.5, 2.0), capsule(0.25, 2.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0),
                      quat_normalize((0.0, 0.0, 0.0, 1.0)),
                      quat_normalize((0.0, 0.0, 1.0, 6.103515625e-05)))
    assert _nearly_parallel_overlap(world)
    _, _, _, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), np.inf)
    assert -depth.max() == pytest.approx(_capsule_capsule_gap(cm, world), abs=1e-9)


def test_coincident_capsules_nearly_antiparallel_are_as_deep_as_both_radii():
    """The pose hypothesis drew in CI (2026-12-06): two capsules r 0.5, half length 1, at
    the same centre, one turned by pi - 1e-3 about z: the axes cross at the centre, so
    the depth is r + r = 1; the overlap's ends alone gave 0.999."""
    cm, world = setup(capsule(0.5, 2.0), capsule(0.5, 2.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                      I, quat_normalize((0.0, 0.0, 0.5, 0.00025)))
    _, _, _, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), np.inf)
    assert depth.max() == pytest.approx(1.0, abs=1e-12)


def _least_axis_distance(a0, b0, a1, b1):
    """Independent truth: the least distance between segments a0b0 and a1b1. The distance
    of a point of segment 1 to segment 0 (its projection clamped: exact) is convex along
    segment 1: dense samples, then a bounded scalar search around the best, to
    round-off."""
    from scipy.optimize import minimize_scalar

    d0 = b0 - a0

    def along(t):
        p = a1 + t * (b1 - a1)
        s = np.clip((p - a0) @ d0 / (d0 @ d0), 0.0, 1.0)
        return float(np.linalg.norm(p - a0 - s * d0))

    samples = np.linspace(0.0, 1.0, 4001)
    best = samples[int(np.argmin([along(t) for t in samples]))]
    found = minimize_scalar(along, bounds=(max(0.0, best - 5e-4), min(1.0, best + 5e-4)),
                            method="bounded", options={"xatol": 1e-14})
    return min(found.fun, along(best))


@pytest.mark.parametrize("seed", range(40))
def test_nearly_parallel_capsules_have_their_exact_depth_in_both_detections(seed):
    """The class of the two cases above: capsules (r 0.05-0.5, half length 0.1-1) at a
    random pose, the second's axis the first's turned by 1e-9 to 1e-3 rad (within
    PARALLEL_SIN: the two-point manifold) about a random direction, forward or reversed,
    its centre shifted along the axis (overlapping) and sideways by up to r0 + r1 (the
    axes crossing in a third of the draws). The numpy narrow phase and the compiled one
    (kernels.collide) both report, as their deepest point, r0 + r1 less the least
    distance of the axes to 1e-9 m (the truth's search is good to ~1e-12), and no point
    deeper than that."""
    from vrsim_cli.kernels import collide as kc
    from vrsim_cli.maths.spatial import quat_multiply, quat_to_matrix
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.stages.collision.detect import detect

    rng = np.random.default_rng(7000 + seed)
    r = rng.uniform(0.05, 0.5, 2)
    half = rng.uniform(0.1, 1.0, 2)
    q0 = quat_normalize(rng.normal(size=4))
    turn = quat_from_axis_angle(rng.normal(size=3), 10.0 ** rng.uniform(-9, -3)
                                + (math.pi if rng.random() < 0.5 else 0.0))
    q1 = quat_normalize(quat_multiply(turn, q0))
    u0 = quat_to_matrix(q0)[:, 1]
    side = rng.normal(size=3)
    side -= (side @ u0) * u0
    side /= np.linalg.norm(side)
    lateral = 0.0 if seed % 3 == 0 else rng.uniform(0.0, 0.999) * (r[0] + r[1])
    p0 = rng.uniform(-2.0, 2.0, 3)
    p1 = p0 + rng.uniform(-0.9, 0.9) * min(half) * u0 + lateral * side
    text = ("vrsim: 1\nduration: 0.01\nframe_rate: 100\ndt: 0.01\n"
            "collision: {impacts: stepped}\nbodies:\n" + "".join(
                f"  - {{name: c{i}, mass: 1, position: {list(map(float, p))!r}, "
                f"orientation: {list(map(float, q))!r}, shape: {{type: capsule, "
                f"radius: {float(r[i])!r}, length: {float(2 * half[i])!r}}}}}\n"
                for i, (p, q) in enumerate(((p0, q0), (p1, q1)))))
    model = compile_model(parse_scene(text))
    state = make_state(model)
    ends = []
    for i in range(2):
        u = quat_to_matrix(state.body_quat[i])[:, 1] * half[i]
        ends += [state.body_pos[i] - u, state.body_pos[i] + u]
    truth = r[0] + r[1] - _least_axis_distance(*ends)
    ref = detect(model, state)
    k, C, _ = compiled_detect(model, state)
    for depth in (ref.depth, C[:k, kc.C_D]):
        assert depth.max() == pytest.approx(truth, abs=1e-9)
        assert (depth <= truth + 1e-9).all()


def test_a_sphere_centred_on_a_cylinders_axis_is_inside_it():
    """A sphere (r 1) whose centre lies 1e-12 m from a cylinder's (r 0.5, half length 1)
    centre, on its axis: it is inside, and leaves through the side, depth 1 + 0.5 (the
    pose hypothesis found: the radial direction fell back to a default there, and the
    centre was classed outside, depth 1)."""
    cm, world = setup({"type": "cylinder", "radius": 0.5, "length": 2.0}, sphere(1.0),
                      (0.0, 0.0, 0.0), (0.0, 1e-12, 0.0), quat_normalize((0.0, 0.0, 1.0, 1.0)))
    _, _, _, depth = narrow_phase(cm, world, np.array([0]), np.array([1]), np.inf)
    assert depth.max() == pytest.approx(1.5, abs=1e-9)


@pytest.mark.parametrize("seed", range(24))
def test_a_bar_lying_across_a_box_face_touches_at_both_rims(seed):
    """A bar (a box turned 45 deg about its long axis, an edge down) lying across the top
    face of a box at a random pose, yaw and offset, tilted along its length so that one
    rim touches (up to 1e-4 m deep) and the other is apart by 5-50 % of the tolerance:
    the contact is the segment of the edge over the face, and both detections must
    report its two ends (a row each: the face's normal, depth minus the end's height
    above the face, the point halfway to the face) to 1e-9 m. The separating axis of the
    bar's edge and the face's edge direction is the shallowest in most draws: its one
    edge-edge point alone, at the touching rim, let a bar rock about that rim and reach
    the face unseen at the other (a pile of 4 boxes rocked for 11 s). Truth: the edge
    clipped to the face rectangle in the lower box's frame, computed here."""
    from vrsim_cli.kernels import collide as kc
    from vrsim_cli.maths.spatial import quat_from_matrix, quat_to_matrix
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.stages.collision.detect import detect

    rng = np.random.default_rng(7100 + seed)
    ha = rng.uniform(0.05, 0.5, 3)  # the lower box's half sizes
    qa = quat_normalize(rng.normal(size=4))
    Ra = quat_to_matrix(qa)
    pa = rng.uniform(-1.0, 1.0, 3)
    w = rng.uniform(0.01, 0.1)  # the bar's square section
    yaw = rng.uniform(0.0, math.pi)
    u = np.array([math.cos(yaw), 0.0, math.sin(yaw)])  # the edge's heading (A's frame)
    up = np.array([0.0, 1.0, 0.0])  # the face's normal (A's frame)
    mid = np.array([rng.uniform(-0.5, 0.5) * ha[0], ha[1], rng.uniform(-0.5, 0.5) * ha[2]])
    s_lo, s_hi = -math.inf, math.inf  # where the line mid + s u crosses the face's rims
    for c in (0, 2):
        if abs(u[c]) > 1e-12:
            a_, b_ = (-ha[c] - mid[c]) / u[c], (ha[c] - mid[c]) / u[c]
            s_lo, s_hi = max(s_lo, min(a_, b_)), min(s_hi, max(a_, b_))
    model0 = compile_model(parse_scene("vrsim: 1\nduration: 0.01\ncollision: {}\nbodies:\n"
                                       "  - {name: a, mass: 1, shape: {type: sphere, "
                                       "radius: 1}}\n"))
    tol = model0.collision.tolerance
    depth0 = rng.uniform(0.0, 1e-4)
    rise = 10.0 ** rng.uniform(math.log10(0.05), math.log10(0.5)) * tol + depth0
    slope = rise / (s_hi - s_lo)  # height gained per metre along the face
    along = u + slope * up
    along /= np.linalg.norm(along)
    side = np.cross(along, up)
    side /= np.linalg.norm(side)
    down = np.cross(side, along)  # perpendicular to the bar, upwards
    Rb_loc = np.column_stack([(side + down) / math.sqrt(2.0), along,
                              np.cross((side + down) / math.sqrt(2.0), along)])
    # the bar's lowest edge runs through mid + s u + height(s) up, height(s_lo) = -depth0
    edge_mid = mid + (-depth0 - s_lo * slope) * up
    cb = pa + Ra @ (edge_mid + (w / math.sqrt(2.0)) * down)
    qb = quat_from_matrix(Ra @ Rb_loc)
    span = 4.0 * float(np.linalg.norm(ha[[0, 2]]))  # longer than the face's diagonal
    text = ("vrsim: 1\nduration: 0.01\nframe_rate: 100\ndt: 0.01\n"
            "collision: {impacts: stepped}\nbodies:\n"
            f"  - {{name: a, type: static, position: {list(map(float, pa))!r}, "
            f"orientation: {list(map(float, qa))!r}, shape: {{type: box, "
            f"size: {list(map(float, 2 * ha))!r}}}}}\n"
            f"  - {{name: bar, mass: 1, position: {list(map(float, cb))!r}, "
            f"orientation: {list(map(float, qb))!r}, shape: {{type: box, "
            f"size: {[float(w), span, float(w)]!r}}}}}\n")
    model = compile_model(parse_scene(text))
    state = make_state(model)
    n_world = Ra @ up
    ends = []
    for s in (s_lo, s_hi):
        height = -depth0 + (s - s_lo) * slope
        e = pa + Ra @ (mid + s * u + height * up)
        ends.append((e - n_world * (0.5 * height), -height))
    ref = detect(model, state)
    k, C, _ = compiled_detect(model, state)
    got = [(ref.point, ref.normal, ref.depth),
           (C[:k, kc.C_P:kc.C_P + 3], C[:k, kc.C_N:kc.C_N + 3], C[:k, kc.C_D])]
    for name, (P, N, D) in zip(("numpy", "compiled"), got):
        for point, depth in ends:
            near = np.linalg.norm(P - point, axis=1)
            q = int(np.argmin(near))
            assert near[q] <= 1e-9, (name, seed, near[q], slope, len(D))
            assert D[q] == pytest.approx(depth, abs=1e-9), (name, seed)
            np.testing.assert_allclose(N[q], n_world, atol=1e-9)
