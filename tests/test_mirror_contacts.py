"""Issue 15 item 2, the narrow phase's part: the contacts of a body and its mirror image
are their own mirror image, in both narrow phases (stages/collision, numpy, for located
impacts; kernels/collide.py, compiled, for stepped ones).

Body B is the mirror of body A in the plane x = 0 (positions (-x, y, z), orientation
R -> M R M, M = diag(-1, 1, 1)), pushed across the plane by a random overlap. The pair's
contacts (point p, normal n from A to B, depth d) must then map onto themselves under
(p, n, d) -> (M p, -M n, d): swapping the bodies and mirroring is the identity on this
scene. Random poses make A and B meet corner to corner (their nearest points to the
plane are corners), where a face axis of A and the mirrored face axis of B are equally
shallow: a narrow phase that takes the reference face from the first body gives one
contact off the plane, with a normal that is not the mirror of any other (that is what
tests/test_mirror_symmetry.py saw as 30 m/s of asymmetry). Capsules in the same way
(nearly parallel axes side by side, and random ones).

Truth: the symmetry itself. Tolerance 1e-12 m (points, depths) and 1e-12 (normals): both
halves are computed from exactly mirrored inputs (negating x is exact), so only the
order of a few operations differs: a few ulps of coordinates ~1 m.
"""

from __future__ import annotations

import numpy as np
import pytest

from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import parse_scene

TOL = 1e-12
M = np.array([-1.0, 1.0, 1.0])


def _rot(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def mirror_pair(seed: int, kind: str) -> str:
    """A scene (YAML) of body a and its mirror image b overlapping across x = 0."""
    rng = np.random.default_rng([15, 2, 7, seed])
    q = rng.normal(size=4)
    if kind == "capsule" and seed % 2:  # axis nearly in the mirror plane: side by side
        angle = rng.uniform(-np.pi, np.pi)
        tilt = rng.uniform(-1e-4, 1e-4)
        q = np.array([np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0])
        q = q + tilt * rng.normal(size=4)
    q /= np.linalg.norm(q)
    R = _rot(q)
    if kind == "box":
        half = rng.uniform(0.1, 0.3, 3)
        shape = f"{{type: box, size: {(2 * half).tolist()}}}"
        support = float(half @ np.abs(R[0]))  # the farthest a corner reaches along +x
    else:
        radius, length = rng.uniform(0.05, 0.15), rng.uniform(0.1, 0.4)
        shape = f"{{type: capsule, radius: {float(radius)}, length: {float(length)}}}"
        support = float(0.5 * length * abs(R[0, 1]) + radius)
    overlap = float(rng.uniform(1e-6, 1e-3))
    pos = [-support + overlap, 2.0, float(rng.uniform(-0.2, 0.2))]
    qa = q.tolist()
    qb = [float(q[0]), float(q[1]), float(-q[2]), float(-q[3])]
    body = "  - {{name: {n}, mass: 1, position: {p!r}, orientation: {q!r}, shape: {s}}}"
    return "\n".join([
        "vrsim: 1\nduration: 0.01\nframe_rate: 100\ndt: 0.01\n"
        "collision: {impacts: stepped}\nbodies:",
        body.format(n="a", p=pos, q=qa, s=shape),
        body.format(n="b", p=(M * pos).tolist(), q=qb, s=shape)]) + "\n"


def numpy_contacts(model, state):
    from vrsim_cli.stages.collision.detect import detect

    c = detect(model, state)
    return c.point, c.normal, c.depth


def compiled_contacts(model, state):
    from vrsim_cli.kernels import collide as kc
    from vrsim_cli.stages.collision import stepped as stage
    from vrsim_cli.stages.dynamics import motion as dynamics

    tb = stage.tables(model, dynamics)
    S, RS = np.zeros_like(tb["S"]), np.zeros_like(tb["RS"])
    stage._rows(model, state, S, RS)
    k, C, _, nf = kc.detect(tb["gf"], S, 0, np.zeros(model.n_body),
                            model.collision.tolerance, False)
    assert nf == 0
    return C[:k, kc.C_P:kc.C_P + 3], C[:k, kc.C_N:kc.C_N + 3], C[:k, kc.C_D]


def assert_mirror_invariant(point, normal, depth):
    rows = np.concatenate([point, normal, depth[:, None]], axis=1)
    image = np.concatenate([point * M, -normal * M, depth[:, None]], axis=1)
    for r in image:  # every contact's image is a contact
        assert np.abs(rows - r).max(axis=1).min() <= TOL, (r, rows)
    for r in rows:
        assert np.abs(image - r).max(axis=1).min() <= TOL, (r, rows)


@pytest.mark.parametrize("detect", [numpy_contacts, compiled_contacts],
                         ids=["numpy", "compiled"])
@pytest.mark.parametrize("kind", ["box", "capsule"])
@pytest.mark.parametrize("seed", range(12))
def test_a_body_and_its_mirror_image_touch_symmetrically(seed, kind, detect):
    model = compile_model(parse_scene(mirror_pair(seed, kind)))
    point, normal, depth = detect(model, make_state(model))
    assert len(depth) >= 1 and depth.max() > 0.0  # they overlap
    assert_mirror_invariant(point, normal, depth)
