"""Observer navigation (slide 5.1): the walk table, walk/fly/examine against closed forms,
terrain, steps, falling and walls."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import SCENARIOS
from vrsim_cli.loop import run
from vrsim_cli.maths.spatial import quat_rotate
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.observer import input_at
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.tools.walk_table import format_table, slide_rows

# Slide 5.1, the walk table (errata: the slide's column labels are swapped).
SLIDE_TABLE = """\
| -1.00 | -1.00 | (-141,-141) | -100 | (285,285) | (115,81) |
| -0.99 | -0.99 | (-162,-113) | -99 | (269,274) | (128,59) |
| -0.96 | -0.96 | (-173,-81) | -96 | (252,266) | (136,37) |
| -0.91 | -0.91 | (-175,-48) | -91 | (234,261) | (140,15) |
| -0.84 | -0.84 | (-166,-18) | -84 | (218,259) | (141,-4) |
| -0.75 | -0.75 | (-149,5) | -75 | (203,260) | (139,-23) |
| -0.64 | -0.64 | (-126,21) | -64 | (190,262) | (136,-38) |
| -0.51 | -0.51 | (-98,27) | -51 | (180,265) | (132,-50) |
| -0.36 | -0.36 | (-67,25) | -36 | (173,267) | (128,-58) |
| -0.19 | -0.19 | (-34,15) | -19 | (170,269) | (126,-63) |
| 0.00 | 0.00 | (0,0) | 0 | (170,269) | (126,-63) |
"""


def frames(text: str):
    """Run a scene; return (model, [state at the end of every frame])."""
    model = compile_model(parse_scene(text))
    ends = []
    run(model, make_state(model), on_frame=ends.append)
    return model, ends


def test_walk_table_reproduces_all_eleven_rows_of_the_slide(invoke):
    table = format_table(slide_rows())
    assert table.splitlines()[0] == ("| alpha | beta | v(alpha) (v_z, v_x) | gamma(beta) | "
                                     "V_new (z, x) | d_new (z, x) |")
    assert "\n".join(table.splitlines()[2:]) + "\n" == SLIDE_TABLE
    assert invoke("walk-table").stdout == table


def test_walk_table_truncates_toward_zero():
    row = slide_rows()[0]
    assert row.position_zx[0] == pytest.approx(285.857864376269)  # printed 285, not 286
    assert slide_rows()[4].direction_zx[1] == pytest.approx(-4.9355341556672)  # printed -4


def test_vrsim_run_on_the_shipped_scene_gives_the_table_trajectory(invoke, tmp_path):
    out = tmp_path / "walk.csv"
    assert invoke("run", SCENARIOS / "walk-table.yaml", "-o", out).exit_code == 0
    track = read_trajectory(out).tracks["observer"]
    rows = slide_rows()
    assert len(track.t) == 12
    for k, row in enumerate(rows, start=1):
        assert (track.pos[k, 2], track.pos[k, 0]) == row.position_zx  # bit-identical
        assert (track.vel[k, 2], track.vel[k, 0]) == row.v_zx
    assert invoke("walk-table", "--scene", SCENARIOS / "walk-table.yaml").stdout == \
        invoke("walk-table").stdout


def test_walk_table_parameters_and_formats(invoke):
    result = invoke("walk-table", "--alpha", "1,1", "--beta", "0,0", "--v-max", "10",
                    "--dt", "0.5", "--position", "0", "0", "--direction", "1", "0",
                    "--format", "csv", "--exact")
    assert result.exit_code == 0
    assert result.stdout.splitlines() == [
        "alpha,beta,v_z,v_x,gamma,V_z,V_x,d_z,d_x",
        "1.00,0.00,10.0,0.0,0,5.0,0.0,1.0,0.0",
        "1.00,0.00,10.0,0.0,0,10.0,0.0,1.0,0.0"]
    bad = invoke("walk-table", "--alpha", "1.5")
    assert bad.exit_code == 2 and "values must lie in [-1, 1]" in bad.stderr
    for args in (["--v-max", "nan"], ["--dt", "20"], ["--alpha", ""], ["--direction", "0", "0"]):
        result = invoke("walk-table", *args)
        assert result.exit_code == 2 and "Invalid value" in result.stderr, args


def test_walk_table_velocity_is_the_steps_velocity_not_a_difference_quotient(invoke):
    # v = alpha * v_max * d_hat = -0.97 * 200 = -194 exactly; (V_new - V) / dt would give
    # -193.99999999999977, which truncates to -193.
    result = invoke("walk-table", "--alpha", "-0.97", "--beta", "0", "--direction", "1", "0")
    assert "| -0.97 | 0.00 | (-194,0) | 0 | (280,300) | (1,0) |" in result.stdout


WALK = """
vrsim: 1
duration: {duration}
frame_rate: {rate}
dt: {dt}
observer: {{mode: walk, position: [0, 1.6, 0], direction: [0, 0, -1], v_max: 1.5,
           gamma_max: 45}}
input: {{mouse: [{{t: 0, alpha: 0.8, beta: 0.5}}]}}
"""


def test_walk_with_constant_beta_is_a_regular_polygon_on_a_circle():
    # Each frame moves a chord s = |v| dt and turns by theta = gamma dt, so the positions
    # are vertices of a regular polygon with circumradius R = s / (2 sin(theta / 2)).
    model, ends = frames(WALK.format(duration=8, rate=50, dt=0.02))
    pts = np.array([s.observer_pos for s in ends])
    s = 0.8 * 1.5 * 0.02
    theta = math.radians(0.5 * 45) * 0.02
    radius = s / (2 * math.sin(theta / 2))
    # circumcentre of the first three vertices (independent of the radius formula)
    a, b, c = pts[0, [0, 2]], pts[1, [0, 2]], pts[2, [0, 2]]
    d = 2 * (a[0] * (b[1] - c[1]) + b[0] * (c[1] - a[1]) + c[0] * (a[1] - b[1]))
    ux = ((a @ a) * (b[1] - c[1]) + (b @ b) * (c[1] - a[1]) + (c @ c) * (a[1] - b[1])) / d
    uy = ((a @ a) * (c[0] - b[0]) + (b @ b) * (a[0] - c[0]) + (c @ c) * (b[0] - a[0])) / d
    dist = np.hypot(pts[:, 0] - ux, pts[:, 2] - uy)
    assert dist == pytest.approx(radius, rel=1e-9)  # 400 frames of round-off, R ~ 1.9 m
    assert np.all(pts[:, 1] == 1.6)  # no geometry: the slide's plane walk keeps its height


def test_fly_moves_along_the_full_view_direction_and_pitches():
    text = """
vrsim: 1
duration: 1
frame_rate: 10
dt: 0.1
observer: {mode: fly, position: [0, 2, 0], direction: [0, 3, -4], v_max: 5, pitch_max: 10}
input: {per_frame: [[1, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, -1]]}
"""
    model, ends = frames(text)
    # frames 1-2: v = 5 * (0, 0.6, -0.8): a real y component
    assert ends[1].observer_pos == pytest.approx([0, 2 + 2 * 0.1 * 3.0, -2 * 0.1 * 4.0])
    assert ends[0].observer_vel == pytest.approx([0, 3.0, -4.0])
    # frame 3 pitches up by 1 degree, frame 4 back down
    up_angle = lambda d: math.degrees(math.acos(d[1] / np.linalg.norm(d)))
    start = up_angle([0, 3, -4])
    assert up_angle(ends[2].observer_dir) == pytest.approx(start - 1.0, abs=1e-9)
    assert up_angle(ends[3].observer_dir) == pytest.approx(start, abs=1e-9)


EXAMINE = """
vrsim: 1
duration: {duration}
frame_rate: 100
dt: 0.01
observer: {{mode: examine, position: [0.3, 1.2, 4.0], look_at: [0, 1, 0], gamma_max: 40,
           delta_max: 70, examine_axes: {axes}}}
input: {{mouse: [{{t: 0, alpha: {alpha}, beta: {beta}}}]}}
"""


def test_examine_view_axes_keep_the_distance_over_ten_thousand_frames():
    model, ends = frames(EXAMINE.format(duration=100, axes="view", alpha=0.3, beta=0.7))
    assert len(ends) == 10_000
    r0 = np.linalg.norm(np.array([0.3, 1.2, 4.0]) - [0, 1, 0])
    r = np.array([np.linalg.norm(s.observer_pos - [0, 1, 0]) for s in ends])
    assert np.abs(r - r0).max() < 1e-12 * r0
    # the camera keeps looking at L
    for s in ends[::997]:
        forward = quat_rotate(s.observer_quat, [0, 0, -1])
        assert forward == pytest.approx((np.array([0, 1, 0]) - s.observer_pos) / r0, abs=1e-12)


def test_examine_world_axes_rotate_about_y_in_closed_form():
    model, ends = frames(EXAMINE.format(duration=1, axes="world", alpha=0, beta=0.5))
    offset0 = np.array([0.3, 0.2, 4.0])
    angle = math.radians(35.0) * 1.0  # beta * delta_max * t
    c, s = math.cos(angle), math.sin(angle)
    expected = np.array([offset0[0] * c + offset0[2] * s, 0.2, offset0[2] * c - offset0[0] * s])
    assert ends[-1].observer_pos - [0, 1, 0] == pytest.approx(expected, abs=1e-12)


def test_examine_world_axes_degenerate_when_looking_along_x_view_axes_do_not():
    # The slide's problem: rotating about the world x axis does nothing when the view
    # direction is the x axis; rotating about the camera's own x axis pitches the view.
    text = """
vrsim: 1
duration: 0.5
frame_rate: 100
dt: 0.01
observer: {mode: examine, position: [-3, 0, 0], look_at: [0, 0, 0], gamma_max: 60,
           examine_axes: AXES}
input: {mouse: [{t: 0, alpha: 1, beta: 0}]}
"""
    _, world = frames(text.replace("AXES", "world"))
    _, view = frames(text.replace("AXES", "view"))
    assert world[-1].observer_pos == pytest.approx([-3, 0, 0], abs=1e-12)
    pitched = view[-1].observer_pos
    assert math.degrees(math.atan2(abs(pitched[1]), -pitched[0])) == pytest.approx(30, abs=1e-9)


GROUND = """
vrsim: 1
duration: {duration}
frame_rate: 50
dt: 0.02
observer: {{mode: walk, position: {position}, direction: [1, 0, 0], v_max: 1, eye_height: 1.6,
           step_height: 0.3, radius: 0.25, walls: {walls}}}
input: {{mouse: [{{t: 0, alpha: {alpha}, beta: 0}}]}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0], offset: 0}}}}
{extra}
"""


def ground(duration=2.0, position="[0, 1.6, 0]", alpha=1.0, walls="slide", extra=""):
    return frames(GROUND.format(duration=duration, position=position, alpha=alpha,
                                walls=walls, extra=extra))


def test_walker_climbs_a_step_lower_than_step_height():
    extra = "  - {name: step, type: static, shape: {type: box, size: [2, 0.2, 2]}, " \
            "position: [1.5, 0.1, 0]}"
    _, ends = ground(extra=extra)
    assert ends[-1].observer_pos[0] == pytest.approx(2.0)  # 2 s at 1 m/s: not blocked
    assert ends[-1].observer_pos[1] == pytest.approx(0.2 + 1.6, abs=1e-12)  # on the step


@pytest.mark.parametrize("height,stop_x", [
    # A wall-like step: the capsule (radius 0.25) meets the face x = 0.5 and stops at 0.25.
    (0.9, 0.25),
    # A 0.5 m step: the capsule's lowest sphere (centre 0.3 + 0.25 = 0.55 m up) meets the
    # step's top edge (0.5, 0.5): it touches at x = 0.5 - sqrt(0.25^2 - 0.05^2).
    (0.5, 0.5 - math.sqrt(0.25 ** 2 - 0.05 ** 2)),
])
def test_a_step_higher_than_step_height_blocks(height, stop_x):
    extra = f"  - {{name: step, type: static, shape: {{type: box, size: [2, {height}, 2]}}, " \
            f"position: [1.5, {height / 2}, 0]}}"
    _, ends = ground(extra=extra)
    x = np.array([s.observer_pos[0] for s in ends])
    # The horizontal push-out is exact against a face; against the curved contact with an
    # edge it stops short by less than 1e-4 m (measured 3.8e-5 m at 1 m/s and 50 Hz).
    assert x.max() <= stop_x + 1e-12 and x[-1] >= stop_x - 1e-4
    assert all(s.observer_pos[1] == 1.6 for s in ends)  # never climbed


def test_walking_off_a_ledge_falls_under_gravity_and_lands():
    # Standing on a 2 m platform whose edge is at x = 0.5; the ground is at y = 0.
    extra = "  - {name: platform, type: static, shape: {type: box, size: [4, 2, 4]}, " \
            "position: [-1.5, 1, 0]}"
    model, ends = ground(duration=3.0, position="[0, 3.6, 0]", extra=extra)
    heights = np.array([s.observer_pos[1] for s in ends])
    leaving = int(np.argmax(heights < 3.6 - 1e-12))
    # Semi-implicit Euler from rest: after k frames the drop is g dt^2 k (k + 1) / 2.
    dt, g = 0.02, 9.81
    k = np.arange(1, 20)
    expected = 3.6 - g * dt * dt * k * (k + 1) / 2
    falling = heights[leaving:leaving + 19]
    in_air = expected > 1.6
    assert falling[in_air] == pytest.approx(expected[in_air], abs=1e-12)
    assert heights[-1] == 1.6  # landed on the ground, eye height above it


def test_wall_sliding_removes_the_normal_component():
    # A wall whose face is the plane x = 1; the observer touches it (distance = radius)
    # and pushes diagonally into it: only the tangential part of the move remains.
    extra = "  - {name: wall, type: static, shape: {type: box, size: [1, 3, 20]}, " \
            "position: [1.5, 1.5, 0]}"
    text = GROUND.format(duration=0.2, position="[0.75, 1.6, 0]", alpha=1.0, walls="slide",
                         extra=extra).replace("direction: [1, 0, 0]", "direction: [1, 0, -1]")
    _, ends = frames(text)
    v = np.array([1.0, 0.0, -1.0]) / math.sqrt(2)
    n = np.array([-1.0, 0.0, 0.0])
    tangential = v - np.dot(v, n) * n
    for k, state in enumerate(ends, start=1):
        assert state.observer_pos == pytest.approx(
            np.array([0.75, 1.6, 0]) + k * 0.02 * tangential, abs=1e-9)
    _, stopped = frames(text.replace("walls: slide", "walls: stop"))
    assert stopped[-1].observer_pos == pytest.approx([0.75, 1.6, 0], abs=1e-12)


def test_tracker_sets_the_pose(write_scene, tmp_path):
    (tmp_path / "head.csv").write_text(
        "t,px,py,pz,qw,qx,qy,qz\n0,0,1.7,0,1,0,0,0\n0.5,1,1.7,0,0,0,1,0\n")
    text = """
vrsim: 1
duration: 1
frame_rate: 4
dt: 0.25
observer: {mode: tracked}
input: {tracker: head.csv, interpolation: INTERP}
"""
    for interp, x_at_quarter in (("hold", 0.0), ("linear", 0.5)):
        model = compile_model(load_scene(write_scene(text.replace("INTERP", interp))))
        ends = []
        run(model, make_state(model), on_frame=ends.append)
        # frame 1 starts at t = 0.25
        assert ends[1].observer_pos == pytest.approx([x_at_quarter, 1.7, 0])
        assert ends[2].observer_quat == pytest.approx([0, 0, 1, 0])
    assert ends[1].observer_quat == pytest.approx([math.sqrt(0.5), 0, math.sqrt(0.5), 0])


def test_mouse_samples_hold_or_interpolate():
    text = """
vrsim: 1
duration: 1
frame_rate: 4
dt: 0.25
observer: {mode: walk, v_max: 1}
input: {mouse: [{t: 0.25, alpha: 0.2, beta: 0}, {t: 0.75, alpha: 0.6, beta: 0}],
        interpolation: INTERP}
"""
    def alphas(interp):
        inputs = compile_model(parse_scene(text.replace("INTERP", interp))).inputs
        return [input_at(inputs, k, k * 0.25)[0][0] for k in range(4)]

    hold, lin = np.array(alphas("hold")), np.array(alphas("linear"))
    assert hold.tolist() == [0.0, 0.2, 0.2, 0.6]
    assert lin.tolist() == pytest.approx([0.0, 0.2, 0.4, 0.6])


def test_replay_of_a_recorded_run_is_bit_identical(write_scene, tmp_path, invoke):
    recorded = write_scene(WALK.format(duration=2, rate=50, dt=0.02).replace(
        "[{t: 0, alpha: 0.8, beta: 0.5}]",
        "[{t: 0, alpha: 0.8, beta: 0.5}, {t: 0.7, alpha: -0.3, beta: -1}]"), "rec.yaml")
    assert invoke("run", recorded, "-o", tmp_path / "rec.mcap").exit_code == 0
    replay = write_scene(WALK.format(duration=2, rate=50, dt=0.02).replace(
        "{mouse: [{t: 0, alpha: 0.8, beta: 0.5}]}", "{replay: rec.mcap}"), "replay.yaml")
    assert invoke("run", replay, "-o", tmp_path / "replay.csv").exit_code == 0
    assert invoke("run", recorded, "-o", tmp_path / "rec.csv").exit_code == 0
    a = read_trajectory(tmp_path / "rec.csv").tracks["observer"]
    b = read_trajectory(tmp_path / "replay.csv").tracks["observer"]
    assert np.array_equal(a.pos, b.pos) and np.array_equal(a.quat, b.quat)


def test_observer_is_an_entity_in_every_output(invoke, tmp_path):
    out = tmp_path / "w.mcap"
    assert invoke("run", SCENARIOS / "walk-table.yaml", "-o", out).exit_code == 0
    traj = read_trajectory(out)
    assert list(traj.tracks) == ["observer"]
    assert ("/vrsim/input", "vrsim.Input", 11) in traj.channels


@pytest.mark.parametrize("inputs,message", [
    ("{mouse: [{t: 0, alpha: 1.5, beta: 0}]}", ":7:31: input.mouse[0].alpha: must be <= 1, got 1.5"),
    ("{mouse: [{t: 1, alpha: 0, beta: 0}, {t: 0.5, alpha: 0, beta: 0}]}",
     ":7:48: input.mouse[1].t: times must increase strictly: 0.5 after 1"),
    ("{file: nope.csv}", ":7:15: input.file: file 'nope.csv' not found"),
    ("{per_frame: [[0, 0]], mouse: [{t: 0, alpha: 0, beta: 0}]}",
     ":7:9: input.per_frame: give one input source, not mouse and per_frame"),
])
def test_bad_input_is_located(invoke, write_scene, inputs, message):
    text = WALK.format(duration=1, rate=10, dt=0.1).replace(
        "{mouse: [{t: 0, alpha: 0.8, beta: 0.5}]}", inputs)
    result = invoke("run", write_scene(text))
    assert result.exit_code == 2 and message in result.stderr, result.stderr


@pytest.mark.parametrize("content,message", [
    ("t,x,y\n0,1,2\n", "head.csv:1:1: unexpected header"),
    ("t,px,py,pz,qw,qx,qy,qz\n0,0,0,0,1,0,0,zero\n", "head.csv:2:1: a column holds something"),
    ("t,px,py,pz,qw,qx,qy,qz\n1,0,0,0,1,0,0,0\n0,0,0,0,1,0,0,0\n",
     "head.csv:3:1: times must increase strictly"),
    (b"\xff\xfe\x00junk", "cannot read 'head.csv'"),
])
def test_unreadable_tracker_file_is_located(invoke, write_scene, tmp_path, content, message):
    path = tmp_path / "head.csv"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    scene = write_scene("vrsim: 1\nduration: 1\nobserver: {mode: tracked}\n"
                        "input: {tracker: head.csv}\n")
    result = invoke("run", scene)
    assert result.exit_code == 2 and message in result.stderr, result.stderr


def test_attached_observer_rides_its_body_exactly(invoke, tmp_path):
    out = tmp_path / "k.csv"
    assert invoke("run", SCENARIOS / "keyframes.yaml", "-o", out).exit_code == 0
    tracks = read_trajectory(out).tracks
    rig, observer = tracks["camera_rig"], tracks["observer"]
    for field in ("t", "pos", "quat", "vel", "angvel"):
        assert np.array_equal(getattr(rig, field), getattr(observer, field)), field
    # the rig at (0, 1.6, 4) looks along -z at the lamp's axis; the lamp's centre is 0.6 m
    # lower at 4 m distance: atan(0.6 / 4) = 8.5 degrees below the view direction
    forward = quat_rotate(observer.quat[0], [0, 0, -1])
    to_lamp = np.array([0, 1, 0]) - observer.pos[0]
    assert np.degrees(np.arccos(forward @ to_lamp / np.linalg.norm(to_lamp))) < 9


@pytest.mark.parametrize("observer,message", [
    ("{mode: attached}", "observer: mode attached needs the body to ride on (add body: NAME)"),
    ("{mode: attached, body: rigg}", "observer.body: no body named 'rigg' (did you mean 'rig'?)"),
    ("{mode: walk, body: rig}", "observer.body: body is for mode: attached"),
])
def test_attached_observer_errors(invoke, write_scene, observer, message):
    scene = write_scene(f"vrsim: 1\nduration: 1\nobserver: {observer}\n"
                        "bodies: [{name: rig, type: kinematic}]\n")
    result = invoke("validate", scene)
    assert result.exit_code == 2 and message in result.stderr, result.stderr
