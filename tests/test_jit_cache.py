"""The kernel cache stays right when processes compile at the same time.

numba's own cache save reads a function's index, picks the first free data-file name and
writes index and data; two processes compiling different variants of one function (our
closure kernels are made per integrator and pair kinds) pick the same name, and a later
run can load one variant's machine code for the other: silently wrong numbers. The window
is a few milliseconds, so the test widens it: every process sleeps after reading an index,
and the first one writes its data late. Then a fresh process must load each variant from
the cache (no compile) and get that variant's result. With numba's plain save this test
fails (one variant computes the other's result: [1.0, 1.0]).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

from vrsim_cli.kernels import jit

MODULE = """
from vrsim_cli.kernels.jit import kernel


def make(k):
    @kernel
    def add(x):
        return x + k
    return add
"""

RACER = """
import sys, time
import vrsim_cli.kernels.jit  # first: it points numba's cache at VRSIM_CACHE_DIR
import numba.core.caching as caching
k = int(sys.argv[1])
read, write = caching.IndexDataCacheFile._load_index, caching.IndexDataCacheFile._save_data

def slow_read(self):
    found = read(self)
    time.sleep(1.0)  # both processes hold the same view of the index
    return found

def late_write(self, name, data):
    time.sleep(2.0 if k == 1 else 0.0)  # variant 1's data lands last
    return write(self, name, data)

caching.IndexDataCacheFile._load_index = slow_read
caching.IndexDataCacheFile._save_data = late_write
import racemod
print(racemod.make(k)(0.0))
"""

def child_env(tmp_path, cache) -> dict:
    """This environment for a child Python that imports modules written to tmp_path and
    caches kernels in `cache` (numba's own variable unset: jit takes ours)."""
    env = {**os.environ, "VRSIM_CACHE_DIR": str(cache),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    env.pop("NUMBA_CACHE_DIR", None)
    return env


READER = """
import racemod
from vrsim_cli.kernels import jit
out = [racemod.make(k)(0.0) for k in (1, 2)]
print(out, jit.compile_report())
"""


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to cache with the JIT off")
@pytest.mark.skipif(not hasattr(os, "fork"), reason="the save lock is POSIX (fcntl)")
def test_concurrent_saves_of_two_variants_keep_each_variants_code(tmp_path):
    (tmp_path / "racemod.py").write_text(MODULE)
    env = child_env(tmp_path, tmp_path / "cache")
    racers = [subprocess.Popen([sys.executable, "-c", textwrap.dedent(RACER), str(k)],
                               cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True) for k in (1, 2)]
    for k, proc in zip((1, 2), racers):
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-2000:]
        assert float(out.split()[-1]) == k
    proc = subprocess.run([sys.executable, "-c", READER], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    values, compiled = proc.stdout.strip().rsplit(" ", 1)
    assert values == "[1.0, 2.0]"
    assert float(compiled) == 0.0, "both variants should have come from the cache"


@pytest.mark.parametrize("variable", ["XDG_CACHE_HOME", "NUMBA_CACHE_DIR", "VRSIM_CACHE_DIR"])
def test_processes_a_run_starts_use_its_cache_folder(tmp_path, variable):
    """A process that vrsim starts (sweep workers, the compile helper, a test's `vrsim`)
    finds the kernels where its parent keeps them. jit points numba at the folder through
    NUMBA_CACHE_DIR; a child given only that took it for the user's base folder and
    nested another src-<digest> inside, compiling everything again there."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("XDG_CACHE_HOME", "NUMBA_CACHE_DIR", "VRSIM_CACHE_DIR")}
    env[variable] = str(tmp_path / "base")
    child = "from vrsim_cli.kernels import jit; print(jit.cache_dir())"
    parent = ("import subprocess, sys\nfrom vrsim_cli.kernels import jit\n"
              "print(jit.cache_dir(), flush=True)\n"
              f"subprocess.run([sys.executable, '-c', {child!r}], check=True)\n")
    out = subprocess.run([sys.executable, "-c", parent], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    expected = (tmp_path / "base" / "vrsim" / "numba" if variable == "XDG_CACHE_HOME"
                else tmp_path / "base")
    assert out == [str(expected / f"src-{jit._source_digest()}")] * 2


ALLOCATING = """
import numpy as np

from vrsim_cli.kernels.jit import kernel


@kernel
def spread(x, n):
    out = np.empty(n)  # numba's runtime allocates it: the loaded code needs the runtime
    for i in range(n):
        out[i] = x * i
    return out
"""

PROBE = """
import sys
import loadmod
from vrsim_cli.kernels import jit
values = loadmod.spread(0.5, 4).tolist()
print(values, jit.compile_report() > 0.0, "numba.np.linalg" in sys.modules,
      "scipy.linalg" in sys.modules)
"""


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to load with the JIT off")
def test_kernels_load_from_the_cache_without_initialising_numbas_compiler(tmp_path):
    """Start-up (issue 16: a warm small run in <= 1.0 s): numba initialises its whole CPU
    target (imports and registers every implementation it has, ~0.2 s) before it loads a
    kernel from the cache, which needs only its runtime. A warm process loads and runs an
    allocating kernel without that (before: numba.np.linalg was imported by every warm
    run); a compiling one initialises it, with BLAS blocked (scipy.linalg not imported)."""
    (tmp_path / "loadmod.py").write_text(ALLOCATING)
    env = child_env(tmp_path, tmp_path / "cache")
    runs = [subprocess.run([sys.executable, "-c", PROBE], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=300) for _ in range(2)]
    for proc in runs:
        assert proc.returncode == 0, proc.stderr[-2000:]
    first, warm = (proc.stdout.split("]")[-1].split() for proc in runs)
    assert all(proc.stdout.startswith("[0.0, 0.5, 1.0, 1.5]") for proc in runs)
    assert first == ["True", "True", "False"]  # compiled: target initialised, no BLAS
    assert warm == ["False", "False", "False"]  # loaded: neither


@pytest.mark.skipif(jit.JIT_DISABLED, reason="nothing is compiled with the JIT off")
def test_a_cache_folder_that_cannot_be_written_is_said_once_with_the_fix(tmp_path):
    """The kernels compile in memory for the run, and the run says why they are not kept
    and what to do (before: "not cached", then "compiled ... (kept for the next runs)")."""
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder\n")  # a folder cannot be made below it, even as root
    scene = tmp_path / "one.yaml"
    scene.write_text("vrsim: 1\nduration: 0.01\nframe_rate: 100\ndt: 0.001\n"
                     "integrator: symplectic-euler\n"
                     "bodies: [{name: p, mass: 1, position: [0, 0, 1]}]\n")
    env = {**os.environ, "VRSIM_CACHE_DIR": str(blocker / "cache")}
    env.pop("NUMBA_CACHE_DIR", None)
    proc = subprocess.run([sys.executable, "-m", "vrsim_cli", "run", str(scene), "-o",
                           str(tmp_path / "one.csv")], env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "kept for the next runs" not in proc.stderr, proc.stderr
    assert "(not kept: the kernel cache folder" in proc.stderr, proc.stderr
    assert "set VRSIM_CACHE_DIR to a writable folder" in proc.stderr, proc.stderr
    assert (tmp_path / "one.csv").is_file()


FIRST = """
import numba  # before vrsim: numba reads NUMBA_CACHE_DIR at its import, so jit must
import firstmod  # point numba's cache at its folder itself
print(firstmod.twice(2.0))
"""


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to cache with the JIT off")
def test_kernels_are_cached_in_vrsims_folder_when_numba_was_imported_first(tmp_path):
    """A notebook or script that imports numba before vrsim (the Python API) must keep
    the kernels in vrsim's folder (src-<digest>: stale machine code of a changed callee
    in another file is never loaded). Before, numba had read NUMBA_CACHE_DIR (unset) at
    its import and cached next to the sources (the package's kernels/__pycache__), keyed
    by each defining file's timestamp only."""
    (tmp_path / "firstmod.py").write_text(textwrap.dedent("""
        from vrsim_cli.kernels.jit import kernel


        @kernel
        def twice(x):
            return 2.0 * x
        """))
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["VRSIM_CACHE_DIR"] = str(tmp_path / "base")
    env["PYTHONPATH"] = str(tmp_path) + os.pathsep + env.get("PYTHONPATH", "")
    out = subprocess.run([sys.executable, "-c", FIRST], env=env, cwd=tmp_path,
                         capture_output=True, text=True, check=True).stdout.split()
    assert out == ["4.0"]
    assert not list(tmp_path.glob("__pycache__/*.nbi")), "cached beside the source"
    saved = list((tmp_path / "base").glob(f"src-{jit._source_digest()}/**/firstmod.twice-*.nbi"))
    assert len(saved) == 1, sorted(str(p) for p in (tmp_path / "base").rglob("*"))


COPY_PROBE = """
from vrsim_cli.kernels import trig
trig.sin_cos(0.3)
stats = trig.sin_cos.stats
print(sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
"""


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to cache with the JIT off")
def test_a_copy_of_the_same_sources_loads_what_another_copy_compiled(tmp_path):
    """The cache folder and the stepped compile's marker in it are keyed by the kernels'
    sources (src-<digest>); numba's entries were keyed by the checkout's path and each
    file's mtime. A second checkout or install of the same sources (or a `touch` of a
    kernel file) then found the marker, skipped the compile helper, missed every entry and
    compiled all kernels in the run's own process. Here two copies of the package at two
    paths share one cache: the second copy, and the first after its kernel file's mtime
    moved, load the entry the first compiled (numba's counters of hits and misses)."""
    import shutil

    import vrsim_cli

    source = os.path.dirname(vrsim_cli.__file__)
    for copy in ("a", "b"):
        shutil.copytree(source, tmp_path / copy / "vrsim_cli",
                        ignore=shutil.ignore_patterns("__pycache__"))
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["VRSIM_CACHE_DIR"] = str(tmp_path / "cache")

    def probe(copy):
        env["PYTHONPATH"] = str(tmp_path / copy)
        out = subprocess.run([sys.executable, "-c", COPY_PROBE], env=env, cwd=tmp_path,
                             capture_output=True, text=True, check=True).stdout.split()
        return int(out[0]), int(out[1])  # (loaded, compiled)

    assert probe("a") == (0, 1)
    assert probe("b") == (1, 0), "another path of the same sources compiled again"
    trig_py = tmp_path / "a" / "vrsim_cli" / "kernels" / "trig.py"
    later = trig_py.stat().st_mtime + 100.0
    os.utime(trig_py, (later, later))
    assert probe("a") == (1, 0), "a touched kernel file compiled again"
    assert len(list((tmp_path / "cache").glob("src-*/kernels/trig.sin_cos-*.nbi"))) == 1


NAMER = """
import os, sys
import racemod
fork = sys.argv[1] == "fork"

def name_of(k):
    f = racemod.make(k)
    f(0.0)
    return next(iter(f.overloads.values())).fndesc.mangled_name

if fork:  # two children of one parent: they inherit its state, as a sweep's workers
    for k in (1, 2):
        r, w = os.pipe()
        if os.fork() == 0:
            os.write(w, name_of(k).encode())
            os._exit(0)
        os.close(w)
        os.wait()
        print(os.read(r, 4096).decode())
else:
    print(name_of(int(sys.argv[2])))
"""


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to name with the JIT off")
@pytest.mark.parametrize("how", ["spawn", "fork"])
def test_processes_never_give_two_variants_one_symbol(tmp_path, how):
    """Two processes that compile different variants of one closure kernel (the stepped
    step per integrator: the compile helper per integrator, a sweep's forked workers)
    name their machine code apart. numba counted from 1 in each process, so both
    variants got the same symbol, and a process that loaded both from the cache ran the
    first one for both (numba/numba#10486): a CI run computed rk4 and verlet bounces with
    symplectic-euler's step. The hash seed is fixed so that nothing else varies."""
    if how == "fork" and not hasattr(os, "fork"):
        pytest.skip("no fork on this platform")
    (tmp_path / "racemod.py").write_text(MODULE)
    names = []
    runs = [["fork"]] if how == "fork" else [["spawn", "1"], ["spawn", "2"]]
    for i, args in enumerate(runs):
        env = child_env(tmp_path, tmp_path / f"cache{i}")  # each compiles afresh
        env["PYTHONHASHSEED"] = "0"
        proc = subprocess.run([sys.executable, "-c", NAMER, *args], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr[-2000:]
        names += proc.stdout.split()
    assert len(names) == 2 and names[0] != names[1], names


# ----------------------------------------------------------------------------- faults
# Issue 53: a damaged cache entry (an interrupted compile, a full disk, a bad copy) made
# every later run fail with a pickle traceback, forever, and nothing said which folder to
# delete; a save on a full disk was an OSError traceback.

FAULTMOD = """
from vrsim_cli.kernels.jit import kernel


@kernel
def half(x):
    return 0.5 * x


@kernel
def third(x):
    return x / 3.0
"""

FAULT_RUN = """
import sys
if sys.argv[1:] == ["full"]:  # every cache file fails as on a full disk
    import builtins, errno
    real_open = builtins.open
    def full_open(file, mode="r", *args, **kwargs):
        if "w" in mode and ".tmp." in str(file):
            raise OSError(errno.ENOSPC, "No space left on device", str(file))
        return real_open(file, mode, *args, **kwargs)
    builtins.open = full_open
import faultmod
from vrsim_cli.kernels import jit
print(faultmod.half(3.0), faultmod.third(3.0), jit.compile_report() > 0)
"""


def _fault_run(tmp_path, *args, modules=None):
    """FAULT_RUN with faultmod from `modules` (default tmp_path), caching in tmp_path/cache."""
    env = child_env(modules or tmp_path, tmp_path / "cache")
    return subprocess.run([sys.executable, "-c", FAULT_RUN, *args], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def warm_faultmod(tmp_path_factory):
    """(folder of faultmod.py, a cache holding its two kernels): compiled once for the
    damage cases, which each damage a copy (numba keys entries by the module's path, so
    the module stays where it was compiled)."""
    folder = tmp_path_factory.mktemp("faultmod")
    (folder / "faultmod.py").write_text(FAULTMOD)
    first = _fault_run(folder)
    assert first.returncode == 0 and first.stdout.split() == ["1.5", "1.0", "True"], \
        first.stderr
    return folder, folder / "cache"


def _damage(path, how: str) -> None:
    data = path.read_bytes()
    path.write_bytes({"truncated": data[:len(data) // 2], "empty": b"",
                      "random": os.urandom(max(len(data), 64))}[how])


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to cache with the JIT off")
@pytest.mark.parametrize("suffix", [".nbc", ".nbi"])
@pytest.mark.parametrize("how", ["truncated", "empty", "random"])
def test_an_unreadable_cache_entry_is_compiled_again_and_said_once(tmp_path, suffix, how,
                                                                    warm_faultmod):
    import shutil

    modules, warm = warm_faultmod
    shutil.copytree(warm, tmp_path / "cache")
    files = sorted((tmp_path / "cache").rglob(f"faultmod.*{suffix}"))
    assert len(files) == 2  # one per kernel
    for path in files:
        _damage(path, how)
    second = _fault_run(tmp_path, modules=modules)
    assert second.returncode == 0, second.stderr
    assert "Traceback" not in second.stderr
    assert second.stdout.split() == ["1.5", "1.0", "True"]  # compiled again, right numbers
    notices = [line for line in second.stderr.splitlines() if "unreadable entry" in line]
    assert len(notices) == 1, second.stderr  # once, not once per kernel
    assert f"the kernel cache in {files[0].parent} held an unreadable entry" in notices[0]
    assert "vrsim cache --clear" in notices[0]
    third = _fault_run(tmp_path, modules=modules)  # the recompiled entries were saved whole
    assert third.returncode == 0 and third.stdout.split() == ["1.5", "1.0", "False"], \
        third.stderr
    assert "unreadable" not in third.stderr


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to cache with the JIT off")
def test_a_cache_save_that_fails_compiles_for_this_run_only_and_says_so_once(tmp_path):
    (tmp_path / "faultmod.py").write_text(FAULTMOD)
    full = _fault_run(tmp_path, "full")
    assert full.returncode == 0, full.stderr
    assert "Traceback" not in full.stderr
    assert full.stdout.split() == ["1.5", "1.0", "True"]
    notices = [line for line in full.stderr.splitlines() if "cannot save" in line]
    assert len(notices) == 1, full.stderr
    assert "cannot save compiled kernels in " in notices[0]
    assert "No space left on device): compiled for this run only" in notices[0]
    # nothing half-written was left to load: the next run compiles and keeps them
    assert list((tmp_path / "cache").rglob("*.tmp.*")) == []
    again = _fault_run(tmp_path)
    assert again.returncode == 0 and again.stdout.split() == ["1.5", "1.0", "True"]
    assert "unreadable" not in again.stderr and "cannot save" not in again.stderr


@pytest.mark.skipif(jit.JIT_DISABLED, reason="no compiled code to cache with the JIT off")
def test_cache_clear_removes_compiled_kernels_and_nothing_else(tmp_path, invoke, monkeypatch):
    (tmp_path / "faultmod.py").write_text(FAULTMOD)
    assert _fault_run(tmp_path).returncode == 0
    base = tmp_path / "cache"
    theirs = [base / "README.txt", next(base.glob("src-*")) / "notes.txt"]
    for path in theirs:
        path.write_text("mine")
    monkeypatch.setenv("VRSIM_CACHE_DIR", str(base))
    shown = invoke("cache")
    assert shown.exit_code == 0 and f"cache: {base}: " in shown.stdout
    result = invoke("cache", "--clear")
    assert result.exit_code == 0, result.output
    assert f"from {base}" in result.stdout
    left = sorted(p for p in base.rglob("*") if p.is_file())
    assert left == sorted(theirs)
    assert _fault_run(tmp_path).stdout.split()[-1] == "True"  # compiled again
