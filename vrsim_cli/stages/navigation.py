"""Loop stage 2.2, sensor-driven motion: the observer walks, flies, examines or is tracked.

Slide 5.1, once per frame of length dt (the frame interval), velocity constant over it:
  walk:    d_hat = d/|d|, v = alpha v_max d_hat, V_new = V + v dt,
           d_new = R_y(beta gamma_max dt) d       (v uses d *before* this frame's rotation)
  fly:     as walk without gravity; v follows the full view direction, whose pitch a third
           input channel (`pitch`, rate pitch_max) changes
  examine: L fixed, gamma = alpha gamma_max about x, delta = beta delta_max about y;
           world axes (the slide's): d_hat_new = R_y(delta dt) R_x(gamma dt) d_hat;
           view axes: the same rotations about the camera's own x and y axes;
           V_new = L - r d_hat_new with r = |V - L|, the current distance
  tracked: V and the orientation come from the head tracker.
  attached: the observer rides on a body (a keyframed camera rig, a car), looking along
           the body's local -z; exact at every sample, since it is read off the state.
With scene geometry (static and kinematic bodies with analytic shapes), walking follows the
terrain at eye_height, climbs steps up to step_height, falls under gravity where the ground
drops by more than a step, and walls stop or slide the observer (X3D avatarSize semantics):
  walls: the observer's body is a vertical capsule from step_height + radius above the feet
         up to the eye, of the collision radius; a penetrating move is pushed back along
         the wall normal (slide: v - (v.n) n) or undone (stop).
"""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.maths.products import dot, norm

from vrsim_cli.maths import geometry, trig
from vrsim_cli.maths.spatial import (look_rotation, quat_conjugate, quat_from_axis_angle,
                               quat_multiply, quat_normalize, quat_rotate, quat_slerp,
                               quat_to_matrix, rotate_about_y)
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import Inputs, State

WALL_ITERATIONS = 4  # push-outs per frame; corners need two, more means "stuck": stop
MIN_PITCH = math.radians(1.0)  # fly: keep the view at least 1 degree away from straight up/down
Y_UP = np.array([0.0, 1.0, 0.0])


def step(model: Model, state: State, inputs: Inputs, dt: float) -> State:
    """Advance the observer by one frame of `dt` seconds. Pure: returns a new State."""
    ob = model.observer
    mode = ob.mode
    if mode == "attached":
        return attach(model, state)
    vel = None  # None: the frame's displacement over dt
    if mode == "tracked":
        pos, quat = inputs.pose[:3].copy(), inputs.pose[3:].copy()
        direction = quat_rotate(quat, [0.0, 0.0, -1.0])
        fall = 0.0
    elif mode == "examine":
        pos, direction, quat = _examine(model, state, inputs, dt)
        fall = 0.0
    else:
        pos, direction, fall, vel = _walk_or_fly(model, state, inputs, dt)
        quat = look_rotation(direction, ob.up, state.observer_quat)
    return state.replace(observer_pos=pos, observer_dir=direction, observer_quat=quat,
                         observer_vel=vel if vel is not None else (pos - state.observer_pos) / dt,
                         observer_angvel=angular_velocity(state.observer_quat, quat, dt),
                         observer_fall=fall)


def _rotate_about_up(ob, vec, angle):
    if np.array_equal(ob.up, Y_UP):
        return rotate_about_y(vec, angle)  # the slide's R_y, term for term
    return quat_rotate(quat_from_axis_angle(ob.up, angle), vec)


def _walk_or_fly(model: Model, state: State, inputs: Inputs, dt: float):
    ob = model.observer
    d = state.observer_dir
    up = ob.up
    if ob.mode == "walk":
        heading = d - dot(d, up) * up  # walking moves in the ground plane
    else:
        heading = d
    length = norm(heading)
    v = inputs.alpha * ob.v_max * heading / length if length > 0 else np.zeros(3)
    d_new = _rotate_about_up(ob, d, inputs.beta * ob.gamma_max * dt)
    if ob.mode == "fly" and inputs.pitch:
        d_new = _pitch(d_new, up, inputs.pitch * ob.pitch_max * dt)
    pos = state.observer_pos
    proposed = pos + v * dt
    if not model.observer_obstacles:  # the slide's walk: v is the velocity, exactly
        return proposed, d_new, 0.0, v
    obstacles = Obstacles(model, state)
    if ob.mode == "fly":
        moved = _resolve_walls(model, obstacles, pos, proposed, horizontal=False)
        return moved, d_new, 0.0, (v if moved is proposed else None)
    moved = _resolve_walls(model, obstacles, pos, proposed, horizontal=True)
    pos_new, fall = _follow_terrain(model, state, obstacles, pos, moved, dt)
    return pos_new, d_new, fall, None


def _pitch(d, up, angle):
    """Rotate d about the view's right axis by `angle`, stopping short of the poles."""
    length = norm(d)
    current = trig.acos(max(-1.0, min(1.0, float(dot(d, up)) / length)))  # from up
    target = min(max(current - angle, MIN_PITCH), math.pi - MIN_PITCH)
    right = np.cross(d, up)
    if norm(right) == 0.0:
        return d
    return quat_rotate(quat_from_axis_angle(right, current - target), d)


class Obstacles:
    """The bodies the observer collides with, with their world bounding boxes, so each
    query only looks at the few whose boxes it touches (one numpy test for all)."""

    def __init__(self, model: Model, state: State):
        index = np.asarray(model.observer_obstacles, dtype=np.int64)
        self.shapes = [model.body_shape[i] for i in index]
        self.pos = state.body_pos[index]
        self.quat = state.body_quat[index]
        half = np.array([geometry.local_half_extents(s) if s["type"] != "plane"
                         else np.full(3, np.inf) for s in self.shapes]).reshape(-1, 3)
        # world box of a rotated box: |R| @ half (planes: everywhere)
        finite = np.isfinite(half).all(axis=1)
        world = np.full_like(half, np.inf)
        if finite.any():
            world[finite] = np.einsum("nij,nj->ni", np.abs(quat_to_matrix(self.quat[finite])),
                                      half[finite])
        self.lo, self.hi = self.pos - world, self.pos + world

    def near(self, lo, hi):
        """(shape, pos, quat) of the obstacles whose boxes overlap the box [lo, hi]."""
        hit = np.all((self.lo <= hi) & (self.hi >= lo), axis=1)
        return [(self.shapes[i], self.pos[i], self.quat[i]) for i in np.flatnonzero(hit)]


def _body_axis(model: Model, eye):
    """The observer's collision capsule axis (a, b) for an eye position."""
    ob = model.observer
    if ob.mode != "walk":
        return eye, eye
    low = eye - (ob.eye_height - ob.step_height - ob.radius) * ob.up
    if dot(low - eye, ob.up) > 0.0:  # short avatar: the capsule shrinks to a sphere
        low = eye
    return low, eye


def _penetration(model: Model, obstacles, eye):
    """Deepest penetration of the observer's body: (depth m > 0, normal) or (0, None)."""
    a, b = _body_axis(model, eye)
    deepest, normal = 0.0, None
    radius = model.observer.radius
    for shape, pos, quat in obstacles.near(np.minimum(a, b) - radius, np.maximum(a, b) + radius):
        if not geometry.capsule_overlaps_bounds(shape, pos, quat, a, b, radius):
            continue
        d, n, _ = geometry.capsule_distance(shape, pos, quat, a, b, radius)
        if -d > deepest:
            deepest, normal = -d, n
    return deepest, normal


def _resolve_walls(model: Model, obstacles, start, proposed, horizontal: bool):
    """Slide 5.4.2 on the observer: push a penetrating move back along the contact normal
    (removing the normal component of the motion: slide), or keep the start (stop)."""
    ob = model.observer
    pos = proposed
    for _ in range(WALL_ITERATIONS):
        depth, normal = _penetration(model, obstacles, pos)
        if depth <= 0.0:
            return pos
        if ob.walls == "stop":
            return start
        if horizontal:
            normal = normal - dot(normal, ob.up) * ob.up
            length = norm(normal)
            if length < 1e-9:  # the obstacle is straight above or below: nowhere to slide
                return start
            normal = normal / length
            pos = pos + (depth / length) * normal
        else:
            pos = pos + depth * normal
    return start if _penetration(model, obstacles, pos)[0] > 0.0 else pos


def ground_height(model: Model, obstacles, eye) -> float | None:
    """Height (along up) of the highest ground under the observer that is at most
    step_height above its feet; None when there is none; +inf when the feet plus a step
    are inside a solid (a step too high to climb)."""
    ob = model.observer
    origin = eye - (ob.eye_height - ob.step_height) * ob.up
    best = None
    # The downward ray's box: below the origin, along -up (the whole space if up is skew).
    lo = np.where(ob.up > 0, -np.inf, origin) if np.count_nonzero(ob.up) == 1 else \
        np.full(3, -np.inf)
    hi = np.where(ob.up < 0, np.inf, origin) if np.count_nonzero(ob.up) == 1 else \
        np.full(3, np.inf)
    for shape, pos, quat in obstacles.near(lo, hi):
        t = geometry.ray_cast(shape, pos, quat, origin, -ob.up)
        if t is not None and (best is None or t < best):
            best = t
    if best is None:
        return None
    if best == 0.0:
        return math.inf
    return float(dot(origin, ob.up)) - best


def _follow_terrain(model: Model, state: State, obstacles, start, moved, dt):
    """Vertical part of walking: climb, follow the ground, or fall under gravity."""
    ob = model.observer
    up = ob.up
    ground = ground_height(model, obstacles, moved)
    if ground == math.inf:  # a step higher than step_height: blocked like a wall
        moved, ground = start, ground_height(model, obstacles, start)
    foot = float(dot(moved, up)) - ob.eye_height
    gravity = float(dot(model.gravity, up))  # m/s^2 along up, negative when it pulls down
    fall = state.observer_fall
    if ground is not None and ground != math.inf and foot - ground <= ob.step_height \
            and fall == 0.0:
        new_foot, fall = ground, 0.0  # on the ground: follow it, up or down a step
    else:  # in the air: semi-implicit Euler under gravity, landing on the ground
        fall = fall + gravity * dt
        new_foot = foot + fall * dt
        if ground is not None and ground != math.inf and new_foot <= ground:
            new_foot, fall = ground, 0.0
    return moved + (new_foot - foot) * up, fall


def _examine(model: Model, state: State, inputs: Inputs, dt: float):
    ob = model.observer
    gamma = inputs.alpha * ob.gamma_max * dt  # about x
    delta = inputs.beta * ob.delta_max * dt  # about y
    offset = state.observer_pos - ob.look_at
    r = float(norm(offset))
    length = float(norm(state.observer_dir))
    qx = quat_from_axis_angle([1.0, 0.0, 0.0], gamma)
    qy = quat_from_axis_angle([0.0, 1.0, 0.0], delta)
    if ob.examine_axes == "world":
        d_hat = state.observer_dir / length
        d_hat = quat_rotate(qy, quat_rotate(qx, d_hat))
        d_hat = d_hat / norm(d_hat)
        quat = look_rotation(d_hat, ob.up, state.observer_quat)
    else:  # about the camera's own axes: right-multiply (local frame), then renormalise
        quat = quat_normalize(quat_multiply(state.observer_quat, quat_multiply(qy, qx)))
        d_hat = quat_rotate(quat, [0.0, 0.0, -1.0])
    return ob.look_at - r * d_hat, length * d_hat, quat


def angular_velocity(q0, q1, dt: float) -> np.ndarray:
    """World-frame angular velocity (rad/s) of the constant rotation taking q0 to q1 in dt."""
    rel = quat_multiply(q1, quat_conjugate(q0))
    if rel[0] < 0.0:
        rel = -rel
    s = float(norm(rel[1:]))
    if s == 0.0:
        return np.zeros(3)
    angle = 2.0 * trig.atan2(s, rel[0])
    return rel[1:] / s * angle / dt


def attach(model: Model, state: State) -> State:
    """The observer riding on its body: the body's pose and velocities, looking along the
    body's local -z. A function of the current state, so exact at every sample."""
    i = model.observer.body
    quat = state.body_quat[i].copy()
    length = float(norm(state.observer_dir))
    return state.replace(observer_pos=state.body_pos[i].copy(),
                         observer_dir=length * quat_rotate(quat, [0.0, 0.0, -1.0]),
                         observer_quat=quat, observer_vel=state.body_vel[i].copy(),
                         observer_angvel=state.body_angvel[i].copy(), observer_fall=0.0)


def within_frame(model: Model, state: State, start: State, end: State, frac: float) -> State:
    """The observer at fraction `frac` of a frame: position moves linearly (the slide's
    velocity is constant over the frame) and the orientation turns at a constant rate."""
    if model.observer.mode == "attached":
        return attach(model, state)
    if frac >= 1.0:
        return state.replace(observer_pos=end.observer_pos, observer_dir=end.observer_dir,
                             observer_quat=end.observer_quat, observer_vel=end.observer_vel,
                             observer_angvel=end.observer_angvel, observer_fall=end.observer_fall)
    quat = quat_slerp(start.observer_quat, end.observer_quat, frac)
    turn = quat_multiply(quat, quat_conjugate(start.observer_quat))
    return state.replace(
        observer_pos=start.observer_pos + frac * (end.observer_pos - start.observer_pos),
        observer_dir=quat_rotate(turn, start.observer_dir), observer_quat=quat,
        observer_vel=end.observer_vel, observer_angvel=end.observer_angvel)
