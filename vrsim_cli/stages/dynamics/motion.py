"""Loop stage 2.1, dynamic motion: forces on point masses, integrated over one step.

In this stage bodies move as point masses at their centre of mass (slide 5.3: the linear
part `P(t1) = P(t0) + dt v`, `v(t1) = v(t0) + dt a`). Forces: gravity on dynamic bodies
and the scene's constant, optionally time-windowed forces at the centre of mass.
Kinematic bodies keep their velocity; static bodies never move. Emitted particles wait at
their nozzle until their emission step, then leave with their launch velocity.
Scenes with rotating bodies, springs, torques or forces at points go through `rigid.step`
(the same stage, slide 5.3 in full); point-mass scenes keep this lean path.
"""

from __future__ import annotations

import numpy as np

import dataclasses

from vrsim_cli.model.model import BODY_DYNAMIC, Model
from vrsim_cli.model.state import State
from vrsim_cli.stages.dynamics.integrators import INTEGRATORS


def moving_mask(model: Model, step: int) -> np.ndarray:
    """(n_body, 1) 1.0 for dynamic bodies that are free to move during `step`, else 0.0."""
    moving = model.body_type == BODY_DYNAMIC
    if model.has_emitters:
        moving = moving & (model.body_emit_step <= step)
    return moving.astype(float)[:, None]


def active_forces(model: Model, t: float) -> np.ndarray:
    """(n_force,) bool: the forces acting during the step that starts at time t.

    A force window is sampled once per step, at its start, for every integrator: within a
    step the force is constant, so a window [start, end) acts on exactly the steps whose
    start time lies in it, also for the intermediate stages of rk4."""
    return (model.force_start <= t) & (t < model.force_end)


def accelerations(model: Model, active: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(n_body, 3) m/s^2 from gravity and the active forces."""
    acc = mask * model.gravity
    if active.any():
        body = model.force_body[active]
        np.add.at(acc, body, model.force_vec[active] * model.body_inv_mass[body, None]
                  * mask[body])
    return acc


def emit(model: Model, state: State) -> State:
    """Give particles whose emission step is now their launch velocity."""
    starting = model.body_emit_step == state.step
    if state.step == 0 or not starting.any():
        return state
    vel = np.where(starting[:, None], model.body_vel0, state.body_vel)
    return state.replace(body_vel=vel)


def step(model: Model, state: State) -> State:
    """Advance every body by one physics step dt. Pure: returns a new State."""
    mask = moving_mask(model, state.step)
    if model.rigid is not None:  # rotation, springs, torques: slide 5.3 in rigid.py
        from vrsim_cli.stages.dynamics import rigid

        new = rigid.step(model, state, mask)
        return emit(model, new) if model.has_emitters else new
    integrate = INTEGRATORS[model.integrator]
    acc = accelerations(model, active_forces(model, state.t), mask)

    def accel(t, x, v):  # forces depend neither on x nor v yet, nor on t within a step
        return acc

    pos, vel = integrate(accel, state.t, model.dt, state.body_pos, state.body_vel)
    n = state.step + 1
    new = state.replace(step=n, t=n * model.dt, body_pos=pos, body_vel=vel)
    return emit(model, new) if model.has_emitters else new


def advance(model: Model, state: State, h: float) -> State:
    """The state after time h (0 < h <= dt) of the same dynamics, with the step counter
    unchanged and t = state.t + h: collision response integrates up to a time of impact
    and on from it with this. Time windows of forces are sampled at state.t, as in step."""
    new = step(dataclasses.replace(model, dt=h), state)
    return new.replace(step=state.step, t=state.t + h)
