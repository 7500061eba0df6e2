"""Compile the rigid-body part of a scene into frozen arrays (`Model.rigid`).

Layer 2 helper of `model.compile_model`. Structure-of-arrays over the *rotating subset*
of bodies (`rot_*`, indexed by `rot_index`): a point mass is never in it, so it pays
nothing for rotation. Forces keep the order of `Model.force_*` (scene order), so
`force_point[k]` belongs to `Model.force_vec[k]`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from vrsim_cli.maths.eigen import principal_axes
from vrsim_cli.maths.products import inv3, matmul, norm

from vrsim_cli.errors import Problem
from vrsim_cli.maths.spatial import quat_to_matrix
from vrsim_cli.model.mass_properties import MassPropertyError, body_mass_properties
from vrsim_cli.scene.rigid import rotates

ADAPTIVE = ("dopri5",)
BODY_DYNAMIC, BODY_KINEMATIC = 0, 1  # model.BODY_* (model imports this module)
DEFAULT_TOLERANCE = 1e-6
DEFAULT_FREE_FLOW = "splitting"
SPLITTING = ("symplectic-euler", "verlet")  # the integrators with a free-rotation drift


@dataclass(frozen=True)
class RigidModel:
    """Constants of the rigid-body dynamics. r rotating bodies, s springs, k torques.

    rot_index: (r,) int64 body index of each rotating body
    rot_slot: (n_body,) int64 position in the rot_* arrays, -1 for bodies that do not rotate
    rot_kinematic: (r,) bool, True: a kinematic body turning at rot_angvel0
    rot_inertia: (r, 3, 3) kg m^2, body frame, about the centre of mass (2D: Izz E)
    rot_inv_inertia: (r, 3, 3) 1/(kg m^2); zero for kinematic bodies
    rot_moments: (r, 3) kg m^2 principal moments, ascending; rot_axes: (r, 3, 3) the
        principal axes as columns (body frame), rot_inertia = axes diag(moments) axes^T
    rot_matrix0: (r, 3, 3) R at t = 0; rot_angmom0: (r, 3) kg m^2/s world L at t = 0;
    rot_angvel0: (r, 3) rad/s world omega at t = 0
    body_lin_damping, body_ang_damping: (n_body,) 1/s
    force_vec: (n_force, 3) N: world vectors, except body-frame forces on rotating bodies
        (force_in_body), which are in model coordinates; a body-frame force on a body that
        does not rotate is turned by its fixed orientation here, once
    force_point: (n_force, 3) m; force_has_point, force_in_body: (n_force,) bool
    torque_body: (k,) int64; torque_vec: (k, 3) N m; torque_start, torque_end: (k,) s;
        torque_in_body: (k,) bool
    spring_a, spring_b: (s,) int64 body indices (spring_b -1: a world anchor);
    spring_point_a: (s, 3) m model coordinates of a; spring_point_b: (s, 3) m model
        coordinates of b, or the world anchor (an end on a body that does not rotate
        holds its lever arm in world axes instead); spring_k N/m, spring_c N s/m,
        spring_rest m
    """

    rot_index: np.ndarray
    rot_slot: np.ndarray
    rot_kinematic: np.ndarray
    rot_inertia: np.ndarray
    rot_inv_inertia: np.ndarray
    rot_moments: np.ndarray
    rot_axes: np.ndarray
    rot_matrix0: np.ndarray
    rot_angmom0: np.ndarray
    rot_angvel0: np.ndarray
    body_lin_damping: np.ndarray
    body_ang_damping: np.ndarray
    force_vec: np.ndarray
    force_point: np.ndarray
    force_has_point: np.ndarray
    force_in_body: np.ndarray
    torque_body: np.ndarray
    torque_vec: np.ndarray
    torque_start: np.ndarray
    torque_end: np.ndarray
    torque_in_body: np.ndarray
    spring_a: np.ndarray
    spring_b: np.ndarray
    spring_point_a: np.ndarray
    spring_point_b: np.ndarray
    spring_k: np.ndarray
    spring_c: np.ndarray
    spring_rest: np.ndarray
    orthonormalize: bool  # re-orthonormalise R after every step
    tolerance: float  # dopri5: error tolerance per step
    energy_guard: bool  # the scene conserves energy (up to damping): guard against growth
    mass_properties: tuple  # (n_body,) MassProperties | None, for reports
    static_forces: bool = False  # forces and torques depend on time only (not on x, v, R, L)
    energy0_body: np.ndarray | None = None  # (n_body,) J at t = 0 (energy_guard only)
    energy0_scale: float = 0.0  # J: kinetic + |spring| energy at t = 0 (energy_guard only)
    energy_omega: float = 0.0  # rad/s: the scene's frequency scale (`frequency_scale`)
    # s: the guard watches the energy from this time on (0: from the start; when windowed
    # forces or torques act, from the end of the last window, against the energy then).
    energy_guard_from: float = 0.0
    # The free-rotation drift of symplectic-euler and verlet: "splitting" (exact rotations
    # about the principal axes) or "exact" (the exact torque-free flow, `free_body.py`).
    free_flow: str = "splitting"

    @property
    def n_rot(self) -> int:
        return len(self.rot_index)


def _frozen(array, dtype=float) -> np.ndarray:
    out = np.array(array, dtype=dtype)
    out.flags.writeable = False
    return out


def _vec3(values, dim: int) -> list[float]:
    values = [float(v) for v in values]
    return values + [0.0] * (3 - len(values))


def _about_z(value, dim: int) -> list[float]:
    """A 2D scalar (about z) or a 3D vector as a 3-vector."""
    return [0.0, 0.0, float(value)] if dim == 2 else [float(v) for v in value]


def rigid_notes(data: dict) -> tuple:
    """Valid keys that have no effect in this scene, said out loud."""
    integrator = data.get("integrator", "symplectic-euler")
    notes = []
    if "tolerance" in data and integrator not in ADAPTIVE:
        notes.append(f"tolerance has no effect with integrator {integrator}: it is for "
                     f"dopri5, which chooses its own steps")
    free_flow = (data.get("rotation") or {}).get("free_flow", DEFAULT_FREE_FLOW)
    if free_flow != DEFAULT_FREE_FLOW and integrator not in SPLITTING:
        notes.append(f"rotation.free_flow: {free_flow} has no effect with integrator "
                     f"{integrator}: it is the drift of symplectic-euler and verlet")
    return tuple(notes)


def needs_rigid(data: dict) -> bool:
    """Does the scene use anything beyond point masses under forces at the centre of mass?"""
    if data.get("integrator") in ADAPTIVE or data.get("springs"):
        return True
    for body in data.get("bodies") or []:
        if rotates(body) or "angular_velocity" in body or "damping" in body \
                or body.get("torques"):
            return True
        if any("point" in f or f.get("frame") == "body" for f in body.get("forces") or []):
            return True
    return False


def compile_rigid(scene, dim: int, n_body: int, kinds: list, masses: list, pos0: list,
                  vel0: list, quat0: list, mesh_paths: list, problems: list[Problem]) \
        -> RigidModel | None:
    """The rigid part of the model, or None for a scene of point masses only. Sets the
    masses of bodies whose mass comes from particles or density (in `masses`)."""
    data = scene.data
    if not needs_rigid(data):
        return None
    bodies = data.get("bodies") or []
    props_all: list = [None] * n_body
    rot_index, rot_kin, inertia, angvel0 = [], [], [], []
    lin_damp = np.zeros(n_body)
    ang_damp = np.zeros(n_body)
    force_vec, force_point, force_has_point, force_in_body = [], [], [], []
    torque_body, torque_vec, torque_start, torque_end, torque_in_body = [], [], [], [], []
    for i, body in enumerate(bodies):
        at = ("bodies", i)
        kind = body.get("type", "dynamic")
        if mesh_paths[i] is None and (body.get("shape") or {}).get("type") == "mesh":
            continue  # the missing file is already reported
        if kind == "dynamic" and rotates(body):
            try:
                props = body_mass_properties(body, dim, mesh_paths[i])
            except MassPropertyError as exc:
                problems.append(scene.problem(at + exc.key, exc.message, exc.hint))
                continue
            props_all[i] = props
            masses[i] = props.mass
            rot_index.append(i)
            rot_kin.append(False)
            izz = props.inertia[2, 2]
            # 2D: omega and L lie along z, where only Izz acts; an isotropic tensor makes
            # the 3D machinery reproduce the slide's scalar L = I omega exactly.
            inertia.append(izz * np.eye(3) if dim == 2 else props.inertia)
            angvel0.append(_about_z(body.get("angular_velocity", 0.0 if dim == 2
                                             else [0.0] * 3), dim))
        elif kind == "kinematic" and "angular_velocity" in body:
            rot_index.append(i)
            rot_kin.append(True)
            inertia.append(np.eye(3))
            angvel0.append(_about_z(body["angular_velocity"], dim))
        damping = body.get("damping") or {}
        lin_damp[i] = float(damping.get("linear", 0.0))
        ang_damp[i] = float(damping.get("angular", 0.0))
        turning = bool(rot_index) and rot_index[-1] == i
        for force in body.get("forces") or []:
            vec = np.array(_vec3(force["force"], dim))
            in_body = force.get("frame", "world") == "body"
            if in_body and not turning:  # a fixed orientation: turn the force once, here
                vec = matmul(quat_to_matrix(np.asarray(quat0[i], dtype=float)), vec)
            force_vec.append(vec)
            force_point.append(_vec3(force.get("point", [0.0] * dim), dim))
            force_has_point.append("point" in force)
            force_in_body.append(in_body and turning)
        for torque in body.get("torques") or []:
            torque_body.append(i)
            torque_vec.append(_about_z(torque["torque"], dim))
            torque_start.append(float(torque.get("start", 0.0)))
            torque_end.append(float(torque.get("end", math.inf)))
            torque_in_body.append(torque.get("frame", "world") == "body")
    index = {b["name"]: i for i, b in enumerate(bodies)}
    springs = data.get("springs") or []
    r = len(rot_index)
    inertia_arr = np.reshape(np.array(inertia, dtype=float), (r, 3, 3))
    kin = np.array(rot_kin, dtype=bool)
    inv = np.zeros((r, 3, 3))
    if (~kin).any():
        inv[~kin] = inv3(inertia_arr[~kin])
    # right-handed principal frames, by our Jacobi (LAPACK's last bits depend on the CPU)
    moments, axes = np.zeros((r, 3)), np.zeros((r, 3, 3))
    for k in range(r):
        moments[k], axes[k] = principal_axes(inertia_arr[k])
    R0 = quat_to_matrix(np.reshape(np.array([quat0[i] for i in rot_index]), (r, 4)))
    w0 = np.reshape(np.array(angvel0, dtype=float), (r, 3))
    L0 = np.einsum("rij,rjk,rlk,rl->ri", R0, inertia_arr, R0, w0)
    L0[kin] = 0.0
    slot = np.full(n_body, -1, dtype=np.int64)
    slot[rot_index] = np.arange(r)
    sa, sb, spa, spb, sk, sc, srest = [], [], [], [], [], [], []
    R_full = quat_to_matrix(np.reshape(np.array(quat0, dtype=float), (n_body, 4)))
    for spring in springs:
        a = index[spring["body"]]
        pa = np.array(_vec3(spring.get("point", [0.0] * dim), dim))
        world_a = np.array(pos0[a]) + matmul(R_full[a], pa)
        if "to" in spring:
            b = index[spring["to"]]
            pb = np.array(_vec3(spring.get("to_point", [0.0] * dim), dim))
            world_b = np.array(pos0[b]) + matmul(R_full[b], pb)
        else:
            b = -1
            pb = world_b = np.array(_vec3(spring["anchor"], dim))
        # An end on a body that does not rotate (a static body, a kinematic one without
        # spin) keeps its orientation: store its lever arm in world axes, once.
        sa.append(a)
        sb.append(b)
        spa.append(pa if slot[a] >= 0 else matmul(R_full[a], pa))
        spb.append(pb if b < 0 or slot[b] >= 0 else matmul(R_full[b], pb))
        sk.append(float(spring["stiffness"]))
        sc.append(float(spring.get("damping", 0.0)))
        srest.append(float(spring.get("rest_length", norm(world_b - world_a))))
    kinematic_spring = any(b >= 0 and kinds[b] == BODY_KINEMATIC for b in sb)
    static_forces = not (sa or any(force_has_point) or any(force_in_body)
                         or any(torque_in_body) or lin_damp.any() or ang_damp.any())
    # Forces and torques inject energy while they act; once the last window has closed the
    # scene conserves energy again. A force without an end keeps the guard off.
    windows = [float(f.get("end", math.inf)) for b in bodies
               for f in (b.get("forces") or []) + (b.get("torques") or [])]
    guard_from = max(windows, default=0.0)
    guard = not (data.get("emitters") or kinematic_spring) and math.isfinite(guard_from)
    n_force, n_torque, n_spring = len(force_point), len(torque_body), len(sa)
    rigid = RigidModel(
        rot_index=_frozen(rot_index, np.int64),
        rot_slot=_frozen(slot, np.int64),
        rot_kinematic=_frozen(kin, bool),
        rot_inertia=_frozen(inertia_arr),
        rot_inv_inertia=_frozen(inv),
        rot_moments=_frozen(moments),
        rot_axes=_frozen(axes),
        rot_matrix0=_frozen(R0),
        rot_angmom0=_frozen(L0),
        rot_angvel0=_frozen(w0),
        body_lin_damping=_frozen(lin_damp),
        body_ang_damping=_frozen(ang_damp),
        force_vec=_frozen(np.reshape(force_vec, (n_force, 3))),
        force_point=_frozen(np.reshape(force_point, (n_force, 3))),
        force_has_point=_frozen(force_has_point, bool),
        force_in_body=_frozen(force_in_body, bool),
        torque_body=_frozen(torque_body, np.int64),
        torque_vec=_frozen(np.reshape(torque_vec, (n_torque, 3))),
        torque_start=_frozen(torque_start),
        torque_end=_frozen(torque_end),
        torque_in_body=_frozen(torque_in_body, bool),
        spring_a=_frozen(sa, np.int64),
        spring_b=_frozen(sb, np.int64),
        spring_point_a=_frozen(np.reshape(spa, (n_spring, 3))),
        spring_point_b=_frozen(np.reshape(spb, (n_spring, 3))),
        spring_k=_frozen(sk),
        spring_c=_frozen(sc),
        spring_rest=_frozen(srest),
        orthonormalize=bool((data.get("rotation") or {}).get("orthonormalize", True)),
        tolerance=float(data.get("tolerance", DEFAULT_TOLERANCE)),
        energy_guard=guard,
        energy_guard_from=guard_from if guard else 0.0,
        mass_properties=tuple(props_all),
        static_forces=static_forces,
        free_flow=str((data.get("rotation") or {}).get("free_flow", DEFAULT_FREE_FLOW)),
    )
    if not guard or problems:
        return rigid
    gravity = np.array(_vec3(data.get("gravity", [0.0, -9.81, 0.0][:dim]), dim))
    per_body, kinetic, spring = mechanical_energy(
        rigid, np.array(masses, dtype=float), gravity, np.reshape(pos0, (n_body, 3)),
        np.reshape(vel0, (n_body, 3)), R0, L0)
    omega = frequency_scale(rigid, np.array(masses, dtype=float), kinds, gravity)
    return dataclasses.replace(rigid, energy0_body=_frozen(per_body),
                               energy0_scale=kinetic + abs(spring), energy_omega=omega)


def frequency_scale(rigid: RigidModel, mass: np.ndarray, kinds: list,
                    gravity: np.ndarray, length_m: float = 1.0) -> float:
    """rad/s: the fastest rate at which a conserving scene's state turns, for the energy
    guard's bound (`kernels.dynamics.energy_bound`): the largest of
    - every dynamic rotating body's sqrt(2 T / I_min), T = L.omega / 2 its energy of
      rotation (|omega|^2 = sum L_i^2 / I_i^2 <= 2 T / I_min: a free body never turns
      faster);
    - every spring's sqrt(k w) and c w, w = sum over its moving ends of 1/m + |arm|^2 /
      I_min (the stiffness and damping rate of the spring with the ends' inertia);
    - every body's linear and angular damping rate (1/s);
    - sqrt(|g| / length_m) when a dynamic body feels gravity (the rate at which a fall
      of one length changes the speed; the guard's scale uses the same length).
    mass: (n_body,) kg; kinds: (n_body,) body types; gravity: (3,) m/s^2."""
    rates = [0.0]
    slot = rigid.rot_slot
    i_min = rigid.rot_moments[:, 0] if len(rigid.rot_moments) else np.zeros(0)
    for k in range(rigid.n_rot):
        if not rigid.rot_kinematic[k] and i_min[k] > 0.0:  # 2 T = L.omega
            twice_t = float(np.einsum("i,i->", rigid.rot_angmom0[k], rigid.rot_angvel0[k]))
            rates.append(math.sqrt(max(twice_t, 0.0) / i_min[k]))

    def weight(body: int, arm: np.ndarray) -> float:
        if body < 0 or kinds[body] != BODY_DYNAMIC or not mass[body] > 0.0:
            return 0.0
        k = slot[body]
        turn = norm(arm) ** 2 / i_min[k] if k >= 0 and i_min[k] > 0.0 else 0.0
        return 1.0 / mass[body] + turn

    for j in range(len(rigid.spring_a)):
        w = weight(int(rigid.spring_a[j]), rigid.spring_point_a[j]) + \
            weight(int(rigid.spring_b[j]), rigid.spring_point_b[j])
        rates.append(math.sqrt(rigid.spring_k[j] * w))
        rates.append(rigid.spring_c[j] * w)
    rates.extend(rigid.body_lin_damping.tolist() + rigid.body_ang_damping.tolist())
    if any(kind == BODY_DYNAMIC for kind in kinds):
        rates.append(math.sqrt(norm(gravity) / length_m))
    return float(max(rates))


def angular_velocity(rigid: RigidModel, R: np.ndarray, L: np.ndarray,
                     exact_inverse: bool = False) -> np.ndarray:
    """(r, 3) rad/s world omega = I(t)^-1 L with I(t) = R I_body R^T (slide 5.3.2).

    For orthonormal R, I(t)^-1 = R I_body^-1 R^T. `exact_inverse` solves with I(t) as
    written instead, which differs only when R has drifted from a rotation (the slide's
    Euler step without re-orthonormalisation). Kinematic bodies turn at their given rate.
    """
    if exact_inverse:
        inertia = matmul(matmul(R, rigid.rot_inertia), np.swapaxes(R, -1, -2))
        w = matmul(inv3(inertia), L[..., None])[..., 0]
    else:
        body = matmul(L[:, None, :], R)  # (R^T L)^T
        w = matmul(R, matmul(rigid.rot_inv_inertia, body[:, 0, :, None]))[..., 0]
    if rigid.rot_kinematic.any():
        w = np.where(rigid.rot_kinematic[:, None], rigid.rot_angvel0, w)
    return w


def spring_ends(rigid: RigidModel, x: np.ndarray, R: np.ndarray):
    """World positions of both ends of every spring and their lever arms from the centres
    of mass: (pa, arm_a, pb, arm_b), each (s, 3); arm_b is 0 at a world anchor."""
    def arm(body, point):  # turning bodies: R p; others store their world arm already
        slot = rigid.rot_slot[body]
        out = point.copy()
        turning = slot >= 0
        out[turning] = np.einsum("sij,sj->si", R[slot[turning]], point[turning])
        return out

    a, b = rigid.spring_a, rigid.spring_b
    arm_a = arm(a, rigid.spring_point_a)
    anchored = b < 0
    bb = np.where(anchored, 0, b)
    arm_b = np.where(anchored[:, None], 0.0, arm(bb, rigid.spring_point_b))
    pb = np.where(anchored[:, None], rigid.spring_point_b, x[bb] + arm_b)
    return x[a] + arm_a, arm_a, pb, arm_b


def mechanical_energy(rigid: RigidModel, mass: np.ndarray, gravity: np.ndarray,
                      x: np.ndarray, v: np.ndarray, R: np.ndarray, L: np.ndarray):
    """(per-body energy (n,) J, total kinetic J, total spring J). Kinetic energy
    m|v|^2/2 + L.omega/2, gravity -m g.x, a spring's k (l - l0)^2/2 split between its two
    bodies (all to the dynamic one when the other end is an anchor or a static or
    kinematic body). Kinematic and static bodies count 0."""
    dyn = np.isfinite(mass)
    m = np.where(dyn, mass, 0.0)
    kinetic = 0.5 * m * (v * v).sum(1)
    if rigid.n_rot:
        w = angular_velocity(rigid, R, L)
        rot_ke = 0.5 * (L * w).sum(1)
        kinetic[rigid.rot_index] += np.where(rigid.rot_kinematic, 0.0, rot_ke)
    per_body = kinetic - m * matmul(x, gravity)
    spring_total = 0.0
    if len(rigid.spring_a):
        pa, _, pb, _ = spring_ends(rigid, x, R)
        stretch = np.linalg.norm(pb - pa, axis=1) - rigid.spring_rest
        spe = 0.5 * rigid.spring_k * stretch ** 2
        b = rigid.spring_b
        shared = (b >= 0) & dyn[np.where(b >= 0, b, 0)]  # both ends can move
        np.add.at(per_body, rigid.spring_a, np.where(shared, 0.5, 1.0) * spe)
        np.add.at(per_body, b[shared], 0.5 * spe[shared])
        spring_total = float(spe.sum())
    return per_body, float(kinetic.sum()), spring_total
