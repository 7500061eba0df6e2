"""What a path names, checked before vrsim reads or writes it.

Layer 1 (stdlib only), used by the scene loader, the model's file keys, the writers and
the command line.

Inputs (scene files, meshes, sensor CSVs, replays) must be regular files: a FIFO without a
writer blocks `open` forever, `/dev/zero` never ends, a folder is not a file. Each kind of
input has a size limit, so reading it is bounded in time and memory.

Outputs are written to a temporary file beside the target and renamed over it. A rename
replaces whatever the name held, so the target must be absent or a regular file (CSV,
MCAP), or a folder that holds only TUM trajectories (TUM): a device node, FIFO, socket or
symbolic link is refused (renaming over `/dev/null` would turn it into a regular file,
renaming over a link would replace the link, not its target). `-o -` writes to standard
output instead, on purpose. Temporary files are named `.NAME.XXXXXXXX.partial`; a run
killed before it could remove its own leaves one, which a later run writing the same
target removes (`stale_partials`).
"""

from __future__ import annotations

import errno
import os
import re
import stat
import time
from pathlib import Path

STDOUT = "-"  # `-o -`: write the trajectory to standard output

PARTIAL_SUFFIX = ".partial"
# tempfile.mkstemp(prefix=".NAME.", suffix=".partial"): 8 random characters in between.
PARTIAL_RANDOM = r"[a-z0-9_]{8}"
PARTIAL_OVERHEAD = len("." + "." + "x" * 8 + PARTIAL_SUFFIX)  # bytes a partial adds to a name
STALE_AFTER_S = 60.0  # a partial untouched this long, and unlocked, belongs to a dead run

MAX_SCENE_BYTES = 4 * 1024 * 1024  # pure-Python YAML reads ~1 MB/s; a scene is hand-written
MAX_MESH_BYTES = 32 * 1024 * 1024  # ~650k triangles of binary STL, before the triangle limit
MAX_SENSOR_BYTES = 16 * 1024 * 1024  # input.file / input.tracker CSV (read into lists of
# floats, ~15x the text), input.replay MCAP


def kind_of(mode: int) -> str:
    """'a regular file', 'a folder', 'a FIFO (named pipe)', ... for an st_mode."""
    if stat.S_ISREG(mode):
        return "a regular file"
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def input_file_problem(path: str | os.PathLike, limit_bytes: int) -> str | None:
    """Why `path` cannot be read as an input file of at most `limit_bytes`, or None.
    Symbolic links are followed (a scene's own paths are checked to stay in its folder)."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "no such file"
    except OSError as exc:
        return f"cannot read: {exc.strerror or exc}"
    except ValueError:  # a NUL character
        return "a path cannot hold a NUL character"
    if not stat.S_ISREG(st.st_mode):
        return f"is {kind_of(st.st_mode)}, not a regular file"
    if st.st_size > limit_bytes:
        return f"is {st.st_size} bytes; at most {limit_bytes} are read"
    return None


def read_input_file(path: str | os.PathLike, limit_bytes: int) -> bytes:
    """The bytes of a regular file of at most `limit_bytes`. Raises ValueError with the
    reason (see `input_file_problem`). The file is opened without blocking and checked on
    the open descriptor, so a FIFO swapped in after a check cannot hang the read."""
    problem = input_file_problem(path, limit_bytes)
    if problem is not None:
        raise ValueError(problem)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as exc:
        raise ValueError(f"cannot read: {exc.strerror or exc}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise ValueError(f"is {kind_of(st.st_mode)}, not a regular file")
        chunks, size = [], 0
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            size += len(chunk)
            if size > limit_bytes:
                raise ValueError(f"is more than {limit_bytes} bytes; at most {limit_bytes} "
                                 f"are read")
            chunks.append(chunk)
        return b"".join(chunks)
    except OSError as exc:
        raise ValueError(f"cannot read: {exc.strerror or exc}") from None
    finally:
        os.close(fd)


# ----------------------------------------------------------------------------- outputs


def name_max(folder: str | os.PathLike) -> int:
    """Longest file name (bytes) the file system of `folder` takes."""
    try:
        return os.pathconf(folder, "PC_NAME_MAX")
    except (OSError, ValueError):
        return 255


def _name_problem(path: Path) -> str | None:
    limit = name_max(path.parent) - PARTIAL_OVERHEAD
    size = len(os.fsencode(path.name))
    if size > limit:
        return (f"the file name is {size} bytes long; at most {limit} fit (the file "
                f"system's limit less {PARTIAL_OVERHEAD} for the temporary file vrsim "
                f"writes first)")
    return None


def _special_hint(path: Path) -> str:
    if str(path) in ("/dev/stdout", "/dev/fd/1", "/proc/self/fd/1"):
        return "; use -o - to write to standard output"
    if str(path) == "/dev/null":
        return "; leave out -o to write nothing"
    return ""


def is_partial_of(name: str, target_name: str) -> bool:
    """True when `name` is a temporary file vrsim writes before renaming it to
    `target_name` (in the same folder)."""
    if not (name.startswith(f".{target_name}.") and name.endswith(PARTIAL_SUFFIX)):
        return False  # most names in a folder: no regular expression needed
    return re.fullmatch(re.escape(f".{target_name}.") + PARTIAL_RANDOM
                        + re.escape(PARTIAL_SUFFIX), name) is not None


def is_partial(name: str) -> bool:
    """True for any name vrsim gives its temporary files."""
    return re.fullmatch(r"\..+\." + PARTIAL_RANDOM + re.escape(PARTIAL_SUFFIX), name) \
        is not None


def _target_stat(path: Path):
    """(os.lstat of an output target, None) or (None, why it cannot be written, or None
    when it is simply absent)."""
    try:
        if not path.parent.is_dir():
            return None, f"folder '{path.parent}' does not exist"
        return os.lstat(path), None
    except FileNotFoundError:
        return None, _name_problem(path)
    except OSError as exc:
        if exc.errno == errno.ENAMETOOLONG:
            return None, _name_problem(path) or "the name is too long"
        return None, f"cannot write: {exc.strerror or exc}"
    except ValueError:
        return None, "a path cannot hold a NUL character"


def file_target_problem(path: Path) -> str | None:
    """Why a CSV or MCAP trajectory cannot be written to `path`, or None. The target must
    be absent or a regular file in an existing folder."""
    if str(path) == STDOUT:
        return None
    st, problem = _target_stat(path)
    if st is None:
        return problem
    if stat.S_ISDIR(st.st_mode):
        return "is a folder; give a file name"
    if not stat.S_ISREG(st.st_mode):
        return (f"is {kind_of(st.st_mode)}; vrsim only replaces regular files"
                + _special_hint(path))
    return _name_problem(path)


def tum_folder_problem(folder: Path, entities=None, scene_file=None) -> str | None:
    """Why TUM trajectories cannot be written into `folder`, or None.

    The folder must be absent (it is created), or hold nothing but regular `.tum` files
    (and vrsim's own temporary files): TUM output replaces files in it one by one and never
    removes anything else. With `entities` (the names this run writes), `.tum` files of
    other entities are refused too: they would be left beside the new ones as a mix of two
    runs. `scene_file`: the scene, which must not be in the folder."""
    st, problem = _target_stat(folder)
    if st is None:
        return problem
    if stat.S_ISLNK(st.st_mode):
        return "is a symbolic link; give the folder it points to"
    if not stat.S_ISDIR(st.st_mode):
        return f"is {kind_of(st.st_mode)}; tum output is a folder"
    try:
        names = sorted(os.listdir(folder))
    except OSError as exc:
        return f"cannot list the folder: {exc.strerror or exc}"
    if scene_file is not None:
        scene = Path(scene_file).resolve()
        if scene.parent == folder.resolve() and scene.is_file():
            return (f"holds the scene file '{scene.name}'; tum output needs a folder of its "
                    f"own")
    foreign = []
    stale = []
    for name in names:
        if is_partial(name):
            continue
        try:
            mode = os.lstat(folder / name).st_mode
        except OSError:
            continue  # gone meanwhile
        if not (name.endswith(".tum") and stat.S_ISREG(mode)):
            foreign.append(name)
        elif entities is not None and name[:-4] not in entities:
            stale.append(name)
    if foreign:
        return (f"holds {_listed(foreign)} besides TUM trajectories; tum output needs a "
                f"folder of its own (an empty or new one), and never removes other files")
    if stale:
        return (f"holds {_listed(stale)} of entities this run does not have; remove "
                f"{'it' if len(stale) == 1 else 'them'}, or give an empty or new folder, so "
                f"the folder does not mix two runs")
    return None


def folder_write_problem(folder: Path) -> str | None:
    """Why a new file cannot be made in `folder` (or, when it does not exist yet, in the
    nearest folder above it that does), or None. Found by making one, a temporary file
    removed at once: permission bits do not tell (root passes `os.access` on a read-only
    file system, or on sysfs)."""
    import tempfile

    folder = Path(os.path.abspath(folder))
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".vrsim-probe.",
                                         suffix=PARTIAL_SUFFIX):
            pass
    except OSError as exc:
        return f"folder '{folder}' is not writable ({exc.strerror or exc})"
    return None


def about(path_text: str, problem: str) -> str:
    """`problem` said about the path the user gave: "'out' is a folder; ...", or
    "'x.csv': the file name is ..." (a long name shortened in the middle)."""
    shown = path_text if len(path_text) <= 80 else path_text[:50] + "..." + path_text[-20:]
    if problem.startswith(("is ", "holds ")):
        return f"'{shown}' {problem}"
    if problem.startswith(("folder ", "a path ")):
        return problem
    return f"'{shown}': {problem}"


def _listed(names: list, shown: int = 3) -> str:
    text = ", ".join(f"'{n}'" for n in names[:shown])
    return text + (f" and {len(names) - shown} more" if len(names) > shown else "")


def stale_partials(folder: Path, target_name: str | None = None,
                   older_than_s: float = STALE_AFTER_S) -> list[Path]:
    """vrsim's temporary files in `folder` left by runs that died (SIGKILL, power loss):
    named like ours (for `target_name`, or any), regular files owned by this user, not
    modified for `older_than_s`, and not locked (a live writer holds a lock on its own)."""
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    now = time.time()
    found = []
    for name in names:
        if not (is_partial_of(name, target_name) if target_name is not None
                else is_partial(name)):
            continue
        path = folder / name
        try:
            st = os.lstat(path)
        except OSError:
            continue
        if (stat.S_ISREG(st.st_mode) and st.st_uid == os.geteuid()
                and now - st.st_mtime >= older_than_s and not _locked(path)):
            found.append(path)
    return found


def remove_stale_partials(folder: Path, target_name: str | None = None) -> int:
    """Remove `stale_partials`; returns how many went. Failures are ignored: a leftover
    file is not worth failing a run for."""
    removed = 0
    for path in stale_partials(folder, target_name):
        try:
            path.unlink()
            removed += 1
        except OSError:
            pass
    return removed


def lock(fd: int) -> None:
    """Mark a temporary file as in use for as long as `fd` is open (and the process
    lives): `stale_partials` leaves it alone."""
    try:
        import fcntl
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except (ImportError, OSError):
        pass  # no flock (Windows, some network file systems): the age check still holds


def _locked(path: Path) -> bool:
    try:
        import fcntl
    except ImportError:
        return False
    try:
        flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0)
        fd = os.open(path, flags)
    except OSError:
        return True  # cannot tell: leave it
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False  # we got it: no live writer holds it (closing the fd releases it)
    except OSError:
        return True
    finally:
        os.close(fd)


def fsync_dir(folder: Path) -> None:
    """Make renames and new names in `folder` durable. Some file systems cannot fsync a
    folder; the files' data is on disk already, so that is not an error."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
