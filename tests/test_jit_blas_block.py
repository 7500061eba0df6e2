"""numba's BLAS stays blocked however a process meets numba (review of 2d290bd).

`jit._refresh_target` imports numba's implementations with `scipy.linalg.cython_blas`
blocked, so that `numba.np.arraymath._HAVE_BLAS` is False (np.correlate/np.convolve then
use a plain loop, not the machine's BLAS) and scipy.linalg is not imported at start-up.
Since 2d290bd a warm process no longer refreshes before loading a kernel, but loading one
whose environment names an implementation module (`a.sum()`, `np.sort`, every stepped
kernel) imports numba.np.arraymath from the cache's pickle (numba/core/environment.py
`_rebuild_env`) -- outside the block: scipy.linalg is imported and `_HAVE_BLAS` is True
for the rest of the process. A kernel compiled afterwards in that process then takes
BLAS's summation order, and which bits it computes depends on what the cache held before.

These tests fail on 2d290bd (the first two pass on 0705a36; the np.dot one failed on
both: the block only covered arraymath's import-time check, and np.dot/@ call numba's
`ensure_blas()` when they are lowered, after the block was lifted; `jit._refusing` now
makes that check refuse while one of our kernels compiles).
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from vrsim_cli.kernels import jit

pytestmark = pytest.mark.skipif(jit.JIT_DISABLED, reason="about compiled and loaded code")

MODULE = """
import numpy as np

from vrsim_cli.kernels.jit import kernel


@kernel
def total(a):
    return a.sum()  # its cached environment names numba.np.arraymath


@kernel
def correlate(a, v):
    return np.correlate(a, v)[0]  # BLAS ddot when arraymath found BLAS, else a loop


@kernel
def product(a, b):
    return np.dot(a, b)
"""

PROBE = """
import sys
import numpy as np
import blasmod
rng = np.random.default_rng(7)
a, v = rng.standard_normal(1001), rng.standard_normal(1001)
for name in sys.argv[1:]:
    if name == "total":
        blasmod.total(a)
    elif name == "correlate":
        print("correlate", float(blasmod.correlate(a, v)).hex())
    elif name == "product":
        try:
            blasmod.product(np.eye(3), np.ones((3, 3)))
            print("product compiled")
        except Exception as exc:
            print("product failed", type(exc).__name__)
am = sys.modules.get("numba.np.arraymath")
print("scipy.linalg", "scipy.linalg" in sys.modules, "have_blas", getattr(am, "_HAVE_BLAS", None))
"""


def _run(tmp_path, cache: str, *names: str) -> list[str]:
    (tmp_path / "blasmod.py").write_text(MODULE)
    env = {**os.environ, "VRSIM_CACHE_DIR": str(tmp_path / cache),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")])}
    env.pop("NUMBA_CACHE_DIR", None)
    proc = subprocess.run([sys.executable, "-c", PROBE, *names], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.split("\n")


def test_loading_a_kernel_from_the_cache_keeps_blas_blocked(tmp_path):
    _run(tmp_path, "cache", "total")  # compiles and caches it
    warm = _run(tmp_path, "cache", "total")  # loads it
    assert "scipy.linalg False have_blas False" in warm, warm


def test_a_kernel_computes_the_same_bits_whatever_the_cache_held_before(tmp_path):
    """np.correlate of two 1001-vectors: the loop and OpenBLAS's ddot differ in the last
    bits (12.196946891581367 against ...387 here)."""
    first = _run(tmp_path, "a", "correlate")[0]  # its first compile, in a fresh cache
    _run(tmp_path, "b", "total")
    after_load = _run(tmp_path, "b", "total", "correlate")[0]  # compiled after a load
    assert first.startswith("correlate ") and after_load == first


def test_np_dot_in_a_kernel_fails_to_compile(tmp_path):
    """docs/architecture.md and docs/dynamics.md: `np.dot` in a kernel fails to compile,
    whether it is the process's first compile or comes after a load from the cache."""
    assert _run(tmp_path, "cache", "product")[0].startswith("product failed"), "first"
    _run(tmp_path, "warm", "total")
    out = _run(tmp_path, "warm", "total", "product")
    assert out[0].startswith("product failed"), out
