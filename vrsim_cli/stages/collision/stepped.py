"""Loop stage 2.1 + 2.3 with `collision.impacts: stepped`: a whole step of many colliding
bodies (speculative contacts, impacts, rest, integration, position pass) in one compiled
call, `kernels.stepped` (docs/collision-response.md, "The default: one compiled step").

This module is the thin Python side: it packs the geometry and the materials once per
model (`tables`), turns a state into kernel rows and back, and asks Python only for the
pairs the compiled detection has no closed form for (convex hulls, meshes, mesh proxies
re-fitted every step, cylinders against boxes, capsules or cylinders): those are found
with `detect`'s numpy broad and narrow phase at the step's start and handed to the kernel.

- `step(model, before, after, dynamics) -> State`: one step from `before`; `after` is only
  read for the time and, in animated scenes, for where the scene graph put the kinematic
  bodies. `dynamics` is the dynamics stage (`stages.dynamics.motion`), passed in by the
  loop so that stages do not import each other: its packed model of the forces and
  integrators is the kernel's, and its rules for the energy guard and errors apply.
- `prepare(model, dynamics)`: pack the tables and load (or compile) the kernel.
"""

from __future__ import annotations

import numpy as np

from vrsim_cli.maths.products import norm
from vrsim_cli.model.collision import BOX, CAPSULE, CONVEX, CYLINDER, MESH, SPHERE
from vrsim_cli.model.model import BODY_DYNAMIC, BODY_STATIC, Model
from vrsim_cli.model.response import DEFAULT_FRICTION, DEFAULT_RESTITUTION
from vrsim_cli.model.state import State
from vrsim_cli.stages.collision.contacts import Contacts


def _kernels():
    from vrsim_cli.kernels import collide, dynamics, stepped  # numba: stepped scenes only

    return collide, dynamics, stepped


def tables(model: Model, dynamics) -> dict:
    """The kernel's tables of `model`, built once: gf (geometry), rb, rp (materials),
    the pair kinds it can meet, the geoms Python detects, the kernel."""
    found = model.cache.get("stepped")
    if found is not None:
        return found
    kc, kd, ks = _kernels()

    cm, rm = model.collision, model.response
    n = model.n_body
    gf = np.zeros((cm.n_geom, kc.G_SIZE))
    gf[:, kc.G_BODY] = cm.geom_body
    gf[:, kc.G_TYPE] = cm.geom_type
    gf[:, kc.G_LPOS:kc.G_LPOS + 3] = cm.geom_local_pos
    gf[:, kc.G_LQUAT:kc.G_LQUAT + 4] = cm.geom_local_quat
    gf[:, kc.G_TURNED] = np.any(cm.geom_local_quat[:, 1:] != 0.0, axis=1)
    gf[:, kc.G_RADIUS] = cm.geom_radius
    gf[:, kc.G_HALF:kc.G_HALF + 3] = cm.geom_half
    gf[:, kc.G_PN:kc.G_PN + 3] = cm.geom_plane_normal
    gf[:, kc.G_PO] = cm.geom_plane_offset
    rbound = np.where(np.isfinite(cm.geom_rbound), cm.geom_rbound, 0.0)
    gf[:, kc.G_RBOUND] = rbound
    gf[:, kc.G_EMIT] = model.body_emit_step[cm.geom_body]
    gf[:, kc.G_MOVES] = np.asarray(model.body_type)[cm.geom_body] != BODY_STATIC
    kind = cm.geom_type
    python = (kind == CONVEX) | (kind == MESH) | cm.geom_world_aabb
    # a cylinder meets a box, a capsule or a cylinder: Python's narrow phase (fcl, and
    # `cylinder_pairs`' manifolds; all its pairs then go to Python, so a body is never
    # split between the two detections)
    others = set(kind[~python].tolist())
    if (CYLINDER in others) and (others & {BOX, CAPSULE}) or (kind == CYLINDER).sum() > 1:
        python |= kind == CYLINDER
    gf[:, kc.G_PYTHON] = python
    # Every pair kind, whatever the scene has: one compiled entry (for every integrator
    # too, kernels/stepped.py), shared by every stepped scene. Pruned to the scene's
    # kinds, each new mix of shapes was another first compile of the whole step (~60 s
    # of CPU), which a user met scene after scene (and the suite ~20 times on an empty
    # cache); the pair functions a
    # scene cannot reach cost ~10 s of CPU once. Results are the same bits: a kind
    # only gates narrow-phase calls that the scene's geometry types never reach.
    kinds = (True,) * len(ks.PAIR_KINDS)
    rb = np.zeros((n, ks.RB_SIZE))
    rb[:, ks.RB_MODE] = rm.body_mode
    rb[:, ks.RB_EPS] = rm.body_restitution
    rb[:, ks.RB_MU] = rm.body_friction
    # how far turning moves a body's surface per rad, from its centre of mass: a sphere's
    # surface does not move when it turns about its centre (only its offset counts), a
    # capsule's is its segment's end; the rest their farthest point. (Rolling spheres
    # otherwise doubled their sweep, and a pile's candidate pairs with it.)
    offset = np.linalg.norm(cm.geom_local_pos, axis=1)
    turning = np.where(kind == SPHERE, offset,
                       np.where(kind == CAPSULE, offset + cm.geom_half[:, 1], rbound))
    for g in range(cm.n_geom):
        b = cm.geom_body[g]
        rb[b, ks.RB_RBOUND] = max(rb[b, ks.RB_RBOUND], turning[g])
    rp = np.zeros((len(rm.pair_key), ks.RP_SIZE))
    rp[:, ks.RP_KEY] = rm.pair_key
    rp[:, ks.RP_MODE] = rm.pair_mode
    rp[:, ks.RP_EPS] = rm.pair_restitution
    rp[:, ks.RP_MU] = rm.pair_friction
    prm = np.zeros(ks.PR_SIZE)
    prm[ks.PR_DT] = model.dt
    prm[ks.PR_TOL] = cm.tolerance
    prm[ks.PR_BOUNCE] = rm.rest_speed
    prm[ks.PR_ITER] = rm.iterations
    prm[ks.PR_POS_ITER] = rm.position_iterations
    prm[ks.PR_SLOP] = rm.slop
    prm[ks.PR_PLANAR] = model.dimension == 2
    prm[ks.PR_DEF_EPS] = DEFAULT_RESTITUTION
    prm[ks.PR_DEF_MU] = DEFAULT_FRICTION
    integ = kd.INTEGRATOR_CODES[model.integrator]
    r = 0 if model.rigid is None else model.rigid.n_rot
    animated = model.animation is not None and model.animation.has_motion
    found = dict(gf=gf, rb=rb, rp=rp, prm=prm, python=np.flatnonzero(python),
                 kernel=ks.entry(kinds), kinds=kinds, mf=dynamics.packed(model),
                 work=kd.make_work(n, r, integ), S=np.zeros((n, kd.S_SIZE)),
                 RS=np.zeros((r, kd.RS_SIZE)), S1=np.zeros((n, kd.S_SIZE)),
                 RS1=np.zeros((r, kd.RS_SIZE)), animated=animated,
                 no_contacts=(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0),
                              np.zeros((0, 3)), np.zeros((0, 3))),
                 no_rows=np.zeros((0, kc.C_SIZE)), no_kin=np.zeros((0, kd.S_SIZE)),
                 no_kin_rs=np.zeros((0, kd.RS_SIZE)))
    model.cache["stepped"] = found
    return found


def _rows(model: Model, state: State, into_S, into_RS) -> None:
    into_S[:, 0:3] = state.body_pos
    into_S[:, 3:6] = state.body_vel
    into_S[:, 6:10] = state.body_quat
    into_S[:, 10:13] = state.body_angvel
    if into_RS.shape[0]:
        into_RS[:, 0:9] = np.reshape(state.rot_matrix, (-1, 9))
        into_RS[:, 9:12] = state.rot_angmom


def _python_contacts(model: Model, state: State, tb: dict) -> np.ndarray:
    """Contact rows (x, C_SIZE) of the pairs with a geom the kernel does not test, at
    `state`, numpy's detection with a margin of what the bodies can travel in a step
    (their speed plus gravity's, and their turning; other forces are not counted)."""
    from vrsim_cli.stages.collision.broadphase import broad_phase
    from vrsim_cli.stages.collision.contacts import to_contacts
    from vrsim_cli.stages.collision.narrowphase import narrow_phase
    from vrsim_cli.stages.collision.shapes import aabbs, place

    kc = _kernels()[0]
    cm = model.collision
    dt = model.dt
    g = norm(model.gravity)
    moving = np.asarray(model.body_type) == BODY_DYNAMIC
    reach = dt * (np.linalg.norm(state.body_vel, axis=1) + g * dt * moving) + \
        dt * np.linalg.norm(state.body_angvel, axis=1) * tb["rb"][:, 3]
    world = place(cm, state.body_pos, state.body_quat)
    lo, hi = aabbs(cm, world)
    pad = reach[cm.geom_body][:, None] + 0.5 * cm.tolerance
    ia, ib = broad_phase(model, lo - pad, hi + pad, state.step)
    python = np.zeros(cm.n_geom, bool)
    python[tb["python"]] = True
    keep = python[ia] | python[ib]
    ia, ib = ia[keep], ib[keep]
    if not len(ia):
        return tb["no_rows"]
    margin = float((reach[cm.geom_body[ia]] + reach[cm.geom_body[ib]]).max()) + cm.tolerance
    # triangle meshes against spheres, capsules and boxes: the triangles touching now and
    # the first ones reached, not every triangle within reach (continuous.py)
    mesh = np.zeros(len(ia), bool)
    for m, o in ((ia, ib), (ib, ia)):
        mesh |= (cm.geom_type[m] == MESH) & np.isin(cm.geom_type[o], (SPHERE, CAPSULE, BOX))
    rest = np.flatnonzero(~mesh)
    parts = [to_contacts(cm, ia[rest], ib[rest], *narrow_phase(cm, world, ia[rest], ib[rest],
                                                               margin))]
    sel = np.flatnonzero(mesh)
    if len(sel):
        from vrsim_cli.stages.collision.continuous import first_mesh_contacts

        flip = cm.geom_type[ia[sel]] != MESH
        m_, o_ = np.where(flip, ib[sel], ia[sel]), np.where(flip, ia[sel], ib[sel])
        vel = state.body_vel + dt * np.where(moving[:, None], model.gravity, 0.0)
        parts.append(to_contacts(cm, m_, o_, *first_mesh_contacts(
            cm, state.body_pos, state.body_quat, vel, state.body_angvel, m_, o_, 2.0 * dt)))
    c = Contacts.concatenate(parts)
    rows = np.zeros((len(c), kc.C_SIZE))
    rows[:, kc.C_A] = c.body_a
    rows[:, kc.C_B] = c.body_b
    rows[:, kc.C_P:kc.C_P + 3] = c.point
    rows[:, kc.C_N:kc.C_N + 3] = c.normal
    rows[:, kc.C_D] = c.depth
    return rows


def step(model: Model, before: State, after: State, dynamics) -> State:
    """One stepped step from `before` (see the module docstring). Returns the state at
    after.t with its contacts (those at the step's start within the tolerance or with an
    impulse; toi 0 for those that took an impact) and their impulses."""
    _, kd, ks = _kernels()
    tb = tables(model, dynamics)
    S, RS, S1, RS1 = tb["S"], tb["RS"], tb["S1"], tb["RS1"]
    _rows(model, before, S, RS)
    prm = tb["prm"]
    prm[ks.PR_STEP] = before.step
    prm[ks.PR_T] = before.t
    prm[ks.PR_H_PROP] = before.ode_step
    c, imp = before.contacts, before.contact_impulse
    if c is None or imp is None or not len(c):
        prev = tb["no_contacts"]
    else:
        rest = before.contact_rest
        prev = (c.body_a, c.body_b, c.toi, imp, imp if rest is None or len(rest) != len(imp)
                else rest)
    rows = _python_contacts(model, before, tb) if len(tb["python"]) else tb["no_rows"]
    kin, kin_rs = tb["no_kin"], tb["no_kin_rs"]
    if tb["animated"]:
        kin, kin_rs = np.zeros_like(S), np.zeros_like(RS)
        _rows(model, after, kin, kin_rs)
    wb, wr, wm, kS = tb["work"]
    out, m, h_prop = tb["kernel"](tb["mf"], tb["gf"], tb["rb"], tb["rp"], prm, S, RS, *prev,
                                  rows, kin, kin_rs, S1, RS1, wb, wr, wm, kS)
    if h_prop < 0.0:
        from vrsim_cli.errors import SimulationError

        raise SimulationError("the adaptive step size fell below round-off (the motion is "
                              "not smooth or not finite); try another integrator",
                              body=dynamics.body_of_component(model, int(-1.0 - h_prop)),
                              t=float(wm[kd.WM_FAIL_T]))
    out = out[:m]
    contacts = Contacts(out[:, ks.O_A].astype(np.int64), out[:, ks.O_B].astype(np.int64),
                        out[:, ks.O_P:ks.O_P + 3].copy(), out[:, ks.O_N:ks.O_N + 3].copy(),
                        out[:, ks.O_D].copy(), out[:, ks.O_TOI].copy())
    changes = {}
    if RS1.shape[0]:
        changes = dict(rot_matrix=RS1[:, 0:9].reshape(-1, 3, 3).copy(),
                       rot_angmom=RS1[:, 9:12].copy())
    new = after.replace(body_pos=S1[:, 0:3].copy(), body_vel=S1[:, 3:6].copy(),
                        body_quat=S1[:, 6:10].copy(), body_angvel=S1[:, 10:13].copy(),
                        ode_step=h_prop, contacts=contacts,
                        contact_impulse=out[:, ks.O_IMP:ks.O_IMP + 3].copy(),
                        contact_rest=out[:, ks.O_REST:ks.O_REST + 3].copy(), **changes)
    return dynamics._guard_baseline(model, before, new)  # the dynamics stage's rule


def batched(model: Model, dynamics) -> bool:
    """Whether the loop may make many steps in one call (`run`): nothing of the step
    needs Python (no pairs of Python's detection, no scene graph moving bodies)."""
    tb = tables(model, dynamics)
    return not tb["animated"] and not len(tb["python"])


def _run_scratch(model: Model, tb: dict) -> dict:
    found = tb.get("run")
    if found is None:
        n, r = model.n_body, tb["RS"].shape[0]
        found = tb["run"] = dict(bS=np.zeros((2, n, tb["S"].shape[1])),
                                 bRS=np.zeros((2, r, tb["RS"].shape[1])), base=np.zeros(n),
                                 base_set=np.zeros(1, np.int64),
                                 status=np.zeros(5, np.int64))
    return found


def run(model: Model, state: State, count: int, dynamics):
    """Up to `count` stepped steps from `state` in one compiled call (`batched` scenes):
    the states and contacts of `count` calls of `step`, bit for bit, with the loop's
    per-step checks made in the kernel. Returns (the last good state, the state that
    failed a check or None, a SimulationError or None): a failed state is for the loop's
    `check_state` to name (the compiled test stops a little early on unit quaternions,
    so a failed state may yet pass it, and the run goes on from there)."""
    _, kd, ks = _kernels()
    tb = tables(model, dynamics)
    sc = _run_scratch(model, tb)
    if not sc.get("step_typed"):
        # the step kernel compiled (or loaded) through a call from Python before the run
        # kernel types it: a step kernel first compiled inside the run kernel's typing and
        # cached failed to return its arrays when a later process called it from Python
        # (numba: "NRT_adapt_ndarray_to_python: descr is NULL"); this step is thrown away
        from vrsim_cli.errors import SimulationError

        try:
            step(model, state, state.replace(step=state.step + 1,
                                              t=(state.step + 1) * model.dt), dynamics)
        except SimulationError:
            pass  # the run below reports it
        sc["step_typed"] = True
    bS, bRS, base, base_set, status = (sc[k] for k in ("bS", "bRS", "base", "base_set",
                                                       "status"))
    _rows(model, state, bS[0], bRS[0])
    rigid = model.rigid
    if state.rot_energy0 is not None:
        base[:] = state.rot_energy0
        base_set[0] = 1
    else:
        base[:] = 0.0 if rigid is None or rigid.energy0_body is None else rigid.energy0_body
        base_set[0] = 0
    c, imp = state.contacts, state.contact_impulse
    if c is None or imp is None or not len(c):
        prev = tb["no_contacts"]
    else:
        rest = state.contact_rest
        if rest is None or len(rest) != len(imp):
            rest = imp
        prev = (np.ascontiguousarray(c.body_a, np.int64), np.ascontiguousarray(c.body_b,
                np.int64), np.ascontiguousarray(c.toi, float), np.ascontiguousarray(imp, float),
                np.ascontiguousarray(rest, float))
    mf = tb["mf"]
    guard = bool(mf[int(mf[kd.H_PARAM]) + kd.P_ENERGY_GUARD] != 0.0)
    set_base = rigid is not None and bool(rigid.energy_guard)
    wb, wr, wm, kS = tb["work"]
    kernel = ks.run_entry(tb["kinds"])
    got = kernel(mf, tb["gf"], tb["rb"], tb["rp"], tb["prm"], state.step, count,
                 model.n_steps, model.steps_per_frame, state.t, state.ode_step, bS, bRS,
                 *prev, tb["no_rows"], tb["no_kin"], tb["no_kin_rs"], wb, wr, wm, kS, base,
                 base_set, set_base, guard, status)
    code, done, cur, index, failed = (int(v) for v in status)
    energy0 = base.copy() if base_set[0] else None

    def at(buffer: int, steps: int, out, m, h) -> State:
        k = state.step + steps
        out = out[:m]
        rot = {}
        if bRS.shape[1]:
            rot = dict(rot_matrix=bRS[buffer, :, 0:9].reshape(-1, 3, 3).copy(),
                       rot_angmom=bRS[buffer, :, 9:12].copy())
        S1 = bS[buffer]
        contacts = Contacts(out[:, ks.O_A].astype(np.int64), out[:, ks.O_B].astype(np.int64),
                            out[:, ks.O_P:ks.O_P + 3].copy(), out[:, ks.O_N:ks.O_N + 3].copy(),
                            out[:, ks.O_D].copy(), out[:, ks.O_TOI].copy())
        return state.replace(step=k, t=k * model.dt, body_pos=S1[:, 0:3].copy(),
                             body_vel=S1[:, 3:6].copy(), body_quat=S1[:, 6:10].copy(),
                             body_angvel=S1[:, 10:13].copy(), ode_step=h, contacts=contacts,
                             contact_impulse=out[:, ks.O_IMP:ks.O_IMP + 3].copy(),
                             contact_rest=out[:, ks.O_REST:ks.O_REST + 3].copy(),
                             rot_energy0=energy0, **rot)

    good = at(cur, done, *got[0:3]) if done else state
    if code == ks.RUN_OK:
        return good, None, None
    if code == ks.RUN_UNDERFLOW:
        from vrsim_cli.errors import SimulationError

        return good, None, SimulationError(
            "the adaptive step size fell below round-off (the motion is not smooth or not "
            "finite); try another integrator", body=dynamics.body_of_component(model, index),
            t=float(wm[kd.WM_FAIL_T]))
    return good, at(failed, done + 1, *got[3:6]), None


def prepare(model: Model, dynamics) -> None:
    """Pack the tables and load (on the first run after an install: compile) the kernel,
    with a step of the initial state that is thrown away."""
    from vrsim_cli.model.state import make_state

    state = make_state(model)
    if batched(model, dynamics):  # the loop's kernel: many steps per call
        run(model, state, 0, dynamics)
        return
    after = state.replace(step=state.step + 1, t=model.dt)
    step(model, state, after, dynamics)
