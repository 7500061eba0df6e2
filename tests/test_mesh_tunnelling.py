"""No tunnelling through static triangle meshes, located and stepped (issue 15, item 1).

A seeded property test: spheres, boxes and capsules at 1-200 m/s (log-uniform), coming in
at 5-90 degrees to the surface, meet a flat part of a static triangle mesh at a random
time (j + tau) dt, j in {0, 1, 2}, tau in (0.01, 0.99), dt 10 ms, eps in {0, 0.5, 1},
frictionless, no gravity, no spin before the impact. The meshes are open surfaces (one
triangle; a flat grid with jittered inner vertices and random diagonals; a roof of two
slopes) and closed ones (a box; an icosphere; the convex hull of random points), written
as OBJ files, at a random scale (0.5-5) and pose.

Truth, written here and independent of the code under test. The hit triangle is drawn
from the mesh, and the side the body comes from is one with the whole mesh on or below
the triangle's plane (both sides of a flat surface; the outside of a closed convex mesh or
the roof). The body's extreme point along -n (sphere: r n below the centre; box: its
lowest corner; capsule: the lowest end cap's pole) touches the triangle at a random inner
point at the constructed time, and nothing of the mesh can be touched before (it is all
below the plane). Checked per case:
1. never on the far side: at every output sample the centre is never below the hit
   plane where it is over the flat face the triangle belongs to (the coplanar triangles
   of the mesh), nor (closed meshes, convex) inside the mesh; no corner (box), end cap
   pole (capsule) or sphere lies deeper than PENETRATION below the hit plane where it is
   over that face: at every sample in located mode, at the end in stepped mode (which
   solves every contact at the step's start: the far corner of a box or end of a
   capsule turned by the impact may sink into the face within the step, and the
   position pass takes it out over the next steps; stepped scenes run 3 steps past the
   last impact step);
2. spheres: the bounce follows the impact law of the plane, v' = v - (1 + eps)(v.n) n
   (tangential velocity unchanged with mu = 0), to 1e-9 relative, in both modes (stepped
   mode applies restitution to the approach velocity at the step's start, which without
   gravity is v);
3. spheres: the state at the end of the impact step (both modes) and at the end
   (located) is the closed form: located, the bounce at t_hit, c(t) = c_hit + v' (t -
   t_hit), to 1e-9 relative along the plane, and along n at most (1 + eps) times the
   tolerance above it (another case's impact in the same scene may cut the step when
   this sphere is within the tolerance of its face, and then it bounces there); stepped,
   the bounce at the impact step's start, x_j + v' dt, to 1e-9 relative (eps = 0: the
   landing, normal velocity -gap_j / dt, which closes the gap at the step's end).

234 cases (13 per scene); VRSIM_SLOW_TESTS=1 runs 2 160 (3 scenes of 40).
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh

from conftest import Steps
from test_stepped import _rot, _unit_quat, random_shape

DT = 0.01
TOLERANCE = 1e-3  # m, collision.tolerance (default)
SPACING = 100.0  # m between cases in one scene (a case moves < 2 m per step, 6 steps)
# Allowed depth of a body point below the face it hit: the collision tolerance (contacts
# and impacts are found within it) plus the resting solver's slop.
PENETRATION = 2.0 * TOLERANCE
SLOW = os.environ.get("VRSIM_SLOW_TESTS") == "1"
PER_SCENE = 40 if SLOW else 13  # 18 scenes: 234 cases; slow: 3 seeds each, 2 160
SEEDS = 3 if SLOW else 1
MESHES = ("triangle", "grid", "roof", "box", "icosphere", "hull")


def _mesh(family, rng):
    """(vertices (V, 3), faces (F, 3)) of a mesh about 2 m across, in its own frame."""
    if family == "triangle":
        angles = np.array([0.0, 2.1, 4.2]) + rng.uniform(-0.3, 0.3, 3)
        v = np.column_stack([np.cos(angles), np.zeros(3), np.sin(angles)])
        return v, np.array([[0, 1, 2]])
    if family == "grid":
        return _grid(int(rng.integers(2, 5)), 1.0, 0.3, rng)
    if family == "roof":
        w, h = rng.uniform(0.5, 1.2), rng.uniform(0.1, 1.0)
        v = np.array([[0, 0, -1], [0, 0, 1], [w, -h, -1], [w, -h, 1], [-w, -h, -1],
                      [-w, -h, 1]], float)
        return v, np.array([[0, 1, 3], [0, 3, 2], [0, 4, 5], [0, 5, 1]])
    if family == "box":
        m = trimesh.creation.box(extents=rng.uniform(0.5, 2.0, 3))
    elif family == "icosphere":
        m = trimesh.creation.icosphere(subdivisions=int(rng.integers(1, 3)))
    else:
        m = trimesh.convex.convex_hull(rng.normal(size=(int(rng.integers(8, 20)), 3)))
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def _grid(k, half, jitter, rng):
    """A flat k x k grid over [-half, half]^2 in the x-z plane: inner vertices moved by
    up to `jitter` cells in the plane, each cell split along a random diagonal."""
    x, z = np.meshgrid(np.linspace(-half, half, k + 1), np.linspace(-half, half, k + 1))
    x, z = x.ravel(), z.ravel()
    inner = (np.abs(x) < half) & (np.abs(z) < half)
    x[inner] += rng.uniform(-jitter, jitter, inner.sum()) * 2 * half / k
    z[inner] += rng.uniform(-jitter, jitter, inner.sum()) * 2 * half / k
    faces = []
    for i in range(k):
        for j in range(k):
            a, b, c, d = i * (k + 1) + j, i * (k + 1) + j + 1, (i + 1) * (k + 1) + j, \
                (i + 1) * (k + 1) + j + 1
            faces += [[a, b, d], [a, d, c]] if rng.random() < 0.5 else [[a, b, c], [b, d, c]]
    return np.column_stack([x, np.zeros_like(x), z]), np.array(faces)


def _support(kind, size, R, n):
    """Arm (3,) from the centre to the body's extreme point along -n."""
    if kind == "sphere":
        return -size[0] * n
    if kind == "box":
        corners = [R @ (0.5 * np.array(size) * s) for s in _SIGNS]
        return min(corners, key=lambda c: float(n @ c))
    ends = [R @ np.array([0.0, 0.5 * size[1] * s, 0.0]) for s in (-1.0, 1.0)]
    return min(ends, key=lambda e: float(n @ e)) - size[0] * n


_SIGNS = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3).astype(float)


def _points(kind, size, pos, quat):
    """World points (k, 3) whose depth below a plane bounds the body's: box corners,
    capsule end cap poles are taken per plane in `_deepest`; here the centres."""
    R = _rot(quat)
    if kind == "box":
        return pos + (R @ (0.5 * np.array(size) * _SIGNS).T).T
    if kind == "capsule":
        return pos + np.array([R[:, 1] * 0.5 * size[1] * s for s in (-1.0, 1.0)])
    return pos[None]


def _in_triangles(x, tris, n):
    """(k,) bool: do points x (k, 3), projected along n, fall inside any triangle (T, 3, 3)
    of the plane of normal n?"""
    inside = np.zeros(len(x), bool)
    for a, b, c in tris:
        s = [np.einsum("ki,i->k", np.cross(q - p, x - p), n) for p, q in ((a, b), (b, c),
                                                                          (c, a))]
        inside |= ((s[0] >= 0) & (s[1] >= 0) & (s[2] >= 0)) | \
            ((s[0] <= 0) & (s[1] <= 0) & (s[2] <= 0))
    return inside


def mesh_cases(kind, eps, mode, count, seed, folder):
    """`count` cases in one scene: case c = a static mesh (body 2c) and a 1 kg body (2c +
    1). Returns (scene text, cases)."""
    rng = np.random.default_rng(seed)
    steps = 4 if mode == "located" else 6  # stepped: 3 steps after the last impact step
    lines = [f"vrsim: 1\nduration: {steps * DT}\nframe_rate: {1 / DT}\ndt: {DT}\n"
             f"integrator: symplectic-euler\ngravity: [0, 0, 0]\n"
             f"collision: {{impacts: {mode}}}\nbodies:"]
    material = f"material: {{restitution: {eps}, friction: 0}}"
    cases = []
    side = int(np.ceil(count ** (1 / 3)))
    for c in range(count):
        centre = SPACING * np.array([c % side, (c // side) % side, c // side ** 2], float)
        family = MESHES[int(rng.integers(len(MESHES)))]
        v, faces = _mesh(family, rng)
        name = f"m{seed}_{c}.obj"
        (folder / name).write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in v.tolist()) +
                                   "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in
                                           faces))  # every digit: the truth uses them
        scale = float(np.exp(rng.uniform(np.log(0.5), np.log(5.0))))
        qm = _unit_quat(rng)
        world = centre + scale * (_rot(qm) @ v.T).T
        tris = world[faces]
        normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        while True:  # a triangle with the whole mesh on one side of its plane
            t = int(rng.integers(len(faces)))
            n = normals[t]
            height = (world - tris[t, 0]) @ n
            size_m = np.ptp(world, axis=0).max()
            sides = [s for s in (1.0, -1.0) if (s * height <= 1e-9 * size_m).all()]
            if sides:
                n = n * sides[int(rng.integers(len(sides)))]
                break
        face = [k for k in range(len(faces)) if abs(abs(normals[k] @ n) - 1.0) < 1e-9 and
                abs((tris[k, 0] - tris[t, 0]) @ n) < 1e-9 * size_m]
        w = rng.dirichlet([4.0, 4.0, 4.0])  # an inner point, away from the edges
        touch = w @ tris[t]
        size, shape = random_shape(rng, kind)
        qb = _unit_quat(rng)
        R = _rot(qb)
        speed = float(np.exp(rng.uniform(np.log(1.0), np.log(200.0))))
        angle = float(np.radians(rng.uniform(5.0, 90.0)))
        tangent = np.cross(n, rng.normal(size=3))
        tangent /= np.linalg.norm(tangent)
        vel = speed * (-np.sin(angle) * n + np.cos(angle) * tangent)
        when = (int(rng.integers(0, 3)) + float(rng.uniform(0.01, 0.99))) * DT
        pos = touch - _support(kind, size, R, n) - vel * when
        lines.append(f"  - {{name: m{c}, type: static, position: {centre.tolist()!r}, "
                     f"orientation: {qm.tolist()!r}, shape: {{type: mesh, file: {name}, "
                     f"scale: {scale!r}}}, collision: {{geometry: mesh}}, {material}}}")
        lines.append(f"  - {{name: b{c}, mass: 1, position: {pos.tolist()!r}, orientation: "
                     f"{qb.tolist()!r}, velocity: {vel.tolist()!r}, shape: {shape}, "
                     f"{material}}}")
        out = vel - (1.0 + eps) * float(vel @ n) * n
        closed = None
        if family in ("box", "icosphere", "hull"):  # convex: inside = below every face
            outward = normals * np.where(((world.mean(axis=0) - tris[:, 0]) * normals).sum(1)
                                         > 0.0, -1.0, 1.0)[:, None]
            closed = (outward, (outward * tris[:, 0]).sum(1))
        cases.append(dict(closed=closed, body=2 * c + 1, kind=kind, size=size, normal=n, origin=touch,
                          face=tris[face], when=when, vel=vel, out=out, family=family,
                          start=pos, speed=speed))
    return "\n".join(lines) + "\n", cases


def far_side(case, states):
    """The deepest (m) any point of the body went below the plane of the face it hit,
    while over that face; and whether its centre was ever below the plane there, or
    (closed convex meshes) inside the mesh (below the planes of all its faces)."""
    n, o = case["normal"], case["origin"]
    deepest, through = 0.0, False
    kind, size = case["kind"], case["size"]
    for s in states:
        pos, quat = s.body_pos[case["body"]], s.body_quat[case["body"]]
        pts = _points(kind, size, pos, quat)
        reach = size[0] if kind in ("sphere", "capsule") else 0.0
        low = pts - reach * n  # sphere and capsule: the pole of each end cap along -n
        depth = -(low - o) @ n
        over = _in_triangles(low, case["face"], n)
        if over.any():
            deepest = max(deepest, float(depth[over].max()))
        if _in_triangles(pos[None], case["face"], n)[0] and (pos - o) @ n < 0.0:
            through = True
        if case["closed"] is not None:
            planes_n, planes_o = case["closed"]
            if (planes_n @ pos - planes_o).max() < 0.0:
                through = True
    return deepest, through


def _run(kind, eps, mode, seed, tmp_path):
    text, cases = mesh_cases(kind, eps, mode, PER_SCENE, seed, tmp_path)
    scene = tmp_path / f"s{seed}.yaml"
    scene.write_text(text)
    from vrsim_cli.loop import run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene

    model = compile_model(load_scene(str(scene)))
    rec = Steps()
    result = run(model, make_state(model), rec)
    return model, rec.states, result.state, cases


def sphere_truth(case, eps, mode, t):
    """(position, velocity) of a sphere case at time t after its impact step (the one
    that holds `when`) has ended. located: the exact bounce at `when`. stepped: the bounce
    at the impact step's start (restitution on the approach velocity), or with eps = 0
    the landing that closes the gap exactly at the step's end; valid until the sphere
    meets anything else."""
    n, v, r = case["normal"], case["vel"], case["size"][0]
    hit = case["origin"] + r * n
    if mode == "located":
        return hit + case["out"] * (t - case["when"]), case["out"]
    j = int(case["when"] // DT)
    start = hit - v * (case["when"] - j * DT)  # free flight up to the step's start
    gap = float((start - hit) @ n)
    out = case["out"] if eps > 0 else v - float(v @ n) * n - gap / DT * n
    return start + out * (t - j * DT), out


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("eps", [0.0, 0.5, 1.0])
@pytest.mark.parametrize("kind", ["sphere", "box", "capsule"])
def test_no_body_ends_on_the_far_side_of_a_mesh(kind, eps, mode, tmp_path):
    seed = 1000 * ["sphere", "box", "capsule"].index(kind) + 10 * int(2 * eps) + \
        (mode == "stepped")
    bad = []
    for extra in range(SEEDS):
        bad += _check(kind, eps, mode, seed + 100 * extra, tmp_path)
    assert not bad, bad


def _check(kind, eps, mode, seed, tmp_path):
    """The failures (list) of the cases of one scene (module docstring)."""
    model, states, final, cases = _run(kind, eps, mode, seed, tmp_path)
    bad = []
    for c in cases:
        # located: never deeper than PENETRATION; stepped (every contact solved at the
        # step's start, a turning body's other end is not held within the step): the
        # centre never crosses, and the position pass leaves no overlap at the end
        deepest, through = far_side(c, states + [final] if mode == "located" else [final])
        if deepest > PENETRATION or through or far_side(c, states)[1]:
            bad.append((c["family"], c["speed"], "deepest", deepest, through))
            continue
        if kind != "sphere":
            continue
        # the state at the end of the impact step, and (located: nothing else is met)
        # the last one
        after = states[int(c["when"] // DT) + 1]
        checks = [after] + ([final] if mode == "located" else [])
        for s in checks:
            pos, vel = sphere_truth(c, eps, mode, s.t)
            v = s.body_vel[c["body"]]
            if np.abs(v - vel).max() > 1e-9 * c["speed"]:
                bad.append((c["family"], c["speed"], "velocity", s.t, v, vel))
                break
            d = s.body_pos[c["body"]] - pos
            along = float(d @ c["normal"])
            across = d - along * c["normal"]
            scale = 1.0 + np.abs(pos).max()
            # located: an impact of another case may bounce it up to the tolerance early
            early = (1.0 + eps) * TOLERANCE if mode == "located" else 0.0
            if np.abs(across).max() > 1e-9 * scale or \
                    not -1e-9 * scale <= along <= early + 1e-9 * scale:
                bad.append((c["family"], c["speed"], "position", s.t, along, across))
                break
    return bad


def _cube_stl(folder, half=0.5):
    trimesh.creation.box(extents=[2 * half] * 3).export(folder / "cube.stl")


@pytest.mark.parametrize("mode", ["located", "stepped"])
def test_a_ball_dropped_on_a_mesh_cube_rests_on_its_top(mode, tmp_path):
    """The reported scene (issue 15): a 0.1 m ball 5 cm above a 1 m cube mesh, gravity,
    default material (plastic). It fell through in both modes (fcl's depths had the
    wrong sign). Truth: free fall until its bottom touches y = 0.5, then rest on the
    top face, y = 0.6, with no sideways drift."""
    _cube_stl(tmp_path)
    (tmp_path / "s.yaml").write_text(
        "vrsim: 1\nduration: 0.5\ndt: 0.01\nframe_rate: 100\n"
        f"collision: {{impacts: {mode}}}\nbodies:\n"
        "  - {name: m, type: static, shape: {type: mesh, file: cube.stl}, "
        "collision: {geometry: mesh}}\n"
        "  - {name: ball, mass: 1, shape: {type: sphere, radius: 0.1}, "
        "position: [0.05, 0.65, 0]}\n")
    from vrsim_cli.loop import run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene

    model = compile_model(load_scene(str(tmp_path / "s.yaml")))
    rec = Steps()
    final = run(model, make_state(model), rec).state
    y = np.array([s.body_pos[1, 1] for s in rec.states])
    assert y.min() >= 0.6 - TOLERANCE  # never more than the tolerance into the face
    assert abs(final.body_pos[1, 1] - 0.6) <= TOLERANCE
    assert np.abs(final.body_pos[1] - [0.05, final.body_pos[1, 1], 0.0]).max() <= 1e-12
    assert np.abs(final.body_vel[1]).max() <= 1e-9


# rad/s. A ghost edge contact kicks a sliding box at O(v / size) ~ 10 rad/s; stepped mode's
# Gauss-Seidel (8 iterations) over the face's points leaves residuals of up to 2.3e-9
# rad/s in this run (decaying to 1e-14), located mode's solves are exact to round-off.
SPIN = {"located": 1e-9, "stepped": 1e-8}


@pytest.mark.parametrize("mode", ["located", "stepped"])
@pytest.mark.parametrize("kind", ["sphere", "box"])
def test_sliding_over_the_inner_edges_of_a_flat_mesh(kind, mode, tmp_path):
    """A sphere and a box slide (mu = 0, gravity) across a flat 6 x 6 grid of triangles
    with jittered inner vertices, over many inner edges and corners. Truth: a flat
    floor: the body keeps its height and its horizontal velocity exactly, no spin; an
    inner edge reporting a tilted ghost contact would kick it up or turn it."""
    v, faces = _grid(6, 4.0, 0.2, np.random.default_rng(3))
    (tmp_path / "grid.obj").write_text(
        "".join(f"v {a!r} {b!r} {c!r}\n" for a, b, c in v.tolist()) +
        "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist()))
    height = 0.2 if kind == "sphere" else 0.15
    shape = "{type: sphere, radius: 0.2}" if kind == "sphere" else \
        "{type: box, size: [0.4, 0.3, 0.5]}"
    (tmp_path / "s.yaml").write_text(
        "vrsim: 1\nduration: 1.0\ndt: 0.01\nframe_rate: 100\nintegrator: symplectic-euler\n"
        f"collision: {{impacts: {mode}}}\nbodies:\n"
        "  - {name: m, type: static, shape: {type: mesh, file: grid.obj}, "
        "collision: {geometry: mesh}, material: {restitution: 0, friction: 0}}\n"
        f"  - {{name: b, mass: 1, shape: {shape}, position: [-3.2, {height}, -2.9], "
        "velocity: [6.1, 0, 5.3], material: {restitution: 0, friction: 0}}\n")
    from vrsim_cli.loop import run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene

    model = compile_model(load_scene(str(tmp_path / "s.yaml")))
    rec = Steps()
    run(model, make_state(model), rec)
    for s in rec.states:
        assert abs(s.body_pos[1, 1] - height) <= 1e-6, (s.t, s.body_pos[1])
        assert np.abs(s.body_vel[1] - [6.1, s.body_vel[1, 1], 5.3]).max() <= 1e-9, s.t
        assert abs(s.body_vel[1, 1]) <= 1e-6
        if kind == "box":
            assert np.abs(s.body_angvel[1]).max() <= SPIN[mode], (s.t, s.body_angvel[1])


@pytest.mark.parametrize("other, noted", [("{type: sphere, radius: 0.1}", False),
                                          ("{type: box, size: [0.2, 0.2, 0.2]}", False),
                                          ("{type: cylinder, radius: 0.1, length: 0.2}",
                                           True)])
def test_validate_notes_mesh_pairs_that_go_to_fcl(other, noted, tmp_path):
    """Meshes meet spheres, capsules, boxes and planes in closed form (tested above);
    against a cylinder, hull or mesh the pair goes to python-fcl, which is not: the model
    says so in a note."""
    _cube_stl(tmp_path)
    (tmp_path / "s.yaml").write_text(
        "vrsim: 1\nduration: 0.1\ndt: 0.01\ncollision: {}\nbodies:\n"
        "  - {name: m, type: static, shape: {type: mesh, file: cube.stl}, "
        "collision: {geometry: mesh}}\n"
        f"  - {{name: b, mass: 1, shape: {other}, position: [0, 2, 0]}}\n")
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene

    notes = compile_model(load_scene(str(tmp_path / "s.yaml"))).notes
    assert any("python-fcl" in n and "bodies[1], a cylinder" in n for n in notes) == noted
