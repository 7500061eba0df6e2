"""Loop stages 2.1 (kinematic motion: keyframes, drives) and 3 (scene graph).

Layer 4. `step(model, state) -> state` sets the world pose and velocity of every node
(a body with keyframes, drive or parent) at `state.t`:

1. local motion: keyframe tracks (position, orientation) and drives give each node its
   pose and velocity relative to its parent's frame (slide 5.2; slide 5.0 step 2.1);
2. composition down the tree, level by level (parents first), for parent p and child c
   with local position r_l, orientation q_l, velocity v_l and angular velocity w_l (both
   in the parent's frame):
       p_c = p_p + R_p r_l           q_c = q_p q_l
       v_c = v_p + w_p x (R_p r_l) + R_p v_l
       w_c = w_p + R_p w_l
   (the rigid-body velocity of the point r_l on the moving parent, plus the child's own
   motion). Nodes are kinematic bodies: infinite mass, velocity from the motion's derivative.

When: the loop calls `step` after every physics step and once at t = 0, so physics always
sees the nodes where they are at the step's time and every output sample is exact (a
keyframed body is evaluated at the sample's time, not predicted). The tracks are read at
one fixed point, the start of each frame, for all the frame's step times at once
(`local_motion` is vectorised over time); composition then runs per step, because a
parent may be a dynamic body that only the physics step moves. The stage costs nothing
when the scene animates nothing (`model.animation is None`; the loop does not call it).
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.products import matmul

from vrsim_cli.maths.spatial import quat_multiply, quat_rotation_matrices
from vrsim_cli.maths.trig import sin_cos, sin_over_x
from vrsim_cli.model.keyframes import evaluate
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State


def local_motion(model: Model, times) -> tuple:
    """Motion of every node relative to its parent's frame at each of `times` (n_t,) s:
    (pos (n_t, n_node, 3) m, quat (n_t, n_node, 4), vel (n_t, n_node, 3) m/s,
    angvel (n_t, n_node, 3) rad/s in the parent's frame)."""
    anim = model.animation
    times = np.asarray(times, dtype=float)
    n_t = len(times)
    pos = np.repeat(anim.node_pos0[None], n_t, axis=0)
    quat = np.repeat(anim.node_quat0[None], n_t, axis=0)
    vel = np.zeros_like(pos)
    angvel = np.zeros_like(pos)
    dim = anim.dimension
    for node, track in anim.pos_tracks:
        value, rate = evaluate(track, times)
        pos[:, node, :dim], vel[:, node, :dim] = value, rate
    for node, track, is_angle in anim.rot_tracks:
        value, rate = evaluate(track, times)
        if is_angle:  # 2D: degrees about z
            half = 0.5 * np.radians(value)
            quat[:, node] = 0.0
            quat[:, node, 3], quat[:, node, 0] = sin_cos(half)  # not libm: same bits anywhere
            angvel[:, node, 2] = np.radians(rate)
        else:
            quat[:, node], angvel[:, node] = value, rate
    if len(anim.drive_node):
        _drive(anim, times[:, None], pos, quat, vel, angvel)
    return pos, quat, vel, angvel


def _drive(anim, t, pos, quat, vel, angvel) -> None:
    """Speed v along the heading psi(t) = psi0 + r t, turning at yaw rate r, in closed form.

    With forward f(psi) (3D: (sin psi, 0, cos psi) on the z-x ground plane; 2D:
    (cos psi, sin psi, 0)) the path is p0 + v * integral_0^t f(psi0 + r tau) d tau, and
        integral_0^t (sin, cos)(psi0 + r tau) = t (sin psi0 S + cos psi0 K,
                                                   cos psi0 S - sin psi0 K)
    with S = sin(rt) / (rt) and K = (1 - cos rt) / (rt) = sin(a) sinc(a), a = rt / 2:
    exact for r = 0 too (a straight line), no integration error at any time.
    t: (n_t, 1) s; the arrays are (n_t, n_node, k) and are filled for the driven nodes.
    """
    k = anim.drive_node
    v, psi0, r = anim.drive_speed, anim.drive_heading0, anim.drive_yaw_rate
    psi = psi0 + r * t  # (n_t, n_drive)
    a = 0.5 * r * t
    # maths.trig, not libm (numpy's sin and cos): libm's differ in the last bit by CPU
    big_s = sin_over_x(2.0 * a)
    big_k = sin_cos(a)[0] * sin_over_x(a)
    sin_psi0, cos_psi0 = sin_cos(psi0)
    int_sin = v * t * (sin_psi0 * big_s + cos_psi0 * big_k)  # v * integral of sin
    int_cos = v * t * (cos_psi0 * big_s - sin_psi0 * big_k)  # v * integral of cos
    sin_psi, cos_psi = sin_cos(psi)
    sin_half, cos_half = sin_cos(0.5 * psi)
    zeros = np.zeros_like(psi)
    rate = np.broadcast_to(r, psi.shape)
    if anim.dimension == 3:
        offset = np.stack([int_sin, zeros, int_cos], axis=-1)
        velocity = np.stack([v * sin_psi, zeros, v * cos_psi], axis=-1)
        turn = np.stack([cos_half, zeros, sin_half, zeros], axis=-1)
        spin = np.stack([zeros, rate, zeros], axis=-1)
    else:
        offset = np.stack([int_cos, int_sin, zeros], axis=-1)
        velocity = np.stack([v * cos_psi, v * sin_psi, zeros], axis=-1)
        turn = np.stack([cos_half, zeros, zeros, sin_half], axis=-1)
        spin = np.stack([zeros, zeros, rate], axis=-1)
    pos[:, k] = anim.node_pos0[k] + offset
    vel[:, k] = velocity
    quat[:, k] = quat_multiply(turn, anim.node_quat0[k])
    angvel[:, k] = spin


def compose(anim, state: State, local) -> tuple:
    """World (pos, quat, vel, angvel) arrays of all bodies: the state's, with every node
    replaced by its local motion composed with its parent's world motion."""
    lpos, lquat, lvel, lang = local
    pos, quat = state.body_pos.copy(), state.body_quat.copy()
    vel, angvel = state.body_vel.copy(), state.body_angvel.copy()
    for depth, nodes in enumerate(anim.levels):
        body = anim.node_body[nodes]
        if depth == 0:  # no parent: local is world
            pos[body], quat[body] = lpos[nodes], lquat[nodes]
            vel[body], angvel[body] = lvel[nodes], lang[nodes]
            continue
        par = anim.node_parent[nodes]
        left, rot = quat_rotation_matrices(quat[par])
        # one matmul turns the three local vectors into the parent's orientation
        arm, v_own, w_own = np.moveaxis(matmul(rot, np.stack([lpos[nodes], lvel[nodes],
                                                              lang[nodes]], axis=-1)), -1, 0)
        w_par = angvel[par]
        swirl = w_par[:, _YZX] * arm[:, _ZXY] - w_par[:, _ZXY] * arm[:, _YZX]  # w x arm
        pos[body] = pos[par] + arm
        quat[body] = matmul(left, lquat[nodes][:, :, None])[:, :, 0]
        vel[body] = vel[par] + swirl + v_own
        angvel[body] = w_par + w_own
    return pos, quat, vel, angvel


_YZX, _ZXY = [1, 2, 0], [2, 0, 1]  # cross product a x b = a_yzx b_zxy - a_zxy b_yzx


def step(model: Model, state: State, local=None) -> State:
    """The state with every node at its keyframed/driven pose at `state.t`. Pure.

    local: the nodes' local motion at state.t, one time slice of `local_motion` (the loop
    evaluates the tracks once per frame for all of the frame's step times); computed here
    when not given.
    """
    if model.animation is None or not model.animation.has_motion:
        return state
    if local is None:
        local = tuple(a[0] for a in local_motion(model, [state.t]))
    pos, quat, vel, angvel = compose(model.animation, state, local)
    return state.replace(body_pos=pos, body_quat=quat, body_vel=vel, body_angvel=angvel)
