"""Results do not depend on the CPU (issue 19, item 3; issue 53, item 4).

Every scenario is run for its first 0.2 s in a child process under environment variables
that change which machine code numpy, OpenBLAS and numba use, and every sample of its
trajectory (the CSV's bytes: shortest round-trip floats, so equal bytes are equal bits)
and its final state hash (sha256 of every state array) must equal those of the unchanged
environment. The scenarios without contacts also run whole under the libm variants: a
final hash missed the car's last-bit differences from t = 3.3 s (issue 53):

- OPENBLAS_CORETYPE = Prescott, Haswell, SkylakeX, Zen: OpenBLAS's kernels for those CPUs
  (vrsim does its small-matrix algebra itself, `maths/products.py` and `kernels/`, so no
  result may go through BLAS or LAPACK; before that, `np.linalg.norm` of the observer's
  direction and the `pinv` of the resting-contact solve changed keyframes.yaml and
  stack.yaml in the last bit);
- NPY_DISABLE_CPU_FEATURES without the AVX-512 groups, and without AVX2 as well: numpy's
  SIMD loops for sums, norms and transcendental functions;
- NUMBA_CPU_NAME=generic: the compiled kernels built for a generic x86-64 (no AVX, no FMA)
  instead of this machine's CPU. A fresh kernel build costs ~15 s per integrator, so this
  variant runs one scenario per integrator the scenarios use: verlet (dzhanibekov: the
  rotation kernels), rk4 (projectile) and symplectic-euler (fountain).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from conftest import SCENARIOS

SECONDS = 0.2

CHILD = r"""
import hashlib, json, sys
from click.testing import CliRunner
from vrsim_cli.cli import cli
hashes = {}
for path in sys.argv[2:]:
    seconds = [] if sys.argv[1] == "whole" else ["--duration", sys.argv[1]]
    result = CliRunner().invoke(cli, ["run", path, "-o", "trajectory.csv", *seconds],
                                catch_exceptions=False)
    lines = [l for l in result.stdout.splitlines() if l.startswith("state sha256:")]
    if result.exit_code == 0 and lines:
        with open("trajectory.csv", "rb") as f:  # every sample, bit for bit
            data = f.read()
        # the first sample that differs is found by comparing these per-sample digests
        rows = {}
        for line in data.splitlines()[1:]:
            t = line.split(b",", 1)[0]
            rows.setdefault(t, hashlib.sha256()).update(line)
        hashes[path] = [lines[0], [t.decode() + " " + h.hexdigest()[:16]
                                   for t, h in rows.items()]]
    else:
        hashes[path] = f"exit {result.exit_code}: {result.stdout[-300:]} {result.stderr[-300:]}"
print(json.dumps(hashes))
"""

ALL = sorted(str(p) for p in SCENARIOS.glob("*.yaml"))
GENERIC = [str(SCENARIOS / f"{name}.yaml") for name in ("dzhanibekov", "projectile",
                                                         "fountain")]

VARIANTS = {f"OPENBLAS_CORETYPE={core}": ({"OPENBLAS_CORETYPE": core}, ALL)
            for core in ("Prescott", "Haswell", "SkylakeX", "Zen")}
VARIANTS["numpy without AVX-512"] = (
    {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"}, ALL)
VARIANTS["numpy without AVX2 and AVX-512"] = (
    {"NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"}, ALL)
# glibc's libm picks FMA/AVX2 variants of sin, cos, exp, pow ... by CPU (ifuncs); this
# hides those features from glibc only (numpy, OpenBLAS and LLVM read cpuid themselves).
# Names checked with `ld.so --list-diagnostics` (glibc 2.36): the FMA bit of leaf 1 ECX and
# the AVX2 and AVX512F bits of leaf 7 EBX go from usable to not.
GLIBC_NO_FMA = "glibc.cpu.hwcaps=-AVX2,-FMA,-FMA4,-AVX512F"
VARIANTS["glibc's libm without FMA and AVX2"] = ({"GLIBC_TUNABLES": GLIBC_NO_FMA}, ALL)
VARIANTS["glibc's libm and numpy without FMA and AVX2"] = (
    {"GLIBC_TUNABLES": GLIBC_NO_FMA,
     "NPY_DISABLE_CPU_FEATURES": "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"}, ALL)
VARIANTS["numba for a generic x86-64"] = ({"NUMBA_CPU_NAME": "generic"}, GENERIC)
# whole runs of the scenarios without contacts (~1 s each; the contact scenarios' whole
# runs would cost minutes per variant): where libm's variants would show
WHOLE = sorted(str(p) for p in SCENARIOS.glob("*.yaml")
               if not any(line.startswith("collision:") for line in p.read_text().splitlines()))
WHOLE_VARIANTS = {name: VARIANTS[name] for name in (
    "glibc's libm without FMA and AVX2", "glibc's libm and numpy without FMA and AVX2",
    "numpy without AVX2 and AVX-512")}


MODEL_CHILD = r"""
import hashlib, json, sys
import numpy as np
from vrsim_cli.model.model import compile_model
from vrsim_cli.scene.spec import load_scene
out = {}
for path in sys.argv[1:]:
    model = compile_model(load_scene(path))
    h = hashlib.sha256()
    for part in (model, model.rigid):
        for name, value in sorted(vars(part).items() if part is not None else []):
            if isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
                h.update(name.encode() + np.ascontiguousarray(value).tobytes())
    out[path] = h.hexdigest()
print(json.dumps(out))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.uname().machine != "x86_64",
                    reason="GLIBC_TUNABLES names x86-64 features")
def test_every_compiled_model_is_bit_identical_without_fma_in_libm(tmp_path):
    """Every array of every scenario's compiled model (initial state, emitted particles'
    launch velocities, inertia and principal axes, ...) with glibc's libm variants
    without FMA: the whole run is not needed to see a libm call at compile. Before
    maths/trig.py, the fountain's launch directions (numpy's sin and cos -> libm)
    differed here, and its final state after 4 s."""
    def run(extra):
        env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
        env.update(extra)
        proc = subprocess.run([sys.executable, "-c", MODEL_CHILD, *ALL], env=env,
                              capture_output=True, text=True, timeout=600, cwd=tmp_path)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return json.loads(proc.stdout.splitlines()[-1])

    plain, no_fma = run({}), run({"GLIBC_TUNABLES": GLIBC_NO_FMA})
    assert plain == no_fma, [os.path.basename(k) for k in plain if plain[k] != no_fma[k]]


def _hashes(extra_env: dict, scenes: list[str], cwd, seconds=SECONDS) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES", "NUMBA_CPU_NAME",
                        "NUMBA_CPU_FEATURES", "GLIBC_TUNABLES")}
    env.update(extra_env)
    # a scenario's outputs are relative to the current folder: a temporary one
    proc = subprocess.run([sys.executable, "-c", CHILD, str(seconds), *scenes], env=env,
                          capture_output=True, text=True, timeout=600, cwd=cwd)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.splitlines()[-1])


def _reference(tmp_path_factory, scenes, seconds):
    found = _hashes({}, scenes, tmp_path_factory.mktemp("reference"), seconds)
    failed = {k: v for k, v in found.items() if isinstance(v, str)}
    assert not failed, failed
    return found


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    return _reference(tmp_path_factory, ALL, SECONDS)


@pytest.fixture(scope="module")
def whole_reference(tmp_path_factory):
    return _reference(tmp_path_factory, WHOLE, "whole")


def _differences(reference: dict, found: dict, scenes) -> dict:
    """scene -> the first sample whose values differ (or the final hash, or the error)."""
    differ = {}
    for k in scenes:
        if found[k] == reference[k]:
            continue
        if isinstance(found[k], str):
            differ[os.path.basename(k)] = found[k]
            continue
        (hash_a, rows_a), (hash_b, rows_b) = reference[k], found[k]
        first = next((a.split()[0] for a, b in zip(rows_a, rows_b) if a != b), None)
        differ[os.path.basename(k)] = f"from t = {first}" if first else \
            f"final state {hash_a} != {hash_b}"
    return differ


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.uname().machine != "x86_64",
                    reason="the variants name x86-64 CPUs and OpenBLAS/numpy x86 kernels")
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_every_sample_of_every_scenario_is_bit_identical_whatever_the_cpu_code(
        variant, reference, tmp_path):
    extra, scenes = VARIANTS[variant]
    differ = _differences(reference, _hashes(extra, scenes, tmp_path), scenes)
    assert not differ, f"{variant} changes the trajectory of {differ}"


@pytest.mark.skipif(not sys.platform.startswith("linux") or os.uname().machine != "x86_64",
                    reason="the variants name x86-64 CPUs and numpy x86 kernels")
@pytest.mark.parametrize("variant", list(WHOLE_VARIANTS))
def test_whole_runs_without_contacts_are_bit_identical_whatever_the_cpu_code(
        variant, whole_reference, tmp_path):
    """Issue 53: car.yaml without FMA in libm differed in the last bit of 7 values from
    t = 3.3 s (numpy's sin and cos of the drive's heading); its final hash did not."""
    extra, _ = WHOLE_VARIANTS[variant]
    differ = _differences(whole_reference, _hashes(extra, WHOLE, tmp_path, "whole"), WHOLE)
    assert not differ, f"{variant} changes the trajectory of {differ}"


# Off the simulation path: the camera places rendered frames (PNG pixels, not the state);
# the numpy orthonormalize is the tests' reference (the kernels have their own,
# kernels/linalg.py); a mesh's flatness check answers yes or no about an input file.
NOT_SIMULATION = {"vrsim_cli/maths/camera.py", "vrsim_cli/maths/rotation.py:orthonormalize",
                  "vrsim_cli/maths/meshes.py:solid_problem"}
BLAS_CALLS = {"dot", "matmul", "inner", "vdot", "tensordot"}
LAPACK_CALLS = {"inv", "solve", "pinv", "lstsq", "eig", "eigh", "eigvals", "eigvalsh",
                "det", "svd", "qr", "cholesky"}


def _blas_uses(path):
    """Lines of `path` with a product that goes through BLAS or LAPACK: `a @ b`,
    np.dot/matmul/..., np.linalg's solvers, and np.linalg.norm of a whole array (a dot
    product; with `axis` numpy sums itself)."""
    import ast
    found = []
    tree = ast.parse(path.read_text("utf-8"))
    exempt = set()
    for fn in ast.walk(tree):
        if isinstance(fn, ast.FunctionDef) and f"{rel_of(path)}:{fn.name}" in NOT_SIMULATION:
            exempt |= {id(n) for n in ast.walk(fn)}
    for node in ast.walk(tree):
        if id(node) in exempt:
            continue
        elif isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult):
            found.append(node.lineno)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            name, owner = node.func.attr, ast.unparse(node.func.value)
            if owner in ("np", "numpy") and name in BLAS_CALLS or \
                    owner in ("np.linalg", "numpy.linalg") and name in LAPACK_CALLS or \
                    owner in ("np.linalg", "numpy.linalg") and name == "norm" and \
                    not any(k.arg == "axis" for k in node.keywords):
                found.append(node.lineno)
    return found


def rel_of(path) -> str:
    from conftest import REPO
    try:
        return path.resolve().relative_to(REPO).as_posix()
    except ValueError:
        return path.name


def test_the_simulation_path_has_no_blas_products():
    """No product on the simulation path goes through BLAS or LAPACK, whose kernels round
    by CPU (maths/products.py says why). The scenario runs above catch what they reach;
    this catches the paths they do not (a cylinder pair's manifold used `@` and made the
    coins scenario differ under every OPENBLAS_CORETYPE; the located solver's work
    checks and fcl's touching probe did too)."""
    from conftest import REPO
    package = REPO / "vrsim_cli"
    files = [p for sub in ("stages", "model", "maths", "kernels")
             for p in sorted((package / sub).rglob("*.py"))] + [package / "loop.py"]
    offenders = {}
    for path in files:
        rel = path.relative_to(REPO).as_posix()
        if rel in NOT_SIMULATION:
            continue
        lines = _blas_uses(path)
        if lines:
            offenders[rel] = lines
    assert not offenders, offenders


def test_the_blas_scan_finds_what_it_looks_for(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import numpy as np\nx = a @ b\ny = np.dot(a, b)\nz = np.linalg.norm(v)\n"
                   "w = np.linalg.norm(v, axis=1)\nq = np.linalg.solve(A, b)\n")
    assert _blas_uses(bad) == [2, 3, 4, 6]
