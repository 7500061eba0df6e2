"""What `vrsim run` reports when a run ends: one dict (`--json`) and its text lines.

Layer 7: reads the model and the loop's RunResult; the CLI only prints.
"""

from __future__ import annotations

from vrsim_cli.errors import printable
from vrsim_cli.model.state import state_hash
from vrsim_cli.text import plural, significant, table


def run_summary(model, result, *, frames=None, live_url=None, error=None,
                interrupted_by=None, passes_through=None) -> dict:
    """The run as JSON-ready numbers (SI units; names say the unit)."""
    state = result.state
    from vrsim_cli.stages.dynamics.rigid import energy_loss_warning

    loss = energy_loss_warning(model, state)
    return {
        "ok": error is None and interrupted_by is None,
        "scene": model.name,
        "scene_file": str(model.scene_file) if model.scene_file else None,
        "output": str(model.output.path) if model.output.path is not None else None,
        "format": model.output.format,
        "simulated_s": float(state.t),
        "duration_s": float(model.duration),
        "steps": int(state.step),
        "dt_s": float(model.dt),
        "integrator": model.integrator,
        "frames": int(result.frames),
        "samples": int(result.samples),
        "wall_s": float(result.wall_s),
        "realtime_factor": float(state.t / result.wall_s) if result.wall_s > 0 else None,
        "state_sha256": state_hash(state),
        "missed_deadlines": int(result.missed_deadlines),
        "worst_late_s": float(result.worst_late_s),
        "profile_s": {k: float(v) for k, v in result.profile.items()},
        "images": None if frames is None else int(frames.images),
        "frames_dir": None if frames is None else str(model.frames.dir),
        "live": live_url,
        "interrupted_by": interrupted_by,
        "error": None if error is None else str(error),
        # shapes that met without a collision block (tools/pass_through): bodies, t_s, depth_m
        "passes_through": passes_through,
        "warnings": [] if loss is None else [loss],  # numbers to distrust; still ok
    }


def failure_summary(model, error) -> dict:
    """A run that failed (SimulationError): where and why; the output keeps the states
    up to the last good one."""
    return {"ok": False, "scene": model.name,
            "scene_file": str(model.scene_file) if model.scene_file else None,
            "output": str(model.output.path) if model.output.path is not None else None,
            "format": model.output.format, "error": str(error),
            "body": getattr(error, "body", None), "failed_at_s": getattr(error, "t", None)}


def format_run(summary: dict, profile: bool, realtime: bool) -> list[str]:
    """The human lines of a finished run, escaped: the scene's name may hold terminal
    control sequences (errors.printable)."""
    factor = summary["realtime_factor"]
    output = "standard output" if summary["output"] == "-" else summary["output"]
    where = f" -> {output}" if output is not None else " (no output: use -o FILE)"
    lines = [f"{summary['scene']}: simulated {summary['simulated_s']:.6g} s in "
             f"{plural(summary['steps'], 'step')} of {summary['dt_s']:.6g} s, wall "
             f"{summary['wall_s']:.3f} s, "
             f"{'inf' if factor is None else significant(factor)}x real time{where}",
             f"state sha256:{summary['state_sha256']}"]
    lines += [f"warning: {text}" for text in summary.get("warnings", [])]
    if realtime:
        lines.append(f"realtime: missed {summary['missed_deadlines']} of "
                     f"{plural(summary['frames'], 'frame deadline')} (worst "
                     f"{1e3 * summary['worst_late_s']:.2f} ms late)")
    if profile:
        stages = summary["profile_s"]
        total = sum(stages.values()) or 1.0
        steps = max(summary["steps"], 1)
        lines += table(["stage", "total s", "us/step", "share"],
                       [[stage, f"{s:.4f}", f"{1e6 * s / steps:.2f}", f"{100 * s / total:.1f}%"]
                        for stage, s in stages.items()], right={1, 2, 3})
    return [printable(line) for line in lines]
