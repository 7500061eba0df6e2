"""The walk table of slide 5.1, computed by the same walk code as `vrsim run`.

Layer 7. The table is built from a scene (the slide's by default, or any walk scene) run
through the ordinary loop; each row shows the values computed in one frame. As on the
slide, printed numbers are the exact values truncated toward zero (285.86 prints as 285),
and gamma is computed from alpha/beta as written in decimal, so that -0.36 * 100 prints
-36 and not -35 (see docs/slides.md). The slide's column labels are swapped; the labels
here are the correct ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from decimal import Decimal

from vrsim_cli.errors import InputError
from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.observer import input_at
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import Scene, parse_scene

SLIDE_ALPHAS = (-1.00, -0.99, -0.96, -0.91, -0.84, -0.75, -0.64, -0.51, -0.36, -0.19, 0.00)
SLIDE = {"position_zx": (300.0, 300.0), "direction_zx": (100.0, 100.0), "v_max": 200.0,
         "gamma_max": 100.0, "dt": 0.1, "alphas": SLIDE_ALPHAS, "betas": SLIDE_ALPHAS}
HEADERS = ("alpha", "beta", "v(alpha) (v_z, v_x)", "gamma(beta)", "V_new (z, x)",
           "d_new (z, x)")


@dataclass(frozen=True)
class Row:
    alpha: float
    beta: float
    v_zx: tuple  # m/s, the velocity of this frame (uses d before the frame's rotation)
    gamma: Decimal  # deg/s, beta * gamma_max in decimal arithmetic
    position_zx: tuple  # V_new
    direction_zx: tuple  # d_new


def slide_scene_text(position_zx=SLIDE["position_zx"], direction_zx=SLIDE["direction_zx"],
                     v_max=SLIDE["v_max"], gamma_max=SLIDE["gamma_max"], dt=SLIDE["dt"],
                     alphas=SLIDE["alphas"], betas=SLIDE["betas"]) -> str:
    """The walk-table scene for the given parameters (the defaults are the slide's)."""
    if len(alphas) != len(betas):
        raise InputError(f"{len(alphas)} alpha values but {len(betas)} beta values")
    (z, x), (dz, dx) = position_zx, direction_zx
    frames = "\n".join(f"    - [{a!r}, {b!r}]" for a, b in zip(alphas, betas))
    return f"""vrsim: 1
name: walk-table
duration: {len(alphas) * dt!r}
frame_rate: {1.0 / dt!r}
dt: {dt!r}
observer:
  mode: walk
  position: [{x!r}, 0, {z!r}]
  direction: [{dx!r}, 0, {dz!r}]
  v_max: {v_max!r}
  gamma_max: {gamma_max!r}
input:
  per_frame:
{frames}
"""


def walk_table(scene: Scene) -> list[Row]:
    """Run a walk scene and return one row per frame."""
    model = compile_model(scene)
    if model.observer is None or model.observer.mode != "walk":
        raise InputError([scene.problem(("observer",), "the walk table needs an observer "
                                                       "with mode: walk")])
    ends = []
    run(model, make_state(model), on_frame=ends.append)
    gamma_max = Decimal(repr(float(scene.data["observer"].get("gamma_max", 90.0))))
    rows = []
    for frame, state in enumerate(ends):
        alpha, beta, _ = input_at(model.inputs, frame, 0.0)[0]
        rows.append(Row(
            alpha=float(alpha), beta=float(beta),
            v_zx=_zx(state.observer_vel), gamma=Decimal(repr(float(beta))) * gamma_max,
            position_zx=_zx(state.observer_pos), direction_zx=_zx(state.observer_dir)))
    return rows


def _zx(vec) -> tuple:
    return float(vec[2]), float(vec[0])


def _trunc(value) -> str:
    """Truncation toward zero, printed without a sign on zero (the slide prints 0)."""
    return str(int(math.trunc(value)))


def _pair(pair, exact: bool) -> str:
    if exact:
        return f"({', '.join(repr(v) for v in pair)})"
    return f"({','.join(_trunc(v) for v in pair)})"  # the slide's compact form


def format_table(rows: list[Row], fmt: str = "markdown", exact: bool = False) -> str:
    cells = []
    for row in rows:
        gamma = f"{row.gamma.normalize():f}" if exact else _trunc(row.gamma)
        cells.append((f"{row.alpha:.2f}", f"{row.beta:.2f}", _pair(row.v_zx, exact), gamma,
                      _pair(row.position_zx, exact), _pair(row.direction_zx, exact)))
    if fmt == "csv":
        head = "alpha,beta,v_z,v_x,gamma,V_z,V_x,d_z,d_x"
        lines = [head]
        for row, cell in zip(rows, cells):
            values = [*row.v_zx, row.gamma, *row.position_zx, *row.direction_zx]
            shown = [repr(v) if exact and not isinstance(v, Decimal) else
                     (f"{v.normalize():f}" if exact else _trunc(v)) for v in values]
            lines.append(",".join([cell[0], cell[1], *shown]))
        return "\n".join(lines) + "\n"
    lines = ["| " + " | ".join(HEADERS) + " |", "|" + "---|" * len(HEADERS)]
    lines += ["| " + " | ".join(cell) + " |" for cell in cells]
    return "\n".join(lines) + "\n"


def slide_rows() -> list[Row]:
    return walk_table(parse_scene(slide_scene_text(), "<walk-table>"))
