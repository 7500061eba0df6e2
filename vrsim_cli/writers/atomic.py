"""Atomic file output: write to a temporary file beside the target, then rename.

A reader never sees a half-written file: until `commit` the target is either absent or
the previous version, untouched. `os.replace` is atomic on POSIX within one file system,
which is why the temporary file lives in the target's own folder. Only regular files are
ever replaced (see `scene.files`: a device, FIFO, socket, symbolic link or folder at the
target is refused), and a replaced file keeps its permissions.

The temporary file `.NAME.XXXXXXXX.partial` is locked while it is written; temporary files
of the same target left by killed runs (unlocked and older than a minute) are removed when
the next run opens the target. `-o -` (`STDOUT`) writes straight to standard output:
nothing to rename, nothing to keep on failure (MCAP goes through an unnamed temporary file
first: its writer seeks back, a pipe cannot).
"""

from __future__ import annotations

import errno
import os
import shutil
import stat
import sys
import tempfile
from pathlib import Path

from vrsim_cli.errors import OutputError
from vrsim_cli.scene.files import (PARTIAL_SUFFIX, STDOUT, file_target_problem, fsync_dir,
                                   lock, remove_stale_partials)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class _Stdout:
    """Standard output as a binary stream that knows its position (MCAP records offsets
    with tell(); a pipe cannot)."""

    def __init__(self):
        self.stream = sys.stdout.buffer
        self.offset = 0

    def write(self, data) -> int:
        self.stream.write(data)
        self.offset += len(data)
        return len(data)

    def tell(self) -> int:
        return self.offset

    def flush(self) -> None:
        self.stream.flush()

    def fileno(self) -> int:
        return self.stream.fileno()


class AtomicFile:
    """A binary file that appears at `path` only when `commit()` succeeds."""

    def __init__(self, path: str | os.PathLike, sweep_stale: bool = True):
        """`sweep_stale=False`: the caller removed the folder's stale temporary files
        itself, once for many files (the frames writer: a sweep per file lists the folder
        once per frame, quadratic in the number of frames)."""
        self.path = Path(path)
        self.done = False
        self.synced = False
        self.stream = str(path) == STDOUT
        if self.stream:
            self.tmp_path = None
            self.file = _Stdout()
            return
        problem = file_target_problem(self.path)
        if problem is not None:
            raise OutputError(f"cannot write {self.path}: {problem}")
        folder = self.path.parent
        if sweep_stale:
            remove_stale_partials(folder, self.path.name)
        try:
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=PARTIAL_SUFFIX,
                                       dir=folder)
        except OSError as exc:
            raise OutputError(f"cannot write {self.path}: {exc.strerror}") from None
        lock(fd)
        self.tmp_path = Path(tmp)
        self.file = os.fdopen(fd, "wb")

    def seekable(self) -> "AtomicFile":
        """For a writer that seeks back (the Foxglove SDK's MCAP writer): a file on disk
        is seekable; standard output is a pipe, so the data goes to an unnamed temporary
        file first, copied out at `commit`. Call before the first write."""
        if self.stream and isinstance(self.file, _Stdout):
            try:
                self.file = tempfile.TemporaryFile()
            except OSError as exc:
                raise OutputError(f"cannot write to standard output: no temporary file "
                                  f"({exc.strerror})") from None
        return self

    def write(self, data: bytes) -> None:
        try:
            self.file.write(data)
        except OSError as exc:
            raise self._error(exc) from None

    def _error(self, exc: OSError) -> OutputError:
        if self.stream and exc.errno == errno.EPIPE:
            # The reader went away (`vrsim run -o - | head`): stop writing, and keep Python
            # from failing again when it flushes stdout at exit.
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            except OSError:
                pass
            return OutputError("cannot write to standard output: the reader closed the pipe")
        return OutputError(f"cannot write {self.path}: {exc.strerror}")

    def sync(self) -> None:
        """Flush the data to disk (the first half of `commit`); OutputError on failure,
        with the temporary file removed and the target untouched."""
        if self.done or self.synced:
            return
        if self.stream:
            try:
                if not isinstance(self.file, _Stdout):  # the seekable stand-in: copy it out
                    spool, self.file = self.file, _Stdout()
                    with spool:
                        spool.seek(0)
                        shutil.copyfileobj(spool, self.file, 1 << 20)
                self.file.flush()
            except OSError as exc:
                self.done = True
                raise self._error(exc) from None
            return
        self.synced = True
        try:
            self.file.flush()
            os.fsync(self.file.fileno())
            self.file.close()
            os.chmod(self.tmp_path, self._mode())
        except OSError as exc:
            self.discard()
            raise OutputError(f"cannot write {self.path}: {exc.strerror}; any previous "
                              f"file there is untouched") from None

    def _mode(self) -> int:
        """A replaced file keeps its permission bits; a new one gets 0666 less the umask."""
        try:
            st = os.lstat(self.path)
            if stat.S_ISREG(st.st_mode):
                return stat.S_IMODE(st.st_mode)
        except OSError:
            pass
        return 0o666 & ~_umask()

    def commit(self, sync_folder: bool = True) -> None:
        """Flush to disk and move into place. On failure the target is left untouched.
        `sync_folder` False: the caller fsyncs the folder once for several files."""
        if self.done:
            return
        self.sync()
        if self.stream:
            self.done = True
            return
        try:
            # The target may have changed kind during the run: never rename over a device,
            # FIFO, socket, link or folder.
            problem = file_target_problem(self.path)
            if problem is not None:
                raise OSError(errno.EEXIST, problem)
            os.replace(self.tmp_path, self.path)
        except OSError as exc:
            self.discard()
            raise OutputError(f"cannot write {self.path}: {exc.strerror}; any previous "
                              f"file there is untouched") from None
        self.done = True
        if sync_folder:
            fsync_dir(self.path.parent)  # make the rename itself durable

    def discard(self) -> None:
        """Drop the temporary file; the target is left as it was."""
        if self.done:
            return
        self.done = True
        if self.stream:
            try:
                # what was written stays written; the seekable stand-in is dropped unread
                self.file.flush() if isinstance(self.file, _Stdout) else self.file.close()
            except OSError:
                pass
            return
        try:
            self.file.close()
        except OSError:
            pass
        try:
            self.tmp_path.unlink()
        except OSError:
            pass
