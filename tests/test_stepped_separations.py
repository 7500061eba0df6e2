"""The stepped solver's end-of-step separations of rounded contacts are exact (issue 15,
item 4: no mode gains energy).

`kernels.stepped.end_separations` tells the position pass how deep each contact ends
after the integrator moved the bodies. For a sphere or a capsule's end cap touching a
plane, the truth along the contact's normal n is geometry alone: the sphere's (or the
cap's) centre c1 at the step's end, n . c1 - r - offset. Carrying the witness point (the
lowest point at the step's start) with the body instead lifts it off the surface by
r (1 - cos theta) in a turn theta, so a spinning capsule ended millimetres deeper than
the pass believed, and the later steps that pushed it out gained energy (the strict
xfails of tests/test_stepped_impact_energy.py).

Cases: spheres and capsules (random sizes and orientations) touching or just above a
tilted ground plane; their end poses moved by random translations (<= 5 mm) and turns
(<= 0.6 rad about random axes: 60 rad/s for 10 ms). Truth: computed here from the scene's
own numbers (centres, radii, the capsule's axis along local y, half of `length` either
side) and the end pose. Tolerance 1e-12 m: the two sides are sums of a few products of
numbers below 2 m (~10 ulps of 2 m is 4e-15 m; 1e-12 leaves room and is still 10^7
below the 1e-5 m or more that carrying the witness point is wrong by at these turns).
"""

from __future__ import annotations

import numpy as np
import pytest

from test_stepped import _kernel_inputs, _rot, _unit_quat

TOL = 1e-12


def _axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def ground_scene(seed):
    """(scene text, plane normal, plane offset, bodies [(kind, radius, half length,
    centre, R)]) of 8 spheres and capsules at rest on or just above a tilted plane."""
    rng = np.random.default_rng([15, 4, seed])
    n = np.array([0.0, 0.0, 1.0]) + rng.uniform(-0.3, 0.3, 3) * [1, 1, 0]
    n /= np.linalg.norm(n)
    offset = float(rng.uniform(-0.5, 0.5))
    lines = ["vrsim: 1\nduration: 0.1\nframe_rate: 100\ndt: 0.01\nintegrator: "
             "symplectic-euler\ngravity: [0, 0, -9.81]\ncollision: {impacts: stepped}\n"
             "bodies:",
             f"  - {{name: ground, type: static, shape: {{type: plane, normal: "
             f"{n.tolist()!r}, offset: {offset!r}}}}}"]
    bodies = []
    for c in range(8):
        kind = ("sphere", "capsule")[c % 2]
        r = float(rng.uniform(0.03, 0.3))
        half = float(rng.uniform(0.02, 0.4)) if kind == "capsule" else 0.0
        q = _unit_quat(rng)
        R = _rot(q)
        axis = R[:, 1]
        # the lowest core point (centre, or the lower cap's centre) at height r - depth
        reach = half * abs(float(axis @ n))
        depth = float(rng.uniform(-0.002, 0.004))
        along = np.array([3.0 * c, 0.0, 0.0])
        along -= (along @ n) * n
        centre = along + (offset + r - depth + reach) * n
        shape = (f"{{type: sphere, radius: {r!r}}}" if kind == "sphere" else
                 f"{{type: capsule, radius: {r!r}, length: {2 * half!r}}}")
        lines.append(f"  - {{name: b{c}, mass: 1, position: {centre.tolist()!r}, "
                     f"orientation: {q.tolist()!r}, shape: {shape}}}")
        bodies.append((kind, r, half, centre, R))
    return "\n".join(lines) + "\n", n, offset, bodies


@pytest.mark.parametrize("seed", range(12))
def test_end_separation_of_a_rounded_contact_is_exact(seed):
    from vrsim_cli.kernels import collide as kc
    from vrsim_cli.kernels import dynamics as kd
    from vrsim_cli.kernels import stepped as ks

    text, n, offset, bodies = ground_scene(seed)
    model, tb, S, RS, _ = _kernel_inputs(text, steps=0)
    mf, gf = tb["mf"], tb["gf"]
    k, C, _, nf = kc.detect(gf, S, 0, np.full(S.shape[0], 0.01), 1e-3, False)
    assert nf == 0 and k >= 8  # every body touches or nearly touches the plane
    inv_m, IW = np.empty(S.shape[0]), np.empty((S.shape[0], 9))
    ks.body_tables(mf, 0, S, RS, inv_m, IW)
    K = np.zeros((k, ks.K_SIZE))
    V = np.zeros((S.shape[0], 3))
    for q in range(k):
        ks.prepare(K, q, C, q, S, inv_m, IW, V, V, V, V, tb["rb"], tb["rp"], tb["prm"])
    rng = np.random.default_rng([15, 5, seed])
    S1, RS1 = S.copy(), RS.copy()
    ends = {}
    for b, (kind, r, half, centre, R0) in enumerate(bodies, start=1):
        assert np.allclose(S[b, kd.S_POS:kd.S_POS + 3], centre)
        turn = _axis_angle(rng.normal(size=3), float(rng.uniform(0.05, 0.6)))
        R1 = turn @ R0
        x1 = centre + rng.uniform(-0.005, 0.005, 3)
        S1[b, kd.S_POS:kd.S_POS + 3] = x1
        slot = int(kd.slot_of(mf, b))
        assert slot >= 0  # spheres and capsules both turn
        RS1[slot, kd.RS_R:kd.RS_R + 9] = R1.reshape(-1)
        ends[b] = (R0, R1, x1)
    ks.end_separations(mf, K, k, S, RS, S1, RS1)
    worst, old = 0.0, 0.0
    for i in range(k):
        a, b = int(K[i, ks.K_A]), int(K[i, ks.K_B])
        assert a == 0 and np.allclose(K[i, ks.K_N:ks.K_N + 3], n)
        kind, r, half, centre, R0 = bodies[b - 1]
        _, R1, x1 = ends[b]
        if kind == "sphere":
            core0, core1 = centre, x1
        else:  # the cap this contact is on: the end r above its witness point
            witness = S[b, kd.S_POS:kd.S_POS + 3] + K[i, ks.K_RB:ks.K_RB + 3]
            e = min((-1.0, 1.0), key=lambda s: np.linalg.norm(
                centre + s * half * R0[:, 1] - (witness + r * n)))
            core0, core1 = centre + e * half * R0[:, 1], x1 + e * half * R1[:, 1]
        assert abs(n @ core0 - r - offset - K[i, ks.K_GAP]) <= TOL  # detection agrees
        truth = float(n @ core1) - r - offset
        worst = max(worst, abs(K[i, ks.K_SEND] - truth))
        # what carrying the witness point gives (the old rule), to show the test bites
        carried = x1 + R1 @ R0.T @ K[i, ks.K_RB:ks.K_RB + 3]
        old = max(old, abs(float(n @ carried) - offset - truth))
    assert worst <= TOL, worst
    assert old > 1e-5  # the turns are large enough that the witness rule would fail

