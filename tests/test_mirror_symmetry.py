"""Issue 15 item 2: mirror-symmetric scenes stay mirror-symmetric to round-off.

Every scene here is its own mirror image in the plane x = 0 (gravity along -y lies in
it): a pair of identical bodies at mirror poses and velocities, or one body whose pose
and motion are themselves symmetric, on a ground plane. The mirror of a body's state is
(-x, y, z) for positions and velocities, q = (w, x, y, z) -> (w, x, -y, -z) for the
orientation (R -> M R M with M = diag(-1, 1, 1)) and (wx, -wy, -wz) for the angular
velocity, a pseudo-vector. So at every sample body B's state must be the mirror of body
A's; a solver that treats the contacts of one event one after another (Gauss-Seidel in
list order) or picks a box pair's reference face from the first body breaks it.

Truth: the symmetry itself (no code under test computes it). Tolerance 1e-9 (m, m/s,
rad/s, quaternion components) over 1.5 s: round-off of the two mirror halves (~1e-15 per
step) grows over ~150 steps and a few impacts to ~1e-13; 1e-9 leaves four orders for it
and is still 10^5 below what an order-dependent solver produces here (~1e-4 and more).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import parse_scene

TOL = 1e-9
SEEDS = range(16)


class Recorder:
    def __init__(self):
        self.states = []

    def write(self, s):
        self.states.append((s.t, s.body_pos.copy(), s.body_vel.copy(), s.body_quat.copy(),
                            s.body_angvel.copy()))


def mirror_pos(p):
    return [-p[0], p[1], p[2]]


def mirror_quat(q):
    return [q[0], q[1], -q[2], -q[3]]


def mirror_angvel(w):
    return [w[0], -w[1], -w[2]]


def random_quat(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return (q if q[0] >= 0 else -q).tolist()


def random_shape(rng, kind):
    if kind == "sphere":
        return {"type": "sphere", "radius": float(rng.uniform(0.1, 0.3))}
    if kind == "box":
        return {"type": "box", "size": rng.uniform(0.15, 0.5, 3).tolist()}
    return {"type": "capsule", "radius": float(rng.uniform(0.05, 0.15)),
            "length": float(rng.uniform(0.1, 0.4))}


def pair_scene(seed: int, mode: str) -> tuple[dict, list[tuple[int, int]]]:
    """Two identical bodies at mirror poses thrown at each other above the ground."""
    rng = np.random.default_rng([15, 2, seed])
    kind = ("sphere", "box", "capsule")[seed % 3]
    shape = random_shape(rng, kind)
    material = {"restitution": float(rng.choice([0.0, 0.5, 1.0])),
                "friction": float(rng.choice([0.0, 0.3, 0.8]))}
    pos = [float(-rng.uniform(0.6, 1.0)), float(rng.uniform(0.6, 1.2)),
           float(rng.uniform(-0.2, 0.2))]
    vel = [float(rng.uniform(1.0, 4.0)), float(rng.uniform(-1.0, 1.0)),
           float(rng.uniform(-0.5, 0.5))]
    quat = random_quat(rng) if kind != "sphere" else [1.0, 0.0, 0.0, 0.0]
    w = rng.uniform(-3.0, 3.0, 3).tolist()
    a = {"name": "a", "mass": 1.3, "shape": shape, "material": material, "position": pos,
         "velocity": vel, "orientation": quat, "angular_velocity": w}
    b = dict(a, name="b", position=mirror_pos(pos), velocity=mirror_pos(vel),
             orientation=mirror_quat(quat), angular_velocity=mirror_angvel(w))
    return scene(mode, material, [a, b]), [(1, 2)]


def single_scene(seed: int, mode: str) -> tuple[dict, list[tuple[int, int]]]:
    """One body whose pose and motion are their own mirror image: turned about x only,
    moving in the y-z plane, spinning about x; it lands on an edge or face parallel to x
    (a box's four corners, a capsule's side) and must not drift or turn out of it."""
    rng = np.random.default_rng([15, 3, seed])
    kind = ("box", "capsule")[seed % 2]
    shape = random_shape(rng, kind)
    material = {"restitution": float(rng.choice([0.0, 0.5, 1.0])),
                "friction": float(rng.choice([0.0, 0.3, 0.8]))}
    # about x only: a box keeps its x faces on the mirror's sides, a capsule's axis
    # (local y) stays in the mirror plane
    angle = float(rng.uniform(-np.pi, np.pi))
    quat = [np.cos(angle / 2), np.sin(angle / 2), 0.0, 0.0]
    body = {"name": "a", "mass": 0.8, "shape": shape, "material": material,
            "position": [0.0, float(rng.uniform(0.5, 1.0)), 0.0],
            "velocity": [0.0, float(rng.uniform(-2.0, 1.0)), float(rng.uniform(-1.0, 1.0))],
            "orientation": [float(c) for c in quat],
            "angular_velocity": [float(rng.uniform(-4.0, 4.0)), 0.0, 0.0]}
    return scene(mode, material, [body]), [(1, 1)]


def scene(mode, material, bodies):
    return {"vrsim": 1, "name": "mirror", "dimension": 3, "duration": 1.5, "frame_rate": 100,
            "dt": 0.01, "integrator": "rk4", "collision": {"impacts": mode},
            "output": {"rate": 100},
            "bodies": [{"name": "ground", "type": "static",
                        "shape": {"type": "plane", "normal": [0, 1, 0]},
                        "material": material}] + bodies}


def mirror_errors(data: dict, pairs) -> tuple[float, float]:
    """(largest mirror asymmetry over every sample and pair, largest speed seen)."""
    model = compile_model(parse_scene(json.dumps(data), "<mirror>"))
    rec = Recorder()
    run(model, make_state(model), rec)
    worst, fastest = 0.0, 0.0
    for _, pos, vel, quat, angvel in rec.states:
        for i, j in pairs:
            worst = max(worst,
                        float(np.abs(pos[j] - mirror_pos(pos[i])).max()),
                        float(np.abs(vel[j] - mirror_pos(vel[i])).max()),
                        float(np.abs(angvel[j] - mirror_angvel(angvel[i])).max()),
                        # q and -q are one rotation
                        min(float(np.abs(quat[j] - mirror_quat(quat[i])).max()),
                            float(np.abs(quat[j] + np.array(mirror_quat(quat[i]))).max())))
        fastest = max(fastest, float(np.abs(vel).max()))
    return worst, fastest


# Cases that still fail, each with its measured cause (issue 15 item 2 is not finished
# for them). Strict: a fix that makes one pass fails here until it is taken off the list.
STEPPED_ORDER = ("stepped mode: kernels/stepped.py solves a pair's points by Gauss-Seidel "
                 "sweeps in list order (`impact_pair`, `rest`), and a body's mirror corners "
                 "(or its mirror body's) come in another order; the sweeps stop before "
                 "friction converges: the first asymmetric step's impulses differ by 1e-9 "
                 "(single 4, an edge landing) to 2e-3 N s (single 8), pair 10 in `rest` "
                 "(measured with 100 impact sweeps; taken to 5000, pair 13 passes and these "
                 "still do not). Since small islands rest to convergence (2026-12-06) singles "
                 "4 and 8 pass and pair 8 (two capsules meeting plastically, mu 0.8) fails: "
                 "asymmetry 0.13, 6e-16 with the islands' sweeps off (traced with "
                 "NUMBA_DISABLE_JIT); its island's sweeps in list order end on another "
                 "share of friction")
STEPPED_CLOSING = ("stepped mode, theta = 1/2 (rk4 here): the position pass pulls loaded "
                   "contacts that end apart closed (`kernels.stepped.push_out`) in sweeps in "
                   "list order, and the box landing on its edge ends 6.5e-8 out of its plane "
                   "(1e-16 with that closing off; off, 4 of 48 pivot draws gain energy, "
                   "tests/test_stepped_pivot.py). Found 2026-12-07; a pair's points closed "
                   "together would treat mirror corners alike")
KNOWN = {
    ("single", "stepped", 8): STEPPED_CLOSING,
    ("pair", "stepped", 4): STEPPED_ORDER,
    ("pair", "stepped", 7): STEPPED_ORDER,
    ("pair", "stepped", 8): STEPPED_ORDER,
    ("pair", "stepped", 10): STEPPED_ORDER,
    ("single", "stepped", 6): STEPPED_ORDER,
    ("single", "stepped", 14): STEPPED_ORDER,
}


def known(request, kind, mode, seed):
    reason = KNOWN.get((kind, mode, seed))
    if reason is not None:
        request.applymarker(pytest.mark.xfail(strict=True, reason=reason))


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("seed", SEEDS)
def test_mirror_pair_stays_mirror_symmetric(seed, mode, request):
    known(request, "pair", mode, seed)
    data, pairs = pair_scene(seed, mode)
    worst, fastest = mirror_errors(data, pairs)
    assert fastest > 0.5  # it moved
    assert worst <= TOL, f"asymmetry {worst:.3g} ({data['bodies'][1]['shape']['type']})"


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("seed", SEEDS)
def test_self_symmetric_body_stays_in_its_plane(seed, mode, request):
    known(request, "single", mode, seed)
    data, pairs = single_scene(seed, mode)
    worst, fastest = mirror_errors(data, pairs)
    assert fastest > 0.5
    assert worst <= TOL, f"asymmetry {worst:.3g} ({data['bodies'][1]['shape']['type']})"
