"""A yes/no check of a document against the scene schema, for the start-up of every run.

jsonschema is the reference: it finds and explains every problem (`spec._explain`). But
importing it costs ~0.1 s, a tenth of a small run's budget, and a valid scene (nearly
every run) needs no explanation. `compile_check(schema)` turns the schema into nested
closures once; `check(document)` returns True only when the document is valid. A value
outside plain JSON (a NaN or inf, a non-string key, a YAML date or set) is not modelled:
for those the check returns False without looking further, as for an invalid document,
and the caller asks jsonschema. So this check can only ever save time, never let an
invalid scene through:

    check(document) is True  =>  jsonschema finds no error.

`tests/test_schema_check.py` holds it to that over random valid and mutated scenes.

Keywords modelled (JSON Schema 2020-12, the ones scene.schema.json uses): type, enum,
const, minimum, maximum, exclusiveMinimum, exclusiveMaximum, minLength, maxLength,
pattern, minItems, maxItems, items, properties, additionalProperties, required,
maxProperties, propertyNames, allOf, anyOf, oneOf, not, if/then/else and local $ref. A
schema with any other keyword makes `compile_check` raise Unsupported, and the caller
then uses jsonschema alone.
"""

from __future__ import annotations

import math
import re
from typing import Any, Callable

Check = Callable[[Any], bool]

_ANNOTATIONS = {"$schema", "$id", "$comment", "$defs", "title", "description", "default",
                "examples", "deprecated", "readOnly", "writeOnly"}


class Unsupported(ValueError):
    """The schema uses a keyword this checker does not model."""


def _is_number(value) -> bool:
    return type(value) in (int, float)


def plain_json(value, depth: int = 0) -> bool:
    """True when `value` is made only of dict (string keys), list, str, bool, int, finite
    float and None: the world the compiled checks decide exactly."""
    kind = type(value)
    if kind is dict:
        return depth < _MAX_DEPTH and all(
            type(k) is str and plain_json(v, depth + 1) for k, v in value.items())
    if kind is list:
        return depth < _MAX_DEPTH and all(plain_json(v, depth + 1) for v in value)
    if kind is float:
        return math.isfinite(value)
    return kind in (str, bool, int) or value is None


_MAX_DEPTH = 200  # deeper documents go to jsonschema (and its own recursion limits)


def _type_test(name: str) -> Check:
    tests = {
        "object": lambda v: type(v) is dict,
        "array": lambda v: type(v) is list,
        "string": lambda v: type(v) is str,
        "boolean": lambda v: type(v) is bool,
        "null": lambda v: v is None,
        "number": _is_number,
        "integer": lambda v: type(v) is int or (_is_number(v) and float(v).is_integer()),
    }
    if name not in tests:
        raise Unsupported(f"type {name!r}")
    return tests[name]


def _json_equal(a, b) -> bool:
    """Equality as JSON Schema defines it: true/false are not 1/0; 1 equals 1.0."""
    if type(a) is bool or type(b) is bool:
        return type(a) is bool and type(b) is bool and a == b
    if _is_number(a) and _is_number(b):
        return a == b
    if type(a) is str and type(b) is str:
        return a == b
    if a is None or b is None:
        return a is None and b is None
    if type(a) is list and type(b) is list:
        return len(a) == len(b) and all(_json_equal(x, y) for x, y in zip(a, b))
    if type(a) is dict and type(b) is dict:
        return a.keys() == b.keys() and all(_json_equal(a[k], b[k]) for k in a)
    return False


def compile_check(schema) -> Check:
    """The schema as one function document -> bool (True only if valid)."""
    inner = _compile(schema)
    return lambda document: plain_json(document) and inner(document)


def _compile(schema) -> Check:
    """Exact validity of a plain-JSON document (see `plain_json`)."""
    root = schema
    compiled: dict[str, Check] = {}

    def ref(pointer: str) -> Check:
        if not pointer.startswith("#/"):
            raise Unsupported(f"$ref {pointer!r}")
        if pointer not in compiled:
            target = root
            for part in pointer[2:].split("/"):
                target = target[part.replace("~1", "/").replace("~0", "~")]
            compiled[pointer] = lambda v: False  # placeholder while compiling a cycle
            slot = build(target)
            compiled[pointer] = slot
        return lambda v: compiled[pointer](v)

    def build(node) -> Check:
        if node is True:
            return lambda v: True
        if node is False:
            return lambda v: False
        if type(node) is not dict:
            raise Unsupported(f"schema {node!r}")
        unknown = set(node) - _ANNOTATIONS - _KEYWORDS
        if unknown:
            raise Unsupported(", ".join(sorted(unknown)))
        checks: list[Check] = []
        if "$ref" in node:
            checks.append(ref(node["$ref"]))
        if "type" in node:
            names = node["type"] if isinstance(node["type"], list) else [node["type"]]
            tests = [_type_test(n) for n in names]
            checks.append(lambda v, t=tests: any(test(v) for test in t))
        if "enum" in node:
            options = list(node["enum"])
            checks.append(lambda v, o=options: any(_json_equal(v, x) for x in o))
        if "const" in node:
            checks.append(lambda v, c=node["const"]: _json_equal(v, c))
        checks.extend(_numeric(node))
        checks.extend(_string(node))
        checks.extend(_array(node, build))
        checks.extend(_object(node, build))
        for sub in node.get("allOf", ()):
            checks.append(build(sub))
        if "anyOf" in node:
            subs = [build(s) for s in node["anyOf"]]
            checks.append(lambda v, s=subs: any(c(v) for c in s))
        if "oneOf" in node:
            subs = [build(s) for s in node["oneOf"]]
            checks.append(lambda v, s=subs: sum(1 for c in s if c(v)) == 1)
        if "not" in node:
            inner = build(node["not"])
            checks.append(lambda v, c=inner: not c(v))
        if "if" in node:
            cond = build(node["if"])
            then = build(node.get("then", True))
            other = build(node.get("else", True))
            checks.append(lambda v, c=cond, t=then, e=other: t(v) if c(v) else e(v))
        if not checks:
            return lambda v: True
        if len(checks) == 1:
            return checks[0]
        return lambda v, cs=tuple(checks): all(c(v) for c in cs)

    return build(schema)


def _numeric(node) -> list[Check]:
    bounds = [(k, node[k]) for k in ("minimum", "maximum", "exclusiveMinimum",
                                     "exclusiveMaximum") if k in node]
    if not bounds:
        return []
    compare = {"minimum": lambda v, b: v >= b, "maximum": lambda v, b: v <= b,
               "exclusiveMinimum": lambda v, b: v > b, "exclusiveMaximum": lambda v, b: v < b}
    tests = [(compare[k], b) for k, b in bounds]

    def check(v):
        if type(v) not in (int, float):  # bounds apply to numbers only (bool is not one)
            return True
        return all(test(v, b) for test, b in tests)
    return [check]


def _lengths(node, kind: type, low: str, high: str) -> list[Check]:
    """minLength/maxLength (str) or minItems/maxItems (list): they apply to `kind` only."""
    out: list[Check] = []
    if low in node:
        out.append(lambda v, n=node[low]: type(v) is not kind or len(v) >= n)
    if high in node:
        out.append(lambda v, n=node[high]: type(v) is not kind or len(v) <= n)
    return out


def _string(node) -> list[Check]:
    out = _lengths(node, str, "minLength", "maxLength")
    if "pattern" in node:
        rx = re.compile(node["pattern"])
        out.append(lambda v, r=rx: type(v) is not str or r.search(v) is not None)
    return out


def _array(node, build) -> list[Check]:
    out = _lengths(node, list, "minItems", "maxItems")
    if "items" in node:
        item = build(node["items"])
        out.append(lambda v, c=item: type(v) is not list or all(c(x) for x in v))
    return out


def _object(node, build) -> list[Check]:
    keys = ("properties", "additionalProperties", "required", "maxProperties",
            "propertyNames")
    if not any(k in node for k in keys):
        return []
    props = {name: build(sub) for name, sub in node.get("properties", {}).items()}
    extra = build(node["additionalProperties"]) if "additionalProperties" in node else None
    names = build(node["propertyNames"]) if "propertyNames" in node else None
    required = tuple(node.get("required", ()))
    most = node.get("maxProperties")

    def check(v):
        if type(v) is not dict:
            return True  # object keywords apply to objects only
        if most is not None and len(v) > most:
            return False
        for name in required:
            if name not in v:
                return False
        for key, value in v.items():
            if names is not None and not names(key):
                return False
            sub = props.get(key)
            if sub is not None:
                if not sub(value):
                    return False
            elif extra is not None and not extra(value):
                return False
        return True
    return [check]


_KEYWORDS = {"$ref", "type", "enum", "const", "minimum", "maximum", "exclusiveMinimum",
             "exclusiveMaximum", "minLength", "maxLength", "pattern", "minItems", "maxItems",
             "items", "properties", "additionalProperties", "required", "maxProperties",
             "propertyNames", "allOf", "anyOf", "oneOf", "not", "if", "then", "else"}
