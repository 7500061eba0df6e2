"""`vrsim plot`: the numbers it draws (energy against closed forms, speed from positions
when a file has no velocities) and the PNG it writes."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from conftest import SCENARIOS
from vrsim_cli.model.model import compile_model
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.tools.plot import series
from vrsim_cli.tools.trajectory import Track, Trajectory, read_trajectory

pytest.importorskip("matplotlib")


def test_projectile_energy_is_its_initial_energy(invoke, tmp_path):
    """rk4 is exact for constant gravity, so E(t) = 1/2 m |v0|^2 + m g y0 at every sample
    (to round-off: 1e-12 J on 12 J)."""
    out = tmp_path / "p.mcap"
    assert invoke("run", SCENARIOS / "projectile.yaml", "-o", out, "-q").exit_code == 0
    traj = read_trajectory(out)
    model = compile_model(load_scene(SCENARIOS / "projectile.yaml"))
    data = series(traj, model)
    ball = data["entities"]["ball"]
    m, v0, y0 = 0.2, 10.0, 1.0  # 10 m/s at 45 degrees from 1 m (the scenario)
    assert np.allclose(ball["energy"], 0.5 * m * v0 ** 2 + m * 9.81 * y0, rtol=0, atol=1e-12)
    assert data["entities"]["ground"]["energy"] is None  # static: infinite mass
    assert np.array_equal(ball["speed"], np.linalg.norm(traj.tracks["ball"].vel, axis=1))


def test_rotational_energy_uses_the_world_inertia():
    """A box (inertia diag(Ix, Iy, Iz) about its centre) turned 90 degrees about x, spinning
    at 2 rad/s about world y: world y is the body's -z after the turn, so E = 1/2 Iz 2^2."""
    model = compile_model(parse_scene("""
vrsim: 1
duration: 0.1
gravity: [0, 0, 0]
bodies: [{name: box, mass: 12, shape: {type: box, size: [1, 2, 3]}}]
"""))
    m = 12.0
    iz = m * (1 ** 2 + 2 ** 2) / 12
    half = np.sqrt(0.5)
    track = Track(np.array([0.0, 1.0]), np.zeros((2, 3)), np.array([[half, half, 0, 0]] * 2),
                  np.zeros((2, 3)), np.array([[0.0, 2.0, 0.0]] * 2))
    traj = Trajectory("hand", "csv", {"box": track})
    energy = series(traj, model)["entities"]["box"]["energy"]
    assert np.allclose(energy, 0.5 * iz * 4.0, rtol=1e-14)


def test_without_velocities_the_speed_comes_from_positions():
    """Central differences are exact for uniform motion: 3 m/s along a diagonal."""
    t = np.linspace(0.0, 1.0, 11)
    direction = np.array([1.0, 2.0, 2.0]) / 3.0
    track = Track(t, 3.0 * t[:, None] * direction, np.tile([1.0, 0, 0, 0], (11, 1)),
                  np.full((11, 3), np.nan), np.full((11, 3), np.nan))
    data = series(Trajectory("t", "tum", {"cart": track}))
    cart = data["entities"]["cart"]
    assert cart["speed_from_positions"] and cart["energy"] is None
    assert np.allclose(cart["speed"], 3.0, rtol=1e-12)


def test_plot_writes_a_png(invoke, tmp_path):
    from PIL import Image

    out = tmp_path / "b.mcap"
    assert invoke("run", SCENARIOS / "bounce.yaml", "-o", out, "-q").exit_code == 0
    result = invoke("plot", out)  # default: b.png in the current folder
    assert result.exit_code == 0, result.output
    assert "wrote b.png: position, speed and energy of ground, ball" in result.stdout
    image = Image.open(tmp_path / "b.png")
    assert image.format == "PNG" and image.size == (900, 900)
    many = tmp_path / "f.csv"
    assert invoke("run", SCENARIOS / "fountain.yaml", "-o", many, "-q").exit_code == 0
    result = invoke("plot", many, "--entity", "drop.000*", "-o", tmp_path / "f.png")
    assert result.exit_code == 0 and "drop.0009" in result.stdout


@pytest.mark.parametrize("args,message", [
    (["--entity", "nothing*"], "--entity nothing*: no entity matches"),
    (["-o", "x.jpg"], "vrsim plot writes PNG"),
])
def test_plot_usage_errors_exit_2(invoke, tmp_path, args, message):
    out = tmp_path / "p.csv"
    assert invoke("run", SCENARIOS / "projectile.yaml", "-o", out, "-q").exit_code == 0
    result = invoke("plot", out, *args)
    assert result.exit_code == 2 and message in result.stderr, result.output


def test_missing_matplotlib_is_a_clear_error(invoke, tmp_path, monkeypatch):
    out = tmp_path / "p.csv"
    assert invoke("run", SCENARIOS / "projectile.yaml", "-o", out, "-q").exit_code == 0
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    result = invoke("plot", out)
    assert result.exit_code == 2
    assert "vrsim plot needs matplotlib, which is not installed: pip install " \
           "'vrsim-cli[plot]'" in result.stderr
