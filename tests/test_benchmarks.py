"""Every script in benchmarks/ runs to its end on a small size: a benchmark that ends in a
traceback (as output_cost.py did with the default 1000 bodies and TUM's 256-entity limit)
is found here, not by the next person who wants a number. The sizes are the smallest that
go through every branch of each script; the numbers they print are not checked (they are
measurements, taken at full size on a quiet machine; docs/benchmarks.md)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from conftest import REPO

RUNS = {
    "output_cost.py": ["--bodies", "300", "--samples", "3", "--repeats", "1"],
    "collision_bench.py": ["--max-n", "100", "--repeats", "1"],
    "sweep_bench.py": ["--quick", "--only", "overhead", "--jobs", "1"],
    "patch_coulomb.py": ["10"],
    "bench_render.py": ["--bodies", "3", "--frames", "2", "--batches", "1", "--width", "64",
                        "--height", "48"],
}


def test_every_benchmark_script_is_run_here():
    assert {p.name for p in (REPO / "benchmarks").glob("*.py")} == set(RUNS)


@pytest.mark.parametrize("script", [pytest.param(name, marks=pytest.mark.osmesa)
                                    if name == "bench_render.py" else name for name in RUNS])
def test_benchmark_script_runs(script, tmp_path):
    done = subprocess.run([sys.executable, str(REPO / "benchmarks" / script), *RUNS[script]],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stdout + done.stderr
    assert done.stdout.strip()


def test_output_cost_says_why_it_skips_tum():
    done = subprocess.run([sys.executable, str(REPO / "benchmarks" / "output_cost.py"),
                           *RUNS["output_cost.py"]], capture_output=True, text=True,
                          timeout=600)
    assert "tum    skipped: TUM writes one file per entity, at most 256" in done.stdout
