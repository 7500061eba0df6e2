"""`vrsim bench`: speed reported together with error, as work-precision data.

Layer 7. Each reference problem has an independent truth (a closed form, or a
high-accuracy solution computed once). For every engine and method the problem is run at a
sweep of step sizes; each run reports (wall time, error). Timing covers only the stepping:
the model is built first, one warm-up run is made, and the best of `repeats` timed runs is
kept (machines here are noisy; the minimum is the least disturbed measurement).

Peers (MuJoCo, PyBullet) run the same problems in the same process when they are
installed (`pip install 'vrsim-cli[bench]'`); see `bench_peers.py` for their settings.
The report states, per problem, the least wall time each engine needs to reach the
problem's target error, and the ratio vrsim / peer.
"""

from __future__ import annotations

import json
import math
import platform
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from vrsim_cli.loop import run
from vrsim_cli.model import compile_model
from vrsim_cli.scene import parse_scene
from vrsim_cli.state import make_state


@dataclass
class Point:
    """One run: engine, method and setting, with its wall time and error."""

    problem: str
    engine: str  # vrsim | mujoco | pybullet
    method: str  # integrator or engine setting
    dt: float  # s
    wall_s: float  # best of the timed repeats, stepping only
    error: float  # problem's error measure (units in Problem.error_unit)
    steps: int


@dataclass
class Problem:
    name: str
    description: str
    truth: str  # how the reference is obtained
    error_unit: str
    target_error: float  # the comparison is made at this error
    runners: dict = field(default_factory=dict)  # engine -> runner(dts, repeats) -> [Point]


def best_time(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """One warm-up call, then the minimum wall time of `repeats` calls and the last result."""
    result = fn()
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return best, result


# ----------------------------------------------------------------------------- problems

PROJECTILE = {"x0": (0.0, 1.0, 0.0), "v0": (3.0, 7.0, -1.5), "g": (0.0, -9.81, 0.0),
              "mass": 0.2, "duration": 1.0}


def projectile_truth(t: float) -> np.ndarray:
    p = PROJECTILE
    return np.add(p["x0"], np.multiply(p["v0"], t)) + 0.5 * np.multiply(p["g"], t * t)


def _vrsim_projectile(dts, repeats, integrators=("euler", "symplectic-euler", "rk4")):
    p = PROJECTILE
    points = []
    for integrator in integrators:
        for dt in dts:
            scene = parse_scene(f"""
vrsim: 1
duration: {p['duration']}
frame_rate: {1.0 / dt}
dt: {dt}
integrator: {integrator}
gravity: {list(p['g'])}
bodies: [{{name: ball, mass: {p['mass']}, position: {list(p['x0'])},
          velocity: {list(p['v0'])}}}]
""", "<bench projectile>")
            model = compile_model(scene)
            wall, result = best_time(lambda: run(model, make_state(model)), repeats)
            state = result.state
            error = float(np.linalg.norm(state.body_pos[0] - projectile_truth(state.t)))
            points.append(Point("projectile", "vrsim", integrator, model.dt, wall, error,
                                state.step))
    return points


DZHANIBEKOV = {"size": (0.1, 0.4, 1.0), "mass": 1.0, "omega0": (0.01, 5.0, 0.01),
               "duration": 2.0, "min_dt": 2e-3, "tolerances": (1e-6, 1e-8, 1e-10)}


def dzhanibekov_truth() -> np.ndarray:
    """(3, 3) orientation of the free box at the end: Euler's equations in the body frame
    with quaternion kinematics, by scipy's DOP853 at rtol = atol = 1e-12 (an independent
    formulation and solver; scipy is in the `test` and `bench` extras)."""
    from scipy.integrate import solve_ivp

    from vrsim_cli.spatial import quat_to_matrix

    a, b, c = DZHANIBEKOV["size"]
    moments = DZHANIBEKOV["mass"] / 12.0 * np.array([b * b + c * c, a * a + c * c,
                                                     a * a + b * b])

    def rhs(_t, y):
        w, (qw, qx, qy, qz) = y[:3], y[3:]
        wx, wy, wz = w
        return np.concatenate([np.cross(moments * w, w) / moments, 0.5 * np.array(
            [-qx * wx - qy * wy - qz * wz, qw * wx + qy * wz - qz * wy,
             qw * wy - qx * wz + qz * wx, qw * wz + qx * wy - qy * wx])])

    sol = solve_ivp(rhs, (0.0, DZHANIBEKOV["duration"]),
                    np.concatenate([DZHANIBEKOV["omega0"], [1.0, 0.0, 0.0, 0.0]]),
                    method="DOP853", rtol=1e-12, atol=1e-12)
    q = sol.y[3:, -1]
    return quat_to_matrix(q / np.linalg.norm(q))


def rotation_error(R, R_ref) -> float:
    """rad, the angle between two orientations (accurate for tiny angles)."""
    return float(2.0 * np.arcsin(min(1.0, np.linalg.norm(R - R_ref) / (2.0 * math.sqrt(2)))))


def _vrsim_dzhanibekov(dts, repeats):
    from vrsim_cli.spatial import quat_to_matrix

    d = DZHANIBEKOV
    truth = dzhanibekov_truth()
    runs = [(integrator, dt, "") for integrator in ("euler", "symplectic-euler", "verlet", "rk4")
            for dt in dts if dt >= d["min_dt"]]
    runs += [("dopri5", max(dts), f"tolerance: {tol}") for tol in d["tolerances"]]
    points = []
    for integrator, dt, extra in runs:
        scene = parse_scene(f"""
vrsim: 1
duration: {d['duration']}
frame_rate: {1.0 / dt}
dt: {dt}
integrator: {integrator}
{extra}
gravity: [0, 0, 0]
bodies: [{{name: box, mass: {d['mass']}, shape: {{type: box, size: {list(d['size'])}}},
          angular_velocity: {list(d['omega0'])}}}]
""", "<bench dzhanibekov>")
        model = compile_model(scene)
        wall, result = best_time(lambda: run(model, make_state(model)), repeats)
        error = rotation_error(quat_to_matrix(result.state.body_quat[0]), truth)
        method = integrator + (f" tol={extra.split()[-1]}" if extra else "")
        points.append(Point("dzhanibekov", "vrsim", method, model.dt, wall, error,
                            result.state.step))
    return points


def problems() -> dict[str, Problem]:
    from vrsim_cli import bench_peers

    projectile = Problem(
        name="projectile",
        description="a 0.2 kg point mass thrown at (3, 7, -1.5) m/s under gravity for 1 s",
        truth="closed form x0 + v0 t + g t^2 / 2",
        error_unit="m (position error at t = 1 s)",
        target_error=1e-6,
        runners={"vrsim": _vrsim_projectile,
                 "mujoco": bench_peers.mujoco_projectile,
                 "pybullet": bench_peers.pybullet_projectile})
    dzhanibekov = Problem(
        name="dzhanibekov",
        description="a torque-free 1 kg box 0.1 x 0.4 x 1.0 m spun at (0.01, 5, 0.01) rad/s "
                    "about its intermediate axis, for 2 s (through its first flip at 1.70 s)",
        truth="Euler's equations by scipy DOP853 at rtol 1e-12",
        error_unit="rad (orientation error at t = 2 s)",
        target_error=1e-4,
        runners={"vrsim": _vrsim_dzhanibekov, "mujoco": bench_peers.mujoco_dzhanibekov})
    return {projectile.name: projectile, dzhanibekov.name: dzhanibekov}


# ----------------------------------------------------------------------------- running


def run_bench(names=None, quick=False, peers=False, repeats=None) -> list[Point]:
    from vrsim_cli import bench_peers

    dts = (1e-2, 4e-3, 2e-3, 1e-3) if quick else (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4)
    repeats = repeats or (2 if quick else 5)
    chosen = problems()
    points = []
    for name in names or list(chosen):
        problem = chosen[name]
        for engine, runner in problem.runners.items():
            if engine != "vrsim" and (not peers or not bench_peers.available(engine)):
                continue
            points.extend(runner(dts, repeats))
    return points


def summary(points: list[Point]) -> list[dict]:
    """Per problem and engine: least wall time reaching the target error; ratios to vrsim."""
    rows = []
    table = problems()
    for name in dict.fromkeys(p.problem for p in points):
        target = table[name].target_error
        best = {}
        for p in points:
            if p.problem == name and p.error <= target:
                if p.engine not in best or p.wall_s < best[p.engine].wall_s:
                    best[p.engine] = p
        engines = dict.fromkeys(p.engine for p in points if p.problem == name)
        for engine in engines:
            b = best.get(engine)
            row = {"problem": name, "engine": engine, "target_error": target,
                   "best_wall_s": b.wall_s if b else None,
                   "method": f"{b.method}, dt = {b.dt:g} s" if b else "target not reached"}
            if engine != "vrsim" and b and "vrsim" in best:
                row["vrsim_over_peer"] = best["vrsim"].wall_s / b.wall_s
            rows.append(row)
    return rows


def machine() -> dict:
    import os
    return {"python": platform.python_version(), "machine": platform.machine(),
            "processor": platform.processor() or "unknown", "cores": os.cpu_count(),
            "system": f"{platform.system()} {platform.release()}"}


def markdown(points: list[Point], repeats_note: str) -> str:
    lines = ["# vrsim bench", "", f"Machine: {json.dumps(machine())}", "",
             f"Timing: {repeats_note}", ""]
    table = problems()
    for name in dict.fromkeys(p.problem for p in points):
        problem = table[name]
        lines += [f"## {name}", "", f"{problem.description}. Truth: {problem.truth}. "
                  f"Error: {problem.error_unit}.", "",
                  "| engine | method | dt (s) | steps | wall (ms) | error |",
                  "|---|---|---|---|---|---|"]
        for p in points:
            if p.problem == name:
                lines.append(f"| {p.engine} | {p.method} | {p.dt:g} | {p.steps} | "
                             f"{1e3 * p.wall_s:.3f} | {p.error:.3e} |")
        lines += ["", f"Least wall time to reach error <= {problem.target_error:g}:", "",
                  "| engine | best setting | wall (ms) | vrsim / engine |", "|---|---|---|---|"]
        for row in summary(points):
            if row["problem"] == name:
                wall = f"{1e3 * row['best_wall_s']:.3f}" if row["best_wall_s"] else "-"
                ratio = f"{row['vrsim_over_peer']:.2f}" if "vrsim_over_peer" in row else "-"
                lines.append(f"| {row['engine']} | {row['method']} | {wall} | {ratio} |")
        lines.append("")
    return "\n".join(lines)


def plot(points: list[Point], folder: Path) -> list[Path]:
    """Work-precision plots (log-log error vs wall time), one curve per engine and method."""
    try:
        import matplotlib
    except ImportError:
        return []
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for name in dict.fromkeys(p.problem for p in points):
        fig, ax = plt.subplots(figsize=(6.4, 4.4))
        curves = dict.fromkeys((p.engine, p.method) for p in points if p.problem == name)
        for engine, method in curves:
            pts = [p for p in points if (p.problem, p.engine, p.method) == (name, engine, method)]
            # errors at round-off are plotted at 1e-17 so log axes keep them visible
            ax.loglog([p.wall_s for p in pts], [max(p.error, 1e-17) for p in pts], "o-",
                      label=f"{engine}: {method}")
        ax.set_xlabel("wall time (s), best of repeats")
        ax.set_ylabel("error")
        ax.set_title(f"work-precision: {name}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
        path = folder / f"{name}.png"
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)
    return written


def to_json(points: list[Point]) -> str:
    return json.dumps({"machine": machine(), "points": [asdict(p) for p in points],
                       "summary": summary(points)}, indent=2)
