"""A stepped scene's first compile runs in a helper process (`loop._compile_apart`).

What the helper saves in memory is measured by test_memory.py (the largest particle scene,
with an empty kernel cache), which also checks that another stepped scene then compiles
nothing. Here: a signal during that compile is answered at once, as a signal at any other
point of start-up, and leaves neither the helper nor a marker behind; a run killed
outright (SIGKILL) leaves no helper compiling on either.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SCENE = """vrsim: 1
duration: 0.1
frame_rate: 100
dt: 0.01
integrator: verlet
collision: {impacts: stepped}
output: {file: out.csv}
bodies:
  - {name: floor, type: static, shape: {type: plane, normal: [0, 0, 1]}}
  - {name: box, mass: 1, position: [0, 0, 0.3], shape: {type: box, size: [0.2, 0.2, 0.2]}}
"""


def helpers_using(cache: Path) -> list[int]:
    """pids of compile helpers whose kernel cache is `cache` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            environ = (entry / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"compile_main" in cmdline and f"VRSIM_CACHE_DIR={cache}".encode() in environ:
            found.append(int(entry.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs Linux /proc")
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL])
def test_a_signal_during_the_first_stepped_compile_is_answered_at_once(tmp_path, signum):
    cache = tmp_path / "empty-cache"
    scene = tmp_path / "scene.yaml"
    scene.write_text(SCENE)
    env = dict(os.environ, VRSIM_CACHE_DIR=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("NUMBA_DISABLE_JIT", None)
    proc = subprocess.Popen([sys.executable, "-m", "vrsim_cli", "run", str(scene)],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    assert line.startswith("vrsim: compiling kernels"), line
    deadline = time.monotonic() + 30
    while not helpers_using(cache):  # the helper has started (and is compiling: > 30 s)
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.05)
    time.sleep(0.5)
    sent = time.monotonic()
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=30)
    waited = time.monotonic() - sent
    # answered within the run's 0.05 s polling and a kill, not after the compile (> 30 s);
    # 3 s for a loaded 2-core machine
    assert waited < 3.0, waited
    if signum == signal.SIGKILL:  # the run cannot act: its helper notices and stops
        assert proc.returncode == -signum
        while helpers_using(cache):
            assert time.monotonic() - sent < 3.0
            time.sleep(0.05)
    else:
        assert proc.returncode == 128 + signum, err
        assert "Traceback" not in err
        assert f"interrupted by {signal.Signals(signum).name}" in err
    assert not (tmp_path / "out.csv").exists()
    assert not helpers_using(cache)
    assert not list(cache.glob("src-*/stepped-*.compiled"))  # nothing claims a compile
