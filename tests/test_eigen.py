"""The Jacobi eigen-solver of symmetric 3 x 3 matrices (maths/eigen.py) that replaces
LAPACK's eigh at model compile (issue 19, item 3).

Truths: numpy's eigh (LAPACK) for the eigenvalues; A v = lambda v and V^T V = I for the
vectors (numpy's vectors inside a degenerate eigenspace are arbitrary, so they are not
compared); exact answers for diagonal matrices and the degenerate cases (sphere,
symmetric top), and the stated conventions (ascending, sign, right-handed frame).

Tolerances: a backward-stable symmetric eigen-solver gives every eigenvalue to a few ulps
of the largest |lambda| (Golub & Van Loan, Theorem 8.1.4 with ||E|| ~ u ||A||), and LAPACK
does the same, so the two agree to ~1e-15 of max |lambda| (measured 1.6e-15 over 20000
matrices); 1e-14 leaves a factor of 6. Residuals and orthonormality: a few ulps, bound
1e-14 (measured 4e-16 and 7e-16). Below the normal range an ulp is absolute, the
subnormal step 4.9e-324, not relative: eigenvalues and residuals also get FLOOR, four such
steps (a CI-like run's hypothesis drew entries of 5e-324: the solver's and LAPACK's
eigenvalues differed by one step, 5e-324, against a relative bound of 1e-337).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from vrsim_cli.maths.eigen import det3, eigh3, principal_axes

TOL = 1e-14
FLOOR = 4 * np.finfo(float).smallest_subnormal  # absolute round-off of subnormal values


def rotation(angles) -> np.ndarray:
    """A rotation matrix from three angles (z-y-x), so hypothesis draws any orientation."""
    a, b, c = angles
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rx = np.array([[1, 0, 0], [0, np.cos(c), -np.sin(c)], [0, np.sin(c), np.cos(c)]])
    return rz @ ry @ rx


def check(A: np.ndarray) -> None:
    values, vectors = eigh3(A)
    expected = np.linalg.eigh(A)[0]
    scale = np.abs(expected).max()
    assert np.all(np.diff(values) >= 0.0)  # ascending
    assert np.abs(values - expected).max() <= TOL * scale + FLOOR
    assert np.abs(A @ vectors - vectors * values).max() <= TOL * scale + FLOOR
    assert np.abs(vectors.T @ vectors - np.eye(3)).max() <= TOL
    for j in range(3):  # the sign convention: largest component positive
        col = vectors[:, j]
        assert col[int(np.argmax(np.abs(col)))] > 0.0


angles = st.tuples(*[st.floats(-np.pi, np.pi)] * 3)
moment = st.floats(1e-3, 1e3)
magnitude = st.integers(-8, 8)


@settings(max_examples=400, deadline=None)
@given(angles, st.tuples(moment, moment, moment), magnitude,
       st.sampled_from(["general", "sphere", "top-low", "top-high"]))
def test_random_inertia_tensors_match_lapack(ang, moments, exp, kind):
    m = np.array(sorted(moments)) * 10.0 ** exp
    if kind == "sphere":
        m[:] = m[0]
    elif kind == "top-low":  # symmetric top: two equal moments
        m[1] = m[0]
    elif kind == "top-high":
        m[1] = m[2]
    R = rotation(ang)
    A = R @ np.diag(m) @ R.T
    A = 0.5 * (A + A.T)
    check(A)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=6, max_size=6))
@example([5e-324, 0.0, 0.0, 0.0, 5e-324, 0.0])  # subnormal: found by hypothesis in CI
@example([0.0, 0.0, 0.0, 0.0, 5e-324, 5e-324])
def test_random_symmetric_matrices_match_lapack(entries):
    a, b, c, d, e, f = entries
    A = np.array([[a, d, e], [d, b, f], [e, f, c]])
    if not np.abs(A).max() > 0.0:
        values, vectors = eigh3(A)
        assert values.tolist() == [0.0] * 3 and vectors.tolist() == np.eye(3).tolist()
        return
    check(A)


def test_diagonal_and_degenerate_tensors_are_exact_and_keep_the_body_axes():
    # a box: already diagonal, no rotation is made; ascending order, unit axes
    values, vectors = eigh3(np.diag([3.0, 1.0, 2.0]))
    assert values.tolist() == [1.0, 2.0, 3.0]
    assert vectors.tolist() == np.eye(3)[:, [1, 2, 0]].tolist()
    # a sphere and the slide's cube: equal moments keep the diagonal's order
    values, vectors = eigh3(np.eye(3) * 0.4)
    assert values.tolist() == [0.4] * 3 and vectors.tolist() == np.eye(3).tolist()
    # a symmetric top turned about its axis: the axis is found exactly up to round-off
    R = rotation((0.3, -0.7, 1.1))
    A = R @ np.diag([1.0, 1.0, 2.5]) @ R.T
    values, vectors = eigh3(A)
    assert values == pytest.approx([1.0, 1.0, 2.5], rel=TOL, abs=TOL)
    axis = R[:, 2] * np.sign(R[np.argmax(np.abs(R[:, 2])), 2])
    assert np.abs(vectors[:, 2] - axis).max() < 1e-14


def test_principal_axes_are_right_handed_and_the_same_bits_every_time():
    rng = np.random.default_rng(7)
    for _ in range(200):
        M = rng.normal(size=(3, 3))
        A = M @ M.T + 0.1 * np.eye(3)
        moments, axes = principal_axes(A)
        assert det3(axes) == pytest.approx(1.0, abs=1e-14)
        assert np.abs(A @ axes - axes * moments).max() <= TOL * np.abs(moments).max()
        again = principal_axes(A.copy())
        assert again[0].tobytes() == moments.tobytes() and again[1].tobytes() == axes.tobytes()


def test_det3_matches_the_cofactor_expansion_and_lapack():
    rng = np.random.default_rng(3)
    for _ in range(100):
        M = rng.normal(size=(3, 3))
        assert det3(M) == pytest.approx(np.linalg.det(M), rel=1e-12, abs=1e-14)


def test_non_finite_input_gives_nan_not_a_hang():
    A = np.eye(3)
    A[0, 1] = A[1, 0] = np.nan
    values, vectors = eigh3(A)
    assert np.isnan(values).all() and np.isnan(vectors).all()


def test_mesh_and_particle_bodies_take_their_axes_from_it():
    # a particle set whose tensor is not diagonal: the model's principal frame is ours
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import parse_scene

    model = compile_model(parse_scene("""
vrsim: 1
duration: 0.1
gravity: [0, 0, 0]
bodies:
  - name: rod
    particles: [{position: [0, 0, 0], mass: 1}, {position: [1, 1, 0.2], mass: 2},
                {position: [0.3, -0.5, 1], mass: 0.5}, {position: [-0.2, 0.4, -0.3], mass: 1}]
"""))
    inertia = model.rigid.rot_inertia[0]
    assert np.abs(inertia - np.diag(np.diag(inertia))).max() > 0.1
    moments, axes = principal_axes(inertia)
    assert model.rigid.rot_moments[0].tobytes() == moments.tobytes()
    assert model.rigid.rot_axes[0].tobytes() == axes.tobytes()
    props = model.rigid.mass_properties[0]
    assert props.principal()[1].tobytes() == axes.tobytes()
