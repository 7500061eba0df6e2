"""The bench harness: errors against the closed form, and the summary's bookkeeping.
(Speed itself is measured by `vrsim bench`, never asserted in a test.)"""

from __future__ import annotations

import json

import pytest

from vrsim_cli.bench import Point, run_bench, summary


def test_projectile_errors_match_the_integrators_known_errors():
    points = run_bench(["projectile"], quick=True, repeats=1)
    assert {p.engine for p in points} == {"vrsim"}
    for p in points:
        if p.method == "rk4":
            assert p.error < 1e-12  # exact for a quadratic, round-off only
        else:  # first order: |g| dt t / 2 at t = 1 s (tests/test_dynamics.py derives it)
            assert p.error == pytest.approx(0.5 * 9.81 * p.dt * 1.0, rel=1e-8)
        assert p.wall_s > 0 and p.steps == round(1.0 / p.dt)


def test_summary_picks_the_fastest_run_below_the_target_and_forms_ratios():
    pts = [Point("projectile", "vrsim", "rk4", 0.01, 2.0, 1e-14, 100),
           Point("projectile", "vrsim", "rk4", 0.001, 9.0, 1e-14, 1000),
           Point("projectile", "vrsim", "euler", 0.001, 1.0, 1e-2, 1000),
           Point("projectile", "mujoco", "RK4", 0.01, 0.5, 1e-14, 100),
           Point("projectile", "pybullet", "semi-implicit Euler", 0.01, 0.1, 1e-2, 100)]
    rows = {r["engine"]: r for r in summary(pts)}
    assert rows["vrsim"]["best_wall_s"] == 2.0
    assert rows["mujoco"]["vrsim_over_peer"] == 4.0
    assert rows["pybullet"]["method"] == "target not reached"


def test_bench_command_writes_report_and_json(invoke, tmp_path):
    result = invoke("bench", "--quick", "--repeats", "1", "-o", tmp_path / "b")
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "b" / "bench.json").read_text())
    assert data["points"] and data["machine"]["cores"]
    assert "| engine | method | dt (s) |" in (tmp_path / "b" / "bench.md").read_text()
    assert invoke("bench", "--problem", "nope").exit_code == 2


def test_dzhanibekov_errors_follow_the_integrators_orders():
    # Orientation error at t = 2 s against scipy's DOP853 (the truth of the problem):
    # halving dt divides verlet's error by ~4 (order 2: measured 4.0 from 10 ms to 5 ms)
    # and rk4's by ~16 (measured 17); the slide's euler stays far off (~0.3 rad).
    from vrsim_cli.bench import _vrsim_dzhanibekov

    points = {(p.method, p.dt): p.error for p in _vrsim_dzhanibekov((0.01, 0.005), 1)}
    assert 3.0 < points[("verlet", 0.01)] / points[("verlet", 0.005)] < 5.0
    assert 12.0 < points[("rk4", 0.01)] / points[("rk4", 0.005)] < 24.0
    assert points[("euler", 0.005)] > 0.1
    assert points[("dopri5 tol=1e-10", 0.01)] < 1e-8
