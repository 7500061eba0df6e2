"""The exact torque-free flow (`free_body.py`) and `rotation: {free_flow: exact}`.

Truth used here: Euler's equations of the free rigid body with quaternion kinematics,
solved by scipy's DOP853 at rtol = atol = 1e-12 (`test_rigid.reference`, an independent
formulation and solver); the closed form of the symmetric top; steady rotation about a
principal axis; conservation of energy and |L|; the group property of a flow.

Tolerances. DOP853 at rtol = atol = 1e-12 is itself accurate to ~1e-10 rad on the
Dzhanibekov box over 20 s (measured: 8e-11 rad from the same solve at rtol 1e-13) and to
~1e-12 rad over a few seconds on bodies away from the separatrix. Next to the separatrix
the motion is ill-conditioned: a relative energy change e (round-off: a few 1e-16 per
step) changes the flip period by ~ e / (2 * separatrix distance) relative, and the
Dzhanibekov box is 1e-6 (relative) from it, so round-off alone moves its orientation by
up to ~1e-9 rad over 20 s and thousands of steps (measured 3e-9 rad for 2000 steps of the
box mirrored, 4e-11 rad for the box as given). The bounds below are these figures,
rounded up.
"""

from __future__ import annotations


import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from test_rigid import (MOMENTS, OMEGA0, free_box_scene, reference, rotation_angle,
                        simulate)
from vrsim_cli.errors import InputError
from vrsim_cli.kernels.free_flow import exact_free_rotation
from vrsim_cli.loop import run
from vrsim_cli.maths.rotation import axis_rotation
from vrsim_cli.maths.spatial import quat_to_matrix
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import parse_scene
from vrsim_cli.stages.dynamics import rigid

EXACT = "rotation: {free_flow: exact}"


def flow(moments, Rp, L, h):
    """One body: exact_free_rotation on (1, ...) stacks."""
    return exact_free_rotation(np.asarray(moments, float)[None], np.asarray(Rp, float)[None],
                               np.asarray(L, float)[None], h)[0]


def truth(moments, Rp0, L, t):
    """Rp(t) by DOP853 from Rp0 under world L: the body starts at Rp0, so the body-frame
    reference (which starts at E) is turned by Rp0."""
    moments = np.asarray(moments, float)
    omega_body = (Rp0.T @ L) / moments
    _, R = reference(omega_body, np.array([0.0, t]), moments)
    return Rp0 @ R[-1]


def random_rotation(seed) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=4)
    return quat_to_matrix(q / np.linalg.norm(q))


# ----------------------------------------------------------------------------- Dzhanibekov


@pytest.fixture(scope="module")
def dzhanibekov_end():
    return reference(OMEGA0, np.array([0.0, 20.0]))[1][-1]


@pytest.mark.parametrize("dt,rate", [(0.1, 10), (20.0 / 3.0, 0.15)])
def test_verlet_exact_is_exact_at_any_step(dzhanibekov_end, dt, rate):
    # 200 steps and 3 steps of 6.7 s (1.6 flip periods each): the orientation after 20 s
    # agrees with DOP853 to its own accuracy plus the separatrix's round-off amplification
    # (module docstring): 1e-9 rad. The splitting verlet is 0.006 deg = 1e-4 rad off at
    # dt = 4 ms.
    model, s0, s1, rec = simulate(free_box_scene("verlet", dt, 20.0, rate, extra=EXACT))
    assert s1.t == pytest.approx(20.0)
    assert rotation_angle(rec.R[-1], dzhanibekov_end) < 1e-9
    # No torque: the world L, the state, is kept bit for bit.
    assert np.array_equal(s1.rot_angmom, s0.rot_angmom)


def test_symplectic_euler_exact_is_the_same_flow(dzhanibekov_end):
    # Without torque the kick does nothing: both splitting methods are the exact flow.
    rec = simulate(free_box_scene("symplectic-euler", 1.0, 20.0, 1, extra=EXACT))[3]
    assert rotation_angle(rec.R[-1], dzhanibekov_end) < 1e-9


def test_energy_and_momentum_are_kept_to_round_off_over_many_steps():
    # 5000 steps of 0.01 s of three bodies: the box near its separatrix, a body circling
    # its major axis, one circling its minor axis. Each step recomputes m = Rp^T L from a
    # rounded Rp: relative errors of a few 1e-16 per step that add up like a random walk
    # (sqrt(5000) * 4e-16 = 3e-14): bound 1e-13.
    moments = np.array([np.sort(MOMENTS), [1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    omega = np.array([np.array([0.01, 5.0, 0.01])[np.argsort(MOMENTS)], [0.3, 0.4, 2.0],
                      [2.0, 0.4, 0.3]])
    L = moments * omega
    Rp = np.broadcast_to(np.eye(3), (3, 3, 3)).copy()
    for _ in range(5000):
        Rp = exact_free_rotation(moments, Rp, L, 0.01)
    m = np.einsum("kij,ki->kj", Rp, L)
    assert np.abs((m * m / moments).sum(1) / (L * L / moments).sum(1) - 1).max() < 1e-13
    assert np.abs(np.linalg.norm(m, axis=1) / np.linalg.norm(L, axis=1) - 1).max() < 1e-13
    assert np.abs(np.swapaxes(Rp, 1, 2) @ Rp - np.eye(3)).max() < 1e-13


# ----------------------------------------------------------------------------- cases


@pytest.mark.parametrize("moments,axis", [((1.0, 1.0, 3.0), 2), ((1.0, 3.0, 3.0), 0),
                                          ((2.0, 2.0, 2.0), 0)])
def test_symmetric_top_is_the_closed_form_precession(moments, axis):
    # A symmetric body (symmetry axis s, moment I_s, the other two I_p) precesses
    # regularly: R(t) = exp(t L* / I_p) R0 exp(t (1/I_s - 1/I_p) m_s e_s*) (the world
    # angular velocity is L / I_p + (1/I_s - 1/I_p) m_s R e_s; the two factors commute
    # with it). Round-off of a few rotations of size ~10 rad: 1e-12 rad.
    moments = np.array(moments)
    I_s = moments[axis]
    I_p = moments[(axis + 1) % 3]
    R0 = random_rotation(1)
    L = np.array([0.4, -1.1, 2.3])
    m_s = (R0.T @ L)[axis]
    for t in (0.3, 7.0, 40.0):
        expected = _exp(t * L / I_p) @ R0 @ axis_rotation(
            axis, np.array(t * (1 / I_s - 1 / I_p) * m_s))
        assert rotation_angle(flow(moments, R0, L, t), expected) < 1e-12 * max(1.0, t)


def _exp(w):
    from vrsim_cli.maths.rotation import exp_so3
    return exp_so3(w[None])[0]


@pytest.mark.parametrize("omega_body,t", [
    ((0.3, 0.4, 2.0), 6.0),      # circles the major axis 3
    ((2.0, 0.4, 0.3), 6.0),      # circles the minor axis 1
    ((-2.0, -0.4, 0.3), 6.0),    # minor, other signs
    ((0.3, -0.4, -2.0), 6.0),    # major, other signs
    ((1e-4, 1.0, 1e-4), 12.0),   # next to the separatrix, major side (k' ~ 1e-4)
    ((1e-4, 1.0, -5e-5), 12.0),  # next to the separatrix, minor side
])
def test_both_regimes_and_near_separatrix_match_dop853(omega_body, t):
    # One step of several seconds (many periods circling, one flip near the separatrix).
    # DOP853's own error over such runs is ~1e-11 rad (~1e-10 near the separatrix, where
    # its error is amplified like ours): 1e-10 rad, 1e-9 near the separatrix.
    moments = np.array([1.0, 2.0, 3.0])
    Rp0 = random_rotation(7)
    L = Rp0 @ (moments * np.array(omega_body))
    near = abs(omega_body[0]) < 1e-3
    assert rotation_angle(flow(moments, Rp0, L, t), truth(moments, Rp0, L, t)) < \
        (1e-9 if near else 1e-10)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_rotation_about_a_principal_axis_is_steady(axis):
    # Also about the unstable middle axis: m stays put exactly, the body turns at G / I.
    moments = np.array([1.0, 2.0, 3.0])
    Rp0 = random_rotation(3)
    m = np.zeros(3)
    m[axis] = -1.7
    L = Rp0 @ m
    got = flow(moments, Rp0, L, 9.0)
    expected = Rp0 @ axis_rotation(axis, np.array(9.0 * m[axis] / moments[axis]))
    assert rotation_angle(got, expected) < 1e-14 * 16  # round-off of a 15 rad rotation


def test_zero_angular_momentum_leaves_the_body_alone():
    Rp0 = random_rotation(5)
    assert np.array_equal(flow([1.0, 2.0, 3.0], Rp0, np.zeros(3), 3.0), Rp0)


def test_a_non_finite_state_stays_non_finite():
    # NaN or Inf in L (or R) gives a non-finite R, which rigid.check reports with the
    # body's name; finite bodies in the same batch are unaffected.
    moments = np.array([[1.0, 2.0, 3.0]] * 3)
    Rp = np.broadcast_to(np.eye(3), (3, 3, 3))
    L = np.array([[0.3, 0.2, 1.0], [np.nan, 0.0, 1.0], [np.inf, 0.0, 0.0]])
    with np.errstate(invalid="ignore"):
        out = exact_free_rotation(moments, Rp, L, 1.0)
    assert np.isfinite(out[0]).all() and np.isnan(out[1:]).all()
    assert np.array_equal(out[0], exact_free_rotation(moments[:1], Rp[:1], L[:1], 1.0)[0])


def test_spherical_body_turns_about_l():
    Rp0 = random_rotation(9)
    L = np.array([0.3, -0.2, 0.9])
    expected = _exp(4.0 * L / 2.0) @ Rp0
    assert rotation_angle(flow([2.0, 2.0, 2.0], Rp0, L, 4.0), expected) < 1e-14


def test_planar_body_stays_planar_exactly():
    # 2D: the tensor is Izz E, so the flow is exp(h w*) about z: x and y of the quaternion
    # stay exactly 0 and the angle is w t (round-off of 30 rad: 1e-13).
    model, _, s1, rec = simulate("""
vrsim: 1
dimension: 2
duration: 10
frame_rate: 2
dt: 0.5
gravity: [0, 0]
integrator: verlet
rotation: {free_flow: exact}
output: {rate: 2}
bodies:
  - {name: plate, mass: 2, shape: {type: box, size: [0.3, 0.1]}, angular_velocity: 3.0}
""")
    q = s1.body_quat[0]
    assert q[1] == 0.0 and q[2] == 0.0
    angle = 2.0 * np.arctan2(q[3], q[0])
    assert np.angle(np.exp(1j * (angle - 30.0))) == pytest.approx(0.0, abs=1e-13)


# ----------------------------------------------------------------------------- properties


_moment = st.floats(0.05, 5.0)
_rate = st.floats(-3.0, 3.0)


@settings(max_examples=40, deadline=None, derandomize=True)  # the same cases in CI
@given(moments=st.tuples(_moment, _moment, _moment), omega=st.tuples(_rate, _rate, _rate),
       t=st.floats(1e-3, 1.5), seed=st.integers(0, 2 ** 31), symmetric=st.integers(0, 2))
def test_random_bodies_match_dop853(moments, omega, t, seed, symmetric):
    # Any inertia (also symmetric: symmetric = 1, 2 makes two moments equal), any omega and
    # orientation, up to 1.5 s: |omega| <= 5.2 rad/s, so errors grow at most ~e^(5.2 * 1.5)
    # = 2.4e3-fold (the separatrix's exponential rate is below |omega|): DOP853's ~1e-12
    # becomes < 3e-9 rad: bound 1e-8 rad.
    moments = np.sort(np.array(moments))
    if symmetric == 1:
        moments[1] = moments[0]
    elif symmetric == 2:
        moments[1] = moments[2]
    Rp0 = random_rotation(seed)
    L = Rp0 @ (moments * np.array(omega))
    assert rotation_angle(flow(moments, Rp0, L, t), truth(moments, Rp0, L, t)) < 1e-8


def _bodies(n, seed):
    rng = np.random.default_rng(seed)
    moments = np.sort(rng.uniform(0.1, 3.0, (n, 3)), axis=1)
    moments[0] = [1.0, 1.0, 2.0]  # symmetric
    moments[1] = [1.0, 1.0, 1.0]  # spherical
    Rp = quat_to_matrix(_unit(rng.normal(size=(n, 4))))
    L = rng.normal(size=(n, 3))
    L[2] = Rp[2] @ np.array([1e-4, 1.0, 1e-4]) * moments[2]  # near its separatrix
    L[3] = 0.0
    return moments, Rp, L


def _unit(q):
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_flow_property_and_vectorisation():
    # flow(h2) after flow(h1) is flow(h1 + h2) (a flow is a one-parameter group), for steps
    # short and long against the periods (up to ~15 rad of turning): round-off, 1e-12 rad
    # (1e-10 for the near-separatrix body, whose condition amplifies it). The batch agrees
    # with each body alone (the quadrature adapts to the batch; round-off, 1e-13 rad), and
    # the same call gives the same bits.
    moments, Rp, L = _bodies(12, 4)
    for h1, h2 in ((0.01, 0.02), (0.7, 2.9), (5.0, -2.0)):
        once = exact_free_rotation(moments, Rp, L, h1 + h2)
        twice = exact_free_rotation(moments, exact_free_rotation(moments, Rp, L, h1), L, h2)
        errors = [rotation_angle(a, b) for a, b in zip(once, twice)]
        assert max(errors[:2] + errors[3:]) < 1e-12 and errors[2] < 1e-10
        alone = [flow(moments[i], Rp[i], L[i], h1) for i in range(len(L))]
        batch = exact_free_rotation(moments, Rp, L, h1)
        assert max(rotation_angle(a, b) for a, b in zip(batch, alone)) < 1e-13
        assert np.array_equal(batch, exact_free_rotation(moments, Rp, L, h1))


def test_runs_are_bit_identical():
    text = free_box_scene("verlet", 0.05, 3.0, 20, extra=EXACT)
    a, b = simulate(text)[2], simulate(text)[2]
    assert np.array_equal(a.rot_matrix, b.rot_matrix)
    assert np.array_equal(a.body_quat, b.body_quat)


# ----------------------------------------------------------------------------- with torques


def _torqued_reference(t_end, omega0, torque):
    """Euler's equations with a constant world torque tau: I w' = (I w) x w + R^T tau."""
    def rhs(_t, y):
        w, q = y[:3], y[3:]
        R = quat_to_matrix(q / np.linalg.norm(q))
        dw = (np.cross(MOMENTS * w, w) + R.T @ torque) / MOMENTS
        qw, qx, qy, qz = q
        wx, wy, wz = w
        dq = 0.5 * np.array([-qx * wx - qy * wy - qz * wz, qw * wx + qy * wz - qz * wy,
                             qw * wy - qx * wz + qz * wx, qw * wz + qx * wy - qy * wx])
        return np.concatenate([dw, dq])

    sol = solve_ivp(rhs, (0.0, t_end), np.concatenate([omega0, [1.0, 0, 0, 0]]),
                    method="DOP853", rtol=1e-12, atol=1e-12)
    q = sol.y[3:, -1]
    return quat_to_matrix(q / np.linalg.norm(q))


def test_with_torque_verlet_exact_is_second_order():
    # Kick with the torque, exact free drift (Celledoni et al. 2008): order 2, so halving
    # dt quarters the error (ratio 4; 3.5-4.5 allows the O(dt^3) terms at these steps).
    omega0, torque = np.array([0.3, 2.0, 0.5]), np.array([0.01, 0.0, 0.02])
    expected = _torqued_reference(2.0, omega0, torque)
    errors = []
    for dt in (0.02, 0.01):
        text = free_box_scene("verlet", dt, 2.0, 50, extra=EXACT, omega=omega0)
        text += f"    torques: [{{torque: {torque.tolist()}}}]\n"
        errors.append(rotation_angle(simulate(text)[3].R[-1], expected))
    assert 3.5 < errors[0] / errors[1] < 4.5


def test_after_a_torque_window_the_energy_stays_put_and_the_guard_watches():
    # A body-frame torque spins the box up for 0.5 s (kicks: the energy changes); from the
    # window's end the scene conserves energy again, the guard watches it from there
    # (rigid.check), and the exact drift keeps it to round-off over 400 steps of 10 ms
    # (relative 1e-13, as in the conservation test above): no false alarm, no drift.
    text = free_box_scene("verlet", 0.01, 4.5, 100, extra=EXACT)
    text += "    torques: [{torque: [0.0, 0.0, 0.02], frame: body, end: 0.5}]\n"
    model = compile_model(parse_scene(text))
    assert model.rigid.energy_guard and model.rigid.energy_guard_from == 0.5

    class Energy:
        def __init__(self):
            self.values = []

        def write(self, state):
            if state.t >= 0.5:
                self.values.append(rigid.energy(model, state)[1])

    rec = Energy()
    run(model, make_state(model), rec)
    values = np.array(rec.values)
    assert len(values) == 401
    assert np.abs(values / values[0] - 1).max() < 1e-13


# ----------------------------------------------------------------------------- scene


def test_free_flow_is_validated_with_its_location():
    text = free_box_scene("verlet", 0.01, 1.0, extra="rotation: {free_flow: exakt}")
    with pytest.raises(InputError) as info:
        parse_scene(text, "spin.yaml")
    message = str(info.value)
    assert "spin.yaml:8:" in message and "free_flow" in message


def test_free_flow_without_a_splitting_integrator_is_noted():
    model = compile_model(parse_scene(free_box_scene("rk4", 0.01, 1.0, extra=EXACT)))
    assert any("free_flow: exact has no effect with integrator rk4" in n for n in model.notes)
    model = compile_model(parse_scene(free_box_scene("verlet", 0.01, 1.0, extra=EXACT)))
    assert model.rigid.free_flow == "exact" and not model.notes
