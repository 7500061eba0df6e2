"""`vrsim plot FILE`: position, speed and energy over time per entity, as a PNG.

Layer 7. `series` computes the numbers (tested against closed forms); `draw` hands them to
matplotlib, the `plot` extra (`pip install 'vrsim-cli[plot]'`), imported only here.

Energy needs the masses and inertias: an MCAP file written by vrsim carries its scene
(metadata `vrsim`), from which the model is compiled again; for other files give the
scene with `--scene`. Per dynamic body E = 1/2 m |v|^2 + 1/2 w^T (R I R^T) w - m g . p
(J; I the body-frame inertia about the centre of mass, R from the orientation), and the
total over the plotted bodies; kinematic and static bodies (infinite mass) have none.
Files without velocities (TUM, transforms of other tools) get the speed from central
differences of the positions, and no energy.
"""

from __future__ import annotations

import fnmatch
from pathlib import Path

import numpy as np

from vrsim_cli.errors import InputError
from vrsim_cli.maths.spatial import quat_to_matrix

MAX_ENTITIES = 10  # more lines than this are unreadable; --entity picks others
PLOT_HINT = "pip install 'vrsim-cli[plot]'"


def model_of(traj, scene_file: str | None):
    """The Model behind a trajectory: from --scene, else from a vrsim MCAP's metadata;
    None when neither is known."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene, parse_scene

    if scene_file is not None:
        return compile_model(load_scene(scene_file))
    made = traj.metadata.get("vrsim", {})
    if made.get("scene"):
        return compile_model(parse_scene(made["scene"], f"{traj.source} (its scene)"))
    return None


def pick(names: list[str], patterns: tuple[str, ...]) -> tuple[list[str], int]:
    """(the entities to plot, how many matching ones were left out)."""
    chosen = [n for n in names if not patterns or any(fnmatch.fnmatchcase(n, p)
                                                       for p in patterns)]
    if patterns and not chosen:
        raise InputError(f"--entity {', '.join(patterns)}: no entity matches (entities: "
                         f"{', '.join(names[:10])}{', ...' if len(names) > 10 else ''})")
    return chosen[:MAX_ENTITIES], max(0, len(chosen) - MAX_ENTITIES)


def series(traj, model=None, patterns: tuple[str, ...] = ()) -> dict:
    """{entity: {t (k,) s, pos (k, 3) m, speed (k,) m/s, speed_from_positions: bool,
    energy (k,) J or None}}, and 'total_energy' (t, E) over the entities with energy."""
    names, left_out = pick(list(traj.tracks), patterns)
    out: dict = {"entities": {}, "left_out": left_out}
    index = {n: i for i, n in enumerate(model.body_name)} if model is not None else {}
    for name in names:
        track = traj.tracks[name]
        t, pos = track.t, track.pos
        if np.isfinite(track.vel).all():
            vel, derived = track.vel, False
        else:
            vel = np.gradient(pos, t, axis=0) if len(t) > 1 else np.zeros_like(pos)
            derived = True
        energy = None
        body = index.get(name)
        if body is not None and not derived and np.isfinite(model.body_mass[body]):
            m = float(model.body_mass[body])
            g = np.asarray(model.gravity, dtype=float)[:3]
            g = np.pad(g, (0, 3 - len(g)))
            energy = 0.5 * m * (vel * vel).sum(axis=1) - m * (pos @ g)
            rigid = model.rigid
            if rigid is not None and rigid.rot_slot[body] >= 0 and \
                    np.isfinite(track.angvel).all():
                inertia = rigid.rot_inertia[rigid.rot_slot[body]]
                rot = quat_to_matrix(track.quat)
                world = rot @ inertia @ rot.transpose(0, 2, 1)
                w = track.angvel
                energy = energy + 0.5 * np.einsum("ki,kij,kj->k", w, world, w)
        out["entities"][name] = {"t": t, "pos": pos, "speed": np.linalg.norm(vel, axis=1),
                                 "speed_from_positions": derived, "energy": energy}
    with_energy = [s for s in out["entities"].values() if s["energy"] is not None]
    if with_energy and all(len(s["t"]) == len(with_energy[0]["t"]) and
                           np.array_equal(s["t"], with_energy[0]["t"]) for s in with_energy):
        out["total_energy"] = (with_energy[0]["t"], sum(s["energy"] for s in with_energy))
    return out


def draw(data: dict, title: str, path: Path, energy_note: str | None) -> None:
    """Three panels over time: position (x solid, y dashed, z dotted), speed, energy."""
    try:
        import matplotlib
    except ImportError:
        raise InputError(f"vrsim plot needs matplotlib, which is not installed: "
                         f"{PLOT_HINT}") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_p, ax_v, ax_e) = plt.subplots(3, 1, sharex=True, figsize=(9, 9), dpi=100)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (name, s) in enumerate(data["entities"].items()):
        c = colors[k % len(colors)]
        for axis, style in zip(range(3), ("-", "--", ":")):
            ax_p.plot(s["t"], s["pos"][:, axis], style, color=c,
                      label=name if axis == 0 else None)
        ax_v.plot(s["t"], s["speed"], color=c,
                  label=f"{name} (from positions)" if s["speed_from_positions"] else name)
        if s["energy"] is not None:
            ax_e.plot(s["t"], s["energy"], color=c, label=name)
    if "total_energy" in data:
        ax_e.plot(*data["total_energy"], "k--", linewidth=1.5, label="total")
    ax_p.set_ylabel("position m\n(x solid, y dashed, z dotted)")
    ax_v.set_ylabel("speed |v| m/s")
    ax_e.set_ylabel("energy J\n(kinetic + potential)")
    ax_e.set_xlabel("t s")
    if energy_note:
        ax_e.text(0.5, 0.5, energy_note, transform=ax_e.transAxes, ha="center", va="center")
    for ax in (ax_p, ax_v, ax_e):
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc="best")
    more = f" ({data['left_out']} more entities not shown: --entity)" if data["left_out"] \
        else ""
    fig.suptitle(title + more)
    fig.tight_layout()
    from vrsim_cli.writers.atomic import AtomicFile

    out = AtomicFile(path)
    try:
        import io

        buffer = io.BytesIO()
        fig.savefig(buffer, format="png")
        out.write(buffer.getvalue())
        out.commit()
    finally:
        out.discard()
        plt.close(fig)
