"""TUM trajectories: a folder with one `ENTITY.tum` per entity, lines `t tx ty tz qx qy qz qw`.

The format of the TUM RGB-D benchmark, read by the `evo` trajectory tools. Note the
quaternion order: TUM puts w last. The files are written into a temporary folder beside
the target and the folder is swapped in when the run ends, so the target holds either the
previous run's complete set of files or the new one's, never a mix (and no stale files of
entities the new run does not have). Lines are kept in memory until then: TUM is meant for
a handful of entities.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from vrsim_cli.errors import OutputError
from vrsim_cli.model.model import Model
from vrsim_cli.model.state import State
from vrsim_cli.writers.entities import entity_arrays, entity_names

# Columns of entity_arrays: px py pz qw qx qy qz ...; TUM wants tx ty tz qx qy qz qw.
TUM_ORDER = [0, 1, 2, 4, 5, 6, 3]


class TumWriter:
    def __init__(self, model: Model, folder: Path):
        self.model = model
        self.folder = Path(folder)
        if not self.folder.parent.is_dir():
            raise OutputError(f"cannot write {self.folder}: folder '{self.folder.parent}' "
                              f"does not exist")
        if self.folder.exists() and not self.folder.is_dir():
            raise OutputError(f"cannot write {self.folder}: it is a file, not a folder")
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
        parent, name = self.folder.parent, self.folder.name
        try:
            tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".partial", dir=parent))
        except OSError as exc:
            raise OutputError(f"cannot write {self.folder}: {exc.strerror}") from None
        old = None
        moved_aside = False
        try:
            for entity, lines in zip(self.names, self.lines):
                with open(tmp / f"{entity}.tum", "w", encoding="utf-8") as f:
                    f.write("".join(lines))
            os.sync()  # one flush for all files (an fsync per file costs ~1 ms each)
            if self.folder.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".old", dir=parent))
                os.replace(self.folder, old / name)
                moved_aside = True
            os.replace(tmp, self.folder)
        except OSError as exc:
            if moved_aside:  # put the previous output back where it was
                os.replace(old / name, self.folder)
            shutil.rmtree(tmp, ignore_errors=True)
            raise OutputError(f"cannot write {self.folder}: {exc.strerror}; any previous "
                              f"output there is untouched") from None
        finally:
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)

    def abort(self) -> None:
        self.lines = []
