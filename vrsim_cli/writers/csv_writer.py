"""CSV trajectories, long format: one row per entity per sample.

Columns exactly `t,entity,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz` (SI units; quaternion
[w, x, y, z]). Numbers are written with Python's shortest round-trip repr, so reading the
file back gives the very same float64 values.
"""

from __future__ import annotations

from pathlib import Path

from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.writers.atomic import AtomicFile
from vrsim_cli.writers.entities import CSV_COLUMNS, entity_arrays, entity_names


class CsvWriter:
    def __init__(self, model: Model, path: Path):
        self.model = model
        self.names = entity_names(model)
        self.out = AtomicFile(path)
        self.out.write((",".join(CSV_COLUMNS) + "\n").encode())
        self.samples = 0

    def write(self, state: State) -> None:
        t = repr(float(state.t))
        rows = entity_arrays(self.model, state).tolist()
        lines = [f"{t},{name},{','.join(map(repr, row))}\n"
                 for name, row in zip(self.names, rows)]
        self.out.write("".join(lines).encode())
        self.samples += 1

    def close(self) -> None:
        self.out.commit()

    def abort(self) -> None:
        self.out.discard()
