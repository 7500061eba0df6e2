"""The free-bodies problem of `vrsim bench` (tools/bench/freebodies.py): its correctness
figures against hand-computed and independently computed values, the scenes each engine
gets, and the quick run with and without peers, whose figures must be what the
integrators' orders allow (speed itself is reported by `vrsim bench`, never asserted)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vrsim_cli.tools.bench import freebodies as fb
from vrsim_cli.tools.bench import peers as bench_peers
from vrsim_cli.tools.bench import report
from vrsim_cli.tools.bench.report import run_bench

G = 9.81


def _quat_wxyz(rotation: Rotation) -> np.ndarray:
    x, y, z, w = rotation.as_quat().T  # scipy: scalar last
    return np.stack([w, x, y, z], axis=-1)


def test_box_moments_are_the_solid_box_formula():
    # unit cube of 1 kg: m/6; a 0.1 x 0.4 x 1.0 box: (b^2 + c^2) m/12 etc.
    assert fb.box_moments(np.array([[1.0, 1.0, 1.0]]))[0] == pytest.approx([1 / 6] * 3)
    assert fb.box_moments(np.array([[0.1, 0.4, 1.0]]))[0] == pytest.approx(
        [1.16 / 12, 1.01 / 12, 0.17 / 12], rel=1e-14)


def test_energy_and_angular_momentum_of_rotated_bodies():
    # Random orientations and rates: L = R diag(I) R^T w with R from scipy's own
    # quaternion conversion, E = w.L / 2; about a principal axis E = I w^2 / 2.
    rng = np.random.default_rng(3)
    rot = Rotation.random(20, random_state=4)
    w = rng.normal(size=(20, 3))
    moments = rng.uniform(0.1, 2.0, (20, 3))
    energy, L = fb.rotational(_quat_wxyz(rot), w, moments)
    R = rot.as_matrix()
    expected = np.einsum("nij,nj,nkj,nk->ni", R, moments, R, w)
    np.testing.assert_allclose(L, expected, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(energy, 0.5 * (w * expected).sum(axis=1), rtol=1e-13)
    e, L1 = fb.rotational(np.array([[1.0, 0, 0, 0]]), np.array([[0, 3.0, 0]]),
                          np.array([[1.0, 2.0, 5.0]]))
    assert e[0] == pytest.approx(9.0) and L1[0] == pytest.approx([0, 6.0, 0])


def test_sanity_figures_are_zero_for_the_truth_and_see_each_kind_of_error():
    n, t = 3, 0.7
    pos0, vel0, w0, _ = fb.layout("points", n)
    exact = pos0 + vel0 * t + 0.5 * np.array(fb.G) * t * t
    assert fb.sanity("points", n, t, exact)["position_error_m"] < 1e-13
    off = exact.copy()
    off[1, 2] += 2e-3
    assert fb.sanity("points", n, t, off)["position_error_m"] == pytest.approx(2e-3, rel=1e-9)

    # boxes: the reference's own orientation, with the angular velocity that keeps L and E
    pos0, vel0, w0, edges = fb.layout("boxes", n)
    moments = fb.box_moments(edges)
    R = fb.reference_orientations(n, t)
    quat = _quat_wxyz(Rotation.from_matrix(R))
    _, L0 = fb.rotational(np.tile([1.0, 0, 0, 0], (n, 1)), w0, moments)
    w_world = np.einsum("nij,nj->ni", R, np.einsum("nji,nj->ni", R, L0) / moments)
    good = fb.sanity("boxes", n, t, pos0 + vel0 * t, quat, w_world)
    assert good["position_error_m"] < 1e-13
    assert good["energy_drift"] < 1e-13 and good["angmom_drift"] < 1e-13
    assert good["orientation_error_rad"] < 1e-7  # quaternion round trip of scipy's matrix
    # a box that never turned keeps E and L but is caught by the orientation error
    still = fb.sanity("boxes", n, t, pos0 + vel0 * t, np.tile([1.0, 0, 0, 0], (n, 1)), w0)
    assert still["energy_drift"] < 1e-13 and still["angmom_drift"] < 1e-13
    assert still["orientation_error_rad"] > 0.1
    # rates scaled by 1.01: energy 2 %, L 1 %
    scaled = fb.sanity("boxes", n, t, pos0 + vel0 * t, quat, 1.01 * w_world)
    assert scaled["energy_drift"] == pytest.approx(0.0201, rel=1e-6)
    assert scaled["angmom_drift"] == pytest.approx(0.01, rel=1e-6)


def test_reference_orientation_of_a_box_spinning_about_a_principal_axis(monkeypatch):
    # w = (0, 3, 0) rad/s along a principal axis is a steady rotation: R = Rot_y(3 t)
    # (layout's random rates replaced by that one for this check).
    from vrsim_cli.tools.bench.problems import rotation_error

    t = 1.3
    steady = Rotation.from_rotvec([0.0, 3.0 * t, 0.0]).as_matrix()
    original = fb.layout

    def layout(scene, n):
        pos, vel, _, edges = original(scene, n)
        return pos, vel, np.array([[0.0, 3.0, 0.0]] * n), edges

    monkeypatch.setattr(fb, "layout", layout)
    fb.reference_orientations.cache_clear()
    try:
        R = fb.reference_orientations(1, t)
    finally:
        fb.reference_orientations.cache_clear()
    assert rotation_error(R[0], steady) < 1e-10


def test_vrsim_and_mujoco_scenes_hold_the_same_bodies():
    n = 7
    pos, vel, w, edges = fb.layout("boxes", n)
    model = fb.vrsim_model("boxes", n, 30, "verlet")
    assert model.n_body == n and model.n_steps == 30 and model.n_frames == 1
    np.testing.assert_array_equal(model.body_pos0, pos)
    np.testing.assert_array_equal(model.body_vel0, vel)
    np.testing.assert_allclose(np.sort(np.reshape(model.rigid.rot_moments, (n, 3)), axis=1),
                               np.sort(fb.box_moments(edges), axis=1), rtol=1e-12)
    points = fb.vrsim_model("points", n, 30, "rk4")
    assert points.rigid is None  # point masses: no rotation to pay for
    assert fb.vrsim_model("sphere", 1, 30, "rk4").rigid is not None  # a rigid body
    if bench_peers.available("mujoco"):
        import mujoco

        m = mujoco.MjModel.from_xml_string(fb.mujoco_xml("boxes", n))
        assert m.nbody == n + 1 and m.njnt == n and (m.geom_contype == 0).all()
        np.testing.assert_allclose(np.sort(m.body_inertia[1:], axis=1),
                                   np.sort(fb.box_moments(edges), axis=1), rtol=1e-9)
        np.testing.assert_allclose(m.body_mass[1:], fb.BOX_MASS)


# ----------------------------------------------------------------------------- the quick run

# Bounds of the correctness figures in the quick run (dt = 1 ms; T = 2 s at N = 1 and 10,
# 0.2 s at N = 100; |w| up to ~7 rad/s, so w dt <= 7e-3):
# - rk4 / RK4: fourth order; measured energy and L drift 1e-12 and orientation 7e-12 rad,
#   positions exact to round-off. 1e-8 is (w dt)^4 w T at the largest rates, still four
#   orders below any second-order method here.
# - verlet: second order with a bounded energy error ~ (w dt)^2 = 5e-5 (measured 1e-6);
#   its orientation error grows with time, (w dt)^2 w T <= 7e-4 rad (measured 1e-6).
# - first order (euler, symplectic-euler, MuJoCo Euler and implicitfast): energy, L and
#   orientation off by ~ w dt per unit of w T (measured energy 9e-3, orientation 0.10 rad
#   for euler): bounds 0.05 and 0.3 rad would still catch a missing gyroscopic term (an O(1)
#   change of L) or a box that does not turn.
# - point masses: rk4 and verlet are exact for constant gravity (round-off); every first-
#   order method here is off by exactly |g| dt T / 2 (tests/test_dynamics.py derives it).
ROUND_OFF_M = 1e-9  # positions up to 200 m over 2000 steps
EXACT_ORDERS = {"rk4", "RK4", "verlet"}
ROTATION_BOUNDS = {  # energy drift, L drift, orientation error (rad)
    "rk4": (1e-8, 1e-8, 1e-8), "RK4": (1e-8, 1e-8, 1e-8), "verlet": (1e-4, 1e-3, 1e-3),
    "symplectic-euler": (0.05, 0.05, 0.3), "euler": (0.05, 0.05, 0.3),
    "Euler": (0.05, 0.05, 0.3), "implicitfast": (0.05, 0.05, 0.3)}


@pytest.fixture(scope="module")
def quick_with_peers():
    return run_bench([fb.PROBLEM], quick=True, peers=True, repeats=1).rows


@pytest.fixture(scope="module")
def quick_alone():
    return run_bench([fb.PROBLEM], quick=True, peers=False, repeats=1).rows


def _check_rows(rows, engine, methods):
    sizes = {n for n, _ in fb.plan(True)}
    timed = [r for r in rows if r.engine == engine and not r.setting.startswith("start-up")]
    found = {fb.parse_setting(r.setting) + (r.bodies,) for r in timed}
    expected = {(scene, m, n) for scene in ("boxes", "points") for m in methods for n in sizes}
    expected |= {("sphere", m, 1) for m in (("rk4",) if engine == "vrsim" else methods)}
    assert found == expected and len(timed) == len(expected)
    for r in timed:
        scene, method = fb.parse_setting(r.setting)
        assert r.wall_s > 0
        assert r.steps == (fb.SPHERE_STEPS["quick"] if scene == "sphere" else
                           dict(fb.plan(True))[r.bodies])
        T = r.steps * fb.DT
        error = r.sanity["position_error_m"]
        if scene == "boxes":  # no gravity: every method is exact for x0 + v0 t
            assert error < ROUND_OFF_M, r
            energy, angmom, orientation = ROTATION_BOUNDS[method]
            assert r.sanity["energy_drift"] < energy, r
            assert r.sanity["angmom_drift"] < angmom, r
            assert r.sanity["orientation_error_rad"] < orientation, r
        elif method in EXACT_ORDERS:
            assert error < ROUND_OFF_M, r
        else:
            assert error == pytest.approx(0.5 * G * fb.DT * T, rel=1e-6), r


def test_quick_run_without_peers_gives_vrsim_rows_with_correct_figures(quick_alone):
    assert {r.engine for r in quick_alone} == {"vrsim", "python"}
    _check_rows(quick_alone, "vrsim", fb.VRSIM_INTEGRATORS)
    assert fb.ratios(quick_alone) == []
    startup, floor = [r for r in quick_alone if r.setting.startswith("start-up")]
    assert "warm cache" in startup.setting and startup.wall_s > 0
    assert startup.sanity["exit_code"] == 0
    # the reference: a Python that imports numba and sets up its target, nothing else
    assert floor.engine == "python" and "reference" in floor.setting
    assert floor.sanity["exit_code"] == 0 and 0 < floor.wall_s
    # scenarios/projectile.yaml is rk4 under constant gravity: exact to round-off
    assert startup.sanity["position_error_m"] < 1e-9
    # the warm runs used this process's cache, not a copy nested in it (which they once
    # compiled from scratch: the warm-up run then paid a first compile every bench)
    from vrsim_cli.kernels import jit

    assert not list(jit.cache_dir().glob("src-*"))


@pytest.mark.skipif(not bench_peers.available("mujoco"), reason="MuJoCo not installed "
                    "(pip install 'vrsim-cli[bench]')")
def test_quick_run_with_mujoco_gives_the_same_figures_and_the_ratios(quick_with_peers):
    rows = quick_with_peers
    assert {r.engine for r in rows} == {"vrsim", "mujoco", "python"}
    _check_rows(rows, "vrsim", fb.VRSIM_INTEGRATORS)
    _check_rows(rows, "mujoco", fb.MUJOCO_INTEGRATORS)
    found = fb.ratios(rows)
    table = {(e["scene"], e["bodies"], e["vrsim"], e["mujoco"]): e for e in found}
    sizes = [n for n, _ in fb.plan(True)]
    assert set(table) == ({(s, n, a, b) for s in ("boxes", "points") for n in sizes
                           for a, b in fb.PAIRS}
                          | {("sphere", 1, "rk4", m) for m in fb.MUJOCO_INTEGRATORS})
    by_key = {(r.engine,) + fb.parse_setting(r.setting) + (r.bodies,): r for r in rows
              if not r.setting.startswith("start-up")}
    for (scene, n, mine, theirs), e in table.items():
        a, b = by_key[("vrsim", scene, mine, n)], by_key[("mujoco", scene, theirs, n)]
        assert a.steps == b.steps  # the same work on both sides
        assert e["vrsim_over_mujoco"] == pytest.approx(a.wall_s / b.wall_s)
        assert e["vrsim_us_per_step"] == pytest.approx(1e6 * a.wall_s / a.steps)
    text = "\n".join(fb.markdown(report.problems()[fb.PROBLEM], rows))
    assert "| N | euler / Euler | symplectic-euler / Euler |" in text
    assert "One-body projectile (a sphere: a rigid body), us per step: vrsim rk4" in text
    assert "Start-up, warm cache" in text


def test_problem_is_registered_as_throughput_with_its_own_section():
    problem = report.problems()[fb.PROBLEM]
    assert problem.kind == "throughput" and problem.section is fb.markdown
    assert set(problem.runners) == {"vrsim", "mujoco"}
    assert [n for n, _ in fb.plan(False)] == [1, 10, 100, 1000, 10000]
    for quick in (True, False):  # every run about the same work, within the step limits
        for n, steps in fb.plan(quick):
            key = "quick" if quick else "full"
            assert fb.MIN_STEPS[key] <= steps <= fb.MAX_STEPS[key]
