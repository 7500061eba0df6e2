"""Layer 6: trajectory writers. They read the model and states, never the loop.

Every writer takes samples one at a time (`write(state)`), then `close()` finalises the
file atomically, or `abort()` leaves any previous file untouched. The entities of a
sample are the bodies, in model order (later issues add the observer).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vrsim_cli.errors import OutputError
from vrsim_cli.model import Model
from vrsim_cli.state import State

CSV_COLUMNS = ("t", "entity", "px", "py", "pz", "qw", "qx", "qy", "qz",
               "vx", "vy", "vz", "wx", "wy", "wz")


def entity_names(model: Model) -> tuple:
    return model.body_name


def entity_arrays(model: Model, state: State) -> np.ndarray:
    """(n_entity, 13): px py pz qw qx qy qz vx vy vz wx wy wz, SI units, per entity."""
    return np.hstack([state.body_pos, state.body_quat, state.body_vel, state.body_angvel])


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
