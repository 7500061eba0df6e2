"""The loop as a whole: sampling, determinism, interruption, lazy imports."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import pytest

from conftest import REPO, SCENARIOS
from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state, state_hash
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.writers import open_writer


class Recorder:
    def __init__(self):
        self.times = []

    def write(self, state):
        self.times.append(state.t)


def test_samples_on_the_output_grid_and_always_the_final_state():
    model = compile_model(parse_scene("""
vrsim: 1
duration: 1.005
frame_rate: 100
dt: 0.001
output: {rate: 50}
bodies: [{name: a, mass: 1}]
"""))
    rec = Recorder()
    result = run(model, make_state(model), rec)
    assert model.n_steps == 1005 and model.n_frames == 101
    assert rec.times[:3] == [0.0, 0.02, 0.04]
    assert len(rec.times) == 52 and rec.times[-1] == result.state.t == 1005 * 0.001
    assert result.frames == 101 and result.samples == 52


def test_stop_request_ends_the_run_at_a_frame_boundary():
    model = compile_model(parse_scene("vrsim: 1\nduration: 10\nframe_rate: 10\ndt: 0.01\n"
                                      "bodies: [{name: a, mass: 1}]\n"))
    frames = []
    result = run(model, make_state(model), should_stop=lambda: len(frames) >= 3,
                 on_frame=frames.append)
    assert result.interrupted and result.frames == 3 and result.state.step == 30


def _counting_calls(monkeypatch):
    """The steps of every compiled dynamics call the loop makes."""
    from vrsim_cli.stages.dynamics import motion

    counts, real = [], motion.run
    monkeypatch.setattr(motion, "run", lambda m, s, n, *a: counts.append(n) or real(m, s, n, *a))
    return counts


@pytest.mark.parametrize("n_body, integrator", [(1, "rk4"), (3, "symplectic-euler"),
                                                (2, "verlet")])
def test_coarse_callbacks_make_one_compiled_call_per_output_sample(monkeypatch, n_body,
                                                                   integrator):
    """Issue 16: between two output samples one compiled call, also under the command
    line's signal check and progress bar (coarse callbacks); the states are those of a
    run without callbacks, bit for bit."""
    bodies = ", ".join(f"{{name: b{i}, mass: 1, shape: {{type: box, size: [0.1, 0.2, 0.3]}}, "
                       f"angular_velocity: [0.1, {i + 1}, 0.2], velocity: [{i}, 2, 0]}}"
                       for i in range(n_body))
    model = compile_model(parse_scene(f"""
vrsim: 1
duration: 2.0
frame_rate: 100
dt: 0.002
integrator: {integrator}
output: {{rate: 10}}
bodies: [{bodies}]
"""))
    plain = Recorder()
    truth = run(model, make_state(model), plain).state
    counts = _counting_calls(monkeypatch)
    rec, seen = Recorder(), []
    result = run(model, make_state(model), rec, should_stop=lambda: False,
                 on_frame=lambda s: seen.append(s.step), coarse_callbacks=True)
    assert counts == [50] * 20  # 2 s of 2 ms steps, a sample every 0.1 s
    assert seen == [50 * (k + 1) for k in range(20)]
    assert rec.times == plain.times and result.frames == 200 and result.samples == 21
    assert state_hash(result.state) == state_hash(truth)
    counts.clear()
    run(model, make_state(model), Recorder(), should_stop=lambda: False, on_frame=seen.append)
    assert counts == [5] * 200  # fine callbacks (the API): one call per frame


def test_coarse_callbacks_stop_at_a_frame_and_calls_stay_short(monkeypatch):
    """Without output every call is cut at whole frames of at most CALL_BODY_STEPS
    body-steps, so a signal is answered between calls; a stop ends the run there."""
    from vrsim_cli.loop import CALL_BODY_STEPS

    model = compile_model(parse_scene("vrsim: 1\nduration: 1000\nframe_rate: 30\n"
                                      "dt: 0.001\nbodies: [" + ", ".join(
                                          f"{{name: p{i}, mass: 1}}" for i in range(7)) + "]\n"))
    counts = _counting_calls(monkeypatch)
    calls = []
    result = run(model, make_state(model), None, should_stop=lambda: len(calls) >= 4,
                 on_frame=calls.append, coarse_callbacks=True)
    spf = model.steps_per_frame
    assert result.interrupted and len(counts) == 4
    assert all(c % spf == 0 and c * 7 <= CALL_BODY_STEPS for c in counts)
    assert result.state.step == sum(counts) and result.frames == sum(counts) // spf


def test_render_runs_at_stage_3_with_the_initial_state_and_every_frame():
    model = compile_model(parse_scene("vrsim: 1\nduration: 0.35\nframe_rate: 10\ndt: 0.01\n"
                                      "bodies: [{name: a, mass: 1}]\n"))
    seen = []
    result = run(model, make_state(model), render=lambda s: seen.append(s.step))
    # 0.35 s at 10 Hz: three whole frames and a last one of 5 steps.
    assert seen == [0, 10, 20, 30, 35] and result.frames == 4
    assert "render" in result.profile
    assert "render" not in run(model, make_state(model)).profile


# The scenarios' whole runs are reproduced bit for bit by tests/test_golden.py (state
# hash and CSV bytes, on a pool and in one process, against the pins). What is left here
# is one model run again in the same process, to both writers (MCAP's bytes are checked
# only here). The first second of each scenario runs the same stages and writers as the
# whole run (they are chosen by the scene, not by the time) at a fifth of the cost.
SAME_SCENE_S = 1.0


@pytest.mark.parametrize("scenario", sorted(p.name for p in SCENARIOS.glob("*.yaml")))
def test_same_scene_gives_bit_identical_outputs(scenario, tmp_path):
    scene = load_scene(SCENARIOS / scenario)
    if float(scene.data["duration"]) > SAME_SCENE_S:
        scene = scene.with_overrides({("duration",): (SAME_SCENE_S, "duration")})
    model = compile_model(scene)
    hashes, blobs = [], []
    for i in range(2):
        for fmt in ("csv", "mcap"):
            path = tmp_path / f"{i}.{fmt}"
            writer = open_writer(model, path, fmt)
            result = run(model, make_state(model), writer)
            writer.close()
            hashes.append(state_hash(result.state))
            blobs.append(path.read_bytes())
    assert len(set(hashes)) == 1
    assert blobs[0] == blobs[2] and blobs[1] == blobs[3]


LONG = """
vrsim: 1
name: long
duration: 60
frame_rate: 50
dt: 0.001
bodies: [{name: ball, mass: 1, position: [0, 10, 0], velocity: [1, 0, 0]}]
"""


@pytest.mark.parametrize("sig,code,suffix", [(signal.SIGINT, 130, "mcap"),
                                             (signal.SIGTERM, 143, "csv"),
                                             (signal.SIGTERM, 143, "mcap")])
def test_signal_mid_run_finalises_the_output(write_scene, tmp_path, sig, code, suffix):
    scene = write_scene(LONG)
    out = tmp_path / f"run.{suffix}"
    proc = subprocess.Popen([sys.executable, "-m", "vrsim_cli", "run", str(scene), "-o",
                             str(out), "--realtime"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.monotonic() + 30
    while not any(p.name.endswith(".partial") for p in tmp_path.iterdir()):
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.05)
    time.sleep(0.5)  # let it write some samples
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == code, stderr
    assert f"interrupted by {signal.Signals(sig).name}" in stderr and "output finalised" in stderr
    traj = read_trajectory(out)  # a complete, readable file (MCAP with its summary)
    times = traj.tracks["ball"].t
    assert 0.2 < times[-1] < 60 and len(times) == round(times[-1] * 50) + 1
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".partial")]


HEAVY = ("trimesh", "fcl", "OpenGL", "matplotlib", "scipy", "mujoco", "pybullet")


def test_point_mass_runs_import_nothing_heavy(tmp_path):
    code = f"""
import json, sys
from vrsim_cli.cli import main
light = [m for m in sys.modules if m.split('.')[0] in {HEAVY!r}]
for fmt in ("csv", "mcap"):
    sys.argv = ["vrsim", "run", {str(SCENARIOS / 'fountain.yaml')!r}, "-q",
                "-o", {str(tmp_path)!r} + "/out." + fmt]
    try:
        main()
    except SystemExit as exc:
        assert exc.code in (0, None), exc.code
# numba imports scipy's top-level package to check its version (numba/__init__.py,
# _ensure_critical_deps): that and scipy's private helpers are allowed, no subpackage.
heavy = sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r}
               and not (m == "scipy" or m.startswith(("scipy._", "scipy.version"))))
print(json.dumps({{"at_import": light, "after_runs": heavy}}))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=REPO, check=True)
    assert json.loads(out.stdout) == {"at_import": [], "after_runs": []}


def test_help_does_not_import_numpy():
    code = "import sys, vrsim_cli.cli; print('numpy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
