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
    assert "stepped impacts: about three minutes" in line, line  # the wait is said
    deadline = time.monotonic() + 30
    while not helpers_using(cache):  # the helper has started (and is compiling: > 30 s)
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.05)
    time.sleep(0.5)
    sent = time.monotonic()
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=30)
    # answered at once, not after the compile: the helper was stopped before it could
    # finish, so no marker claims a compile (checked below); no wall-clock bound, whose
    # verdict would depend on the machine's load (issue 53)
    if signum == signal.SIGKILL:  # the run cannot act: its helper notices and stops
        assert proc.returncode == -signum
        _wait_for(lambda: not helpers_using(cache), 60, "the helper never stopped")
    else:
        assert proc.returncode == 128 + signum, err
        assert "Traceback" not in err
        assert f"interrupted by {signal.Signals(signum).name}" in err
    assert not (tmp_path / "out.csv").exists()
    assert not helpers_using(cache)
    assert not list(cache.glob("src-*/stepped-*.compiled"))  # nothing claims a compile


def _start_run(tmp_path, cache: Path, name: str):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "scene.yaml").write_text(SCENE)
    env = dict(os.environ, VRSIM_CACHE_DIR=str(cache))
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("NUMBA_DISABLE_JIT", None)
    return subprocess.Popen([sys.executable, "-m", "vrsim_cli", "run", "scene.yaml"],
                            cwd=folder, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_for(condition, seconds: float, what: str):
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs Linux /proc")
def test_a_second_run_waits_for_the_first_runs_compile_instead_of_compiling_too(tmp_path):
    """Two runs of a stepped scene on one empty cache (a sweep's workers): one compile
    helper, not two (each is ~60 s of CPU and ~0.5 GB). The waiting run answers a signal
    at once; when the compiling run dies (SIGKILL: its lock goes with it), the waiting one
    takes over the compile."""
    cache = tmp_path / "empty-cache"
    first = _start_run(tmp_path, cache, "first")
    second = third = None
    try:
        assert first.stderr.readline().startswith("vrsim: compiling kernels")
        _wait_for(lambda: helpers_using(cache), 30, "the first run's helper")
        helper = helpers_using(cache)
        second = _start_run(tmp_path, cache, "second")
        assert second.stderr.readline().startswith("vrsim: compiling kernels")
        time.sleep(2.0)  # the second run is started and past its announcement: waiting
        assert helpers_using(cache) == helper and second.poll() is None
        sent = time.monotonic()
        second.send_signal(signal.SIGINT)
        out, err = second.communicate(timeout=30)
        # at once: the first run's compile is still going (below), so the second did not
        # wait for it (no wall-clock bound: its verdict would depend on the load)
        assert second.returncode == 130, err
        assert "interrupted by SIGINT" in err and "Traceback" not in err
        assert helpers_using(cache) == helper  # the first compile goes on, undisturbed

        third = _start_run(tmp_path, cache, "third")
        assert third.stderr.readline().startswith("vrsim: compiling kernels")
        time.sleep(1.0)
        assert helpers_using(cache) == helper and third.poll() is None
        first.kill()  # its helper dies with it (PR_SET_PDEATHSIG), and so does its lock
        first.wait(timeout=30)
        _wait_for(lambda: helpers_using(cache) and helpers_using(cache) != helper, 10,
                  "the waiting run's own helper")
        assert len(helpers_using(cache)) == 1 and third.poll() is None
    finally:
        for proc in (first, second, third):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.communicate(timeout=30)
    _wait_for(lambda: not helpers_using(cache), 5, "no helper left")
    assert not list(cache.glob("src-*/stepped-*.compiled"))


@pytest.mark.skipif(not Path("/proc/self/environ").exists(), reason="needs Linux /proc")
def test_a_run_killed_as_its_helper_starts_leaves_no_helper(tmp_path):
    """Killed while its helper's Python is still starting (before the helper can ask the
    kernel to kill it with its parent, and before it reads its parent's pid): the helper
    knows the run's pid from its command line, sees it gone and stops."""
    cache = tmp_path / "empty-cache"
    run = _start_run(tmp_path, cache, "run")
    try:
        assert run.stderr.readline().startswith("vrsim: compiling kernels")
        deadline = time.monotonic() + 30
        while not helpers_using(cache):
            assert time.monotonic() < deadline
            time.sleep(0.005)
    finally:
        run.kill()
        run.communicate(timeout=30)
    _wait_for(lambda: not helpers_using(cache), 3.0, "the helper of a killed run stopped")
    assert not list(cache.glob("src-*/stepped-*.compiled"))
