"""`vrsim sweep`: run variants of scenes (the cartesian product of `--set KEY=V1,V2,...`
values) and measure each against a reference, as a work-precision study of the user's own
scene.

Layer 7. The steps, in order:

1. Plan (`plan_sweep`), in this process, before anything runs. Each scene file is read,
   parsed and schema-checked once. Each `--set` key path is resolved against the scene
   and the scene schema (`bodies.ball.material.restitution`: list items by name or by
   index). Every variant gets its values and passes the checks of a scene file
   (`Scene.with_overrides`: schema and semantics) and of `compile_model`; any problem, in
   any variant, stops the sweep with exit 2 and the problem located (the `--set` option,
   or FILE:LINE:COL for a problem a value causes elsewhere, with the variant named).
   Each variant is compiled exactly once, here: the workers get the pickled model
   (tools/jobs.py).
2. References (`--reference KEY=V...`): the reference of a variant is the variant with
   these values on top; variants that share a reference (every key they differ in is
   set by `--reference`) share its run. Or a trajectory file, for one scene.
3. Runs, on an executor (tools/executors.py). Each finished run is appended to
   `DIR/runs.csv` (and its per-entity errors to `DIR/entities.csv`) at once, one
   `write` of whole lines on a file opened for appending: a killed sweep leaves whole
   rows, and `--resume` skips the runs already there.
4. The report (tools/sweep_report.py): `DIR/sweep.md` with the table and the Pareto
   fronts, and a log-log plot per scene (matplotlib), from the rows in `runs.csv`.
"""

from __future__ import annotations

import csv
import hashlib
import io
import itertools
import json
import math
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

from vrsim_cli.errors import (InputError, OutputError, Problem, did_you_mean,
                              format_key_path)
from vrsim_cli.text import duration, plural
from vrsim_cli.tools.jobs import KEEP_TRAJECTORY, Job, pack_model

RUNS_CSV = "runs.csv"
ENTITIES_CSV = "entities.csv"
MAX_VARIANTS = 100_000  # a product larger than this is a typo, not a plan
MAX_PROBLEMS = 20  # distinct problems reported over all variants

# The figures of a run, after the parameter columns (units in the names).
RESULT_COLUMNS = ("reference", "dt_used_s", "integrator_used", "status", "steps", "wall_s",
                  "cpu_s", "task_s",
                  "pos_err_m", "angle_err_rad", "vel_err_m_s", "angvel_err_rad_s",
                  "worst_entity", "state_sha256", "message")
ENTITY_COLUMNS = ("run", "entity", "pos_err_m", "angle_err_rad", "vel_err_m_s",
                  "angvel_err_rad_s", "note")
ERROR_COLUMNS = ("pos_err_m", "angle_err_rad", "vel_err_m_s", "angvel_err_rad_s")
DONE = ("ok", "failed")  # statuses --resume keeps; "error" rows (crashes, bugs) rerun


# ----------------------------------------------------------------------------- options


def split_values(text: str) -> list[str]:
    """`0.1,0.2,[1, 2]` -> ['0.1', '0.2', '[1, 2]']: commas outside brackets and quotes."""
    parts, depth, quote, start = [], 0, None, 0
    for i, c in enumerate(text):
        if quote:
            quote = None if c == quote else quote
        elif c in "'\"":
            quote = c
        elif c in "[{":
            depth += 1
        elif c in "]}":
            depth -= 1
        elif c == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip() for p in parts]


_RANGE = re.compile(r"^(lin|log):([^:]+):([^:]+):([0-9]+)$")


def parse_value(text: str, option: str):
    """One value, read as a scene file reads it (YAML, with 1e-3 a number)."""
    import yaml

    from vrsim_cli.scene.spec import _SceneLoader  # the scene files' own YAML rules

    try:
        return yaml.load(text, Loader=_SceneLoader)
    except yaml.YAMLError as exc:
        raise InputError([Problem(f"command line ({option})", 0, 0, None,
                                  f"cannot read the value {text!r} as YAML "
                                  f"({getattr(exc, 'problem', None) or exc})")]) from None


def parse_setting(text: str, option: str = "--set") -> tuple[str, list]:
    """`KEY=V1,V2,...` (or `KEY=lin:A:B:N`, `KEY=log:A:B:N`: N values evenly spaced, on a
    log scale for log) -> (KEY, [values])."""
    where = f"command line ({option} {text})"
    key, sep, rest = text.partition("=")
    key = key.strip()
    if not sep or not key or not rest.strip():
        raise InputError([Problem(where, 0, 0, None, "expected KEY=VALUE[,VALUE...]",
                                  "e.g. --set dt=0.01,0.005 or --set "
                                  "bodies.ball.material.restitution=0.5,0.8")])
    match = _RANGE.match(rest.strip())
    if match:
        return key, _range(match, where)
    values = [parse_value(v, f"{option} {text}") for v in split_values(rest)]
    if any(v is None for v in values):
        raise InputError([Problem(where, 0, 0, None, "an empty value", "remove the extra "
                                  "comma, or write null in quotes to mean the text")])
    return key, values


def _range(match, where: str) -> list[float]:
    kind, a, b, n = match.group(1), match.group(2), match.group(3), int(match.group(4))
    try:
        lo, hi = float(a), float(b)
    except ValueError:
        raise InputError([Problem(where, 0, 0, None, f"{kind}:A:B:N needs numbers A and B")]) \
            from None
    if n < 1 or not (math.isfinite(lo) and math.isfinite(hi)):
        raise InputError([Problem(where, 0, 0, None, f"{kind}:A:B:N needs finite A, B and "
                                                     f"N >= 1")])
    if kind == "log" and (lo <= 0 or hi <= 0):
        raise InputError([Problem(where, 0, 0, None, "log:A:B:N needs A > 0 and B > 0")])
    if n == 1:
        return [lo]
    if kind == "lin":
        return [lo + (hi - lo) * i / (n - 1) for i in range(n)]
    la, lb = math.log10(lo), math.log10(hi)
    return [10.0 ** (la + (lb - la) * i / (n - 1)) for i in range(n)]


def parse_reference(texts: tuple[str, ...]) -> tuple[list[tuple[str, object]], Path | None]:
    """`--reference` options: KEY=V words (several per option, space-separated) or one
    trajectory file. -> ([(KEY, value)], None) or ([], path)."""
    words = [w for text in texts for w in text.split()]
    if not words:
        return [], None
    if all("=" not in w for w in words):
        if len(words) != 1:
            raise InputError("--reference: give one trajectory file, or KEY=VALUE pairs")
        path = Path(words[0])
        if not path.exists():
            raise InputError([Problem(str(path), 0, 0, None, "no such file",
                                      "--reference takes KEY=VALUE pairs (e.g. "
                                      "'integrator=dopri5 tolerance=1e-12') or a "
                                      "trajectory file")])
        return [], path
    pairs = []
    for word in words:
        key, values = parse_setting(word, "--reference")
        if len(values) != 1:
            raise InputError([Problem(f"command line (--reference {word})", 0, 0, None,
                                      "a reference takes one value per key")])
        pairs.append((key, values[0]))
    return pairs, None


# ----------------------------------------------------------------------------- key paths


def _segments(key: str) -> list:
    """`bodies[0].shape.radius` -> ['bodies', 0, 'shape', 'radius']. Brackets hold an
    index or a name (`bodies[my.ball]`); between them, every dot separates, so empty
    segments stay (a name ending in a dot, `bodies.a..mass`, is 'a.' then 'mass')."""
    out: list = []
    pos = 0
    for match in re.finditer(r"\[([^\]]*)\]", key):
        out.extend(_plain(key[pos:match.start()], after_bracket=pos > 0))
        inner = match.group(1).strip().strip("'\"")
        out.append(int(inner) if re.fullmatch(r"-?[0-9]+", inner) else ("name", inner))
        pos = match.end()
    out.extend(_plain(key[pos:], after_bracket=pos > 0))
    return out


def _plain(text: str, after_bracket: bool) -> list:
    if after_bracket:
        if not text:
            return []
        if not text.startswith("."):
            return [text]  # `a[0]b`: kept whole, reported as an unknown key
        text = text[1:]
    return text.split(".") if text else []


def _schema_here(node, root) -> list[dict]:
    """The schema objects that apply at `node`: $ref resolved, allOf / anyOf / oneOf and
    if-then-else branches included."""
    out, todo = [], [node]
    while todo:
        n = todo.pop()
        if not isinstance(n, dict):
            continue
        if "$ref" in n:
            ref = n["$ref"]
            target = root
            for part in ref.lstrip("#/").split("/"):
                target = target[part]
            todo.append(target)
        out.append(n)
        for combo in ("allOf", "anyOf", "oneOf"):
            todo.extend(n.get(combo, []))
        for branch in ("then", "else"):
            if branch in n:
                todo.append(n[branch])
    return out


def _is_array(node, root) -> bool:
    return any(n.get("type") == "array" or "items" in n for n in _schema_here(node, root))


def _schema_child(node, key, root):
    """The schema of `key` (a str property or an int item) under `node`, or None when the
    schema does not allow it. Also the property names known there (for hints)."""
    names: list[str] = []
    for n in _schema_here(node, root):
        if isinstance(key, int):
            if "items" in n:
                return n["items"], names
            continue
        props = n.get("properties", {})
        names.extend(props)
        if key in props:
            return props[key], names
        for pattern, sub in n.get("patternProperties", {}).items():
            if re.search(pattern, key):
                return sub, names
        if isinstance(n.get("additionalProperties"), dict):
            return n["additionalProperties"], names
    return None, names


def resolve_key(scene, key: str, option: str) -> tuple:
    """The concrete key path (str and int parts) of `key` in `scene`, e.g.
    ('bodies', 1, 'material', 'restitution'). List items are named by index or by name;
    a dotted name is matched longest first, falling back to shorter ones when the rest of
    the path does not resolve under it. Raises InputError naming what is wrong."""
    from vrsim_cli.scene.spec import scene_schema

    where = f"command line ({option})"
    parts = _segments(key)
    if not parts:
        raise InputError([Problem(where, 0, 0, None, f"'{key}' is not a key path",
                                  "e.g. dt or bodies.ball.material.restitution")])
    return _resolve(scene.data, scene_schema(), scene_schema(), parts, 0, (), where)


def _resolve(node, schema, root, parts: list, i: int, path: tuple, where: str) -> tuple:
    if i == len(parts):
        return path
    part = parts[i]
    shown = format_key_path(path) if path else "the scene"
    if isinstance(node, list) or (node is None and _is_array(schema, root)):
        items = node or []
        item_schema = _schema_child(schema, 0, root)[0]
        if isinstance(part, int):
            if not -len(items) <= part < len(items):
                raise InputError([Problem(where, 0, 0, path, f"index {part} is outside the "
                                          f"{len(items)} items of {shown}")])
            index = part % len(items)
            return _resolve(items[index], item_schema, root, parts, i + 1, path + (index,),
                            where)
        first_error = None
        for index, used in _items_named(items, parts, i):
            try:
                return _resolve(items[index], item_schema, root, parts, i + used,
                                path + (index,), where)
            except InputError as exc:
                first_error = first_error or exc
        if first_error is not None:
            raise first_error
        wanted = part[1] if isinstance(part, tuple) else str(part)
        names = [item.get("name") for item in items if isinstance(item, dict)]
        what = {"bodies": "body", "emitters": "emitter", "springs": "spring"}.get(
            str(path[-1]) if path else "", "item")
        raise InputError([Problem(where, 0, 0, path, f"no {what} named '{wanted}' in "
                                                     f"{shown}",
                                  did_you_mean(wanted, [n for n in names if n]))])
    if isinstance(part, (int, tuple)):
        label = part if isinstance(part, int) else part[1]
        raise InputError([Problem(where, 0, 0, path, f"{shown} is not a list, so "
                                                     f"[{label}] names nothing")])
    if node is not None and not isinstance(node, dict):
        raise InputError([Problem(where, 0, 0, path, f"{shown} is a value, not a mapping: "
                                                     f"it has no key '{part}'")])
    child, names = _schema_child(schema, part, root)
    if child is None:
        raise InputError([Problem(where, 0, 0, path + (part,), f"unknown key '{part}' in "
                                                               f"{shown}",
                                  did_you_mean(part, names) or (
                                      "allowed here: " + ", ".join(sorted(set(names)))
                                      if names else None))])
    return _resolve(node.get(part) if isinstance(node, dict) else None, child, root, parts,
                    i + 1, path + (part,), where)


def _items_named(items: list, parts: list, i: int) -> list:
    """[(index, segments used)] of the items whose name is parts[i], or several segments
    from i joined by dots (names may hold dots), the longest first."""
    part = parts[i]
    if isinstance(part, tuple):
        wanted = [(part[1], 1)]
    else:
        wanted = []
        for j in range(len(parts), i, -1):
            chunk = parts[i:j]
            if all(isinstance(c, str) for c in chunk):
                wanted.append((".".join(chunk), j - i))
    found = []
    for name, used in wanted:
        for index, item in enumerate(items):
            if isinstance(item, dict) and item.get("name") == name:
                found.append((index, used))
    return found


def set_value(data, path: tuple, value) -> None:
    """Set `value` at `path` in plain data, making missing mappings on the way."""
    node = data
    for part in path[:-1]:
        if isinstance(node, list):
            node = node[part]
        else:
            node = node.setdefault(part, {})
    node[path[-1]] = value


def parse_assignment(text: str, option: str = "--set") -> tuple[str, object]:
    """`KEY=VALUE` (one value, YAML) -> (KEY, value): `vrsim run --set` and the Python
    API's `load(..., set=[...])`, in the syntax of the sweep's --set."""
    key, values = parse_setting(text, option)
    if len(values) != 1:
        raise InputError([Problem(f"command line ({option} {text})", 0, 0, None,
                                  f"one value per key here, not {len(values)}",
                                  "several values make several runs: vrsim sweep --set "
                                  f"{text}")])
    return key, values[0]


def override(scene, pairs, option: str = "--set"):
    """A copy of `scene` with each (KEY, value) of `pairs` set at its key path (as the
    sweep's --set: `dt`, `bodies.ball.material.restitution`, `bodies[0].position`),
    validated like the file's own values. Raises InputError naming a key that is not in
    the scene's schema (with a did-you-mean) or a value the checks refuse."""
    from vrsim_cli.scene.spec import Scene

    data = json.loads(json.dumps(scene.data))
    overrides = dict(scene.overrides)
    for key, value in pairs:
        path = resolve_key(scene, key, f"{option} {key}")
        set_value(data, path, value)
        overrides[path] = f"{option} {key}={canonical(value)}"
    return Scene(scene.file, scene.base_dir, scene.text, data, scene.value_pos,
                 scene.key_pos, overrides).with_overrides({})


# ----------------------------------------------------------------------------- plan


def canonical(value) -> str:
    """The text of a parameter value in the table and in run identities."""
    if isinstance(value, str):
        return value
    return json.dumps(value, sort_keys=True)


@dataclass
class Run:
    """One planned run: a variant (role "run") or a reference (role "reference")."""

    run_id: str
    role: str
    scene_file: str
    scene_name: str
    scene_sha: str
    params: dict  # key as typed -> value
    job: Job
    reference: str = ""  # run_id of its reference, or "file:PATH"; "" for none

    @property
    def label(self) -> str:
        return self.job.label


@dataclass
class Plan:
    keys: list  # the --set keys, in order: the table's parameter columns
    runs: list = field(default_factory=list)  # [Run] of role "run", in product order
    references: dict = field(default_factory=dict)  # run_id -> Run
    reference_pairs: list = field(default_factory=list)  # [(key, value)] of --reference
    reference_file: Path | None = None
    reference_trajectory: object = None  # the file's Trajectory
    scenes: dict = field(default_factory=dict)  # scene file -> (name, sha)
    notes: list = field(default_factory=list)

    @property
    def columns(self) -> tuple:
        return ("run", "role", "scene", "scene_sha256", *self.keys, *RESULT_COLUMNS)


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


def _run_id(role: str, scene_sha: str, params: dict) -> str:
    text = json.dumps([role, scene_sha, sorted((k, canonical(v)) for k, v in params.items())])
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]


def _label(name: str, params: dict) -> str:
    return " ".join([name] + [f"{k}={canonical(v)}" for k, v in params.items()])


def plan_sweep(scene_files: list[str], settings: list[tuple[str, list]],
               reference_pairs: list, reference_file: Path | None) -> Plan:
    """Everything the sweep will run, checked and compiled. Raises InputError with the
    problems of every scene and variant (at most MAX_PROBLEMS distinct ones)."""
    from vrsim_cli.scene.spec import load_scene

    keys = [k for k, _ in settings]
    for key in keys:
        if keys.count(key) > 1:
            raise InputError(f"--set {key} is given twice: list all its values in one "
                             f"--set {key}=V1,V2,...")
    if len({k for k, _ in reference_pairs}) != len(reference_pairs):
        raise InputError("--reference sets a key twice")
    total = math.prod(len(v) for _, v in settings) * len(scene_files)
    if total > MAX_VARIANTS:
        raise InputError(f"the sweep has {total} runs; at most {MAX_VARIANTS} are allowed")
    if reference_file is not None and len(scene_files) != 1:
        raise InputError("--reference FILE compares runs of one scene: give one scene, or "
                         "KEY=VALUE pairs for a computed reference")
    plan = Plan(keys, reference_pairs=list(reference_pairs), reference_file=reference_file)
    problems: list[Problem] = []
    for file in dict.fromkeys(scene_files):  # a scene given twice runs once
        try:
            scene = load_scene(file)
        except InputError as exc:
            problems.extend(exc.problems)
            continue
        _plan_scene(plan, file, scene, settings, problems)
    if reference_file is not None and not problems:
        from vrsim_cli.tools.trajectory import read_trajectory
        plan.reference_trajectory = read_trajectory(reference_file)
    if problems:
        unique = list(dict.fromkeys(problems))
        more = len(unique) - MAX_PROBLEMS
        shown = unique[:MAX_PROBLEMS]
        if more > 0:
            shown.append(Problem("", 0, 0, None, f"... and {more} more problems"))
        raise InputError(shown)
    if reference_pairs and len(plan.references) > len(plan.scenes):
        varying = [k for k in keys if k not in dict(reference_pairs)]
        plan.notes.append(f"{len(plan.references)} reference runs: the reference keeps "
                          f"each run's {', '.join(varying)}; set "
                          f"{'them' if len(varying) > 1 else 'it'} in --reference to share "
                          f"one reference")
    return plan


def _plan_scene(plan: Plan, file: str, scene, settings, problems: list) -> None:
    name = str(scene.data.get("name", Path(file).stem))
    sha = _sha(scene.text)
    plan.scenes[file] = (name, sha)
    paths: dict = {}
    for key, values in settings:
        try:
            paths[key] = (resolve_key(scene, key, f"--set {key}"), "--set")
        except InputError as exc:
            problems.extend(_in_scene(p, file) for p in exc.problems)
    for key, _ in plan.reference_pairs:
        if key not in paths or paths[key][1] != "--set":
            try:
                paths[key] = (resolve_key(scene, key, f"--reference {key}"), "--reference")
            except InputError as exc:
                problems.extend(_in_scene(p, file) for p in exc.problems)
    if len(paths) < len({k for k, _ in settings} | {k for k, _ in plan.reference_pairs}):
        return
    ref_values = dict(plan.reference_pairs)
    for combo in itertools.product(*[values for _, values in settings]):
        params = {key: value for (key, _), value in zip(settings, combo)}
        job = _job(scene, name, params, paths, problems, sha)
        if job is None:
            continue
        run = Run(job.key, "run", file, name, sha, params, job)
        if plan.reference_pairs:
            ref_params = {**params, **ref_values}
            ref_id = _run_id("reference", sha, ref_params)
            if ref_id not in plan.references:
                ref_job = _job(scene, name, ref_params, paths, problems, sha,
                               role="reference", only=set(ref_values))
                if ref_job is None:
                    continue
                plan.references[ref_id] = Run(ref_id, "reference", file, name, sha,
                                              ref_params, ref_job)
            run.reference = ref_id
        elif plan.reference_file is not None:
            run.reference = f"file:{plan.reference_file}"
        plan.runs.append(run)


def _in_scene(problem: Problem, file: str) -> Problem:
    """A command-line problem, said of the scene it concerns."""
    return Problem(problem.file, problem.line, problem.col, problem.path,
                   f"{problem.message} (scene {file})", problem.hint)


def _job(scene, name: str, params: dict, paths: dict, problems: list, sha: str,
         role: str = "run", only: set | None = None) -> Job | None:
    """The job of one variant, validated and compiled; None (and problems) when invalid.
    `only`: the keys whose values come from --reference."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.scene.spec import Scene

    data = json.loads(json.dumps(scene.data))
    overrides = dict(scene.overrides)
    for key, value in params.items():
        path, given_by = paths[key]
        if only is not None and key in only:
            given_by = "--reference"
        set_value(data, path, value)
        overrides[path] = f"{given_by} {key}={canonical(value)}"
    label = _label(name, params)
    try:
        variant = Scene(scene.file, scene.base_dir, scene.text, data, scene.value_pos,
                        scene.key_pos, overrides).with_overrides({})
        model = compile_model(variant)
    except InputError as exc:
        for p in exc.problems:
            if p.file.startswith("command line"):
                problems.append(_in_scene(p, scene.file))
            else:  # a value that breaks something elsewhere: say which variant
                problems.append(Problem(p.file, p.line, p.col, p.path,
                                        f"{p.message} [in the variant {label}]", p.hint))
        return None
    run_id = _run_id(role, sha, params)
    blob = pack_model(model)
    scene_copy = None if blob is not None else (variant.file, variant.text,
                                                variant.base_dir, variant.data)
    return Job(run_id, label, model=blob, scene=scene_copy,
               compare=None if role == "reference" else "errors",
               keep=KEEP_TRAJECTORY if role == "reference" else "none")


# ----------------------------------------------------------------------------- table


def _number(x) -> str:
    if x is None or (isinstance(x, str) and not x):
        return ""
    return repr(float(x))


def _csv_line(values) -> bytes:
    buffer = io.StringIO()
    csv.writer(buffer, lineterminator="\n").writerow(values)
    return buffer.getvalue().encode("utf-8")


class AppendTable:
    """A CSV file that grows by whole rows: each `append` is one `write` on a descriptor
    opened with O_APPEND, so a killed process leaves whole rows behind (a torn last line,
    possible only on power loss, is dropped by `read_rows`)."""

    def __init__(self, path: Path, columns: tuple):
        self.path = path
        self.columns = columns
        self.fd = None
        new = not path.exists() or path.stat().st_size == 0
        try:
            self.fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        except OSError as exc:
            raise OutputError(f"cannot write {path}: {exc.strerror}") from None
        if new:
            self._write(_csv_line(columns))

    def append(self, rows: list) -> None:
        if rows:
            self._write(b"".join(_csv_line(r) for r in rows))

    def _write(self, data: bytes) -> None:
        try:
            written = os.write(self.fd, data)
        except OSError as exc:  # a full disk: the rows before this one are all there
            raise OutputError(f"cannot write {self.path}: {exc.strerror}; the rows "
                              f"before this run are kept (--resume continues)") from None
        if written != len(data):
            raise OutputError(f"cannot write {self.path}: short write (disk full?); "
                              f"--resume drops the cut row and continues")

    def close(self) -> None:
        if self.fd is not None:
            try:
                os.fsync(self.fd)
            except OSError:
                pass
            os.close(self.fd)
            self.fd = None


def read_rows(path: Path) -> tuple[list[str], list[dict]]:
    """(header, rows) of a table; a last line without its newline is left out."""
    data = path.read_bytes()
    complete = data[: data.rfind(b"\n") + 1]
    reader = csv.reader(io.StringIO(complete.decode("utf-8"), newline=""))
    header = next(reader, [])
    rows = [dict(zip(header, row)) for row in reader if len(row) == len(header)]
    return header, rows


def latest(rows: list[dict]) -> dict:
    """run id -> its last row (a rerun after --resume supersedes an older "error" row)."""
    out: dict = {}
    for row in rows:
        out[row["run"]] = row
    return out


def _truncate_torn_line(path: Path) -> bool:
    data = path.read_bytes()
    if not data or data.endswith(b"\n"):
        return False
    with open(path, "r+b") as f:
        f.truncate(data.rfind(b"\n") + 1)
    return True


# ----------------------------------------------------------------------------- running


@dataclass
class SweepResult:
    plan: Plan
    folder: Path
    done: int = 0  # runs finished in this invocation
    skipped: int = 0  # runs already in the table (--resume)
    failed: list = field(default_factory=list)  # [(label, status, message)]
    interrupted: bool = False
    wall_s: float = 0.0


def run_sweep(plan: Plan, folder: Path, executor, *, resume: bool = False,
              on_run=None, should_stop=None) -> SweepResult:
    """Run the plan's references, then its runs, appending each result to the tables in
    `folder` as it arrives. `on_run(run, row)` is called for every finished run."""
    from vrsim_cli.writers.atomic import AtomicFile

    start = time.perf_counter()
    _prepare(folder)
    runs_path, entities_path = folder / RUNS_CSV, folder / ENTITIES_CSV
    result = SweepResult(plan, folder)
    finished: dict = {}
    if runs_path.exists() and runs_path.stat().st_size:
        if not resume:
            raise InputError([Problem(str(runs_path), 0, 0, None, "a sweep's table is "
                                      "already here", "add --resume to continue it, or "
                                      "choose another -o folder")])
        finished = _resume(plan, runs_path, entities_path, AtomicFile)
    runs_table = AppendTable(runs_path, plan.columns)
    entity_table = AppendTable(entities_path, ENTITY_COLUMNS)
    try:
        todo = [r for r in plan.runs if finished.get(r.run_id, {}).get("status") not in DONE]
        result.skipped = len(plan.runs) - len(todo)
        trajectories = _references(plan, todo, finished, executor, runs_table, result,
                                   on_run, should_stop)
        if result.interrupted:
            return result
        items = []
        for run in todo:
            ref = trajectories.get(run.reference)
            if run.reference and ref is None and not run.reference.startswith("file:"):
                continue  # its reference failed: recorded with the reason below
            items.append((run.job, ref))
        by_key = {r.run_id: r for r in todo}
        for run in todo:
            if run.reference and run.reference not in trajectories:
                why = trajectories.get(("failed", run.reference), "its reference failed")
                _record(plan, run, None, runs_table, entity_table, result, on_run,
                        failed_reference=why)

        def done(job, outcome):
            _record(plan, by_key[job.key], outcome, runs_table, entity_table, result, on_run)

        executor.run(items, done, should_stop)
        result.interrupted = bool(should_stop and should_stop())
    finally:
        runs_table.close()
        entity_table.close()
        result.wall_s = time.perf_counter() - start
    return result


def _prepare(folder: Path) -> None:
    """The output folder, made if needed. A file in its place is an input error; a folder
    that cannot be made, an output error."""
    if folder.exists() and not folder.is_dir():
        raise InputError([Problem(str(folder), 0, 0, None, "is a file; -o names a folder")])
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot make the folder {folder}: {exc.strerror}") from None


def _resume(plan: Plan, runs_path: Path, entities_path: Path, atomic) -> dict:
    """The rows already in the table (run id -> row), after checking they belong to this
    sweep; entity rows of runs without a row (killed in between) are dropped."""
    _truncate_torn_line(runs_path)
    header, rows = read_rows(runs_path)
    if tuple(header) != plan.columns:
        raise InputError([Problem(str(runs_path), 1, 1, None, "the table has other columns "
                                  "than this sweep makes (other --set keys?)",
                                  "resume with the same --set keys, or choose another "
                                  "-o folder")])
    for row in rows:
        known = plan.scenes.get(row["scene"])
        if known is not None and known[1] != row["scene_sha256"]:
            raise InputError([Problem(str(runs_path), 0, 0, None, f"scene {row['scene']} "
                                      f"has changed since its runs were written",
                                      "choose another -o folder for the changed scene")])
    finished = latest(rows)
    if entities_path.exists():
        _truncate_torn_line(entities_path)
        ent_header, ent_rows = read_rows(entities_path)
        kept = [r for r in ent_rows if r.get("run") in finished]
        if tuple(ent_header) != ENTITY_COLUMNS or len(kept) != len(ent_rows):
            out = atomic(entities_path)
            out.write(_csv_line(ENTITY_COLUMNS))
            out.write(b"".join(_csv_line([r.get(c, "") for c in ENTITY_COLUMNS])
                               for r in kept))
            out.commit()
    return finished


def _references(plan: Plan, todo: list, finished: dict, executor, runs_table, result,
                on_run, should_stop) -> dict:
    """Reference trajectories as executor handles: run id (or "file:PATH") -> handle.
    A failed reference maps ("failed", id) -> its message."""
    handles: dict = {}
    if plan.reference_trajectory is not None:
        handles[f"file:{plan.reference_file}"] = executor.share(plan.reference_trajectory)
        return handles
    needed = {r.reference for r in todo if r.reference}
    refs = [plan.references[i] for i in plan.references if i in needed]
    if not refs:
        return handles
    by_key = {r.run_id: r for r in refs}

    def done(job, outcome):
        ref = by_key[job.key]
        if outcome.status == "ok" and outcome.trajectory is not None:
            handles[ref.run_id] = executor.share(outcome.trajectory)
        else:
            handles[("failed", ref.run_id)] = (f"its reference ({ref.label}) "
                                               f"{outcome.status}: {outcome.message}")
        if ref.run_id not in finished:
            runs_table.append([_row(plan, ref, outcome)])
        if outcome.status != "ok":
            result.failed.append((ref.label, outcome.status, outcome.message))
        if on_run is not None:
            on_run(ref, outcome)

    executor.run([(r.job, None) for r in refs], done, should_stop)
    if should_stop is not None and should_stop():
        result.interrupted = True
    return handles


def _row(plan: Plan, run: Run, outcome, entities: list | None = None,
         status: str | None = None, message: str = "") -> list:
    values = {"run": run.run_id, "role": run.role, "scene": run.scene_file,
              "scene_sha256": run.scene_sha, "reference": run.reference}
    for key in plan.keys:
        values[key] = canonical(run.params[key]) if key in run.params else ""
    if outcome is not None:
        values.update({"dt_used_s": _number(outcome.dt_s),
                       "integrator_used": outcome.integrator,
                       "status": outcome.status, "steps": str(outcome.steps),
                       "wall_s": _number(outcome.wall_s), "cpu_s": _number(outcome.cpu_s),
                       "task_s": _number(outcome.task_s),
                       "state_sha256": outcome.state_sha256, "message": outcome.message})
    if status is not None:
        values["status"], values["message"] = status, message
    if entities:
        for col in ERROR_COLUMNS:
            values[col] = _number(_max([e[col] for e in entities]))
        worst = max(entities, key=lambda e: _sort_key(e["pos_err_m"]))
        values["worst_entity"] = worst["entity"]
    return [values.get(c, "") for c in plan.columns]


def _max(values: list) -> float:
    """The largest value; NaN when any is NaN (an error that could not be measured)."""
    if any(math.isnan(v) for v in values):
        return math.nan
    return max(values) if values else math.nan


def _sort_key(x: float) -> tuple:
    return (math.isnan(x), x)


def _record(plan: Plan, run: Run, outcome, runs_table, entity_table, result, on_run,
            failed_reference: str | None = None) -> None:
    """Append one finished run: its entity rows first, then its run row (the row is what
    --resume looks for, so a run killed between the two is simply rerun)."""
    if failed_reference is not None:
        runs_table.append([_row(plan, run, None, status="failed", message=failed_reference)])
        result.failed.append((run.label, "failed", failed_reference))
        if on_run is not None:
            on_run(run, None)
        return
    entity_table.append([[run.run_id, e["entity"], *(_number(e[c]) for c in ERROR_COLUMNS),
                          e["note"]] for e in outcome.entities])
    runs_table.append([_row(plan, run, outcome, outcome.entities)])
    result.done += 1
    if outcome.status != "ok":
        result.failed.append((run.label, outcome.status, outcome.message))
    if on_run is not None:
        on_run(run, outcome)


# ----------------------------------------------------------------------------- report


def write_report(plan: Plan, folder: Path, executor_text: str) -> list[Path]:
    """`sweep.md` (atomic) and the plots, from every row in the folder's table."""
    from vrsim_cli.tools import sweep_report
    from vrsim_cli.tools.bench.report import machine
    from vrsim_cli.writers.atomic import AtomicFile

    _, rows = read_rows(folder / RUNS_CSV)
    rows = list(latest(rows).values())
    out = AtomicFile(folder / "sweep.md")
    out.write(sweep_report.markdown(plan, rows, executor_text, machine()).encode("utf-8"))
    out.commit()
    return [folder / "sweep.md"] + sweep_report.plot(plan, rows, folder)


def fronts_summary(plan: Plan, folder: Path) -> list[str]:
    """One line per scene and measure: the Pareto front, fastest first."""
    from vrsim_cli.tools import sweep_report

    _, rows = read_rows(folder / RUNS_CSV)
    lines = []
    for file, srows in sweep_report.scene_rows(plan, list(latest(rows).values())).items():
        for col, label, unit in sweep_report.MEASURES:
            if not sweep_report.measured(srows, col):
                continue
            front = sweep_report.pareto(srows, col)
            shown = "; ".join(f"{sweep_report._params(r, plan.keys) or 'as is'} "
                              f"{duration(float(r['wall_s']))}, {float(r[col]):.3g} {unit}"
                              for r in front[:6])
            more = f"; ... ({len(front) - 6} more)" if len(front) > 6 else ""
            lines.append(f"{plan.scenes[file][0]}: Pareto front ({label}): {shown}{more}")
    return lines


def progress_line(run: Run, outcome, index: int, total: int) -> str:
    """`[3/24] bounce dt=0.005: ok, 500 steps, 12.3 ms, position error 1.2e-09 m`."""
    head = f"[{index}/{total}] {run.label}" + (" (reference)" if run.role == "reference"
                                                else "")
    if outcome is None:
        return f"{head}: failed: its reference failed"
    if outcome.status != "ok":
        return f"{head}: {outcome.status}: {outcome.message}"
    text = f"{head}: ok, {plural(outcome.steps, 'step')}, {duration(outcome.wall_s)}"
    if outcome.entities:
        pos = _max([e["pos_err_m"] for e in outcome.entities])
        ang = _max([e["angle_err_rad"] for e in outcome.entities])
        text += f", position error {pos:.3g} m"
        if ang > 0 or math.isnan(ang):
            text += f", orientation error {ang:.3g} rad"
    return text
