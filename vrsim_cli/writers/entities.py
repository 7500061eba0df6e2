"""The entities of a sample, shared by every writer: the bodies in model order, then the
observer; and their 13 numbers per sample in the column order of the CSV output."""

from __future__ import annotations

import numpy as np

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
