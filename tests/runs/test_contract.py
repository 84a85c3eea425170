"""The portal and the agent build from one contract (``basestation/contract.py``).

A test here fails when a column, a limit or a state is changed on one side only.
"""

from __future__ import annotations

import sqlite3

import pytest
from django.db import models

from basestation import contract
from basestation.program import InvalidRunBody, parse_run_body
from basestation.store import RunStore
from basestation.store import Sample as AgentSample
from portal.experiments.choices import Direction
from portal.runs.models import Sample
from portal.runs.states import STATE_FOR_AGENT_END, RunState

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


def test_the_agents_store_and_answers_have_the_contract_columns(tmp_path):
    store = RunStore(tmp_path / "runs.sqlite3")
    try:
        with sqlite3.connect(store.path) as conn:
            stored = [row[1] for row in conn.execute("PRAGMA table_info(samples)")]
    finally:
        store.close()
    assert stored == ["run_id", *contract.SAMPLE_FIELDS]
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
    ],
)
def test_a_bad_sample_is_refused_naming_its_column(change, message):
    raw = AgentSample(7, 1.5, 0, 0.5, 0.4, "cw", 59.9, 12.0).to_json_dict() | change
    with pytest.raises(ValueError, match=message):
        contract.sample_parse(raw)


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
