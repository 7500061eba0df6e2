"""Layer 6: trajectory writers. They read the model and states, never the loop.

Every writer takes samples one at a time (`write(state)`), then `close()` finalises the
file atomically, or `abort()` leaves any previous file untouched. The entities of a
sample are the bodies, in model order, then the observer.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vrsim_cli.errors import OutputError
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State

CSV_COLUMNS = ("t", "entity", "px", "py", "pz", "qw", "qx", "qy", "qz",
               "vx", "vy", "vz", "wx", "wy", "wz")


OBSERVER = "observer"


def entity_names(model: Model) -> tuple:
    """Bodies in model order, then the observer (when the scene has one)."""
    return model.body_name + ((OBSERVER,) if model.observer is not None else ())


def entity_arrays(model: Model, state: State) -> np.ndarray:
    """(n_entity, 13): px py pz qw qx qy qz vx vy vz wx wy wz, SI units, per entity."""
    rows = np.hstack([state.body_pos, state.body_quat, state.body_vel, state.body_angvel])
    if model.observer is None:
        return rows
    observer = np.concatenate([state.observer_pos, state.observer_quat, state.observer_vel,
                               state.observer_angvel])
    return np.vstack([rows, observer])


def open_writer(model: Model, path: Path, fmt: str):
    """The writer for `fmt` ('csv', 'mcap', 'tum') writing to `path`."""
    if fmt == "csv":
        from vrsim_cli.writers.csv_writer import CsvWriter
        return CsvWriter(model, path)
    if fmt == "mcap":
        from vrsim_cli.writers.mcap_writer import McapWriter
        return McapWriter(model, path)
    if fmt == "tum":
        from vrsim_cli.writers.tum_writer import TumWriter
        return TumWriter(model, path)
    raise OutputError(f"unknown output format '{fmt}'")
