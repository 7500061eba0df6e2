"""Every "did you mean" and every example an error message offers is fed back: the
suggested fix, applied as written, must then be accepted. A hint that proposes something
vrsim itself refuses is worse than none.

Scene hints go through `vrsim validate` (the broken file exits 2 naming the fix; the file
with the fix applied exits 0); command-line and tool hints through the function or
command that printed them. `test_every_suggestion_site_has_a_case` counts the places that
make such suggestions, so a new one cannot arrive untested.
"""

from __future__ import annotations

import re
import shutil
import textwrap
from pathlib import Path

import pytest

from conftest import REPO

BASE = """
vrsim: 1
duration: 0.1
dt: 0.01
frame_rate: 50
"""


def suggested(text: str) -> str:
    match = re.search(r"did you mean '([^']+)'\?", text)
    assert match, f"no suggestion in: {text}"
    return match.group(1)


# (case, scene with a typo, the typo): the suggestion replaces the typo
TYPOS = [
    ("unknown key", "bodies: [{name: ball, mass: 1, positon: [0, 1, 0]}]", "positon"),
    ("enum value", "integrator: rk5\nbodies: [{name: ball, mass: 1}]", "rk5"),
    ("spring body", "bodies: [{name: ball, mass: 1}]\n"
     "springs: [{body: bal, anchor: [0, 2, 0], stiffness: 10}]", "bal"),
    ("observer body", "bodies: [{name: cart, type: kinematic, velocity: [1, 0, 0]}]\n"
     "observer: {mode: attached, body: crat}", "crat"),
    ("interpolation", "bodies: [{name: door, type: kinematic, keyframes: {position: "
     "{times: [0, 1], values: [[0, 0, 0], [1, 0, 0]], interpolation: linaer}}}]", "linaer"),
    ("extrapolation", "bodies: [{name: door, type: kinematic, keyframes: {position: "
     "{times: [0, 1], values: [[0, 0, 0], [1, 0, 0]], extrapolation: clmap}}}]", "clmap"),
    ("ease", "bodies: [{name: door, type: kinematic, keyframes: {position: "
     "{times: [0, 1], values: [[0, 0, 0], [1, 0, 0]], ease: in-ot}}}]", "in-ot"),
    ("parent", "bodies: [{name: base, type: kinematic}, "
     "{name: arm, type: kinematic, parent: bsae}]", "bsae"),
]


@pytest.mark.parametrize("case, body, typo", TYPOS, ids=[c[0] for c in TYPOS])
def test_did_you_mean_fixes_the_scene(invoke, write_scene, case, body, typo):
    broken = write_scene(BASE + body)
    result = invoke("validate", broken)
    assert result.exit_code == 2, result.output
    fix = suggested(result.stderr)
    assert fix != typo
    fixed = write_scene(BASE + re.sub(rf"\b{re.escape(typo)}\b", fix, body), "fixed.yaml")
    result = invoke("validate", fixed)
    assert result.exit_code == 0, f"{case}: '{fix}' is refused too:\n{result.stderr}"


# (case, scene, hint text, scene after doing what the hint says)
ADVICE = [
    ("plane on a moving body",
     "bodies: [{name: floor, shape: {type: plane, normal: [0, 1, 0]}}]", "add type: static",
     "bodies: [{name: floor, type: static, shape: {type: plane, normal: [0, 1, 0]}}]"),
    ("animated body not kinematic",
     "bodies: [{name: door, keyframes: {position: {times: [0, 1], "
     "values: [[0, 0, 0], [1, 0, 0]]}}}]", "add type: kinematic",
     "bodies: [{name: door, type: kinematic, keyframes: {position: {times: [0, 1], "
     "values: [[0, 0, 0], [1, 0, 0]]}}}]"),
    ("attached observer without a body",
     "bodies: [{name: cart, type: kinematic, velocity: [1, 0, 0]}]\n"
     "observer: {mode: attached}", "add body: NAME",
     "bodies: [{name: cart, type: kinematic, velocity: [1, 0, 0]}]\n"
     "observer: {mode: attached, body: cart}"),
    ("input without an observer",
     "bodies: [{name: ball, mass: 1}]\ninput: {mouse: [{t: 0, alpha: 0.5, beta: 0}]}",
     "add an observer: {mode: walk, ...}",
     "bodies: [{name: ball, mass: 1}]\ninput: {mouse: [{t: 0, alpha: 0.5, beta: 0}]}\n"
     "observer: {mode: walk}"),
    ("output format",
     "bodies: [{name: ball, mass: 1}]\noutput: {file: out.dat}",
     "use a .mcap or .csv suffix", "bodies: [{name: ball, mass: 1}]\noutput: {file: out.csv}"),
]


@pytest.mark.parametrize("case, body, hint, fixed", ADVICE, ids=[c[0] for c in ADVICE])
def test_advice_fixes_the_scene(invoke, write_scene, tmp_path, monkeypatch, case, body, hint,
                                fixed):
    monkeypatch.chdir(tmp_path)  # output files are relative to where vrsim runs
    result = invoke("validate", write_scene(BASE + body))
    assert result.exit_code == 2 and hint in result.stderr, result.stderr
    result = invoke("validate", write_scene(BASE + fixed, "fixed.yaml"))
    assert result.exit_code == 0, f"{case}: doing '{hint}' is refused:\n{result.stderr}"


@pytest.mark.parametrize("rate", [70, 33, 1000 / 7])
def test_the_nearest_fitting_output_rates_fit(invoke, write_scene, rate):
    """The hint's rates are printed to 6 digits: each must still be a whole number of
    steps (the check allows 1e-6 relative)."""
    body = "frame_rate: 60\ndt: 0.001\nbodies: [{name: ball, mass: 1}]\n"
    result = invoke("validate", write_scene(
        BASE.replace("dt: 0.01\nframe_rate: 50\n", "") + body + f"output: {{rate: {rate}}}"))
    assert result.exit_code == 2
    rates = re.search(r"nearest rates that fit: ([^)]*) Hz", result.stderr).group(1)
    for shown in rates.split(", "):
        fixed = write_scene(BASE.replace("dt: 0.01\nframe_rate: 50\n", "") + body
                            + f"output: {{rate: {shown}}}", "fixed.yaml")
        assert invoke("validate", fixed).exit_code == 0, shown


def test_a_mesh_outside_the_folder_is_fixed_by_copying_it_in(invoke, tmp_path):
    scenes = tmp_path / "scenes"
    scenes.mkdir()
    mesh = tmp_path / "tetra.obj"
    mesh.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    scene = scenes / "s.yaml"
    text = BASE + "bodies: [{name: rock, mass: 1, shape: {type: mesh, file: ../tetra.obj}}]\n"
    scene.write_text(text)
    result = invoke("validate", scene)
    assert result.exit_code == 2 and "copy the file there" in result.stderr
    assert "copy or link" not in result.stderr  # a link out is refused like the path
    (scenes / "tetra.obj").symlink_to(mesh)
    scene.write_text(text.replace("../tetra.obj", "tetra.obj"))
    assert invoke("validate", scene).exit_code == 2  # the link leads out: refused
    (scenes / "tetra.obj").unlink()
    shutil.copy(mesh, scenes / "tetra.obj")  # what the hint says
    result = invoke("validate", scene)
    assert result.exit_code == 0, result.stderr


def test_the_pass_through_note_is_fixed_by_its_collision_block(invoke, write_scene):
    body = ("bodies:\n  - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 0]}}\n"
            "  - {name: crate, mass: 1, shape: {type: box, size: [1, 1, 1]}, "
            "position: [0, 2, 0]}\n")
    result = invoke("validate", write_scene(BASE + body))
    assert result.exit_code == 0 and "add `collision: {}`" in result.stderr
    for block in ("collision: {}", "collision: {enabled: false}"):  # both offered
        result = invoke("validate", write_scene(BASE + body + block + "\n", "fixed.yaml"))
        assert result.exit_code == 0, result.stderr
        assert "pass through" not in result.stderr


def test_the_output_suffix_advice_of_run(invoke, write_scene, tmp_path):
    scene = write_scene(BASE + "bodies: [{name: ball, mass: 1}]")
    result = invoke("run", scene, "-o", tmp_path / "out.dat")
    assert result.exit_code == 2 and "use a .mcap or .csv suffix" in result.stderr
    for suffix in (".mcap", ".csv"):
        assert invoke("run", scene, "-o", tmp_path / f"out{suffix}").exit_code == 0


# ----------------------------------------------------------------------------- tools


SWEEP_SCENE = BASE + "bodies: [{name: ball, mass: 1, material: {restitution: 0.5}}]\n"


def test_sweep_examples_are_accepted(write_scene):
    from vrsim_cli.errors import InputError
    from vrsim_cli.tools import sweep

    scene = str(write_scene(SWEEP_SCENE))
    with pytest.raises(InputError) as bad:
        sweep.parse_setting("dt")
    hint = bad.value.problems[0].hint
    examples = re.findall(r"--set (\S+)", hint)
    assert len(examples) == 2
    for example in examples:
        plan = sweep.plan_sweep([scene], [sweep.parse_setting(example)], [], None)
        assert plan.runs
    with pytest.raises(InputError) as bad:
        sweep.parse_reference(["no-such-file.csv"])
    example = re.search(r"e\.g\. '([^']+)'", bad.value.problems[0].hint).group(1)
    pairs, _ = sweep.parse_reference([example])
    assert sweep.plan_sweep([scene], [sweep.parse_setting("dt=0.01,0.005")], pairs, None).runs


@pytest.mark.parametrize("key, typo", [("bodies.bal.material.restitution=0.5", "bal"),
                                       ("bodies.ball.materal.restitution=0.5", "materal")])
def test_sweep_key_paths_did_you_mean(write_scene, key, typo):
    from vrsim_cli.errors import InputError
    from vrsim_cli.tools import sweep

    scene = str(write_scene(SWEEP_SCENE))
    with pytest.raises(InputError) as bad:
        sweep.plan_sweep([scene], [sweep.parse_setting(key)], [], None)
    fix = suggested(str(bad.value))
    fixed = key.replace(typo, fix)
    assert sweep.plan_sweep([scene], [sweep.parse_setting(fixed)], [], None).runs


def test_the_key_path_example_of_sweep_resolves(write_scene):
    from vrsim_cli.errors import InputError
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.tools import sweep

    scene = load_scene(write_scene(SWEEP_SCENE))
    with pytest.raises(InputError) as bad:
        sweep.resolve_key(scene, "", "--set")
    for example in re.search(r"e\.g\. (.*)", bad.value.problems[0].hint).group(1) \
            .split(" or "):
        assert sweep.resolve_key(scene, example, "--set")


@pytest.mark.parametrize("text, typo", [("defaults: {atol: 1e-6}\n", "defaults"),
                                        ("default: {atoll: 1e-6}\n", "atoll")])
def test_regress_tolerance_keys_did_you_mean(tmp_path, text, typo):
    from vrsim_cli.errors import InputError
    from vrsim_cli.tools.regress import load_tolerances

    file = tmp_path / "tolerances.yaml"
    file.write_text(text)
    with pytest.raises(InputError) as bad:
        load_tolerances(file)
    file.write_text(text.replace(typo, suggested(str(bad.value))))
    load_tolerances(file)


def test_regress_scene_names_did_you_mean(tmp_path):
    from vrsim_cli.errors import InputError
    from vrsim_cli.tools.regress import plan_regress

    (tmp_path / "drop.yaml").write_text(textwrap.dedent(SWEEP_SCENE))
    with pytest.raises(InputError) as bad:
        plan_regress(tmp_path, tmp_path / "golden", ["dorp"], update=True)
    fix = suggested(str(bad.value))
    assert plan_regress(tmp_path, tmp_path / "golden", [fix], update=True).cases


def test_the_tolerance_examples_of_compare(invoke, write_scene, tmp_path):
    out = tmp_path / "a.csv"
    assert invoke("run", write_scene(SWEEP_SCENE), "-o", out).exit_code == 0
    result = invoke("compare", out, out, "--tol", "ball")
    assert result.exit_code == 2
    examples = re.search(r"\(e\.g\. (\S+) or '([^']+)'\)", result.output).groups()
    for example in examples:
        result = invoke("compare", out, out, "--tol", example)
        assert result.exit_code == 0, result.output


# ----------------------------------------------------------------------------- coverage


# where vrsim_cli calls did_you_mean or writes "e.g." into an error's hint, and the
# cases above that feed each back
SITES = {
    "vrsim_cli/scene/spec.py": (3, ["unknown key", "enum value", "observer body"]),
    "vrsim_cli/scene/animation.py": (4, ["interpolation", "extrapolation", "ease", "parent"]),
    "vrsim_cli/scene/rigid.py": (1, ["spring body"]),
    "vrsim_cli/tools/sweep.py": (5, ["test_sweep_examples_are_accepted",
                                     "test_sweep_key_paths_did_you_mean",
                                     "test_the_key_path_example_of_sweep_resolves"]),
    "vrsim_cli/tools/regress.py": (3, ["test_regress_tolerance_keys_did_you_mean",
                                       "test_regress_scene_names_did_you_mean"]),
    "vrsim_cli/cli.py": (2, ["test_the_tolerance_examples_of_compare",
                             "test_sweep_examples_are_accepted"]),  # --reference's help
    "vrsim_cli/api.py": (1, ["test_api_body_names_did_you_mean"]),
}


def test_api_body_names_did_you_mean():
    """The Python API's pushes name a body; a misspelt one gets the nearest name, and
    that name then takes the impulse (v changes by J / m)."""
    import vrsim_cli

    sim = vrsim_cli.simulate(vrsim_cli.load(BASE + "bodies: [{name: ball, mass: 2}]"))
    with pytest.raises(KeyError) as err:
        sim.apply_impulse("bal", [1.0, 0.0, 0.0])
    hint = re.search(r"did you mean '([^']+)'\?", str(err.value))
    assert hint, err.value
    before = sim.state.body_vel[0].copy()
    sim.apply_impulse(hint.group(1), [1.0, 0.0, 0.0])
    assert (sim.state.body_vel[0] - before).tolist() == [0.5, 0.0, 0.0]


def test_every_suggestion_site_has_a_case():
    """A new did_you_mean call or "e.g." example in a message fails here until a case
    above feeds it back (then raise its count)."""
    found = {}
    for path in sorted((REPO / "vrsim_cli").rglob("*.py")):
        text = path.read_text()
        calls = len(re.findall(r"did_you_mean\((?!word)", text))  # not the definition
        examples = len([m for m in re.finditer(r'^\s*(?:f?"|[^#\n]*\(f?")[^"\n]*\be\.g\. ',
                                               text, flags=re.M)
                        if '"""' not in m.group(0)])
        if calls + examples:
            found[str(path.relative_to(REPO))] = calls + examples
    assert found == {k: n for k, (n, _) in SITES.items()}
    cases = {c[0] for c in TYPOS} | set(globals())
    for file, (_, names) in SITES.items():
        assert all(name in cases for name in names), file


@pytest.mark.parametrize("target, hint, instead", [
    ("/dev/stdout", "use -o - to write to standard output", ["-o", "-"]),
    ("/dev/null", "leave out -o to write nothing", []),
])
def test_the_special_output_advice_of_run(invoke, write_scene, target, hint, instead):
    scene = write_scene(BASE + "bodies: [{name: ball, mass: 1}]")
    result = invoke("run", scene, "-o", target, "--format", "csv")
    assert result.exit_code == 2 and hint in result.stderr, result.stderr
    result = invoke("run", scene, *instead)
    assert result.exit_code == 0, result.stderr
    if instead:  # the CSV went to standard output
        assert result.stdout.startswith("t,entity,")
