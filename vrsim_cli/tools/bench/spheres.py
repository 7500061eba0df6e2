"""`vrsim bench` problems 4 and 7: N spheres in a closed box, throughput with sanity figures.

Two problems share the scene and every engine's set-up: `spheres` at N = 100 and 1000
(`sizes`), and `spheres-scaling` at N = 8, 16, 27, 32, 33, 64, 128 (`SCALING_SIZES`,
issue 48 (b): the per-step cost must rise with N and stay <= 1 x MuJoCo's at every N;
32/33 straddle the old located/stepped switch), reported per N as vrsim's wall per step
over MuJoCo's fastest solver's (`scaling`, `scaling_markdown`).

N spheres (radius 0.05 m, 0.1 kg, restitution 0.5, friction 0.5) start on a jittered
lattice with random velocities (seeded, the same in every engine) inside a closed box of
six walls (inner width `side` * 0.12 + 0.1 m, height twice that), y up, gravity 9.81
m/s^2, dt = 0.01 s. There is no closed form for a pile; the figures are throughput
(body-steps per second of wall time, stepping only) and sanity: the mechanical energy at
the end over the initial (restitution and friction only take energy: > 1 is wrong), the
number of spheres that left the box (must be 0), and the deepest wall penetration.

Engines, each as a careful user would set them up for this scene:
- vrsim: symplectic Euler; `spheres` sets `collision: {impacts: stepped}`, `spheres-scaling`
  leaves `impacts` unset (the default mode the issue asks about; `auto` is the compiled
  step for every scene since ea23510, so both run the same step). The initial state is made
  before the timing, as in free-bodies; no writer, so `loop.run` makes one compiled call
  for all the steps, as MuJoCo's `mj_step(nstep)` does.
- MuJoCo: a free joint per sphere, the walls as planes (half-spaces); restitution through
  `solref = (timeconst, dampratio)`: a contact is a damped spring, and a linear damped
  oscillator rebounds with eps = exp(-zeta pi / sqrt(1 - zeta^2)), so zeta = -ln eps /
  sqrt(pi^2 + ln^2 eps) = 0.2155 for eps = 0.5. timeconst = 4 dt = 0.04 s: at 2 dt (the
  least MuJoCo allows) this under-damped contact diverges at dt = 0.01 s (energy x 1e12
  in 3 s with 100 spheres), at 3 dt it gains energy (x 3.6); 4 dt is the first stable
  multiple. friction "0.5 0.005 0.0001", Euler integrator. Solvers: Newton (the
  default), CG and PGS up to N = 128; CG and PGS at N = 1000, where Newton's dense
  factorisation takes ~1.5 s per step once the pile has formed (measured once, not run).
  The fastest is compared.
- PyBullet: DIRECT mode, one multibody per sphere, damping 0. Bullet multiplies the two
  bodies' restitution and friction, so every body gets sqrt(0.5): every pair then has
  exactly 0.5 (sphere-sphere and sphere-wall alike).
"""

from __future__ import annotations

import math

import numpy as np

RADIUS, MASS, EPS, MU, DT, G = 0.05, 0.1, 0.5, 0.5, 0.01, 9.81
TIMECONST = 4 * DT  # s, MuJoCo's contact spring (see above)
SEED = 4
PROBLEM, SCALING = "spheres", "spheres-scaling"
# issue 48 (b): no cliff at the old located/stepped switch (32 bodies); 3 s each (the
# pile forms and rests, as at N = 100), --quick 0.5 s (mostly the first impacts)
SCALING_SIZES = (8, 16, 27, 32, 33, 64, 128)
SCALING_STEPS = {"full": 300, "quick": 50}


def layout(n: int):
    """(positions (n, 3), velocities (n, 3), half width of the box, its height): spheres
    on a lattice of pitch 0.12 m from the floor up, random velocities ~ N(0, 1) m/s."""
    side = int(math.ceil(n ** (1.0 / 3.0) - 1e-9))
    half = 0.5 * (side * 0.12 + 0.1)
    height = 2.0 * (2.0 * half)
    rng = np.random.default_rng(SEED)
    cells = [(i, j, k) for j in range(side) for i in range(side) for k in range(side)][:n]
    pos = np.array([[-half + 0.11 + 0.12 * i, 0.11 + 0.12 * j, -half + 0.11 + 0.12 * k]
                    for i, j, k in cells]) + rng.uniform(-0.005, 0.005, (n, 3))
    vel = rng.normal(size=(n, 3))
    return pos, vel, half, height


def walls(half: float, height: float):
    """(name, point, inward normal) of the six walls."""
    return [("floor", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0)),
            ("lid", (0.0, height, 0.0), (0.0, -1.0, 0.0)),
            ("wall_x0", (-half, 0.0, 0.0), (1.0, 0.0, 0.0)),
            ("wall_x1", (half, 0.0, 0.0), (-1.0, 0.0, 0.0)),
            ("wall_z0", (0.0, 0.0, -half), (0.0, 0.0, 1.0)),
            ("wall_z1", (0.0, 0.0, half), (0.0, 0.0, -1.0))]


def sanity(pos, vel, angvel, pos0, vel0, half, height) -> dict:
    """Energy ratio (end / start, J/J), escaped spheres, deepest wall penetration (m)."""
    inertia = 0.4 * MASS * RADIUS ** 2

    def energy(p, v, w):
        return float(0.5 * MASS * (v * v).sum() + 0.5 * inertia * (w * w).sum() +
                     MASS * G * p[:, 1].sum())

    e0 = energy(pos0, vel0, np.zeros_like(vel0))
    gap = np.concatenate([half - np.abs(pos[:, [0, 2]]).ravel(), pos[:, 1],
                          height - pos[:, 1]])
    escaped = int(((np.abs(pos[:, [0, 2]]) > half).any(axis=1) | (pos[:, 1] < 0.0) |
                   (pos[:, 1] > height)).sum())
    return {"energy_ratio": energy(pos, vel, angvel) / e0, "escaped": escaped,
            "max_penetration_m": float(max(RADIUS - gap.min(), 0.0))}


def scene_text(n: int, steps: int, impacts: str | None = "stepped") -> str:
    """The vrsim scene; `impacts` None leaves the collision block's mode to `auto`."""
    pos, vel, half, height = layout(n)
    collision = "{}" if impacts is None else f"{{impacts: {impacts}}}"
    lines = [f"vrsim: 1\nname: spheres-{n}\nduration: {steps * DT!r}\nframe_rate: {1 / DT!r}\n"
             f"dt: {DT!r}\nintegrator: symplectic-euler\ngravity: [0, {-G!r}, 0]\n"
             f"collision: {collision}\nbodies:"]
    for name, point, normal in walls(half, height):
        lines.append(f"  - {{name: {name}, type: static, position: {list(point)}, "
                     f"shape: {{type: plane, normal: {list(normal)}}}}}")
    for i in range(n):
        lines.append(f"  - {{name: s{i}, mass: {MASS}, position: {pos[i].tolist()}, "
                     f"velocity: {vel[i].tolist()}, shape: {{type: sphere, radius: "
                     f"{RADIUS}}}, material: {{restitution: {EPS}, friction: {MU}}}}}")
    return "\n".join(lines) + "\n"


def row(engine, setting, n, steps, wall, figures, problem=PROBLEM) -> dict:
    return {"problem": problem, "engine": engine, "setting": setting, "bodies": n,
            "steps": steps, "wall_s": wall, "ms_per_step": 1e3 * wall / steps,
            "body_steps_per_s": n * steps / wall, "sanity": figures}


def sizes(quick: bool):
    """(N, steps) pairs: the issue's N = 100 and 1000. The full run covers the pile's
    forming and resting (3 s and 1.5 s); --quick mostly the first impacts."""
    return ((100, 100), (1000, 30)) if quick else ((100, 300), (1000, 150))


def scaling_sizes(quick: bool):
    """(N, steps) pairs of `spheres-scaling`."""
    steps = SCALING_STEPS["quick" if quick else "full"]
    return tuple((n, steps) for n in SCALING_SIZES)


def vrsim_spheres(quick: bool, repeats: int) -> list[dict]:
    return _vrsim_runs(sizes(quick), repeats, PROBLEM, "stepped")


def vrsim_spheres_scaling(quick: bool, repeats: int) -> list[dict]:
    return _vrsim_runs(scaling_sizes(quick), repeats, SCALING, None)


def _vrsim_runs(plan, repeats: int, problem: str, impacts: str | None) -> list[dict]:
    from vrsim_cli.loop import prepare, run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene
    from vrsim_cli.tools.bench.problems import best_time

    rows = []
    for n, steps in plan:
        model = compile_model(parse_scene(scene_text(n, steps, impacts),
                                          f"<bench {problem} {n}>"))
        prepare(model)  # kernels loaded (or compiled) before any timing
        state0 = make_state(model)  # runs are pure: every repeat starts from this state
        wall, result = best_time(lambda: run(model, state0), repeats)
        s = result.state
        assert s.step == steps, (s.step, steps)
        pos0, vel0, half, height = layout(n)
        first = len(walls(half, height))  # the scene lists the walls, then the spheres
        dyn = slice(first, first + n)
        mode = "impacts unset (auto: stepped)" if impacts is None else "stepped impacts"
        rows.append(row("vrsim", f"{mode} (compiled, speculative), "
                        f"{model.response.iterations}+{model.response.position_iterations} "
                        f"Gauss-Seidel iterations", n, s.step,
                        wall, sanity(s.body_pos[dyn], s.body_vel[dyn], s.body_angvel[dyn],
                                     pos0, vel0, half, height), problem))
    return rows


def _mujoco_xml(n: int, solver: str) -> str:
    pos, _, half, height = layout(n)
    ln = math.log(EPS)
    zeta = -ln / math.sqrt(math.pi ** 2 + ln * ln)
    geoms = "".join(
        f'<geom name="{name}" type="plane" size="0 0 1" pos="{" ".join(map(repr, point))}" '
        f'zaxis="{" ".join(map(repr, normal))}"/>'
        for name, point, normal in walls(half, height))
    bodies = "".join(
        f'<body pos="{" ".join(map(repr, p.tolist()))}"><freejoint/><geom type="sphere" '
        f'size="{RADIUS}" mass="{MASS}"/></body>' for p in pos)
    return (f'<mujoco><option timestep="{DT}" gravity="0 {-G} 0" integrator="Euler" '
            f'solver="{solver}"/><default><geom friction="{MU} 0.005 0.0001" '
            f'solref="{TIMECONST!r} {zeta!r}"/></default><worldbody>{geoms}{bodies}'
            f'</worldbody></mujoco>')


def mujoco_spheres(quick: bool, repeats: int) -> list[dict]:
    return _mujoco_runs(sizes(quick), repeats, PROBLEM)


def mujoco_spheres_scaling(quick: bool, repeats: int) -> list[dict]:
    return _mujoco_runs(scaling_sizes(quick), repeats, SCALING)


def _mujoco_runs(plan, repeats: int, problem: str) -> list[dict]:
    import mujoco

    from vrsim_cli.tools.bench.problems import best_time

    rows = []
    for n, steps in plan:
        pos0, vel0, half, height = layout(n)
        for solver in ("Newton", "CG", "PGS") if n <= 128 else ("CG", "PGS"):
            model = mujoco.MjModel.from_xml_string(_mujoco_xml(n, solver))
            data = mujoco.MjData(model)

            def go():
                mujoco.mj_resetData(model, data)
                data.qvel.reshape(n, 6)[:, :3] = vel0
                mujoco.mj_step(model, data, nstep=steps)
                return data

            wall, _ = best_time(go, repeats)
            q = data.qpos.reshape(n, 7)
            v = data.qvel.reshape(n, 6)  # angular velocity of a free joint: body frame
            rows.append(row("mujoco", f"Euler, {solver}, solref ({TIMECONST:g}, "
                            f"dampratio from eps)", n, steps, wall,
                            sanity(q[:, :3], v[:, :3], v[:, 3:], pos0, vel0, half, height),
                            problem))
    return rows


def pybullet_spheres(quick: bool, repeats: int) -> list[dict]:
    return _pybullet_runs(sizes(quick), repeats, PROBLEM)


def pybullet_spheres_scaling(quick: bool, repeats: int) -> list[dict]:
    return _pybullet_runs(scaling_sizes(quick), repeats, SCALING)


def _pybullet_runs(plan, repeats: int, problem: str) -> list[dict]:
    import time

    import pybullet

    rows = []
    each = math.sqrt(EPS), math.sqrt(MU)  # Bullet multiplies the pair's values
    for n, steps in plan:
        pos0, vel0, half, height = layout(n)
        client = pybullet.connect(pybullet.DIRECT)
        try:
            pybullet.setGravity(0.0, -G, 0.0, physicsClientId=client)
            pybullet.setTimeStep(DT, physicsClientId=client)
            for _, point, normal in walls(half, height):
                shape = pybullet.createCollisionShape(pybullet.GEOM_PLANE, planeNormal=normal,
                                                      physicsClientId=client)
                wall = pybullet.createMultiBody(0.0, shape, basePosition=point,
                                                physicsClientId=client)
                pybullet.changeDynamics(wall, -1, restitution=each[0], lateralFriction=each[1],
                                        physicsClientId=client)
            sphere = pybullet.createCollisionShape(pybullet.GEOM_SPHERE, radius=RADIUS,
                                                   physicsClientId=client)
            ids = []
            for p in pos0:
                body = pybullet.createMultiBody(MASS, sphere, basePosition=p.tolist(),
                                                physicsClientId=client)
                pybullet.changeDynamics(body, -1, restitution=each[0], lateralFriction=each[1],
                                        linearDamping=0.0, angularDamping=0.0,
                                        physicsClientId=client)
                ids.append(body)

            def go():
                for body, p, v in zip(ids, pos0, vel0):
                    pybullet.resetBasePositionAndOrientation(body, p.tolist(), (0, 0, 0, 1),
                                                             physicsClientId=client)
                    pybullet.resetBaseVelocity(body, v.tolist(), (0, 0, 0),
                                               physicsClientId=client)
                start = time.perf_counter()
                for _ in range(steps):
                    pybullet.stepSimulation(physicsClientId=client)
                return time.perf_counter() - start

            iterations = pybullet.getPhysicsEngineParameters(
                physicsClientId=client)["numSolverIterations"]

            # The reset of N bodies is set-up, not stepping: time the steps only.
            go()
            wall = min(go() for _ in range(repeats))
            state = [pybullet.getBasePositionAndOrientation(b, physicsClientId=client)[0]
                     for b in ids]
            vels = [pybullet.getBaseVelocity(b, physicsClientId=client) for b in ids]
        finally:
            pybullet.disconnect(client)
        rows.append(row("pybullet", f"default solver ({iterations} iterations), "
                        "restitution and friction sqrt(0.5) per body", n, steps, wall,
                        sanity(np.array(state), np.array([v[0] for v in vels]),
                               np.array([v[1] for v in vels]), pos0, vel0, half, height),
                        problem))
    return rows


# ----------------------------------------------------------------------------- spheres-scaling report


def scaling(rows) -> list[dict]:
    """Per N of `spheres-scaling`: vrsim's wall per step, each peer's fastest setting's,
    and vrsim's over MuJoCo's and PyBullet's (< 1: vrsim is faster; issue 48 (b) asks
    <= 1 against MuJoCo at every N). `rises`: whether vrsim's cost per step is above the
    previous N's (None at the first N)."""
    from vrsim_cli.tools.bench.problems import Row

    rows = [Row.of(r) for r in rows if Row.of(r).problem == SCALING]
    best = {}
    for r in rows:
        key = (r.bodies, r.engine)
        if key not in best or r.ms_per_step < best[key].ms_per_step:
            best[key] = r
    out, previous = [], None
    for n in sorted({r.bodies for r in rows}):
        mine = best.get((n, "vrsim"))
        entry = {"bodies": n, "vrsim_ms_per_step": mine.ms_per_step if mine else None}
        for engine in ("mujoco", "pybullet"):
            peer = best.get((n, engine))
            if peer is None:
                continue
            entry[f"{engine}_ms_per_step"] = peer.ms_per_step
            entry[f"{engine}_setting"] = peer.setting
            if mine is not None:
                entry[f"vrsim_over_{engine}"] = mine.ms_per_step / peer.ms_per_step
        if mine is not None:
            entry["rises"] = None if previous is None else mine.ms_per_step > previous
            previous = mine.ms_per_step
        out.append(entry)
    return out


def scaling_markdown(problem, rows) -> list[str]:
    """The section of bench.md: every row with its figures, then vrsim's wall per step
    against each peer's fastest per N, and where vrsim's cost does not rise with N."""
    from vrsim_cli.tools.bench.problems import throughput_table

    lines = throughput_table(problem, rows, ("wall/step (ms)", "body-steps/s"), lambda r: (
        f"{r.ms_per_step:.4f}", f"{r.body_steps_per_s:.4g}"))
    found = scaling(rows)
    if not found:
        return lines + [""]
    peers = [e for e in ("mujoco", "pybullet") if any(f"{e}_ms_per_step" in x for x in found)]
    names = {"mujoco": "MuJoCo", "pybullet": "PyBullet"}
    lines += ["", "Wall per step (ms) at each N, each peer at its fastest setting; vrsim / "
              "peer <= 1: vrsim is as fast or faster (issue 48 (b): <= 1 against MuJoCo):",
              "", "| N | vrsim | " + " | ".join(
                  f"{names[e]} (fastest) | vrsim / {names[e]}" for e in peers) + " |",
              "|---|---|" + "---|---|" * len(peers)]

    def ms(value):
        return "-" if value is None else f"{value:.4f}"

    for e in found:
        cells = []
        for peer in peers:
            setting = e.get(f"{peer}_setting", "")
            solver = f" ({setting.split(', ')[1]})" if peer == "mujoco" and setting else ""
            ratio = e.get(f"vrsim_over_{peer}")
            cells += [ms(e.get(f"{peer}_ms_per_step")) + solver,
                      "-" if ratio is None else f"{ratio:.2f}"]
        lines.append(f"| {e['bodies']} | {ms(e['vrsim_ms_per_step'])} | "
                     + " | ".join(cells) + " |")
    falls = [(a["bodies"], b["bodies"]) for a, b in zip(found, found[1:])
             if b.get("rises") is False]
    lines += ["", "vrsim's cost per step rises with N at every step of the list." if not falls
              else "vrsim's cost per step does not rise from N = " + ", ".join(
                  f"{a} to {b}" for a, b in falls) + "."]
    return lines + [""]


def scaling_plot(rows, path, plt):
    """Log-log wall per step against N, one curve per engine and setting."""
    from vrsim_cli.tools.bench.problems import Row

    rows = [Row.of(r) for r in rows]
    fig, ax = plt.subplots(figsize=(6.4, 4.4))
    for engine, setting in dict.fromkeys((r.engine, r.setting) for r in rows):
        pts = sorted((r.bodies, r.ms_per_step) for r in rows
                     if (r.engine, r.setting) == (engine, setting))
        ax.loglog([n for n, _ in pts], [m for _, m in pts],
                  "o-" if engine == "vrsim" else "s--", label=f"{engine}: {setting}"[:60])
    ax.set_xlabel("N (spheres)")
    ax.set_ylabel("wall time per step (ms), best of repeats")
    ax.set_title(f"throughput: {SCALING}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
