"""Loop stage 2.1 for rigid bodies (slide 5.3): forces, torques and the rotation update.

Called by `dynamics.step` when the model has a rigid part (`Model.rigid`); it belongs to
the dynamics stage. The state integrated is the slide's S (body_pos), P = m v
(body_vel), R (rot_matrix) and L (rot_angmom, world frame), with omega = I(t)^-1 L and
I(t) = R I_body R^T. Everything is vectorised: translation over all bodies, rotation over
the rotating subset `rot_index` only (point masses pay nothing for rotation).

Integrators (docs/dynamics.md has the table with orders and costs):
- euler: the slide's step exactly: forces and omega at t; S += dt v, R += dt omega* R,
  P += dt F, L += dt M; v = P/m, omega = I(t+dt)^-1 L; then R is re-orthonormalised
  (polar decomposition, `rotation.orthonormalize`) unless `rotation: {orthonormalize:
  false}`.
- symplectic-euler: P and L kicked with the forces at t, then S drifts with the new v and
  R with the free rigid body flow under the new L, split into three exact rotations about
  the principal axes (Lie-Trotter). Order 1, symplectic.
- verlet: half kick, drift (Strang splitting of the free rigid body: axes 1, 2, 3, 2, 1
  with half, half, full, half, half steps), half kick. Order 2, symplectic,
  time-reversible. Free rotation: |L| and R's orthonormality are kept exactly (each
  sub-step is an exact rotation; McLachlan 1993, Touma & Wisdom 1994, Dullweber,
  Leimkuhler & McLachlan 1997) and the energy error stays bounded (no drift).
- `rotation: {free_flow: exact}` replaces the drift of both by the exact torque-free flow
  (`free_body.py`; Celledoni, Fasso, Safstrom & Zanna 2008): a body without torque is
  then exact to round-off at any dt, and with torques the kicks carry them.
- rk4: classical Runge-Kutta on (S, v, R, L) with R' = omega* R, then polar
  re-orthonormalisation. Order 4.
- dopri5: Dormand-Prince 5(4) on the same system with error control (`adaptive.py`),
  projecting R onto the rotations after every accepted step. Order 5.

Forces (`forces`): gravity; the scene's forces, at the centre of mass or at a point
(world or body frame; torque = arm x F, slide 5.3.2); torques; springs with damping
between body points or a body point and a world anchor; linear damping -c m v and angular
damping -c L.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.errors import SimulationError
import reference_adaptive as adaptive
from vrsim_cli.maths.rotation import (axis_rotation, cross, exp_so3, orthonormalize,
                                quat_from_matrix, skew)
from vrsim_cli.model.model import Model
from vrsim_cli.model.rigid import (RigidModel, angular_velocity, mechanical_energy,
                                   spring_ends)
from vrsim_cli.model.state import State
from reference_free_body import exact_free_rotation
from vrsim_cli.stages.dynamics.rigid import check  # the package's checks, not a copy

# A conserving scene has blown up when its energy grew by more than this fraction of
# (kinetic + |spring| energy now and at t = 0, + m|g| * 1 m per body): a free rotor whose
# energy tripled, an oscillator whose amplitude grew by ~70 %. Honest integration errors
# are orders of magnitude smaller; explicit Euler's exponential growth is not.
ENERGY_GROWTH_LIMIT = 0.5
GRAVITY_SCALE_M = 1.0
# rad per drift: beyond these the exact flow (kernels/dynamics.py has the why)
SPLIT_MAX_TURN_LIE_RAD, SPLIT_MAX_TURN_STRANG_RAD = 0.05, 0.2


def forces(model: Model, t: float, x, v, R, L, mask, w=None):
    """Accelerations (n, 3) m/s^2 of all bodies and torques (r, 3) N m of the rotating ones.

    t: s, the start of the step: selects the time-windowed forces and torques, which are
    sampled once per step for every integrator (a window acts on the steps whose start
    lies in it; for dopri5, on the grid intervals). x, v: (n, 3);
    R: (r, 3, 3); L, w: (r, 3) world angular momentum and velocity (w is computed here
    when None and springs need it); mask: (n, 1) 1.0 for bodies moved by forces.
    """
    rigid: RigidModel = model.rigid
    n, r = model.n_body, rigid.n_rot
    if rigid.static_forces and not (len(model.force_body) or len(rigid.torque_body)):
        return mask * model.gravity, np.zeros((r, 3))  # gravity only
    F = np.zeros((n, 3))
    M = np.zeros((r, 3))
    if len(model.force_body):
        active = (model.force_start <= t) & (t < model.force_end)
        if active.any():
            body = model.force_body[active]
            f = rigid.force_vec[active]
            slot = rigid.rot_slot[body]
            turning = slot >= 0
            in_body = rigid.force_in_body[active]
            if in_body.any():  # body-frame forces turn with the body
                f[in_body] = np.einsum("kij,kj->ki", R[slot[in_body]], f[in_body])
            np.add.at(F, body, f)
            at = rigid.force_has_point[active] & turning
            if at.any():
                point = rigid.force_point[active][at]
                arm = np.where(in_body[at, None],
                               np.einsum("kij,kj->ki", R[slot[at]], point),
                               point - x[body[at]])
                np.add.at(M, slot[at], cross(arm, f[at]))
    if len(rigid.torque_body):
        active = (rigid.torque_start <= t) & (t < rigid.torque_end)
        if active.any():
            slot = rigid.rot_slot[rigid.torque_body[active]]
            tau = rigid.torque_vec[active]
            in_body = rigid.torque_in_body[active]
            tau = np.where(in_body[:, None], np.einsum("kij,kj->ki", R[slot], tau), tau)
            np.add.at(M, slot, tau)
    if len(rigid.spring_a):
        w = _omega(model, R, L) if w is None else w
        _spring_forces(model, rigid, x, v, R, w, F, M)
    mass = model.body_mass
    if rigid.body_lin_damping.any():
        F -= np.where(np.isfinite(mass), rigid.body_lin_damping * mass, 0.0)[:, None] * v
    if r:
        M -= rigid.body_ang_damping[rigid.rot_index, None] * L
        M[rigid.rot_kinematic] = 0.0
    return mask * (model.gravity + F * model.body_inv_mass[:, None]), M


def _spring_forces(model, rigid, x, v, R, w, F, M) -> None:
    """Add the spring forces (F, (n, 3)) and torques (M, (r, 3)) in place.

    Tension k (l - l0) + c dl/dt along the spring, with dl/dt the relative velocity of
    the two end points along it (each point moves with v + omega x arm)."""
    pa, arm_a, pb, arm_b = spring_ends(rigid, x, R)
    a, b = rigid.spring_a, rigid.spring_b
    anchored = b < 0
    bb = np.where(anchored, 0, b)

    def point_velocity(body, arm):
        vel = v[body].copy()
        slot = rigid.rot_slot[body]
        turning = slot >= 0
        vel[turning] += cross(w[slot[turning]], arm[turning])
        return vel

    va = point_velocity(a, arm_a)
    vb = np.where(anchored[:, None], 0.0, point_velocity(bb, arm_b))
    d = pb - pa
    length = np.linalg.norm(d, axis=1)
    u = d / np.where(length > 0, length, 1.0)[:, None]
    tension = rigid.spring_k * (length - rigid.spring_rest) + \
        rigid.spring_c * ((vb - va) * u).sum(1)
    f = tension[:, None] * u  # on a, towards b when stretched; -f on b
    np.add.at(F, a, f)
    np.add.at(F, bb[~anchored], -f[~anchored])
    for body, arm, sign, keep in ((a, arm_a, 1.0, np.ones(len(a), bool)),
                                  (bb, arm_b, -1.0, ~anchored)):
        slot = rigid.rot_slot[body]
        turning = (slot >= 0) & keep
        np.add.at(M, slot[turning], sign * cross(arm[turning], f[turning]))


def _omega(model: Model, R, L):
    rigid = model.rigid
    return angular_velocity(rigid, R, L, exact_inverse=not rigid.orthonormalize)


def _finish_rotation(model: Model, R):
    # A non-finite R is left as it is: `check` then names the body and time (the SVD of the
    # projection would only fail with a traceback).
    if model.rigid.orthonormalize and len(R) and np.isfinite(R).all():
        return orthonormalize(R)
    return R


def free_rotation(rigid: RigidModel, R, L, h: float, strang: bool):
    """R after time h of torque-free motion with constant world L.

    `rotation: {free_flow: exact}`: the exact flow (Jacobi's solution, `free_body.py`),
    to round-off at any h. Otherwise (`splitting`, the default) by splitting the kinetic
    energy sum_i Lb_i^2 / (2 I_i) (principal body frame) into its three terms: each term's
    flow is an exact rotation of the body about principal axis i by h Lb_i / I_i
    (Lb_i is constant under it). Lie-Trotter (1, 2, 3) is order 1; Strang (1, 2, 3, 2, 1
    with half steps outside) is order 2. (Kinematic bodies are turned exactly by `step`.)
    Either way a body that turns by more than SPLIT_MAX_TURN_STRANG_RAD (Strang) or
    SPLIT_MAX_TURN_LIE_RAD (Lie-Trotter) in h takes the exact flow."""
    Q = rigid.rot_axes
    Rp = R @ Q  # principal frame -> world
    if rigid.free_flow == "exact":
        # Kinematic bodies have L = 0 here: they stay put (`step` turns them).
        return exact_free_rotation(rigid.rot_moments, Rp, L, h) @ np.swapaxes(Q, -1, -2)
    Lb = L[:, None, :] @ Rp  # (r, 1, 3): (Rp^T L)^T, a row per body
    rates = np.where(rigid.rot_kinematic[:, None], 0.0, 1.0 / rigid.rot_moments)
    # A drift that turns a body farther than the splitting's limit takes the exact flow
    # (kernels/dynamics.py).
    limit = SPLIT_MAX_TURN_STRANG_RAD if strang else SPLIT_MAX_TURN_LIE_RAD
    far = np.linalg.norm(Lb[:, 0, :] * rates, axis=1) * abs(h) > limit
    m = rigid.rot_moments
    far &= m[:, 2] - m[:, 0] > 1e-12 * m[:, 2]  # spherical bodies keep the splitting
    exact = exact_free_rotation(rigid.rot_moments[far], Rp[far], L[far], h) \
        if far.any() else None
    plan = [(0, 0.5 * h), (1, 0.5 * h), (2, h), (1, 0.5 * h), (0, 0.5 * h)] if strang \
        else [(0, h), (1, h), (2, h)]
    for axis, hh in plan:
        # Rp <- Rp Rot_axis(theta), Lb <- Rot_axis(theta)^T Lb, theta = h Lb_axis / I_axis.
        rot = axis_rotation(axis, (hh * rates[:, axis]) * Lb[:, 0, axis])
        Rp = Rp @ rot
        Lb = Lb @ rot
    if exact is not None:
        Rp[far] = exact
    return Rp @ np.swapaxes(Q, -1, -2)


# ----------------------------------------------------------------------------- steppers


def _euler(model, t, dt, x, v, R, L, mask):
    w = _omega(model, R, L)
    a, M = forces(model, t, x, v, R, L, mask, w)
    R1 = R + dt * (skew(w) @ R)  # slide step 2 with the old omega
    return x + dt * v, v + dt * a, _finish_rotation(model, R1), L + dt * M


def _symplectic_euler(model, t, dt, x, v, R, L, mask):
    a, M = forces(model, t, x, v, R, L, mask)
    v1 = v + dt * a
    L1 = L + dt * M
    R1 = free_rotation(model.rigid, R, L1, dt, strang=False)
    return x + dt * v1, v1, _finish_rotation(model, R1), L1


def _verlet(model, t, dt, x, v, R, L, mask):
    a, M = forces(model, t, x, v, R, L, mask)
    v_half = v + (0.5 * dt) * a
    L_half = L + (0.5 * dt) * M
    x1 = x + dt * v_half
    R1 = _finish_rotation(model, free_rotation(model.rigid, R, L_half, dt, strang=True))
    # Time windows are sampled at the step's start t, so a windowed force acts on whole
    # steps; forces that do not depend on the configuration need no second evaluation.
    a1, M1 = (a, M) if model.rigid.static_forces else \
        forces(model, t, x1, v_half, R1, L_half, mask)
    return x1, v_half + (0.5 * dt) * a1, R1, L_half + (0.5 * dt) * M1


def _derivative(model, mask, t_step: float):
    """(S, v, R, L)' at a stage. Time windows are sampled once per step, at its start
    t_step (as for point masses, `dynamics.active_forces`): within a step the system is
    autonomous, so the stage time is not needed."""
    def f(_t, x, v, R, L):
        w = _omega(model, R, L)
        a, M = forces(model, t_step, x, v, R, L, mask, w)
        return v, a, skew(w) @ R, M
    return f


def _rk4(model, t, dt, x, v, R, L, mask):
    f = _derivative(model, mask, t)
    h = 0.5 * dt
    k1 = f(t, x, v, R, L)
    k2 = f(t + h, *(y + h * k for y, k in zip((x, v, R, L), k1)))
    k3 = f(t + h, *(y + h * k for y, k in zip((x, v, R, L), k2)))
    k4 = f(t + dt, *(y + dt * k for y, k in zip((x, v, R, L), k3)))
    x1, v1, R1, L1 = (y + (dt / 6.0) * (a + 2.0 * b + 2.0 * c + d)
                      for y, a, b, c, d in zip((x, v, R, L), k1, k2, k3, k4))
    return x1, v1, _finish_rotation(model, R1), L1


STEPPERS = {"euler": _euler, "symplectic-euler": _symplectic_euler, "rk4": _rk4,
            "verlet": _verlet}


def _dopri5(model: Model, state: State, mask):
    """Adaptive steps over [t, t + dt] (exactly: the last one is clipped); returns the
    new (x, v, R, L) and the step proposed for the next interval."""
    n, r = model.n_body, model.rigid.n_rot
    cuts = np.cumsum([0, 3 * n, 3 * n, 9 * r, 3 * r])
    f = _derivative(model, mask, state.t)

    def unpack(y):
        return (y[cuts[0]:cuts[1]].reshape(n, 3), y[cuts[1]:cuts[2]].reshape(n, 3),
                y[cuts[2]:cuts[3]].reshape(r, 3, 3), y[cuts[3]:cuts[4]].reshape(r, 3))

    def flat(t, y):
        return np.concatenate([part.ravel() for part in f(t, *unpack(y))])

    def project(y):
        if not model.rigid.orthonormalize or not r or not np.isfinite(y).all():
            return y
        y = y.copy()
        y[cuts[2]:cuts[3]] = orthonormalize(y[cuts[2]:cuts[3]].reshape(r, 3, 3)).ravel()
        return y

    y0 = np.concatenate([state.body_pos.ravel(), state.body_vel.ravel(),
                         state.rot_matrix.ravel(), state.rot_angmom.ravel()])
    h0 = state.ode_step if state.ode_step > 0 else model.dt
    try:
        y1, h, _, _ = adaptive.integrate(flat, state.t, state.t + model.dt, y0, h0,
                                         model.rigid.tolerance, project)
    except adaptive.StepSizeUnderflow as exc:
        raise SimulationError("the adaptive step size fell below round-off (the motion is "
                              "not smooth or not finite); try another integrator",
                              body=_body_of_component(model, exc.component), t=exc.t) from None
    return (*unpack(y1), h)


def _body_of_component(model: Model, k: int) -> str:
    n = model.n_body
    if k < 6 * n:
        return model.body_name[(k % (3 * n)) // 3]
    k -= 6 * n
    r = model.rigid.n_rot
    slot = k // 9 if k < 9 * r else (k - 9 * r) // 3
    return model.body_name[model.rigid.rot_index[slot]]


def step(model: Model, state: State, mask: np.ndarray) -> State:
    """Advance every body by dt (translation of all, rotation of the rotating subset).
    mask: (n_body, 1) 1.0 for bodies moved by forces. Pure: returns a new State."""
    rigid = model.rigid
    ode_step = state.ode_step
    if model.integrator == "dopri5":
        x, v, R, L, ode_step = _dopri5(model, state, mask)
    else:
        x, v, R, L = STEPPERS[model.integrator](model, state.t, model.dt, state.body_pos,
                                                state.body_vel, state.rot_matrix,
                                                state.rot_angmom, mask)
    kin = rigid.rot_kinematic
    if kin.any():  # kinematic bodies turn exactly at their rate, whatever the integrator
        R = R.copy()
        R[kin] = exp_so3(model.dt * rigid.rot_angvel0[kin]) @ state.rot_matrix[kin]
    n = state.step + 1
    if rigid.n_rot and not (np.isfinite(R).all() and np.isfinite(L).all()):
        # report at once: quaternions and angular velocities of a blown-up R mean nothing
        check(model, state.replace(step=n, t=n * model.dt, rot_matrix=R, rot_angmom=L))
    quat, angvel = state.body_quat, state.body_angvel
    if rigid.n_rot:
        quat = quat.copy()
        angvel = angvel.copy()
        shown = R if rigid.orthonormalize else orthonormalize(R)
        quat[rigid.rot_index] = quat_from_matrix(shown)
        angvel[rigid.rot_index] = _omega(model, R, L)
    new = state.replace(step=n, t=n * model.dt, body_pos=x, body_vel=v, body_quat=quat,
                        body_angvel=angvel, rot_matrix=R, rot_angmom=L, ode_step=ode_step)
    guard_from = rigid.energy_guard_from
    if rigid.energy_guard and 0.0 < guard_from and state.t < guard_from <= new.t:
        new = new.replace(rot_energy0=energy(model, new)[0])  # the windows have closed
    return new


# ----------------------------------------------------------------------------- checks


def energy(model: Model, state: State):
    """(per-body mechanical energy (n,) J, total kinetic J, total spring J)."""
    return mechanical_energy(model.rigid, model.body_mass, model.gravity, state.body_pos,
                             state.body_vel, state.rot_matrix, state.rot_angmom)

