"""The portal and the agent build from one contract (``basestation/contract.py``).

A test here fails when a column, a limit or a state is changed on one side only.
"""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path
from typing import Any

import pytest
import yaml
from django.db import models
from drf_spectacular.generators import SchemaGenerator
from hypothesis import given, settings
from hypothesis import strategies as st

from basestation import contract
from basestation.program import InvalidRunBody, parse_run_body
from basestation.store import RunStore
from basestation.store import Sample as AgentSample
from portal.experiments.choices import Direction
from portal.runs.models import Sample
from portal.runs.states import STATE_FOR_AGENT_END, RunState

AGENT_OPENAPI = Path(__file__).resolve().parents[2] / "docs" / "agent-openapi.yaml"

# How each kind of contract column may be stored by the portal's model.
MODEL_FIELDS_FOR_KIND: dict[str, tuple[type[models.Field], ...]] = {
    "int": (models.IntegerField, models.SmallIntegerField, models.PositiveIntegerField),
    "float": (models.FloatField,),
    "text": (models.CharField,),
    "epoch": (models.DateTimeField,),
}


def _model_fields() -> dict[str, models.Field]:
    return {
        f.name: f
        for f in Sample._meta.concrete_fields
        if f.name not in ("id", "run")  # the portal's own keys
    }


def test_the_sample_model_has_exactly_the_contract_columns():
    assert set(_model_fields()) == set(contract.SAMPLE_FIELDS)


@pytest.mark.parametrize("column", contract.SAMPLE_COLUMNS, ids=lambda c: c.name)
def test_each_sample_column_is_stored_as_the_contract_says(column):
    field = _model_fields()[column.name]
    assert isinstance(field, MODEL_FIELDS_FOR_KIND[column.kind]), (column.kind, type(field))
    assert field.null == column.nullable
    if column.max_length is not None:
        assert field.max_length == column.max_length
    if column.choices is not None:
        assert {value for value, _ in field.choices or []} == set(column.choices)


# How each kind of contract column is declared in the agent's SQLite table.
SQLITE_TYPE_FOR_KIND = {"int": "INTEGER", "float": "REAL", "text": "TEXT", "epoch": "REAL"}
# ... and typed in the portal's OpenAPI schema.
OPENAPI_TYPE_FOR_KIND = {
    "int": {"type": "integer"},
    "float": {"type": "number", "format": "double"},
    "text": {"type": "string"},
    "epoch": {"type": "string", "format": "date-time"},
}


def test_the_agents_store_and_answers_have_the_contract_columns(tmp_path):
    store = RunStore(tmp_path / "runs.sqlite3")
    try:
        with sqlite3.connect(store.path) as conn:
            table = [
                (name, declared, bool(notnull))
                for _, name, declared, notnull, _, _ in conn.execute("PRAGMA table_info(samples)")
            ]
    finally:
        store.close()
    assert table == [
        ("run_id", "TEXT", True),
        *((c.name, SQLITE_TYPE_FOR_KIND[c.kind], not c.nullable) for c in contract.SAMPLE_COLUMNS),
    ]
    assert tuple(AgentSample.__dataclass_fields__) == contract.SAMPLE_FIELDS
    sample = AgentSample(1, 1.0, 0, 0.5, 0.5, "cw", 60.0, 1.0)
    assert tuple(sample.to_json_dict()) == contract.SAMPLE_FIELDS


def test_a_sample_from_the_agent_round_trips_through_the_contract():
    sample = AgentSample(7, 1.5, None, 0.5, 0.4, "ccw", 59.9, 12.0, 4, 40.6, -8.6, "B2", -1)
    assert contract.sample_parse(sample.to_json_dict()) == sample.values()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"seq": "7"}, "seq: not an integer"),
        ({"t": None}, "t: is required"),
        ({"velocity_mps": float("nan")}, "velocity_mps: not a finite number"),
        ({"direction": "up"}, "direction: 'up' is not one of cw, ccw"),
        ({"grid_id": "A" * 9}, "grid_id: longer than 8"),
        ({"lap": True}, "lap: not an integer"),
        ({"seq": 0}, "seq: 0 is less than 1"),
        ({"velocity_mps": -0.1}, "velocity_mps: -0.1 is less than 0"),
    ],
)
def test_a_bad_sample_is_refused_naming_its_column(change, message):
    raw = AgentSample(7, 1.5, 0, 0.5, 0.4, "cw", 59.9, 12.0).to_json_dict() | change
    with pytest.raises(ValueError, match=message):
        contract.sample_parse(raw)


# Values a column may meet in a page: good ones of every kind and each way of being wrong.
_ANY_VALUE = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["cw", "ccw", "up", "A2", "A" * 9, ""]),
)


def _good_sample(seq: int) -> dict:
    return AgentSample(
        seq, 1.5 + seq, 0, 0.5, 0.4, "cw", 59.9, 12.0, 4, 40.6, None, "B2", 1
    ).to_json_dict()


@settings(max_examples=300, deadline=None)
@given(
    pages=st.lists(
        st.dictionaries(st.sampled_from(contract.SAMPLE_FIELDS), _ANY_VALUE, max_size=3),
        min_size=0,
        max_size=6,
    ),
    drop=st.sets(st.sampled_from(contract.SAMPLE_FIELDS), max_size=2),
)
def test_a_page_is_parsed_as_each_sample_alone_would_be(pages, drop):
    """``samples_parse`` (a column at a time) gives what ``sample_parse`` gives for each
    sample: the same values, or the same error for the first bad sample."""
    raws = [
        {k: v for k, v in (_good_sample(i + 1) | change).items() if i != 0 or k not in drop}
        for i, change in enumerate(pages)
    ]
    try:
        expected = [contract.sample_parse(raw) for raw in raws]
    except (ValueError, OverflowError) as exc:
        error = exc
    else:
        error = None
    if error is not None:
        with pytest.raises(type(error), match=f"^{re.escape(str(error))}$"):
            contract.samples_parse(raws)
        return
    parsed = contract.samples_parse(raws)
    assert parsed == expected
    assert [[type(v) for v in row] for row in parsed] == [
        [type(v) for v in row] for row in expected
    ]


def test_directions_agree():
    assert tuple(Direction.values) == contract.DIRECTIONS


def test_every_end_on_the_agent_ends_the_run_in_a_portal_state():
    assert set(contract.PORTAL_STATE_FOR_AGENT_END) == set(contract.AGENT_END_STATES)
    assert set(STATE_FOR_AGENT_END.values()) <= set(RunState.values)


def test_the_agent_refuses_what_the_portal_would_never_send():
    body = {
        "owner": "alice",
        "title": "t",
        "start_at": "2030-01-01T10:00:00Z",
        "end_at": "2030-01-01T12:00:00Z",
        "limits": {"max_velocity_mps": 2.0, "max_accel_mps2": 1.0},
        "segments": [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 1.0}]
        * (contract.MAX_SEGMENTS + 1),
    }
    with pytest.raises(InvalidRunBody) as refused:
        parse_run_body(body)
    assert refused.value.fields["segments"] == [f"must hold 1 to {contract.MAX_SEGMENTS} segments"]


def _resolved(node: Any, document: dict[str, Any]) -> Any:
    """``node`` with every ``$ref`` of ``document`` replaced by what it names."""
    if isinstance(node, list):
        return [_resolved(item, document) for item in node]
    if not isinstance(node, dict):
        return node
    if "$ref" in node:
        target: Any = document
        for part in node["$ref"].removeprefix("#/").split("/"):
            target = target[part]
        siblings = {k: v for k, v in node.items() if k != "$ref"}
        return _resolved({**target, **siblings}, document)
    return {key: _resolved(value, document) for key, value in node.items()}


def test_the_agents_openapi_sample_is_the_contracts():
    spec = yaml.safe_load(AGENT_OPENAPI.read_text(encoding="utf-8"))
    sample = _resolved(spec["components"]["schemas"]["Sample"], spec)
    sample.pop("description", None)
    assert sample == contract.sample_json_schema()


@pytest.fixture(scope="module")
def portal_sample_schema() -> dict[str, Any]:
    schema = SchemaGenerator().get_schema(request=None, public=True)
    return _resolved(schema["components"]["schemas"]["Sample"], schema)


def test_the_portals_sample_schema_has_the_contract_columns_in_order(portal_sample_schema):
    assert tuple(portal_sample_schema["properties"]) == contract.SAMPLE_FIELDS
    # The portal always answers every column (null where there is no value).
    assert set(portal_sample_schema["required"]) == set(contract.SAMPLE_FIELDS)


@pytest.mark.parametrize("column", contract.SAMPLE_COLUMNS, ids=lambda c: c.name)
def test_each_column_of_the_portals_sample_schema_is_as_the_contract_says(
    column, portal_sample_schema
):
    field = portal_sample_schema["properties"][column.name]
    assert field.get("nullable", False) == column.nullable
    if column.choices is not None:
        assert field["enum"] == list(column.choices)
        return
    assert {k: field[k] for k in ("type", "format") if k in field} == OPENAPI_TYPE_FOR_KIND[
        column.kind
    ]
    assert field.get("minimum") == column.minimum
    assert field.get("maxLength") == column.max_length
    assert field.get("description", "") == column.doc
