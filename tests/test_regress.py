"""`vrsim regress` (vrsim_cli/tools/regress.py): goldens, tolerances, pins, JUnit XML.

Truths used: the golden file made the long way, independently of regress (`vrsim run -o
X.csv`, thinned and gzipped here by code of this test), must equal the bytes `--update`
writes; the JUnit XML must validate against tests/data/junit.xsd and its counts must
equal the elements it holds; a perturbation of known size (1 mm) must fail a tighter
tolerance and pass a looser one.
"""

from __future__ import annotations

import gzip
import json
import math
import shutil
import xml.etree.ElementTree as ET

import pytest

from conftest import REPO
from vrsim_cli.tools import regress
from vrsim_cli.tools.compare import Tolerance

DROP = """\
vrsim: 1
name: drop
duration: 0.5
frame_rate: 20
dt: 0.01
bodies: [{name: ball, mass: 1, position: [0, 1, 0]}]
"""

SPIN = """\
vrsim: 1
name: spin
duration: 0.4
frame_rate: 50
dt: 0.01
integrator: verlet
gravity: [0, 0, 0]
bodies:
  - name: box
    mass: 1
    shape: {type: box, size: [0.1, 0.4, 1.0]}
    angular_velocity: [0.01, 5, 0.01]
"""

XSD = REPO / "tests" / "data" / "junit.xsd"
SUREFIRE_XSD = REPO / "tests" / "data" / "surefire.xsd"  # Maven Surefire's strict 3.0 report


@pytest.fixture
def scenes(tmp_path):
    folder = tmp_path / "scenes"
    folder.mkdir()
    (folder / "drop.yaml").write_text(DROP)
    (folder / "spin.yaml").write_text(SPIN)
    return folder


def regress_cli(invoke, scenes, golden, *args):
    return invoke("regress", scenes, "--golden", golden, "--jobs", "1", *args)


def independent_golden(invoke, scene, tmp_path, keep=21) -> str:
    """The golden's text the long way: `vrsim run -o X.csv`, keeping `keep` evenly
    strided sample times (first and last always)."""
    out = tmp_path / f"{scene.stem}-long.csv"
    assert invoke("run", scene, "-o", out, "-q").exit_code == 0
    header, *rows = out.read_text().splitlines(keepends=True)
    times = sorted({float(r.split(",", 1)[0]) for r in rows})
    stride = max(1, math.ceil((len(times) - 1) / (keep - 1)))
    kept = set(times[::stride]) | {times[-1]}
    return header + "".join(r for r in rows if float(r.split(",", 1)[0]) in kept)


def test_update_check_and_the_missing_golden_message(invoke, scenes, tmp_path):
    golden = tmp_path / "golden"
    golden.mkdir()
    result = regress_cli(invoke, scenes, golden)
    assert result.exit_code == 1
    assert (f"drop: FAILED: no golden file {golden / 'drop.csv.gz'}; create it with "
            f"`vrsim regress {scenes} --golden {golden} --update`") in result.output
    result = regress_cli(invoke, scenes, golden, "--update")
    assert result.exit_code == 0, result.output
    first = {p.name: p.read_bytes() for p in golden.iterdir()}
    assert sorted(first) == ["drop.csv.gz", "hashes.json", "spin.csv.gz"]
    assert regress_cli(invoke, scenes, golden).exit_code == 0
    result = regress_cli(invoke, scenes, golden, "--update")
    assert "drop: golden unchanged" in result.output and "spin: golden unchanged" in \
        result.output
    assert {p.name: p.read_bytes() for p in golden.iterdir()} == first  # an empty diff
    # a change in the physics: the check fails, an update says what moved and rewrites
    (scenes / "drop.yaml").write_text(DROP.replace("[0, 1, 0]", "[0, 1.001, 0]"))
    result = regress_cli(invoke, scenes, golden)
    assert result.exit_code == 1 and "drop: FAILED: first exceedance at t = 0 s (ball)" \
        in result.output and "spin: ok" in result.output
    result = regress_cli(invoke, scenes, golden, "--update")
    assert "largest position error: 0.001 m" in result.output
    assert "drop: state sha256 " in result.output and " -> " in result.output
    assert regress_cli(invoke, scenes, golden).exit_code == 0
    # a removed scene takes its golden and its pin with it
    (scenes / "spin.yaml").unlink()
    result = regress_cli(invoke, scenes, golden, "--update")
    assert "spin: no such scene any more; pin removed" in result.output
    assert sorted(p.name for p in golden.iterdir()) == ["drop.csv.gz", "hashes.json"]
    assert "spin" not in json.loads((golden / "hashes.json").read_text())[
        regress.platform_key()]


def test_a_golden_is_the_thinned_csv_of_vrsim_run_gzipped_without_name_or_time(
        invoke, scenes, tmp_path):
    golden = tmp_path / "golden"
    assert regress_cli(invoke, scenes, golden, "--update").exit_code == 0
    for name in ("drop", "spin"):
        blob = (golden / f"{name}.csv.gz").read_bytes()
        assert gzip.decompress(blob).decode() == \
            independent_golden(invoke, scenes / f"{name}.yaml", tmp_path)
        assert blob[3] & 0x08 == 0 and blob[4:8] == b"\0\0\0\0"  # RFC 1952: no FNAME, MTIME 0
        assert blob == regress.gzip_bytes(gzip.decompress(blob))  # level 9, data only
    blob = (golden / "drop.csv.gz").read_bytes()
    times = {ln.split(",")[0] for ln in gzip.decompress(blob).decode().splitlines()[1:]}
    assert len(times) == 11 and "0.0" in times and "0.5" in times  # 11 samples: all kept
    assert regress_cli(invoke, scenes, tmp_path / "g5", "--update", "--samples", "5") \
        .exit_code == 0
    times = {ln.split(",")[0] for ln in gzip.decompress(
        (tmp_path / "g5" / "spin.csv.gz").read_bytes()).decode().splitlines()[1:]}
    assert times == {"0.0", "0.1", "0.2", "0.3", "0.4"}


def test_the_repository_goldens_are_what_update_writes(tmp_path):
    """`vrsim regress scenarios --golden tests/golden --update` on an unchanged tree
    rewrites nothing: the lead's regeneration path keeps the format of every golden."""
    names = ["projectile", "walk-table"]  # cheap ones: the golden test runs them all
    golden = tmp_path / "golden"
    shutil.copytree(REPO / "tests" / "golden", golden)
    before = {p.name: p.read_bytes() for p in golden.iterdir()}
    plan = regress.plan_regress(REPO / "scenarios", golden, names, update=True)
    from vrsim_cli.tools.executors import Serial
    said = []
    regress.update_goldens(regress.run_regress(plan, Serial()), say=said.append)
    assert said == [f"{n}: golden unchanged" for n in names]
    assert {p.name: p.read_bytes() for p in golden.iterdir()} == before


# ----------------------------------------------------------------------------- tolerances


def test_tolerances_per_scene_and_per_entity(invoke, scenes, tmp_path):
    """Move the drop scene's ball by 1 mm: it fails at the default 1e-9, passes with a
    scene tolerance of 1e-2 in tolerances.yaml or a --tol for its ball, and a --tol for
    another scene does not help it."""
    golden = tmp_path / "golden"
    assert regress_cli(invoke, scenes, golden, "--update").exit_code == 0
    (scenes / "drop.yaml").write_text(DROP.replace("[0, 1, 0]", "[0, 1.001, 0]"))
    pinless = ("--no-pins",)
    assert regress_cli(invoke, scenes, golden, *pinless).exit_code == 1
    assert regress_cli(invoke, scenes, golden, *pinless, "--atol", "2e-3").exit_code == 0
    assert regress_cli(invoke, scenes, golden, *pinless, "--tol", "drop:ball=2e-3") \
        .exit_code == 0
    assert regress_cli(invoke, scenes, golden, *pinless, "--tol", "b*=2e-3").exit_code == 0
    assert regress_cli(invoke, scenes, golden, *pinless, "--tol", "spin:ball=2e-3") \
        .exit_code == 1
    assert regress_cli(invoke, scenes, golden, *pinless, "--tol", "drop:ball=5e-4") \
        .exit_code == 1
    (golden / "tolerances.yaml").write_text(
        "default: {atol: 1e-9}\nscenes:\n  drop: {atol: 2e-3}\n")
    assert regress_cli(invoke, scenes, golden, *pinless).exit_code == 0
    (golden / "tolerances.yaml").write_text(
        "scenes:\n  drop:\n    atol: 1e-9\n    entities: {'ba*': {atol: 2e-3}}\n")
    assert regress_cli(invoke, scenes, golden, *pinless).exit_code == 0
    # the pin still sees the change: bit-identity is the pin's job
    result = regress_cli(invoke, scenes, golden)
    assert result.exit_code == 1 and "differs from the pin" in result.output


@pytest.mark.parametrize("text, where, message", [
    ("default: {atol: -1}\n", ":1:17:", "expected a finite number >= 0, got '-1'"),
    ("scenes:\n  drop: {atoll: 1e-3}\n", ":2:10:", "unknown key 'atoll' (did you mean "
                                                   "'atol'?)"),
    ("defaults: {}\n", ":1:1:", "unknown key 'defaults' (did you mean 'default'?)"),
    ("scenes: [1, 2]\n", ":1:9:", "expected a mapping"),
    ("default: {atol: [1}\n", ":1:", "YAML"),
])
def test_a_bad_tolerances_file_is_located(invoke, scenes, tmp_path, text, where, message):
    golden = tmp_path / "golden"
    golden.mkdir()
    (golden / "tolerances.yaml").write_text(text)
    result = regress_cli(invoke, scenes, golden)
    assert result.exit_code == 2
    assert f"tolerances.yaml{where}" in result.stderr and message in result.stderr


# ----------------------------------------------------------------------------- pins


def test_pins_missing_platform_is_a_note_missing_scene_a_failure(invoke, scenes, tmp_path):
    golden = tmp_path / "golden"
    assert regress_cli(invoke, scenes, golden, "--update").exit_code == 0
    pins = json.loads((golden / "hashes.json").read_text())
    (golden / "hashes.json").write_text(json.dumps({"Other-arch": pins[
        regress.platform_key()]}))
    result = regress_cli(invoke, scenes, golden)
    assert result.exit_code == 0 and f"has no pins for {regress.platform_key()}" in \
        result.stderr
    del pins[regress.platform_key()]["spin"]
    (golden / "hashes.json").write_text(json.dumps(pins))
    result = regress_cli(invoke, scenes, golden)
    assert result.exit_code == 1 and "spin: FAILED: no pinned state hash" in result.output
    assert regress_cli(invoke, scenes, golden, "--no-pins").exit_code == 0


# ----------------------------------------------------------------------------- junit


def test_junit_xml_validates_and_its_counts_match(invoke, scenes, tmp_path):
    """Four scenes: one passes, one drifts from its golden (failure), one blows up (error),
    one has no golden (failure). The XML validates against the JUnit schema, and the
    counts on <testsuites> and <testsuite> equal the elements below them."""
    xmlschema = pytest.importorskip("xmlschema", reason="xmlschema is in the test extra")
    golden = tmp_path / "golden"
    assert regress_cli(invoke, scenes, golden, "--update").exit_code == 0
    (scenes / "drop.yaml").write_text(DROP.replace("[0, 1, 0]", "[0, 1.001, 0]"))
    # the largest force on the smallest mass a scene may give (scene/limits): explicit Euler
    # reaches 1e22 m/s in its first step
    (scenes / "boom.yaml").write_text(
        DROP.replace("mass: 1, position: [0, 1, 0]",
                     "mass: 1.0e-9, position: [0, 1, 0], forces: [{force: [1.0e15, 0, 0]}]")
        .replace("name: drop", "name: boom\nintegrator: euler"))
    (scenes / "new.yaml").write_text(DROP.replace("name: drop", "name: new"))
    report = tmp_path / "out" / "junit.xml"
    report.parent.mkdir()
    result = invoke("regress", scenes, "--golden", golden, "--jobs", "2", "--junit", report,
                    "--no-pins")
    assert result.exit_code == 1
    for xsd in (XSD, SUREFIRE_XSD):  # the usual dialect and Surefire's strict one
        xmlschema.XMLSchema(str(xsd)).validate(str(report))
    suite = ET.parse(report).getroot()
    assert suite.tag == "testsuite"
    cases = suite.findall("testcase")
    failures = [c for c in cases if c.find("failure") is not None]
    errors = [c for c in cases if c.find("error") is not None]
    assert int(suite.get("tests")) == len(cases) == 4
    assert int(suite.get("failures")) == len(failures) == 2
    assert int(suite.get("errors")) == len(errors) == 1
    assert int(suite.get("skipped")) == 0
    assert all(c.find("system-out").text.startswith("scene file: ") for c in cases)
    assert {c.get("name") for c in failures} == {"drop", "new"}
    assert errors[0].get("name") == "boom"
    assert "faster than light" in errors[0].find("error").get("message")
    drop = next(c for c in failures if c.get("name") == "drop").find("failure")
    assert "first exceedance at t = 0 s (ball)" in drop.get("message")
    assert "largest position error: 0.001 m" in drop.text
    assert "regress: 4 scenes, 1 passed, 2 failed, 1 errors" in result.output


def test_markup_and_control_characters_in_a_reason_keep_the_xml_valid(tmp_path):
    xmlschema = pytest.importorskip("xmlschema", reason="xmlschema is in the test extra")
    plan = regress.Plan(tmp_path, tmp_path, [], [], None, None, False)
    reason = "moved <&> \x1b[31mred\x00 \ud800"
    result = regress.Result(plan, {"x": regress.CaseResult("x", "failed", [reason])})
    blob = regress.junit_xml(result)
    for xsd in (XSD, SUREFIRE_XSD):
        xmlschema.XMLSchema(str(xsd)).validate(blob.decode())
    message = ET.fromstring(blob).find("testcase/failure").get("message")
    assert message == "moved <&> \ufffd[31mred\ufffd \ufffd"


def test_the_xsd_rejects_what_ci_systems_would_not_read(tmp_path):
    """The schema itself: a testcase without a name, or a count that is not a number,
    does not validate (so the test above can fail)."""
    xmlschema = pytest.importorskip("xmlschema", reason="xmlschema is in the test extra")
    schema = xmlschema.XMLSchema(str(XSD))
    good = ('<testsuites><testsuite name="s" tests="1" failures="1"><testcase name="a">'
            '<failure message="m">text</failure></testcase></testsuite></testsuites>')
    assert schema.is_valid(good)
    assert not schema.is_valid(good.replace(' name="a"', ""))
    assert not schema.is_valid(good.replace('tests="1"', 'tests="one"'))
    assert not schema.is_valid(good.replace("<failure", "<fail").replace("</failure", "</fail"))


def test_the_surefire_xsd_is_strict_where_the_old_report_was_not():
    """What the report wrote before and Surefire's schema refuses: a <testsuites> root, a
    timestamp on the suite, a file on a testcase, a testcase without a time."""
    xmlschema = pytest.importorskip("xmlschema", reason="xmlschema is in the test extra")
    schema = xmlschema.XMLSchema(str(SUREFIRE_XSD))
    good = ('<testsuite name="s" time="1.250" tests="1" errors="0" skipped="0" failures="1">'
            '<testcase name="a" time="0.125"><failure message="m" type="T">text</failure>'
            '<system-out>scene file: a.yaml</system-out></testcase></testsuite>')
    assert schema.is_valid(good)
    assert not schema.is_valid(f"<testsuites>{good}</testsuites>")
    assert not schema.is_valid(good.replace('time="1.250"', 'time="1.250" timestamp="x"'))
    assert not schema.is_valid(good.replace('name="a"', 'name="a" file="a.yaml"'))
    assert not schema.is_valid(good.replace(' time="0.125"', ""))
    assert not schema.is_valid(good.replace(' type="T"', ""))


# ----------------------------------------------------------------------------- input


def test_bad_input_is_found_before_anything_runs(invoke, scenes, tmp_path):
    golden = tmp_path / "golden"
    assert regress_cli(invoke, scenes, golden, "--update").exit_code == 0
    (scenes / "bad.yaml").write_text(DROP.replace("mass: 1", "mass: -1"))
    report = tmp_path / "junit.xml"
    result = regress_cli(invoke, scenes, golden, "--junit", report)
    assert result.exit_code == 2 and "bad.yaml:6:" in result.stderr
    assert not report.exists()
    (scenes / "bad.yaml").unlink()
    result = regress_cli(invoke, scenes, golden, "drpo")
    assert result.exit_code == 2 and "no scene named 'drpo' (did you mean 'drop'?)" in \
        result.stderr
    assert regress_cli(invoke, scenes, tmp_path / "none").exit_code == 2
    assert regress_cli(invoke, tmp_path / "nowhere", golden).exit_code == 2
    (golden / "spin.csv.gz").write_bytes(b"not gzip")
    result = regress_cli(invoke, scenes, golden)
    assert result.exit_code == 2 and "spin.csv.gz" in result.stderr


def test_a_tol_option_keeps_the_scene_rtol_and_angle_tolerance(tmp_path):
    """--tol sets atol (and the angle tolerance when given) of matching entities; the rest
    comes from that scene's own tolerance, not from the default."""
    file = tmp_path / "tolerances.yaml"
    file.write_text("default: {atol: 1e-9, rtol: 1e-9, angle_tol: 1e-9}\n"
                    "scenes:\n  spin: {rtol: 1e-3, angle_tol: 1e-4}\n")
    tol = regress.tolerances_from_options(file, overrides=[("sp*:box", [0.5]),
                                                           ("ball", [0.1, 0.2])])
    spin, drop = tol.plan("spin"), tol.plan("drop")
    assert spin.for_entity("box") == Tolerance(atol=0.5, rtol=1e-3, angle_tol=1e-4)
    assert spin.for_entity("other").atol == 1e-9 and spin.for_entity("other").rtol == 1e-3
    assert drop.for_entity("box").atol == 1e-9  # sp*: not this scene
    assert (drop.for_entity("ball").atol, drop.for_entity("ball").angle_tol,
            drop.for_entity("ball").rtol) == (0.1, 0.2, 1e-9)
    # --atol replaces the default's atol only, and so that of scenes without their own
    cli = regress.tolerances_from_options(file, atol=1e-3)
    assert cli.plan("drop").default == Tolerance(atol=1e-3, rtol=1e-9, angle_tol=1e-9)
    assert cli.plan("spin").default == Tolerance(atol=1e-3, rtol=1e-3, angle_tol=1e-4)
