"""Loop stage 2.1 compiled: forces and the integrators of point masses and rigid bodies.

The maths is slide 5.3's (docs/dynamics.md has the methods, orders and costs): the state
is S (body_pos), v (body_vel), R (rot_matrix, the rotating subset) and L (rot_angmom,
world), with omega = I(t)^-1 L and I(t) = R I_body R^T.
- euler: the slide's explicit step (forces and omega at t; S += dt v, R += dt omega* R,
  P += dt F, L += dt M), then R re-orthonormalised unless the scene turns that off;
- symplectic-euler: kick P and L, drift S and R (the free rigid body split into exact
  rotations about the principal axes, Lie-Trotter; or the exact flow, `free_flow.py`,
  always with `free_flow: exact` and for any drift that turns a body by more than
  SPLIT_MAX_TURN_LIE_RAD);
- verlet: half kick, drift (Strang splitting or the exact flow, as above with
  SPLIT_MAX_TURN_STRANG_RAD), half kick, with the end
  forces evaluated at v0 + dt a0 (order 2 also with velocity-dependent forces);
- rk4, dopri5: the body-frame system (q, Lb = R^T L) with Euler's equations
  Lb' = Lb x omega_b + R^T M and q' = q (0, omega_b) / 2, q normalised once per step:
  the rotation stays on the group, and the free rigid body keeps the accuracy that the
  world-frame (R, L) system in R^12 loses.

Layout. numba pays a few nanoseconds for every array a compiled function receives, so
the kernels take few, packed arrays (as MuJoCo's mjModel packs its own):

    mf   (n_model,)   the model: a header of counts and offsets (H_*), then row-major
                      tables with named columns: body (n, B_SIZE), force (f, FC_SIZE),
                      torque (k, TQ_SIZE), spring (s, SP_SIZE), rot (r, RT_SIZE), the
                      parameters (P_*) and the exact flow's Gauss-Legendre tables.
                      Integers (body indices, steps) are stored exactly as floats.
    S    (n, 13)      one row per body: position m, velocity m/s, quaternion [w x y z],
                      world angular velocity rad/s (S_POS, S_VEL, S_QUAT, S_ANGVEL)
    RS   (r, 12)      one row per rotating body: R (9, row-major) and world L kg m^2/s
    ext  (n, 6)       forces N and torques N m from other stages (contacts), per body
    wb, wr, wm        scratch: per-body 3-vector planes, per-rotating-body 12-wide
                      planes, and a few scalars (make_work)

Inlining. The functions a step calls once per stage (forces, derivative, combine, the
body-frame conversions, post_step, the checks) are inlined into the steppers
(`kernel(inline="always")`): a call between compiled functions passes every array as a
struct with reference counts, which cost a one-body rk4 step about half its time (1.1 ->
0.6 us per step, CPU time, `vrsim bench --problem free-bodies`), for about 2.6 s more CPU
on the first compile.

n bodies, r rotating, f forces, k torques, s springs. `run` double-buffers the state
(bS (2, n, 13), bRS (2, r, 12)): step i reads buffer c and writes 1 - c, so a step that
fails its checks leaves the last good state untouched.
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.kernels import free_flow
from vrsim_cli.kernels import linalg as la
from vrsim_cli.kernels import trig
from vrsim_cli.kernels.jit import kernel

EULER, SYMPLECTIC_EULER, RK4, VERLET, DOPRI5 = range(5)
INTEGRATOR_CODES = {"euler": EULER, "symplectic-euler": SYMPLECTIC_EULER, "rk4": RK4,
                    "verlet": VERLET, "dopri5": DOPRI5}

# The principal-axis splitting approximates the free rigid body's flow only for small turns
# per drift. One drift that turns a body by theta = |omega| h changes its kinetic energy by
# up to 0.34 theta^2 of it (Lie-Trotter) or 0.09 theta^3 (Strang): the worst of 40000
# random boxes, side ratios up to 1000, theta <= 0.2; beyond ~1 rad the splitting is no
# approximation at all (a box turning 26 rad per step after an impact gained 43 % of its
# energy in one step, 1.6 % in a cut drift of 0.28 rad). A drift that turns a body by more
# than these takes the exact flow (`free_flow.py`, exact at any h), which keeps one
# drift's energy error of the splitting below 1e-3 (worst of 40000: 8.5e-4 and 7.4e-4).
# Spherical bodies keep the splitting (their energy is exact under it); the scenarios'
# other bodies stay below the limits.
SPLIT_MAX_TURN_LIE_RAD = 0.05
SPLIT_MAX_TURN_STRANG_RAD = 0.2

# Beyond these a run has blown up numerically, not simulated anything physical.
MAX_POSITION_M = 1e12  # about 7 times the Earth-Sun distance
MAX_SPEED_M_S = 299_792_458.0  # the speed of light

OK, BLOWUP_TRANSLATION, BLOWUP_ROTATION, ENERGY_GROWTH, STEP_UNDERFLOW = range(5)

# state row S (n, 13) and rotating row RS (r, 12)
S_POS, S_VEL, S_QUAT, S_ANGVEL, S_SIZE = 0, 3, 6, 10, 13
RS_R, RS_L, RS_SIZE = 0, 9, 12

# header of mf: counts and table offsets
H_N, H_R, H_F, H_K, H_S, H_BODY, H_FORCE, H_TORQUE, H_SPRING, H_ROT, H_PARAM, H_GL_X, \
    H_GL_W, H_GL_START, H_SIZE = range(15)
# body table columns
B_INV_MASS, B_MASS, B_LIN_DAMP, B_ANG_DAMP, B_VEL0, B_DYNAMIC, B_EMIT, B_SLOT, \
    B_ENERGY0 = 0, 1, 2, 3, 4, 7, 8, 9, 10
B_SIZE = 11
# force table columns
FC_BODY, FC_VEC, FC_POINT, FC_START, FC_END, FC_HAS_POINT, FC_IN_BODY = 0, 1, 4, 7, 8, 9, 10
FC_SIZE = 11
# torque table columns
TQ_BODY, TQ_VEC, TQ_START, TQ_END, TQ_IN_BODY = 0, 1, 4, 5, 6
TQ_SIZE = 7
# spring table columns
SP_A, SP_B, SP_PA, SP_PB, SP_K, SP_C, SP_REST = 0, 1, 2, 5, 8, 9, 10
SP_SIZE = 11
# rot table columns
RT_INDEX, RT_KINEMATIC, RT_INERTIA, RT_INV_INERTIA, RT_MOMENTS, RT_AXES, RT_ANGVEL0 = \
    0, 1, 2, 11, 20, 23, 32
RT_SIZE = 35
# parameters
P_GRAVITY, P_INTEGRATOR, P_ORTHONORMALIZE, P_EXACT_FLOW, P_STATIC_FORCES, P_ENERGY_GUARD, \
    P_HAS_EMITTERS, P_TOLERANCE, P_GUARD_FROM, P_ENERGY0_SCALE, P_WEIGHT, \
    P_GROWTH_LIMIT = 0, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13
# the energy guard's bound (`energy_bound`, set by stages.dynamics.motion.packed)
P_OMEGA, P_ORDER, P_SAFETY, P_STEPS_PER_TURN, P_FLOOR, P_ROUND_OFF, P_TWO_SIDED = \
    14, 15, 16, 17, 18, 19, 20
P_SIZE = 21

# scratch planes: wb (WB_SIZE, n, 3), wr (WR_SIZE, r, 12), wm (WM_SIZE + n,)
WB_ACC, WB_VH = 0, 1
WB_SIZE = 2
WR_M, WR_W, WR_LH, WR_LB0, WR_LBS, WR_KL = 0, 1, 2, 3, 4, 5
WR_SIZE = 12
WM_RATIOS, WM_FAIL_T, WM_ERR, WM_SIZE = 0, 16, 17, 21  # then the per-body energies (n)


def pack(counts: dict, tables: dict, param: np.ndarray, gl) -> np.ndarray:
    """The model array mf from its tables (a helper of `stages.dynamics.motion.packed`):
    counts n, r, f, k, s; tables body, force, torque, spring, rot (2D, named columns);
    param (P_SIZE,); gl = (x, w, start) of `free_flow.gauss_tables`."""
    header = np.zeros(H_SIZE)
    parts = [header]
    offset = H_SIZE

    def add(array, slot):
        nonlocal offset
        header[slot] = offset
        flat = np.ascontiguousarray(array, dtype=float).ravel()
        parts.append(flat)
        offset += flat.size

    for key, slot in (("n", H_N), ("r", H_R), ("f", H_F), ("k", H_K), ("s", H_S)):
        header[slot] = counts[key]
    add(tables["body"], H_BODY)
    add(tables["force"], H_FORCE)
    add(tables["torque"], H_TORQUE)
    add(tables["spring"], H_SPRING)
    add(tables["rot"], H_ROT)
    add(param, H_PARAM)
    add(gl[0], H_GL_X)
    add(gl[1], H_GL_W)
    add(gl[2], H_GL_START)
    return np.concatenate(parts)


def make_work(n: int, r: int, integrator: int):
    """Scratch arrays (wb, wr, wm, kS) of the steppers, allocated once per model; kS
    (stages, n, 13) holds the Runge-Kutta stage derivatives (rk4, dopri5)."""
    stages = {RK4: 4, DOPRI5: 7}.get(integrator, 0)
    return (np.zeros((WB_SIZE, n, 3)), np.zeros((WR_SIZE, r, 12)), np.zeros(WM_SIZE + n),
            np.zeros((stages, n, S_SIZE)))


# ----------------------------------------------------------------------------- tables


@kernel
def at(mf, table, row, width):
    """Index in mf of row `row` of the table whose offset is in header slot `table`."""
    return int(mf[table]) + row * width


@kernel
def vec3(mf, i):
    return (mf[i], mf[i + 1], mf[i + 2])


@kernel
def mat9(mf, i):
    return (mf[i], mf[i + 1], mf[i + 2], mf[i + 3], mf[i + 4], mf[i + 5], mf[i + 6],
            mf[i + 7], mf[i + 8])


@kernel
def param(mf, p):
    return mf[int(mf[H_PARAM]) + p]


@kernel
def slot_of(mf, body):
    return int(mf[at(mf, H_BODY, body, B_SIZE) + B_SLOT])


@kernel
def row3(a, i, c):
    return (a[i, c], a[i, c + 1], a[i, c + 2])


@kernel
def row4(a, i, c):
    return (a[i, c], a[i, c + 1], a[i, c + 2], a[i, c + 3])


@kernel
def row9(a, i, c):
    return (a[i, c], a[i, c + 1], a[i, c + 2], a[i, c + 3], a[i, c + 4], a[i, c + 5],
            a[i, c + 6], a[i, c + 7], a[i, c + 8])


@kernel
def put3(a, i, c, v):
    a[i, c] = v[0]
    a[i, c + 1] = v[1]
    a[i, c + 2] = v[2]


@kernel
def put4(a, i, c, v):
    a[i, c] = v[0]
    a[i, c + 1] = v[1]
    a[i, c + 2] = v[2]
    a[i, c + 3] = v[3]


@kernel
def put9(a, i, c, m):
    for j in range(9):
        a[i, c + j] = m[j]


@kernel
def add3(a, i, c, v):
    a[i, c] += v[0]
    a[i, c + 1] += v[1]
    a[i, c + 2] += v[2]


# ----------------------------------------------------------------------------- forces


@kernel(inline="always")
def world_omega(mf, k, R, L):
    """omega = I(t)^-1 L of rotating body k (R, L: 9- and 3-tuples); kinematic bodies turn
    at their given rate. Without orthonormalisation (the slide's plain Euler step) R may
    have drifted from a rotation: then I(t) = R I R^T is inverted as written."""
    i = at(mf, H_ROT, k, RT_SIZE)
    if mf[i + RT_KINEMATIC] != 0.0:
        return vec3(mf, i + RT_ANGVEL0)
    if param(mf, P_ORTHONORMALIZE) != 0.0:
        return la.matvec(R, la.matvec(mat9(mf, i + RT_INV_INERTIA), la.mattvec(R, L)))
    return la.solve3(la.sandwich(R, mat9(mf, i + RT_INERTIA)), L)


@kernel
def omegas(mf, RS, W):
    """World angular velocities W (r, 3) of the rotating bodies at RS."""
    for k in range(RS.shape[0]):
        put3(W, k, 0, world_omega(mf, k, row9(RS, k, RS_R), row3(RS, k, RS_L)))


@kernel
def arm_of(slot, point, RS):
    """Lever arm of a body-fixed point: R p for a turning body (slot >= 0), else p (stored
    in world axes already)."""
    if slot >= 0:
        return la.matvec(row9(RS, slot, RS_R), point)
    return point


@kernel(inline="always")
def forces(mf, step, t, S, RS, W, ext, acc, M):
    """Accelerations acc (n, 3) m/s^2 of all bodies and torques M (r, 3+) N m of the
    rotating ones at the state (S, RS); W (r, 3+): world angular velocities (used by
    damped springs only).

    Time windows are sampled at t, the step's start, for every stage of every integrator
    (a window acts on the steps whose start lies in it). ext (n, 6): forces and torques
    from other stages, constant over the step."""
    n, r = S.shape[0], RS.shape[0]
    ob, orr = int(mf[H_BODY]), int(mf[H_ROT])
    for i in range(n):
        acc[i, 0] = ext[i, 0]
        acc[i, 1] = ext[i, 1]
        acc[i, 2] = ext[i, 2]
    for k in range(r):
        b = int(mf[orr + k * RT_SIZE + RT_INDEX])
        M[k, 0] = ext[b, 3]
        M[k, 1] = ext[b, 4]
        M[k, 2] = ext[b, 5]
    of = int(mf[H_FORCE])
    for j in range(int(mf[H_F])):
        i = of + j * FC_SIZE
        if not (mf[i + FC_START] <= t < mf[i + FC_END]):
            continue
        b = int(mf[i + FC_BODY])
        slot = int(mf[ob + b * B_SIZE + B_SLOT])
        in_body = mf[i + FC_IN_BODY] != 0.0
        f = vec3(mf, i + FC_VEC)
        if in_body:  # body-frame forces turn with the body
            f = la.matvec(row9(RS, slot, RS_R), f)
        add3(acc, b, 0, f)
        if mf[i + FC_HAS_POINT] != 0.0 and slot >= 0:
            p = vec3(mf, i + FC_POINT)
            arm = la.matvec(row9(RS, slot, RS_R), p) if in_body else \
                la.sub(p, row3(S, b, S_POS))
            add3(M, slot, 0, la.cross(arm, f))
    ot = int(mf[H_TORQUE])
    for j in range(int(mf[H_K])):
        i = ot + j * TQ_SIZE
        if not (mf[i + TQ_START] <= t < mf[i + TQ_END]):
            continue
        slot = int(mf[ob + int(mf[i + TQ_BODY]) * B_SIZE + B_SLOT])
        tau = vec3(mf, i + TQ_VEC)
        if mf[i + TQ_IN_BODY] != 0.0:
            tau = la.matvec(row9(RS, slot, RS_R), tau)
        add3(M, slot, 0, tau)
    for j in range(int(mf[H_S])):
        spring(mf, j, S, RS, W, acc, M)
    for b in range(n):
        i = ob + b * B_SIZE
        c = mf[i + B_LIN_DAMP]
        if c != 0.0 and mf[i + B_MASS] > 0.0:
            cm = c * mf[i + B_MASS]
            acc[b, 0] -= cm * S[b, S_VEL]
            acc[b, 1] -= cm * S[b, S_VEL + 1]
            acc[b, 2] -= cm * S[b, S_VEL + 2]
    for k in range(r):
        i = orr + k * RT_SIZE
        if mf[i + RT_KINEMATIC] != 0.0:
            M[k, 0] = 0.0
            M[k, 1] = 0.0
            M[k, 2] = 0.0
            continue
        c = mf[ob + int(mf[i + RT_INDEX]) * B_SIZE + B_ANG_DAMP]
        if c != 0.0:
            M[k, 0] -= c * RS[k, RS_L]
            M[k, 1] -= c * RS[k, RS_L + 1]
            M[k, 2] -= c * RS[k, RS_L + 2]
    op = int(mf[H_PARAM])
    g0, g1, g2 = mf[op + P_GRAVITY], mf[op + P_GRAVITY + 1], mf[op + P_GRAVITY + 2]
    for b in range(n):
        i = ob + b * B_SIZE
        # gravity and forces move dynamic bodies that are in the scene during this step
        mask = 1.0 if (mf[i + B_DYNAMIC] != 0.0 and mf[i + B_EMIT] <= step) else 0.0
        im = mf[i + B_INV_MASS]
        acc[b, 0] = mask * (g0 + acc[b, 0] * im)
        acc[b, 1] = mask * (g1 + acc[b, 1] * im)
        acc[b, 2] = mask * (g2 + acc[b, 2] * im)


@kernel
def spring(mf, j, S, RS, W, acc, M):
    """Tension k (l - l0) + c dl/dt along spring j, dl/dt the relative velocity of its two
    ends along it: the force on a (towards b when stretched), minus it on b."""
    i = at(mf, H_SPRING, j, SP_SIZE)
    a, b = int(mf[i + SP_A]), int(mf[i + SP_B])
    slot_a = slot_of(mf, a)
    arm_a = arm_of(slot_a, vec3(mf, i + SP_PA), RS)
    pa = la.add(row3(S, a, S_POS), arm_a)
    va = row3(S, a, S_VEL)
    if slot_a >= 0:
        va = la.add(va, la.cross(row3(W, slot_a, 0), arm_a))
    slot_b = -1
    arm_b = (0.0, 0.0, 0.0)
    vb = (0.0, 0.0, 0.0)
    if b < 0:
        pb = vec3(mf, i + SP_PB)
    else:
        slot_b = slot_of(mf, b)
        arm_b = arm_of(slot_b, vec3(mf, i + SP_PB), RS)
        pb = la.add(row3(S, b, S_POS), arm_b)
        vb = row3(S, b, S_VEL)
        if slot_b >= 0:
            vb = la.add(vb, la.cross(row3(W, slot_b, 0), arm_b))
    dvec = la.sub(pb, pa)
    length = la.norm(dvec)
    u = la.scale(1.0 / length if length > 0.0 else 1.0, dvec)
    tension = mf[i + SP_K] * (length - mf[i + SP_REST]) + \
        mf[i + SP_C] * la.dot(la.sub(vb, va), u)
    f = la.scale(tension, u)
    add3(acc, a, 0, f)
    if slot_a >= 0:
        add3(M, slot_a, 0, la.cross(arm_a, f))
    if b >= 0:
        add3(acc, b, 0, la.scale(-1.0, f))
        if slot_b >= 0:
            add3(M, slot_b, 0, la.scale(-1.0, la.cross(arm_b, f)))


# ----------------------------------------------------------------------------- rotation


@kernel
def free_rotation(mf, k, R, L, h, strang, ratios):
    """R after time h of torque-free motion of rotating body k with constant world L:
    the exact flow (`rotation: {free_flow: exact}`, or a turn beyond SPLIT_MAX_TURN_*)
    or the splitting of the kinetic energy into its principal-axis terms, each an exact
    rotation: Lie-Trotter (1, 2, 3) or Strang (1, 2, 3, 2, 1 with half steps outside).
    Kinematic bodies are turned by the caller."""
    i = at(mf, H_ROT, k, RT_SIZE)
    if mf[i + RT_KINEMATIC] != 0.0:
        return R
    Q = mat9(mf, i + RT_AXES)
    Rp = la.matmul(R, Q)  # principal frame -> world
    moments = vec3(mf, i + RT_MOMENTS)
    Lb = la.mattvec(Rp, L)
    if param(mf, P_EXACT_FLOW) != 0.0 or too_far_to_split(moments, Lb, h, strang):
        ox, ow, os_ = int(mf[H_GL_X]), int(mf[H_GL_W]), int(mf[H_GL_START])
        Rp = free_flow.free_rotation(moments, Rp, L, h, mf[ox:ow], mf[ow:os_],
                                     mf[os_:os_ + free_flow.MAX_NODES + 2], ratios)
        return la.matmul(Rp, la.transpose(Q))
    rates = (1.0 / moments[0], 1.0 / moments[1], 1.0 / moments[2])
    if strang:
        for axis, hh in ((0, 0.5 * h), (1, 0.5 * h), (2, h), (1, 0.5 * h), (0, 0.5 * h)):
            turn = la.axis_rotation(axis, (hh * rates[axis]) * Lb[axis])
            Rp = la.matmul(Rp, turn)
            Lb = la.mattvec(turn, Lb)
    else:
        for axis in range(3):
            turn = la.axis_rotation(axis, (h * rates[axis]) * Lb[axis])
            Rp = la.matmul(Rp, turn)
            Lb = la.mattvec(turn, Lb)
    return la.matmul(Rp, la.transpose(Q))


@kernel
def too_far_to_split(moments, Lb, h, strang):
    """True when a drift of h s turns the body (principal-frame L Lb, moments kg m^2,
    ascending) by more than the splitting's limit (SPLIT_MAX_TURN_STRANG_RAD or _LIE_RAD):
    |omega| h with omega_i = Lb_i / I_i. Never for a spherical body: the splitting keeps
    its energy |L|^2 / (2 I) exactly (|L| is kept), so it keeps the splitting's numbers."""
    if moments[2] - moments[0] <= 1e-12 * moments[2]:
        return False
    w2 = 0.0
    for axis in range(3):
        w = Lb[axis] / moments[axis]
        w2 += w * w
    limit = SPLIT_MAX_TURN_STRANG_RAD if strang else SPLIT_MAX_TURN_LIE_RAD
    return math.sqrt(w2) * abs(h) > limit


@kernel
def finish(mf, R):
    """Re-orthonormalise R (unless the scene turned it off, or R is not finite: the checks
    then name the body)."""
    if param(mf, P_ORTHONORMALIZE) != 0.0 and finite9(R):
        return la.orthonormalize(R)
    return R


@kernel
def finite9(m):
    s = 0.0
    for i in range(9):
        s += m[i] * 0.0
    return s == 0.0


# ----------------------------------------------------------------------------- steppers


@kernel
def step_euler(mf, step, t, dt, S, RS, ext, S1, RS1, wb, wr):
    """The slide's explicit step: forces and omega at t; S += dt v, R += dt omega* R,
    P += dt F, L += dt M."""
    acc, M, W = wb[WB_ACC], wr[WR_M], wr[WR_W]
    omegas(mf, RS, W)
    forces(mf, step, t, S, RS, W, ext, acc, M)
    for i in range(S.shape[0]):
        for c in range(3):
            S1[i, S_POS + c] = S[i, S_POS + c] + dt * S[i, S_VEL + c]
            S1[i, S_VEL + c] = S[i, S_VEL + c] + dt * acc[i, c]
    for k in range(RS.shape[0]):
        Rk = row9(RS, k, RS_R)
        Rn = la.mat_axpy(dt, la.skew_mul(row3(W, k, 0), Rk), Rk)
        put9(RS1, k, RS_R, finish(mf, Rn))
        put3(RS1, k, RS_L, la.axpy(dt, row3(M, k, 0), row3(RS, k, RS_L)))


@kernel
def step_symplectic(mf, step, t, dt, S, RS, ext, S1, RS1, wb, wr, ratios):
    """Kick P and L with the forces at t, then drift: S with the new v, R with the free
    rigid-body flow under the new L (Lie-Trotter splitting or the exact flow)."""
    acc, M, W = wb[WB_ACC], wr[WR_M], wr[WR_W]
    if int(mf[H_S]):  # spring damping needs the ends' velocities
        omegas(mf, RS, W)
    forces(mf, step, t, S, RS, W, ext, acc, M)
    for i in range(S.shape[0]):
        for c in range(3):
            vv = S[i, S_VEL + c] + dt * acc[i, c]
            S1[i, S_VEL + c] = vv
            S1[i, S_POS + c] = S[i, S_POS + c] + dt * vv
    for k in range(RS.shape[0]):
        Lk = la.axpy(dt, row3(M, k, 0), row3(RS, k, RS_L))
        put3(RS1, k, RS_L, Lk)
        put9(RS1, k, RS_R, finish(mf, free_rotation(mf, k, row9(RS, k, RS_R), Lk, dt, False,
                                                    ratios)))


@kernel
def step_verlet(mf, step, t, dt, S, RS, ext, S1, RS1, wb, wr, ratios):
    """Half kick, drift (Strang splitting or the exact flow), half kick. The second kick
    needs the forces at the step's end, which may depend on the end velocities (damping,
    damped springs): they are evaluated at v0 + dt a0 and L0 + dt M0, within O(dt^2) of
    the end values, so the step stays of order 2. Forces that do not depend on velocities
    are unchanged by this: the method is then the symplectic, time-reversible
    Stormer-Verlet."""
    acc, M, W = wb[WB_ACC], wr[WR_M], wr[WR_W]
    vh, Lh = wb[WB_VH], wr[WR_LH]
    n, r = S.shape[0], RS.shape[0]
    springs = int(mf[H_S]) > 0
    if springs:
        omegas(mf, RS, W)
    forces(mf, step, t, S, RS, W, ext, acc, M)
    h = 0.5 * dt
    for i in range(n):
        for c in range(3):
            vh[i, c] = S[i, S_VEL + c] + h * acc[i, c]
            S1[i, S_POS + c] = S[i, S_POS + c] + dt * vh[i, c]
            S1[i, S_VEL + c] = vh[i, c] + h * acc[i, c]  # the predictor v0 + dt a0
    for k in range(r):
        for c in range(3):
            Lh[k, c] = RS[k, RS_L + c] + h * M[k, c]
            RS1[k, RS_L + c] = Lh[k, c] + h * M[k, c]  # the predictor L0 + dt M0
        put9(RS1, k, RS_R, finish(mf, free_rotation(mf, k, row9(RS, k, RS_R), row3(Lh, k, 0),
                                                    dt, True, ratios)))
    if param(mf, P_STATIC_FORCES) == 0.0:
        if springs:
            omegas(mf, RS1, W)
        forces(mf, step, t, S1, RS1, W, ext, acc, M)
    for i in range(n):
        for c in range(3):
            S1[i, S_VEL + c] = vh[i, c] + h * acc[i, c]
    for k in range(r):
        for c in range(3):
            RS1[k, RS_L + c] = Lh[k, c] + h * M[k, c]


# ------------------------------------------------------------------ body-frame Runge-Kutta
#
# The stage state: positions and velocities in the S layout (n, 13; the quaternions of
# the rotating bodies in column S_QUAT of their rows, as in the state), and Lb (r, 3).
# A stage's derivative goes into k arrays of the same layout: kS (stages, n, 13) holds
# (x', v', q'), kL (stages, r, 3) holds Lb'.


@kernel(inline="always")
def derivative(mf, step, t, Ss, Lb, ext, RSs, W, M, kS, kL, stage):
    """(x, v, q, Lb)' of the body-frame system at the stage state (Ss, Lb), into row
    `stage` of kS, kL. RSs (r, 12): scratch for the stage's (R, L world); W, M: scratch."""
    n, r = Ss.shape[0], Lb.shape[0]
    for k in range(r):
        i = at(mf, H_ROT, k, RT_SIZE)
        b = int(mf[i + RT_INDEX])
        qk = row4(Ss, b, S_QUAT)
        Rk = la.quat_to_matrix(la.quat_normalize(qk))
        Lbk = row3(Lb, k, 0)
        if mf[i + RT_KINEMATIC] != 0.0:
            wb = la.mattvec(Rk, vec3(mf, i + RT_ANGVEL0))
        else:
            wb = la.matvec(mat9(mf, i + RT_INV_INERTIA), Lbk)
        put9(RSs, k, RS_R, Rk)
        put3(RSs, k, RS_L, la.matvec(Rk, Lbk))
        put3(W, k, 0, la.matvec(Rk, wb))
        dq = la.quat_mul(qk, (0.0, wb[0], wb[1], wb[2]))
        put4(kS[stage], b, S_QUAT, (0.5 * dq[0], 0.5 * dq[1], 0.5 * dq[2], 0.5 * dq[3]))
    acc = kS[stage, :, S_VEL:S_VEL + 3]
    forces(mf, step, t, Ss, RSs, W, ext, acc, M)
    for k in range(r):
        i = at(mf, H_ROT, k, RT_SIZE)
        if mf[i + RT_KINEMATIC] != 0.0:
            put3(kL[stage], k, 0, (0.0, 0.0, 0.0))
            continue
        Lbk = row3(Lb, k, 0)
        wb = la.matvec(mat9(mf, i + RT_INV_INERTIA), Lbk)
        put3(kL[stage], k, 0, la.add(la.cross(Lbk, wb), la.mattvec(row9(RSs, k, RS_R),
                                                                   row3(M, k, 0))))
    for i in range(n):
        kS[stage, i, S_POS] = Ss[i, S_VEL]
        kS[stage, i, S_POS + 1] = Ss[i, S_VEL + 1]
        kS[stage, i, S_POS + 2] = Ss[i, S_VEL + 2]


@kernel(inline="always")
def combine(mf, S0, Lb0, kS, kL, coef, stages, h, Ss, Lbs):
    """Ss = S0 + h sum_s coef[s] kS[s] on positions, velocities and the rotating bodies'
    quaternions; Lbs likewise; zero coefficients skipped (the textbook stage sums)."""
    n, r = S0.shape[0], Lb0.shape[0]
    for i in range(n):
        for c in range(6):
            a = S0[i, c]
            for s in range(stages):
                w = coef[s]
                if w != 0.0:
                    a += (h * w) * kS[s, i, c]
            Ss[i, c] = a
    for k in range(r):
        b = int(mf[at(mf, H_ROT, k, RT_SIZE) + RT_INDEX])
        for c in range(S_QUAT, S_QUAT + 4):
            a = S0[b, c]
            for s in range(stages):
                w = coef[s]
                if w != 0.0:
                    a += (h * w) * kS[s, b, c]
            Ss[b, c] = a
        for c in range(3):
            a = Lb0[k, c]
            for s in range(stages):
                w = coef[s]
                if w != 0.0:
                    a += (h * w) * kL[s, k, c]
            Lbs[k, c] = a


@kernel(inline="always")
def body_frame_start(mf, S, RS, S0, Lb0):
    """The Runge-Kutta start: S0 = S (quaternions included) and Lb0 = R^T L."""
    for i in range(S.shape[0]):
        for c in range(S_SIZE):
            S0[i, c] = S[i, c]
    for k in range(RS.shape[0]):
        put3(Lb0, k, 0, la.mattvec(row9(RS, k, RS_R), row3(RS, k, RS_L)))


@kernel(inline="always")
def body_frame_end(mf, Sf, Lbf, S1, RS1):
    """Positions and velocities from Sf; the quaternions projected onto the unit sphere
    (once per step) and (R, L world) from them and Lbf."""
    for i in range(Sf.shape[0]):
        for c in range(6):
            S1[i, c] = Sf[i, c]
    for k in range(Lbf.shape[0]):
        b = int(mf[at(mf, H_ROT, k, RT_SIZE) + RT_INDEX])
        qk = la.quat_normalize(row4(Sf, b, S_QUAT))
        if qk[0] < 0.0:
            qk = (-qk[0], -qk[1], -qk[2], -qk[3])
        put4(S1, b, S_QUAT, qk)
        Rk = la.quat_to_matrix(qk)
        put9(RS1, k, RS_R, Rk)
        put3(RS1, k, RS_L, la.matvec(Rk, row3(Lbf, k, 0)))


RK4_A = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 1.0]])
RK4_B = np.array([1 / 6, 1 / 3, 1 / 3, 1 / 6])


@kernel
def step_rk4(mf, step, t, dt, S, RS, ext, S1, RS1, wb, wr, kS, Ss, S0, RSs):
    """Classical Runge-Kutta on (S, v, q, Lb), body frame; order 4. For positions and
    velocities the stage sums are written as the textbook's, so accelerations that are
    polynomials of degree <= 3 in t (projectiles) integrate to round-off."""
    M, W = wr[WR_M], wr[WR_W]
    Lb0, Lbs, kL = wr[WR_LB0, :, :3], wr[WR_LBS, :, :3], wr[WR_KL:WR_KL + 4, :, :3]
    n, r = S.shape[0], RS.shape[0]
    body_frame_start(mf, S, RS, S0, Lb0)
    for s in range(4):
        combine(mf, S0, Lb0, kS, kL, RK4_A[s], s, dt, Ss, Lbs)
        derivative(mf, step, t, Ss, Lbs, ext, RSs, W, M, kS, kL, s)
    sixth = dt / 6.0
    for i in range(n):
        for j in range(6):
            Ss[i, j] = S0[i, j] + sixth * (kS[0, i, j] + 2.0 * kS[1, i, j]
                                           + 2.0 * kS[2, i, j] + kS[3, i, j])
    for k in range(r):
        b = int(mf[at(mf, H_ROT, k, RT_SIZE) + RT_INDEX])
        for j in range(S_QUAT, S_QUAT + 4):
            Ss[b, j] = S0[b, j] + sixth * (kS[0, b, j] + 2.0 * kS[1, b, j]
                                           + 2.0 * kS[2, b, j] + kS[3, b, j])
        for j in range(3):
            Lbs[k, j] = Lb0[k, j] + sixth * (kL[0, k, j] + 2.0 * kL[1, k, j]
                                             + 2.0 * kL[2, k, j] + kL[3, k, j])
    body_frame_end(mf, Ss, Lbs, S1, RS1)


# Dormand & Prince 5(4) (Hairer, Norsett & Wanner, Solving ODEs I, table II.5.2): the 5th
# order solution is propagated, the embedded 4th order one estimates the error.
DP_A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [1 / 5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3 / 40, 9 / 40, 0.0, 0.0, 0.0, 0.0, 0.0],
    [44 / 45, -56 / 15, 32 / 9, 0.0, 0.0, 0.0, 0.0],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0.0, 0.0, 0.0],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0.0, 0.0],
    [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0],
])
DP_B5 = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0.0])
DP_B4 = np.array([5179 / 57600, 0.0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100,
                  1 / 40])
DP_E = DP_B5 - DP_B4
SAFETY, MIN_SHRINK, MAX_GROW = 0.9, 0.2, 5.0


@kernel
def dp_error(mf, S0, Ss, Lb0, Lbs, kS, kL, h, tol, err):
    """The RMS of err_i / (tol + tol max(|y0_i|, |y1_i|)) over every component (x, v: 3n
    each; q: 4r; Lb: 3r), err = h sum_s E_s k_s; err[1] gets the worst component, err[2]
    its ratio."""
    n, r = S0.shape[0], Lb0.shape[0]
    total, count, worst, worst_i = 0.0, 0, -1.0, 0
    for k in range(r + n):
        for c in range(7):
            if k < n:  # x (3n), then v (3n) components
                if c >= 6:
                    continue
                row, col = k, c
                y0, y1 = S0[row, col], Ss[row, col]
                comp = (3 * n if c >= 3 else 0) + 3 * k + (c % 3)
            else:  # rotating body kk: q (4r) then Lb (3r)
                kk = k - n
                b = int(mf[at(mf, H_ROT, kk, RT_SIZE) + RT_INDEX])
                if c < 4:
                    row, col = b, S_QUAT + c
                    y0, y1 = S0[row, col], Ss[row, col]
                    comp = 6 * n + 4 * kk + c
                else:
                    row, col = kk, c - 4
                    y0, y1 = Lb0[row, col], Lbs[row, col]
                    comp = 6 * n + 4 * r + 3 * kk + (c - 4)
            e = 0.0
            for s in range(7):
                w = DP_E[s]
                if w != 0.0:
                    e += w * (kS[s, row, col] if (k < n or c < 4) else kL[s, row, col])
            ratio = abs(h * e) / (tol + tol * max(abs(y0), abs(y1)))
            if not math.isfinite(ratio):
                ratio = math.inf
            total += ratio * ratio
            count += 1
            if ratio > worst:
                worst, worst_i = ratio, comp
    err[1] = worst_i
    err[2] = worst
    return math.sqrt(total / count) if count else 0.0


@kernel
def step_dopri5(mf, step, t, dt, S, RS, ext, S1, RS1, wb, wr, wm, kS, Ss, S0, RSs, h_prop):
    """Adaptive Dormand-Prince steps over [t, t + dt] (the last one clipped to land on
    t + dt) on the body-frame system, error per step <= tolerance (mixed absolute and
    relative, RMS norm), q normalised after every accepted step. Returns the step proposed
    for the next interval, or -1 - (worst component) at a step-size underflow, with its
    time in wm[WM_FAIL_T]. Components: x (3n), v (3n), q (4r), Lb (3r)."""
    M, W = wr[WR_M], wr[WR_W]
    Lb0, Lbs, kL = wr[WR_LB0, :, :3], wr[WR_LBS, :, :3], wr[WR_KL:WR_KL + 7, :, :3]
    err = wm[WM_ERR:WM_ERR + 4]
    n, r = S.shape[0], RS.shape[0]
    tol = param(mf, P_TOLERANCE)
    body_frame_start(mf, S, RS, S0, Lb0)
    t1 = t + dt
    tt = t
    span = dt
    hp = min(h_prop if h_prop > 0.0 else dt, span)
    while t1 - tt > 1e-14 * max(abs(t1), span):
        last = hp >= t1 - tt
        hh = t1 - tt if last else hp
        for s in range(7):
            combine(mf, S0, Lb0, kS, kL, DP_A[s], s, hh, Ss, Lbs)
            # autonomous within the step: time windows are read at the step's start t
            derivative(mf, step, t, Ss, Lbs, ext, RSs, W, M, kS, kL, s)
        combine(mf, S0, Lb0, kS, kL, DP_B5, 7, hh, Ss, Lbs)
        norm_ = dp_error(mf, S0, Ss, Lb0, Lbs, kS, kL, hh, tol, err)
        if not math.isfinite(norm_):
            norm_ = math.inf
        factor = MAX_GROW if norm_ == 0.0 else \
            min(MAX_GROW, max(MIN_SHRINK, SAFETY * trig.inv_fifth_root(norm_)))
        if norm_ <= 1.0:
            tt = t1 if last else tt + hh
            for i in range(n):
                for c in range(6):
                    S0[i, c] = Ss[i, c]
            for k in range(r):
                b = int(mf[at(mf, H_ROT, k, RT_SIZE) + RT_INDEX])
                qk = row4(Ss, b, S_QUAT)
                if qk[0] == qk[0]:  # not NaN: back onto the unit quaternions
                    qk = la.quat_normalize(qk)
                put4(S0, b, S_QUAT, qk)
                for c in range(3):
                    Lb0[k, c] = Lbs[k, c]
            hp = max(hp, hh * factor) if last else hh * factor
        else:
            hp = hh * factor
            if hp < 1e-13 * max(abs(tt), span):
                wm[WM_FAIL_T] = tt
                return -1.0 - err[1]
    body_frame_end(mf, S0, Lb0, S1, RS1)
    return hp


# ----------------------------------------------------------------------------- after a step


@kernel(inline="always")
def post_step(mf, body_frame, step_index, dt, RS, S1, RS1):
    """After any stepper: kinematic bodies turned exactly at their rate, quaternions of
    the splitting methods' R (from the polar factor where R is not kept orthonormal),
    world angular velocities, and emitted bodies launched when their step comes."""
    ortho = param(mf, P_ORTHONORMALIZE) != 0.0
    n, r = S1.shape[0], RS1.shape[0]
    ob = int(mf[H_BODY])
    for i in range(n):
        S1[i, S_ANGVEL] = 0.0
        S1[i, S_ANGVEL + 1] = 0.0
        S1[i, S_ANGVEL + 2] = 0.0
    for k in range(r):
        i = at(mf, H_ROT, k, RT_SIZE)
        b = int(mf[i + RT_INDEX])
        if mf[i + RT_KINEMATIC] != 0.0:
            Rk = la.matmul(la.exp_so3(la.scale(dt, vec3(mf, i + RT_ANGVEL0))),
                           row9(RS, k, RS_R))
            put9(RS1, k, RS_R, Rk)
            if body_frame:
                put4(S1, b, S_QUAT, la.quat_from_matrix(Rk))
        Rk = row9(RS1, k, RS_R)
        if not body_frame:
            shown = Rk if ortho else la.orthonormalize(Rk)
            put4(S1, b, S_QUAT, la.quat_from_matrix(shown))
        put3(S1, b, S_ANGVEL, world_omega(mf, k, Rk, row3(RS1, k, RS_L)))
    if param(mf, P_HAS_EMITTERS) != 0.0:
        after = step_index + 1
        for b in range(n):
            i = ob + b * B_SIZE
            if mf[i + B_EMIT] == after and after != 0:
                S1[b, S_VEL] = mf[i + B_VEL0]
                S1[b, S_VEL + 1] = mf[i + B_VEL0 + 1]
                S1[b, S_VEL + 2] = mf[i + B_VEL0 + 2]


# ----------------------------------------------------------------------------- checks


@kernel(inline="always")
def translation_ok(S):
    """-1 when every position and velocity is finite and within bounds, else the first
    offending body."""
    for i in range(S.shape[0]):
        for c in range(3):
            if not (abs(S[i, S_POS + c]) < MAX_POSITION_M
                    and abs(S[i, S_VEL + c]) < MAX_SPEED_M_S):
                return i
    return -1


@kernel(inline="always")
def rotation_ok(mf, RS):
    for k in range(RS.shape[0]):
        for c in range(RS_SIZE):
            if not math.isfinite(RS[k, c]):
                return int(mf[at(mf, H_ROT, k, RT_SIZE) + RT_INDEX])
    return -1


@kernel
def body_energy(mf, S, RS, out):
    """Per-body mechanical energy (n,) J into `out`: m|v|^2/2 + L.omega/2 - m g.x, a
    spring's k (l - l0)^2/2 split between its two bodies (all to the one that moves when
    the other end is an anchor, a static or a kinematic body). Returns (kinetic J,
    spring J) totals."""
    op, ob = int(mf[H_PARAM]), int(mf[H_BODY])
    g0, g1, g2 = mf[op + P_GRAVITY], mf[op + P_GRAVITY + 1], mf[op + P_GRAVITY + 2]
    n = S.shape[0]
    kinetic = 0.0
    for b in range(n):
        m = mf[ob + b * B_SIZE + B_MASS]
        vx, vy, vz = S[b, S_VEL], S[b, S_VEL + 1], S[b, S_VEL + 2]
        ke = 0.5 * m * (vx * vx + vy * vy + vz * vz)
        out[b] = ke - m * (S[b, S_POS] * g0 + S[b, S_POS + 1] * g1 + S[b, S_POS + 2] * g2)
        kinetic += ke
    for k in range(RS.shape[0]):
        i = at(mf, H_ROT, k, RT_SIZE)
        if mf[i + RT_KINEMATIC] != 0.0:
            continue
        Lk = row3(RS, k, RS_L)
        ke = 0.5 * la.dot(Lk, world_omega(mf, k, row9(RS, k, RS_R), Lk))
        out[int(mf[i + RT_INDEX])] += ke
        kinetic += ke
    total_spring = 0.0
    for j in range(int(mf[H_S])):
        i = at(mf, H_SPRING, j, SP_SIZE)
        a, b = int(mf[i + SP_A]), int(mf[i + SP_B])
        pa = la.add(row3(S, a, S_POS), arm_of(slot_of(mf, a), vec3(mf, i + SP_PA), RS))
        if b < 0:
            pb = vec3(mf, i + SP_PB)
        else:
            pb = la.add(row3(S, b, S_POS), arm_of(slot_of(mf, b), vec3(mf, i + SP_PB), RS))
        stretch = la.norm(la.sub(pb, pa)) - mf[i + SP_REST]
        e = 0.5 * mf[i + SP_K] * stretch * stretch
        total_spring += e
        if b >= 0 and mf[ob + b * B_SIZE + B_DYNAMIC] != 0.0:
            out[a] += 0.5 * e
            out[b] += 0.5 * e
        else:
            out[a] += e
    return kinetic, total_spring


@kernel
def energy_bound(mf, S, RS, kinetic, spring_e, tau, dt):
    """J: how much the mechanical energy of a conserving scene may have grown tau s after
    the guard's baseline, in steps of dt (docs/dynamics.md, "Energy guard"):

        scale * min(cap, max(floor, safety * (omega dt)^p * (1 + omega tau)))
        + round_off * sum_b m_b |g| |x_b|

    An order-p method errs by ~(omega dt)^(p+1) of the energy per step, (omega dt)^p
    (omega tau) after tau / dt steps. omega (rad/s): the scene's frequency scale (spin,
    springs, damping, gravity over 1 m; P_OMEGA), raised to sqrt(2 T / I_min) of any
    rotating body now (T = L.omega / 2 its kinetic energy of rotation: |omega| never
    exceeds it while T is kept; impacts and springs can change it). dopri5
    (p = 5) errs by at most its tolerance per step, over max(omega tau * P_STEPS_PER_TURN,
    tau / dt) steps. scale: kinetic + |spring| now or at t = 0, + m |g| 1 m per body. The
    last term covers the round-off of m g.x far from the origin."""
    op = int(mf[H_PARAM])
    omega = mf[op + P_OMEGA]
    for k in range(RS.shape[0]):
        i = at(mf, H_ROT, k, RT_SIZE)
        moment = mf[i + RT_MOMENTS]  # the smallest principal moment
        if mf[i + RT_KINEMATIC] == 0.0 and moment > 0.0:
            Lk = row3(RS, k, RS_L)
            twice_t = la.dot(Lk, world_omega(mf, k, row9(RS, k, RS_R), Lk))
            omega = max(omega, math.sqrt(max(twice_t, 0.0) / moment))
    order = int(mf[op + P_ORDER])
    if order >= 5:
        steps = max(omega * tau * mf[op + P_STEPS_PER_TURN], tau / dt)
        rel = mf[op + P_SAFETY] * mf[op + P_TOLERANCE] * (1.0 + steps)
    else:
        power = 1.0
        for _ in range(order):  # no pow: libm's differs in the last bit between CPUs
            power *= omega * dt
        rel = mf[op + P_SAFETY] * power * (1.0 + omega * tau)
    rel = min(mf[op + P_GROWTH_LIMIT], max(mf[op + P_FLOOR], rel))
    g = la.norm(vec3(mf, op + P_GRAVITY))
    ob = int(mf[H_BODY])
    far = 0.0
    for b in range(S.shape[0]):
        far += mf[ob + b * B_SIZE + B_MASS] * g * la.norm(row3(S, b, S_POS))
    scale = max(kinetic + abs(spring_e), mf[op + P_ENERGY0_SCALE]) + mf[op + P_WEIGHT]
    return rel * scale + mf[op + P_ROUND_OFF] * far


@kernel
def energy_check(mf, S, RS, base, per_body, tau, dt):
    """(-1 when the energy has not grown past `energy_bound` (nor fallen past it, in a
    scene with nothing that dissipates: P_TWO_SIDED), else the body whose energy changed
    most that way; the growth J (< 0: a loss); the bound J). `base` (n,) J: the
    baseline per body; tau s: the time since it."""
    kinetic, spring_e = body_energy(mf, S, RS, per_body)
    n = S.shape[0]
    gain = 0.0
    for i in range(n):
        gain += per_body[i]
    for i in range(n):
        gain -= base[i]
    bound = energy_bound(mf, S, RS, kinetic, spring_e, tau, dt)
    sign = 1.0 if gain > bound else -1.0 if (
        param(mf, P_TWO_SIDED) != 0.0 and -gain > bound) else 0.0
    if sign != 0.0:
        worst, worst_body = -math.inf, 0
        for i in range(n):
            if sign * (per_body[i] - base[i]) > worst:
                worst, worst_body = sign * (per_body[i] - base[i]), i
        return worst_body, gain, bound
    return -1, gain, bound


# ----------------------------------------------------------------------------- entries
#
# One compiled entry point per integrator, made on first use. The integrator is a
# constant of the closure, so numba prunes the other integrators' branches and compiles,
# caches and loads only the one a scene uses.

_ENTRIES: dict = {}


def entry(integ: int):
    """The `run` kernel of integrator `integ` (INTEGRATOR_CODES)."""
    if integ not in _ENTRIES:
        _ENTRIES[integ] = _make_run(integ)
    return _ENTRIES[integ]


def _make_run(integ: int):
    body_frame = integ == RK4 or integ == DOPRI5

    @kernel
    def run(mf, step0, count, n_steps, steps_per_frame, t_first, dt, h_prop, checked, bS,
            bRS, ext, base, base_set, wb, wr, wm, kS, status):
        """Up to `count` steps of dt from step0 on the double buffers bS (2, n, 13) and
        bRS (2, r, 12), starting in buffer 0; the first step starts at t_first (collision
        response advances by parts of a step), the others at (step0 + s) dt. With
        `checked`, the blow-up checks run after every step and the energy guard at frame
        ends. kS (stages, n, 13): the Runge-Kutta stage derivatives (rk4, dopri5).

        status (out, int64 (5,)): [code (OK, BLOWUP_*, ENERGY_GROWTH, STEP_UNDERFLOW),
        steps done, buffer holding the last good state, offending body or component,
        buffer holding the failed state]. Returns the dopri5 step proposal. `base` (n,) J:
        the energy guard's baseline (the model's energy at t = 0, or the state's once the
        force windows have closed); replaced, with base_set[0] = 1, when they close here.
        """
        n, r = bS.shape[1], bRS.shape[1]
        guard = checked and param(mf, P_ENERGY_GUARD) != 0.0
        guard_from = param(mf, P_GUARD_FROM)
        ratios = wm[WM_RATIOS:WM_RATIOS + 16]
        per_body = wm[WM_SIZE:WM_SIZE + n]
        Ss = np.empty((n, S_SIZE))  # Runge-Kutta stage state and start, and its rotation
        S0 = np.empty((n, S_SIZE))
        RSs = np.empty((r, RS_SIZE))
        status[0] = OK
        status[1] = 0
        status[2] = 0
        status[3] = -1
        status[4] = 1
        cur = 0
        for s in range(count):
            st = step0 + s
            t = t_first if s == 0 else st * dt
            nxt = 1 - cur
            S, RS, S1, RS1 = bS[cur], bRS[cur], bS[nxt], bRS[nxt]
            status[4] = nxt
            for i in range(n):  # quaternions of bodies that do not turn stay as they are
                for c in range(S_QUAT, S_QUAT + 4):
                    S1[i, c] = S[i, c]
            if integ == EULER:
                step_euler(mf, st, t, dt, S, RS, ext, S1, RS1, wb, wr)
            elif integ == SYMPLECTIC_EULER:
                step_symplectic(mf, st, t, dt, S, RS, ext, S1, RS1, wb, wr, ratios)
            elif integ == VERLET:
                step_verlet(mf, st, t, dt, S, RS, ext, S1, RS1, wb, wr, ratios)
            elif integ == RK4:
                step_rk4(mf, st, t, dt, S, RS, ext, S1, RS1, wb, wr, kS, Ss, S0, RSs)
            else:
                h_new = step_dopri5(mf, st, t, dt, S, RS, ext, S1, RS1, wb, wr, wm, kS, Ss, S0,
                                    RSs, h_prop)
                if h_new < 0.0:
                    status[0] = STEP_UNDERFLOW
                    status[3] = int(-1.0 - h_new)
                    break
                h_prop = h_new
            post_step(mf, body_frame, st, dt, RS, S1, RS1)
            if checked:
                bad = translation_ok(S1)
                if bad >= 0:
                    status[0] = BLOWUP_TRANSLATION
                    status[3] = bad
                    break
                bad = rotation_ok(mf, RS1)
                if bad >= 0:
                    status[0] = BLOWUP_ROTATION
                    status[3] = bad
                    break
            after = st + 1
            t_after = after * dt
            if guard and 0.0 < guard_from and t < guard_from <= t_after:  # windows closed
                body_energy(mf, S1, RS1, base)
                base_set[0] = 1
            if guard and t_after >= guard_from and (after % steps_per_frame == 0
                                                    or after == n_steps):
                bad = energy_check(mf, S1, RS1, base, per_body, t_after - guard_from, dt)[0]
                if bad >= 0:
                    status[0] = ENERGY_GROWTH
                    status[3] = bad
                    break
            cur = nxt
            status[1] = s + 1
            status[2] = cur
        return h_prop

    return run
