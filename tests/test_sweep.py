"""`vrsim sweep` (vrsim_cli/tools/sweep.py, executors.py, jobs.py, sweep_report.py).

Truths used: the closed form of explicit Euler under constant gravity (its position error
at time T is g T dt / 2 exactly, rk4 is exact there), `vrsim compare` on files written by
`vrsim run` (the sweep must report the very same numbers), and the definition of a Pareto
front (checked by brute force over random point sets).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time

import pytest
from hypothesis import given, settings, strategies as st

from vrsim_cli.errors import InputError
from vrsim_cli.scene.spec import parse_scene
from vrsim_cli.tools import sweep
from vrsim_cli.tools.executors import LocalPool, Serial
from vrsim_cli.tools.sweep_report import pareto

G = 9.81

DROP = """\
vrsim: 1
name: drop
duration: 0.5
frame_rate: 20
dt: 0.01
integrator: euler
bodies:
  - name: ground
    type: static
    shape: {type: plane, normal: [0, 1, 0]}
  - name: ball
    mass: 1
    position: [0, 10, 0]
    velocity: [1, 2, 0]
    shape: {type: sphere, radius: 0.1}
    material: {restitution: 0.5}
"""

# Collision, rotation and a tumbling box: enough of the pipeline that an executor leaking
# state between runs, or rounding differently, would show in the hashes.
MIXED = """\
vrsim: 1
name: mixed
duration: 0.4
frame_rate: 50
dt: 0.01
integrator: rk4
collision: {}
bodies:
  - name: ground
    type: static
    shape: {type: plane, normal: [0, 1, 0]}
  - name: ball
    mass: 1
    position: [0, 0.3, 0]
    shape: {type: sphere, radius: 0.1}
    material: {restitution: 0.8}
  - name: box
    mass: 2
    position: [1, 2, 0]
    shape: {type: box, size: [0.1, 0.4, 1.0]}
    angular_velocity: [0.1, 5, 0.1]
"""


def rows_of(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


TIMES = ("wall_s", "cpu_s", "task_s")


def results(folder):
    """run id -> its row without the times (the only columns allowed to differ)."""
    out = {}
    for row in rows_of(folder / sweep.RUNS_CSV):
        out[row["run"]] = {k: v for k, v in row.items() if k not in TIMES}
    return out


def entity_rows(folder):
    return sorted(tuple(r.values()) for r in rows_of(folder / sweep.ENTITIES_CSV))


def plan_of(scene_file, sets, reference=()):
    pairs, ref_file = sweep.parse_reference(tuple(reference))
    return sweep.plan_sweep([str(scene_file)], [sweep.parse_setting(s) for s in sets],
                            pairs, ref_file)


# ----------------------------------------------------------------------------- options


def test_values_are_read_as_scene_files_read_them():
    assert sweep.parse_setting("dt=1e-3,0.01, 2") == ("dt", [0.001, 0.01, 2])
    assert sweep.parse_setting("integrator=rk4,euler") == ("integrator", ["rk4", "euler"])
    key, values = sweep.parse_setting("bodies.ball.velocity=[1, 0, 0],[2e0,0,0]")
    assert values == [[1, 0, 0], [2.0, 0, 0]] and isinstance(values[1][0], float)
    assert sweep.parse_setting("collision.continuous=true,false")[1] == [True, False]


def test_ranges_give_evenly_spaced_values():
    assert sweep.parse_setting("dt=lin:0.01:0.05:5")[1] == pytest.approx(
        [0.01, 0.02, 0.03, 0.04, 0.05], rel=1e-15)
    values = sweep.parse_setting("dt=log:1e-4:1e-2:5")[1]
    assert values == pytest.approx([1e-4, 10 ** -3.5, 1e-3, 10 ** -2.5, 1e-2], rel=1e-14)
    assert values[0] == 1e-4 and values[-1] == pytest.approx(1e-2, rel=1e-15)


@pytest.mark.parametrize("text, message", [
    ("dt", "expected KEY=VALUE"), ("=1", "expected KEY=VALUE"),
    ("dt=0.1,,0.2", "an empty value"), ("dt=[1,", "cannot read the value"),
    ("dt=log:0:1:3", "A > 0"), ("dt=lin:a:1:3", "needs numbers"),
])
def test_bad_settings_are_input_errors_that_name_the_option(text, message):
    with pytest.raises(InputError) as info:
        sweep.parse_setting(text)
    assert message in str(info.value) and "--set" in str(info.value)


# ----------------------------------------------------------------------------- key paths


def test_key_paths_resolve_by_name_and_by_index():
    scene = parse_scene(DROP)
    assert sweep.resolve_key(scene, "dt", "--set") == ("dt",)
    assert sweep.resolve_key(scene, "bodies.ball.material.restitution", "--set") == \
        ("bodies", 1, "material", "restitution")
    assert sweep.resolve_key(scene, "bodies[0].shape.normal", "--set") == \
        ("bodies", 0, "shape", "normal")
    assert sweep.resolve_key(scene, "bodies.ball.velocity[1]", "--set") == \
        ("bodies", 1, "velocity", 1)
    # keys the scene does not have yet, but the schema allows
    assert sweep.resolve_key(scene, "bodies.ground.material.friction", "--set") == \
        ("bodies", 0, "material", "friction")
    assert sweep.resolve_key(scene, "collision.tolerance", "--set") == ("collision",
                                                                        "tolerance")


@pytest.mark.parametrize("key, message, hint", [
    ("bodies.bal.mass", "no body named 'bal'", "did you mean 'ball'?"),
    ("bodies.ball.material.restituton", "unknown key 'restituton'",
     "did you mean 'restitution'?"),
    ("dtt", "unknown key 'dtt'", "did you mean 'dt'?"),
    ("bodies[7].mass", "index 7 is outside the 2 items", None),
    ("dt.x", "is a value, not a mapping", None),
    ("bodies.ball.shape.radius.x", "is a value, not a mapping", None),
    ("emitters.jet.rate", "no emitter named 'jet' in emitters", None),
])
def test_bad_key_paths_are_located_and_explained(key, message, hint):
    with pytest.raises(InputError) as info:
        sweep.resolve_key(parse_scene(DROP), key, f"--set {key}")
    text = str(info.value)
    assert f"command line (--set {key})" in text and message in text
    if hint:
        assert hint in text


@settings(max_examples=60, deadline=None)
@given(st.lists(st.from_regex(r"[A-Za-z_][A-Za-z0-9_.-]{0,10}", fullmatch=True),
                min_size=1, max_size=6, unique=True), st.data())
def test_any_body_is_found_by_its_name_even_with_dots(names, data):
    """Names may hold dots (and end in one): `bodies[NAME]` always finds the body, and so
    does `bodies.NAME.mass` unless another body's name is NAME.mass or longer along the
    same dots (then the longest name wins: the documented rule)."""
    bodies = "\n".join(f"  - {{name: '{n}', mass: 1}}" for n in names)
    scene = parse_scene(f"vrsim: 1\nduration: 1\nbodies:\n{bodies}\n")
    i = data.draw(st.integers(0, len(names) - 1))
    assert sweep.resolve_key(scene, f"bodies[{names[i]}].mass", "--set") == \
        ("bodies", i, "mass")
    dotted = f"{names[i]}.mass"
    if not any(n != names[i] and (dotted == n or dotted.startswith(n + ".") and
                                  len(n) > len(names[i])) for n in names):
        assert sweep.resolve_key(scene, f"bodies.{dotted}", "--set") == ("bodies", i, "mass")


# ----------------------------------------------------------------------------- validation


def test_every_variant_is_validated_before_anything_runs(write_scene, invoke, tmp_path):
    scene = write_scene(DROP)
    out = tmp_path / "out"
    result = invoke("sweep", scene, "--set", "bodies.ball.material.restitution=0.5,1.5",
                    "--set", "dt=0.01,0.02", "-o", out)
    assert result.exit_code == 2
    assert ("error: command line (--set bodies.ball.material.restitution=1.5): "
            f"bodies[1].material.restitution: must be <= 1, got 1.5 (scene {scene})") \
        in result.stderr
    assert result.stderr.count("must be <= 1") == 1  # one problem, not one per variant
    assert not out.exists()  # nothing ran, nothing was written


def test_a_value_that_breaks_the_scene_elsewhere_names_its_variant(write_scene, invoke,
                                                                     tmp_path):
    """dt = 0.3 s cannot fit the 0.5 s duration's output rate: the problem is in the file
    (output.rate), so the message says which variant caused it."""
    scene = write_scene(DROP + "output: {rate: 20}\n")
    result = invoke("sweep", scene, "--set", "frame_rate=20,7", "-o", tmp_path / "out")
    assert result.exit_code == 2
    assert "output.rate" in result.stderr and "[in the variant drop frame_rate=7]" in \
        result.stderr


def test_a_bad_key_is_an_input_error_in_every_scene(write_scene, invoke, tmp_path):
    scene = write_scene(DROP)
    result = invoke("sweep", scene, "--set", "bodies.bal.mass=1,2", "-o", tmp_path / "o")
    assert result.exit_code == 2
    assert "no body named 'bal'" in result.stderr and "did you mean 'ball'?" in \
        result.stderr and str(scene) in result.stderr
    assert "Traceback" not in result.output


# ----------------------------------------------------------------------------- errors


def test_errors_are_the_closed_form_of_euler(write_scene, tmp_path):
    """Explicit Euler under gravity lags the exact flight by g t dt / 2 at time t; rk4 is
    exact, so against an rk4 reference the sweep must report g T dt / 2 at T = 0.5 s, for
    the ball, with the ground (static) exactly 0."""
    scene = write_scene(DROP.replace("type: static\n    shape: {type: plane, normal: "
                                     "[0, 1, 0]}", "type: static"))
    plan = plan_of(scene, ["dt=0.01,0.005,0.0025,0.001"], ["integrator=rk4"])
    sweep.run_sweep(plan, tmp_path / "o", Serial())
    rows = [r for r in rows_of(tmp_path / "o" / sweep.RUNS_CSV) if r["role"] == "run"]
    assert len(rows) == 4
    for row in rows:
        dt = float(row["dt"])
        assert float(row["pos_err_m"]) == pytest.approx(G * 0.5 * dt / 2, rel=1e-9)
        assert row["worst_entity"] == "ball" and row["status"] == "ok"
        assert int(row["steps"]) == round(0.5 / dt)
    per_entity = {(r["run"], r["entity"]): r for r in rows_of(tmp_path / "o" /
                                                             sweep.ENTITIES_CSV)}
    for row in rows:
        assert float(per_entity[(row["run"], "ground")]["pos_err_m"]) == 0.0


def test_errors_are_those_of_vrsim_compare(write_scene, invoke, tmp_path):
    """The same two runs written by `vrsim run` and compared by `vrsim compare --json`
    give the sweep's per-entity numbers, digit for digit; a reference file gives the same
    as the computed reference."""
    scene = write_scene(MIXED)
    run_csv, ref_csv = tmp_path / "a.csv", tmp_path / "ref.csv"
    assert invoke("run", scene, "--dt", "0.005", "-o", run_csv, "-q").exit_code == 0
    assert invoke("run", scene, "--integrator", "dopri5", "--tolerance", "1e-10",
                  "-o", ref_csv, "-q").exit_code == 0
    report = json.loads(invoke("compare", run_csv, ref_csv, "--json").output)
    expected = {e["entity"]: e for e in report["entities"]}
    for reference in (["integrator=dopri5 tolerance=1e-10 dt=0.01"], [str(ref_csv)]):
        out = tmp_path / f"o{len(reference[0])}"
        result = invoke("sweep", scene, "--set", "dt=0.005", "--reference", *reference,
                        "-o", out, "--jobs", "1")
        assert result.exit_code == 0, result.output
        got = {r["entity"]: r for r in rows_of(out / sweep.ENTITIES_CSV)}
        assert set(got) == set(expected)
        for name, e in expected.items():
            assert float(got[name]["pos_err_m"]) == e["max_position_error_m"]
            assert float(got[name]["angle_err_rad"]) == e["max_orientation_error_rad"]
            assert float(got[name]["vel_err_m_s"]) == e["max_velocity_error_m_s"]
            assert float(got[name]["angvel_err_rad_s"]) == \
                e["max_angular_velocity_error_rad_s"]


def test_a_reference_is_shared_only_by_runs_that_differ_in_its_keys(write_scene):
    scene = write_scene(DROP)
    shared = plan_of(scene, ["dt=0.01,0.005", "integrator=euler,rk4"],
                     ["integrator=dopri5 tolerance=1e-10 dt=0.01"])
    assert len(shared.runs) == 4 and len(shared.references) == 1 and not shared.notes
    per_dt = plan_of(scene, ["dt=0.01,0.005", "integrator=euler,rk4"],
                     ["integrator=dopri5 tolerance=1e-10"])
    assert len(per_dt.references) == 2
    assert "set it in --reference to share one reference" in per_dt.notes[0]
    material = plan_of(scene, ["bodies.ball.material.restitution=0.5,0.9", "dt=0.01,0.005"],
                       ["integrator=dopri5 tolerance=1e-10 dt=0.01"])
    assert len(material.references) == 2  # each restitution has its own truth


# ----------------------------------------------------------------------------- executors


def test_results_are_bit_identical_in_process_on_a_pool_and_on_ray(write_scene, tmp_path):
    """The same sweep (with a reference, so shared objects travel too) on every executor:
    every figure but the wall times is the same text in the table, hashes included."""
    ray = pytest.importorskip("ray", reason="Ray is part of the test extra")
    from vrsim_cli.tools.executors import RayExecutor

    scene = write_scene(MIXED)
    plan = plan_of(scene, ["dt=0.01,0.005", "integrator=verlet,rk4",
                           "bodies.ball.material.restitution=0.5,0.8"],
                   ["integrator=dopri5 tolerance=1e-9 dt=0.01"])
    found = {}
    executors = {"serial": Serial, "pool": lambda: LocalPool(2),
                 "ray": lambda: RayExecutor(None, 2)}
    for name, make in executors.items():
        executor = make()
        try:
            result = sweep.run_sweep(plan, tmp_path / name, executor)
        finally:
            executor.close()
        assert result.done == 8 and not result.failed, result.failed
        found[name] = (results(tmp_path / name), entity_rows(tmp_path / name))
    assert not ray.is_initialized()
    assert len(found["serial"][0]) == 8 + 2  # runs and their two references
    assert all(r["state_sha256"] for r in found["serial"][0].values())
    assert found["pool"] == found["serial"]
    assert found["ray"] == found["serial"]


def test_a_model_that_does_not_pickle_is_compiled_in_the_worker_alike(write_scene,
                                                                       tmp_path, monkeypatch):
    """The fallback for models that cannot be pickled: the job carries the validated
    scene and the worker compiles it; the numbers are those of the pickled path."""
    scene = write_scene(DROP)
    sets, ref = ["dt=0.01,0.005", "integrator=verlet,rk4"], ["integrator=rk4 dt=0.01"]
    plan = plan_of(scene, sets, ref)
    assert all(r.job.model is not None and r.job.scene is None for r in plan.runs)
    sweep.run_sweep(plan, tmp_path / "pickled", Serial())
    monkeypatch.setattr(sweep, "pack_model", lambda model: None)
    fallback = plan_of(scene, sets, ref)
    assert all(r.job.model is None and r.job.scene is not None for r in fallback.runs)
    for name, executor in (("serial", Serial()), ("pool", LocalPool(2))):
        try:
            sweep.run_sweep(fallback, tmp_path / name, executor)
        finally:
            executor.close()
        assert results(tmp_path / name) == results(tmp_path / "pickled")
        assert entity_rows(tmp_path / name) == entity_rows(tmp_path / "pickled")


class _Exit:
    """Unpickling this ends the process: a job that kills its worker."""

    def __reduce__(self):
        return (os._exit, (3,))


def test_a_dead_worker_fails_its_own_job_and_the_pool_goes_on(write_scene):
    import pickle

    from vrsim_cli.tools.jobs import Job

    plan = plan_of(write_scene(DROP), ["dt=0.01,0.005,0.0025"])
    jobs = [(r.job, None) for r in plan.runs]
    poison = Job("poison", "poison", model=pickle.dumps(_Exit()))
    jobs.insert(1, (poison, None))
    done = {}
    pool = LocalPool(2)
    try:
        pool.run(jobs, lambda job, outcome: done.__setitem__(job.key, outcome))
    finally:
        pool.close()
    assert done["poison"].status == "error"
    assert "worker process died" in done["poison"].message and "exit code 3" in \
        done["poison"].message
    assert [done[r.run_id].status for r in plan.runs] == ["ok"] * 3


# ----------------------------------------------------------------------------- failures


def test_a_failing_variant_is_reported_and_the_rest_finish(write_scene, invoke, tmp_path):
    """A ball of the smallest mass a scene may give (scene/limits), pushed by 1e4 N, passes
    the speed of light in its first step and fails its run (the loop's blow-up check,
    naming the body and the time); the other variants finish; the exit code is 1."""
    scene = write_scene(DROP.replace("    velocity: [1, 2, 0]\n", "    velocity: [1, 2, 0]\n"
                                     "    forces: [{force: [1.0e4, 0, 0]}]\n"))
    out = tmp_path / "out"
    result = invoke("sweep", scene, "--set", "bodies.ball.mass=1,1e-9",
                    "--set", "dt=0.01,0.005", "--reference", "integrator=rk4", "-o", out,
                    "--jobs", "2")
    assert result.exit_code == 1
    rows = [r for r in rows_of(out / sweep.RUNS_CSV) if r["role"] == "run"]
    assert len(rows) == 4
    bad = [r for r in rows if r["bodies.ball.mass"] == "1e-09"]
    assert {r["status"] for r in bad} == {"failed"}
    assert all("its reference" in r["message"] and "ball" in r["message"] for r in bad)
    assert {r["status"] for r in rows if r not in bad} == {"ok"}
    assert "error: [" in result.stderr and "bodies.ball.mass=1e-09" in \
        result.stderr and "faster than light" in result.stderr
    assert "4 runs" not in result.stdout and "2 runs in" in result.stdout
    # without a reference the variant itself fails, with the same reason
    out2 = tmp_path / "out2"
    result = invoke("sweep", scene, "--set", "bodies.ball.mass=1,1e-9",
                    "-o", out2, "--jobs", "1")
    assert result.exit_code == 1
    rows = {r["bodies.ball.mass"]: r for r in rows_of(out2 / sweep.RUNS_CSV)}
    assert rows["1e-09"]["status"] == "failed"
    assert "body 'ball', t = 0.01 s" in rows["1e-09"]["message"]
    assert rows["1"]["status"] == "ok"


# ----------------------------------------------------------------------------- resume


def _sweep_argv(scene, out, *extra):
    return [sys.executable, "-m", "vrsim_cli", "sweep", str(scene), "--set",
            "dt=0.004,0.002,0.001,0.0005", "--set", "integrator=euler,verlet,rk4",
            "--reference", "integrator=rk4 dt=0.004", "-o", str(out), *extra]


def test_resume_after_a_killed_sweep_loses_no_finished_run(write_scene, tmp_path):
    """SIGKILL (no chance to clean up) in the middle of a sweep: every row written before
    stays byte for byte, --resume runs only the rest, and the table then equals that of
    an uninterrupted sweep."""
    scene = write_scene(DROP.replace("duration: 0.5", "duration: 2.0"))
    out = tmp_path / "killed"
    proc = subprocess.Popen(_sweep_argv(scene, out, "--jobs", "2", "-q"),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    table = out / sweep.RUNS_CSV
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if table.exists() and table.read_bytes().count(b"\n") >= 4:  # header + 3 rows
            break
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = table.read_bytes()
    lines_before = before.splitlines(keepends=True)[1:]
    assert 3 <= len(lines_before) < 13, "the sweep was not killed in the middle"
    resumed = subprocess.run(_sweep_argv(scene, out, "--jobs", "2", "--resume"),
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    after = table.read_bytes()
    assert after.startswith(before)  # nothing rewritten, only appended
    rows = rows_of(table)
    ids = [r["run"] for r in rows]
    assert len(ids) == len(set(ids)) == 13  # 12 runs + 1 reference, each once
    done_before = sum(1 for ln in lines_before if b",run," in ln)
    assert f"{done_before} already in the table" in resumed.stdout
    clean = tmp_path / "clean"
    subprocess.run(_sweep_argv(scene, clean, "--jobs", "1", "-q"), check=True, timeout=300)
    assert results(out) == results(clean)
    assert entity_rows(out) == entity_rows(clean)


def test_resume_drops_a_torn_last_line_and_orphan_entity_rows(write_scene, tmp_path):
    scene = write_scene(DROP)
    plan = plan_of(scene, ["dt=0.01,0.005"], ["integrator=rk4"])
    out = tmp_path / "o"
    sweep.run_sweep(plan, out, Serial())
    full = results(out)
    table, entities = out / sweep.RUNS_CSV, out / sweep.ENTITIES_CSV
    lines = table.read_bytes().splitlines(keepends=True)
    last = lines[-1]
    table.write_bytes(b"".join(lines[:-1]) + last[: len(last) // 2])  # power cut mid-row
    with pytest.raises(InputError):  # a table is there: --resume is needed
        sweep.run_sweep(plan, out, Serial())
    result = sweep.run_sweep(plan, out, Serial(), resume=True)
    assert result.done == 1 and result.skipped == 1
    assert results(out) == full
    assert len(rows_of(entities)) == 2 * 2  # two runs, two entities, no duplicates


def test_resume_refuses_other_keys_and_a_changed_scene(write_scene, tmp_path):
    scene = write_scene(DROP)
    out = tmp_path / "o"
    sweep.run_sweep(plan_of(scene, ["dt=0.01"]), out, Serial())
    with pytest.raises(InputError, match="other columns"):
        sweep.run_sweep(plan_of(scene, ["integrator=rk4"]), out, Serial(), resume=True)
    scene.write_text(DROP.replace("mass: 1", "mass: 2"))
    with pytest.raises(InputError, match="has changed since its runs were written"):
        sweep.run_sweep(plan_of(scene, ["dt=0.01"]), out, Serial(), resume=True)


# ----------------------------------------------------------------------------- report


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(1e-6, 1e3), st.floats(0, 1e3)), min_size=1,
                max_size=30))
def test_the_pareto_front_is_exactly_the_non_dominated_runs(points):
    rows = [{"run": str(i), "status": "ok", "wall_s": repr(w), "pos_err_m": repr(e)}
            for i, (w, e) in enumerate(points)]
    front = {r["run"] for r in pareto(rows, "pos_err_m")}

    def dominated(i):
        wi, ei = points[i]
        return any((w <= wi and e <= ei) and (w < wi or e < ei) for w, e in points)

    for i in range(len(points)):
        if dominated(i):
            assert str(i) not in front
    # every non-dominated value pair is on the front once (ties: one of them)
    kept = {points[int(r)] for r in front}
    assert kept == {points[i] for i in range(len(points)) if not dominated(i)}
    assert len(front) == len(kept)


def test_the_report_has_the_table_the_front_and_a_plot(write_scene, invoke, tmp_path):
    pytest.importorskip("matplotlib", reason="matplotlib is part of the test extra")
    scene = write_scene(DROP.replace("type: static\n    shape: {type: plane, normal: "
                                     "[0, 1, 0]}", "type: static"))
    out = tmp_path / "o"
    result = invoke("sweep", scene, "--set", "dt=0.01,0.005", "--set",
                    "integrator=euler,rk4", "--reference", "integrator=rk4 dt=0.01",
                    "-o", out, "--jobs", "1")
    assert result.exit_code == 0, result.output
    text = (out / "sweep.md").read_text()
    assert "| dt | integrator | dt used (s) | integrator used |" in text
    assert "Pareto front, position error (fastest first):" in text
    assert "drop: Pareto front (position):" in result.stdout
    assert (out / "drop.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote" in result.stdout and "1 plot(s)" in result.stdout


def test_ray_is_optional_and_its_address_cannot_swallow_a_scene(write_scene, invoke,
                                                                  monkeypatch):
    from vrsim_cli.tools.executors import make_executor

    scene = write_scene(DROP)
    result = invoke("sweep", "--ray", scene, "--set", "dt=0.01")
    assert result.exit_code == 2 and "put --ray after the scene files" in result.stderr
    monkeypatch.setitem(sys.modules, "ray", None)  # as if Ray were not installed
    with pytest.raises(InputError, match=r"pip install 'vrsim-cli\[ray\]'"):
        make_executor(None, "")
    result = invoke("sweep", scene, "--set", "dt=0.01", "--ray")
    assert result.exit_code == 2 and "--ray needs Ray" in result.stderr


def test_a_worker_with_another_vrsim_version_refuses_the_job(write_scene):
    """Results could differ in the last bits between versions: a node must match."""
    import dataclasses

    from vrsim_cli.tools import jobs

    job = plan_of(write_scene(DROP), ["dt=0.01"]).runs[0].job
    assert jobs.execute(job).status == "ok"
    outcome = jobs.execute(dataclasses.replace(job, version="0.0.0-elsewhere"))
    assert outcome.status == "error" and "install the same version on every node" in \
        outcome.message


def test_a_shipped_model_accepts_and_refuses_writes_like_the_original():
    """Pickling drops numpy's read-only flag; the worker's copy gets back exactly the
    parent's flags, array by array (nested models included), for every scenario."""
    from conftest import SCENARIOS
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.tools.jobs import model_arrays, pack_model, unpack_model

    for path in sorted(SCENARIOS.glob("*.yaml")):
        model = compile_model(load_scene(path))
        original = model_arrays(model)
        copy = model_arrays(unpack_model(pack_model(model)))
        assert [a.flags.writeable for a in copy] == [a.flags.writeable for a in original]
        for a, b in zip(copy, original):  # bit for bit (NaN included)
            assert a.dtype == b.dtype and a.shape == b.shape
            assert a.tolist() == b.tolist() if a.dtype == object else \
                a.tobytes() == b.tobytes()
        assert len(original) > 5 and not all(a.flags.writeable for a in original)
        frozen = next(a for a in copy if not a.flags.writeable and a.size)
        with pytest.raises(ValueError):
            frozen.flat[0] = 0
