"""The report of a sweep, made from the rows of `runs.csv` (so a resumed or interrupted
sweep reports exactly what its table holds): `sweep.md` with one table per scene and its
Pareto fronts, and a log-log plot of error against wall time per scene (matplotlib).

Layer 7. A run is on the Pareto front of an error measure (position, orientation) when
no other finished run of the same scene is at least as fast and at least as accurate and
better in one of the two: the settings worth choosing from. Wall times are those of one
run each, not best-of-repeats: on a busy machine the front moves with the noise (rerun
the candidates with `vrsim bench`-style repeats, or on a quiet machine, to decide).
"""

from __future__ import annotations

import math
from pathlib import Path

MEASURES = (("pos_err_m", "position", "m"), ("angle_err_rad", "orientation", "rad"))
ERROR_FLOOR = 1e-17  # errors of exactly 0 are plotted here, so log axes keep them


def _float(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def pareto(rows: list[dict], column: str) -> list[dict]:
    """The rows on the front of (wall_s, column), fastest first."""
    points = [r for r in rows if r.get("status") == "ok" and
              math.isfinite(_float(r.get(column))) and math.isfinite(_float(r.get("wall_s")))]
    points.sort(key=lambda r: (_float(r["wall_s"]), _float(r[column])))
    front, best = [], math.inf
    for r in points:
        if _float(r[column]) < best:
            front.append(r)
            best = _float(r[column])
    return front


def measured(rows: list[dict], column: str) -> bool:
    """Whether a measure says anything: some finite error above zero."""
    return any(_float(r.get(column)) > 0.0 for r in rows)


def _ms(text: str) -> str:
    x = _float(text)
    return "-" if math.isnan(x) else f"{1e3 * x:.3f}"


def _err(text: str) -> str:
    x = _float(text)
    return "-" if not text else ("nan" if math.isnan(x) else f"{x:.3e}")


def _params(row: dict, keys: list) -> str:
    return ", ".join(f"{k}={row.get(k, '')}" for k in keys)


def scene_rows(plan, rows: list[dict]) -> dict:
    """scene file -> its variant rows (role "run"), in the plan's order (rows from an
    earlier sweep into the same folder follow)."""
    order = {r.run_id: i for i, r in enumerate(plan.runs)}
    out: dict = {file: [] for file in plan.scenes}
    for row in rows:
        if row.get("role") == "run" and row.get("scene") in out:
            out[row["scene"]].append(row)
    for file in out:
        out[file].sort(key=lambda r: (order.get(r["run"], len(order)), r["run"]))
    return out


def markdown(plan, rows: list[dict], executor_text: str, machine: dict) -> str:
    refs = {r["run"]: r for r in rows if r.get("role") == "reference"}
    lines = ["# vrsim sweep", "",
             f"Runs {executor_text}. Machine: {machine}.", "",
             "Wall time is the simulation loop of one run (recording the samples excluded; "
             "no repeats). Errors are the largest over the entities and the sample times "
             "(the measures of `vrsim compare`); per entity in `entities.csv`.", ""]
    if plan.reference_file is not None:
        lines += [f"Reference: the trajectory file `{plan.reference_file}`.", ""]
    elif plan.reference_pairs:
        pairs = " ".join(f"{k}={v}" for k, v in plan.reference_pairs)
        lines += [f"Reference: each run with `{pairs}`.", ""]
    else:
        lines += ["No reference (`--reference`): no errors, no fronts.", ""]
    for file, srows in scene_rows(plan, rows).items():
        name = plan.scenes[file][0]
        lines += [f"## {name} (`{file}`)", ""]
        used = [ref for ref in refs.values() if ref["scene"] == file]
        for ref in used:
            lines.append(f"Reference run {ref['run']} ({_params(ref, plan.keys)}): "
                         f"{ref['status']}, {ref['steps']} steps, wall {_ms(ref['wall_s'])} ms"
                         + (f": {ref['message']}" if ref.get("message") else "") + ".")
        if used:
            lines.append("")
        fronts = {col: {r["run"] for r in pareto(srows, col)} for col, _, _ in MEASURES
                  if measured(srows, col)}
        head = [*plan.keys, "dt used (s)", "integrator used", "status", "steps", "wall (ms)",
                "position error (m)", "orientation error (rad)", "front"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in srows:
            marks = ", ".join(label for col, label, _ in MEASURES
                              if r["run"] in fronts.get(col, ()))
            status = r["status"] if r["status"] == "ok" else \
                f"{r['status']}: {r.get('message', '')[:80]}"
            cells = [r.get(k, "") for k in plan.keys] + [
                f"{_float(r['dt_used_s']):.6g}" if r.get("dt_used_s") else "-",
                r.get("integrator_used", ""),
                status.replace("|", "/"), r.get("steps", ""), _ms(r.get("wall_s")),
                _err(r.get("pos_err_m")), _err(r.get("angle_err_rad")), marks]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
        for col, label, unit in MEASURES:
            if col not in fronts:
                continue
            lines += [f"Pareto front, {label} error (fastest first):", ""]
            for r in pareto(srows, col):
                lines.append(f"- {_params(r, plan.keys)}: {_ms(r['wall_s'])} ms, "
                             f"{_err(r[col])} {unit}")
            lines.append("")
    return "\n".join(lines)


def plot(plan, rows: list[dict], folder: Path) -> list[Path]:
    """Per scene, `NAME.png`: error against wall time on log-log axes, one panel per
    measure, one curve per combination of the other keys along dt (or along the last
    --set key when dt is not swept), the Pareto front in black. [] without matplotlib."""
    try:
        import matplotlib
    except ImportError:
        return []
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    from vrsim_cli.errors import OutputError

    along = "dt" if "dt" in plan.keys else (plan.keys[-1] if plan.keys else None)
    names = [name for name, _ in plan.scenes.values()]
    others = [k for k in plan.keys if k != along]
    written = []
    for file, srows in scene_rows(plan, rows).items():
        cols = [(c, label, unit) for c, label, unit in MEASURES if measured(srows, c)]
        ok = [r for r in srows if r["status"] == "ok"]
        if not cols or not ok:
            continue
        name = plan.scenes[file][0]
        fig, axes = plt.subplots(1, len(cols), figsize=(6.4 * len(cols), 4.6), squeeze=False)
        for ax, (col, label, unit) in zip(axes[0], cols):
            curves: dict = {}
            for r in ok:
                curves.setdefault(tuple(r.get(k, "") for k in others), []).append(r)
            for key, pts in curves.items():
                pts.sort(key=lambda r: _float(r["wall_s"]))
                ax.loglog([_float(r["wall_s"]) for r in pts],
                          [max(_float(r[col]), ERROR_FLOOR) for r in pts], "o-", ms=4,
                          label=", ".join(f"{k}={v}" for k, v in zip(others, key)) or name)
            front = pareto(srows, col)
            ax.loglog([_float(r["wall_s"]) for r in front],
                      [max(_float(r[col]), ERROR_FLOOR) for r in front], "k--", lw=1,
                      label="Pareto front")
            # 1-2-5 ticks labelled as plain numbers: sweeps often span less than a decade
            ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_xlabel("wall time of the run (s)")
            ax.set_ylabel(f"largest {label} error ({unit})")
            ax.set_title(f"{name}: {label}" + (f", along {along}" if along else ""))
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=6)
        fig.tight_layout()
        # scenes of one name (from different files) get the file's stem too
        stem = name if names.count(name) == 1 else f"{name}-{Path(file).stem}"
        path = folder / f"{_file_name(stem)}.png"
        tmp = path.with_name(f".{path.name}.partial")
        try:
            fig.savefig(tmp, dpi=110, format="png")
            tmp.replace(path)  # atomic: a reader sees the old plot or the new one
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise OutputError(f"cannot write {path}: {exc.strerror}") from None
        finally:
            plt.close(fig)
        written.append(path)
    return written


def _file_name(name: str) -> str:
    return "".join(c if c.isalnum() or c in "._-" else "_" for c in name) or "scene"
