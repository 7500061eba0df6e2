"""The Python API (vrsim_cli.load, simulate, Simulation, Trajectory): the states of the
CLI's runs, bit for bit; stepping in pieces equals one run; the docs' example runs; and
`import vrsim_cli` stays cheap."""

from __future__ import annotations

import re
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import vrsim_cli
from conftest import REPO, SCENARIOS
from vrsim_cli.errors import InputError, SimulationError
from vrsim_cli.loop import run
from vrsim_cli.model.state import make_state, state_hash
from vrsim_cli.writers import open_writer

CHUNKED = ["projectile", "bounce", "keyframes", "car", "fountain", "walk-steps", "dzhanibekov",
           "collision"]


def test_import_is_cheap_and_the_api_loads_on_first_use():
    code = ("import sys, vrsim_cli; assert 'numpy' not in sys.modules; "
            "assert 'vrsim_cli.api' not in sys.modules; vrsim_cli.simulate; "
            "assert 'vrsim_cli.api' in sys.modules; print(sorted(vrsim_cli.API))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=REPO)
    assert "simulate" in out.stdout
    with pytest.raises(AttributeError, match="no attribute 'nonsense'"):
        vrsim_cli.nonsense  # noqa: B018


def test_load_takes_a_path_or_text_and_the_command_lines_overrides(tmp_path):
    path = SCENARIOS / "projectile.yaml"
    for source in (path, str(path)):
        assert vrsim_cli.load(source).name == "projectile"
    model = vrsim_cli.load(path.read_text(), duration=0.5, dt=0.01, integrator="euler")
    assert (model.duration, model.dt, model.integrator) == (0.5, 0.01, "euler")
    with pytest.raises(InputError) as err:
        vrsim_cli.load("vrsim: 1\nduration: -1\n")
    assert err.value.problems[0].line == 2 and "duration" in str(err.value)
    with pytest.raises(InputError, match="no such file"):
        vrsim_cli.load("missing.yaml")
    with pytest.raises(TypeError, match="unknown overrides"):
        vrsim_cli.load(path, speed=3)


@pytest.mark.parametrize("name", ["projectile", "fountain", "walk-steps"])
def test_samples_are_the_cli_outputs_numbers(name, tmp_path):
    """Iterating a Simulation gives the samples a CSV output holds, bit for bit."""
    model = vrsim_cli.load(SCENARIOS / f"{name}.yaml")
    csv = tmp_path / "out.csv"
    writer = open_writer(model, csv, "csv")
    run(model, make_state(model), writer)
    writer.close()
    reference = vrsim_cli.read_trajectory(csv)
    states = list(vrsim_cli.simulate(model))
    traj = vrsim_cli.Trajectory.from_states(model, states)
    assert traj.names == reference.names
    assert traj.t.tolist() == reference.t.tolist()
    for field in ("position", "orientation", "velocity", "angular_velocity"):
        assert getattr(traj, field).tolist() == getattr(reference, field).tolist(), field
    assert vrsim_cli.simulate(model).run().position.tolist() == traj.position.tolist()


@settings(max_examples=12, deadline=None)
@given(name=st.sampled_from(CHUNKED), chunks=st.lists(st.integers(1, 40), min_size=1,
                                                      max_size=6))
def test_stepping_in_pieces_equals_one_run(name, chunks):
    """Any sequence of step(n) calls reaches the state of one uninterrupted run, with the
    same samples on the way (the loop restarts from the state it is given)."""
    model = vrsim_cli.load(SCENARIOS / f"{name}.yaml", duration=0.4)
    whole = vrsim_cli.simulate(model)
    whole.run()
    pieces = vrsim_cli.simulate(model)
    k = 0
    while not pieces.done:
        pieces.step(chunks[k % len(chunks)])
        k += 1
    assert state_hash(pieces.state) == state_hash(whole.state)
    assert [s.step for s in pieces.samples] == [s.step for s in whole.samples]
    assert [state_hash(s) for s in pieces.samples] == [state_hash(s) for s in whole.samples]


def test_step_counts_frames_and_stops_at_the_end():
    model = vrsim_cli.load(SCENARIOS / "projectile.yaml")  # 100 Hz frames, 1.5 s
    sim = vrsim_cli.simulate(model)
    assert sim.step(3).step == 3 * model.steps_per_frame and sim.t == pytest.approx(0.03)
    assert sim.step(0).step == 3 * model.steps_per_frame
    sim.step(10_000)
    assert sim.done and sim.t == 1.5 and sim.step(5).t == 1.5


def test_a_blow_up_raises_and_keeps_the_samples_before_it():
    model = vrsim_cli.load("""
vrsim: 1
duration: 1.0
frame_rate: 50
dt: 0.01
bodies: [{name: rocket, mass: 1.0e-9, forces: [{force: [1.0e15, 0, 0], start: 0.5}]}]
""")
    sim = vrsim_cli.simulate(model)
    with pytest.raises(SimulationError, match="rocket"):
        sim.run()
    assert sim.samples[-1].t == pytest.approx(0.5)


def test_the_dataframe_is_the_csv_output(tmp_path):
    pd = pytest.importorskip("pandas")
    model = vrsim_cli.load(SCENARIOS / "cradle.yaml")
    csv = tmp_path / "out.csv"
    writer = open_writer(model, csv, "csv")
    run(model, make_state(model), writer)
    writer.close()
    frame = vrsim_cli.simulate(model).run().to_dataframe()
    expected = pd.read_csv(csv)
    pd.testing.assert_frame_equal(frame, expected, check_exact=True)


def test_read_trajectory_of_an_mcap_gives_the_run(tmp_path):
    model = vrsim_cli.load(SCENARIOS / "bounce.yaml", duration=0.5)
    path = tmp_path / "b.mcap"
    writer = open_writer(model, path, "mcap")
    run(model, make_state(model), writer)
    writer.close()
    read = vrsim_cli.read_trajectory(path)
    ran = vrsim_cli.simulate(model).run()
    assert read.names == ran.names
    assert np.array_equal(read.position, ran.position)
    assert np.array_equal(read.velocity, ran.velocity)


def test_the_docs_example_runs(monkeypatch, capsys):
    monkeypatch.chdir(REPO)  # the example names scenarios/ relative to the checkout
    text = (REPO / "docs" / "api.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert blocks
    for block in blocks:
        exec(compile(block, "docs/api.md", "exec"), {})
    out = capsys.readouterr().out
    assert "projectile 2 0.001 1.5" in out and "falling from t = 0.73 s" in out
    assert "apex at t = 0.72 s, 3.548 m" in out


def test_the_readme_python_example_runs(monkeypatch):
    monkeypatch.chdir(REPO)
    text = (REPO / "README.md").read_text()
    (block,) = re.findall(r"```python\n(.*?)```", text, re.S)
    scope: dict = {}
    exec(compile(block, "README.md", "exec"), scope)
    assert scope["traj"].position[:, scope["traj"].index("ball")].shape == (151, 3)


@pytest.mark.parametrize("impacts", ["located", "stepped"])
def test_bodies_that_start_inside_each_other_are_an_input_error(impacts):
    """As `vrsim run` and `vrsim validate` refuse them (exit 2): the problem is located
    at the second body's position and names both bodies."""
    text = f"""vrsim: 1
duration: 0.1
collision: {{impacts: {impacts}}}
bodies:
  - {{name: a, mass: 1, shape: {{type: sphere, radius: 0.5}}, position: [0, 1, 0]}}
  - {{name: b, mass: 1, shape: {{type: sphere, radius: 0.5}}, position: [0.3, 1, 0]}}
"""
    with pytest.raises(InputError) as caught:
        vrsim_cli.load(text)
    (problem,) = caught.value.problems
    assert problem.line == 6 and problem.path == ("bodies", 1, "position")
    assert "overlap at start" in problem.message and "'a'" in problem.message
    # apart by 1 mm: loads
    vrsim_cli.load(text.replace("[0.3, 1, 0]", "[1.001, 1, 0]"))
