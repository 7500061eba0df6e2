"""`vrsim run --json`: one JSON object on stdout, numbers that agree with the run itself;
the text summary counts in words with the right plural."""

from __future__ import annotations

import json

import pytest

from test_cli import BALL
from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state, state_hash
from vrsim_cli.scene.spec import parse_scene
from vrsim_cli.text import plural, table
from vrsim_cli.tools.trajectory import read_trajectory



def test_run_json_is_the_only_stdout_and_matches_the_run(invoke, write_scene, tmp_path):
    out = tmp_path / "o.csv"
    result = invoke("run", write_scene(BALL), "-o", out, "--json")
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)  # nothing else on stdout
    model = compile_model(parse_scene(BALL))
    final = run(model, make_state(model)).state
    assert report["ok"] is True and report["scene"] == "drop"
    assert report["output"] == str(out) and report["format"] == "csv"
    assert report["simulated_s"] == 1.0 and report["steps"] == 100 and report["dt_s"] == 0.01
    assert report["state_sha256"] == state_hash(final)
    assert report["samples"] == len(read_trajectory(out).times) == 51
    assert report["frames"] == 50 and report["wall_s"] > 0
    assert set(report["profile_s"]) >= {"dynamics", "output"}


def test_a_failed_run_reports_json_too(invoke, write_scene, tmp_path):
    # the largest force on the smallest mass a scene may give (scene/limits): 1e24 m/s^2
    # moves it 1e20 m in one step, past the blow-up check's 1e12 m
    scene = write_scene(BALL.replace(
        "bodies: [", "bodies: [{name: rocket, mass: 1.0e-9, "
                     "forces: [{force: [1.0e15, 0, 0], start: 0.5}]}, "))
    result = invoke("run", scene, "-o", tmp_path / "o.csv", "--json")
    assert result.exit_code == 1
    report = json.loads(result.stdout)
    assert report["ok"] is False and report["body"] == "rocket"
    assert report["failed_at_s"] == pytest.approx(0.51)
    assert "moved more than 1e+12 m from the origin" in report["error"]


def test_one_step_reads_as_one_step(invoke, write_scene):
    result = invoke("run", write_scene(BALL.replace("duration: 1.0", "duration: 0.01")))
    assert " in 1 step of 0.01 s," in result.stdout
    result = invoke("validate", write_scene(BALL.replace("duration: 1.0", "duration: 0.01")))
    assert "(1 body, 0.01 s in 1 step of 0.01 s" in result.stdout


def test_plural_and_tables():
    assert [plural(n, "body") for n in (0, 1, 2)] == ["0 bodies", "1 body", "2 bodies"]
    assert plural(1, "entity") == "1 entity" and plural(3, "sample") == "3 samples"
    lines = table(["name", "n"], [["a-very-long-entity-name", 1], ["b", 1234]], right={1})
    assert lines == ["name                        n",
                     "a-very-long-entity-name     1",
                     "b                        1234"]
