"""numba, configured once for every kernel: the on-disk cache and the first-run notice.

`kernel` is `numba.njit(cache=True)` without fastmath: the compiled code keeps IEEE
semantics (no reassociation, no FMA contraction), so results are bit-identical across
runs, across the CPUs that run the same x86-64 code, and with the JIT off.

Cache: compiled machine code is kept in `cache_dir()`: a folder `src-<digest>` inside
$VRSIM_CACHE_DIR, else $NUMBA_CACHE_DIR when the user set it, else
$XDG_CACHE_HOME/vrsim/numba (default ~/.cache/vrsim/numba). The digest is of every
kernel's source (this folder's .py files): numba keys an entry by the timestamp of the
file that defines the kernel only, so a changed callee in another file (a kernel inlines
linalg's and dynamics' functions) could load stale machine code; and entries written by
versions before the cache's saves were locked (possibly another variant's code) are
never read again. numba also keys by argument types and CPU, so another machine
recompiles by itself. When that folder cannot be created or written, kernels are
compiled in memory for the run (a few seconds each time) and `cache_note()` says why.

A cache that cannot break a run: an entry that fails to load (a truncated or empty file,
random bytes: an interrupted compile, a full disk, a bad copy) is removed and compiled
again, with one line on stderr naming the folder; a save that fails (a full disk,
permissions) leaves the kernels compiled for this run only, also said once. Files are
written to a temporary name, flushed and renamed, so a killed compile leaves no
half-written entry. `vrsim cache --clear` removes the cache (`clear_cache`).

First run: the first compilation of a run prints one line on stderr ("compiling ...") and
`compile_report()` gives the seconds spent compiling, which `vrsim run` prints after it.
"""

from __future__ import annotations

import contextlib
import functools
import gc
import os
import sys
import tempfile
import time
import types
from pathlib import Path

_CACHE: dict = {}  # "dir": Path | None, "note": str | None


def _default_dir() -> Path:
    if os.environ.get("VRSIM_CACHE_DIR"):
        return Path(os.environ["VRSIM_CACHE_DIR"])
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "vrsim" / "numba"


_KERNELS = Path(__file__).resolve().parent  # this package's folder: the kernels' sources


@functools.lru_cache(maxsize=None)
def _source_digest() -> str:
    """16 hex digits of sha256 over the kernels' sources (name and bytes of each .py file
    of this package folder, in name order): ~1 ms, once per process (the cache folder's
    name and every entry's stamp, `_ContentLocator`)."""
    import hashlib

    h = hashlib.sha256()
    for path in sorted(_KERNELS.glob("*.py")):
        h.update(path.name.encode() + b"\0")
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".probe-"):
            pass
        return True
    except OSError:
        return False


def _configure() -> None:
    """Point numba's cache at our folder before numba is imported."""
    if "dir" in _CACHE:
        return
    base = _default_dir()
    folder = base / f"src-{_source_digest()}"
    if _writable(folder):
        _CACHE["dir"], _CACHE["note"] = folder, None
        os.environ["NUMBA_CACHE_DIR"] = str(folder)
        if "numba" in sys.modules:  # imported before vrsim (a notebook, a script): it
            # read the variable at its import, and would cache beside the sources, keyed
            # by each defining file's timestamp only; its locators read this per kernel
            sys.modules["numba"].config.CACHE_DIR = str(folder)
        # and the base for processes this one starts (sweep workers, tests, the compile
        # helper): given only NUMBA_CACHE_DIR, their jit nested another src-<digest>
        # inside it and compiled everything again there
        os.environ["VRSIM_CACHE_DIR"] = str(base)
    else:
        _CACHE["dir"] = None
        _CACHE["note"] = (f"the kernel cache folder {folder} is not writable: kernels are "
                          f"compiled for this run only (set VRSIM_CACHE_DIR to a writable "
                          f"folder to keep them)")


def cache_dir() -> Path | None:
    """The folder compiled kernels are cached in, or None when none is writable."""
    _configure()
    return _CACHE["dir"]


def cache_note() -> str | None:
    """Why kernels are not cached on disk, or None when they are."""
    _configure()
    return _CACHE["note"]


_configure()


def _refresh_target() -> None:
    """Initialise numba's CPU target (its implementations, once per process) without
    BLAS, before the first compile. numba's CPU target looks for BLAS through
    scipy.linalg.cython_blas when it initialises (numba/np/arraymath.py), which imports all
    of scipy.linalg (~0.2-0.5 s) only to enable np.dot and @ inside kernels, which ours
    must not use: their results would depend on the machine's BLAS (`_refusing` makes
    such a kernel a compile error). Afterwards scipy.linalg imports as usual for whoever
    needs it (collision proxies). A run whose kernels all come from the cache never
    initialises it (`_SafeFunctionCache.load_overload`)."""
    global _TARGET_READY
    if _TARGET_READY:
        return
    with _blas_blocked():
        from numba.core.registry import cpu_target

        cpu_target.target_context.refresh()
    import numba.np.linalg as linalg  # what np.dot, @ and np.linalg call when lowered

    for name in ("ensure_blas", "ensure_lapack"):
        setattr(linalg, name, _refusing(getattr(linalg, name)))
    _TARGET_READY = True


@contextlib.contextmanager
def _blas_blocked():
    """scipy.linalg.cython_blas made unimportable meanwhile (unless already imported):
    numba.np.arraymath, when first imported, then finds no BLAS (`_HAVE_BLAS` False:
    np.correlate and np.convolve take their plain loops)."""
    blocked = "scipy.linalg.cython_blas" not in sys.modules
    if blocked:
        sys.modules["scipy.linalg.cython_blas"] = None
    try:
        yield
    finally:
        if blocked and sys.modules.get("scipy.linalg.cython_blas", 0) is None:
            del sys.modules["scipy.linalg.cython_blas"]


def _refusing(ensure):
    """numba's check that BLAS/LAPACK is there, refusing while one of our kernels
    compiles (`kernel`): np.dot, @ or np.linalg in a kernel is a compile error there, not
    a result that depends on the machine's BLAS; other numba code in the process keeps
    numba's own check."""
    def check():
        if _WATCH.depth > 0 and _WATCH.ours:
            raise ImportError("vrsim kernels must not use BLAS or LAPACK (np.dot, @, "
                              "np.linalg): their results would depend on the machine; "
                              "write the algebra out (kernels/linalg.py)")
        return ensure()
    return check


_TARGET_READY = False  # `_refresh_target` has run
import numba  # noqa: E402
from numba.core import event  # noqa: E402
from numba.core import types as nbtypes  # noqa: E402


class _CompileWatch(event.Listener):
    """Says on stderr when a run first compiles, and adds up the time it takes."""

    def __init__(self):
        self.depth = 0
        self.started = 0.0
        self.seconds = 0.0
        self.announced = False
        self.paused = False
        self.ours = False  # the compile in progress is of a `kernel` (its outermost one)

    def on_start(self, ev):
        if self.depth == 0:
            self.started = time.perf_counter()
            self.ours = getattr(ev.data["dispatcher"], "_vrsim_kernel", False)
            self.announce()
            _refresh_target()  # before numba's own refresh in the compile
            # numba's compile makes reference cycles by the million (IR, types, LLVM
            # modules): with the collector paused for start-up (__main__), a first
            # stepped compile peaked at 0.96 GB instead of 0.55 GB (the largest particle
            # scene validation accepts: 1.28 GB). So the collector runs while compiling,
            # what start-up made frozen out of its passes (it lives as long as the
            # process anyway), at thresholds that keep the compile as fast as without
            # it (59 s against 68 s at the default ones, for 0.49 GB).
            self.paused = not gc.isenabled()
            if self.paused:
                gc.freeze()
                self.thresholds = gc.get_threshold()
                gc.set_threshold(50_000, 20, 1000)
                gc.enable()
        self.depth += 1

    def announce(self, expect: str | None = None):
        if not self.announced:
            self.announced = True
            where = cache_dir()
            print("vrsim: compiling kernels for this kind of scene (once"
                  + (f"; cached in {where}" if where else "; not cached")
                  + (f"; {expect})" if expect else ")") + " ...",
                  file=sys.stderr, flush=True)

    def on_end(self, ev):
        self.depth -= 1
        if self.depth == 0:
            self.seconds += time.perf_counter() - self.started
            if self.paused:
                gc.disable()
                gc.set_threshold(*self.thresholds)


_WATCH = _CompileWatch()
event.register("numba:compile", _WATCH)


class _UnrepeatedIds:
    """numba names a compiled function `qualname$<uid>` (its machine symbol), the uid
    from a counter that starts at 1 in every process. Two processes that compile the
    same steps (compile helpers, a sweep's forked workers, which inherit the counter)
    give different variants of one closure kernel (the free-flight run of two
    integrators; the stepped step of two, when it was one per integrator) the same
    symbol; a later process that loads both from the cache binds calls to the first one
    loaded (numba/numba#10486). A CI
    run computed rk4 and verlet scenes with symplectic-euler's step that way (box
    rebounds exactly symplectic-euler's). Drawn at random, a uid is never repeated:
    the code is the same, only its name differs, and cache keys do not use it."""

    def __iter__(self):
        return self

    def __next__(self) -> int:
        return int.from_bytes(os.urandom(8), "little") | 1 << 64  # never a small count


from numba.core import bytecode as _bytecode  # noqa: E402

_bytecode.FunctionIdentity._unique_ids = _UnrepeatedIds()

JIT_DISABLED = bool(numba.config.DISABLE_JIT)


def compile_report() -> float:
    """Seconds spent compiling kernels in this process so far (0: all came from the cache)."""
    return _WATCH.seconds


def announce_compile(expect: str | None = None) -> None:
    """Print the first-compile line (once per process) for a compile made elsewhere;
    `expect`: how long it takes, when that is long enough to say."""
    _WATCH.announce(expect)


def compiled_apart(seconds: float) -> None:
    """Count `seconds` that a helper process spent compiling kernels for this one (the
    first stepped compile, `loop.prepare`) in `compile_report`."""
    _WATCH.seconds += seconds


def host_key() -> str:
    """12 hex digits of what numba keys cached machine code by, besides a kernel and its
    argument types: the CPU (name and features: numba's magic tuple) and Python."""
    import hashlib

    from numba.core.registry import cpu_target

    magic = cpu_target.target_context.codegen().magic_tuple()
    return hashlib.sha256(repr((magic, sys.version_info[:2])).encode()).hexdigest()[:12]


def kernel(fn=None, *, inline: str = "never"):
    """Compile `fn` with numba: cached on disk, no fastmath, no parallel (fixed order).
    `inline="always"` for small helpers (3-vector algebra) that should cost nothing.
    A call from one kernel to another is typed without literal constants (below)."""
    def wrap(f):
        # no_cfunc_wrapper: the C-callable wrapper (for ctypes/cfunc use) is never used
        # here, and generating it cost ~4 % of a first compile
        d = numba.njit(cache=_CACHE["dir"] is not None, fastmath=False, inline=inline,
                       error_model="numpy", nogil=True, no_cfunc_wrapper=True)(f)
        if not JIT_DISABLED:
            d._vrsim_kernel = True  # `_refusing`
            d.get_call_template = types.MethodType(_unliteral_call_template, d)
            if _CACHE["dir"] is not None:
                d._cache = _SafeFunctionCache(d.py_func)
        return d
    return wrap if fn is None else wrap(fn)


def _unliteral_call_template(self, args, kws):
    """numba types a call from compiled code to a dispatcher with the callers' literal
    types: `put(K, i, K_N, v)` with a column constant compiled one copy of `put` per
    column (18 of them, and 8 of `get`, in the stepped kernel), each a full compile of
    ~0.3 s. Typed as plain ints first, a kernel compiles once per array layout; when that
    does not type (a constant index into a heterogeneous tuple), the literal types are
    used as before. The arithmetic is the same (the constant is folded by LLVM instead of
    numba; no fastmath)."""
    plain = tuple(nbtypes.unliteral(a) for a in args)
    plain_kws = {k: nbtypes.unliteral(v) for k, v in kws.items()}
    if plain != tuple(args) or plain_kws != kws:
        try:
            return type(self).get_call_template(self, plain, plain_kws)
        except numba.core.errors.TypingError:
            pass
    return type(self).get_call_template(self, args, kws)


# ----------------------------------------------------------------------------- cache saves

from numba.core import caching  # noqa: E402

_SAID: set = set()  # the notices of this process, each said once
_SAVES = {"on": True}  # False after a save failed: this run compiles in memory only


def _say_once(kind: str, text: str) -> None:
    """One line on stderr per kind of notice and process; nothing when stderr is closed."""
    if kind in _SAID:
        return
    _SAID.add(kind)
    try:
        if sys.stderr is not None:
            print(f"vrsim: {text}", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _why(exc: BaseException) -> str:
    text = getattr(exc, "strerror", None) or str(exc).splitlines()[0:1]
    text = text if isinstance(text, str) else (text[0] if text else "")
    return f"{type(exc).__name__}: {text[:80]}" if text else type(exc).__name__


def _entry_files(folder: str, base: str) -> list[str]:
    """The index and data files of one function's cache entries (`base`.nbi, .N.nbc)."""
    import re

    pattern = re.compile(re.escape(base) + r"(\.nbi|\.\d+\.nbc)")
    try:
        return [os.path.join(folder, n) for n in os.listdir(folder) if pattern.fullmatch(n)]
    except OSError:
        return []


class _SafeIndexDataCacheFile(caching.IndexDataCacheFile):
    """numba's cache file, safe for processes that save at the same time.

    numba saves an entry by reading the function's index, picking the first data file
    name the index does not use, writing the index, then the data. Two processes that
    compile *different* variants of one function at once (a closure kernel made per
    integrator, or another argument type) read the same index, pick the same name, and
    the last index and the last data written can belong to different variants: a later
    run then loads one variant's machine code for the other's key and computes wrong
    numbers without any error (reproduced by tests/test_jit_cache.py). Here the read-
    pick-write holds an exclusive lock on the folder's lock file, and the data is written
    before the index names it, so a reader (which takes no lock) never finds a name
    whose file is not yet this key's."""

    def save(self, key, data):
        with _folder_lock(self._cache_path):
            try:
                overloads = self._load_index()
            except Exception:  # noqa: BLE001 - unreadable: its entries are lost anyway
                overloads = {}
            name = overloads.get(key)
            if name is None:
                taken = set(overloads.values())
                number = 1
                while self._data_name(number) in taken:
                    number += 1
                name = self._data_name(number)
            self._save_data(name, data)
            if overloads.get(key) != name:
                overloads[key] = name
                self._save_index(overloads)


    @contextlib.contextmanager
    def _open_for_write(self, filepath):
        """numba's (a temporary name, renamed over `filepath`), with the data flushed to
        disk before the rename: after a power loss the name holds the whole file or the
        previous one, never an empty or partial file."""
        import uuid

        tmpname = f"{filepath}.tmp.{uuid.uuid4().hex[:16]}"
        try:
            with open(tmpname, "wb") as f:
                yield f
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmpname, filepath)
        except BaseException:
            try:
                os.unlink(tmpname)
            except OSError:
                pass
            raise


class _ContentLocator(caching.UserProvidedCacheLocator):
    """Where numba caches a kernel of this package: in `src-<digest>/kernels`, with the
    digest of the package's sources as the entry's freshness stamp. numba's own locator
    put each checkout's entries in a folder named by the hash of its path and took the
    defining file's mtime and size as the stamp, while the folder around them (and the
    stepped compile's marker in it, `loop._compile_marker`) is keyed by content: a second
    checkout or install of the same sources, or a `touch` of a kernel file, found the
    marker, skipped the compile helper and compiled ~150 stepped kernels in the run's own
    process (unlocked, ~0.5 GB each: two test workers did so side by side). Keyed by
    content here, any copy of the same sources loads what another compiled. Kernels
    defined outside this package (a user's module) keep numba's locator: the digest does
    not cover their files."""

    def __init__(self, py_func, py_file):
        super().__init__(py_func, py_file)
        self._cache_path = os.path.join(numba.config.CACHE_DIR, "kernels")

    def get_source_stamp(self):
        return _source_digest()

    @classmethod
    def from_function(cls, py_func, py_file):
        if Path(py_file).resolve().parent != _KERNELS:
            return None
        return super().from_function(py_func, py_file)


class _ContentCacheImpl(caching.CompileResultCacheImpl):
    _locator_classes = [_ContentLocator, *caching.CompileResultCacheImpl._locator_classes]


class _SafeFunctionCache(caching.FunctionCache):
    _impl_class = _ContentCacheImpl

    def __init__(self, py_func):
        super().__init__(py_func)
        self._cache_file.__class__ = _SafeIndexDataCacheFile  # same state, safe save

    def save_overload(self, sig, data):
        """numba's save; when it fails (a full disk, permissions changed), this kernel and
        every later one are compiled for this run only, and a line says so."""
        if not _SAVES["on"]:
            return
        try:
            super().save_overload(sig, data)
        except (OSError, caching.pickle.PicklingError) as exc:
            _SAVES["on"] = False
            why = f"cannot save compiled kernels in {self._cache_path} ({_why(exc)})"
            _CACHE["note"] = why  # the run's "compiled in ..." line says it too
            _say_once("save", f"{why}: compiled for this run only")

    def _discard_entries(self, exc: BaseException) -> None:
        """Remove this function's unreadable cache files (under the save lock), so the
        compile that follows writes fresh ones; say so once, naming the folder."""
        base = self._cache_file._index_name[:-len(".nbi")]
        try:
            with _folder_lock(self._cache_path):
                for path in _entry_files(self._cache_path, base):
                    try:
                        os.unlink(path)
                    except OSError:
                        pass
        except OSError:
            pass  # no lock file: the compile's save overwrites the index anyway
        _say_once("load", f"the kernel cache in {self._cache_path} held an unreadable "
                          f"entry ({_why(exc)}); it was removed and is compiled again "
                          f"(`vrsim cache --clear` empties the cache)")

    def load_overload(self, sig, target_context):
        """numba's, without its first step: numba refreshes the target context before
        every load (the first refresh imports and registers all of numba's
        implementations: ~0.1 s of a warm small run's ~0.7 s), of which loaded machine
        code needs only the symbols some of those imports give the linker: numba's
        runtime (reference counts, allocator) and the hash secret. A compile still
        refreshes it; `_CompileWatch` makes that first refresh with BLAS blocked
        (`_refresh_target`)."""
        import numba.cpython.hashing  # noqa: F401  (its import adds the hash secret)
        from numba.core.runtime import rtsys

        rtsys.initialize(target_context)
        # the entry's pickle may import numba.np.arraymath (environment._rebuild_env;
        # a.sum(), np.sort, the stepped kernels): with BLAS blocked, as the refresh
        first = "numba.np.arraymath" not in sys.modules
        try:
            with self._guard_against_spurious_io_errors(), \
                    (_blas_blocked() if first else contextlib.nullcontext()):
                return self._load_overload(sig, target_context)
        except Exception as exc:  # noqa: BLE001 - truncated, empty, foreign: any of pickle's
            self._discard_entries(exc)
            return None  # numba compiles it, and saves a good entry

    def _index_key(self, sig, codegen):
        """numba keys a closure by the pickle of its cells, and a kernel's pickle carries
        a random per-process id: a closure that calls another kernel (the stepped run
        calls the stepped step) would miss the cache in every run. Such cells are keyed
        by what the kernel is instead: its name, bytecode and own cells (its source file
        is this one's or numba's timestamp check covers it like any global callee)."""
        cells = self._py_func.__closure__ or ()
        if not any(isinstance(c.cell_contents, _Dispatcher) for c in cells):
            return super()._index_key(sig, codegen)
        import hashlib

        stable = repr(tuple(_stable_cell(c.cell_contents) for c in cells)).encode()
        code = self._py_func.__code__.co_code
        return (sig, codegen.magic_tuple(), (hashlib.sha256(code).hexdigest(),
                                             hashlib.sha256(stable).hexdigest()))


from numba.core.dispatcher import Dispatcher as _Dispatcher  # noqa: E402


def _stable_cell(value):
    """A closure cell's value as a text that is the same in every process (_index_key)."""
    if isinstance(value, _Dispatcher):
        f = value.py_func
        return ("kernel", f.__module__, f.__qualname__, f.__code__.co_code.hex(),
                tuple(_stable_cell(c.cell_contents) for c in f.__closure__ or ()))
    if isinstance(value, (bool, int, float, str, type(None))):
        return value
    if isinstance(value, tuple):
        return tuple(_stable_cell(v) for v in value)
    from numba.core.serialize import dumps  # numba's own key for anything else

    return dumps(value).hex()


@contextlib.contextmanager
def _folder_lock(folder: str):
    """An exclusive advisory lock on `folder`/.vrsim-save.lock (POSIX; elsewhere none)."""
    try:
        import fcntl
    except ImportError:  # not POSIX: numba's own behaviour
        yield
        return
    with open(os.path.join(folder, ".vrsim-save.lock"), "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


# ----------------------------------------------------------------------------- clearing


def clear_cache() -> tuple[Path, int, int]:
    """Remove the compiled kernels of every vrsim version from the cache base folder
    (`src-*` folders: numba's index and data files, temporary files and vrsim's lock and
    marker files in them); anything else there is left alone. Returns (base folder,
    files removed, bytes freed)."""
    import re

    base = _default_dir()
    ours = re.compile(r".+\.(nbi|nbc)|.+\.(nbi|nbc)\.tmp\.[0-9a-f]+|\.vrsim-save\.lock"
                      r"|\.probe-.+|\.?stepped-.+\.compiled(\.lock)?|\..+\.partial")
    removed = freed = 0
    for folder in sorted(base.glob("src-*")) if base.is_dir() else []:
        for root, dirs, files in os.walk(folder, topdown=False):
            for name in files:
                if ours.fullmatch(name):
                    path = os.path.join(root, name)
                    try:
                        size = os.lstat(path).st_size
                        os.unlink(path)
                    except OSError:
                        continue
                    removed += 1
                    freed += size
            with contextlib.suppress(OSError):
                os.rmdir(root)  # only when emptied
    return base, removed, freed
