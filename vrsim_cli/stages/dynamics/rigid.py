"""The checks of rigid-body scenes (part of loop stage 2.1): rotation finite, energy
bounded. The compiled multi-step path runs the same checks inside the kernel
(`kernels.dynamics.run_steps`); these give the messages, and check step-by-step runs.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.errors import SimulationError
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.stages.dynamics import motion
from vrsim_cli.stages.dynamics.motion import ENERGY_GROWTH_LIMIT, ORDER, guard_order

__all__ = ["ENERGY_GROWTH_LIMIT", "check", "energy", "energy_loss_warning"]

ELASTIC_PAIRS_MAX = 2_000_000  # body pairs checked for restitution 1 and friction 0


def energy(model: Model, state: State):
    """(per-body mechanical energy (n,) J, total kinetic J, total spring J)."""
    return motion.energy(model, state)


def check(model: Model, state: State) -> None:
    """Raise SimulationError naming the body when the rotation is not finite (every step)
    or, in a scene that conserves energy (no driving forces; damping allowed; impacts only
    take energy away), the energy grew past the bound of `motion.energy_check` (the
    integrator's order and dt, at most ENERGY_GROWTH_LIMIT; checked at every frame)."""
    rigid = model.rigid
    if rigid is None:
        return
    if rigid.n_rot:
        finite = np.isfinite(state.rot_angmom).all(1) & np.isfinite(state.rot_matrix).all((1, 2))
        if not finite.all():
            body = model.body_name[rigid.rot_index[int(np.argmin(finite))]]
            raise SimulationError("orientation or angular momentum is not finite (NaN or "
                                  "Inf): the integration blew up; try a smaller dt or "
                                  "another integrator", body=body, t=state.t)
    # Energy grows over many steps, not in one: check it once per frame (and at the end).
    if not rigid.energy_guard or rigid.energy0_body is None or \
            state.t < rigid.energy_guard_from or (
            state.step % model.steps_per_frame and state.step != model.n_steps):
        return
    baseline = rigid.energy0_body if state.rot_energy0 is None else state.rot_energy0
    body, gain, bound = motion.energy_check(model, state, baseline)
    if body >= 0:
        raise SimulationError(energy_message(model, gain, bound), body=model.body_name[body],
                              t=state.t)


def energy_message(model: Model, gain: float, bound: float) -> str:
    """What the energy guard says when it trips (docs/dynamics.md, "Energy guard")."""
    what = (f"grew by {gain:.4g} J in a scene that conserves it" if gain > 0.0 else
            f"fell by {-gain:.4g} J in a scene without damping or impacts, which conserves it")
    contacts = model.response is not None
    hint = ("; in a scene with contacts, a body pivoting on a resting edge or end also "
            "gains energy from position correction, a known limit (docs/collision-"
            "response.md, Known limits), first order in dt"
            if gain > 0.0 and contacts else "")
    order = (f"order {guard_order(model)} with contacts" if contacts else
             f"order {ORDER[model.integrator]}")
    return (f"the energy {what} (bound {bound:.4g} J for {model.integrator}, {order}, "
            f"at dt = {model.dt:.4g} s): the integration blew up or is too coarse; try a "
            f"smaller dt or another integrator{hint}")


def elastic(model: Model) -> bool:
    """True when every pair of bodies that can touch responds with impulses of restitution
    1 and friction 0 (`ResponseModel.pair_values`), and nothing else dissipates (no
    damping of bodies or springs): a scene that, like one without impacts, conserves its
    energy, so a loss past the bound is the integration's."""
    rigid, response = model.rigid, model.response
    if rigid is None or response is None or rigid.body_lin_damping.any() or \
            rigid.body_ang_damping.any() or rigid.spring_c.any():
        return False
    n = model.n_body
    if n * (n - 1) // 2 > ELASTIC_PAIRS_MAX:
        return False  # too many pairs to look at; no warning rather than a slow one
    a, b = np.triu_indices(n, 1)
    mode, eps, mu = response.pair_values(a, b)
    from vrsim_cli.model.response import MODES
    return bool(np.all(mode == MODES.index("impulse")) and np.all(eps == 1.0)
                and np.all(mu == 0.0))


def energy_loss_warning(model: Model, state: State) -> str | None:
    """What to say when a scene with elastic, frictionless impacts and no damping lost
    more energy than the guard's bound (docs/dynamics.md, "Energy guard"), or None.
    A warning, not a stop: the guard stops such scenes only on growth, which impacts
    cannot explain; a loss is wrong numbers all the same (an elastic ball bouncing 60 s
    with symplectic-euler kept 70.6 % of its energy, its apex 0.755 m instead of 1 m)."""
    rigid = model.rigid
    if rigid is None or not rigid.energy_guard or rigid.energy0_body is None or \
            state.t < rigid.energy_guard_from or not elastic(model):
        return None
    baseline = rigid.energy0_body if state.rot_energy0 is None else state.rot_energy0
    _, gain, bound = motion.energy_check(model, state, baseline)
    if -gain <= bound:
        return None
    return (f"the energy fell by {-gain:.4g} J in a scene that conserves it "
            f"(restitution 1, friction 0, no damping): more than the bound {bound:.4g} J "
            f"for {model.integrator}, order {guard_order(model)} with contacts, at dt = "
            f"{model.dt:.4g} s; its numbers are off: try a smaller dt or another integrator")
