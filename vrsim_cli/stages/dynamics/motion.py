"""Loop stage 2.1, dynamic motion: forces on bodies, integrated over a step (slide 5.3).

Point masses move at their centre of mass (`P(t1) = P(t0) + dt v`, `v(t1) = v(t0) + dt a`);
rotating bodies, springs, torques and forces at points add the rotation of slide 5.3
(`Model.rigid`). Forces: gravity on dynamic bodies, the scene's constant and
time-windowed forces and torques, springs with damping, linear and angular damping, and
forces other stages pass in (contact forces, `ext`). Kinematic bodies keep their
velocity (and turn at their given rate); static bodies never move; emitted particles wait
at their nozzle until their emission step, then leave with their launch velocity.

The arithmetic is compiled (`kernels.dynamics`; docs/dynamics.md has the methods, their
orders and costs). This module is the thin Python side: it packs the model's arrays for
the kernels once per model, and turns states into kernel buffers and back:

- `step(model, state, ext=None) -> State`: one step of dt;
- `advance(model, state, h, ext=None) -> State`: the same dynamics over h (0 < h <= dt),
  step counter unchanged (collision response integrates up to a time of impact with it);
- `run(model, state, count) -> (State, Failure | None)`: `count` steps in one compiled
  call, with the blow-up checks after every step and the energy guard at frame ends (the
  loop uses it between two points where Python has work to do).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.products import norm

from vrsim_cli.model.model import BODY_DYNAMIC, Model
from vrsim_cli.model.state import State

# The energy guard (docs/dynamics.md, "Energy guard"; `kernels.dynamics.energy_bound`). In
# a scene that conserves energy, the growth since the baseline may not pass
#   scale * min(ENERGY_GROWTH_LIMIT, max(ENERGY_FLOOR, ENERGY_SAFETY (w dt)^p (1 + w tau)))
# with p the integrator's order and w the scene's frequency scale. The error constants of
# the five methods on the oscillator and the free rigid body are <= 1 (euler's energy
# grows by (w dt)^2 a step: constant 1; symplectic-euler 1/2, verlet 1/8, rk4 < 1/100), so
# ENERGY_SAFETY = 10 covers them with w underestimated by up to 10^(1/(p+1)) (w is a
# scale, not the exact frequency). Whatever the order predicts, a conserving scene whose
# energy grew by more than ENERGY_GROWTH_LIMIT (5 %) of its scale gives wrong numbers:
# oscillation amplitudes off by 2.5 %, spins by 2.5 %; the run stops there.
ENERGY_GROWTH_LIMIT = 0.05
ENERGY_SAFETY = 10.0
ENERGY_FLOOR = 1e-10  # relative: below this, rk4's (w dt)^4 meets round-off
ENERGY_ROUND_OFF = 1e-12  # of m |g| |x|: the round-off of -m g.x far from the origin
GRAVITY_SCALE_M = 1.0
ORDER = {"euler": 1, "symplectic-euler": 1, "verlet": 2, "rk4": 4, "dopri5": 5}


def guard_order(model: Model) -> int:
    """The order the energy guard's bound assumes: the integrator's, or 1 in a scene
    with collision response, whose resting contact is first order in energy whatever
    the integrator (position correction after the free flight: a pivoting body gains
    ~a_n dt^2 (m g - m_eff a_n) / 2 per step, docs/collision-response.md, Known limits).
    With rk4's order-4 bound a box tipping over on the ground stopped the run at dt
    10 ms, and a smaller dt made it worse (the bound shrinks as dt^4, the gain as dt):
    7.6 times the bound at 1/240 s, 1475 times at 5e-4 s."""
    return 1 if model.response is not None else ORDER[model.integrator]


@dataclass(frozen=True)
class Failure:
    """A step that failed its checks: what (kernels.dynamics codes), which body (or
    component, for a step-size underflow), and the failed state (for the message)."""

    code: int
    index: int
    state: State
    t: float  # s, where it happened


def _kernels():
    from vrsim_cli.kernels import dynamics as kd  # numba: only scenes with bodies pay

    return kd


def packed(model: Model) -> np.ndarray:
    """The model as the kernels take it (`kernels.dynamics`: one float array, a header of
    counts and offsets, then tables with named columns), built once per model."""
    found = model.cache.get("dynamics")
    if found is not None:
        return found
    kd = _kernels()
    from vrsim_cli.kernels import free_flow

    n = model.n_body
    rigid = model.rigid
    mass = np.where(np.isfinite(model.body_mass), model.body_mass, 0.0)
    body = np.zeros((n, kd.B_SIZE))
    body[:, kd.B_INV_MASS] = model.body_inv_mass
    body[:, kd.B_MASS] = mass
    body[:, kd.B_VEL0:kd.B_VEL0 + 3] = model.body_vel0
    body[:, kd.B_DYNAMIC] = model.body_type == BODY_DYNAMIC
    body[:, kd.B_EMIT] = model.body_emit_step
    body[:, kd.B_SLOT] = -1.0
    nf = len(model.force_body)
    force = np.zeros((nf, kd.FC_SIZE))
    force[:, kd.FC_BODY] = model.force_body
    force[:, kd.FC_START] = model.force_start
    force[:, kd.FC_END] = model.force_end
    force[:, kd.FC_VEC:kd.FC_VEC + 3] = model.force_vec
    torque = np.zeros((0, kd.TQ_SIZE))
    spring = np.zeros((0, kd.SP_SIZE))
    rot = np.zeros((0, kd.RT_SIZE))
    param = np.zeros(kd.P_SIZE)
    param[kd.P_GRAVITY:kd.P_GRAVITY + 3] = model.gravity
    param[kd.P_INTEGRATOR] = kd.INTEGRATOR_CODES[model.integrator]
    param[kd.P_STATIC_FORCES] = 1.0
    param[kd.P_HAS_EMITTERS] = model.has_emitters
    param[kd.P_TOLERANCE] = 1e-6
    param[kd.P_WEIGHT] = float(mass.sum() * norm(model.gravity) * GRAVITY_SCALE_M)
    param[kd.P_GROWTH_LIMIT] = ENERGY_GROWTH_LIMIT
    param[kd.P_SAFETY] = ENERGY_SAFETY
    param[kd.P_FLOOR] = ENERGY_FLOOR
    param[kd.P_ROUND_OFF] = ENERGY_ROUND_OFF
    param[kd.P_ORDER] = guard_order(model)
    if rigid is not None:
        r = rigid.n_rot
        # The rigid part covers the scene's bodies; emitted particles come after them
        # and neither turn nor feel damping.
        scene = len(rigid.body_lin_damping)
        body[:scene, kd.B_LIN_DAMP] = rigid.body_lin_damping
        body[:scene, kd.B_ANG_DAMP] = rigid.body_ang_damping
        body[:len(rigid.rot_slot), kd.B_SLOT] = rigid.rot_slot
        if rigid.energy0_body is not None:
            body[:len(rigid.energy0_body), kd.B_ENERGY0] = rigid.energy0_body
        force[:, kd.FC_VEC:kd.FC_VEC + 3] = rigid.force_vec
        force[:, kd.FC_POINT:kd.FC_POINT + 3] = rigid.force_point
        force[:, kd.FC_HAS_POINT] = rigid.force_has_point
        force[:, kd.FC_IN_BODY] = rigid.force_in_body
        torque = np.zeros((len(rigid.torque_body), kd.TQ_SIZE))
        torque[:, kd.TQ_BODY] = rigid.torque_body
        torque[:, kd.TQ_VEC:kd.TQ_VEC + 3] = rigid.torque_vec
        torque[:, kd.TQ_START] = rigid.torque_start
        torque[:, kd.TQ_END] = rigid.torque_end
        torque[:, kd.TQ_IN_BODY] = rigid.torque_in_body
        spring = np.zeros((len(rigid.spring_a), kd.SP_SIZE))
        spring[:, kd.SP_A] = rigid.spring_a
        spring[:, kd.SP_B] = rigid.spring_b
        spring[:, kd.SP_PA:kd.SP_PA + 3] = rigid.spring_point_a
        spring[:, kd.SP_PB:kd.SP_PB + 3] = rigid.spring_point_b
        spring[:, kd.SP_K] = rigid.spring_k
        spring[:, kd.SP_C] = rigid.spring_c
        spring[:, kd.SP_REST] = rigid.spring_rest
        rot = np.zeros((r, kd.RT_SIZE))
        rot[:, kd.RT_INDEX] = rigid.rot_index
        rot[:, kd.RT_KINEMATIC] = rigid.rot_kinematic
        rot[:, kd.RT_INERTIA:kd.RT_INERTIA + 9] = np.reshape(rigid.rot_inertia, (r, 9))
        rot[:, kd.RT_INV_INERTIA:kd.RT_INV_INERTIA + 9] = np.reshape(rigid.rot_inv_inertia,
                                                                     (r, 9))
        rot[:, kd.RT_MOMENTS:kd.RT_MOMENTS + 3] = np.reshape(rigid.rot_moments, (r, 3))
        rot[:, kd.RT_AXES:kd.RT_AXES + 9] = np.reshape(rigid.rot_axes, (r, 9))
        rot[:, kd.RT_ANGVEL0:kd.RT_ANGVEL0 + 3] = np.reshape(rigid.rot_angvel0, (r, 3))
        param[kd.P_ORTHONORMALIZE] = rigid.orthonormalize
        param[kd.P_EXACT_FLOW] = rigid.free_flow == "exact"
        param[kd.P_STATIC_FORCES] = rigid.static_forces
        param[kd.P_ENERGY_GUARD] = rigid.energy_guard and rigid.energy0_body is not None
        param[kd.P_TOLERANCE] = rigid.tolerance
        param[kd.P_GUARD_FROM] = rigid.energy_guard_from
        param[kd.P_ENERGY0_SCALE] = rigid.energy0_scale
        param[kd.P_OMEGA] = rigid.energy_omega
        # nothing dissipates (no damping, no impacts): the energy may not fall either
        param[kd.P_TWO_SIDED] = model.response is None and not (
            rigid.body_lin_damping.any() or rigid.body_ang_damping.any()
            or rigid.spring_c.any())
        # dopri5: steps of (w h)^5 ~ tolerance, h = tol^(1/5) / w, tol^(-1/5) per radian
        param[kd.P_STEPS_PER_TURN] = rigid.tolerance ** -0.2 if rigid.tolerance > 0 else 0.0
    counts = {"n": n, "r": len(rot), "f": nf, "k": len(torque), "s": len(spring)}
    # the quadrature tables only where the kernel may read them: the exact flow, chosen
    # (P_EXACT_FLOW) or taken by a drift that turns a non-spherical body too far to split
    # (`too_far_to_split`, any integrator: stepped impacts drift with symplectic Euler)
    gl = free_flow.gauss_tables() if param[kd.P_EXACT_FLOW] or _anisotropic(model) \
        else free_flow.no_tables()
    mf = kd.pack(counts, {"body": body, "force": force, "torque": torque, "spring": spring,
                          "rot": rot}, param, gl)
    model.cache["dynamics"] = mf
    return mf


def _anisotropic(model: Model) -> bool:
    """Whether a rotating body's principal moments differ (as `too_far_to_split` tests)."""
    if model.rigid is None or not model.rigid.n_rot:
        return False
    moments = np.reshape(model.rigid.rot_moments, (-1, 3))
    return bool(np.any(moments[:, 2] - moments[:, 0] > 1e-12 * moments[:, 2]))


def _scratch(model: Model):
    """Work arrays and double buffers of the kernels, allocated once per model."""
    found = model.cache.get("dynamics_scratch")
    if found is None:
        kd = _kernels()
        n, r = model.n_body, (0 if model.rigid is None else model.rigid.n_rot)
        found = dict(work=kd.make_work(n, r, kd.INTEGRATOR_CODES[model.integrator]),
                     bS=np.zeros((2, n, kd.S_SIZE)), bRS=np.zeros((2, r, kd.RS_SIZE)),
                     base=np.zeros(n), base_set=np.zeros(1, np.int64),
                     status=np.zeros(5, np.int64), zero=np.zeros((n, 6)))
        model.cache["dynamics_scratch"] = found
    return found


def _call(model: Model, state: State, count: int, t_first: float, dt: float, checked: bool,
          ext=None):
    """Run the integrator's kernel from `state`; returns (status (5,), h_prop, scratch)."""
    kd = _kernels()
    mf = packed(model)
    sc = _scratch(model)
    bS, bRS, base, base_set = sc["bS"], sc["bRS"], sc["base"], sc["base_set"]
    S = bS[0]
    S[:, kd.S_POS:kd.S_POS + 3] = state.body_pos
    S[:, kd.S_VEL:kd.S_VEL + 3] = state.body_vel
    S[:, kd.S_QUAT:kd.S_QUAT + 4] = state.body_quat
    S[:, kd.S_ANGVEL:kd.S_ANGVEL + 3] = state.body_angvel
    if state.rot_matrix is not None and len(state.rot_matrix):
        bRS[0, :, kd.RS_R:kd.RS_R + 9] = np.reshape(state.rot_matrix, (-1, 9))
        bRS[0, :, kd.RS_L:kd.RS_L + 3] = state.rot_angmom
    if state.rot_energy0 is not None:
        base[:] = state.rot_energy0
        base_set[0] = 1
    else:
        base[:] = 0.0 if model.rigid is None or model.rigid.energy0_body is None else \
            model.rigid.energy0_body
        base_set[0] = 0
    if ext is None:
        ext_arr = sc["zero"]
    else:
        ext_arr = np.ascontiguousarray(np.concatenate([ext[0], ext[1]], axis=1), dtype=float)
    wb, wr, wm, kS = sc["work"]
    run_kernel = kd.entry(kd.INTEGRATOR_CODES[model.integrator])
    h_prop = run_kernel(mf, state.step, count, model.n_steps, model.steps_per_frame, t_first,
                        dt, state.ode_step, checked, bS, bRS, ext_arr, base, base_set, wb,
                        wr, wm, kS, sc["status"])
    return sc["status"], h_prop, sc


def _state_at(model: Model, state: State, sc, buffer: int, step: int, t: float,
              ode_step: float) -> State:
    kd = _kernels()
    S, RS = sc["bS"][buffer], sc["bRS"][buffer]
    rot = {} if state.rot_matrix is None else dict(
        rot_matrix=RS[:, kd.RS_R:kd.RS_R + 9].reshape(-1, 3, 3).copy(),
        rot_angmom=RS[:, kd.RS_L:kd.RS_L + 3].copy())
    return state.replace(step=step, t=t, body_pos=S[:, kd.S_POS:kd.S_POS + 3].copy(),
                         body_vel=S[:, kd.S_VEL:kd.S_VEL + 3].copy(),
                         body_quat=S[:, kd.S_QUAT:kd.S_QUAT + 4].copy(),
                         body_angvel=S[:, kd.S_ANGVEL:kd.S_ANGVEL + 3].copy(),
                         ode_step=ode_step, **rot)


def _one(model: Model, state: State, h: float, ext):
    kd = _kernels()
    status, h_prop, sc = _call(model, state, 1, state.t, h, False, ext)
    if status[0] == kd.STEP_UNDERFLOW:
        _raise_underflow(model, int(status[3]), float(sc["work"][2][kd.WM_FAIL_T]))
    return sc, h_prop


def step(model: Model, state: State, ext=None) -> State:
    """Advance every body by one physics step dt. Pure: returns a new State. ext: (force
    (n, 3) N, torque (n, 3) N m) from other stages, constant over the step."""
    sc, h_prop = _one(model, state, model.dt, ext)
    n = state.step + 1
    new = _state_at(model, state, sc, 1, n, n * model.dt, h_prop)
    return _guard_baseline(model, state, new)


def advance(model: Model, state: State, h: float, ext=None) -> State:
    """The state after time h (0 < h <= dt) of the same dynamics, with the step counter
    unchanged and t = state.t + h: collision response integrates up to a time of impact
    and on from it with this. Time windows of forces are sampled at state.t, as in step."""
    sc, h_prop = _one(model, state, h, ext)
    return _state_at(model, state, sc, 1, state.step, state.t + h, h_prop)


def prepare(model: Model) -> None:
    """Pack the model and load (on the first run after an install: compile) the kernel
    its integrator needs, so that a run's first step does not pay for it."""
    kd = _kernels()
    sc = _scratch(model)
    wb, wr, wm, kS = sc["work"]
    kd.entry(kd.INTEGRATOR_CODES[model.integrator])(
        packed(model), 0, 0, model.n_steps, model.steps_per_frame, 0.0, model.dt, 0.0, True,
        sc["bS"], sc["bRS"], sc["zero"], sc["base"], sc["base_set"], wb, wr, wm, kS,
        sc["status"])


def _guard_baseline(model: Model, before: State, after: State) -> State:
    """The energy guard watches from the end of the last force window on, against the
    energy then (the windows inject energy while they act)."""
    rigid = model.rigid
    if rigid is None or not rigid.energy_guard:
        return after
    guard_from = rigid.energy_guard_from
    if 0.0 < guard_from and before.t < guard_from <= after.t:
        return after.replace(rot_energy0=energy(model, after)[0])
    return after


def run(model: Model, state: State, count: int, checked: bool = True):
    """`count` steps from `state` in one compiled call, checking each (unless `checked` is
    false: studies of how a method fails). Returns (the last good state, None) or (the
    last good state, Failure) at the first step that fails."""
    kd = _kernels()
    status, h_prop, sc = _call(model, state, count, state.t, model.dt, checked)
    code, done, cur, index, failed = (int(v) for v in status)
    energy0 = sc["base"].copy() if sc["base_set"][0] else None

    def at(buffer: int, steps: int) -> State:
        s = state.step + steps
        return _state_at(model, state, sc, buffer, s, s * model.dt, h_prop).replace(
            rot_energy0=energy0)

    good = at(cur, done) if done else state
    if code == kd.OK:
        return good, None
    bad = at(failed, done + 1)
    fail_t = float(sc["work"][2][kd.WM_FAIL_T]) if code == kd.STEP_UNDERFLOW else bad.t
    return good, Failure(code, index, bad, fail_t)


def energy(model: Model, state: State):
    """(per-body mechanical energy (n,) J, total kinetic J, total spring J): kinetic
    m|v|^2/2 + L.omega/2, gravity -m g.x, a spring's k (l - l0)^2/2 split between its two
    bodies. Kinematic and static bodies count 0."""
    kd = _kernels()
    S, RS = _rows(model, state)
    out = np.zeros(model.n_body)
    kinetic, spring = kd.body_energy(packed(model), S, RS, out)
    return out, float(kinetic), float(spring)


def energy_check(model: Model, state: State, baseline: np.ndarray):
    """The energy guard of `state` against the per-body `baseline` (n,) J, as the
    compiled run makes it: (-1 or the body whose energy changed most past the bound,
    change J (< 0: a loss), bound J)."""
    kd = _kernels()
    S, RS = _rows(model, state)
    tau = state.t - (model.rigid.energy_guard_from if model.rigid is not None else 0.0)
    # a copy: the model's baseline is read-only, a state's is not, and numba compiles
    # one variant per kind (a first stepped compile made elsewhere covers one: loop.py)
    bad, gain, bound = kd.energy_check(packed(model), S, RS, np.array(baseline, dtype=float),
                                       np.zeros(model.n_body), tau, model.dt)
    return int(bad), float(gain), float(bound)


def _rows(model: Model, state: State):
    """The kernels' rows S (n, 13) and RS (r, 12) of `state` (positions, velocities, R, L)."""
    kd = _kernels()
    if state.rot_matrix is None:
        R, L = np.zeros((0, 3, 3)), np.zeros((0, 3))
    else:
        R, L = state.rot_matrix, state.rot_angmom
    S = np.zeros((model.n_body, kd.S_SIZE))
    S[:, kd.S_POS:kd.S_POS + 3] = state.body_pos
    S[:, kd.S_VEL:kd.S_VEL + 3] = state.body_vel
    RS = np.zeros((len(R), kd.RS_SIZE))
    RS[:, kd.RS_R:kd.RS_R + 9] = np.reshape(R, (-1, 9))
    RS[:, kd.RS_L:kd.RS_L + 3] = L
    return S, RS


def _raise_underflow(model: Model, component: int, t: float):
    from vrsim_cli.errors import SimulationError

    raise SimulationError("the adaptive step size fell below round-off (the motion is not "
                          "smooth or not finite); try another integrator",
                          body=body_of_component(model, component), t=t)


def body_of_component(model: Model, k: int) -> str:
    """The body of component k of dopri5's state vector (x, v: 3n each; q: 4r; Lb: 3r)."""
    n = model.n_body
    if k < 6 * n:
        return model.body_name[(k % (3 * n)) // 3]
    k -= 6 * n
    r = model.rigid.n_rot
    slot = k // 4 if k < 4 * r else (k - 4 * r) // 3
    return model.body_name[model.rigid.rot_index[slot]]
