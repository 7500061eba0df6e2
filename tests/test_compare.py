"""`vrsim compare` and vrsim_cli.compare, on constructed trajectories whose differences are
known exactly, and on real runs whose difference has a closed form."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from vrsim_cli.tools.compare import (TIME_EPS_S, Tolerance, TolerancePlan, compare, match_times,
                               quat_angle)
from vrsim_cli.tools.trajectory import Track, Trajectory, read_trajectory
from vrsim_cli.writers import CSV_COLUMNS


def write_csv(path, tracks: dict) -> str:
    """tracks: name -> dict(t=(n,), pos=(n,3), quat=(n,4), vel=(n,3)). Rows in time order."""
    lines = [",".join(CSV_COLUMNS)]
    rows = []
    for name, tr in tracks.items():
        n = len(tr["t"])
        quat = tr.get("quat", np.tile([1.0, 0, 0, 0], (n, 1)))
        vel = tr.get("vel", np.zeros((n, 3)))
        for i in range(n):
            values = list(tr["pos"][i]) + list(quat[i]) + list(vel[i]) + [0.0, 0.0, 0.0]
            rows.append((tr["t"][i], name, values))
    rows.sort(key=lambda r: r[0])
    for t, name, values in rows:
        lines.append(",".join([repr(float(t)), name] + [repr(float(v)) for v in values]))
    path.write_text("\n".join(lines) + "\n")
    return str(path)


def line(n=11, rate=10.0, start=(0.0, 0.0, 0.0), velocity=(1.0, 2.0, 0.0)):
    """A body moving at constant velocity, sampled at `rate` from t = 0."""
    t = np.arange(n) / rate
    pos = np.asarray(start) + t[:, None] * np.asarray(velocity)
    return {"t": t, "pos": pos, "vel": np.tile(velocity, (n, 1)).astype(float)}


def quat_z(angle):
    return np.array([math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2)])


def test_identical_files_pass_with_zero_errors(invoke, tmp_path):
    a = write_csv(tmp_path / "a.csv", {"ball": line(), "box": line(velocity=(0, 0, 1))})
    result = invoke("compare", a, a)
    assert result.exit_code == 0, result.output
    assert "OK: 2 entities within tolerance" in result.stdout
    data = json.loads(invoke("compare", a, a, "--json").stdout)
    assert data["ok"] and [e["max_position_error_m"] for e in data["entities"]] == [0.0, 0.0]


def test_position_offset_is_measured_exactly_with_its_first_exceedance(invoke, tmp_path):
    ref = line()
    moved = line()
    # From t = 0.5 s on, A is off by (0.75, 1, 0) m: |e| = 1.25 m, exact in binary.
    moved["pos"] = moved["pos"] + np.where(moved["t"][:, None] >= 0.5, [0.75, 1.0, 0.0], 0.0)
    a = write_csv(tmp_path / "a.csv", {"ball": moved})
    b = write_csv(tmp_path / "b.csv", {"ball": ref})
    result = invoke("compare", a, b, "--json")
    assert result.exit_code == 1
    ball = json.loads(result.stdout)["entities"][0]
    # positions are sums of small binary fractions; 1e-15 m allows their round-off
    assert ball["max_position_error_m"] == pytest.approx(1.25, abs=1e-15)
    assert ball["first_exceedance_s"] == 0.5
    assert ball["first_exceedance_quantity"] == "position"
    assert ball["max_velocity_error_m_s"] == 0.0
    # atol at the error itself passes (the bound is <=), a hair below fails
    assert invoke("compare", a, b, "--atol", "1.2500000001").exit_code == 0
    assert invoke("compare", a, b, "--atol", "1.2499999").exit_code == 1
    text = invoke("compare", a, b).stdout
    assert "FAIL: first exceedance at t = 0.5 s (ball)" in text


def test_relative_tolerance_scales_with_the_reference_norm(tmp_path):
    ref = {"t": np.array([0.0, 1.0]), "pos": np.array([[3.0, 4.0, 0.0], [6.0, 8.0, 0.0]])}
    # A is 1 % farther along the same direction: error 0.05 m at |p| = 5, 0.1 m at 10
    a = {"t": ref["t"], "pos": ref["pos"] * 1.01}
    ta = read_trajectory(write_csv(tmp_path / "a.csv", {"p": a}))
    tb = read_trajectory(write_csv(tmp_path / "b.csv", {"p": ref}))
    assert compare(ta, tb, TolerancePlan(Tolerance(atol=0, rtol=0.0101))).ok
    failing = compare(ta, tb, TolerancePlan(Tolerance(atol=0, rtol=0.0099)))
    assert not failing.ok and failing.entities[0].first_exceed_t == 0.0
    # 0.1 m is the largest error; 1e-12 m allows the round-off of 10 * 1.01
    assert failing.entities[0].pos_err == pytest.approx(0.1, abs=1e-12)


@pytest.mark.parametrize("angle", [0.3, 1e-12, math.pi - 1e-9])
def test_orientation_angle_is_exact_and_sign_invariant(angle):
    n = 4
    qb = np.tile(quat_z(0.2), (n, 1))
    qa = np.tile(quat_z(0.2 + angle), (n, 1))
    qa[1::2] *= -1.0  # q and -q are the same rotation
    theta = quat_angle(qa, qb)
    # atan2 keeps relative precision even at 1e-12 rad (acos would give ~1e-8 there);
    # 1e-6 relative covers the round-off in building the quaternions from the angle
    assert theta == pytest.approx(np.full(n, angle), rel=1e-6)
    assert quat_angle(qb, -qb) == pytest.approx(np.zeros(n), abs=1e-15)


def test_orientation_tolerance_and_first_exceedance(invoke, tmp_path):
    ref = line(n=5)
    turned = line(n=5)
    turned["quat"] = np.array([quat_z(a) for a in (0, 0, 0.01, 0.02, 0.03)])
    a = write_csv(tmp_path / "a.csv", {"top": turned})
    b = write_csv(tmp_path / "b.csv", {"top": ref})
    data = json.loads(invoke("compare", a, b, "--json").stdout)["entities"][0]
    assert data["max_orientation_error_rad"] == pytest.approx(0.03, rel=1e-12)
    assert (data["first_exceedance_s"], data["first_exceedance_quantity"]) == \
        (0.2, "orientation")
    assert invoke("compare", a, b, "--angle-tol", "0.0300001").exit_code == 0
    # per-entity override of the angle tolerance: 'PATTERN=ATOL,ANGLE_TOL'
    assert invoke("compare", a, b, "--tol", "t*=1e-9,0.031").exit_code == 0


def test_velocity_error_and_tum_without_velocities(invoke, tmp_path):
    ref = line()
    fast = line()
    fast["vel"] = fast["vel"] + [0.0, 0.0, 0.5]
    a = write_csv(tmp_path / "a.csv", {"ball": fast})
    b = write_csv(tmp_path / "b.csv", {"ball": ref})
    data = json.loads(invoke("compare", a, b, "--json").stdout)["entities"][0]
    assert data["max_velocity_error_m_s"] == 0.5 and data["first_exceedance_s"] == 0.0
    assert data["first_exceedance_quantity"] == "velocity"
    tum = tmp_path / "tum"
    tum.mkdir()
    (tum / "ball.tum").write_text("".join(
        " ".join(map(repr, [float(t), *map(float, p)])) + " 0.0 0.0 0.0 1.0\n"
        for t, p in zip(ref["t"], ref["pos"])))
    result = invoke("compare", tum, a)
    assert result.exit_code == 0, result.output  # same poses; velocities cannot be compared
    assert "note: velocities not compared for 1 entity (ball)" in result.stdout
    assert json.loads(invoke("compare", tum, a, "--json").stdout)["velocity_not_compared"] \
        == ["ball"]


def test_different_sample_rates_compare_on_common_times(invoke, tmp_path):
    fine = line(n=101, rate=100.0)
    coarse = line(n=26, rate=25.0)
    a = write_csv(tmp_path / "a.csv", {"ball": fine})
    b = write_csv(tmp_path / "b.csv", {"ball": coarse})
    result = invoke("compare", a, b)
    assert result.exit_code == 0, result.output
    assert "note: the files have different sample times" in result.stdout
    e = json.loads(invoke("compare", a, b, "--json").stdout)["entities"][0]
    assert (e["compared_samples"], e["samples_only_in_a"], e["samples_only_in_b"]) == (26, 75, 0)
    # 30 Hz against 40 Hz share the 10 Hz grid: 11 samples over 1 s
    e = json.loads(invoke("compare", write_csv(tmp_path / "c.csv", {"ball": line(31, 30.0)}),
                          write_csv(tmp_path / "d.csv", {"ball": line(41, 40.0)}),
                          "--json").stdout)["entities"][0]
    assert (e["compared_samples"], e["samples_only_in_a"], e["samples_only_in_b"]) == (11, 20, 30)
    assert e["ok"]


def test_a_run_cut_short_fails_even_where_it_agrees(invoke, tmp_path):
    a = write_csv(tmp_path / "a.csv", {"ball": line(n=6)})
    b = write_csv(tmp_path / "b.csv", {"ball": line(n=11)})
    result = invoke("compare", a, b)
    assert result.exit_code == 1
    assert "A covers 0 .. 0.5 s, B covers 0 .. 1 s" in result.stdout
    # no shared time at all
    shifted = line()
    shifted["t"] = shifted["t"] + 0.05
    result = invoke("compare", write_csv(tmp_path / "c.csv", {"ball": shifted}), b)
    assert result.exit_code == 1 and "no sample times in common" in result.stdout


def test_different_entity_sets_are_reported_not_crashed_on(invoke, tmp_path):
    a = write_csv(tmp_path / "a.csv", {"ball": line(), "observer": line()})
    b = write_csv(tmp_path / "b.csv", {"ball": line(), "crate": line()})
    result = invoke("compare", a, b)
    assert result.exit_code == 1
    assert "entities only in A (1): observer" in result.stdout
    assert "entities only in B (1): crate" in result.stdout
    assert invoke("compare", a, b, "--allow-missing-entities").exit_code == 0
    data = json.loads(invoke("compare", a, b, "--json").stdout)
    assert (data["entities_only_in_a"], data["entities_only_in_b"]) == (["observer"], ["crate"])
    nothing_shared = write_csv(tmp_path / "c.csv", {"other": line()})
    result = invoke("compare", nothing_shared, b, "--allow-missing-entities")
    assert result.exit_code == 1 and "no entity in common" in result.stdout


def test_per_entity_overrides_last_match_wins(invoke, tmp_path):
    ref = line()
    off = line()
    off["pos"] = off["pos"] + [0.0, 0.001, 0.0]
    a = write_csv(tmp_path / "a.csv", {"drop.0001": off, "ball": ref})
    b = write_csv(tmp_path / "b.csv", {"drop.0001": ref, "ball": ref})
    assert invoke("compare", a, b).exit_code == 1
    assert invoke("compare", a, b, "--tol", "drop.*=0.0011").exit_code == 0
    assert invoke("compare", a, b, "--tol", "drop.*=0.0011", "--tol", "*=0").exit_code == 1


def test_nan_never_passes(tmp_path):
    bad = line()
    bad["pos"][3, 0] = np.nan
    ta = read_trajectory(write_csv(tmp_path / "a.csv", {"ball": bad}))
    tb = read_trajectory(write_csv(tmp_path / "b.csv", {"ball": line()}))
    report = compare(ta, tb, TolerancePlan(Tolerance(atol=1e300)))
    assert not report.ok and report.entities[0].first_exceed_t == pytest.approx(0.3)
    assert json.dumps(report.as_dict())  # NaN is reported as a string: valid JSON


def test_long_tables_list_failures_and_count_the_rest(invoke, tmp_path):
    ref = {f"p{i:03d}": line(n=3) for i in range(30)}
    moved = dict(ref, p007={**line(n=3), "pos": line(n=3)["pos"] + 1.0})
    a, b = write_csv(tmp_path / "a.csv", moved), write_csv(tmp_path / "b.csv", ref)
    out = invoke("compare", a, b).stdout
    assert "\np007 " in out and "\np008 " not in out
    assert "... 29 more entities within tolerance (--all lists them)" in out
    assert "\np008 " in invoke("compare", a, b, "--all").stdout


@pytest.mark.parametrize("content,message", [
    (b"garbage", "not a readable MCAP file"),
    (None, "no such file"),
])
def test_unreadable_input_exits_2(invoke, tmp_path, content, message):
    good = write_csv(tmp_path / "good.csv", {"ball": line()})
    bad = tmp_path / "bad.mcap"
    if content is not None:
        bad.write_bytes(content)
    result = invoke("compare", bad, good)
    assert result.exit_code == 2 and message in result.stderr
    assert invoke("compare", good, bad).exit_code == 2


def test_repeated_times_and_bad_options_exit_2(invoke, tmp_path):
    twice = line(n=3)
    twice["t"] = np.array([0.0, 0.1, 0.1])
    a = write_csv(tmp_path / "a.csv", {"ball": twice})
    result = invoke("compare", a, a)
    assert result.exit_code == 2 and "entity 'ball' has two samples at t = 0.1 s" in result.stderr
    good = write_csv(tmp_path / "g.csv", {"ball": line()})
    for option in (["--tol", "ball"], ["--tol", "ball=x"], ["--tol", "=1"],
                   ["--atol", "-1"], ["--tol", "b=nan"]):
        assert invoke("compare", good, good, *option).exit_code == 2, option


def test_broken_gzip_csv_exits_2(invoke, tmp_path):
    path = tmp_path / "x.csv.gz"
    path.write_bytes(b"\x1f\x8b\x08\x00garbage")
    result = invoke("compare", path, path)
    assert result.exit_code == 2 and "not a readable gzip file" in result.stderr


def test_match_times_pairs_within_epsilon_only():
    ta = np.array([0.0, 0.1, 0.2 + 0.5 * TIME_EPS_S, 0.3 + 2 * TIME_EPS_S])
    tb = np.array([0.0, 0.2, 0.3])
    ia, ib = match_times(ta, tb)
    assert ia.tolist() == [0, 2] and ib.tolist() == [0, 1]
    assert [x.tolist() for x in match_times(ta, tb[:1])] == [[0], [0]]
    assert [x.tolist() for x in match_times(ta[:0], tb)] == [[], []]


PROJECTILE = """
vrsim: 1
name: throw
duration: 1.5
frame_rate: 100
dt: 0.001
integrator: rk4
bodies: [{name: ball, mass: 0.2, position: [0, 1, 0], velocity: [7, 7, 0]}]
"""


@pytest.mark.parametrize("fmt_a,fmt_b", [("mcap", "csv"), ("tum", "mcap"), ("csv", "tum")])
def test_any_pair_of_formats_from_one_run_agrees_exactly(invoke, write_scene, tmp_path,
                                                         fmt_a, fmt_b):
    scene = write_scene(PROJECTILE)
    paths = {}
    for fmt in (fmt_a, fmt_b):
        paths[fmt] = tmp_path / ("out" if fmt == "tum" else f"out.{fmt}")
        extra = ["--format", "tum"] if fmt == "tum" else []
        assert invoke("run", scene, "-o", paths[fmt], "-q", *extra).exit_code == 0
    result = invoke("compare", paths[fmt_a], paths[fmt_b], "--atol", "0", "--angle-tol", "0")
    assert result.exit_code == 0, result.output


def test_euler_against_rk4_differs_by_the_closed_form(invoke, write_scene, tmp_path):
    """Under constant gravity rk4 is exact, and explicit Euler lags by g t dt / 2 in y
    (it sums v_k dt with v_k = v0 - g k dt: y_n = y0 + v0 t - g t (t - dt) / 2)."""
    scene = write_scene(PROJECTILE)
    rk4, euler = tmp_path / "rk4.csv", tmp_path / "euler.csv"
    invoke("run", scene, "-o", rk4, "-q")
    invoke("run", scene, "-o", euler, "-q", "--integrator", "euler")
    report = json.loads(invoke("compare", euler, rk4, "--json").stdout)
    ball = report["entities"][0]
    g, t, dt = 9.81, 1.5, 0.001
    # round-off of 1500 steps of float64 sums: 1e-12 m is ~1000 times above it
    assert ball["max_position_error_m"] == pytest.approx(g * t * dt / 2, abs=1e-12)
    assert ball["time_of_max_position_error_s"] == 1.5
    assert ball["first_exceedance_s"] == 0.01  # the first sample after t = 0
    tol = str(g * t * dt / 2 * (1 + 1e-9))
    assert invoke("compare", euler, rk4, "--atol", tol).exit_code == 0


def test_trajectory_without_tracks_reports_no_entities():
    empty = Trajectory("e.csv", "csv")
    one = Trajectory("o.csv", "csv", {"ball": Track(np.array([0.0]), np.zeros((1, 3)),
                                                     np.array([[1.0, 0, 0, 0]]),
                                                     np.zeros((1, 3)), np.zeros((1, 3)))})
    report = compare(empty, one)
    assert not report.ok and report.only_in_b == ["ball"] and report.entities == []


def test_nan_tolerance_and_control_characters_in_names(invoke, tmp_path):
    a = write_csv(tmp_path / "a.csv", {"evil\x1b[2J": line()})
    assert invoke("compare", a, a, "--atol", "nan").exit_code == 2
    result = invoke("compare", a, a)
    assert result.exit_code == 0 and "evil\\x1b[2J" in result.stdout
    assert "\x1b" not in result.stdout
