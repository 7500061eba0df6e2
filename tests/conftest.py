"""Shared helpers: scene files in a temporary folder, the CLI runner, the repo's paths."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest
from click.testing import CliRunner

REPO = Path(__file__).resolve().parent.parent
SCENARIOS = REPO / "scenarios"


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
