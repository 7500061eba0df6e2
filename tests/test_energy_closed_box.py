"""Energy in closed boxes of walls (issue 15, item 4).

Truth: without gravity, friction or damping, elastic contacts (restitution 1, mu = 0)
conserve the kinetic energy sum(1/2 m v^2 + 1/2 w . I w); plastic or partly elastic ones
(restitution < 1) can only lose it. The bodies here are spheres and cubes: their inertia
is isotropic, so between contacts w is constant and every integrator moves them exactly
(under zero gravity) -- whatever energy changes is the contact response's doing. (Boxes
with unequal sides and capsules are left out of the 1e-9 bound on purpose: the
integrators' own free rotation does not keep their energy to 1e-9 at dt = 10 ms, e.g.
verlet 3e-5 and rk4 2e-6 relative over 20 s for a box spinning at 5 rad/s, with no
contact at all; that is the dynamics' accuracy, not the response's.)

The energy is computed here from the written state: masses from the scene, the inertia of
a solid sphere 2/5 m r^2 and of a cube m s^2 / 6 (both isotropic), and the velocities.
"""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from conftest import simulate

HALF = 1.0  # m: half the inner size of the closed box

# The 60 s under VRSIM_SLOW_TESTS=1 (as run for the closing notes); the suite (CI)
# runs the same scenes for 15 s, with the same 1e-9 bound, to stay within its 10 minutes.
DURATION_S = 60.0 if os.environ.get("VRSIM_SLOW_TESTS") == "1" else 15.0


def _walls() -> list[str]:
    out = []
    for axis in range(3):
        for sign in (1, -1):
            normal = [0.0, 0.0, 0.0]
            normal[axis] = float(-sign)
            pos = [0.0, 0.0, 0.0]
            pos[axis] = sign * HALF
            out.append(f"  - {{name: wall{axis}{'p' if sign > 0 else 'm'}, type: static, "
                       f"position: {pos}, shape: {{type: plane, normal: {normal}}}}}")
    return out


def closed_box(rng, count: int, restitution, impacts: str, dt: float, integrator: str,
               duration: float | None = None, spin: float = 10.0, cubes: bool = False):
    """(states, [(mass, inertia scalar kg m^2)] per moving body) of `count` random spheres
    and cubes at random places (not overlapping), poses, velocities (0.5-3 m/s) and spins
    (up to `spin` rad/s; all cubes if `cubes`) in the closed box."""
    duration = DURATION_S if duration is None else duration
    bodies, props, centres = [], [], []
    while len(bodies) < count:
        cube = cubes or bool(rng.integers(2))
        size = float(rng.uniform(0.1, 0.5))  # edge of a cube, diameter of a sphere
        reach = 0.5 * size * (math.sqrt(3.0) if cube else 1.0)
        c = rng.uniform(-HALF + reach + 0.01, HALF - reach - 0.01, 3)
        if any(np.linalg.norm(c - o) < reach + r + 0.01 for o, r in centres):
            continue
        centres.append((c, reach))
        mass = float(rng.uniform(0.2, 5.0))
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        v = rng.normal(size=3)
        v *= rng.uniform(0.5, 3.0) / np.linalg.norm(v)
        w = rng.normal(size=3)
        w *= rng.uniform(0.0, spin) / np.linalg.norm(w)
        eps = float(restitution if not callable(restitution) else restitution())
        shape = (f"{{type: box, size: [{size!r}, {size!r}, {size!r}]}}" if cube else
                 f"{{type: sphere, radius: {0.5 * size!r}}}")
        bodies.append(f"  - {{name: b{len(bodies)}, mass: {mass!r}, position: {c.tolist()}, "
                      f"orientation: {q.tolist()}, velocity: {v.tolist()}, "
                      f"angular_velocity: {w.tolist()}, shape: {shape}, "
                      f"material: {{restitution: {eps!r}, friction: 0.0}}}}")
        props.append((mass, mass * size * size / 6.0 if cube else 0.1 * mass * size * size))
    text = "\n".join([f"""
vrsim: 1
duration: {duration!r}
frame_rate: 2
dt: {dt!r}
integrator: {integrator}
gravity: [0, 0, 0]
collision: {{impacts: {impacts}}}
bodies:"""] + _walls() + bodies) + "\n"
    model, states, _ = simulate(text)
    return states, props


def energy(state, props) -> float:
    """J: sum of 1/2 m v^2 + 1/2 I w^2 over the moving bodies (after the six walls)."""
    total = 0.0
    for k, (m, inertia) in enumerate(props):
        v, w = state.body_vel[6 + k], state.body_angvel[6 + k]
        total += 0.5 * m * float(v @ v) + 0.5 * inertia * float(w @ w)
    return total


@pytest.mark.parametrize("seed", range(3))
def test_elastic_bodies_in_a_closed_box_keep_their_energy_for_60_s(seed):
    """Located impacts (the default mode), restitution 1, mu = 0, 1-2 random cubes
    spinning at up to 30 rad/s, 60 s, dt in {1/30 s, 50 ms},
    verlet or rk4: the kinetic energy at every frame equals the first to 1e-9 relative
    (the issue's bound). Fast spin and long steps make a second corner reach a wall in
    the step of the first one's bounce (main lost 47 % and 23 % of the energy in seeds 0
    and 2 there: the second corner was solved as a resting, plastic contact)."""
    rng = np.random.default_rng(seed)
    dt = float(rng.choice([1 / 30, 0.05]))
    integrator = str(rng.choice(["verlet", "rk4"]))
    states, props = closed_box(rng, int(rng.integers(1, 3)), 1.0, "located", dt, integrator,
                               spin=30.0, cubes=True)
    e0 = energy(states[0], props)
    worst = max(abs(energy(s, props) - e0) for s in states) / e0
    assert states[-1].t == pytest.approx(DURATION_S)
    assert worst <= 1e-9, worst


@pytest.mark.parametrize("impacts", ["located", "stepped"])
def test_no_impact_mode_gains_energy(impacts):
    """Each impact mode, restitution drawn per body from {0, U(0, 1), 1}, mu = 0, 2 random
    spheres or cubes spinning at up to 30 rad/s, dt 50 ms, 60 s: the energy never exceeds
    the first frame's by more than 1e-9 relative."""
    rng = np.random.default_rng(20)
    states, props = closed_box(rng, 2, lambda: float(rng.choice([0.0, rng.uniform(), 1.0])),
                               impacts, 0.05, str(rng.choice(["verlet", "rk4"])), spin=30.0)
    e0 = energy(states[0], props)
    gain = max(energy(s, props) - e0 for s in states) / e0
    assert gain <= 1e-9, gain


@pytest.mark.parametrize("seed", range(20))
def test_position_correction_does_not_change_kinetic_energy(seed):
    """response.write_back with a random correction (translation and rotation vector) of a
    random box or capsule spinning at random: the kinetic energy 1/2 m v^2 + 1/2 L.I^-1 L
    (I in the turned pose) is unchanged to 1e-12 relative, as is |L| (the body-frame
    angular momentum is kept: the correction moves the body, it does not push it)."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.stages.collision import response

    rng = np.random.default_rng(seed)
    shape = ("{type: box, size: %s}" % rng.uniform(0.1, 0.8, 3).tolist() if seed % 2 else
             "{type: capsule, radius: %r, length: %r}" % (float(rng.uniform(0.05, 0.3)),
                                                          float(rng.uniform(0.1, 0.8))))
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    model = compile_model(parse_scene(f"""
vrsim: 1
duration: 0.1
dt: 0.01
gravity: [0, 0, 0]
collision: {{}}
bodies:
  - {{name: b, mass: {float(rng.uniform(0.2, 5.0))!r}, orientation: {q.tolist()},
     velocity: {rng.normal(size=3).tolist()}, angular_velocity: {(rng.normal(size=3) * 5).tolist()},
     shape: {shape}}}
"""))
    state = make_state(model)
    bodies = response.bodies_of(model, state)
    dtheta = rng.normal(size=(1, 3)) * float(rng.uniform(1e-4, 0.3))
    dpos = rng.normal(size=(1, 3)) * 1e-3
    new = response.write_back(model, state, bodies, None, dpos, dtheta)

    def kinetic(s):
        R = s.rot_matrix[0]
        inv = R @ model.rigid.rot_inv_inertia[0] @ R.T
        L = s.rot_angmom[0]
        return 0.5 * model.body_mass[0] * float(s.body_vel[0] @ s.body_vel[0]) + \
            0.5 * float(L @ inv @ L)

    assert abs(kinetic(new) - kinetic(state)) <= 1e-12 * kinetic(state)
    assert np.linalg.norm(new.rot_angmom[0]) == pytest.approx(
        np.linalg.norm(state.rot_angmom[0]), rel=1e-14)
    assert not np.allclose(new.rot_matrix[0], state.rot_matrix[0])  # it did turn
