"""Exact geometric queries against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.maths.geometry import (capsule_distance, capsule_overlaps_bounds, ray_cast,
                                signed_distance)
from vrsim_cli.maths.spatial import IDENTITY_QUAT, quat_from_axis_angle

BOX = {"type": "box", "size": [2.0, 1.0, 4.0]}
SPHERE = {"type": "sphere", "radius": 0.5}
PLANE = {"type": "plane", "normal": [0.0, 1.0, 0.0], "offset": 0.25}
CAPSULE = {"type": "capsule", "radius": 0.5, "length": 2.0}
CYLINDER = {"type": "cylinder", "radius": 0.5, "length": 2.0}
ORIGIN = np.zeros(3)


@pytest.mark.parametrize("shape,point,distance,normal", [
    (BOX, [3.0, 0.0, 0.0], 2.0, [1, 0, 0]),
    (BOX, [0.0, 0.2, 0.0], -0.3, [0, 1, 0]),
    (BOX, [2.0, 1.5, 0.0], math.sqrt(2.0), [math.sqrt(0.5), math.sqrt(0.5), 0]),
    (SPHERE, [0.0, 0.0, 2.0], 1.5, [0, 0, 1]),
    (PLANE, [5.0, 1.0, -3.0], 0.75, [0, 1, 0]),
    (CAPSULE, [0.0, 3.0, 0.0], 1.5, [0, 1, 0]),
    (CAPSULE, [2.0, 0.5, 0.0], 1.5, [1, 0, 0]),
    (CYLINDER, [0.0, 3.0, 0.0], 2.0, [0, 1, 0]),
    (CYLINDER, [0.0, 0.0, 2.0], 1.5, [0, 0, 1]),
    (CYLINDER, [0.0, 0.9, 0.1], -0.1, [0, 1, 0]),
])
def test_signed_distance(shape, point, distance, normal):
    d, n = signed_distance(shape, ORIGIN, IDENTITY_QUAT, np.array(point))
    assert d == pytest.approx(distance, abs=1e-12)
    assert n == pytest.approx(normal, abs=1e-12)


def test_signed_distance_respects_the_pose():
    quat = quat_from_axis_angle([0, 0, 1], math.pi / 2)  # box x axis now along world y
    d, n = signed_distance(BOX, np.array([0.0, 10.0, 0.0]), quat, np.array([0.0, 13.0, 0.0]))
    assert d == pytest.approx(2.0) and n == pytest.approx([0, 1, 0], abs=1e-12)


@pytest.mark.parametrize("shape,origin,direction,t", [
    (BOX, [0.0, 5.0, 0.0], [0, -1, 0], 4.5),
    (BOX, [5.0, 0.0, 1.9], [-1, 0, 0], 4.0),
    (BOX, [5.0, 0.0, 2.1], [-1, 0, 0], None),
    (SPHERE, [0.0, 3.0, 0.0], [0, -1, 0], 2.5),
    (PLANE, [1.0, 2.25, 1.0], [0, -1, 0], 2.0),
    (PLANE, [1.0, 2.25, 1.0], [0, 1, 0], None),
    (CAPSULE, [0.0, 5.0, 0.0], [0, -1, 0], 3.5),
    (CAPSULE, [3.0, 0.0, 0.0], [-1, 0, 0], 2.5),
    (CYLINDER, [0.0, 5.0, 0.3], [0, -1, 0], 4.0),
    (CYLINDER, [3.0, 0.0, 0.0], [-1, 0, 0], 2.5),
    (CYLINDER, [0.0, 0.0, 0.0], [-1, 0, 0], 0.0),  # inside
])
def test_ray_cast(shape, origin, direction, t):
    got = ray_cast(shape, ORIGIN, IDENTITY_QUAT, np.array(origin, float), np.array(direction, float))
    assert got == (pytest.approx(t, abs=1e-12) if t is not None else None)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.floats(-3, 3), st.floats(-3, 3), st.floats(0.05, 1.0))
def test_capsule_distance_to_a_sphere_matches_the_closed_form(x, y, radius):
    # Segment from (x, y, 0) to (x, y + 2, 0) against the unit sphere at the origin: the
    # closest axis point is the projection of the centre clamped to the segment.
    a, b = np.array([x, y, 0.0]), np.array([x, y + 2.0, 0.0])
    closest = np.array([x, min(max(0.0, y), y + 2.0), 0.0])
    expected = np.linalg.norm(closest) - 1.0 - radius
    d, _, _ = capsule_distance({"type": "sphere", "radius": 1.0}, ORIGIN, IDENTITY_QUAT, a, b,
                               radius)
    assert d == pytest.approx(expected, abs=1e-9)  # golden section to ~1e-16 of 2 m, sdf exact


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.floats(-4, 4), st.floats(-4, 4), st.floats(-4, 4), st.floats(0.0, 0.8),
       st.sampled_from([BOX, SPHERE, CAPSULE, CYLINDER]))
def test_bounds_test_never_misses_a_contact(x, y, z, radius, shape):
    a = np.array([x, y, z])
    b = a + np.array([0.0, 1.0, 0.0])
    quat = quat_from_axis_angle([1, 2, 3], 0.7)
    d, _, _ = capsule_distance(shape, ORIGIN, quat, a, b, radius)
    if d <= 0.0:
        assert capsule_overlaps_bounds(shape, ORIGIN, quat, a, b, radius)
