"""Point-mass dynamics against closed forms.

Round-off budget used below: a run of n steps accumulates at most a few ulp per step, so
for |x| <= 10 m and n <= 2000 the round-off is below 2000 * 4 * 2.2e-16 * 10 m ~ 2e-11 m;
tolerances of 1e-10 m leave a margin of 5 and are far below any truncation error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from vrsim_cli.errors import SimulationError
from vrsim_cli.loop import check_state, run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import parse_scene, scene_schema
from vrsim_cli.stages.dynamics.integrators import INTEGRATORS, ORDER
from vrsim_cli.stages.dynamics.motion import step

ROUND_OFF_M = 1e-10
G = np.array([0.0, -9.81, 0.0])
V0 = np.array([3.0, 7.0, -1.5])
X0 = np.array([0.5, 1.0, 2.0])


def projectile(integrator: str, dt: float, duration: float = 1.5):
    scene = parse_scene(f"""
vrsim: 1
duration: {duration}
frame_rate: 100
dt: {dt}
integrator: {integrator}
bodies: [{{name: ball, mass: 0.2, position: {X0.tolist()}, velocity: {V0.tolist()}}}]
""")
    model = compile_model(scene)
    result = run(model, make_state(model))
    return model, result.state


def closed_form(t: float) -> np.ndarray:
    return X0 + V0 * t + 0.5 * G * t * t


def test_integrator_names_match_the_schema():
    assert tuple(INTEGRATORS) == tuple(scene_schema()["$defs"]["integrator"]["enum"])


def test_rk4_projectile_is_exact_to_round_off():
    # RK4 integrates polynomials of degree <= 4 exactly; x(t) is quadratic.
    model, state = projectile("rk4", 0.001)
    assert state.t == pytest.approx(1.5, abs=1e-12)
    assert np.abs(state.body_pos[0] - closed_form(state.t)).max() < ROUND_OFF_M
    assert np.abs(state.body_vel[0] - (V0 + G * state.t)).max() < ROUND_OFF_M


@pytest.mark.parametrize("integrator,sign", [("symplectic-euler", +1), ("euler", -1)])
def test_first_order_projectile_error_is_exactly_a_dt_t_over_2(integrator, sign):
    # Summing the recurrences: x_n = x0 + v0 t + a t^2/2 +- a dt t/2 (see integrators.py).
    # The error is first order in dt, with this exact constant.
    for dt in (0.01, 0.001):
        model, state = projectile(integrator, dt)
        t = state.t
        expected = closed_form(t) + sign * 0.5 * G * model.dt * t
        assert np.abs(state.body_pos[0] - expected).max() < ROUND_OFF_M
        assert np.abs(state.body_vel[0] - (V0 + G * t)).max() < ROUND_OFF_M
        assert abs(state.body_pos[0, 1] - closed_form(t)[1]) == pytest.approx(
            0.5 * 9.81 * model.dt * t, rel=1e-8)


@pytest.mark.parametrize("integrator", ["euler", "symplectic-euler"])
def test_measured_convergence_order(integrator):
    errors = []
    for dt in (0.005, 0.0025, 0.00125):  # each divides the 10 ms frame
        _, state = projectile(integrator, dt, duration=1.0)
        errors.append(np.linalg.norm(state.body_pos[0] - closed_form(state.t)))
    orders = [math.log2(errors[i] / errors[i + 1]) for i in range(2)]
    assert orders == pytest.approx([ORDER[integrator]] * 2, abs=0.01)


def test_time_is_step_times_dt_without_drift():
    model, state = projectile("symplectic-euler", 0.001, duration=1.5)
    assert state.step == 1500 and state.t == 1500 * model.dt


def test_windowed_force_gives_the_impulse():
    # F = 4 N on 2 kg from t = 0.1005 to 0.3005 s: the window holds steps 101..300 exactly
    # (forces are evaluated at step starts), so the impulse is 4 N * 0.2 s = 0.8 N s.
    scene = parse_scene("""
vrsim: 1
duration: 0.5
frame_rate: 100
dt: 0.001
gravity: [0, 0, 0]
bodies:
  - name: puck
    mass: 2.0
    forces: [{force: [4, 0, 0], start: 0.1005, end: 0.3005}]
""")
    model = compile_model(scene)
    state = run(model, make_state(model)).state
    assert state.body_vel[0, 0] == pytest.approx(0.4, abs=1e-12)
    # Symplectic Euler position: the steps starting at 101..300 move by dt * k * dv
    # (k = 1..200); the 199 steps starting at 301..499 move by dt * 0.4 m/s.
    dv = 4.0 / 2.0 * 0.001
    expected = 0.001 * dv * (200 * 201 / 2) + 0.4 * 0.001 * 199
    assert state.body_pos[0, 0] == pytest.approx(expected, abs=1e-12)


def test_kinematic_and_static_bodies_ignore_gravity():
    scene = parse_scene("""
vrsim: 1
duration: 2.0
bodies:
  - {name: lift, type: kinematic, position: [0, 0, 0], velocity: [0, 0.5, 0]}
  - {name: wall, type: static, position: [1, 2, 3]}
""")
    model = compile_model(scene)
    state = run(model, make_state(model)).state
    assert np.allclose(state.body_pos[0], [0, 1.0, 0], atol=1e-12)
    assert np.array_equal(state.body_pos[1], [1, 2, 3])


def test_2d_scene_stays_in_the_plane():
    scene = parse_scene("""
vrsim: 1
dimension: 2
duration: 1.0
integrator: rk4
bodies: [{name: p, mass: 1, position: [0, 0], velocity: [1, 2], angle_deg: 90}]
""")
    model = compile_model(scene)
    state = run(model, make_state(model)).state
    assert state.body_pos[0, 2] == 0.0 and state.body_vel[0, 2] == 0.0
    assert state.body_pos[0, :2] == pytest.approx([1.0, 2.0 - 9.81 / 2], abs=1e-12)
    assert state.body_quat[0] == pytest.approx([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])


FOUNTAIN = """
vrsim: 1
duration: 1.0
frame_rate: 100
dt: 0.001
integrator: rk4
emitters:
  - {name: jet, position: [0, 0.5, 0], direction: [0, 1, 0], speed: 5, speed_jitter: 0.2,
     spread_deg: 20, count: 50, rate: 80, mass: 0.01, seed: 3}
"""


def test_emitter_particles_wait_then_fly_ballistically():
    model = compile_model(parse_scene(FOUNTAIN))
    assert model.n_body == 50 and model.body_name[0] == "jet.0000"
    emit_t = model.body_emit_step * model.dt
    assert emit_t == pytest.approx(np.arange(50) / 80, abs=model.dt)
    speeds = np.linalg.norm(model.body_vel0, axis=1)
    assert speeds.min() >= 4.0 - 1e-12 and speeds.max() <= 6.0 + 1e-12
    cos = model.body_vel0[:, 1] / speeds
    assert cos.min() >= math.cos(math.radians(20)) - 1e-12
    state = run(model, make_state(model)).state
    age = state.t - emit_t
    expected = np.array([0, 0.5, 0]) + model.body_vel0 * age[:, None] + 0.5 * G * age[:, None] ** 2
    assert np.abs(state.body_pos - expected).max() < ROUND_OFF_M


def test_waiting_particles_do_not_move():
    model = compile_model(parse_scene(FOUNTAIN))
    state = make_state(model)
    for _ in range(100):
        state = step(model, state)
    waiting = model.body_emit_step > state.step
    assert waiting.any()
    assert np.array_equal(state.body_pos[waiting], np.tile([0, 0.5, 0], (waiting.sum(), 1)))
    assert not state.body_vel[waiting].any()


def test_emitters_are_deterministic_per_seed():
    a = compile_model(parse_scene(FOUNTAIN))
    b = compile_model(parse_scene(FOUNTAIN))
    c = compile_model(parse_scene(FOUNTAIN.replace("seed: 3", "seed: 4")))
    assert np.array_equal(a.body_vel0, b.body_vel0)
    assert not np.array_equal(a.body_vel0, c.body_vel0)


def test_blow_up_names_body_and_time():
    """The safety net behind validation: a force of 1e300 N (validation refuses more than
    1e15 N, so it is put into the compiled model here) overflows the velocity to inf."""
    import dataclasses

    scene = parse_scene("""
vrsim: 1
duration: 1.0
frame_rate: 100
dt: 0.01
bodies:
  - {name: calm, mass: 1}
  - {name: rocket, mass: 1.0e-9, forces: [{force: [1, 0, 0], start: 0.05}]}
""")
    model = compile_model(scene)
    model = dataclasses.replace(model, force_vec=np.array([[1.0e300, 0.0, 0.0]]))
    with pytest.raises(SimulationError) as info:
        run(model, make_state(model))
    assert info.value.body == "rocket"
    assert info.value.t == pytest.approx(0.06)
    assert "body 'rocket', t = 0.06 s" in str(info.value)


def test_check_state_catches_nan_and_runaways():
    model = compile_model(parse_scene("vrsim: 1\nduration: 1\nbodies: [{name: a, mass: 1}, "
                                      "{name: b, mass: 1}]\n"))
    state = make_state(model)
    check_state(model, state)
    for field, value, word in [("body_pos", np.nan, "not finite"),
                               ("body_pos", 2e12, "more than"),
                               ("body_vel", 4e8, "faster than light")]:
        arr = getattr(state, field).copy()
        arr[1, 2] = value
        with pytest.raises(SimulationError, match=word) as info:
            check_state(model, state.replace(**{field: arr}))
        assert info.value.body == "b"


@pytest.mark.parametrize("integrator", ["euler", "symplectic-euler", "rk4", "verlet", "dopri5"])
def test_force_window_is_sampled_at_step_starts_for_every_integrator(integrator):
    # 1 N on 1 kg from 0 to 0.005 s at dt = 1 ms: exactly five steps, impulse 0.005 N s,
    # also for rk4 whose later stages lie past the window's end.
    scene = parse_scene(f"""
vrsim: 1
duration: 0.01
frame_rate: 1000
dt: 0.001
integrator: {integrator}
gravity: [0, 0, 0]
bodies: [{{name: p, mass: 1, forces: [{{force: [1, 0, 0], start: 0, end: 0.005}}]}}]
""")
    model = compile_model(scene)
    assert run(model, make_state(model)).state.body_vel[0, 0] == pytest.approx(0.005, abs=1e-15)


@pytest.mark.parametrize("name", ["verlet", "dopri5"])
@pytest.mark.parametrize("shape", ["", ", shape: {type: sphere, radius: 0.1}"])
def test_second_and_fifth_order_integrators_are_exact_for_projectiles(name, shape):
    # Constant acceleration: Verlet's half kicks and Dormand-Prince (order 5) both
    # reproduce x0 + v0 t + a t^2 / 2 up to round-off, for a point mass and for a sphere
    # (a rigid body: the rotating path of the compiled step).
    model = compile_model(parse_scene(f"""
vrsim: 1
duration: 1.5
frame_rate: 100
dt: 0.01
integrator: {name}
bodies: [{{name: ball, mass: 0.2, position: {X0.tolist()}, velocity: {V0.tolist()}{shape}}}]
"""))
    state = run(model, make_state(model)).state
    assert np.abs(state.body_pos[0] - closed_form(1.5)).max() < ROUND_OFF_M
    assert np.abs(state.body_vel[0] - (V0 + G * 1.5)).max() < ROUND_OFF_M


def oscillator_error(integrator: str, dt: float, extra: str = "") -> float:
    """x'' = -x from (1, 0) (1 kg on a 1 N/m spring to a world anchor at the origin):
    x(t) = cos t; the error of the whole state (x alone can cancel amplitude against
    phase) at t = 2 s."""
    model = compile_model(parse_scene(f"""
vrsim: 1
duration: 2
frame_rate: {1.0 / dt}
dt: {dt}
integrator: {integrator}
gravity: [0, 0, 0]
{extra}
bodies: [{{name: p, mass: 1, position: [1, 0, 0]}}]
springs: [{{body: p, anchor: [0, 0, 0], stiffness: 1, rest_length: 0}}]
"""))
    state = run(model, make_state(model)).state
    return math.hypot(state.body_pos[0, 0] - math.cos(2.0),
                      state.body_vel[0, 0] + math.sin(2.0))


@pytest.mark.parametrize("name,extra", [("verlet", ""), ("rk4", ""),
                                        ("dopri5", "tolerance: 1.0")])
def test_measured_order_on_an_oscillator(name, extra):
    # dopri5 with tolerance 1 accepts every step whole, so its fixed-step order shows.
    # log2 of the error ratio tends to the order as p + O(dt): within 0.1 at these steps.
    errors = [oscillator_error(name, dt, extra) for dt in (0.1, 0.05, 0.025)]
    orders = [math.log2(errors[i] / errors[i + 1]) for i in range(2)]
    assert orders[1] == pytest.approx(ORDER[name], abs=0.1), orders


def test_a_force_window_between_step_starts_is_an_error_and_a_partial_one_a_note():
    from vrsim_cli.errors import InputError
    base = """
vrsim: 1
duration: 1
frame_rate: 10
dt: 0.1
bodies: [{name: p, mass: 1, forces: [{force: [1, 0, 0], start: START, end: END}]}]
"""
    with pytest.raises(InputError, match=r"acts on no physics step: no step starts in "
                                         r"\[0.505, 0.515\) s"):
        compile_model(parse_scene(base.replace("START", "0.505").replace("END", "0.515")))
    model = compile_model(parse_scene(base.replace("START", "0.05").replace("END", "0.25")))
    # steps start at 0.1 and 0.2 s: two whole steps (0.2 s) instead of the written 0.2 s
    # from 0.05 -- the same length, shifted, so no note; 0.05 to 0.2 gives one step
    assert model.notes == ()
    short = compile_model(parse_scene(base.replace("START", "0.05").replace("END", "0.2")))
    assert short.notes == ("bodies[0].forces[0] acts on 1 whole steps, 0.1 s instead of "
                           "0.15 s (forces act from step start to step start)",)
    exact = compile_model(parse_scene(base.replace("START", "0.1").replace("END", "0.3")))
    assert exact.notes == ()
