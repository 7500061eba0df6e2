"""Atomic file output: write to a temporary file beside the target, then rename.

A reader never sees a half-written file: until `commit` the target is either absent or
the previous version, untouched. `os.replace` is atomic on POSIX within one file system,
which is why the temporary file lives in the target's own folder.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from vrsim_cli.errors import OutputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class AtomicFile:
    """A binary file that appears at `path` only when `commit()` succeeds."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        folder = self.path.parent
        if not folder.is_dir():
            raise OutputError(f"cannot write {self.path}: folder '{folder}' does not exist")
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".partial",
                                       dir=folder)
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror}") from None
        self.tmp_path = Path(tmp)
        self.file = os.fdopen(fd, "wb")
        self.done = False

    def write(self, data: bytes) -> None:
        try:
            self.file.write(data)
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror}") from None

    def commit(self) -> None:
        """Flush to disk and move into place. On failure the target is left untouched."""
        if self.done:
            return
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            os.chmod(self.tmp_path, 0o666 & ~_umask())
            os.replace(self.tmp_path, self.path)
        except OSError as exc:
            self.discard()
            raise OutputError(f"cannot write {self.path}: {exc.strerror}; "
                              f"any previous file there is untouched") from None
        self.done = True
        try:  # make the rename itself durable
            dir_fd = os.open(self.path.parent, os.O_RDONLY)
            try:
                os.fsync(dir_fd)
            finally:
                os.close(dir_fd)
        except OSError:
            pass  # some file systems cannot fsync a folder; the data itself is on disk

    def discard(self) -> None:
        """Drop the temporary file; the target is left as it was."""
        if self.done:
            return
        self.done = True
        try:
            self.file.close()
        except OSError:
            pass
        try:
            self.tmp_path.unlink()
        except OSError:
            pass
