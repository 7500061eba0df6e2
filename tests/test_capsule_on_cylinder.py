"""A capsule lying on a cylinder's cap (a pen on a can): the pair's contacts.

fcl gives the pair one point; a capsule lying on a cap then rested on one end of its
line of contact, turned about it and gained energy in every impact mode (an independent
review measured 3.7 rad/s after 1 s, and up to 1.6e3 m/s in thin stacks, with
restitution 0). `cylinder_pairs.cylinder_capsule` gives the two ends of the capsule's
core segment within the cap's disc. Truth: a capsule placed lying on the cap, its centre
over the disc, at rest, stays at rest (1e-9 m and m/s after 1 s; round-off ~1e-15), and
the energy never grows.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import simulate

REST_TOL = 1e-9  # m and m/s: the truth is 0
INTEGRATORS = ("symplectic-euler", "verlet", "rk4")


def _scene(seed):
    rng = np.random.default_rng(seed)
    dt = float(rng.choice([1 / 60, 1 / 120, 1 / 240]))
    mode = ("located", "stepped")[seed % 2]
    integrator = INTEGRATORS[(seed // 2) % 3]
    can_r, can_h = float(rng.uniform(0.02, 0.06)), float(rng.uniform(0.02, 0.15))
    cap_r = float(rng.uniform(0.004, 0.02))
    cap_len = float(rng.uniform(0.2, 3.0)) * can_r  # the core may reach past the rim
    yaw = float(rng.uniform(0.0, 180.0))
    off = (rng.uniform(-0.3, 0.3, 2) * can_r).tolist()  # the centre over the disc
    static = seed % 3 == 0
    mu = float(rng.uniform(0.3, 1.0))
    can = (f"  - {{name: can, {'type: static' if static else 'mass: 0.3'}, position: "
           f"[0.0, {can_h / 2!r}, 0.0], shape: {{type: cylinder, radius: {can_r!r}, "
           f"length: {can_h!r}}}, material: {{friction: {mu!r}}}}}")
    pen = (f"  - {{name: pen, mass: {float(rng.uniform(0.005, 0.05))!r}, position: "
           f"[{off[0]!r}, {can_h + cap_r!r}, {off[1]!r}], euler_deg: [90.0, {yaw!r}, 0.0], "
           f"shape: {{type: capsule, radius: {cap_r!r}, length: {cap_len!r}}}, "
           f"material: {{friction: {mu!r}}}}}")
    return (f"vrsim: 1\nduration: 1.0\nframe_rate: 10\ndt: {dt!r}\nintegrator: {integrator}\n"
            f"collision: {{impacts: {mode}}}\nbodies:\n"
            f"  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}, "
            f"material: {{friction: {mu!r}}}}}\n{can}\n{pen}\n")


@pytest.mark.parametrize("seed", range(12))
def test_a_capsule_lying_on_a_cap_stays_at_rest(seed):
    """Random pens on random cans (static or on the ground), located and stepped, every
    integrator, dt 1/60-1/240 s: at rest after 1 s (on 086eda5 the pen turned about one
    end of its line of contact)."""
    text = _scene(seed)
    model, states, final = simulate(text)
    moved = np.abs(final.body_pos - model.body_pos0).max()
    speed = max(np.abs(final.body_vel).max(), np.abs(final.body_angvel).max())
    assert moved <= REST_TOL and speed <= REST_TOL, (text, moved, speed)


def test_the_pair_gives_the_ends_of_the_line_on_the_disc():
    """A capsule of core half-length 0.05 m lying across a can of radius 0.03 m, its
    centre 0.01 m off the axis along its own axis, 1e-4 m deep: two contacts, at the
    disc's edge (x = -0.03) and the core's end (x = 0.06 > 0.03, so the rim: x = 0.03),
    each 1e-4 m deep, normal up; written out here."""
    from vrsim_cli.model.collision import CAPSULE, CYLINDER, table, _row
    from vrsim_cli.stages.collision import cylinder_pairs
    from vrsim_cli.stages.collision.detect import place
    rows = []
    for body, kind, r, half in ((0, CYLINDER, 0.03, (0.03, 0.1, 0.03)),
                                (1, CAPSULE, 0.01, (0.01, 0.05, 0.01))):
        row = _row(body, kind, "exact")
        row["radius"], row["half"] = r, np.array(half)
        rows.append(row)
    cm = table(rows)
    s2 = np.sqrt(0.5)
    pos = np.array([[0.0, 0.0, 0.0], [0.01, 0.1 + 0.01 - 1e-4, 0.0]])
    quat = np.array([[1.0, 0.0, 0.0, 0.0], [s2, 0.0, 0.0, -s2]])  # capsule axis along x
    world = place(cm, pos, quat)
    pair, point, normal, depth = cylinder_pairs.cylinder_capsule(
        cm, world, np.array([0]), np.array([1]), 1e-3)
    assert len(depth) == 2
    np.testing.assert_allclose(depth, 1e-4, atol=1e-15)
    np.testing.assert_allclose(normal, [[0, 1, 0], [0, 1, 0]], atol=1e-15)
    np.testing.assert_allclose(sorted(point[:, 0]), [-0.03, 0.03], atol=1e-12)
