"""TUM trajectories: a folder with one `ENTITY.tum` per entity, lines `t tx ty tz qx qy qz qw`.

The format of the TUM RGB-D benchmark, read by the `evo` trajectory tools. Note the
quaternion order: TUM puts w last. Each file is written atomically when the run ends
(lines are kept in memory until then: TUM is meant for a handful of entities).
"""

from __future__ import annotations

from pathlib import Path

from vrsim_cli.errors import OutputError
from vrsim_cli.model import Model
from vrsim_cli.state import State
from vrsim_cli.writers import entity_arrays, entity_names
from vrsim_cli.writers.atomic import AtomicFile

# Columns of entity_arrays: px py pz qw qx qy qz ...; TUM wants tx ty tz qx qy qz qw.
TUM_ORDER = [0, 1, 2, 4, 5, 6, 3]


class TumWriter:
    def __init__(self, model: Model, folder: Path):
        self.model = model
        self.folder = Path(folder)
        try:
            self.folder.mkdir(parents=False, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create folder {self.folder}: {exc.strerror}") from None
        self.names = entity_names(model)
        self.lines: list[list[str]] = [[] for _ in self.names]
        self.samples = 0

    def write(self, state: State) -> None:
        t = repr(float(state.t))
        rows = entity_arrays(self.model, state)[:, TUM_ORDER].tolist()
        for lines, row in zip(self.lines, rows):
            lines.append(f"{t} {' '.join(map(repr, row))}\n")
        self.samples += 1

    def close(self) -> None:
        for name, lines in zip(self.names, self.lines):
            out = AtomicFile(self.folder / f"{name}.tum")
            try:
                out.write("".join(lines).encode())
                out.commit()
            finally:
                out.discard()

    def abort(self) -> None:
        self.lines = []
