"""`vrsim bench`: the registry of problems, running them, and the report (Markdown,
JSON, plots).

Layer 7. The problems, their truths and vrsim's runs are in `problems.py`; the peers'
runs in `peers.py` (MuJoCo, PyBullet) and `spheres.py` (problem 4 for every engine).
"""

from __future__ import annotations

import json
import os
import platform
from dataclasses import asdict
from pathlib import Path

import numpy as np

from vrsim_cli.tools.bench import freebodies as bench_free
from vrsim_cli.tools.bench import peers as bench_peers
from vrsim_cli.tools.bench import spheres as bench_spheres
from vrsim_cli.tools.bench.problems import (REPEAT_BUDGET_S, Point, Problem, Results, Row,
                                            _vrsim_bounce, _vrsim_dzhanibekov,
                                            _vrsim_projectile, _vrsim_stack, dt_label,
                                            throughput_table)

__all__ = ["REPEAT_BUDGET_S", "markdown", "plot", "problems", "run_bench", "summary",
           "throughput_summary", "to_json"]


# ----------------------------------------------------------------------------- registry


# what the two spheres-in-a-box problems check against (the same scene)
SPHERES_TRUTH = ("energy at the end over the start (<= 1), spheres that left the box (0), "
                 "deepest wall penetration in m")

def problems() -> dict[str, Problem]:
    listed = [
        Problem(
            name="projectile",
            description="a 0.2 kg point mass thrown at (3, 7, -1.5) m/s under gravity for 1 s",
            truth="closed form x0 + v0 t + g t^2 / 2",
            error_unit="m (position error at t = 1 s)",
            target_error=1e-6,
            runners={"vrsim": _vrsim_projectile,
                     "mujoco": bench_peers.mujoco_projectile,
                     "pybullet": bench_peers.pybullet_projectile}),
        Problem(
            name="bounce",
            description="a 1 kg ball (r = 0.1 m) dropped with its bottom 1 m above a plane, "
                        "restitution 0.8, g = 9.81, for 3 s (the drop and 5 bounces)",
            truth="apex heights h_k = h0 eps^(2k), impact times t_1 = sqrt(2 h0/g), "
                  "t_(k+1) = t_k + 2 eps^k sqrt(2 g h0)/g",
            error_unit="m (largest apex error over flights 0-5; apex = bottom height + "
                       "vy^2/(2g) at the flight's sample nearest its apex)",
            target_error=1e-9,
            runners={"vrsim": _vrsim_bounce, "mujoco": bench_peers.mujoco_bounce,
                     "pybullet": bench_peers.pybullet_bounce}),
        Problem(
            name="dzhanibekov",
            description="a torque-free 1 kg box 0.1 x 0.4 x 1.0 m spun at (0.01, 5, 0.01) "
                        "rad/s about its intermediate axis, for 20 s (five flips, the "
                        "first at 1.70 s)",
            truth="Euler's equations by scipy DOP853 at rtol 1e-12 (cached)",
            error_unit="rad (largest orientation error at t = 1, 2, ... 20 s)",
            target_error=1e-6,
            runners={"vrsim": _vrsim_dzhanibekov, "mujoco": bench_peers.mujoco_dzhanibekov,
                     "pybullet": bench_peers.pybullet_dzhanibekov}),
        Problem(
            name="spheres",
            description="N = 100 and 1000 spheres (r = 0.05 m, 0.1 kg, restitution 0.5, "
                        "friction 0.5) with random velocities in a closed box, g = 9.81, "
                        "dt = 0.01 s (tools/bench/spheres.py)",
            truth=SPHERES_TRUTH,
            kind="throughput",
            runners={"vrsim": bench_spheres.vrsim_spheres,
                     "mujoco": bench_spheres.mujoco_spheres,
                     "pybullet": bench_spheres.pybullet_spheres}),
        Problem(
            name=bench_spheres.SCALING,
            description="spheres in a box as in `spheres`, at N = 8, 16, 27, 32, 33, 64, "
                        "128, 3 s (--quick: 0.5 s), vrsim with `impacts` unset; wall per "
                        "step against N and vrsim / MuJoCo per N (issue 48 (b): rises "
                        "with N, <= 1 x MuJoCo at every N)",
            truth=SPHERES_TRUTH,
            kind="throughput",
            runners={"vrsim": bench_spheres.vrsim_spheres_scaling,
                     "mujoco": bench_spheres.mujoco_spheres_scaling,
                     "pybullet": bench_spheres.pybullet_spheres_scaling},
            section=bench_spheres.scaling_markdown),
        Problem(
            name="stack",
            description="ten 1 kg unit cubes stacked on a ground plane, friction 0.5, "
                        "5 s (--quick: 0.5 s); each engine also at coarser steps (1/5 ... "
                        "1/30 s; --quick: 1/15 s) for the wall per simulated second at "
                        "matched drift",
            truth="the top box's drift |p(T) - p(0)| in m and tilt in rad (both 0 for a "
                  "stack at rest)",
            kind="throughput",
            runners={"vrsim": _vrsim_stack, "mujoco": bench_peers.mujoco_stack,
                     "pybullet": bench_peers.pybullet_stack},
            section=stack_markdown),
        Problem(
            name=bench_free.PROBLEM,
            description="N = 1, 10, 100, 1000, 10000 (--quick: 1, 10, 100) free bodies, "
                        "dt = 1 ms, no contacts, one timed call of ~500 000 body-steps "
                        "(--quick: 20 000): torque-free spinning boxes (random edges 0.1-1 "
                        "m, w ~ N(0, 2 rad/s)), point masses under gravity, and one sphere "
                        "(a rigid body) under gravity with rk4; plus the wall time of a "
                        "whole `vrsim run scenarios/projectile.yaml` (tools/bench/"
                        "freebodies.py)",
            truth="boxes: largest relative drift of energy and of the world angular "
                  "momentum vector, orientation error (rad) of the first 4 boxes against "
                  "scipy DOP853 on Euler's equations, position error against x0 + v0 t "
                  "(m); points and sphere: position error against x0 + v0 t + g t^2/2 (m)",
            kind="throughput",
            runners={"vrsim": bench_free.vrsim_free_bodies,
                     "mujoco": bench_free.mujoco_free_bodies},
            section=bench_free.markdown),
    ]
    return {p.name: p for p in listed}


# ----------------------------------------------------------------------------- running


def run_bench(names=None, quick=False, peers=False, repeats=None,
              on_progress=None) -> Results:
    """Run the problems `names` (default all). `on_progress(done, total, what)` is called
    before each (problem, engine) pair, for a progress bar."""
    repeats = repeats or (2 if quick else 5)
    chosen = problems()
    results = Results()
    todo = [(name, engine, runner) for name in names or list(chosen)
            for engine, runner in chosen[name].runners.items()
            if engine == "vrsim" or (peers and bench_peers.available(engine))]
    for done, (name, engine, runner) in enumerate(todo):
        problem = chosen[name]
        if on_progress is not None:
            on_progress(done, len(todo), f"{name} ({engine}), {done + 1}/{len(todo)}")
        found = runner(quick, repeats)
        if problem.kind == "throughput":
            results.rows.extend(Row.of(item) for item in found)
        else:
            results.points.extend(found)
    return results


def summary(points: list[Point]) -> list[dict]:
    """Per problem and engine: least wall time reaching the target error (ratio to vrsim's),
    and the least error reached at all (with its setting and wall time)."""
    rows = []
    table = problems()
    for name in dict.fromkeys(p.problem for p in points):
        target = table[name].target_error
        best, least = {}, {}
        for p in points:
            if p.problem != name:
                continue
            if p.error <= target and (p.engine not in best or p.wall_s < best[p.engine].wall_s):
                best[p.engine] = p
            if p.engine not in least or (p.error, p.wall_s) < (least[p.engine].error,
                                                                least[p.engine].wall_s):
                least[p.engine] = p
        for engine in least:
            b, low = best.get(engine), least[engine]
            row = {"problem": name, "engine": engine, "target_error": target,
                   "best_wall_s": b.wall_s if b else None,
                   "method": f"{b.method}, dt = {b.dt:g} s" if b else "target not reached",
                   "least_error": low.error, "least_error_wall_s": low.wall_s,
                   "least_error_method": f"{low.method}, dt = {low.dt:g} s"}
            if engine != "vrsim" and "vrsim" in best:
                # a peer that misses the target is compared at its most accurate setting
                row["vrsim_over_peer"] = best["vrsim"].wall_s / (b or low).wall_s
            rows.append(row)
    return rows


def machine() -> dict:
    return {"python": platform.python_version(), "machine": platform.machine(),
            "processor": platform.processor() or "unknown", "cores": os.cpu_count(),
            "system": f"{platform.system()} {platform.release()}",
            "load_average": [round(x, 2) for x in os.getloadavg()]}


def _format_extra(extra: dict) -> str:
    return ", ".join(f"{key} {value:.3g}" for key, value in extra.items())


def markdown(results: Results, repeats_note: str) -> str:
    lines = ["# vrsim bench", "", f"Machine: {json.dumps(machine())}", "",
             f"Timing: {repeats_note}", ""]
    table = problems()
    points = results.points
    for name in dict.fromkeys(p.problem for p in points):
        problem = table[name]
        lines += [f"## {name}", "", f"{problem.description}. Truth: {problem.truth}. "
                  f"Error: {problem.error_unit}.", "",
                  "| engine | method | dt (s) | steps | wall (ms) | error | also |",
                  "|---|---|---|---|---|---|---|"]
        for p in points:
            if p.problem == name:
                lines.append(f"| {p.engine} | {p.method} | {p.dt:.6g} | {p.steps} | "
                             f"{1e3 * p.wall_s:.3f} | {p.error:.3e} | {_format_extra(p.extra)} |")
        lines += ["", f"Least wall time to reach error <= {problem.target_error:g}, and the "
                  "least error reached:", "",
                  "| engine | best setting | wall (ms) | vrsim / engine | least error | "
                  "at (setting, wall ms) |", "|---|---|---|---|---|---|"]
        for row in summary(points):
            if row["problem"] == name:
                wall = f"{1e3 * row['best_wall_s']:.3f}" if row["best_wall_s"] else "-"
                ratio = f"{row['vrsim_over_peer']:.2f}" if "vrsim_over_peer" in row else "-"
                if row["best_wall_s"] is None and "vrsim_over_peer" in row:
                    ratio += " (at its least error)"
                lines.append(f"| {row['engine']} | {row['method']} | {wall} | {ratio} | "
                             f"{row['least_error']:.2e} | {row['least_error_method']}, "
                             f"{1e3 * row['least_error_wall_s']:.3f} |")
        lines.append("")
    for name in dict.fromkeys(r.problem for r in results.rows):
        section = table[name].section or throughput_markdown
        lines += section(table[name], [r for r in results.rows if r.problem == name])
    return "\n".join(lines)


def throughput_summary(rows: list[Row]) -> list[dict]:
    """Per problem, number of bodies and engine: the highest body-steps/s, and vrsim's
    over it."""
    best = {}
    for r in rows:
        key = (r.problem, r.bodies, r.engine)
        if key not in best or r.body_steps_per_s > best[key].body_steps_per_s:
            best[key] = r
    out = []
    for (problem, bodies, engine), r in best.items():
        entry = {"problem": problem, "bodies": bodies, "engine": engine,
                 "setting": r.setting, "body_steps_per_s": r.body_steps_per_s,
                 "ms_per_step": r.ms_per_step}
        mine = best.get((problem, bodies, "vrsim"))
        if engine != "vrsim" and mine is not None:
            entry["vrsim_over_peer"] = mine.body_steps_per_s / r.body_steps_per_s
        out.append(entry)
    return out


def throughput_markdown(problem: Problem, rows: list[Row]) -> list[str]:
    lines = throughput_table(problem, rows, ("wall/step (ms)", "body-steps/s"), lambda r: (
        f"{r.ms_per_step:.3f}", f"{r.body_steps_per_s:.4g}"))
    lines += ["", "Highest throughput per engine (vrsim / engine > 1: vrsim is faster):", "",
              "| bodies | engine | best setting | wall/step (ms) | body-steps/s | "
              "vrsim / engine |", "|---|---|---|---|---|---|"]
    for e in throughput_summary(rows):
        ratio = f"{e['vrsim_over_peer']:.3g}" if "vrsim_over_peer" in e else "-"
        lines.append(f"| {e['bodies']} | {e['engine']} | {e['setting']} | "
                     f"{e['ms_per_step']:.3f} | {e['body_steps_per_s']:.4g} | {ratio} |")
    return lines + [""]


FRONTIER_FACTOR = 100.0  # issue 15's stack target: at a drift at least 100 x smaller


def stack_frontier(rows: list[Row], factor: float = FRONTIER_FACTOR) -> list[dict]:
    """Wall time per simulated second at matched accuracy: for each peer row of the stack
    (one engine and step), vrsim's cheapest row whose top-box drift is at most 1/factor
    of the peer's, and the ratio of the two walls per simulated second (vrsim / peer
    <= 1: vrsim is as fast or faster with `factor` x less drift); `same_dt`: vrsim's
    stepped row at the peer's step, if any, and the ratio of wall per step there."""
    stack = [r for r in rows if r.problem == "stack" and r.simulated_s > 0.0]
    mine = [r for r in stack if r.engine == "vrsim"]
    out = []
    for peer in (r for r in stack if r.engine != "vrsim"):
        entry = {"engine": peer.engine, "setting": peer.setting, "dt_s": _dt_of(peer),
                 "drift_m": peer.sanity["drift_m"],
                 "ms_per_simulated_s": 1e3 * peer.wall_s / peer.simulated_s}
        fit = [r for r in mine if r.sanity["drift_m"] <= peer.sanity["drift_m"] / factor]
        if fit:
            best = min(fit, key=lambda r: r.wall_s / r.simulated_s)
            entry.update(vrsim_setting=best.setting, vrsim_drift_m=best.sanity["drift_m"],
                         vrsim_ms_per_simulated_s=1e3 * best.wall_s / best.simulated_s)
            entry["vrsim_over_peer"] = entry["vrsim_ms_per_simulated_s"] / \
                entry["ms_per_simulated_s"]
        same = [r for r in mine if "stepped" in r.setting and _dt_of(r) == entry["dt_s"]]
        if same:
            entry["same_dt_vrsim_over_peer"] = same[0].ms_per_step / peer.ms_per_step
        out.append(entry)
    return out


def _dt_of(row: Row) -> float:
    """A stack row's step (s): its simulated time over its steps, to 1e-12 relative."""
    return float(f"{row.simulated_s / row.steps:.12g}")


def stack_markdown(problem: Problem, rows: list[Row]) -> list[str]:
    lines = throughput_markdown(problem, rows)
    frontier = stack_frontier(rows)
    if not frontier:
        return lines
    lines += [f"Wall time per simulated second at a drift at least {FRONTIER_FACTOR:g} x "
              "smaller: each peer setting against vrsim's cheapest setting that drifts "
              f"at most 1/{FRONTIER_FACTOR:g} as much (vrsim / engine <= 1: vrsim is as "
              "fast or faster); and vrsim's compiled (stepped) step at the same step, per "
              "step:", "",
              "| engine | dt | drift (m) | ms per simulated s | vrsim's cheapest within "
              f"1/{FRONTIER_FACTOR:g} the drift | its drift (m) | its ms per simulated s | vrsim / engine | "
              "same dt: vrsim / engine per step |", "|---|---|---|---|---|---|---|---|---|"]
    for e in frontier:
        mine = ("-", "-", "-", "none") if "vrsim_over_peer" not in e else (
            e["vrsim_setting"], f"{e['vrsim_drift_m']:.2e}",
            f"{e['vrsim_ms_per_simulated_s']:.3f}", f"{e['vrsim_over_peer']:.3g}")
        same = f"{e['same_dt_vrsim_over_peer']:.3g}" if "same_dt_vrsim_over_peer" in e \
            else "-"
        lines.append(f"| {e['engine']} | {dt_label(e['dt_s'])} | {e['drift_m']:.2e} | "
                     f"{e['ms_per_simulated_s']:.3f} | " + " | ".join(mine) + f" | {same} |")
    return lines + [""]


def plot(results: Results, folder: Path) -> list[Path]:
    """Work-precision plots (log-log error vs wall time, one curve per engine and method)
    and, per throughput problem, a bar chart of body-steps/s per engine and setting."""
    try:
        import matplotlib
    except ImportError:
        return []
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    points = results.points
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
        ax.legend(fontsize=6)
        written.append(_save(fig, folder / f"{name}.png", plt))
    for name in dict.fromkeys(r.problem for r in results.rows):
        rows = [r for r in results.rows if r.problem == name]
        if name == bench_free.PROBLEM:  # cost per body-step against N
            written.append(bench_free.plot(rows, folder / f"{name}.png", plt))
            continue
        if name == bench_spheres.SCALING:  # cost per step against N
            written.append(bench_spheres.scaling_plot(rows, folder / f"{name}.png", plt))
            continue
        fig, ax = plt.subplots(figsize=(6.4, 0.6 + 0.45 * len(rows)))
        ax.barh([f"{r.engine}: {r.setting}"[:60] for r in rows],
                [r.body_steps_per_s for r in rows])
        ax.set_xscale("log")
        ax.invert_yaxis()
        ax.tick_params(axis="y", labelsize=6)
        ax.set_xlabel("body-steps/s (best of repeats)")
        ax.set_title(f"throughput: {name}")
        written.append(_save(fig, folder / f"{name}.png", plt))
    return written


def _save(fig, path: Path, plt) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def to_json(results: Results) -> str:
    rows = [dict(asdict(r), ms_per_step=r.ms_per_step, body_steps_per_s=r.body_steps_per_s)
            for r in results.rows]
    return json.dumps({"machine": machine(), "points": [asdict(p) for p in results.points],
                       "summary": summary(results.points), "throughput": rows,
                       "throughput_summary": throughput_summary(results.rows),
                       "stack_frontier": stack_frontier(results.rows),
                       "spheres_scaling": bench_spheres.scaling(results.rows),
                       "free_bodies": bench_free.ratios(
                           [r for r in results.rows if r.problem == bench_free.PROBLEM])},
                      indent=2)
