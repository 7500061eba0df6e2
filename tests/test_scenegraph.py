"""The scene graph stage: parent/child transforms against hand-computed matrices, drives in
closed form, the car with wheels, and keyframed velocities in the written CSV."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import SCENARIOS
from vrsim_cli.loop import run
from vrsim_cli.maths.spatial import quat_from_euler_deg, quat_multiply, quat_to_matrix
from vrsim_cli.model.keyframes import evaluate
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.stages.scenegraph import step
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.writers import open_writer


def world_state(text: str, t: float = 0.0):
    model = compile_model(parse_scene(text))
    state = make_state(model)
    state = state.replace(t=t, step=round(t / model.dt))
    return model, step(model, state)


def homogeneous(model, state, name):
    """4x4 world transform of body `name`."""
    i = model.body_index[name]
    out = np.eye(4)
    out[:3, :3] = quat_to_matrix(state.body_quat[i])
    out[:3, 3] = state.body_pos[i]
    return out


TREE = """
vrsim: 1
duration: 1
bodies:
  - {name: base, type: static, position: [1, 2, 3], euler_deg: [0, 0, 90]}
  - {name: arm, type: kinematic, parent: base, position: [1, 0, 0], euler_deg: [90, 0, 0]}
  - {name: tip, type: kinematic, parent: arm, position: [0, 0, 2]}
"""


def test_parent_child_transforms_against_hand_computed_matrices():
    model, state = world_state(TREE)
    # By hand: T_base = [Rz(90) | (1,2,3)], T_arm_local = [Rx(90) | (1,0,0)],
    # T_tip_local = [I | (0,0,2)].
    # Rz(90) Rx(90) = [[0,-1,0],[1,0,0],[0,0,1]] [[1,0,0],[0,0,-1],[0,1,0]]
    #               = [[0,0,1],[1,0,0],[0,1,0]];  p_arm = Rz(90) (1,0,0) + (1,2,3) = (1,3,3)
    # p_tip = p_arm + R_arm (0,0,2) = (1,3,3) + (2,0,0) = (3,3,3)
    arm = np.array([[0, 0, 1, 1], [1, 0, 0, 3], [0, 1, 0, 3], [0, 0, 0, 1]], float)
    tip = np.array([[0, 0, 1, 3], [1, 0, 0, 3], [0, 1, 0, 3], [0, 0, 0, 1]], float)
    # trigonometry of 90 degrees in floating point: cos(pi/2) = 6e-17, so 1e-15
    assert np.allclose(homogeneous(model, state, "arm"), arm, atol=1e-15)
    assert np.allclose(homogeneous(model, state, "tip"), tip, atol=1e-15)
    # and T_tip = T_base T_arm_local T_tip_local as a matrix product
    local_arm = np.array([[1, 0, 0, 1], [0, 0, -1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], float)
    local_tip = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 2], [0, 0, 0, 1]], float)
    product = homogeneous(model, state, "base") @ local_arm @ local_tip
    assert np.allclose(homogeneous(model, state, "tip"), product, atol=1e-15)


def test_file_order_does_not_matter():
    head, bodies = TREE.split("bodies:\n")
    lines = bodies.strip("\n").split("\n")
    reversed_tree = head + "bodies:\n" + "\n".join(reversed(lines)) + "\n"
    model, state = world_state(reversed_tree)  # children before their parents
    ref_model, reference = world_state(TREE)
    for name in ("base", "arm", "tip"):
        assert np.array_equal(state.body_pos[model.body_index[name]],
                              reference.body_pos[ref_model.body_index[name]])


CAR = """
vrsim: 1
duration: 4
frame_rate: 50
dt: 0.005
bodies:
  - name: car
    type: kinematic
    position: [1, 0.5, 2]
    drive: {speed: 2, heading_deg: 30, yaw_rate_deg: 90}
  - name: wheel
    type: kinematic
    parent: car
    position: [0.9, -0.2, 1.1]
    keyframes:
      orientation:
        times: [0, 0.3141592653589793, 0.6283185307179586, 0.9424777960769379]
        euler_deg: [[0, 0, 90], [0, -120, 90], [0, -240, 90], [0, -360, 90]]
        extrapolation: loop
"""


@pytest.mark.parametrize("t", [0.0, 0.37, 1.0, 2.9])
def test_drive_follows_the_closed_form_circle(t):
    model, state = world_state(CAR, t)
    v, r, psi0 = 2.0, math.radians(90), math.radians(30)
    psi = psi0 + r * t
    radius = v / r
    # forward (sin psi, 0, cos psi); integrating gives a circle about the centre
    # p0 + radius (cos psi0, 0, -sin psi0)
    centre = np.array([1, 0.5, 2]) + radius * np.array([math.cos(psi0), 0, -math.sin(psi0)])
    expected = centre + radius * np.array([-math.cos(psi), 0, math.sin(psi)])
    car = model.body_index["car"]
    assert np.allclose(state.body_pos[car], expected, atol=1e-14)
    assert np.allclose(state.body_vel[car], [v * math.sin(psi), 0, v * math.cos(psi)],
                       atol=1e-14)
    assert np.allclose(state.body_angvel[car], [0, r, 0], atol=1e-15)
    assert np.allclose(quat_to_matrix(state.body_quat[car]),
                       [[math.cos(psi), 0, math.sin(psi)], [0, 1, 0],
                        [-math.sin(psi), 0, math.cos(psi)]], atol=1e-15)


def test_drive_without_turning_is_a_straight_line():
    model, state = world_state(CAR.replace("yaw_rate_deg: 90", "yaw_rate_deg: 0"), 1.5)
    psi = math.radians(30)
    expected = np.array([1, 0.5, 2]) + 3.0 * np.array([math.sin(psi), 0, math.cos(psi)])
    assert np.allclose(state.body_pos[model.body_index["car"]], expected, atol=1e-15)


@pytest.mark.parametrize("t", [0.0, 0.5, 1.7])
def test_wheel_moves_with_the_car_and_spins_on_its_own(t):
    model, state = world_state(CAR, t)
    car, wheel = model.body_index["car"], model.body_index["wheel"]
    rot = quat_to_matrix(state.body_quat[car])
    offset = rot @ np.array([0.9, -0.2, 1.1])
    w_car = np.array([0, math.radians(90), 0])
    assert np.allclose(state.body_pos[wheel], state.body_pos[car] + offset, atol=1e-14)
    # rigid-body velocity of the mounting point, plus nothing (the wheel's centre is fixed
    # on the car): v = v_car + w_car x r
    assert np.allclose(state.body_vel[wheel], state.body_vel[car] + np.cross(w_car, offset),
                       atol=1e-14)
    # the spin: 120 degrees per 0.1 pi s = 20/3 rad/s about the car's x axis
    spin = rot @ np.array([20.0 / 3.0, 0, 0])
    assert np.allclose(state.body_angvel[wheel], w_car + spin, atol=1e-12)


def assert_velocity_is_derivative(track):
    """Written velocities against central differences of the written positions. The
    difference's error is |p'''| dt^2 / 6 per component; |p'''| is estimated from second
    differences of the written velocities, with a margin of 1.5 for sampling a maximum."""
    dt = track.t[1] - track.t[0]
    central = (track.pos[2:] - track.pos[:-2]) / (2 * dt)
    jerk = np.abs(np.diff(track.vel, 2, axis=0)).max() / dt ** 2
    bound = 1.5 * jerk * dt ** 2 / 6 + 1e-12
    assert np.abs(central - track.vel[1:-1]).max() <= bound
    assert bound < 0.02 * np.abs(track.vel).max()  # a bound that still says something


def run_to_csv(scenario: str, folder):
    """(model, trajectory read back) of a shipped scenario written as CSV."""
    model = compile_model(load_scene(SCENARIOS / scenario))
    out = folder / "out.csv"
    writer = open_writer(model, out, "csv")
    run(model, make_state(model), writer)
    writer.close()
    return model, read_trajectory(out)


def test_car_scenario_closes_its_circle_and_csv_velocities_are_derivatives(tmp_path):
    _, traj = run_to_csv("car.yaml", tmp_path)
    car = traj.tracks["car"]
    # one full turn of the heading in 4 s: back where it started, facing the same way
    assert np.allclose(car.pos[-1], car.pos[0], atol=1e-14)
    for name in ("car", "wheel_fl", "wheel_rr"):
        assert_velocity_is_derivative(traj.tracks[name])


def test_keyframed_velocities_in_the_csv_equal_the_curve_derivative(tmp_path):
    model, traj = run_to_csv("keyframes.yaml", tmp_path)
    rig = traj.tracks["camera_rig"]
    (_, position), = model.animation.pos_tracks
    (_, orientation, _), = model.animation.rot_tracks
    value, rate = evaluate(position, rig.t)
    assert np.array_equal(rig.pos, value) and np.array_equal(rig.vel, rate)  # bit for bit
    q, w = evaluate(orientation, rig.t)
    assert np.array_equal(rig.quat, q) and np.array_equal(rig.angvel, w)
    # and the derivative is the derivative: central differences of the written positions
    assert_velocity_is_derivative(rig)
    speed = np.linalg.norm(rig.vel, axis=1)  # arc_length: true, so constant speed
    assert np.abs(speed - speed[0]).max() < 1e-9


def test_child_of_a_dynamic_body_follows_it():
    model = compile_model(parse_scene("""
vrsim: 1
duration: 0.5
dt: 0.01
frame_rate: 100
integrator: rk4
bodies:
  - {name: ball, mass: 1, position: [0, 10, 0], velocity: [1, 0, 0]}
  - {name: cam, type: kinematic, parent: ball, position: [0, 1, 0]}
"""))
    result = run(model, make_state(model))
    s = result.state
    ball, cam = model.body_index["ball"], model.body_index["cam"]
    t = 0.5
    assert np.allclose(s.body_pos[ball], [t, 10 - 9.81 * t * t / 2, 0], atol=1e-12)
    assert np.allclose(s.body_pos[cam], s.body_pos[ball] + [0, 1, 0], atol=1e-12)
    assert np.allclose(s.body_vel[cam], s.body_vel[ball], atol=1e-12)


def test_2d_angle_track_and_drive():
    model, state = world_state("""
vrsim: 1
dimension: 2
duration: 2
bodies:
  - name: cart
    type: kinematic
    drive: {speed: 1, heading_deg: 90, yaw_rate_deg: 0}
  - name: flag
    type: kinematic
    parent: cart
    position: [1, 0]
    keyframes:
      angle_deg: {times: [0, 2], values: [0, 90]}
""", 1.0)
    cart, flag = model.body_index["cart"], model.body_index["flag"]
    # 2D forward at heading 90 degrees is +y; the cart is turned 90 degrees about z
    assert np.allclose(state.body_pos[cart], [0, 1, 0], atol=1e-15)
    assert np.allclose(state.body_pos[flag], [0, 2, 0], atol=1e-15)  # (1, 0) turned to +y
    half = math.radians(90 + 45) / 2  # cart's 90 degrees plus the flag's 45 at t = 1
    assert np.allclose(state.body_quat[flag], [math.cos(half), 0, 0, math.sin(half)],
                       atol=1e-15)
    assert np.allclose(state.body_angvel[flag], [0, 0, math.radians(45)], atol=1e-15)
    assert state.body_pos[:, 2].max() == 0.0 and state.body_vel[:, 2].max() == 0.0


def test_scenes_without_animation_skip_the_stage():
    model = compile_model(load_scene(SCENARIOS / "projectile.yaml"))
    assert model.animation is None
    assert "scenegraph" not in run(model, make_state(model)).profile
    colour_only = compile_model(parse_scene("""
vrsim: 1
duration: 0.1
bodies:
  - name: ball
    mass: 1
    keyframes: {color: {times: [0, 1], values: [[1, 0, 0], [0, 0, 1]]}}
"""))
    # a colour track changes the drawing, not the motion: a dynamic body stays dynamic
    assert colour_only.animation is not None and not colour_only.animation.has_motion
    assert "scenegraph" not in run(colour_only, make_state(colour_only)).profile


def test_first_sample_is_exact_for_a_keyframed_body():
    model = compile_model(parse_scene("""
vrsim: 1
duration: 0.1
bodies:
  - name: slider
    type: kinematic
    keyframes:
      position: {times: [0, 1], values: [[0, 0, 0], [2, 0, 0]]}
"""))
    seen = []

    class Recorder:
        def write(self, state):
            seen.append((state.t, state.body_pos[0].copy(), state.body_vel[0].copy()))

    run(model, make_state(model), Recorder())
    for t, p, v in seen:
        assert np.array_equal(p, [2 * t, 0, 0]) or np.allclose(p, [2 * t, 0, 0], atol=1e-15)
        assert np.array_equal(v, [2, 0, 0])
    assert seen[0][0] == 0.0 and len(seen) == 7


def test_world_velocities_are_the_derivatives_of_world_poses():
    """A keyframed child on a keyframed, spinning parent on a driven grandparent: the
    composed velocities against central differences of the composed poses."""
    text = """
vrsim: 1
duration: 3
bodies:
  - name: car
    type: kinematic
    drive: {speed: 1.5, heading_deg: 20, yaw_rate_deg: -40}
  - name: turret
    type: kinematic
    parent: car
    position: [0, 1, 0]
    keyframes:
      orientation: {times: [0, 1, 3], euler_deg: [[0, 0, 0], [10, 60, 0], [0, 200, 30]],
                    interpolation: squad}
  - name: barrel
    type: kinematic
    parent: turret
    keyframes:
      position: {times: [0, 1, 2, 3], values: [[0, 0, 1], [0, 0.2, 2], [0.5, 0, 1.5], [0, 0, 1]],
                 interpolation: catmull-rom}
"""
    model = compile_model(parse_scene(text))
    state0 = make_state(model)

    def at(t):
        return step(model, state0.replace(t=t))

    h = 1e-5
    for t in (0.4, 1.3, 2.2):
        s, ahead, behind = at(t), at(t + h), at(t - h)
        fd_vel = (ahead.body_pos - behind.body_pos) / (2 * h)
        # central differences: error |p'''| h^2 / 6 ~ 1e-9 here, round-off eps |p| / h ~ 1e-10
        assert np.allclose(s.body_vel, fd_vel, atol=1e-7)
        # angular velocity from the quaternions: w = 2 dq/dt q*
        dq = (ahead.body_quat - behind.body_quat) / (2 * h)
        conj = s.body_quat * np.array([1, -1, -1, -1])
        fd_w = 2 * quat_multiply(dq, conj)[:, 1:]
        # squad's own rate is a central difference with step 1e-5 in s: 1e-7 relative
        assert np.allclose(s.body_angvel, fd_w, atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.lists(st.floats(-5, 5), min_size=3, max_size=3),
                          st.lists(st.floats(-180, 180), min_size=3, max_size=3)),
                min_size=2, max_size=4))
def test_chains_compose_like_homogeneous_matrices(chain):
    lines = ["vrsim: 1", "duration: 1", "bodies:"]
    for k, (pos, euler) in enumerate(chain):
        parent = f", parent: n{k - 1}" if k else ""
        lines.append(f"  - {{name: n{k}, type: kinematic{parent}, position: {pos}, "
                     f"euler_deg: {euler}}}")
    model, state = world_state("\n".join(lines) + "\n")
    expected = np.eye(4)
    for k, (pos, euler) in enumerate(chain):
        local = np.eye(4)
        local[:3, :3] = quat_to_matrix(quat_from_euler_deg(euler))
        local[:3, 3] = pos
        expected = expected @ local
        # products of up to 4 rotations and offsets up to 5 m: round-off below 1e-13
        assert np.allclose(homogeneous(model, state, f"n{k}"), expected, atol=1e-13)


def test_cli_profile_shows_the_scene_graph_stage(invoke, tmp_path):
    result = invoke("run", SCENARIOS / "car.yaml", "--profile", "-o", tmp_path / "car.csv")
    assert result.exit_code == 0, result.output
    assert any(line.startswith("scenegraph ") for line in result.stdout.splitlines())
    result = invoke("run", SCENARIOS / "projectile.yaml", "--profile", "-o",
                    tmp_path / "p.csv")
    assert result.exit_code == 0 and "scenegraph" not in result.stdout
