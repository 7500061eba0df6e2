"""Batched rotation helpers against independent forms (spatial's quaternions, Rodrigues)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.maths.rotation import (axis_rotation, exp_so3, orthonormality_error, orthonormalize,
                                quat_from_matrix, skew)
from vrsim_cli.maths.spatial import quat_normalize, quat_to_matrix

unit = st.floats(-1, 1, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(unit, min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1))
def test_quaternion_round_trip(q):
    # Both branches of Shepperd's method (fast w-pivot and the general table) are hit:
    # random quaternions have w anywhere in [0, 1]. Round-off: a few ulp.
    # q and -q are the same rotation (they differ only when w = 0).
    q = quat_normalize(np.array(q))[None]
    back = quat_from_matrix(quat_to_matrix(q))
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-14


def test_half_turns_have_w_zero():
    for axis in np.eye(3):
        q = quat_from_matrix(exp_so3(np.pi * axis[None]))[0]
        assert abs(q[0]) < 1e-15 and np.abs(q[1:]) == pytest.approx(axis, abs=1e-15)


def test_axis_rotation_is_rodrigues_about_the_axis():
    angles = np.array([0.3, -1.1, 2.9])
    for axis in range(3):
        vecs = np.zeros((3, 3))
        vecs[:, axis] = angles
        assert axis_rotation(axis, angles) == pytest.approx(exp_so3(vecs), abs=1e-15)


def test_skew_is_the_cross_product():
    a, b = np.array([[1.0, -2.0, 0.5]]), np.array([0.3, 0.7, -1.1])
    assert (skew(a)[0] @ b) == pytest.approx(np.cross(a[0], b), abs=1e-15)


@pytest.mark.parametrize("drift", [1e-10, 1e-3, 0.3])
def test_orthonormalize_gives_the_nearest_rotation(drift):
    # The polar factor (both code paths: Newton-Schulz near a rotation, SVD otherwise)
    # is orthonormal and no farther from R than the rotation R came from.
    rng = np.random.default_rng(5)
    true = exp_so3(rng.normal(size=(4, 3)))
    R = true + drift * rng.normal(size=(4, 3, 3))
    P = orthonormalize(R)
    assert orthonormality_error(P).max() < 1e-14
    assert np.linalg.det(P) == pytest.approx(np.ones(4), abs=1e-14)
    assert (np.linalg.norm(P - R, axis=(1, 2)) <=
            np.linalg.norm(true - R, axis=(1, 2)) + 1e-15).all()
