"""`vrsim bench` problem 6, free bodies: the cost of a step as N grows, with no contacts.

Three scenes, N = 1, 10, 100, 1000, 10000 (`--quick`: 1, 10, 100), dt = 1 ms, no
contacts, each as one timed run of many steps:

- boxes: N torque-free boxes (1 kg, edges uniform in 0.1 .. 1.0 m, identity orientation)
  spinning at random angular velocities (each component ~ N(0, 2 rad/s)) and drifting at
  random velocities (~ N(0, 1 m/s)), no gravity. Rigid bodies: every step integrates the
  rotation with the gyroscopic term.
- points: N point masses (0.2 kg) under gravity g = (0, -9.81, 0) with random velocities.
- sphere: one 0.2 kg sphere (r = 0.05 m; a shape with a volume makes it a rigid body in
  vrsim) thrown under gravity, rk4 only: the issue's one-body projectile, in us per step.

Seeded (SEED), the same in every engine. Every run takes about BODY_STEPS body-steps
(steps = BODY_STEPS / N, between MIN_STEPS and MAX_STEPS), so that small N are not timed
on a few microseconds and N = 10000 does not take minutes.

Correctness, so that a fast wrong answer shows (the `sanity` figures of every row):
- boxes: the largest relative drift over the bodies of the energy |E(T) - E(0)| / E(0)
  and of the world angular momentum vector |L(T) - L(0)| / |L(0)| (both conserved by the
  torque-free motion; the vector also catches a wrong orientation, L = R I R^T w), the
  largest orientation error (rad) of the first REFERENCE_BODIES boxes against Euler's
  equations solved by scipy's DOP853 (energy and L alone would pass a box that never
  turned), and the largest position error against x0 + v0 t (m);
- points, sphere: the largest position error against x0 + v0 t + g t^2 / 2 (m).
Both are computed by the same function from every engine's final state.

Engines:
- vrsim: the scene as a dict; up to 100 bodies it is read as scene text with the file's
  full validation, above that it goes straight to compile_model (10000 bodies exceed
  the scene file's value limit, and parsing them would take minutes); one output
  sample at the end and no writer, so `loop.run` makes one compiled call for all the steps (the
  blow-up checks and the energy guard included), as MuJoCo's `mj_step(nstep)` does.
- MuJoCo: one free joint per body, geoms with contype = conaffinity = 0 and the contact
  flag disabled (no collision stage at all), the same mass (box: the same edges, so the same inertia; points and sphere: a sphere
  geom of r = 0.05 m: a free joint also integrates its rotation, which MuJoCo cannot
  leave out for a free body); integrators Euler, implicitfast and RK4; one
  `mj_step(model, data, nstep)` call. Same coordinates and gravity vector as vrsim.

Ratios (`ratios`): vrsim's wall time over MuJoCo's at the same N for the pairs in PAIRS
(< 1: vrsim is faster). Start-up (`startup_rows`): the wall time of a whole
`vrsim run scenarios/projectile.yaml -o x.csv` as a subprocess, warm kernel cache (the
best of the repeats after one warm-up run) and, in the full run, once with an empty
cache (the first run after an install, which compiles).
"""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

PROBLEM = "free-bodies"
SEED = 16
DT = 1e-3  # s
G = (0.0, -9.81, 0.0)  # m/s^2, points and sphere; boxes have none
BOX_MASS, POINT_MASS, RADIUS = 1.0, 0.2, 0.05  # kg, kg, m
EDGE_RANGE = (0.1, 1.0)  # m, box edges
OMEGA_SIGMA, VEL_SIGMA = 2.0, 1.0  # rad/s, m/s
SIZES = {"full": (1, 10, 100, 1000, 10000), "quick": (1, 10, 100)}
BODY_STEPS = {"full": 500_000, "quick": 20_000}
MIN_STEPS, MAX_STEPS = {"full": 50, "quick": 20}, {"full": 10_000, "quick": 2_000}
VRSIM_INTEGRATORS = ("euler", "symplectic-euler", "verlet", "rk4")
MUJOCO_INTEGRATORS = ("Euler", "implicitfast", "RK4")
# vrsim integrator -> the MuJoCo integrator its time is compared with: the same order
# where MuJoCo has it (RK4), else MuJoCo's first-order pair (Euler: semi-implicit for free
# bodies; implicitfast for verlet, which `ratios` also gives against Euler).
PAIRS = (("euler", "Euler"), ("symplectic-euler", "Euler"), ("verlet", "implicitfast"),
         ("verlet", "Euler"), ("rk4", "RK4"))
SPHERE_STEPS = {"full": 10_000, "quick": 2_000}
REFERENCE_BODIES = 4  # boxes whose orientation is checked against an independent solution
STARTUP_SCENE = "scenarios/projectile.yaml"
STARTUP_REPEATS = {"full": 5, "quick": 2}


def plan(quick: bool) -> list[tuple[int, int]]:
    """(N, steps) of the boxes and points runs."""
    key = "quick" if quick else "full"
    return [(n, int(min(MAX_STEPS[key], max(MIN_STEPS[key], BODY_STEPS[key] // n))))
            for n in SIZES[key]]


def layout(scene: str, n: int):
    """The initial state of a scene: positions (n, 3) m on a line 2 m apart, velocities
    (n, 3) m/s, angular velocities (n, 3) rad/s (world frame = body frame at t = 0) and
    box edges (n, 3) m (boxes only; None otherwise). The same numbers for every engine."""
    rng = np.random.default_rng([SEED, n, ("boxes", "points", "sphere").index(scene)])
    pos = np.zeros((n, 3))
    pos[:, 0] = 2.0 * np.arange(n)
    vel = rng.normal(0.0, VEL_SIGMA, (n, 3))
    if scene != "boxes":
        return pos, vel, np.zeros((n, 3)), None
    edges = rng.uniform(*EDGE_RANGE, (n, 3))
    return pos, vel, rng.normal(0.0, OMEGA_SIGMA, (n, 3)), edges


def box_moments(edges: np.ndarray, mass: float = BOX_MASS) -> np.ndarray:
    """(n, 3) kg m^2, principal moments of solid boxes with edges (n, 3) m."""
    sq = np.asarray(edges, float) ** 2
    return mass / 12.0 * np.stack([sq[:, 1] + sq[:, 2], sq[:, 0] + sq[:, 2],
                                   sq[:, 0] + sq[:, 1]], axis=1)


def rotational(quat: np.ndarray, omega_world: np.ndarray, moments: np.ndarray):
    """(energy (n,) J, angular momentum (n, 3) kg m^2/s, world frame) of bodies with
    orientations quat (n, 4) [w, x, y, z], angular velocities (n, 3) rad/s in the world
    frame and principal moments (n, 3) along the body axes: L = R I R^T w, E = w.L / 2."""
    from vrsim_cli.maths.spatial import quat_to_matrix

    R = quat_to_matrix(quat)
    body = np.einsum("nji,nj->ni", R, omega_world)  # R^T w
    L = np.einsum("nij,nj->ni", R, moments * body)
    return 0.5 * np.einsum("ni,ni->n", omega_world, L), L


def sanity(scene: str, n: int, t: float, pos, quat=None, omega_world=None) -> dict:
    """The correctness figures of a final state at time t (module docstring)."""
    pos0, vel0, w0, edges = layout(scene, n)
    g = np.zeros(3) if scene == "boxes" else np.asarray(G)
    truth = pos0 + vel0 * t + 0.5 * g * t * t
    figures = {"position_error_m": float(np.abs(np.asarray(pos) - truth).max())}
    if scene == "boxes":
        moments = box_moments(edges)
        e0, L0 = rotational(np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), w0, moments)
        e1, L1 = rotational(np.asarray(quat), np.asarray(omega_world), moments)
        figures["energy_drift"] = float((np.abs(e1 - e0) / e0).max())
        figures["angmom_drift"] = float((np.linalg.norm(L1 - L0, axis=1)
                                         / np.linalg.norm(L0, axis=1)).max())
        figures["orientation_error_rad"] = orientation_error(np.asarray(quat), n, t)
    return figures


def orientation_error(quat: np.ndarray, n: int, t: float) -> float:
    """rad: the largest orientation error at time t of the first REFERENCE_BODIES boxes
    against `reference_orientations` (energy and angular momentum alone would pass a box
    that never turned)."""
    from vrsim_cli.maths.spatial import quat_to_matrix
    from vrsim_cli.tools.bench.problems import rotation_error

    truth = reference_orientations(n, float(t))
    return max(rotation_error(quat_to_matrix(q), R) for q, R in zip(quat, truth))


@functools.lru_cache(maxsize=32)
def reference_orientations(n: int, t: float) -> np.ndarray:
    """(k, 3, 3) orientations at time t of the first k = min(n, REFERENCE_BODIES) boxes:
    Euler's equations in the body frame with quaternion kinematics, by scipy's DOP853 at
    rtol = atol = 1e-12 (an independent formulation and solver; ~0.1 s per box)."""
    from scipy.integrate import solve_ivp

    from vrsim_cli.maths.spatial import quat_to_matrix

    _, _, w0, edges = layout("boxes", n)
    k = min(n, REFERENCE_BODIES)
    out = np.empty((k, 3, 3))
    for i, moments in enumerate(box_moments(edges[:k])):
        def rhs(_t, y, moments=moments):
            w, (qw, qx, qy, qz) = y[:3], y[3:]
            wx, wy, wz = w
            return np.concatenate([np.cross(moments * w, w) / moments, 0.5 * np.array(
                [-qx * wx - qy * wy - qz * wz, qw * wx + qy * wz - qz * wy,
                 qw * wy - qx * wz + qz * wx, qw * wz + qx * wy - qy * wx])])

        sol = solve_ivp(rhs, (0.0, t), np.concatenate([w0[i], [1.0, 0.0, 0.0, 0.0]]),
                        method="DOP853", rtol=1e-12, atol=1e-12, t_eval=[t])
        q = sol.y[3:, -1]
        out[i] = quat_to_matrix(q / np.linalg.norm(q))
    return out


def setting(scene: str, method: str) -> str:
    return f"{scene}: {method}, dt = {DT * 1e3:g} ms"


def parse_setting(text: str) -> tuple[str, str]:
    """(scene, method) of a row's setting (the inverse of `setting`)."""
    scene, rest = text.split(": ", 1)
    return scene, rest.split(",")[0]


def _row(engine, scene, method, n, steps, wall, figures):
    from vrsim_cli.tools.bench.problems import Row

    return Row(PROBLEM, engine, setting(scene, method), n, steps, wall, figures)


# ----------------------------------------------------------------------------- vrsim


def scene_data(scene: str, n: int, steps: int, integrator: str) -> dict:
    """The scene as the dict a YAML file would give (one frame: one sample, at the end)."""
    pos, vel, w, edges = layout(scene, n)
    bodies = []
    for i in range(n):
        body = {"name": f"b{i}", "position": pos[i].tolist(), "velocity": vel[i].tolist()}
        if scene == "boxes":
            body.update(mass=BOX_MASS, shape={"type": "box", "size": edges[i].tolist()},
                        angular_velocity=w[i].tolist())
        elif scene == "sphere":
            body.update(mass=POINT_MASS, shape={"type": "sphere", "radius": RADIUS})
        else:
            body.update(mass=POINT_MASS)
        bodies.append(body)
    duration = steps * DT
    return {"vrsim": 1, "name": f"free-bodies {scene} {n}", "duration": duration,
            "frame_rate": 1.0 / duration, "dt": DT, "integrator": integrator,
            "gravity": [0.0, 0.0, 0.0] if scene == "boxes" else list(G), "bodies": bodies}


def vrsim_model(scene: str, n: int, steps: int, integrator: str):
    """The compiled model. Scenes up to 100 bodies are read as scene text (JSON, which
    is YAML with exact floats) with the file's full validation; larger ones go straight
    from the dict to compile_model (module docstring)."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import Scene, parse_scene

    name = f"<bench free-bodies {scene} {n}>"
    data = scene_data(scene, n, steps, integrator)
    if n <= 100:
        scene_obj = parse_scene(json.dumps(data), name)
    else:
        scene_obj = Scene(name, Path("."), "", data)
    model = compile_model(scene_obj)
    assert model.n_steps == steps and model.n_frames == 1, (model.n_steps, model.n_frames)
    return model


def _vrsim_run(scene: str, n: int, steps: int, integrator: str, repeats: int):
    from vrsim_cli.loop import prepare, run
    from vrsim_cli.model.state import make_state
    from vrsim_cli.tools.bench.problems import best_time

    model = vrsim_model(scene, n, steps, integrator)
    prepare(model)  # kernels loaded (or compiled) before any timing
    state0 = make_state(model)  # runs are pure: every repeat starts from the same state
    wall, result = best_time(lambda: run(model, state0), repeats)
    s = result.state
    assert s.step == steps
    figures = sanity(scene, n, s.t, s.body_pos, s.body_quat, s.body_angvel)
    return _row("vrsim", scene, integrator, n, steps, wall, figures)


def vrsim_free_bodies(quick: bool, repeats: int) -> list:
    key = "quick" if quick else "full"
    rows = [_vrsim_run("sphere", 1, SPHERE_STEPS[key], "rk4", repeats)]
    for n, steps in plan(quick):
        for scene in ("boxes", "points"):
            for integrator in VRSIM_INTEGRATORS:
                rows.append(_vrsim_run(scene, n, steps, integrator, repeats))
    return rows + startup_rows(quick)


# ----------------------------------------------------------------------------- MuJoCo


def mujoco_xml(scene: str, n: int, integrator: str = "Euler") -> str:
    """The scene in MJCF: contype = conaffinity = 0 and the contact flag disabled (the
    flag skips mj_collision, whose broad phase otherwise asks for ~2 N^2 bytes of arena
    and costs ~5 % at N = 1000: MuJoCo at its cheapest for a scene without contacts).
    Above 1000 bodies the arena is sized explicitly (20 kB per body): MuJoCo's automatic
    size fails at 10000 free bodies ("Could not allocate memory"); the size does not
    change the cost of a step."""
    pos, _, _, edges = layout(scene, n)
    g = (0.0, 0.0, 0.0) if scene == "boxes" else G
    bodies = []
    for i in range(n):
        if scene == "boxes":
            geom = (f'type="box" size="{" ".join(repr(0.5 * float(e)) for e in edges[i])}" '
                    f'mass="{BOX_MASS!r}"')
        else:
            geom = f'type="sphere" size="{RADIUS!r}" mass="{POINT_MASS!r}"'
        bodies.append(f'<body pos="{" ".join(map(repr, pos[i].tolist()))}"><freejoint/>'
                      f'<geom {geom} contype="0" conaffinity="0"/></body>')
    size = f'<size memory="{20 * n}K"/>' if n > 1000 else ""
    return (f'<mujoco><option timestep="{DT!r}" integrator="{integrator}" '
            f'gravity="{" ".join(map(repr, g))}"><flag contact="disable"/></option>{size}'
            f'<worldbody>{"".join(bodies)}</worldbody></mujoco>')


def _mujoco_runs(scene: str, n: int, steps: int, integrators, repeats: int) -> list:
    """One model per scene and N (compiling 10000 bodies takes MuJoCo ~40 s), its
    integrator switched between the timed runs through model.opt."""
    import mujoco

    from vrsim_cli.maths.spatial import quat_to_matrix
    from vrsim_cli.tools.bench.problems import best_time

    _, vel, w, _ = layout(scene, n)
    model = mujoco.MjModel.from_xml_string(mujoco_xml(scene, n))
    data = mujoco.MjData(model)
    qvel = np.concatenate([vel, w], axis=1).ravel()  # free joint: v (world), w (body = world at t = 0)

    def go():
        mujoco.mj_resetData(model, data)
        data.qvel[:] = qvel
        mujoco.mj_step(model, data, nstep=steps)

    rows = []
    for integrator in integrators:
        model.opt.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{integrator.upper()}")
        wall, _ = best_time(go, repeats)
        q = data.qpos.reshape(n, 7)
        quat = q[:, 3:].copy()
        w_world = np.einsum("nij,nj->ni", quat_to_matrix(quat), data.qvel.reshape(n, 6)[:, 3:])
        figures = sanity(scene, n, data.time, q[:, :3], quat, w_world)
        rows.append(_row("mujoco", scene, integrator, n, steps, wall, figures))
    return rows


def mujoco_free_bodies(quick: bool, repeats: int) -> list:
    key = "quick" if quick else "full"
    rows = _mujoco_runs("sphere", 1, SPHERE_STEPS[key], MUJOCO_INTEGRATORS, repeats)
    for n, steps in plan(quick):
        for scene in ("boxes", "points"):
            rows += _mujoco_runs(scene, n, steps, MUJOCO_INTEGRATORS, repeats)
    return rows


# ----------------------------------------------------------------------------- start-up


def _startup_scene() -> Path | None:
    """scenarios/projectile.yaml of the source tree (an editable install), or None."""
    import vrsim_cli

    path = Path(vrsim_cli.__file__).resolve().parent.parent / STARTUP_SCENE
    return path if path.is_file() else None


def _vrsim_command() -> list[str]:
    script = Path(sys.executable).parent / "vrsim"
    if script.is_file():
        return [str(script)]
    found = shutil.which("vrsim")
    return [found] if found else [sys.executable, "-m", "vrsim_cli"]


def timed_run(scene: Path, out: Path, cache: str | None) -> tuple[float, int, str]:
    """(wall s, exit code, stderr) of one `vrsim run scene -o out` subprocess with the
    kernel cache in `cache` (None: the user's)."""
    env = dict(os.environ)
    # a user's later runs read the bytecode their first run wrote; without it every run
    # compiles vrsim's sources again (~0.1 s), which is not the start-up a user sees
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    if cache is not None:
        env["VRSIM_CACHE_DIR"] = cache
    start = time.perf_counter()
    proc = subprocess.run(_vrsim_command() + ["run", str(scene), "-o", str(out)], env=env,
                          capture_output=True, text=True, timeout=300)
    return time.perf_counter() - start, proc.returncode, proc.stderr


# numba imported as every run imports it (kernels/jit.py; its CPU target is set up only
# when something compiles) and nothing else of vrsim
NUMBA_FLOOR = "import vrsim_cli.kernels.jit"


def timed_python(code: str) -> tuple[float, int]:
    """(wall s, exit code) of `python -c code` with the environment of `timed_run`."""
    env = dict(os.environ)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                          timeout=300)
    return time.perf_counter() - start, proc.returncode


def startup_rows(quick: bool) -> list:
    """Rows `start-up: warm cache` (best of the repeats after a warm-up run, with the
    kernel cache of this process) and, in the full run, `start-up: empty cache` (one run
    with a new, empty cache folder: it compiles). steps: the scene's 1500; sanity: the
    exit code and the position error of the last CSV row against the closed form."""
    from vrsim_cli.kernels import jit  # noqa: F401  (exports the cache folder)
    from vrsim_cli.tools.bench.problems import Row

    scene = _startup_scene()
    if scene is None:
        return []
    key = "quick" if quick else "full"
    # warm runs: this process's cache, which they inherit (importing jit exports its base
    # folder as VRSIM_CACHE_DIR; given jit.cache_dir() itself, a run nested another
    # src-<digest> folder in it and compiled everything again there)
    warm = None
    rows = []
    with tempfile.TemporaryDirectory(prefix="vrsim-bench-") as tmp:
        out = Path(tmp) / "x.csv"
        timed_run(scene, out, warm)  # warm-up: fills the cache
        runs = [timed_run(scene, out, warm)
                for _ in range(STARTUP_REPEATS[key])]
        wall = min(r[0] for r in runs)
        code = max(r[1] for r in runs)
        rows.append(_startup_row("warm cache", wall, code, out))
        # the floor on this machine, for context: a Python that only imports numba
        # (numba imports numpy) as every run does
        floor = [timed_python(NUMBA_FLOOR) for _ in range(STARTUP_REPEATS[key])]
        rows.append(Row(PROBLEM, "python", f"start-up: reference, `python -c` importing "
                        f"numba (kernels/jit.py only)", 1, 1,
                        min(r[0] for r in floor), {"exit_code": max(r[1] for r in floor)}))
        if not quick:
            wall, code, _ = timed_run(scene, out, str(Path(tmp) / "empty-cache"))
            rows.append(_startup_row("empty cache (compiles)", wall, code, out))
    return rows


def _startup_row(which: str, wall: float, code: int, out: Path):
    from vrsim_cli.tools.bench.problems import Row

    figures = {"exit_code": int(code)}
    if code == 0:
        figures["position_error_m"] = projectile_csv_error(out)
    return Row(PROBLEM, "vrsim", f"start-up: {which}, `vrsim run {STARTUP_SCENE} -o x.csv`",
               1, 1500, wall, figures)


def projectile_csv_error(path: Path) -> float:
    """m: the ball's position error at the CSV's last sample against the closed form of
    scenarios/projectile.yaml (x0 = (0, 1, 0), v0 = 10 m/s at 45 degrees, g = 9.81)."""
    import csv

    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["entity"] == "ball"]
    last = rows[-1]
    t = float(last["t"])
    v = 10.0 / math.sqrt(2.0)
    truth = np.array([v * t, 1.0 + v * t - 0.5 * 9.81 * t * t, 0.0])
    got = np.array([float(last[k]) for k in ("px", "py", "pz")])
    return float(np.abs(got - truth).max())


# ----------------------------------------------------------------------------- report


def _timed(rows) -> dict:
    """(engine, scene, method, N) -> row, the start-up rows left out."""
    table = {}
    for r in rows:
        if r.setting.startswith("start-up"):
            continue
        scene, method = parse_setting(r.setting)
        table[(r.engine, scene, method, r.bodies)] = r
    return table


def ratios(rows) -> list[dict]:
    """Per scene, N and pair of PAIRS present: vrsim's wall time over MuJoCo's (< 1: vrsim
    is faster), with both in us per step. The sphere: vrsim rk4 against every MuJoCo
    integrator (the cheapest is the issue's reference)."""
    table = _timed(rows)
    out = []
    scenes_n = dict.fromkeys((scene, n) for (_, scene, _, n) in table)
    for scene, n in scenes_n:
        pairs = PAIRS if scene != "sphere" else [("rk4", m) for m in MUJOCO_INTEGRATORS]
        for mine, theirs in pairs:
            a = table.get(("vrsim", scene, mine, n))
            b = table.get(("mujoco", scene, theirs, n))
            if a is None or b is None:
                continue
            out.append({"scene": scene, "bodies": n, "vrsim": mine, "mujoco": theirs,
                        "vrsim_us_per_step": 1e3 * a.ms_per_step,
                        "mujoco_us_per_step": 1e3 * b.ms_per_step,
                        "vrsim_over_mujoco": a.wall_s / b.wall_s})
    return out


def markdown(problem, rows) -> list[str]:
    """The problem's section of bench.md: every row with its figures, then the ratios and
    the start-up."""
    from vrsim_cli.tools.bench.problems import throughput_table

    timed = [r for r in rows if not r.setting.startswith("start-up")]
    lines = throughput_table(problem, timed, ("wall/step (us)", "ns/body-step"), lambda r: (
        f"{1e3 * r.ms_per_step:.3f}", f"{1e9 / r.body_steps_per_s:.1f}"))
    found = ratios(rows)
    if found:
        lines += ["", "vrsim wall time / MuJoCo wall time at the same N and steps (< 1: "
                  "vrsim is faster):", ""]
        for scene in dict.fromkeys(e["scene"] for e in found):
            mine = [e for e in found if e["scene"] == scene]
            cols = list(dict.fromkeys((e["vrsim"], e["mujoco"]) for e in mine))
            lines += [f"**{scene}**", "", "| N | " + " | ".join(
                f"{a} / {b}" for a, b in cols) + " |", "|---|" + "---|" * len(cols)]
            for n in dict.fromkeys(e["bodies"] for e in mine):
                cells = {(e["vrsim"], e["mujoco"]): e for e in mine if e["bodies"] == n}
                lines.append(f"| {n} | " + " | ".join(
                    f"{cells[c]['vrsim_over_mujoco']:.2f}" if c in cells else "-"
                    for c in cols) + " |")
            lines.append("")
        sphere = [e for e in found if e["scene"] == "sphere"]
        if sphere:
            lines += ["One-body projectile (a sphere: a rigid body), us per step: vrsim rk4 "
                      f"{sphere[0]['vrsim_us_per_step']:.3f}; MuJoCo " + ", ".join(
                          f"{e['mujoco']} {e['mujoco_us_per_step']:.3f}" for e in sphere)
                      + ".", ""]
    for r in rows:
        if r.setting.startswith("start-up: reference"):
            lines.append(f"Start-up, {r.setting[len('start-up: '):]}: {r.wall_s:.3f} s of "
                         f"wall time (exit code {r.sanity['exit_code']}).")
        elif r.setting.startswith("start-up"):
            lines.append(f"Start-up, {r.setting[len('start-up: '):]}: {r.wall_s:.3f} s of "
                         f"wall time (exit code {r.sanity['exit_code']}, final position "
                         f"error {r.sanity.get('position_error_m', math.nan):.2e} m).")
    return lines + [""]


def plot(rows, path: Path, plt) -> Path:
    """Log-log ns per body-step against N, one panel per scene (boxes, points), one curve
    per engine and integrator."""
    table = _timed(rows)
    fig, axes = plt.subplots(1, 2, figsize=(9.6, 4.2), sharey=True)
    for ax, scene in zip(axes, ("boxes", "points")):
        curves = dict.fromkeys((e, m) for (e, s, m, _) in table if s == scene)
        for engine, method in curves:
            pts = sorted((n, r) for (e, s, m, n), r in table.items()
                         if (e, s, m) == (engine, scene, method))
            ax.loglog([n for n, _ in pts], [1e9 / r.body_steps_per_s for _, r in pts],
                      "o-" if engine == "vrsim" else "s--", label=f"{engine}: {method}")
        ax.set_title(f"free bodies: {scene}")
        ax.set_xlabel("N (bodies)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    axes[0].set_ylabel("wall time per body-step (ns), best of repeats")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
