"""`vrsim bench`: speed reported together with error, as work-precision data.

Layer 7. Two kinds of problem:

- work precision (projectile, bounce, dzhanibekov): each has an independent truth (a
  closed form, or a high-accuracy solution computed once and cached). Every engine and
  method runs at a sweep of step sizes (or tolerances); each run gives a `Point` (wall
  time, error). The report states the least wall time each engine needs to reach the
  problem's target error, the ratio vrsim / peer, and the least error each engine reached.
- throughput (stack here; spheres from `spheres.py`): one run per engine and
  setting; each gives a `Row` (bodies, steps, wall time per step, body-steps/s) with named
  sanity figures (drift, tilt, energy ratio, escaped bodies) instead of an error.

Every problem is one entry of `report.problems()` with a runner per engine,
`runner(quick: bool, repeats: int) -> list[Point]` (work precision) or `-> list[Row]`
(throughput). Timing covers only the stepping: the model is built first, one warm-up run
is made, and the best of `repeats` timed runs is kept (machines here are noisy; the
minimum is the least disturbed measurement); runs longer than `REPEAT_BUDGET_S` stop
repeating once that much time has been spent timing them (at least one timed run).

Peers (MuJoCo, PyBullet) run the same problems in the same process when they are
installed (`pip install 'vrsim-cli[bench]'`); see `peers.py` for their settings.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import parse_scene

# s: timed repeats of one run stop once they have taken this long together (the warm-up
# and one timed run always happen), so that 20 s Dzhanibekov runs at small steps fit the
# ten minutes of a full run.
REPEAT_BUDGET_S = 3.0


@dataclass
class Point:
    """One work-precision run: engine, method and setting, with its wall time and error."""

    problem: str
    engine: str  # vrsim | mujoco | pybullet
    method: str  # integrator or engine setting
    dt: float  # s
    wall_s: float  # best of the timed repeats, stepping only
    error: float  # problem's error measure (units in Problem.error_unit)
    steps: int
    extra: dict = field(default_factory=dict)  # secondary figures, e.g. bounce_time_error_s


@dataclass
class Row:
    """One throughput run: engine and setting, its cost, and its sanity figures."""

    problem: str
    engine: str
    setting: str  # e.g. "verlet, dt = 1/60 s, 4 iterations"
    bodies: int  # moving bodies
    steps: int
    wall_s: float  # best of the timed repeats, stepping only (all steps)
    sanity: dict = field(default_factory=dict)  # e.g. drift_m, tilt_rad, energy_ratio
    simulated_s: float = 0.0  # s of simulated time (0: not given); the stack's frontier

    @staticmethod
    def of(item) -> "Row":
        """A Row from a Row or from a dict with at least its fields (derived keys such as
        ms_per_step are recomputed, not read)."""
        if isinstance(item, Row):
            return item
        return Row(**{name: item[name] for name in ("problem", "engine", "setting",
                                                     "bodies", "steps", "wall_s")},
                   sanity=dict(item.get("sanity", {})),
                   simulated_s=float(item.get("simulated_s", 0.0)))

    @property
    def ms_per_step(self) -> float:
        return 1e3 * self.wall_s / self.steps

    @property
    def body_steps_per_s(self) -> float:
        return self.bodies * self.steps / self.wall_s


@dataclass
class Problem:
    name: str
    description: str
    truth: str  # work precision: how the reference is obtained; throughput: the sanity figures
    error_unit: str = ""
    target_error: float | None = None  # work precision: the comparison is made at this error
    # engine -> runner(quick, repeats) -> [Point] (work precision) or [Row] (throughput)
    runners: dict = field(default_factory=dict)
    kind: str = "work-precision"  # or "throughput"
    # throughput: section(problem, rows) -> Markdown lines, in place of the generic table
    # (free-bodies: its ratio tables and start-up)
    section: Callable | None = None


@dataclass
class Results:
    points: list = field(default_factory=list)  # [Point], work-precision problems
    rows: list = field(default_factory=list)  # [Row], throughput problems


def best_time(fn: Callable[[], object], repeats: int) -> tuple[float, object]:
    """One warm-up call, then the minimum wall time of up to `repeats` calls (fewer once
    the timed calls have taken REPEAT_BUDGET_S) and the last result."""
    result = fn()
    best, spent = math.inf, 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        result = fn()
        took = time.perf_counter() - start
        best, spent = min(best, took), spent + took
        if spent >= REPEAT_BUDGET_S:
            break
    return best, result


def format_figure(value) -> str:
    """A sanity figure in a report table: integers as they are, floats to 3 digits."""
    if value is None:
        return "-"
    return f"{value:d}" if isinstance(value, (int, np.integer)) else f"{value:.3g}"


def throughput_table(problem: Problem, rows: list, heads: tuple, cells) -> list[str]:
    """A throughput problem's heading and one table line per row: engine, setting,
    bodies, steps, two cost columns (`heads`, and `cells(row)` -> two strings), then
    every sanity figure found in the rows."""
    figures = list(dict.fromkeys(key for r in rows for key in r.sanity))
    lines = [f"## {problem.name}", "", f"{problem.description}. Sanity: {problem.truth}.", "",
             f"| engine | setting | bodies | steps | {heads[0]} | {heads[1]} | "
             + " | ".join(figures) + " |",
             "|---|---|---|---|---|---|" + "---|" * len(figures)]
    for r in rows:
        values = " | ".join(format_figure(r.sanity.get(key)) for key in figures)
        first, second = cells(r)
        lines.append(f"| {r.engine} | {r.setting} | {r.bodies} | {r.steps} | {first} | "
                     f"{second} | {values} |")
    return lines


# ----------------------------------------------------------------------------- reference cache

def cache_dir() -> Path:
    """Where computed references are kept: $XDG_CACHE_HOME/vrsim/bench (~/.cache/...)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "vrsim" / "bench"


def cached_reference(name: str, params: dict, compute: Callable[[], np.ndarray]) -> np.ndarray:
    """compute(), computed once per distinct `params` and kept as JSON in `cache_dir()`.

    The file name carries a hash of the parameters and the file repeats them; a file whose
    parameters differ (or that cannot be read) is recomputed and replaced. A cache that
    cannot be written only costs the recomputation next time.
    """
    key = json.dumps(params, sort_keys=True)
    path = cache_dir() / f"{name}-{hashlib.sha256(key.encode()).hexdigest()[:16]}.json"
    try:
        data = json.loads(path.read_text())
        if data["params"] == json.loads(key):
            return np.array(data["value"], dtype=float)
    except (OSError, ValueError, KeyError, TypeError):
        pass
    value = np.asarray(compute(), dtype=float)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps({"params": json.loads(key), "value": value.tolist()}))
        os.replace(tmp, path)
    except OSError:
        pass
    return value


# ----------------------------------------------------------------------------- projectile

PROJECTILE = {"x0": (0.0, 1.0, 0.0), "v0": (3.0, 7.0, -1.5), "g": (0.0, -9.81, 0.0),
              "mass": 0.2, "duration": 1.0,
              "dts": (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2.5e-4), "quick_dts": (1e-2, 4e-3, 1e-3)}


def sweep(quick: bool, spec: dict) -> tuple:
    return spec["quick_dts"] if quick else spec["dts"]


def projectile_truth(t: float) -> np.ndarray:
    p = PROJECTILE
    return np.add(p["x0"], np.multiply(p["v0"], t)) + 0.5 * np.multiply(p["g"], t * t)


def _vrsim_projectile(quick, repeats):
    return vrsim_projectile(sweep(quick, PROJECTILE), repeats)


def vrsim_projectile(dts, repeats, integrators=("euler", "symplectic-euler", "rk4")):
    p = PROJECTILE
    points = []
    for integrator in integrators:
        for dt in dts:
            model = _model("projectile", p["duration"], dt, integrator, p["g"], f"""
bodies: [{{name: ball, mass: {p['mass']}, position: {list(p['x0'])},
          velocity: {list(p['v0'])}}}]
""")
            wall, result = best_time(lambda: run(model, make_state(model)), repeats)
            state = result.state
            error = float(np.linalg.norm(state.body_pos[0] - projectile_truth(state.t)))
            points.append(Point("projectile", "vrsim", integrator, model.dt, wall, error,
                                state.step))
    return points


def _model(name: str, duration: float, dt: float, integrator: str, gravity, rest: str):
    """The compiled scene of a bench run: one frame per step (so `on_frame` sees every
    step), the given integrator and gravity, then `rest` (YAML: bodies and other keys)."""
    text = (f"vrsim: 1\nduration: {duration}\nframe_rate: {1.0 / dt}\ndt: {dt}\n"
            f"integrator: {integrator}\ngravity: {list(gravity)}\n{rest}")
    return compile_model(parse_scene(text, f"<bench {name}>"))


# ----------------------------------------------------------------------------- bounce

# Ball dropped with its bottom h0 above the ground; flights 0 .. bounces are measured
# (flight 0 is the drop), and the impacts 1 .. bounces. Duration: past the last measured
# flight's landing (2.88 s), before vrsim's rest_speed ends the bouncing (bounce 15).
# Steps must stay below the shortest measured flight (0.30 s): the apex measure needs a
# sample in every flight.
BOUNCE = {"radius": 0.1, "mass": 1.0, "h0": 1.0, "eps": 0.8, "g": 9.81, "bounces": 5,
          "duration": 3.0, "integrators": ("euler", "symplectic-euler", "verlet", "rk4"),
          "quick_integrators": ("symplectic-euler", "rk4"),
          "dts": (1 / 10, 1 / 30, 1e-2, 1 / 300), "quick_dts": (1 / 10, 1 / 30)}


def bounce_truth() -> tuple[np.ndarray, np.ndarray]:
    """Apex heights of the bottom h_k = h0 eps^(2k), k = 0 .. bounces, and impact times
    t_1 = sqrt(2 h0 / g), t_(k+1) = t_k + 2 eps^k v0 / g with v0 = sqrt(2 g h0)."""
    b = BOUNCE
    k = np.arange(b["bounces"] + 1)
    apex = b["h0"] * b["eps"] ** (2 * k)
    v0 = math.sqrt(2.0 * b["g"] * b["h0"])
    flights = 2.0 * v0 * b["eps"] ** k[1:-1] / b["g"]  # flight times between impacts
    impacts = math.sqrt(2.0 * b["h0"] / b["g"]) + np.concatenate([[0.0], np.cumsum(flights)])
    return apex, impacts


def flight_apexes(t, height, vy, g: float):
    """Per ballistic flight in the samples (height of the bottom above the ground, m; vy
    the vertical velocity, m/s): its apex height and the time it lands.

    Samples with height <= 0 are in contact and belong to no flight; a flight also ends
    where vy turns from negative to positive (a bounce between two samples). Over a
    ballistic flight height + vy^2 / (2 g) is the apex height at every instant; the value
    is taken at the flight's sample nearest its apex (least |vy|), and the landing time
    is the root of the parabola through the flight's last sample. Returns (apexes,
    landings) as lists in flight order; the last flight's landing may lie past the samples.
    """
    flights, current, prev_vy = [], [], None
    for sample in zip(t, height, vy):
        airborne = sample[1] > 0.0
        bounced = prev_vy is not None and prev_vy < 0.0 < sample[2]
        if current and (not airborne or bounced):
            flights.append(current)
            current = []
        if airborne:
            current.append(sample)
        prev_vy = sample[2]
    if current:
        flights.append(current)
    apexes, landings = [], []
    for flight in flights:
        _, h, v = min(flight, key=lambda s: abs(s[2]))
        apexes.append(h + v * v / (2.0 * g))
        t_last, h, v = flight[-1]
        landings.append(t_last + (v + math.sqrt(v * v + 2.0 * g * h)) / g)
    return apexes, landings


def bounce_errors(apexes, impacts) -> tuple[float, float]:
    """(max apex error m over flights 0 .. bounces, max impact-time error s over impacts
    1 .. bounces). A flight or impact the run did not have counts with its true value as
    error (its apex 0 m, its time 0 s): a run that loses bounces cannot look accurate."""
    apex_true, impact_true = bounce_truth()
    n, m = len(apex_true), len(impact_true)
    apex = np.concatenate([apexes[:n], np.zeros(max(0, n - len(apexes)))])
    times = np.concatenate([impacts[:m], np.zeros(max(0, m - len(impacts)))])
    return float(np.max(np.abs(apex - apex_true))), float(np.max(np.abs(times - impact_true)))


def _vrsim_bounce(quick, repeats):
    return vrsim_bounce(sweep(quick, BOUNCE), repeats,
                        BOUNCE["quick_integrators" if quick else "integrators"])


def vrsim_bounce(dts, repeats, integrators=BOUNCE["integrators"]):
    """scenarios/bounce.yaml's physics (located impacts, as the scenario sets them;
    rest_speed 0.14 m/s). Apexes from the per-step states (a second, untimed run: the
    timed one calls nothing per step); impact times are the located ones (contacts' toi)."""
    b = BOUNCE
    points = []
    for integrator in integrators:
        for dt in dts:
            model = _model("bounce", b["duration"], dt, integrator, (0, -b["g"], 0), f"""
collision: {{impacts: located}}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}}}
  - {{name: ball, mass: {b['mass']}, position: [0, {b['h0'] + b['radius']}, 0],
     shape: {{type: sphere, radius: {b['radius']}}}, material: {{restitution: {b['eps']}}}}}
""")
            wall, result = best_time(lambda: run(model, make_state(model)), repeats)
            samples, impacts = [], []

            def record(state, dt=model.dt):
                samples.append((state.t, state.body_pos[1, 1] - b["radius"],
                                state.body_vel[1, 1]))
                toi = state.contacts.toi if state.contacts is not None else ()
                impacts.extend(state.t - dt + x for x in toi if np.isfinite(x))

            run(model, make_state(model), on_frame=record)
            apexes, _ = flight_apexes(*zip(*samples), g=b["g"])
            apex_error, time_error = bounce_errors(apexes, impacts)
            points.append(Point("bounce", "vrsim", integrator, model.dt, wall, apex_error,
                                result.state.step, {"bounce_time_error_s": time_error}))
    return points


# ----------------------------------------------------------------------------- dzhanibekov

DZHANIBEKOV = {"size": (0.1, 0.4, 1.0), "mass": 1.0, "omega0": (0.01, 5.0, 0.01),
               "duration": 20.0, "rtol": 1e-12}
# Sweeps: symplectic-euler only at 10 ms (first order is far off at any affordable step:
# 20 s at 1 ms is 20 000 Python steps; euler is left out: at 10 ms its energy grows until
# vrsim's energy guard stops the run at 4.6 s); the higher orders down to where they pass
# 1e-6 rad; dopri5 at tolerances on a 10 ms grid.
DZHANIBEKOV_SWEEP = {
    "full": {"verlet exact-flow": (1.0, 0.5, 1e-1, 1e-2), "symplectic-euler": (1e-2,),
             "verlet": (1e-2, 5e-3, 2.5e-3), "rk4": (1e-2, 5e-3, 2.5e-3, 1.25e-3),
             "dopri5": (1e-6, 1e-8, 1e-10, 1e-12)},
    "quick": {"verlet exact-flow": (1.0, 1e-1), "verlet": (1e-2,), "rk4": (1e-2,),
              "dopri5": (1e-8,)}}
# Methods that are an integrator with scene keys: verlet whose free-rotation drift is the
# exact torque-free flow (`rotation: {free_flow: exact}`, docs/dynamics.md).
DZHANIBEKOV_VARIANTS = {"verlet exact-flow": ("verlet", "rotation: {free_flow: exact}")}
DOPRI5_GRID_S = 1e-2


def dzhanibekov_moments(d=None) -> np.ndarray:
    d = d or DZHANIBEKOV
    a, b, c = d["size"]
    return d["mass"] / 12.0 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])


def dzhanibekov_truth(d=None) -> np.ndarray:
    """(n, 3, 3) orientations of the free box at t = 1, 2, ... d['duration'] s (whole
    seconds): Euler's equations in the body frame with quaternion kinematics, by scipy's
    DOP853 at rtol = atol = d['rtol'] (an independent formulation and solver; scipy is a
    core dependency). Computed once per parameter set and cached (`cached_reference`)."""
    d = dict(d or DZHANIBEKOV)
    params = {k: d[k] for k in ("size", "mass", "omega0", "duration", "rtol")}
    # what the value is: a changed meaning must not reuse an older cache file
    params["value"] = "orientations (3, 3) at t = 1, 2, ... duration s"
    params = json.loads(json.dumps(params))  # tuples -> lists, as the cache file holds them
    return cached_reference("dzhanibekov", params, lambda: _dzhanibekov_solve(d))


def _dzhanibekov_solve(d: dict) -> np.ndarray:
    from scipy.integrate import solve_ivp

    from vrsim_cli.maths.spatial import quat_to_matrix

    moments = dzhanibekov_moments(d)

    def rhs(_t, y):
        w, (qw, qx, qy, qz) = y[:3], y[3:]
        wx, wy, wz = w
        return np.concatenate([np.cross(moments * w, w) / moments, 0.5 * np.array(
            [-qx * wx - qy * wy - qz * wz, qw * wx + qy * wz - qz * wy,
             qw * wy - qx * wz + qz * wx, qw * wz + qx * wy - qy * wx])])

    seconds = np.arange(1, round(d["duration"]) + 1, dtype=float)
    sol = solve_ivp(rhs, (0.0, d["duration"]),
                    np.concatenate([d["omega0"], [1.0, 0.0, 0.0, 0.0]]),
                    method="DOP853", rtol=d["rtol"], atol=d["rtol"], t_eval=seconds)
    return np.array([quat_to_matrix(q / np.linalg.norm(q)) for q in sol.y[3:].T])


def dzhanibekov_error(quats, truth) -> float:
    """rad: the largest orientation error over the whole seconds, quats (n, 4) [w, x, y, z]
    at t = 1 .. n s against `dzhanibekov_truth` (the error of a spinning body oscillates
    with the flips, so a single end time could catch a run at a lucky phase)."""
    from vrsim_cli.maths.spatial import quat_to_matrix

    assert len(quats) == len(truth), (len(quats), len(truth))
    return max(rotation_error(quat_to_matrix(np.asarray(q)), R) for q, R in zip(quats, truth))


def rotation_error(R, R_ref) -> float:
    """rad, the angle between two orientations (accurate for tiny angles)."""
    return float(2.0 * np.arcsin(min(1.0, np.linalg.norm(R - R_ref) / (2.0 * math.sqrt(2)))))


def _vrsim_dzhanibekov(quick, repeats):
    return vrsim_dzhanibekov(DZHANIBEKOV_SWEEP["quick" if quick else "full"], repeats)


def vrsim_dzhanibekov(plan: dict, repeats, d=None):
    """plan: method (an integrator or a DZHANIBEKOV_VARIANTS name) -> steps (s), or
    tolerances for dopri5 (on a 10 ms grid)."""
    d = d or DZHANIBEKOV
    truth = dzhanibekov_truth(d)
    runs = [(method, dt, DZHANIBEKOV_VARIANTS.get(method, (method, ""))[1])
            for method, dts in plan.items() if method != "dopri5" for dt in dts]
    runs += [("dopri5", DOPRI5_GRID_S, f"tolerance: {tol}") for tol in plan.get("dopri5", ())]
    points = []
    for method, dt, extra in runs:
        integrator = DZHANIBEKOV_VARIANTS.get(method, (method, ""))[0]
        model = _model("dzhanibekov", d["duration"], dt, integrator, (0, 0, 0), f"""
{extra}
bodies: [{{name: box, mass: {d['mass']}, shape: {{type: box, size: {list(d['size'])}}},
          angular_velocity: {list(d['omega0'])}}}]
""")
        wall, result = best_time(lambda: run(model, make_state(model)), repeats)
        per_second = round(1.0 / model.dt)
        quats = []  # a second, untimed run samples the whole seconds
        run(model, make_state(model), on_frame=lambda state: quats.append(
            state.body_quat[0].copy()) if state.step % per_second == 0 else None)
        error = dzhanibekov_error(quats, truth)
        if integrator == "dopri5":
            method += f" tol={extra.split()[-1]}"
        points.append(Point("dzhanibekov", "vrsim", method, model.dt, wall, error,
                            result.state.step))
    return points


# ----------------------------------------------------------------------------- stack

# Ten 1 kg unit cubes on the ground (scenarios/stack.yaml without the heavy/slab pair).
# "dts": both modes; "coarse_dts": the compiled stepped mode also at coarser steps, for
# the work-precision frontier (`report.stack_frontier`: wall per simulated second at a
# drift 100 x smaller than each peer setting's); the peers sweep the same coarse steps.
STACK = {"boxes": 10, "size": 1.0, "mass": 1.0, "friction": 0.5, "g": 9.81,
         "duration": 5.0, "quick_duration": 0.5,
         "dts": (1 / 60, 1 / 240), "quick_dts": (1 / 60,),
         "coarse_dts": (1 / 5, 1 / 10, 1 / 15, 1 / 30), "quick_coarse_dts": (1 / 15,)}


def stack_sanity(pos0, pos, R) -> dict:
    """The top box's drift |p(T) - p(0)| (m) and tilt (rad, the angle of R(T))."""
    return {"drift_m": float(np.linalg.norm(np.subtract(pos, pos0))),
            "tilt_rad": rotation_error(R, np.eye(3))}


def dt_label(dt: float) -> str:
    inverse = 1.0 / dt
    return f"1/{round(inverse)} s" if abs(inverse - round(inverse)) < 1e-9 else f"{dt:g} s"


def _vrsim_stack(quick, repeats):
    return vrsim_stack(STACK["quick_duration"] if quick else STACK["duration"],
                       sweep(quick, STACK), repeats,
                       STACK["quick_coarse_dts" if quick else "coarse_dts"])


def vrsim_stack(duration, dts, repeats, coarse_dts=()):
    """vrsim's defaults for resting contact (the compiled contact step: 8 velocity
    iterations, islands of few contacts to convergence, shock levels, friction 0.5),
    verlet as in scenarios/stack.yaml, also at `coarse_dts`; and the interpreted located
    impacts (`impacts: located`: ~16 ms a step here) at `dts`."""
    from vrsim_cli.maths.spatial import quat_to_matrix

    s = STACK
    boxes = "\n".join(
        f"  - {{name: box{i}, mass: {s['mass']}, position: [0, {(i + 0.5) * s['size']}, 0], "
        f"shape: {{type: box, size: [{s['size']}, {s['size']}, {s['size']}]}}}}"
        for i in range(s["boxes"]))
    rows = []
    # the default (the compiled contact step, one numba call per step) and located
    # impacts (interpreted: 4 iterations, shock propagation)
    settings = (("{}", "defaults (stepped: the compiled contact step, 8 iterations, "
                       "shock levels)"),
                ("{impacts: located}", "located impacts (interpreted, 4 iterations, shock "
                                       "propagation)"))
    plan = [(c, dt) for c in settings for dt in dts] + \
        [(settings[0], dt) for dt in coarse_dts]
    for (collision, label), dt in plan:
        model = _model("stack", duration, dt, "verlet", (0, -s["g"], 0), f"""
collision: {collision}
bodies:
  - {{name: ground, type: static, shape: {{type: plane, normal: [0, 1, 0]}}}}
{boxes}
""")
        wall, result = best_time(lambda: run(model, make_state(model)), repeats)
        top = model.n_body - 1
        rows.append(Row("stack", "vrsim", f"verlet, dt = {dt_label(dt)}, {duration:g} s, "
                        f"{label}", s["boxes"], result.state.step, wall,
                        stack_sanity(model.body_pos0[top], result.state.body_pos[top],
                                     quat_to_matrix(result.state.body_quat[top])),
                        result.state.step * dt))
    return rows
