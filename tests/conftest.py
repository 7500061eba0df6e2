"""Shared helpers: scene files in a temporary folder, the CLI runner, the repo's paths."""

from __future__ import annotations

import os
import textwrap
from functools import lru_cache
from pathlib import Path

import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parent.parent
SCENARIOS = REPO / "scenarios"

# ----------------------------------------------------------------------------- OSMesa
# Tests marked `osmesa` render real frames. On a machine without libosmesa6 they skip with
# a reason naming the package, so the README's test command passes on a fresh machine; CI
# (.ci/run) installs libosmesa6 and sets REQUIRE_OSMESA=1, which turns that skip into a
# failure, so rendering stays tested. HIDE_OSMESA=1 makes this process behave as if the
# library were missing (tests/test_render_gate.py runs pytest that way).
REQUIRE_OSMESA = "VRSIM_REQUIRE_OSMESA"
HIDE_OSMESA = "VRSIM_TEST_HIDE_OSMESA"
OSMESA_PACKAGE = "libosmesa6"


def hide_osmesa() -> None:
    """Make every ctypes load of libOSMesa fail, as on a machine without libosmesa6."""
    import ctypes

    real = ctypes.CDLL.__init__

    def no_osmesa(self, name, *args, **kwargs):
        if name and "OSMesa" in str(name):
            raise OSError(f"{name}: cannot open shared object file: No such file or directory")
        real(self, name, *args, **kwargs)

    ctypes.CDLL.__init__ = no_osmesa


if os.environ.get(HIDE_OSMESA) == "1":
    hide_osmesa()


@lru_cache(maxsize=1)
def osmesa_problem() -> str | None:
    """Why frames cannot be rendered in this process (vrsim's own probe), or None."""
    from vrsim_cli.render import _probe

    return _probe()


def osmesa_gate(problem: str | None, required: bool) -> tuple[str, str] | None:
    """What a test that renders does here: None (run it), ('skip', reason) or ('fail',
    reason). The reason names the Debian package."""
    if problem is None:
        return None
    reason = f"rendering needs OSMesa: apt-get install {OSMESA_PACKAGE} ({problem})"
    if required:
        return "fail", f"{reason}; {REQUIRE_OSMESA}=1 (CI) makes this a failure, not a skip"
    return "skip", reason


def pytest_configure(config):
    config.addinivalue_line("markers", f"osmesa: renders frames through OSMesa ("
                                       f"{OSMESA_PACKAGE}); skipped without it unless "
                                       f"{REQUIRE_OSMESA}=1")


def pytest_runtest_setup(item):
    if item.get_closest_marker("osmesa") is None:
        return
    gate = osmesa_gate(osmesa_problem(), os.environ.get(REQUIRE_OSMESA) == "1")
    if gate is not None:
        (pytest.fail if gate[0] == "fail" else pytest.skip)(gate[1])


@pytest.fixture(autouse=True)
def _run_in_tmp_path(tmp_path, monkeypatch):
    """Every test runs in its own temporary folder: a scene's outputs are relative to the
    current folder, so no test writes into the checkout."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def write_scene(tmp_path):
    """write_scene(text, name='scene.yaml') -> Path of a dedented scene file in tmp_path."""

    def write(text: str, name: str = "scene.yaml") -> Path:
        path = tmp_path / name
        path.write_text(textwrap.dedent(text).lstrip("\n"), encoding="utf-8")
        return path

    return write


@pytest.fixture(scope="session")
def _kernels_compiled():
    """Compile (or load from the cache) every integrator's kernel once, before the first CLI
    test: on a fresh machine the first run of each integrator prints a compile notice on
    stderr, which tests that read stderr line by line must not depend on. The notice itself
    is tested in test_cli.py."""
    from vrsim_cli.kernels.dynamics import INTEGRATOR_CODES
    from vrsim_cli.loop import prepare
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import parse_scene

    for name in INTEGRATOR_CODES:
        prepare(compile_model(parse_scene(
            f"vrsim: 1\nname: warm\nduration: 0.1\ndt: 0.01\nintegrator: {name}\n"
            "bodies: [{name: b, mass: 1.0}]\n")))


@pytest.fixture
def runner():
    return CliRunner()


@pytest.fixture
def invoke(runner, _kernels_compiled):
    """invoke(*args) -> click Result of `vrsim ARGS` run in-process."""
    from vrsim_cli.cli import cli

    def call(*args):
        return runner.invoke(cli, [str(a) for a in args], catch_exceptions=False)

    return call


class Steps:
    """Writer that keeps every sampled state."""

    def __init__(self):
        self.states = []

    def write(self, state):
        self.states.append(state)


def simulate(text: str):
    """(model, sampled states, final state) of a scene given as YAML text."""
    from vrsim_cli.loop import run
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import parse_scene

    model = compile_model(parse_scene(text))
    rec = Steps()
    result = run(model, make_state(model), rec)
    return model, rec.states, result.state
