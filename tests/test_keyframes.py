"""Keyframe tracks against independent truth: keys, slopes, hand-computed Hermite values,
measured derivative jumps, rotation geometry, HSV, extrapolation and arc length."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.maths.spatial import quat_from_axis_angle, quat_multiply
from vrsim_cli.model.keyframes import TrackError, compile_track, evaluate, hsv_to_rgb, rgb_to_hsv

TIMES = [0.0, 1.0, 3.0, 3.5, 5.0]  # uneven on purpose: timing bugs show up
POINTS = [[0.0, 0.0, 0.0], [1.0, 0.5, 0.0], [1.0, 2.0, -1.0], [3.0, 1.0, 1.0], [2.0, 0.0, 0.0]]
CUBIC = ["catmull-rom", "kochanek-bartels"]


def track(interpolation="linear", times=TIMES, values=POINTS, kind="vector", **extra):
    return compile_track({"times": times, "values": values, "interpolation": interpolation,
                          **extra}, kind)


def one_sided_slopes(tr, t, h=1e-4):
    """Second-order one-sided difference quotients left and right of t (error O(h^2))."""
    c = lambda x: evaluate(tr, x)[0]  # noqa: E731
    left = (3 * c(t) - 4 * c(t - h) + c(t - 2 * h)) / (2 * h)
    right = (-3 * c(t) + 4 * c(t + h) - c(t + 2 * h)) / (2 * h)
    return left, right


# ----------------------------------------------------------------------------- keys


HERMITE = dict(in_tangents=[[1, 0, 0]] * 5, out_tangents=[[0, 1, 0]] * 5)


@pytest.mark.parametrize("mode,extra", [("step", {}), ("linear", {}), ("catmull-rom", {}),
                                        ("kochanek-bartels", dict(tension=0.3, continuity=-0.5,
                                                                  bias=0.7)),
                                        ("hermite", HERMITE)])
def test_every_vector_mode_hits_every_key_exactly(mode, extra):
    tr = track(mode, **extra)
    value, _ = evaluate(tr, np.array(TIMES))
    assert np.array_equal(value, np.array(POINTS))  # bit for bit, as slide 5.2 demands
    for t, p in zip(TIMES, POINTS):
        assert np.array_equal(evaluate(tr, t)[0], p)


EULER = [[0, 0, 0], [0, 90, 0], [90, 90, 0], [0, 0, 170], [10, 20, 30]]


@pytest.mark.parametrize("mode", ["step", "slerp", "linear", "squad"])
def test_every_rotation_mode_hits_every_key(mode):
    from vrsim_cli.maths.spatial import quat_from_euler_deg
    tr = compile_track({"times": TIMES, "euler_deg": EULER, "interpolation": mode}, "rotation")
    for t, e in zip(TIMES, EULER):
        q = evaluate(tr, t)[0]
        key = quat_from_euler_deg(e)
        # the same rotation; the sign may be flipped to keep the path on the short arc
        assert np.array_equal(q, key) or np.array_equal(q, -key)


def test_rgb_keys_are_exact_and_hsv_keys_exact_to_round_off():
    colors = [[1, 0, 0], [0.2, 0.8, 0.1], [0.5, 0.5, 0.5], [0, 0, 1], [0.9, 0.1, 0.6]]
    rgb = track("catmull-rom", values=colors, kind="color")
    hsv = track("catmull-rom", values=colors, kind="color", space="hsv")
    keys = np.hstack([colors, np.ones((5, 1))])
    assert np.array_equal(evaluate(rgb, np.array(TIMES))[0], keys)
    # RGB -> HSV -> RGB costs a few roundings: 4 ulp of 1.
    assert np.abs(evaluate(hsv, np.array(TIMES))[0] - keys).max() <= 4 * 2.0 ** -52


# ----------------------------------------------------------------------------- linear


def test_linear_is_the_slide_formula_with_constant_velocity_between_keys():
    tr = track("linear")
    t = 1.5  # s = 0.25 in [t_1, t_2)
    expected = 0.75 * np.array(POINTS[1]) + 0.25 * np.array(POINTS[2])
    assert np.array_equal(evaluate(tr, t)[0], expected)
    slope = (np.array(POINTS[2]) - POINTS[1]) / 2.0
    rates = evaluate(tr, np.linspace(1.0, 2.999, 7))[1]
    assert np.allclose(rates, slope, rtol=0, atol=1e-15)


@pytest.mark.parametrize("i", [1, 2, 3])
def test_linear_velocity_jump_at_a_key_is_the_difference_of_the_slopes(i):
    tr = track("linear")
    p, t = np.array(POINTS), TIMES
    slope_before = (p[i] - p[i - 1]) / (t[i] - t[i - 1])
    slope_after = (p[i + 1] - p[i]) / (t[i + 1] - t[i])
    left, right = one_sided_slopes(tr, t[i])
    # linear pieces: the difference quotients are exact up to round-off, eps * |P| / h
    assert np.allclose(left, slope_before, atol=1e-10)
    assert np.allclose(right, slope_after, atol=1e-10)
    assert np.allclose(right - left, slope_after - slope_before, atol=1e-10)
    assert np.abs(slope_after - slope_before).max() > 0.5  # the flaw the slide notes


# ----------------------------------------------------------------------------- cubic


@pytest.mark.parametrize("mode", CUBIC)
def test_catmull_rom_and_kb_with_zero_parameters_are_c1(mode):
    tr = track(mode)
    for t in TIMES[1:-1]:
        left, right = one_sided_slopes(tr, t)
        # O(h^2) difference error with h = 1e-4 and |C'''| of order 10: about 1e-7.
        assert np.abs(right - left).max() < 1e-6
        linear_left, linear_right = one_sided_slopes(track("linear"), t)
        assert np.abs(linear_right - linear_left).max() > 0.5  # the test can see a jump
        # and the reported rate is the same from both sides
        assert np.allclose(evaluate(tr, t - 1e-9)[1], evaluate(tr, t)[1], atol=1e-7)


def test_catmull_rom_tangent_is_the_neighbour_chord_over_its_time():
    tr = track("catmull-rom")
    p, t = np.array(POINTS), TIMES
    for i in (1, 2, 3):
        chord = (p[i + 1] - p[i - 1]) / (t[i + 1] - t[i - 1])
        assert np.allclose(evaluate(tr, t[i])[1], chord, rtol=0, atol=1e-14)


def test_kochanek_bartels_tangents_by_hand():
    # Scalar keys 0, 1, 3 at t = 0, 1, 2 (uniform: the paper's formulas apply as printed).
    # tension 0.5: both tangents at key 1 are 0.5 * (0.5 * 1 + 0.5 * 2) = 0.75.
    tense = compile_track({"times": [0, 1, 2], "values": [0, 1, 3],
                           "interpolation": "kochanek-bartels", "tension": 0.5})
    assert evaluate(tense, 1.0)[1] == pytest.approx(0.75, abs=1e-14)
    # continuity 0.5: out = 0.75 * 1 + 0.25 * 2 = 1.25, in = 0.25 * 1 + 0.75 * 2 = 1.75
    kinked = compile_track({"times": [0, 1, 2], "values": [0, 1, 3],
                            "interpolation": "kochanek-bartels", "continuity": 0.5})
    left, right = one_sided_slopes(kinked, 1.0)
    assert left == pytest.approx(1.75, abs=1e-7) and right == pytest.approx(1.25, abs=1e-7)
    # bias 1: only the incoming chord counts: 0.5 * 2 * 1 = 1 on both sides
    biased = compile_track({"times": [0, 1, 2], "values": [0, 1, 3],
                            "interpolation": "kochanek-bartels", "bias": 1.0})
    left, right = one_sided_slopes(biased, 1.0)
    assert left == pytest.approx(1.0, abs=1e-7) and right == pytest.approx(1.0, abs=1e-7)


def test_kochanek_bartels_parameters_per_key():
    # a kink only at key 1 (continuity 0.5 there), C1 at key 2
    tr = compile_track({"times": [0, 1, 2, 3], "values": [0, 1, 3, 4],
                        "interpolation": "kochanek-bartels", "continuity": [0, 0.5, 0, 0]})
    left, right = one_sided_slopes(tr, 1.0)
    assert left == pytest.approx(1.75, abs=1e-7) and right == pytest.approx(1.25, abs=1e-7)
    left, right = one_sided_slopes(tr, 2.0)
    assert abs(right - left) < 1e-7  # (4 - 1) / 2 on both sides
    assert right == pytest.approx(1.5, abs=1e-7)
    with pytest.raises(TrackError) as info:
        compile_track({"times": [0, 1], "values": [0, 1], "interpolation": "kochanek-bartels",
                       "bias": [0, 0, 1]})
    assert info.value.issues[0][0] == ("bias",)


def test_gltf_cubicspline_by_hand():
    # glTF 2.0 spec, Appendix C: v0 = 1, b0 = 2 (out), a1 = -1 (in), v1 = 3, td = 2.
    # At s = 0.5: (2/8 - 3/4 + 1) 1 + 2 (1/8 - 1/2 + 1/2) 2 + (-2/8 + 3/4) 3
    #           + 2 (1/8 - 1/4) (-1) = 0.5 + 0.5 + 1.5 + 0.25 = 2.75.
    tr = compile_track({"times": [0, 2], "values": [1, 3], "interpolation": "hermite",
                        "in_tangents": [5, -1], "out_tangents": [2, 7]})
    assert evaluate(tr, 1.0)[0] == pytest.approx(2.75, abs=1e-15)
    assert evaluate(tr, 0.0)[1] == pytest.approx(2.0, abs=1e-15)  # dp/dt = b0 at the start
    assert evaluate(tr, 2.0)[1] == pytest.approx(-1.0, abs=1e-15)  # = a1 at the end


def test_hermite_colour_tangents_without_alpha():
    tr = compile_track({"times": [0, 1], "values": [[0, 0, 0], [1, 0.5, 0]],
                        "interpolation": "hermite", "in_tangents": [[0, 0, 0], [0, 0, 0]],
                        "out_tangents": [[0, 0, 0], [0, 0, 0]]}, "color")
    # zero tangents: smoothstep 3s^2 - 2s^3 = 0.5 at s = 0.5; alpha stays 1
    assert np.allclose(evaluate(tr, 0.5)[0], [0.5, 0.25, 0, 1], atol=1e-15)


def test_closed_loop_catmull_rom_is_c1_across_the_seam():
    square = [[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]]
    tr = compile_track({"times": [0, 1, 2, 3, 4], "values": square,
                        "interpolation": "catmull-rom", "extrapolation": "loop"})
    left, right = one_sided_slopes(tr, 4.0)  # the right side is the next lap's start
    assert np.abs(right - left).max() < 1e-6  # O(h^2) differences, as in the C1 test
    assert np.abs(evaluate(tr, 4.0 + 1e-12)[1] - evaluate(tr, 4.0)[1]).max() < 1e-9
    assert np.allclose(evaluate(tr, 0.0)[1], [0.5, -0.5])  # (P_1 - P_3) / 2 s, wrapped


# ----------------------------------------------------------------------------- rotations


def rotation_angle(a, b):
    """Angle (rad) of the rotation taking quaternion a to b."""
    return 2.0 * math.acos(min(1.0, abs(float(np.dot(a, b)))))


def test_slerp_is_unit_length_with_constant_angular_speed_on_the_short_arc():
    q0 = [1.0, 0.0, 0.0, 0.0]
    q1 = quat_from_axis_angle([0, 0, 1], math.radians(270))  # the short way is -90 degrees
    tr = compile_track({"times": [0, 2], "values": [q0, list(q1)]}, "rotation")
    t = np.linspace(0.0, 2.0, 201)
    q, w = evaluate(tr, t)
    assert np.abs(np.linalg.norm(q, axis=1) - 1.0).max() < 4e-16  # 2 ulp
    steps = [rotation_angle(q[k], q[k + 1]) for k in range(200)]
    speed = np.array(steps) / 0.01
    expected = math.radians(90) / 2.0  # rad/s along the short arc
    assert np.abs(speed - expected).max() < 1e-9  # acos near 1 loses ~1e-8 of 1e-2 rad
    assert np.allclose(w, [0.0, 0.0, -expected], atol=1e-15)  # about -z: the short way


def test_squad_equals_slerp_on_one_axis_and_hits_keys_smoothly():
    angles = [0, 40, 80, 120]
    keys = [list(quat_from_axis_angle([0, 1, 0], math.radians(a))) for a in angles]
    squad = compile_track({"times": [0, 1, 2, 3], "values": keys,
                           "interpolation": "squad"}, "rotation")
    slerp = compile_track({"times": [0, 1, 2, 3], "values": keys}, "rotation")
    t = np.linspace(0, 3, 61)
    # evenly spaced keys about one axis: squad's control points are the keys themselves
    assert np.allclose(evaluate(squad, t)[0], evaluate(slerp, t)[0], atol=1e-15)


def measured_omega(tr, t, h):
    """World angular velocity from quaternion samples: 2 log(q(t+h) q(t)^-1) / h."""
    a, b = evaluate(tr, t)[0], evaluate(tr, t + h)[0]
    d = quat_multiply(b, a * np.array([1, -1, -1, -1]))
    d = d if d[0] >= 0 else -d
    half = math.atan2(np.linalg.norm(d[1:]), d[0])
    return 2.0 * half * d[1:] / max(np.linalg.norm(d[1:]), 1e-300) / h


def test_squad_is_smooth_at_keys_and_reports_its_angular_velocity():
    tr = compile_track({"times": [0, 1, 2, 3], "interpolation": "squad",
                        "euler_deg": [[0, 0, 0], [0, 90, 0], [90, 90, 0], [0, 0, 170]]},
                       "rotation")
    for t in (1.0, 2.0):
        h = 1e-6
        jump = measured_omega(tr, t, h) - measured_omega(tr, t - h, h)
        # a first-order difference moves by h |w'| ~ 3e-6 between the two sides (measured
        # 3e-5 at h = 1e-5, 3e-4 at 1e-4: O(h), so no jump); a kink would stay O(1).
        assert np.abs(jump).max() < 1e-5
        assert np.allclose(evaluate(tr, t + 0.3)[1], measured_omega(tr, t + 0.3, 1e-7),
                           atol=1e-5)  # reported rate vs the measured one, O(h) again
    q = evaluate(tr, np.linspace(0, 3, 301))[0]
    assert np.abs(np.linalg.norm(q, axis=1) - 1.0).max() < 1e-15


# ----------------------------------------------------------------------------- colours


def test_hsv_takes_the_short_way_round_the_colour_wheel():
    red_blue = [[1, 0, 0], [0, 0, 1]]
    hsv = track(times=[0, 1], values=red_blue, kind="color", space="hsv")
    rgb = track(times=[0, 1], values=red_blue, kind="color")
    # red (hue 0) to blue (hue 2/3): the short way is backwards through magenta (5/6)
    assert np.allclose(evaluate(hsv, 0.5)[0], [1, 0, 1, 1], atol=1e-15)
    assert np.allclose(evaluate(rgb, 0.5)[0], [0.5, 0, 0.5, 1], atol=1e-15)
    # hue 0.9 -> 0.1 wraps through 0 (red), never through green (hue 0.5)
    a, b = hsv_to_rgb(np.array([[0.9, 1, 1, 1], [0.1, 1, 1, 1]]))
    wrap = track(times=[0, 1], values=[list(a[:3]), list(b[:3])], kind="color", space="hsv")
    mid = evaluate(wrap, 0.5)[0]
    assert np.allclose(mid, [1, 0, 0, 1], atol=1e-12)
    hues = rgb_to_hsv(evaluate(wrap, np.linspace(0, 1, 101))[0])[:, 0]
    assert ((hues >= 0.9 - 1e-12) | (hues <= 0.1 + 1e-12)).all()


def test_hsv_rate_is_the_derivative_of_the_colour():
    tr = track("catmull-rom", times=[0, 1, 2], values=[[1, 0, 0], [0.2, 0.9, 0.3], [0, 0, 1]],
               kind="color", space="hsv")
    for t in (0.3, 0.77, 1.4):
        h = 1e-6
        fd = (evaluate(tr, t + h)[0] - evaluate(tr, t - h)[0]) / (2 * h)
        assert np.allclose(evaluate(tr, t)[1], fd, atol=1e-6)  # central difference, O(h^2)


# ----------------------------------------------------------------------------- extrapolation


def test_clamp_holds_the_end_values_with_zero_rate():
    tr = track("catmull-rom")
    assert np.array_equal(evaluate(tr, -3.0)[0], POINTS[0])
    assert np.array_equal(evaluate(tr, 9.0)[0], POINTS[-1])
    assert not evaluate(tr, -3.0)[1].any() and not evaluate(tr, 9.0)[1].any()


def test_loop_repeats_with_the_period_before_and_after():
    tr = track("catmull-rom", extrapolation="loop")
    t = np.linspace(0.01, 4.99, 37)
    for shift in (5.0, 10.0, -5.0, -15.0):
        v, r = evaluate(tr, t + shift)
        v0, r0 = evaluate(tr, t)
        # t + shift - shift round-off (1e-15 s) times speeds of order 10: 1e-13
        assert np.allclose(v, v0, atol=1e-12) and np.allclose(r, r0, atol=1e-11)
    assert np.array_equal(evaluate(tr, 10.0)[0], POINTS[-1])  # t_0 + 2T ends a cycle
    assert np.array_equal(evaluate(tr, -5.0)[0], POINTS[0])   # t_0 - T starts one


def test_ping_pong_runs_back_with_negated_rate():
    tr = track("kochanek-bartels", extrapolation="ping-pong", tension=0.2)
    x = np.linspace(0.01, 4.99, 37)
    fwd_v, fwd_r = evaluate(tr, x)
    back_v, back_r = evaluate(tr, 10.0 - x)  # t_0 + 2T - x mirrors x
    assert np.allclose(back_v, fwd_v, atol=1e-12) and np.allclose(back_r, -fwd_r, atol=1e-11)
    before_v, before_r = evaluate(tr, -x)  # mirrored about t_0
    assert np.allclose(before_v, fwd_v, atol=1e-12) and np.allclose(before_r, -fwd_r,
                                                                    atol=1e-11)


def test_before_and_after_can_differ():
    tr = track("linear", extrapolation={"before": "clamp", "after": "loop"})
    assert np.array_equal(evaluate(tr, -1.0)[0], POINTS[0])
    assert np.allclose(evaluate(tr, 5.5)[0], evaluate(tr, 0.5)[0], atol=1e-15)


# ----------------------------------------------------------------------------- timing


@pytest.mark.parametrize("mode", ["linear", "catmull-rom"])
def test_arc_length_gives_constant_speed_along_the_same_path(mode):
    tr = track(mode, arc_length=True)
    plain = track(mode)
    # the path length, independently: a polyline through 200 001 points of the curve
    dense = evaluate(plain, np.linspace(0.0, 5.0, 200_001))[0]
    length = np.linalg.norm(np.diff(dense, axis=0), axis=1).sum()
    if mode == "linear":
        length = np.linalg.norm(np.diff(POINTS, axis=0), axis=1).sum()  # exact
    speed = length / 5.0
    h = 1e-4
    t = np.linspace(0.0, 5.0, 50_001)
    v, r = evaluate(tr, t)
    # Path covered in [t, t + 2h] from chords, Richardson-extrapolated: (c_h - c_2h) / 3
    # removes the (kappa h v)^2 / 24 chord error, leaving O(h^4), below 1e-8 even at the
    # curve's tightest bend (kappa about 45 / m near t = 1.94 s).
    c1 = np.linalg.norm(np.diff(v, axis=0), axis=1)
    pair = c1[:-1] + c1[1:]
    covered = pair + (pair - np.linalg.norm(v[2:] - v[:-2], axis=1)) / 3.0
    # At keys linear has corners (short chords) and Catmull-Rom a curvature jump (C1, not
    # C2), where the extrapolation does not hold: leave the windows around keys out.
    near_key = np.zeros(len(covered), dtype=bool)
    for p in POINTS[1:-1]:
        near_key |= np.linalg.norm(v[1:-1] - p, axis=1) < 3 * h * speed
    measured = covered[~near_key] / (2 * h)
    assert np.abs(measured / speed - 1.0).max() < 1e-8
    assert np.abs(np.linalg.norm(r, axis=1) / speed - 1.0).max() < 1e-9  # polyline: 1e-10
    assert np.array_equal(v[0], POINTS[0]) and np.array_equal(v[-1], POINTS[-1])
    # the curve still passes through every key (at the instant its share of length is due)
    for p in POINTS[1:-1]:
        assert np.linalg.norm(v - p, axis=1).min() < speed * 1e-4


def test_arc_length_with_ease_starts_and_stops_smoothly():
    tr = track("catmull-rom", arc_length=True, ease="in-out")
    assert not evaluate(tr, 0.0)[1].any() and np.abs(evaluate(tr, 5.0)[1]).max() < 1e-15
    assert np.array_equal(evaluate(tr, 5.0)[0], POINTS[-1])


@pytest.mark.parametrize("ease", ["in", "out", "in-out"])
def test_ease_keeps_keys_and_stops_at_eased_ends(ease):
    tr = track("linear", ease=ease)
    assert np.array_equal(evaluate(tr, np.array(TIMES))[0], np.array(POINTS))
    r_start = evaluate(tr, TIMES[1])[1]  # start of segment 1
    r_end = evaluate(tr, TIMES[2] - 1e-12)[1]  # end of segment 1
    assert (np.abs(r_start).max() == 0.0) == (ease in ("in", "in-out"))
    assert (np.abs(r_end).max() < 1e-9) == (ease in ("out", "in-out"))


# ----------------------------------------------------------------------------- errors


def test_times_must_increase_strictly():
    with pytest.raises(TrackError) as info:
        compile_track({"times": [0, 1, 1], "values": [0, 1, 2]})
    assert info.value.issues[0][0] == ("times", 2)
    assert "increase strictly" in str(info.value)


@pytest.mark.parametrize("spec,kind,where", [
    ({"times": [0, 1], "values": [0]}, "vector", ("values",)),
    ({"times": [0, 1], "values": [[0, 1], [0]]}, "vector", ("values", 1)),
    ({"times": [0, 1], "values": [0, 1], "interpolation": "squad"}, "vector",
     ("interpolation",)),
    ({"times": [0, 1], "values": [[1, 0, 0, 0], [0, 0, 0, 0]]}, "rotation", ("values", 1)),
    ({"times": [0, 1], "values": [0, 1], "interpolation": "hermite"}, "vector", ()),
    ({"times": [0, 1], "values": [0, 1], "tension": 1}, "vector", ("tension",)),
    ({"times": [0, 1], "values": [0, 1], "extrapolation": "bounce"}, "vector",
     ("extrapolation",)),
    ({"times": [0, 1], "values": [0, 1], "extrapolation": {"after": "lop"}}, "vector",
     ("extrapolation", "after")),
    ({"times": [0, 1], "values": [0, 1], "ease": "both"}, "vector", ("ease",)),
])
def test_bad_specs_name_the_key(spec, kind, where):
    with pytest.raises(TrackError) as info:
        compile_track(spec, kind)
    assert info.value.issues[0][0] == where


# ----------------------------------------------------------------------------- properties


@st.composite
def random_tracks(draw):
    n = draw(st.integers(2, 7))
    dim = draw(st.integers(1, 3))
    gaps = draw(st.lists(st.floats(0.05, 5.0), min_size=n - 1, max_size=n - 1))
    start = draw(st.floats(-10, 10))
    times = [start] + list(start + np.cumsum(gaps))
    if len(set(times)) < n or any(b <= a for a, b in zip(times, times[1:])):
        times = [start + 0.5 * k for k in range(n)]
    values = draw(st.lists(st.lists(st.floats(-100, 100), min_size=dim, max_size=dim),
                           min_size=n, max_size=n))
    mode = draw(st.sampled_from(["step", "linear", "catmull-rom", "kochanek-bartels"]))
    spec = {"times": times, "values": values, "interpolation": mode,
            "extrapolation": draw(st.sampled_from(["clamp", "loop", "ping-pong"]))}
    if mode == "kochanek-bartels":
        for key in ("tension", "continuity", "bias"):
            spec[key] = draw(st.floats(-1, 1))
    return spec


@settings(max_examples=150, deadline=None)
@given(random_tracks(), st.floats(0.0, 1.0))
def test_random_tracks_hit_keys_and_rates_are_derivatives(spec, frac):
    tr = compile_track(spec)
    times, values = np.array(spec["times"]), np.array(spec["values"])
    assert np.array_equal(evaluate(tr, times)[0], values)
    # inside a segment (away from its ends) the rate is the curve's derivative
    i = min(int(frac * (len(times) - 1)), len(times) - 2)
    gap = times[i + 1] - times[i]
    t = times[i] + gap * (0.25 + 0.5 * frac)
    h = 1e-4 * gap
    fd = (evaluate(tr, t + h)[0] - evaluate(tr, t - h)[0]) / (2 * h)
    scale = np.abs(values).max() + 1.0
    # Central difference of the segment's cubic a + b s + c s^2 + d s^3: error
    # h^2 |C'''| / 6 = h^2 |d| / gap^3. The tangents times gap are at most 32 max|P| (KB
    # with |T|, |C|, |B| <= 1 divides by a span >= gap), so |d| <= 70 max|P| and the error
    # is below 7e-7 max|P| / gap; round-off eps max|P| / h is 2e-12 max|P| / gap.
    assert np.allclose(evaluate(tr, t)[1], fd, atol=1e-6 * scale / gap)
    if spec["interpolation"] == "linear":  # stays between its two keys
        v = evaluate(tr, t)[0]
        lo = np.minimum(values[i], values[i + 1]) - 1e-12 * scale
        hi = np.maximum(values[i], values[i + 1]) + 1e-12 * scale
        assert ((v >= lo) & (v <= hi)).all()
    # extrapolation maps every time to a finite value
    far = evaluate(tr, np.array([times[0] - 7.3 * gap, times[-1] + 11.1 * gap]))[0]
    assert np.isfinite(far).all()


@settings(max_examples=100, deadline=None)
@given(st.lists(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda q: np.linalg.norm(q) > 0.1), min_size=2, max_size=6),
    st.sampled_from(["slerp", "squad"]))
def test_random_rotations_stay_unit_and_hit_keys(quats, mode):
    times = list(range(len(quats)))
    tr = compile_track({"times": times, "values": quats, "interpolation": mode}, "rotation")
    q = evaluate(tr, np.linspace(0, len(quats) - 1, 97))[0]
    assert np.abs(np.linalg.norm(q, axis=1) - 1.0).max() < 1e-14
    keys = np.array(quats) / np.linalg.norm(quats, axis=1, keepdims=True)
    got = evaluate(tr, np.array(times, dtype=float))[0]
    assert np.allclose(np.abs(np.sum(got * keys, axis=1)), 1.0, atol=1e-15)
