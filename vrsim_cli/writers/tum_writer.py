"""TUM trajectories: a folder with one `ENTITY.tum` per entity, lines `t tx ty tz qx qy qz qw`.

The format of the TUM RGB-D benchmark, read by the `evo` trajectory tools. Note the
quaternion order: TUM puts w last.

The folder is the user's: vrsim creates it when it is missing, and otherwise only replaces
its own `ENTITY.tum` files in it, never anything else (a folder holding other files, or
`.tum` files of entities this run does not have, is refused before the run: see
`scene.files.tum_folder_problem`). Each file is streamed into a locked temporary file in
the folder as the run goes (memory does not grow with the run) and renamed over its
target when the run ends, after every file has been flushed to disk (one fsync per file
and one for the folder). Until then the folder holds the previous run's files, untouched;
a run that fails removes its temporary files (and the folder, if it made it and it is
empty). TUM is meant for a handful of entities: one open file each, at most MAX_ENTITIES.
"""

from __future__ import annotations

import os
from pathlib import Path

from vrsim_cli.errors import OutputError
from vrsim_cli.model.model import MAX_TUM_ENTITIES, Model
from vrsim_cli.model.state import State
from vrsim_cli.scene.files import fsync_dir, remove_stale_partials, tum_folder_problem
from vrsim_cli.writers.atomic import AtomicFile
from vrsim_cli.writers.entities import entity_arrays, entity_names

# Columns of entity_arrays: px py pz qw qx qy qz ...; TUM wants tx ty tz qx qy qz qw.
TUM_ORDER = [0, 1, 2, 4, 5, 6, 3]
MAX_ENTITIES = MAX_TUM_ENTITIES  # one open file each (the usual limit is 1024 descriptors)


class TumWriter:
    def __init__(self, model: Model, folder: Path):
        self.model = model
        self.folder = Path(folder)
        self.names = entity_names(model)
        if len(self.names) > MAX_ENTITIES:
            raise OutputError(f"cannot write {self.folder}: tum output writes one file per "
                              f"entity, at most {MAX_ENTITIES}; this run has "
                              f"{len(self.names)} (use csv or mcap)")
        problem = tum_folder_problem(self.folder, set(self.names), model.scene_file or None)
        if problem is not None:
            raise OutputError(f"cannot write {self.folder}: {problem}")
        self.created = False
        if not self.folder.exists():
            try:
                self.folder.mkdir()  # mode 0777 less the umask, like mkdir(1)
            except OSError as exc:
                raise OutputError(f"cannot write {self.folder}: {exc.strerror}") from None
            self.created = True
        remove_stale_partials(self.folder)  # of any entity: earlier killed TUM runs
        self.files: list[AtomicFile] = []
        try:
            for name in self.names:
                self.files.append(AtomicFile(self.folder / f"{name}.tum"))
        except OutputError:
            self.abort()
            raise
        self.samples = 0

    def write(self, state: State) -> None:
        t = repr(float(state.t))
        rows = entity_arrays(self.model, state)[:, TUM_ORDER].tolist()
        for out, row in zip(self.files, rows):
            out.write(f"{t} {' '.join(map(repr, row))}\n".encode())
        self.samples += 1

    def close(self) -> None:
        """Flush every file to disk, then rename each over its target."""
        problem = tum_folder_problem(self.folder, set(self.names), self.model.scene_file
                                     or None)
        if problem is not None:  # the folder changed during the run
            self.abort()
            raise OutputError(f"cannot write {self.folder}: {problem}; any previous output "
                              f"there is untouched")
        try:
            for out in self.files:
                out.sync()
            for out in self.files:
                out.commit(sync_folder=False)
        except OutputError:
            self.abort()
            raise
        fsync_dir(self.folder)
        if self.created:
            fsync_dir(self.folder.parent)

    def abort(self) -> None:
        for out in self.files:
            out.discard()
        if self.created:
            try:
                os.rmdir(self.folder)  # only when empty: never anything but what we made
            except OSError:
                pass
