"""The README's test command passes on a machine without libosmesa6: tests that render
skip with a reason naming the package. CI installs it and sets VRSIM_REQUIRE_OSMESA=1,
which turns that skip into a failure, so rendering stays tested (.ci/run)."""

from __future__ import annotations

import ctypes
import os
import re
import subprocess
import sys

import pytest

from conftest import HIDE_OSMESA, REPO, REQUIRE_OSMESA, osmesa_gate

RENDER_TESTS = ["tests/test_render.py", "tests/test_frames.py", "tests/test_video.py"]


def test_the_gate_runs_skips_or_fails_and_names_the_package():
    assert osmesa_gate(None, required=False) is None
    assert osmesa_gate(None, required=True) is None
    kind, reason = osmesa_gate("the OSMesa library (libOSMesa.so) was not found", False)
    assert kind == "skip" and "apt-get install libosmesa6" in reason
    kind, reason = osmesa_gate("the OSMesa library (libOSMesa.so) was not found", True)
    assert kind == "fail" and "apt-get install libosmesa6" in reason
    assert f"{REQUIRE_OSMESA}=1" in reason


def test_vrsims_probe_sees_a_missing_library(monkeypatch):
    """The gate asks vrsim's own probe (the one `run --frames` uses), so a skipped test
    and a refused run agree on what is missing."""
    from vrsim_cli.render import _probe

    real = ctypes.CDLL.__init__

    def no_osmesa(self, name, *args, **kwargs):
        if name and "OSMesa" in str(name):
            raise OSError(f"{name}: cannot open shared object file")
        real(self, name, *args, **kwargs)

    monkeypatch.setattr(ctypes.CDLL, "__init__", no_osmesa)
    assert _probe() == "the OSMesa library (libOSMesa.so) was not found"


def pytest_run(*args, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-q",
                           "-n", "0", "-rs", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=300, env={**os.environ, **env})


def test_without_libosmesa6_render_tests_skip_and_ci_makes_them_fail():
    """pytest itself, in a process where loading libOSMesa fails as on a machine without
    the package: every `osmesa` test is skipped (exit 0) with the package in the reason;
    with REQUIRE_OSMESA=1, as CI sets it, every one fails (exit 1)."""
    env = {HIDE_OSMESA: "1", REQUIRE_OSMESA: ""}
    collected = pytest_run("--collect-only", "-m", "osmesa", *RENDER_TESTS, **env)
    count = int(re.search(r"(\d+)(?:/\d+)? tests? collected", collected.stdout).group(1))
    assert count >= 15  # the render, frames and video tests
    skipped = pytest_run("-m", "osmesa", *RENDER_TESTS, **env)
    assert skipped.returncode == 0, skipped.stdout
    assert re.search(rf"\b{count} skipped", skipped.stdout), skipped.stdout
    assert "apt-get install libosmesa6" in skipped.stdout
    failed = pytest_run("-m", "osmesa", *RENDER_TESTS, **{**env, REQUIRE_OSMESA: "1"})
    assert failed.returncode == 1  # they fail in set-up: pytest counts them as errors
    assert re.search(rf"\b{count} errors?\b", failed.stdout), failed.stdout
    assert "apt-get install libosmesa6" in failed.stdout


def test_ci_installs_libosmesa6_and_requires_it():
    ci = (REPO / ".ci" / "run").read_text()
    assert "libosmesa6" in ci and f"export {REQUIRE_OSMESA}=1" in ci
    readme = (REPO / "README.md").read_text()
    section = readme.split("## Set up", 1)[1].split("\n## ", 1)[0]
    assert "libosmesa6" in section


@pytest.mark.osmesa
def test_this_machine_renders_when_the_gate_lets_it():
    """On a machine with libosmesa6 (CI) the marked tests really render: a context opens."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.render import open_renderer
    from vrsim_cli.scene.spec import parse_scene

    model = compile_model(parse_scene("vrsim: 1\nduration: 0.1\nbodies: [{name: b, mass: 1}]\n"))
    renderer = open_renderer(model, 16, 16)
    renderer.close()


def test_frames_asked_by_the_scene_without_osmesa_is_a_located_error(tmp_path):
    """Without OSMesa, frames asked for by the scene (output.frames.dir) are refused at the
    scene's key (file:line:col), by --frames at the option; exit 2, nothing written."""
    import subprocess
    import sys

    scene = tmp_path / "scene.yaml"
    scene.write_text("vrsim: 1\nduration: 0.1\nbodies: [{name: a, mass: 1}]\n"
                     "output: {frames: {dir: fr}}\n")
    child = ("import sys; sys.path.insert(0, %r); import conftest; "
             "from vrsim_cli.cli import cli; cli.main(sys.argv[1:], prog_name='vrsim')"
             % str(REPO / "tests"))
    env = {**os.environ, "VRSIM_TEST_HIDE_OSMESA": "1"}
    for extra, where in (([], f"{scene}:4:24: output.frames.dir: "),
                         (["--frames", str(tmp_path / "f2")], "command line (--frames): output.frames.dir: ")):
        proc = subprocess.run([sys.executable, "-c", child, "run", str(scene), "-o",
                               str(tmp_path / "o.csv"), *extra], capture_output=True,
                              text=True, env=env, cwd=tmp_path, timeout=120)
        assert proc.returncode == 2, proc.stderr
        assert f"error: {where}rendering frames needs off-screen OpenGL" in proc.stderr
        assert "libosmesa6" in proc.stderr
        assert not (tmp_path / "o.csv").exists()
