"""The peers of `vrsim bench`: the same problems in MuJoCo and PyBullet, set up as a careful
user would.

MuJoCo: one body on a free joint, gravity as in the problem, contacts off for a
projectile; integrators Euler (semi-implicit for free bodies), implicitfast and RK4; the
stepping is one `mj_step(model, data, nstep=N)` call, so Python adds nothing per step.
PyBullet: DIRECT mode, one multibody, linear and angular damping set to 0 (Bullet's
default 0.04 would dominate the error), fixed time step, no sub-steps.
Both are optional (`pip install 'vrsim-cli[bench]'`) and imported only here.
"""

from __future__ import annotations

import importlib.util

import numpy as np

MUJOCO_INTEGRATORS = ("Euler", "implicitfast", "RK4")


def available(engine: str) -> bool:
    return importlib.util.find_spec(engine) is not None


def _mujoco_timed(xml: str, steps: int, vel_slice, vel, read_slice, repeats: int):
    """Best wall time of `steps` mj_steps of the model `xml` from rest with qvel[vel_slice]
    = vel (one mj_step call, so Python adds nothing per step); returns (wall, the final
    qpos[read_slice])."""
    import mujoco

    from vrsim_cli.bench import best_time

    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)

    def go():
        mujoco.mj_resetData(model, data)
        data.qvel[vel_slice] = vel
        mujoco.mj_step(model, data, nstep=steps)
        return data.qpos[read_slice].copy()

    return best_time(go, repeats)


def mujoco_projectile(dts, repeats):
    from vrsim_cli.bench import PROJECTILE, Point, projectile_truth

    p = PROJECTILE
    points = []
    for integrator in MUJOCO_INTEGRATORS:
        for dt in dts:
            xml = f"""<mujoco><option timestep="{dt!r}" integrator="{integrator}"
                gravity="{' '.join(map(repr, p['g']))}"/>
                <worldbody><body pos="{' '.join(map(repr, p['x0']))}"><freejoint/>
                <geom type="sphere" size="0.05" mass="{p['mass']!r}" contype="0"
                conaffinity="0"/></body></worldbody></mujoco>"""
            steps = round(p["duration"] / dt)
            wall, pos = _mujoco_timed(xml, steps, slice(0, 3), p["v0"], slice(0, 3), repeats)
            error = float(np.linalg.norm(pos - projectile_truth(steps * dt)))
            points.append(Point("projectile", "mujoco", integrator, dt, wall, error, steps))
    return points


def pybullet_projectile(dts, repeats):
    import pybullet

    from vrsim_cli.bench import PROJECTILE, Point, best_time, projectile_truth

    p = PROJECTILE
    points = []
    client = pybullet.connect(pybullet.DIRECT)
    try:
        for dt in dts:
            pybullet.resetSimulation(physicsClientId=client)
            pybullet.setGravity(*p["g"], physicsClientId=client)
            pybullet.setTimeStep(dt, physicsClientId=client)
            pybullet.setPhysicsEngineParameter(numSubSteps=0, physicsClientId=client)
            shape = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=0.05,
                                                  physicsClientId=client)
            body = pybullet.createMultiBody(p["mass"], shape, basePosition=p["x0"],
                                            physicsClientId=client)
            pybullet.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0,
                                    physicsClientId=client)
            steps = round(p["duration"] / dt)

            def go():
                pybullet.resetBasePositionAndOrientation(body, p["x0"], (0, 0, 0, 1),
                                                         physicsClientId=client)
                pybullet.resetBaseVelocity(body, p["v0"], (0, 0, 0), physicsClientId=client)
                for _ in range(steps):
                    pybullet.stepSimulation(physicsClientId=client)
                return np.array(pybullet.getBasePositionAndOrientation(
                    body, physicsClientId=client)[0])

            wall, pos = best_time(go, repeats)
            error = float(np.linalg.norm(pos - projectile_truth(steps * dt)))
            points.append(Point("projectile", "pybullet", "semi-implicit Euler", dt, wall,
                                error, steps))
    finally:
        pybullet.disconnect(client)
    return points


def mujoco_dzhanibekov(dts, repeats):
    """The free box in MuJoCo: a box geom (half-sizes) of the same mass on a free joint, no
    gravity, no contacts; the free joint's angular velocity is in the body frame, which is
    the world frame at t = 0."""
    from vrsim_cli.bench import DZHANIBEKOV, Point, dzhanibekov_truth, rotation_error
    from vrsim_cli.spatial import quat_to_matrix

    d = DZHANIBEKOV
    truth = dzhanibekov_truth()
    half = " ".join(repr(0.5 * s) for s in d["size"])
    points = []
    for integrator in MUJOCO_INTEGRATORS:
        for dt in (dt for dt in dts if dt >= d["min_dt"]):
            xml = f"""<mujoco><option timestep="{dt!r}" integrator="{integrator}"
                gravity="0 0 0"/><worldbody><body><freejoint/>
                <geom type="box" size="{half}" mass="{d['mass']!r}" contype="0"
                conaffinity="0"/></body></worldbody></mujoco>"""
            steps = round(d["duration"] / dt)
            # The free joint's qvel[3:] is the angular velocity, qpos[3:7] the quaternion.
            wall, quat = _mujoco_timed(xml, steps, slice(3, 6), d["omega0"], slice(3, 7),
                                       repeats)
            error = rotation_error(quat_to_matrix(quat), truth)
            points.append(Point("dzhanibekov", "mujoco", integrator, dt, wall, error, steps))
    return points
