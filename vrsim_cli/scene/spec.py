"""Scene files: YAML text -> validated scene spec that remembers where every value came from.

Layer 1 of the package. The spec is the user's document, checked against the JSON Schema
shipped in `vrsim_cli/scene/scene.schema.json` (the same file editors use through
yaml-language-server) and then by the semantic checks a schema cannot express. Every
problem is reported at once as `FILE:LINE:COL: key.path: message (hint)`.

Only `yaml.safe_load` semantics are used: no tags that build Python objects. Documents that
expand to more than `MAX_NODES` values (alias bombs) or nest deeper than `MAX_DEPTH` are
refused before anything walks them.
"""

from __future__ import annotations

import json
import math
import os
import re
import sys
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Iterator, Sequence

import yaml

from vrsim_cli.errors import InputError, Problem, did_you_mean
from vrsim_cli.scene.animation import body_issues
from vrsim_cli.scene.files import MAX_SCENE_BYTES, input_file_problem, read_input_file
from vrsim_cli.scene.limits import limit_issues
from vrsim_cli.scene.rigid import needs_mass_key, rigid_problems

SCHEMA_RESOURCE = "scene.schema.json"
MAX_FILE_BYTES = MAX_SCENE_BYTES  # a scene is text written by people; larger is a mistake
MAX_NODES = 200_000  # values after alias expansion; bounds memory and validation time
MAX_DEPTH = 64
MAX_PROBLEMS = 100  # reported per file; the rest are counted
MAX_BODIES = 400_000  # bodies plus emitted particles (model/budget.py: ~360k fit in memory)

_STR_TAG = "tag:yaml.org,2002:str"


class _SceneLoader(yaml.SafeLoader):
    """safe_load semantics, plus YAML 1.2 floats: PyYAML (YAML 1.1) reads `1e-3` and
    `1.0e300` as strings, which no user writing a time step expects."""


_SceneLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$"),
    list("-+0123456789."))

def _fetch_flow_collection_start(self, TokenClass):
    """Refuse `[` and `{` nested deeper than MAX_DEPTH while scanning: PyYAML's scanner keeps
    a possible simple key per open bracket and rechecks them all for every token, so deep
    bracket nesting costs time quadratic in the depth (3000 levels: seconds; a 32 MB file
    of brackets: hours), long before the composer's recursion would stop."""
    if self.flow_level >= MAX_DEPTH:
        raise yaml.scanner.ScannerError(None, None, f"brackets nest deeper than {MAX_DEPTH} "
                                        f"levels", self.get_mark())
    yaml.SafeLoader.fetch_flow_collection_start(self, TokenClass)


def _construct_located(self, node, deep=False):
    """Constructors raise plain ValueError, KeyError, ... for values such as `!!float x`,
    `!!bool maybe` or a 5000-digit integer (Python's int-from-text limit): report them as
    YAML errors at the node, like every other problem."""
    try:
        return yaml.SafeLoader.construct_object(self, node, deep)
    except (ValueError, KeyError, TypeError, OverflowError, IndexError, AttributeError) as exc:
        detail = str(exc).split(";")[0]
        raise yaml.constructor.ConstructorError(
            None, None, f"cannot read this {node.tag.rsplit(':', 1)[-1]} value ({detail})",
            node.start_mark) from None


def _compose_counted(self, parent, index):
    """Count the nodes as they are composed and stop at MAX_NODES: a 4 MB flow list of two
    million zeros took 52 s and 1.4 GB to compose before any budget could look at it."""
    self.composed = getattr(self, "composed", 0) + 1
    if self.composed > MAX_NODES:
        raise yaml.composer.ComposerError(
            None, None, f"the document holds more than {MAX_NODES} values",
            self.peek_event().start_mark)
    return yaml.SafeLoader.compose_node(self, parent, index)


_SceneLoader.fetch_flow_collection_start = _fetch_flow_collection_start
_SceneLoader.construct_object = _construct_located
_SceneLoader.compose_node = _compose_counted

KeyPath = tuple  # tuple[str | int, ...]


@lru_cache(maxsize=1)
def scene_schema() -> dict:
    """The JSON Schema of scene format v1, as shipped inside the package."""
    text = resources.files("vrsim_cli.scene").joinpath(SCHEMA_RESOURCE).read_text("utf-8")
    return json.loads(text)


@dataclass
class Scene:
    """A parsed, validated scene file.

    data: the document as plain Python values (dicts, lists, numbers, strings).
    value_pos / key_pos: key path -> (line, col), 1-based, of a value and of its key.
    overrides: key paths set from the command line, with the option that set them.
    """

    file: str
    base_dir: Path
    text: str
    data: dict
    value_pos: dict = field(default_factory=dict)
    key_pos: dict = field(default_factory=dict)
    overrides: dict = field(default_factory=dict)

    def get(self, path: Sequence[str | int], default: Any = None) -> Any:
        node: Any = self.data
        for part in path:
            try:
                node = node[part]
            except (KeyError, IndexError, TypeError):
                return default
        return node

    def problem(self, path: Sequence[str | int], message: str, hint: str | None = None,
                *, at_key: bool = False) -> Problem:
        """A problem located at the value (or key) at `path`, or its nearest located parent."""
        path = tuple(path)
        if path in self.overrides:
            return Problem(f"command line ({self.overrides[path]})", 0, 0, path, message, hint)
        table = self.key_pos if at_key else self.value_pos
        probe = path
        while probe and probe not in table and probe not in self.value_pos:
            probe = probe[:-1]
        line, col = table.get(probe) or self.value_pos.get(probe) or (1, 1)
        return Problem(self.file, line, col, path, message, hint)

    def without(self, path: KeyPath) -> "Scene":
        """A copy with the key at `path` removed (as if the file did not give it)."""
        data = json.loads(json.dumps(self.data))
        node = data
        for part in path[:-1]:
            node = node.get(part) if isinstance(node, dict) else None
            if node is None:
                return self
        if isinstance(node, dict):
            node.pop(path[-1], None)
        return Scene(self.file, self.base_dir, self.text, data, self.value_pos, self.key_pos,
                     dict(self.overrides))

    def with_overrides(self, values: dict[KeyPath, tuple[Any, str]]) -> "Scene":
        """A copy with command-line values set: {key path: (value, option name)}."""
        data = json.loads(json.dumps(self.data))  # plain deep copy of JSON-like data
        overrides = dict(self.overrides)
        for path, (value, option) in values.items():
            if value is None:
                continue
            node = data
            for part in path[:-1]:
                node = node.setdefault(part, {})
            node[path[-1]] = value
            overrides[tuple(path)] = option
        scene = Scene(self.file, self.base_dir, self.text, data, self.value_pos, self.key_pos,
                      overrides)
        _validate(scene)  # command-line values meet the same checks as the file's
        return scene

    def resolve_path(self, path: Sequence[str | int], problems: list[Problem],
                     output: bool = False) -> Path | None:
        """Resolve the file path stored at `path`.

        Files a scene reads (meshes, input files) are relative to the scene file's folder
        and must stay inside it: a shared scene cannot read anything else on the user's
        machine. Files it writes (`output.file`, `output.frames.dir`: `output=True`) are
        relative to the current folder, where the user runs vrsim, and must stay inside
        that. Paths given on the command line are the user's own and are not restricted.
        """
        raw = self.get(path)
        if "\0" in raw:  # no file system takes it; os calls would raise ValueError
            problems.append(self.problem(path, "a path cannot hold a NUL character"))
            return None
        candidate = Path(os.path.expanduser(raw)) if tuple(path) in self.overrides else Path(raw)
        if tuple(path) in self.overrides:
            return candidate
        try:
            base = (Path.cwd() if output else self.base_dir).resolve()
            resolved = (base / candidate).resolve()
        except RuntimeError:  # Python 3.11 raises this for a loop of links
            problems.append(self.problem(path, f"'{raw}' is a loop of symbolic links"))
            return None
        except OSError as exc:  # e.g. a name too long for the file system
            problems.append(self.problem(path, f"cannot use '{raw}': {exc.strerror or exc}"))
            return None
        if candidate.is_absolute() or not resolved.is_relative_to(base):
            if output:
                problems.append(self.problem(
                    path, f"path '{raw}' leaves the current folder",
                    "a scene writes only below the folder vrsim runs in; to write elsewhere "
                    "give the path on the command line (-o FILE, --frames DIR)"))
            else:
                problems.append(self.problem(
                    path, f"path '{raw}' leaves the scene file's folder",
                    "a scene reads only files in its own folder or below it; copy the file "
                    "there: a link to it would be followed out of the folder and refused "
                    "too"))
            return None
        return resolved

    def input_path(self, path: Sequence[str | int], problems: list[Problem],
                   limit_bytes: int) -> Path | None:
        """`resolve_path` for a file the run reads (a mesh, a sensor CSV, a replay): it
        must be a regular file of at most `limit_bytes` (not a FIFO, device or folder,
        which would block or never end)."""
        resolved = self.resolve_path(path, problems)
        if resolved is None:
            return None
        problem = input_file_problem(resolved, limit_bytes)
        if problem == "no such file":
            problems.append(self.problem(path, f"file '{self.get(path)}' not found",
                                         f"paths are relative to {self.base_dir}"))
            return None
        if problem is not None:
            problems.append(self.problem(path, f"'{self.get(path)}' {problem}"
                                         if problem.startswith("is ") else problem))
            return None
        return resolved


# ----------------------------------------------------------------------------- loading


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file. Raises InputError with every problem found. Only a
    regular file of at most MAX_FILE_BYTES is read: a FIFO, a device (/dev/zero) or a
    folder is refused before anything blocks or fills memory."""
    path = Path(path)
    name = str(path)
    try:
        raw = read_input_file(path, MAX_FILE_BYTES)
    except ValueError as exc:
        hint = "scene files are YAML text; see docs/scene-format.md" \
            if "bytes" in str(exc) else None
        raise InputError([Problem(name, 0, 0, (), str(exc), hint)]) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        col = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise InputError([Problem(name, line, col, (), "not UTF-8 text",
                                  "scene files are YAML text in UTF-8")]) from None
    return parse_scene(text, name, path.parent)


def parse_scene(text: str, file: str = "<scene>", base_dir: str | os.PathLike = ".") -> Scene:
    """Parse and validate scene text. Raises InputError with every problem found."""
    data, value_pos, key_pos, problems = _load_yaml(text, file)
    if problems:
        raise InputError(_capped(problems, file))
    scene = Scene(file, Path(base_dir), text, data, value_pos, key_pos)
    _validate(scene)
    return scene


def _validate(scene: Scene) -> None:
    """Schema first; the semantic checks assume a document that matches the schema."""
    problems = list(_schema_problems(scene))
    if not problems:
        problems = list(_semantic_problems(scene))
    if problems:
        problems.sort(key=lambda p: (p.line, p.col))
        raise InputError(_capped(problems, scene.file))


def _capped(problems: list[Problem], file: str) -> list[Problem]:
    """The first MAX_PROBLEMS problems and a count of the rest: a hostile file (100000
    aliases of a wrong value) must not print 100000 lines."""
    if len(problems) <= MAX_PROBLEMS:
        return problems
    more = len(problems) - MAX_PROBLEMS
    return problems[:MAX_PROBLEMS] + [Problem(file, 0, 0, (), f"... and {more} more "
                                                              f"problems")]


def _load_yaml(text: str, file: str):
    problems: list[Problem] = []
    try:
        loader = _SceneLoader(text)
    except yaml.YAMLError as exc:  # the reader refuses control characters up front
        return None, {}, {}, [_yaml_problem(file, exc, text)]
    try:
        node = loader.get_single_node()
        if node is None:
            return None, {}, {}, [Problem(file, 1, 1, (), "the file is empty",
                                          "a scene starts with 'vrsim: 1'")]
        # Duplicate keys are found before construction, which folds merge keys (<<) into
        # their mappings; a key given beside a merge overrides it, as YAML intends.
        _check_expansion(node)  # first: merge keys expand while constructing; bombs end here
        _duplicate_keys(node, problems, file, [MAX_NODES], set())
        data = loader.construct_document(node)
    except yaml.YAMLError as exc:
        return None, {}, {}, [_yaml_problem(file, exc, text)]
    except _TooBig as exc:
        return None, {}, {}, [Problem(file, exc.line, exc.col, exc.path, str(exc),
                                      "YAML aliases may not expand to huge documents")]
    except RecursionError:  # the composer recurses once per level of block nesting
        return None, {}, {}, [Problem(file, loader.line + 1, loader.column + 1, (),
                                      "YAML nests too deeply",
                                      f"a scene needs at most {MAX_DEPTH} levels")]
    finally:
        loader.dispose()
    if not isinstance(data, dict):
        return None, {}, {}, [Problem(file, node.start_mark.line + 1, node.start_mark.column + 1,
                                      (), "the document must be a mapping of keys to values",
                                      "a scene starts with 'vrsim: 1'")]
    value_pos: dict = {}
    key_pos: dict = {}
    budget = [MAX_NODES]
    try:
        _walk(node, data, (), value_pos, key_pos, problems, file, budget, 0)
    except _TooBig as exc:
        return None, {}, {}, [Problem(file, exc.line, exc.col, exc.path, str(exc),
                                      "YAML aliases may not expand to huge documents")]
    return data, value_pos, key_pos, problems


def _yaml_problem(file: str, exc: yaml.YAMLError, text: str) -> Problem:
    if isinstance(exc, yaml.reader.ReaderError):  # a character YAML does not allow
        line = text.count("\n", 0, exc.position) + 1
        col = exc.position - (text.rfind("\n", 0, exc.position) + 1) + 1
        return Problem(file, line, col, (), f"YAML: character U+{exc.character:04X} is not allowed",
                       "scene files are plain text")
    if isinstance(exc, yaml.MarkedYAMLError):
        mark = exc.problem_mark or exc.context_mark
        line, col = (mark.line + 1, mark.column + 1) if mark else (0, 0)
        message = exc.problem or exc.context or "invalid YAML"
        if "could not determine a constructor" in str(exc):
            message = f"YAML tag not allowed: {message}"
        opened = exc.context_mark
        if (opened is not None and mark is not None and opened.line < mark.line
                and (exc.context or "").startswith(("while parsing", "while scanning"))):
            # An unclosed bracket or quote: PyYAML notices it where the next line starts
            # something else; point at the bracket or quote the user left open.
            what = exc.context.split(" ", 2)[2]
            return Problem(file, opened.line + 1, opened.column + 1, (),
                           f"YAML: {what} that starts here is not closed ({message}, at "
                           f"line {line}, column {col})", "close the bracket or quote")
        return Problem(file, line, col, (), f"YAML: {message}")
    return Problem(file, 0, 0, (), f"YAML: {exc}")


class _TooBig(Exception):
    def __init__(self, message, line, col, path):
        super().__init__(message)
        self.line, self.col, self.path = line, col, path


_MERGE_TAG = "tag:yaml.org,2002:merge"


def _duplicate_keys(node, problems, file, budget, visiting):
    """Report keys given twice in one mapping (merge keys excepted). Bounded like _walk;
    `visiting` stops recursive aliases."""
    budget[0] -= 1
    if budget[0] < 0 or id(node) in visiting:
        return
    if isinstance(node, yaml.MappingNode):
        seen: dict = {}
        for key_node, value_node in node.value:
            if isinstance(key_node, yaml.ScalarNode) and key_node.tag == _STR_TAG:
                line = key_node.start_mark.line + 1
                if key_node.value in seen:
                    problems.append(Problem(file, line, key_node.start_mark.column + 1, None,
                                            f"duplicate key '{key_node.value}' (first at line "
                                            f"{seen[key_node.value]})"))
                seen.setdefault(key_node.value, line)
    if isinstance(node, (yaml.MappingNode, yaml.SequenceNode)):
        visiting.add(id(node))
        children = [v for pair in node.value for v in pair] \
            if isinstance(node, yaml.MappingNode) else node.value
        for child in children:
            _duplicate_keys(child, problems, file, budget, visiting)
        visiting.discard(id(node))


def _check_expansion(root) -> None:
    """Raise _TooBig when the node graph, with every alias expanded, holds more than
    MAX_NODES nodes or refers to itself. Each node's expanded size is computed once, so a
    bomb is measured in time linear in its text, not in its expansion. This must run before
    construction: PyYAML copies the pairs of merge keys (`<<: [*a, *a]`) while constructing,
    so nested merges take time exponential in their depth (16 levels: seconds; 30: days)."""
    sizes: dict = {}

    def size(node) -> int:
        key = id(node)
        if key in sizes:
            if sizes[key] is None:
                raise _TooBig("document expands without end: an alias refers to its own "
                              "anchor", node.start_mark.line + 1, node.start_mark.column + 1, ())
            return sizes[key]
        sizes[key] = None
        total = 1
        if isinstance(node, yaml.MappingNode):
            total += sum(size(k) + size(v) for k, v in node.value)
        elif isinstance(node, yaml.SequenceNode):
            total += sum(size(item) for item in node.value)
        if total > MAX_NODES:
            raise _TooBig(f"document expands to more than {MAX_NODES} values",
                          node.start_mark.line + 1, node.start_mark.column + 1, ())
        sizes[key] = total
        return total

    size(root)


def _walk(node, value, path, value_pos, key_pos, problems, file, budget, depth):
    """Record positions, and catch what the schema cannot: duplicate and non-string keys,
    NaN and infinities. Bounded by the node budget and depth (alias bombs, recursion)."""
    budget[0] -= 1
    line, col = node.start_mark.line + 1, node.start_mark.column + 1
    if budget[0] < 0:
        raise _TooBig(f"document expands to more than {MAX_NODES} values", line, col, path)
    if depth > MAX_DEPTH:
        raise _TooBig(f"document nests deeper than {MAX_DEPTH} levels", line, col, path)
    value_pos[path] = (line, col)
    if isinstance(node, yaml.MappingNode) and isinstance(value, dict):
        seen: dict = {}
        for key_node, value_node in node.value:
            kline, kcol = key_node.start_mark.line + 1, key_node.start_mark.column + 1
            if not isinstance(key_node, yaml.ScalarNode) or key_node.tag != _STR_TAG:
                shown = key_node.value if isinstance(key_node, yaml.ScalarNode) else "(complex)"
                problems.append(Problem(file, kline, kcol, path,
                                        f"key {shown!r} is not a string",
                                        "quote it if it should be a name"))
                continue
            key = key_node.value
            seen[key] = kline
            key_pos[path + (key,)] = (kline, kcol)  # the last one is the one that counts
            _walk(value_node, value.get(key), path + (key,), value_pos, key_pos, problems,
                  file, budget, depth + 1)
    elif isinstance(node, yaml.SequenceNode) and isinstance(value, list):
        for i, (item_node, item) in enumerate(zip(node.value, value)):
            _walk(item_node, item, path + (i,), value_pos, key_pos, problems, file, budget,
                  depth + 1)
    elif isinstance(value, float) and not math.isfinite(value):
        problems.append(Problem(file, line, col, path, f"must be a finite number, got {value}"))
    elif isinstance(value, int) and abs(value) > sys.float_info.max:
        problems.append(Problem(file, line, col, path, "number is too large (the largest "
                                                       f"float is {sys.float_info.max:.4g})"))


# ----------------------------------------------------------------------------- schema


@lru_cache(maxsize=1)
def _validator():
    import jsonschema  # imported on first validation only: it is not needed to run a model

    return jsonschema.Draft202012Validator(scene_schema())


_YAML_TYPE = {dict: "a mapping", list: "a list", str: "a string", bool: "true/false",
              int: "a number", float: "a number", type(None): "nothing (null)"}
_SCHEMA_TYPE = {"object": "a mapping", "array": "a list", "string": "a string",
                "number": "a number", "integer": "a whole number", "boolean": "true or false"}


@lru_cache(maxsize=1)
def _quick_check():
    """scene_schema() as a yes/no check that needs no jsonschema import (~0.1 s of every
    run's start-up); None if the schema uses a keyword it does not model."""
    from vrsim_cli.scene import schema_check

    try:
        return schema_check.compile_check(scene_schema())
    except schema_check.Unsupported:
        return None


def _schema_problems(scene: Scene) -> Iterator[Problem]:
    quick = _quick_check()
    if quick is not None and quick(scene.data):
        return  # valid: jsonschema is needed only to find and explain problems
    for err in _validator().iter_errors(scene.data):
        yield from _explain(scene, err)


def _explain(scene: Scene, err) -> Iterator[Problem]:
    path = tuple(err.absolute_path)
    kind, expected, value = err.validator, err.validator_value, err.instance
    if kind == "additionalProperties":
        allowed = list(err.schema.get("properties", {}))
        for key in value:
            if key not in allowed:
                hint = did_you_mean(key, allowed) or "allowed here: " + ", ".join(allowed)
                yield scene.problem(path + (key,), f"unknown key '{key}'", hint, at_key=True)
        return
    if kind == "required":
        for key in expected:
            if isinstance(value, dict) and key not in value:
                yield scene.problem(path, f"missing required key '{key}'",
                                    _describe(err.schema, key))
        return
    if kind == "type":
        wanted = _SCHEMA_TYPE.get(expected, str(expected))
        got = _YAML_TYPE.get(type(value), type(value).__name__)
        yield scene.problem(path, f"expected {wanted}, got {got} {_show(value)}")
    elif kind in ("enum", "const"):
        options = list(expected) if kind == "enum" else [expected]
        shown = ", ".join(_show(o) for o in options)
        hint = did_you_mean(value, [str(o) for o in options]) if isinstance(value, str) else None
        yield scene.problem(path, f"expected {'one of ' if kind == 'enum' else ''}{shown}, "
                                  f"got {_show(value)}", hint)
    elif kind in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum"):
        op = {"minimum": ">=", "maximum": "<=", "exclusiveMinimum": ">",
              "exclusiveMaximum": "<"}[kind]
        yield scene.problem(path, f"must be {op} {expected}, got {_show(value)}")
    elif kind in ("minItems", "maxItems"):
        lo = err.schema.get("minItems", 0)
        hi = err.schema.get("maxItems")
        count = f"{lo}" if lo == hi else (f"{lo} to {hi}" if hi is not None else f"at least {lo}")
        if hi is not None and hi - lo == 1:
            count = f"{lo} or {hi}"
        yield scene.problem(path, f"expected {count} items, got {len(value)}")
    elif kind == "pattern":
        yield scene.problem(path, f"{_show(value)} is not a valid name",
                            err.schema.get("description"))
    elif kind == "oneOf":  # alternatives (a number or a vector, a list or a generator)
        yield scene.problem(path, f"{_show(value)} is none of the forms allowed here",
                            err.schema.get("description"))
    elif kind in ("minLength", "maxLength"):
        yield scene.problem(path, "must not be empty" if kind == "minLength"
                            else f"is longer than {expected} characters")
    else:
        yield scene.problem(path, err.message)


def _describe(schema: dict, key: str) -> str | None:
    sub = schema.get("properties", {}).get(key)
    if isinstance(sub, dict) and "$ref" in sub and "description" not in sub:
        name = sub["$ref"].rsplit("/", 1)[-1]
        sub = scene_schema()["$defs"].get(name, {})
    return sub.get("description") if isinstance(sub, dict) else None


def _show(value: Any) -> str:
    text = repr(value) if isinstance(value, str) else json.dumps(value, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


# ----------------------------------------------------------------------------- semantics

# Key paths (relative to a body / emitter / shape / force) that hold spatial vectors whose
# length must equal the scene's dimension.
_BODY_VECTORS = ("position", "velocity")
_EMITTER_VECTORS = ("position", "direction")


def _semantic_problems(scene: Scene) -> Iterator[Problem]:
    data = scene.data
    dim = data.get("dimension", 3)
    names: dict[str, tuple] = {}

    def vector(path: tuple) -> Iterator[Problem]:
        vec = scene.get(path)
        if vec is None:
            return
        if len(vec) != dim:
            axes = "[x, y]" if dim == 2 else "[x, y, z]"
            yield scene.problem(path, f"expected {dim} numbers {axes} in a {dim}D scene, "
                                      f"got {len(vec)}")

    def nonzero(path: tuple, what: str) -> Iterator[Problem]:
        vec = scene.get(path)
        if vec is not None and len(vec) in (2, 3, 4) and not any(vec):
            yield scene.problem(path, f"{what} must not be zero")

    def unique(name: str, path: tuple) -> Iterator[Problem]:
        if name in ("observer", "world"):
            yield scene.problem(path, f"'{name}' is reserved for vrsim's own entities")
        elif name in names:
            line = scene.value_pos.get(names[name], (0, 0))[0]
            yield scene.problem(path, f"name '{name}' is used twice (first at line {line})")
        else:
            names[name] = path

    yield from vector(("gravity",))
    for i, body in enumerate(data.get("bodies") or []):
        at = ("bodies", i)
        yield from unique(body["name"], at + ("name",))
        for key in _BODY_VECTORS:
            yield from vector(at + (key,))
        kind = body.get("type", "dynamic")
        if kind == "static" and any(body.get("velocity") or []):
            yield scene.problem(at + ("velocity",), "a static body cannot move",
                                "use type: kinematic for a body that moves at a given velocity")
        if kind == "dynamic" and "mass" not in body and needs_mass_key(body):
            yield scene.problem(at, "missing required key 'mass' for a dynamic body",
                                "mass in kg, or type: static / kinematic")
        shape = body.get("shape") or {}
        if shape.get("type") == "plane":
            if kind != "static":
                yield scene.problem(at + ("shape", "type"), "a plane is an infinite half-space "
                                    "and must belong to a static body", "add type: static")
            yield from vector(at + ("shape", "normal"))
            yield from nonzero(at + ("shape", "normal"), "a plane's normal")
        if shape.get("type") == "box":
            yield from vector(at + ("shape", "size"))
        if shape.get("type") == "mesh" and dim == 2:
            yield scene.problem(at + ("shape", "type"), "meshes need a 3D scene")
        if dim == 2:
            for key in ("orientation", "euler_deg"):
                if key in body:
                    yield scene.problem(at + (key,), f"'{key}' is for 3D scenes",
                                        "use angle_deg in a 2D scene", at_key=True)
        else:
            if "angle_deg" in body:
                yield scene.problem(at + ("angle_deg",), "'angle_deg' is for 2D scenes",
                                    "use orientation or euler_deg in 3D", at_key=True)
            if "orientation" in body and "euler_deg" in body:
                yield scene.problem(at + ("euler_deg",), "give orientation or euler_deg, "
                                    "not both", at_key=True)
            yield from nonzero(at + ("orientation",), "a quaternion")
        for j, force in enumerate(body.get("forces") or []):
            fat = at + ("forces", j)
            yield from vector(fat + ("force",))
            if kind != "dynamic":
                yield scene.problem(fat, f"forces act on dynamic bodies only; this body is "
                                         f"{kind}")
            if "end" in force and force["end"] <= force.get("start", 0.0):
                yield scene.problem(fat + ("end",), "must be later than start")
    yield from rigid_problems(scene, dim)
    for path, message, hint in limit_issues(data):
        yield scene.problem(path, message, hint)
    total = len(data.get("bodies") or []) + sum(e["count"] for e in data.get("emitters") or [])
    if total > MAX_BODIES:
        yield scene.problem(("emitters",) if data.get("emitters") else ("bodies",),
                            f"the scene has {total} bodies and particles; at most {MAX_BODIES} "
                            f"are allowed", at_key=True)
    for i, emitter in enumerate(data.get("emitters") or []):
        at = ("emitters", i)
        yield from unique(emitter["name"], at + ("name",))
        for key in _EMITTER_VECTORS:
            yield from vector(at + (key,))
        yield from nonzero(at + ("direction",), "an emitter's direction")
    yield from _observer_problems(scene, dim, names)
    # Keyframes, drives and parents (the scene graph): checks in scene/animation.py.
    for path, message, hint in body_issues(data.get("bodies") or [], dim):
        yield scene.problem(path, message, hint)
    # Emitted particles are named NAME.0000 ...: they must not collide with body names.
    for i, emitter in enumerate(data.get("emitters") or []):
        for name, path in names.items():
            prefix = emitter["name"] + "."
            if path[0] == "bodies" and name.startswith(prefix) and name[len(prefix):].isdigit():
                yield scene.problem(path, f"name '{name}' collides with a particle of "
                                          f"emitter '{emitter['name']}'")


INPUT_SOURCES = ("mouse", "per_frame", "file", "tracker", "replay")


def _observer_problems(scene: Scene, dim: int, names: dict) -> Iterator[Problem]:
    observer = scene.data.get("observer")
    inputs = scene.data.get("input") or {}
    sources = [k for k in INPUT_SOURCES if k in inputs]
    if len(sources) > 1:
        yield scene.problem(("input", sources[1]), f"give one input source, not "
                            f"{' and '.join(sources)}", at_key=True)
    if "input" in scene.data and observer is None:
        yield scene.problem(("input",), "sensor input needs an observer to move",
                            "add an observer: {mode: walk, ...}", at_key=True)
    samples = inputs.get("mouse") or []
    for i in range(1, len(samples)):
        if samples[i]["t"] <= samples[i - 1]["t"]:
            yield scene.problem(("input", "mouse", i, "t"), f"times must increase strictly: "
                                f"{samples[i]['t']} after {samples[i - 1]['t']}")
    if observer is None:
        return
    if dim != 3:
        yield scene.problem(("observer",), "the observer needs a 3D scene", at_key=True)
    if "direction" in observer and "look_at" in observer:
        yield scene.problem(("observer", "look_at"), "give direction or look_at, not both",
                            at_key=True)
    for key in ("direction", "up"):
        vec = observer.get(key)
        if vec is not None and not any(vec):
            yield scene.problem(("observer", key), f"the {key} vector must not be zero")
    mode = observer.get("mode", "walk")
    if "tracker" in inputs and mode != "tracked":
        yield scene.problem(("observer", "mode") if "mode" in observer else ("observer",),
                            f"input.tracker sets the pose directly, but the mode is '{mode}'",
                            "use mode: tracked")
    if mode == "attached":
        body = observer.get("body")
        if body is None:
            yield scene.problem(("observer",), "mode attached needs the body to ride on",
                                "add body: NAME", at_key=True)
        elif body not in names or names[body][0] != "bodies":
            yield scene.problem(("observer", "body"), f"no body named '{body}'",
                                did_you_mean(body, [n for n, p in names.items()
                                                    if p[0] == "bodies"]))
        if "input" in scene.data:
            yield scene.problem(("input",), "an attached observer takes no sensor input",
                                at_key=True)
    elif "body" in observer:
        yield scene.problem(("observer", "body"), "body is for mode: attached", at_key=True)
    if mode == "tracked" and not ({"tracker", "replay"} & set(inputs)):
        yield scene.problem(("observer", "mode"), "mode tracked needs input.tracker (or a "
                            "replayed tracker run in input.replay)")
