"""The peers of `vrsim bench`: the same problems in MuJoCo and PyBullet, set up as a careful
user would. Both are optional (`pip install 'vrsim-cli[bench]'`) and imported only here.
Both engines have z up; the problems' y-up heights become z.

MuJoCo (every problem): bodies on free joints; integrators Euler (semi-implicit for free
bodies), implicitfast and RK4; the timed stepping is one `mj_step(model, data, nstep=N)`
call, so Python adds nothing per step.
- projectile, dzhanibekov: contacts off (contype = conaffinity = 0).
- bounce: MuJoCo's contacts are soft (a spring-damper in constraint space), so
  restitution is emulated through `solref = (timeconst, dampratio)`. A linear spring-
  damper with damping ratio zeta returns eps = exp(-zeta pi / sqrt(1 - zeta^2)) of the
  approach speed, so zeta = -ln(eps) / sqrt(pi^2 + ln(eps)^2) = 0.0709 for eps = 0.8.
  MuJoCo's reference acceleration is -b v - k r with b = 2 / (dmax timeconst),
  k = 1 / (dmax^2 timeconst^2 dampratio^2), and the constraint reaches d a_ref (d: the
  impedance); with a constant impedance (solimp dmin = dmax = 0.99, so the spring is
  linear) the contact's damping ratio is sqrt(d) dampratio, hence dampratio =
  zeta / sqrt(0.99). timeconst sets the contact's duration (about pi timeconst zeta:
  0.22 timeconst) and must be >= 2 timesteps (MuJoCo clamps it); at a few timesteps the
  stiff, lightly damped spring gains energy (measured: apexes of 3 m to 2400 m), so
  the sweep tries timeconst = 20, 100 and 400 timesteps with each integrator and step.
  Both geoms carry the same solref/solimp (MuJoCo then uses them as they are).
- stack: MuJoCo's defaults (Newton solver, pyramidal cone, solref 0.02 1, solimp
  0.9 0.95 0.001) and friction 0.5 on every geom (a pair takes the larger of its two).

PyBullet (every problem): DIRECT mode, `createMultiBody` bodies (Featherstone multibodies,
which include the gyroscopic term of a free base), linear and angular damping set to 0
(Bullet's default 0.04 would dominate the error), fixed time step, no sub-steps; one
`stepSimulation` call per step from Python (about 1 us of the cost per step).
- bounce: Bullet combines the restitution of a pair as the product of the two bodies'
  values (`btManifoldResult::calculateCombinedRestitution`), so the ball gets 0.8 and the
  plane 1.0. The restitution velocity threshold (impacts slower than it are plastic) does
  not matter: the measured bounces hit at >= 1.45 m/s. Split impulse and ERP: the split
  impulse switch changed nothing measurable (multibody contacts), ERP 0.8 instead of
  the default 0.2 made the ball gain height (apex 6.6 m at 1/60 s); defaults are kept.
  Bullet reports contacts from a processing threshold (0.02 m) before the surfaces touch
  and applies restitution there; the sweep runs the default and threshold 0.
- stack: friction combines as the product too, so every box and the plane get
  sqrt(0.5) (each pair: 0.5); the default solver (50 iterations).
"""

from __future__ import annotations

import importlib.util
import math

import numpy as np

MUJOCO_INTEGRATORS = ("Euler", "implicitfast", "RK4")
# Bounce in MuJoCo: constant impedance, and the contact's time constant in timesteps.
MUJOCO_BOUNCE_IMPEDANCE = 0.99
MUJOCO_BOUNCE_TIMECONSTS = (20, 100, 400)
MUJOCO_BOUNCE_DTS = {"full": (2e-3, 1e-3, 5e-4), "quick": (2e-3, 1e-3)}
MUJOCO_DZHANIBEKOV_DTS = {"full": (1e-2, 5e-3, 2.5e-3, 1e-3, 5e-4, 2.5e-4),
                          "quick": (1e-2, 5e-3, 2.5e-3, 1e-3)}
MUJOCO_STACK_DTS = {"full": (1 / 5, 1 / 10, 1 / 15, 1 / 30, 1 / 60, 1 / 240, 0.002),
                    "quick": (1 / 15, 1 / 60)}
PYBULLET_BOUNCE_DTS = {"full": (1 / 60, 1 / 240, 1e-3), "quick": (1 / 60, 1 / 240)}
PYBULLET_DZHANIBEKOV_DTS = {"full": (1 / 240, 1e-3, 2.5e-4), "quick": (1 / 240, 1e-3)}
PYBULLET_STACK_DTS = {"full": (1 / 15, 1 / 30, 1 / 60, 1 / 240), "quick": (1 / 60,)}


def available(engine: str) -> bool:
    return importlib.util.find_spec(engine) is not None


def _plan(table: dict, quick: bool) -> tuple:
    return table["quick" if quick else "full"]


def _floats(values) -> str:
    return " ".join(repr(float(v)) for v in values)


# ----------------------------------------------------------------------------- MuJoCo


def _mujoco_timed(xml: str, steps: int, vel_slice, vel, read_slice, repeats: int):
    """Best wall time of `steps` mj_steps of the model `xml` from its initial state with
    qvel[vel_slice] = vel (one mj_step call, so Python adds nothing per step); returns
    (wall, the final qpos[read_slice], model, data)."""
    import mujoco

    from vrsim_cli.tools.bench.problems import best_time

    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)

    def go():
        mujoco.mj_resetData(model, data)
        data.qvel[vel_slice] = vel
        mujoco.mj_step(model, data, nstep=steps)
        return data.qpos[read_slice].copy()

    wall, qpos = best_time(go, repeats)
    return wall, qpos, model, data


def mujoco_projectile(quick, repeats):
    from vrsim_cli.tools.bench.problems import PROJECTILE, Point, projectile_truth, sweep

    p = PROJECTILE
    points = []
    for integrator in MUJOCO_INTEGRATORS:
        for dt in sweep(quick, p):
            xml = f"""<mujoco><option timestep="{dt!r}" integrator="{integrator}"
                gravity="{_floats(p['g'])}"/>
                <worldbody><body pos="{_floats(p['x0'])}"><freejoint/>
                <geom type="sphere" size="0.05" mass="{p['mass']!r}" contype="0"
                conaffinity="0"/></body></worldbody></mujoco>"""
            steps = round(p["duration"] / dt)
            wall, pos, _, _ = _mujoco_timed(xml, steps, slice(0, 3), p["v0"], slice(0, 3),
                                            repeats)
            error = float(np.linalg.norm(pos - projectile_truth(steps * dt)))
            points.append(Point("projectile", "mujoco", integrator, dt, wall, error, steps))
    return points


def mujoco_bounce_solref(timeconst: float) -> tuple[float, float]:
    """(timeconst, dampratio) whose linear contact spring returns eps of the approach
    speed, at the constant impedance MUJOCO_BOUNCE_IMPEDANCE (module docstring)."""
    from vrsim_cli.tools.bench.problems import BOUNCE

    log_eps = math.log(BOUNCE["eps"])
    zeta = -log_eps / math.sqrt(math.pi ** 2 + log_eps ** 2)
    return timeconst, zeta / math.sqrt(MUJOCO_BOUNCE_IMPEDANCE)


def mujoco_bounce(quick, repeats):
    import mujoco

    from vrsim_cli.tools.bench.problems import BOUNCE, Point, bounce_errors, flight_apexes

    b = BOUNCE
    points = []
    for integrator in MUJOCO_INTEGRATORS:
        for factor in MUJOCO_BOUNCE_TIMECONSTS:
            for dt in _plan(MUJOCO_BOUNCE_DTS, quick):
                d = MUJOCO_BOUNCE_IMPEDANCE
                soft = (f'solref="{_floats(mujoco_bounce_solref(factor * dt))}" '
                        f'solimp="{d!r} {d!r} 0.001 0.5 2"')
                xml = f"""<mujoco><option timestep="{dt!r}" integrator="{integrator}"
                    gravity="0 0 {-b['g']!r}"/><worldbody>
                    <geom type="plane" size="5 5 0.1" {soft}/>
                    <body pos="0 0 {b['h0'] + b['radius']!r}"><freejoint/>
                    <geom type="sphere" size="{b['radius']!r}" mass="{b['mass']!r}" {soft}/>
                    </body></worldbody></mujoco>"""
                steps = round(b["duration"] / dt)
                wall, _, model, data = _mujoco_timed(xml, steps, slice(0, 0), (), slice(0, 0),
                                                     repeats)
                mujoco.mj_resetData(model, data)  # untimed: the samples of every step
                samples = []
                for _ in range(steps):
                    mujoco.mj_step(model, data)
                    samples.append((data.time, data.qpos[2] - b["radius"], data.qvel[2]))
                apexes, landings = flight_apexes(*zip(*samples), g=b["g"])
                apex_error, time_error = bounce_errors(apexes, landings)
                points.append(Point("bounce", "mujoco", f"{integrator}, timeconst {factor} dt",
                                    dt, wall, apex_error, steps,
                                    {"bounce_time_error_s": time_error}))
    return points


def mujoco_dzhanibekov(quick, repeats):
    """The free box in MuJoCo: a box geom (half-sizes) of the same mass on a free joint, no
    gravity, no contacts; the free joint's angular velocity is in the body frame, which is
    the world frame at t = 0."""
    import mujoco

    from vrsim_cli.tools.bench.problems import DZHANIBEKOV, Point, dzhanibekov_error, dzhanibekov_truth

    d = DZHANIBEKOV
    truth = dzhanibekov_truth()
    half = _floats(0.5 * s for s in d["size"])
    points = []
    for integrator in MUJOCO_INTEGRATORS:
        for dt in _plan(MUJOCO_DZHANIBEKOV_DTS, quick):
            xml = f"""<mujoco><option timestep="{dt!r}" integrator="{integrator}"
                gravity="0 0 0"/><worldbody><body><freejoint/>
                <geom type="box" size="{half}" mass="{d['mass']!r}" contype="0"
                conaffinity="0"/></body></worldbody></mujoco>"""
            steps = round(d["duration"] / dt)
            # The free joint's qvel[3:] is the angular velocity, qpos[3:7] the quaternion.
            wall, _, model, data = _mujoco_timed(xml, steps, slice(3, 6), d["omega0"],
                                                 slice(3, 7), repeats)
            mujoco.mj_resetData(model, data)  # untimed: the whole seconds
            data.qvel[3:6] = d["omega0"]
            quats = []
            for _ in truth:
                mujoco.mj_step(model, data, nstep=round(1.0 / dt))
                quats.append(data.qpos[3:7].copy())
            points.append(Point("dzhanibekov", "mujoco", integrator, dt, wall,
                                dzhanibekov_error(quats, truth), steps))
    return points


def mujoco_stack(quick, repeats):
    from vrsim_cli.maths.spatial import quat_to_matrix
    from vrsim_cli.tools.bench.problems import STACK, Row, dt_label, stack_sanity

    s = STACK
    duration = s["quick_duration"] if quick else s["duration"]
    half = 0.5 * s["size"]
    friction = f'friction="{s["friction"]!r} 0.005 0.0001"'
    boxes = "".join(
        f'<body pos="0 0 {(i + 0.5) * s["size"]!r}"><freejoint/><geom type="box" '
        f'size="{half!r} {half!r} {half!r}" mass="{s["mass"]!r}" {friction}/></body>'
        for i in range(s["boxes"]))
    top = 7 * (s["boxes"] - 1)  # the top box's qpos: position, then quaternion
    rows = []
    for dt in _plan(MUJOCO_STACK_DTS, quick):
        xml = f"""<mujoco><option timestep="{dt!r}" gravity="0 0 {-s['g']!r}"/><worldbody>
            <geom type="plane" size="20 20 0.1" {friction}/>{boxes}</worldbody></mujoco>"""
        steps = round(duration / dt)
        wall, qpos, _, _ = _mujoco_timed(xml, steps, slice(0, 0), (), slice(top, top + 7),
                                         repeats)
        pos0 = (0.0, 0.0, (s["boxes"] - 0.5) * s["size"])
        rows.append(Row("stack", "mujoco", f"Euler, dt = {dt_label(dt)}, {duration:g} s, "
                        "defaults (Newton, pyramidal, solref 0.02 1)", s["boxes"], steps,
                        wall, stack_sanity(pos0, qpos[:3], quat_to_matrix(qpos[3:])),
                        steps * dt))
    return rows


# ----------------------------------------------------------------------------- PyBullet


class _Bullet:
    """A DIRECT PyBullet client with the common settings (module docstring)."""

    def __init__(self, dt: float, gravity):
        import pybullet

        self.pb = pybullet
        self.client = pybullet.connect(pybullet.DIRECT)
        self.call("resetSimulation")
        self.call("setGravity", *gravity)
        self.call("setTimeStep", dt)
        self.call("setPhysicsEngineParameter", numSubSteps=0)

    def call(self, name: str, *args, **kwargs):
        return getattr(self.pb, name)(*args, physicsClientId=self.client, **kwargs)

    def body(self, mass, shape_type, position, **shape):
        shape_id = self.call("createCollisionShape", shape_type, **shape)
        body = self.call("createMultiBody", mass, shape_id, basePosition=position)
        self.call("changeDynamics", body, -1, linearDamping=0.0, angularDamping=0.0)
        return body

    def steps(self, n: int) -> None:
        step, client = self.pb.stepSimulation, self.client
        for _ in range(n):
            step(physicsClientId=client)

    def pose(self, body):
        """(position (3,), orientation matrix (3, 3)) of `body`."""
        from vrsim_cli.maths.spatial import quat_to_matrix

        pos, (x, y, z, w) = self.call("getBasePositionAndOrientation", body)
        return np.array(pos), quat_to_matrix(np.array([w, x, y, z]))

    def close(self) -> None:
        self.pb.disconnect(self.client)


def pybullet_projectile(quick, repeats):
    from vrsim_cli.tools.bench.problems import PROJECTILE, Point, best_time, projectile_truth, sweep

    p = PROJECTILE
    points = []
    for dt in sweep(quick, p):
        sim = _Bullet(dt, p["g"])
        try:
            body = sim.body(p["mass"], sim.pb.GEOM_SPHERE, p["x0"], radius=0.05)
            steps = round(p["duration"] / dt)

            def go():
                sim.call("resetBasePositionAndOrientation", body, p["x0"], (0, 0, 0, 1))
                sim.call("resetBaseVelocity", body, p["v0"], (0, 0, 0))
                sim.steps(steps)
                return sim.pose(body)[0]

            wall, pos = best_time(go, repeats)
        finally:
            sim.close()
        error = float(np.linalg.norm(pos - projectile_truth(steps * dt)))
        points.append(Point("projectile", "pybullet", "semi-implicit Euler", dt, wall,
                            error, steps))
    return points


def pybullet_bounce(quick, repeats):
    from vrsim_cli.tools.bench.problems import BOUNCE, Point, best_time, bounce_errors, flight_apexes

    b = BOUNCE
    start = (0.0, 0.0, b["h0"] + b["radius"])
    points = []
    for threshold in (None, 0.0):
        for dt in _plan(PYBULLET_BOUNCE_DTS, quick):
            sim = _Bullet(dt, (0.0, 0.0, -b["g"]))
            try:
                plane = sim.body(0.0, sim.pb.GEOM_PLANE, (0.0, 0.0, 0.0))
                ball = sim.body(b["mass"], sim.pb.GEOM_SPHERE, start, radius=b["radius"])
                # product of the two: 0.8 * 1.0
                sim.call("changeDynamics", ball, -1, restitution=b["eps"])
                sim.call("changeDynamics", plane, -1, restitution=1.0)
                if threshold is not None:
                    for body in (plane, ball):
                        sim.call("changeDynamics", body, -1,
                                 contactProcessingThreshold=threshold)
                steps = round(b["duration"] / dt)

                def reset():
                    sim.call("resetBasePositionAndOrientation", ball, start, (0, 0, 0, 1))
                    sim.call("resetBaseVelocity", ball, (0, 0, 0), (0, 0, 0))

                def go():
                    reset()
                    sim.steps(steps)

                wall, _ = best_time(go, repeats)
                reset()  # untimed: the samples of every step
                samples = []
                for k in range(steps):
                    sim.steps(1)
                    z = sim.call("getBasePositionAndOrientation", ball)[0][2]
                    vz = sim.call("getBaseVelocity", ball)[0][2]
                    samples.append(((k + 1) * dt, z - b["radius"], vz))
            finally:
                sim.close()
            apexes, landings = flight_apexes(*zip(*samples), g=b["g"])
            apex_error, time_error = bounce_errors(apexes, landings)
            method = ("semi-implicit Euler" if threshold is None else
                      "semi-implicit Euler, contactProcessingThreshold 0")
            points.append(Point("bounce", "pybullet", method, dt, wall, apex_error, steps,
                                {"bounce_time_error_s": time_error}))
    return points


def pybullet_dzhanibekov(quick, repeats):
    """The free box as a multibody base (box collision shape of the same mass, so the same
    inertia); its gyroscopic term is part of Bullet's Featherstone dynamics."""
    from vrsim_cli.tools.bench.problems import (DZHANIBEKOV, Point, best_time, dzhanibekov_error,
                                 dzhanibekov_truth)

    d = DZHANIBEKOV
    truth = dzhanibekov_truth()
    points = []
    for dt in _plan(PYBULLET_DZHANIBEKOV_DTS, quick):
        sim = _Bullet(dt, (0.0, 0.0, 0.0))
        try:
            box = sim.body(d["mass"], sim.pb.GEOM_BOX, (0.0, 0.0, 0.0),
                           halfExtents=[0.5 * s for s in d["size"]])
            steps = round(d["duration"] / dt)

            def reset():
                sim.call("resetBasePositionAndOrientation", box, (0, 0, 0), (0, 0, 0, 1))
                sim.call("resetBaseVelocity", box, (0, 0, 0), d["omega0"])  # world = body

            def go():
                reset()
                sim.steps(steps)

            wall, _ = best_time(go, repeats)
            reset()  # untimed: the whole seconds
            quats = []
            for _ in truth:
                sim.steps(round(1.0 / dt))
                x, y, z, w = sim.call("getBasePositionAndOrientation", box)[1]
                quats.append((w, x, y, z))
        finally:
            sim.close()
        points.append(Point("dzhanibekov", "pybullet", "semi-implicit Euler", dt, wall,
                            dzhanibekov_error(quats, truth), steps))
    return points


def pybullet_stack(quick, repeats):
    from vrsim_cli.tools.bench.problems import STACK, Row, best_time, dt_label, stack_sanity

    s = STACK
    duration = s["quick_duration"] if quick else s["duration"]
    friction = math.sqrt(s["friction"])  # Bullet multiplies the two bodies' values
    half = 0.5 * s["size"]
    starts = [(0.0, 0.0, (i + 0.5) * s["size"]) for i in range(s["boxes"])]
    rows = []
    for dt in _plan(PYBULLET_STACK_DTS, quick):
        sim = _Bullet(dt, (0.0, 0.0, -s["g"]))
        try:
            plane = sim.body(0.0, sim.pb.GEOM_PLANE, (0.0, 0.0, 0.0))
            boxes = [sim.body(s["mass"], sim.pb.GEOM_BOX, p, halfExtents=[half] * 3)
                     for p in starts]
            for body in (plane, *boxes):
                sim.call("changeDynamics", body, -1, lateralFriction=friction)
            steps = round(duration / dt)

            def go():
                for body, p in zip(boxes, starts):
                    sim.call("resetBasePositionAndOrientation", body, p, (0, 0, 0, 1))
                    sim.call("resetBaseVelocity", body, (0, 0, 0), (0, 0, 0))
                sim.steps(steps)
                return sim.pose(boxes[-1])

            wall, (pos, R) = best_time(go, repeats)
        finally:
            sim.close()
        rows.append(Row("stack", "pybullet", f"semi-implicit Euler, dt = {dt_label(dt)}, "
                        f"{duration:g} s, 50 solver iterations (default)", s["boxes"], steps,
                        wall, stack_sanity(starts[-1], pos, R), steps * dt))
    return rows
