"""The spheres-in-a-box problems of `vrsim bench` (spheres.py: `spheres` and
`spheres-scaling`): set-up and sanity figures against hand-computed values, vrsim's
runners on a small box, and the scaling problem's per-N comparison."""

from __future__ import annotations

import math

import numpy as np
import pytest

from vrsim_cli.model.model import compile_model
from vrsim_cli.scene.spec import parse_scene
from vrsim_cli.tools.bench import report
from vrsim_cli.tools.bench import spheres as bs
from vrsim_cli.tools.bench.problems import Row


def test_layout_puts_every_sphere_inside_the_box_without_overlap():
    for n in (1, 27, 100, 1000):
        pos, vel, half, height = bs.layout(n)
        assert pos.shape == vel.shape == (n, 3)
        assert (np.abs(pos[:, [0, 2]]) <= half - bs.RADIUS).all()
        assert (pos[:, 1] >= bs.RADIUS).all() and (pos[:, 1] <= height - bs.RADIUS).all()
        if n > 1:  # lattice pitch 0.12 m, jitter +-5 mm: gaps of at least 1 cm
            d = np.linalg.norm(pos[:, None] - pos[None], axis=2) + np.eye(n) * 1e9
            assert d.min() >= 2 * bs.RADIUS + 0.01 - 1e-12
    a, b = bs.layout(50), bs.layout(50)
    assert a[0].tobytes() == b[0].tobytes() and a[1].tobytes() == b[1].tobytes()


def test_sanity_figures_match_hand_computed_values():
    pos0 = np.array([[0.0, 1.0, 0.0], [0.1, 2.0, 0.0]])
    vel0 = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    m, g = bs.MASS, bs.G
    e0 = 0.5 * m * (1.0 + 4.0) + m * g * 3.0
    # the first sphere below the floor (escaped), the second 1 cm into the wall x = 0.3,
    # spinning at 10 rad/s (I = 2/5 m r^2)
    pos = np.array([[0.0, -0.2, 0.0], [0.26, 0.5, 0.0]])
    vel = np.zeros((2, 3))
    w = np.array([[0.0, 0.0, 0.0], [0.0, 10.0, 0.0]])
    e1 = 0.5 * 0.4 * m * bs.RADIUS ** 2 * 100.0 + m * g * 0.3
    figures = bs.sanity(pos, vel, w, pos0, vel0, 0.3, 3.0)
    assert math.isclose(figures["energy_ratio"], e1 / e0, rel_tol=1e-14)
    assert figures["escaped"] == 1
    assert math.isclose(figures["max_penetration_m"], bs.RADIUS + 0.2, rel_tol=1e-14)


def test_the_scene_is_a_stepped_box_of_spheres_with_the_problems_materials():
    model = compile_model(parse_scene(bs.scene_text(40, 3), "<spheres>"))
    assert model.response.impacts == "stepped"
    assert model.n_body == 46 and (model.body_type[6:] == 0).all()
    _, eps, mu = model.response.pair_values(np.array([0, 6]), np.array([6, 7]))
    assert np.allclose(eps, bs.EPS) and np.allclose(mu, bs.MU)


def test_vrsim_runner_reports_throughput_and_sane_figures(monkeypatch):
    monkeypatch.setattr(bs, "sizes", lambda quick: ((40, 30),))
    (row,) = bs.vrsim_spheres(True, 1)
    assert row["engine"] == "vrsim" and row["bodies"] == 40 and row["steps"] == 30
    assert math.isclose(row["body_steps_per_s"], 40 * 30 / row["wall_s"])
    figures = row["sanity"]
    assert figures["escaped"] == 0
    assert 0.0 < figures["energy_ratio"] <= 1.0
    # a post-step method lets a sphere in by at most one step of travel
    _, vel0, _, _ = bs.layout(40)
    assert figures["max_penetration_m"] <= np.linalg.norm(vel0, axis=1).max() * bs.DT


# ----------------------------------------------------------------------------- spheres-scaling


def test_scaling_runs_the_issues_sizes_in_the_default_mode():
    assert [n for n, _ in bs.scaling_sizes(False)] == [8, 16, 27, 32, 33, 64, 128]
    assert {steps for _, steps in bs.scaling_sizes(False)} == {300}  # 3 s, as N = 100
    assert [n for n, _ in bs.scaling_sizes(True)] == [8, 16, 27, 32, 33, 64, 128]
    # impacts unset: the default mode issue 48 (b) is about; the same box and spheres
    text = bs.scene_text(8, 3, None)
    assert "impacts" not in text
    assert text.replace("collision: {}", "collision: {impacts: stepped}") == \
        bs.scene_text(8, 3)
    model = compile_model(parse_scene(text, "<spheres-scaling>"))
    assert model.response.impacts == "stepped" and model.response.impacts_why.startswith("auto")


def _row(engine, setting, n, ms):
    return bs.row(engine, setting, n, 100, ms * 100 / 1e3, {"escaped": 0}, bs.SCALING)


def test_scaling_compares_vrsim_with_each_peers_fastest_setting_per_n():
    rows = [_row("vrsim", "v", 8, 0.03), _row("vrsim", "v", 16, 0.02),
            _row("vrsim", "v", 27, 0.5),
            _row("mujoco", "Euler, Newton, s", 8, 0.06), _row("mujoco", "Euler, CG, s", 8, 0.02),
            _row("mujoco", "Euler, Newton, s", 16, 0.04), _row("pybullet", "p", 27, 1.0),
            bs.row("vrsim", "v", 8, 100, 1.0, {}, bs.PROBLEM)]  # another problem: ignored
    found = bs.scaling(rows)
    assert [e["bodies"] for e in found] == [8, 16, 27]
    assert found[0]["mujoco_ms_per_step"] == pytest.approx(0.02)  # CG, the faster
    assert found[0]["vrsim_over_mujoco"] == pytest.approx(1.5)
    assert found[1]["vrsim_over_mujoco"] == pytest.approx(0.5)
    assert "vrsim_over_mujoco" not in found[2]
    assert found[2]["vrsim_over_pybullet"] == pytest.approx(0.5)
    assert [e["rises"] for e in found] == [None, False, True]
    problem = report.problems()[bs.SCALING]
    text = "\n".join(bs.scaling_markdown(problem, [Row.of(r) for r in rows[:-1]]))
    assert "| 8 | 0.0300 | 0.0200 (CG) | 1.50 | - | - |" in text
    assert "| 27 | 0.5000 | - | - | 1.0000 | 0.50 |" in text
    assert "does not rise from N = 8 to 16." in text


def test_vrsim_scaling_runner_rows_belong_to_the_scaling_problem(monkeypatch):
    monkeypatch.setattr(bs, "SCALING_SIZES", (8,))
    monkeypatch.setattr(bs, "SCALING_STEPS", {"full": 20, "quick": 20})
    (row,) = bs.vrsim_spheres_scaling(True, 1)
    assert row["problem"] == bs.SCALING and row["bodies"] == 8 and row["steps"] == 20
    assert row["setting"].startswith("impacts unset (auto: stepped)")
    assert row["sanity"]["escaped"] == 0 and 0.0 < row["sanity"]["energy_ratio"] <= 1.0
