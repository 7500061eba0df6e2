"""The start-up schema check (`scene.schema_check`) against jsonschema, the reference.

The property that makes the quick check safe: it says "valid" only when jsonschema finds
no error — over the scene schema's own generator (tests/test_hostile_schema.py: every key
at every depth, one value in eight hostile), plus documents outside plain JSON (NaN, inf,
non-string keys, YAML dates, sets). And it is exact inside plain JSON, so valid scenes
really take the quick path (otherwise it would save nothing): every scenario, every
example in docs/, and the generator's well-formed documents.
"""

from __future__ import annotations

import datetime
import math
from pathlib import Path

import jsonschema
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from test_hostile_schema import SCHEMA, from_schema
from vrsim_cli.scene import schema_check
from vrsim_cli.scene.spec import _quick_check

ROOT = Path(__file__).resolve().parents[1]
REFERENCE = jsonschema.Draft202012Validator(SCHEMA)
QUICK = schema_check.compile_check(SCHEMA)


def _reference_valid(document) -> bool:
    return not any(True for _ in REFERENCE.iter_errors(document))


def test_the_scene_schema_is_fully_modelled():
    """Every keyword of scene.schema.json is one the quick check decides, so runs use it
    (a new keyword in the schema fails here, not silently slows every run down)."""
    assert _quick_check() is not None


@pytest.mark.parametrize("path", sorted((ROOT / "scenarios").glob("*.yaml")),
                         ids=lambda p: p.name)
def test_every_scenario_takes_the_quick_path(path):
    document = yaml.safe_load(path.read_text())
    assert _reference_valid(document)
    assert QUICK(document) is True


@settings(max_examples=300, derandomize=True, deadline=None,
          suppress_health_check=list(HealthCheck))
@given(document=from_schema(SCHEMA, rate=8))
def test_quick_valid_implies_reference_valid_and_agrees_on_plain_json(document):
    quick, reference = QUICK(document), _reference_valid(document)
    if quick:
        assert reference, "the quick check let through a document jsonschema refuses"
    if schema_check.plain_json(document):
        assert quick == reference


@settings(max_examples=100, derandomize=True, deadline=None,
          suppress_health_check=list(HealthCheck))
@given(document=from_schema(SCHEMA, rate=0))
def test_well_formed_documents_agree(document):
    """rate=0: the generator's own shapes only — mostly valid, so this exercises the
    "valid" side of the agreement (the test above sees mostly invalid documents)."""
    assert QUICK(document) == _reference_valid(document)


def test_well_formed_documents_are_mostly_valid():
    """Guards the test above against passing vacuously on all-invalid documents."""
    seen = []

    @settings(max_examples=40, derandomize=True, deadline=None,
              suppress_health_check=list(HealthCheck))
    @given(document=from_schema(SCHEMA, rate=0))
    def collect(document):
        seen.append(QUICK(document))

    collect()
    assert sum(seen) >= len(seen) // 2, f"{sum(seen)} of {len(seen)} valid"


NOT_PLAIN = [math.nan, math.inf, -math.inf, datetime.date(2026, 1, 1), {1, 2}, (1, 2, 3),
             b"bytes", 1 + 2j]


@pytest.mark.parametrize("odd", NOT_PLAIN, ids=repr)
@pytest.mark.parametrize("where", ["duration", "dt", "name", "gravity"])
def test_values_outside_plain_json_go_to_jsonschema(odd, where):
    """A NaN where a number may stand (jsonschema lets it pass `minimum`), a date, a
    tuple: the quick check does not decide, so the reference (and the semantic checks
    after it) see them."""
    document = yaml.safe_load((ROOT / "scenarios" / "projectile.yaml").read_text())
    document[where] = odd
    assert QUICK(document) is False
    document = {**document, 1: "non-string key"}
    assert QUICK(document) is False


@pytest.mark.parametrize("schema, good, bad", [
    ({"enum": [1, "a"]}, [1, 1.0, "a"], [True, "b", None, [1]]),
    ({"const": False}, [False], [0, 0.0, None, "false"]),
    ({"type": "integer"}, [3, 3.0, -0.0], [3.5, True, "3"]),
    ({"type": "number", "exclusiveMinimum": 0, "maximum": 2}, [1e-300, 2], [0, 2.5, False]),
    ({"minimum": 1}, ["x", None, True, [0]], [0]),  # bounds apply to numbers only
    ({"oneOf": [{"type": "number"}, {"type": "integer"}]}, [1.5], [1, "x"]),
    ({"if": {"type": "number"}, "then": {"minimum": 0}, "else": {"type": "string"}},
     [0, "s"], [-1, None]),
    ({"not": {"type": "string"}}, [1, None], ["s"]),
    ({"type": "object", "properties": {"a": {"type": "string"}}, "required": ["a"],
      "additionalProperties": False}, [{"a": "x"}], [{}, {"a": 1}, {"a": "x", "b": 1}]),
    ({"type": "object", "maxProperties": 1, "propertyNames": {"pattern": "^[a-z]+$"},
      "additionalProperties": {"type": "number"}}, [{"ab": 1}, {}],
     [{"a": 1, "b": 2}, {"A": 1}, {"a": "x"}]),
    ({"type": "array", "minItems": 1, "maxItems": 2, "items": {"type": "string"}},
     [["a"], ["a", "b"]], [[], ["a", "b", "c"], [1]]),
    ({"type": "string", "minLength": 2, "maxLength": 3, "pattern": "b"},
     ["ab", "abc", "éb"], ["b", "abcd", "ac"]),
    ({"$defs": {"n": {"type": "number"}}, "items": {"$ref": "#/$defs/n"}}, [[1, 2.5]],
     [[1, "x"]]),
])
def test_keywords_agree_with_jsonschema(schema, good, bad):
    quick = schema_check.compile_check(schema)
    reference = jsonschema.Draft202012Validator(schema)
    for value in good:
        assert reference.is_valid(value) and quick(value) is True, value
    for value in bad:
        assert not reference.is_valid(value) and quick(value) is False, value


@pytest.mark.parametrize("schema", [{"patternProperties": {"a": {}}},
                                    {"unevaluatedProperties": False},
                                    {"$ref": "https://example.com/other.json"},
                                    {"type": "nonsense"}])
def test_unmodelled_schemas_are_refused_at_compile(schema):
    with pytest.raises(schema_check.Unsupported):
        schema_check.compile_check(schema)
