"""`vrsim regress DIR --golden GOLDEN_DIR`: run every scene of a folder and compare each
with its golden trajectory (`vrsim compare`'s measures and tolerances); `--update`
rewrites the goldens on purpose; `--junit FILE` writes the result for CI systems.

Layer 7. For each `DIR/NAME.yaml` the golden is `GOLDEN_DIR/NAME.csv.gz`: the trajectory
`vrsim run DIR/NAME.yaml -o NAME.csv` writes, at the scene's output rate thinned to at
most `samples` sample times (always the first and the last), gzip-compressed so that the
bytes depend on the data only (no name, mtime 0, level 9): regenerating an unchanged
scene rewrites the very same bytes. `GOLDEN_DIR/hashes.json`, when present, pins the final
state's sha256 (`state sha256` of `vrsim run`) per platform (OS-machine): equal hashes
mean bit-identical runs. `GOLDEN_DIR/tolerances.yaml`, when present, holds the
tolerances per scene and per entity pattern (docs/regression.md).

Scenes are checked and compiled before anything runs (a bad scene: exit 2); the runs go
through the executors of `vrsim sweep` (--jobs, --ray), each compared in its worker.
A scene fails when its trajectory is outside tolerance, its run fails, its golden is
missing, or its state hash differs from this platform's pin.
"""

from __future__ import annotations

import gzip
import io
import json
import math
import platform
import time
from dataclasses import dataclass, field
from pathlib import Path

from vrsim_cli.errors import InputError, Problem, did_you_mean
from vrsim_cli.tools.jobs import Job, pack_model

GOLDEN_SAMPLES = 21
HASHES = "hashes.json"
TOLERANCES = "tolerances.yaml"
SCENE_SUFFIXES = (".yaml", ".yml")
TOLERANCE_KEYS = ("atol", "rtol", "angle_tol")


def platform_key() -> str:
    return f"{platform.system()}-{platform.machine()}"


def gzip_bytes(data: bytes) -> bytes:
    """gzip that depends on the data only: mtime 0, no file name in the header."""
    buffer = io.BytesIO()
    with gzip.GzipFile(filename="", mode="wb", fileobj=buffer, compresslevel=9,
                       mtime=0) as f:
        f.write(data)
    return buffer.getvalue()


def scene_files(folder: Path) -> dict[str, Path]:
    """name -> scene file, for the scene files directly in `folder`, sorted by name."""
    found = {}
    for path in sorted(folder.iterdir()):
        if path.is_file() and path.suffix in SCENE_SUFFIXES and not path.name.startswith("."):
            found.setdefault(path.stem, path)
    return found


def golden_path(golden: Path, name: str) -> Path:
    return golden / f"{name}.csv.gz"


# ----------------------------------------------------------------------------- tolerances


@dataclass
class Tolerances:
    """The default tolerance, per scene ones (name -> compare.Tolerance) and per entity
    pattern ones ([(scene pattern, entity pattern, Tolerance)], the last match wins)."""

    default: object
    scenes: dict = field(default_factory=dict)
    entities: list = field(default_factory=list)
    # --tol: [(scene pattern, entity pattern, atol, angle_tol or None)], after `entities`;
    # rtol (and a missing angle_tol) from the scene's own tolerance
    options: list = field(default_factory=list)
    source: str = ""

    def plan(self, scene: str):
        """The compare.TolerancePlan of one scene."""
        import dataclasses
        import fnmatch

        from vrsim_cli.tools.compare import TolerancePlan

        base = self.scenes.get(scene, self.default)
        overrides = [(entity, tol) for scene_pattern, entity, tol in self.entities
                     if fnmatch.fnmatchcase(scene, scene_pattern)]
        for scene_pattern, entity, atol, angle_tol in self.options:
            if fnmatch.fnmatchcase(scene, scene_pattern):
                overrides.append((entity, dataclasses.replace(
                    base, atol=atol, angle_tol=base.angle_tol if angle_tol is None
                    else angle_tol)))
        return TolerancePlan(base, tuple(overrides))


def tolerances_from_options(path: Path | None, atol=None, rtol=None, angle_tol=None,
                            overrides=()) -> Tolerances:
    """The tolerances of `vrsim regress`: the file's, with --atol/--rtol/--angle-tol
    replacing those values of its default and `overrides` from --tol, [("[SCENE:]PATTERN", [atol] or
    [atol, angle_tol])], after its entity tolerances."""
    given = {k: v for k, v in (("atol", atol), ("rtol", rtol), ("angle_tol", angle_tol))
             if v is not None}
    tol = load_tolerances(path, given)
    for pattern, values in overrides:
        scene_pattern, _, entity_pattern = pattern.rpartition(":")
        tol.options.append((scene_pattern or "*", entity_pattern or "*", values[0],
                            values[1] if len(values) > 1 else None))
    return tol


def load_tolerances(path: Path | None, given: dict | None = None) -> Tolerances:
    """The tolerances of `path` (YAML; absent: compare's defaults). `given` ({"atol": ...}
    from --atol/--rtol/--angle-tol) replaces those values of the file's default, before
    the scenes inherit from it. Raises InputError at FILE:LINE:COL for a bad file."""
    import dataclasses

    from vrsim_cli.tools.compare import Tolerance

    given = given or {}
    tol = Tolerances(dataclasses.replace(Tolerance(), **given))
    if path is None or not path.exists():
        return tol
    tol.source = str(path)
    try:
        text = path.read_text("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError([Problem(str(path), 0, 0, None, f"cannot read: {exc}")]) from None
    node = _compose(text, str(path))
    problems: list[Problem] = []
    if node is not None:
        _read_tolerances(node, str(path), tol, given, problems)
    if problems:
        raise InputError(problems)
    return tol


def _compose(text: str, file: str):
    import yaml

    from vrsim_cli.scene.spec import _SceneLoader  # YAML 1.2 numbers, as in scene files

    try:
        return yaml.compose(text, Loader=_SceneLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InputError([Problem(file, mark.line + 1 if mark else 0,
                                  mark.column + 1 if mark else 0, None,
                                  f"YAML: {getattr(exc, 'problem', None) or exc}")]) from None


def _at(file: str, node, path: tuple, message: str, hint: str | None = None) -> Problem:
    return Problem(file, node.start_mark.line + 1, node.start_mark.column + 1, path, message,
                   hint)


def _mapping(node, file: str, path: tuple, problems: list) -> list:
    import yaml

    if not isinstance(node, yaml.MappingNode):
        problems.append(_at(file, node, path, "expected a mapping"))
        return []
    return [(k, v) for k, v in node.value if isinstance(k, yaml.ScalarNode)]


def _tolerance(node, file: str, path: tuple, base, problems: list, extra=()):
    """A compare.Tolerance from {atol, rtol, angle_tol} (missing keys: from `base`)."""
    import dataclasses

    values = {}
    for key_node, value_node in _mapping(node, file, path, problems):
        key = key_node.value
        if key in extra:
            continue
        if key not in TOLERANCE_KEYS:
            problems.append(_at(file, key_node, path + (key,), f"unknown key '{key}'",
                                did_you_mean(key, TOLERANCE_KEYS + tuple(extra))
                                or "allowed: " + ", ".join(TOLERANCE_KEYS + tuple(extra))))
            continue
        try:
            number = float(value_node.value)
        except (TypeError, ValueError):
            number = math.nan
        if value_node.tag.endswith((":bool", ":null", ":str")) or not 0.0 <= number < math.inf:
            problems.append(_at(file, value_node, path + (key,), f"expected a finite number "
                                f">= 0, got {value_node.value!r}"))
            continue
        values[key] = number
    return dataclasses.replace(base, **values)


def _read_tolerances(node, file: str, tol: Tolerances, given: dict,
                     problems: list) -> None:
    import dataclasses

    for key_node, value_node in _mapping(node, file, (), problems):
        key = key_node.value
        if key == "default":  # --atol/--rtol/--angle-tol win over the file
            parsed = _tolerance(value_node, file, ("default",), tol.default, problems)
            tol.default = dataclasses.replace(parsed, **given)
        elif key != "scenes":
            problems.append(_at(file, key_node, (key,), f"unknown key '{key}'",
                                did_you_mean(key, ["default", "scenes"]) or
                                "allowed: default, scenes"))
    for key_node, value_node in _mapping(node, file, (), []):
        if key_node.value != "scenes":
            continue
        for name_node, spec in _mapping(value_node, file, ("scenes",), problems):
            name = name_node.value
            at = ("scenes", name)
            tol.scenes[name] = _tolerance(spec, file, at, tol.default, problems,
                                          extra=("entities",))
            for k, v in _mapping(spec, file, at, []):
                if k.value != "entities":
                    continue
                for pattern_node, entity_spec in _mapping(v, file, at + ("entities",),
                                                          problems):
                    tol.entities.append((name, pattern_node.value, _tolerance(
                        entity_spec, file, at + ("entities", pattern_node.value),
                        tol.scenes[name], problems)))


# ----------------------------------------------------------------------------- plan


@dataclass
class Case:
    name: str
    file: Path
    job: Job
    golden: object = None  # the golden Trajectory, None when there is none
    pin: str | None = None  # this platform's pinned state hash, None when none


@dataclass
class Plan:
    folder: Path
    golden: Path
    cases: list
    all_names: list  # every scene in the folder (for removing stale goldens)
    tolerances: Tolerances
    pins: dict | None  # platform -> {name: hash} from hashes.json; None: no pin file
    check_pins: bool
    samples: int = GOLDEN_SAMPLES
    notes: list = field(default_factory=list)


def plan_regress(folder: Path, golden: Path, names=(), *, update: bool = False,
                 tolerances: Tolerances | None = None, check_pins: bool = True,
                 samples: int = GOLDEN_SAMPLES) -> Plan:
    """Every selected scene checked and compiled, its golden read. Raises InputError with
    every problem found (bad scenes, unreadable goldens, unknown names)."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.tools.trajectory import read_trajectory

    if not folder.is_dir():
        raise InputError([Problem(str(folder), 0, 0, None, "no such folder",
                                  "vrsim regress DIR: a folder of scene files")])
    if golden.exists() and not golden.is_dir():
        raise InputError([Problem(str(golden), 0, 0, None, "is a file, not a folder")])
    if not golden.exists() and not update:
        raise InputError([Problem(str(golden), 0, 0, None, "no such folder",
                                  "make the goldens with --update")])
    found = scene_files(folder)
    if not found:
        raise InputError([Problem(str(folder), 0, 0, None, "holds no scene files (*.yaml)")])
    unknown = [n for n in names if n not in found]
    if unknown:
        raise InputError([Problem(str(folder), 0, 0, None, f"no scene named '{n}'",
                                  did_you_mean(n, found)) for n in unknown])
    if tolerances is None:
        tolerances = load_tolerances(golden / TOLERANCES)
    pins = None
    if (golden / HASHES).exists():
        try:
            pins = json.loads((golden / HASHES).read_text("utf-8"))
            if not isinstance(pins, dict) or not all(isinstance(v, dict) for v in
                                                     pins.values()):
                raise ValueError("expected {platform: {scene: sha256}}")
        except (OSError, UnicodeDecodeError, ValueError) as exc:
            raise InputError([Problem(str(golden / HASHES), 0, 0, None,
                                      f"not a pin file: {exc}")]) from None
    problems: list[Problem] = []
    cases = []
    for name in (list(names) or list(found)):
        try:
            model = compile_model(load_scene(found[name]))
        except InputError as exc:
            problems.extend(exc.problems)
            continue
        blob = pack_model(model)
        job = Job(name, name, model=blob,
                  scene=None if blob is not None else _scene_copy(found[name]),
                  compare="golden", tolerance=tolerances.plan(name), golden_samples=samples)
        case = Case(name, found[name], job)
        path = golden_path(golden, name)
        if path.exists():
            try:
                case.golden = read_trajectory(path)
            except InputError as exc:
                problems.extend(exc.problems)
        if pins is not None:
            case.pin = pins.get(platform_key(), {}).get(name)
        cases.append(case)
    if problems:
        raise InputError(problems)
    plan = Plan(folder, golden, cases, list(found), tolerances, pins, check_pins, samples)
    if check_pins and pins is not None and platform_key() not in pins and not update:
        plan.notes.append(f"{golden / HASHES} has no pins for {platform_key()}: "
                          f"trajectories compared, state hashes not (--update on this "
                          f"platform adds them)")
    return plan


def _scene_copy(path: Path) -> tuple:
    from vrsim_cli.scene.spec import load_scene

    scene = load_scene(path)
    return (scene.file, scene.text, scene.base_dir, scene.data)


# ----------------------------------------------------------------------------- running


@dataclass
class CaseResult:
    name: str
    status: str  # "passed", "failed" (outside tolerance, pin, no golden), "error" (the run)
    reasons: list = field(default_factory=list)  # one line each, why it did not pass
    lines: list = field(default_factory=list)  # the comparison report
    outcome: object = None  # jobs.Outcome

    @property
    def time_s(self) -> float:
        t = getattr(self.outcome, "task_s", math.nan)
        return t if t == t else 0.0


@dataclass
class Result:
    plan: Plan
    cases: dict = field(default_factory=dict)  # name -> CaseResult, in plan order
    wall_s: float = 0.0
    interrupted: bool = False

    @property
    def ok(self) -> bool:
        return not self.interrupted and all(c.status == "passed" for c in self.cases.values())

    def counts(self) -> dict:
        values = list(self.cases.values())
        return {"tests": len(values),
                "failures": sum(c.status == "failed" for c in values),
                "errors": sum(c.status == "error" for c in values)}


def run_regress(plan: Plan, executor, *, on_case=None, should_stop=None,
                update_command: str = "vrsim regress DIR --golden GOLDEN_DIR --update") -> Result:
    """Run every case and judge it. `on_case(CaseResult)` as each finishes."""
    start = time.perf_counter()
    result = Result(plan)
    cases = {c.name: c for c in plan.cases}
    items = [(c.job, executor.share(c.golden) if c.golden is not None else None)
             for c in plan.cases]

    def done(job, outcome):
        case = _judge(cases[job.key], outcome, plan, update_command)
        result.cases[job.key] = case
        if on_case is not None:
            on_case(case)

    executor.run(items, done, should_stop)
    result.interrupted = bool(should_stop and should_stop()) or len(result.cases) < len(cases)
    result.cases = {c.name: result.cases[c.name] for c in plan.cases if c.name in result.cases}
    result.wall_s = time.perf_counter() - start
    return result


def _judge(case: Case, outcome, plan: Plan, update_command: str) -> CaseResult:
    res = CaseResult(case.name, "passed", outcome=outcome)
    if outcome.status != "ok":
        res.status = "error"
        res.reasons.append(f"the run {outcome.status}: {outcome.message}")
        return res
    if case.golden is None:
        res.status = "failed"
        res.reasons.append(f"no golden file {golden_path(plan.golden, case.name)}; create "
                           f"it with `{update_command}`")
    else:
        res.lines = list(outcome.report_lines)
        if not outcome.ok:
            res.status = "failed"
            res.reasons.append(next((ln[len("FAIL: "):] for ln in outcome.report_lines
                                     if ln.startswith("FAIL: ")), "outside tolerance"))
    if plan.check_pins and plan.pins is not None and platform_key() in plan.pins:
        if case.pin is None:
            res.status = "failed"
            res.reasons.append(f"no pinned state hash for {platform_key()}; add it with "
                               f"`{update_command}`")
        elif case.pin != outcome.state_sha256:
            res.status = "failed"
            res.reasons.append(f"state sha256:{outcome.state_sha256} differs from the pin "
                               f"{case.pin} for {platform_key()}: the run is no longer "
                               f"bit-identical")
    return res


# ----------------------------------------------------------------------------- update


def update_goldens(result: Result, say=print) -> list[str]:
    """Rewrite the goldens and this platform's pins of the cases that ran; remove goldens
    and pins of scenes no longer in the folder. Returns the names not written (their run
    failed). Says what changed, for the commit message."""
    from vrsim_cli.writers.atomic import AtomicFile

    plan = result.plan
    plan.golden.mkdir(parents=True, exist_ok=True)
    hashes = dict(plan.pins or {})
    pins = hashes.setdefault(platform_key(), {})
    not_written = []
    for name, case in result.cases.items():
        outcome = case.outcome
        if outcome.status != "ok" or outcome.csv is None:
            not_written.append(name)
            say(f"{name}: not written: the run {outcome.status}: {outcome.message}")
            continue
        data = gzip_bytes(outcome.csv.encode("utf-8"))
        path = golden_path(plan.golden, name)
        if path.exists() and path.read_bytes() == data:
            say(f"{name}: golden unchanged")
        else:
            if case.lines:  # the new run against the old golden: what moved, from when
                say("\n".join([f"{name}:"] + ["  " + ln for ln in case.lines]))
            out = AtomicFile(path)
            out.write(data)
            out.commit()
            say(f"{name}: wrote {path} ({len(data)} bytes)")
        if pins.get(name) != outcome.state_sha256:
            say(f"{name}: state sha256 {pins.get(name, '(none)')} -> {outcome.state_sha256}")
        pins[name] = outcome.state_sha256
    known = set(plan.all_names)
    for platform_pins in hashes.values():
        for stale in sorted(set(platform_pins) - known):
            del platform_pins[stale]
            say(f"{stale}: no such scene any more; pin removed")
    for path in sorted(plan.golden.glob("*.csv.gz")):
        if path.name[: -len(".csv.gz")] not in known:
            path.unlink()
            say(f"{path.name}: no such scene any more; golden removed")
    out = AtomicFile(plan.golden / HASHES)
    out.write((json.dumps(hashes, indent=2, sort_keys=True) + "\n").encode("utf-8"))
    out.commit()
    return not_written


# ----------------------------------------------------------------------------- junit


def _xml_text(text: str) -> str:
    """Text with the characters XML 1.0 cannot hold replaced (control characters)."""
    return "".join(c if c in "\t\n\r" or (" " <= c <= "\ud7ff") or ("\ue000" <= c <= "\ufffd")
                   or c >= "\U00010000" else "\ufffd" for c in text)


def junit_xml(result: Result, suite_name: str | None = None) -> bytes:
    """JUnit XML as Maven Surefire's strict 3.0 schema has it, which the looser dialects
    (Jenkins, GitLab, Ant) also read: one <testsuite> root, one <testcase> per scene
    (its time required), a <failure> per failed scene and an <error> per scene whose run
    failed, the scene file in the testcase's <system-out>; tests / failures / errors /
    skipped on the suite match the elements. No attribute the schema does not declare
    (timestamp, file): a strict validator refuses them."""
    import xml.etree.ElementTree as ET

    plan = result.plan
    counts = result.counts()
    name = suite_name or f"vrsim regress {plan.folder}"
    suite = ET.Element("testsuite", {
        "name": _xml_text(name), "time": f"{result.wall_s:.3f}",
        "tests": str(counts["tests"]), "errors": str(counts["errors"]), "skipped": "0",
        "failures": str(counts["failures"])})
    properties = ET.SubElement(suite, "properties")
    for key, value in (("folder", str(plan.folder)), ("golden", str(plan.golden))):
        ET.SubElement(properties, "property", {"name": key, "value": _xml_text(value)})
    classname = f"vrsim.regress.{plan.folder.name or 'scenes'}"
    for case in result.cases.values():
        element = ET.SubElement(suite, "testcase", {
            "name": _xml_text(case.name), "classname": _xml_text(classname),
            "time": f"{case.time_s:.3f}"})
        if case.status != "passed":
            kind = "error" if case.status == "error" else "failure"
            detail = ET.SubElement(element, kind, {
                "message": _xml_text("; ".join(case.reasons)[:1000]),
                "type": "RunFailed" if kind == "error" else "RegressionFailure"})
            detail.text = _xml_text("\n".join(case.reasons + case.lines))
        out = ET.SubElement(element, "system-out")
        out.text = _xml_text(f"scene file: {case_file(plan, case.name)}")
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True) + b"\n"


def case_file(plan: Plan, name: str) -> Path:
    return next((c.file for c in plan.cases if c.name == name), plan.folder / name)


def write_junit(result: Result, path: Path) -> None:
    from vrsim_cli.writers.atomic import AtomicFile

    out = AtomicFile(path)
    out.write(junit_xml(result))
    out.commit()
