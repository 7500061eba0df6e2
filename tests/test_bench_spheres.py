"""The spheres-in-a-box problem of `vrsim bench` (bench_spheres.py): its set-up and
sanity figures against hand-computed values, and vrsim's runner on a small box."""

from __future__ import annotations

import math

import numpy as np

from vrsim_cli.model.model import compile_model
from vrsim_cli.scene.spec import parse_scene
from vrsim_cli.tools.bench import spheres as bs


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
