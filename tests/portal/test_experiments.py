from __future__ import annotations

import pytest

from portal.errors import InvalidInput
from portal.experiments.models import Experiment
from portal.experiments.services import experiment_create, segments_validate
from tests.factories import MobileResourceFactory

pytestmark = pytest.mark.django_db


def test_it_normalises_a_valid_program():
    clean = segments_validate(
        [{"velocity_mps": "0.5", "direction": "cw", "duration_s": 3}], robot=MobileResourceFactory()
    )
    assert clean == [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0}]


@pytest.mark.parametrize(
    ("segments", "message"),
    [
        ([], "at least one segment"),
        ("fast", "at least one segment"),
        ([{"velocity_mps": 3.0, "direction": "cw", "duration_s": 1}], "exceeds the maximum 2"),
        ([{"velocity_mps": -1, "direction": "cw", "duration_s": 1}], "velocity must be"),
        ([{"velocity_mps": 1, "direction": "up", "duration_s": 1}], "direction must be"),
        ([{"velocity_mps": 1, "direction": "cw", "duration_s": 0}], "duration must be"),
        ([{"velocity_mps": "nan", "direction": "cw", "duration_s": 1}], "velocity must be"),
        ([{"velocity_mps": 1, "direction": "cw"}], "missing duration_s"),
        ([{"velocity_mps": 1, "direction": "cw", "duration_s": 1, "x": 1}], "unknown x"),
        ([{"velocity_mps": 1, "direction": "cw", "duration_s": 90000}], "at most 86400"),
        ([[1, 2, 3]], "must be an object"),
    ],
)
def test_it_rejects_a_bad_program_naming_the_fault(segments, message):
    with pytest.raises(InvalidInput) as excinfo:
        segments_validate(segments, robot=MobileResourceFactory())
    assert message in " ".join(excinfo.value.fields["segments"])


def test_it_names_the_segment_at_fault():
    segments = [
        {"velocity_mps": 1, "direction": "cw", "duration_s": 1},
        {"velocity_mps": 9, "direction": "cw", "duration_s": 1},
    ]
    with pytest.raises(InvalidInput, match="Segment 2"):
        segments_validate(segments, robot=MobileResourceFactory())


def test_experiment_velocity_is_checked_against_the_robots(owner, mobile):
    with pytest.raises(InvalidInput, match="exceeds the maximum 2"):
        experiment_create(
            owner=owner,
            title="too fast",
            segments=[{"velocity_mps": 2.5, "direction": "cw", "duration_s": 1}],
        )
    assert not Experiment.objects.exists()


def test_api_rejects_excessive_velocity_with_the_field(api, mobile):
    response = api.post(
        "/api/v1/experiments/",
        {"title": "t", "segments": [{"velocity_mps": 5, "direction": "cw", "duration_s": 2}]},
        format="json",
    )
    assert response.status_code == 400
    assert "segments" in response.json()["fields"]
    assert "5 m/s exceeds the maximum 2 m/s" in response.json()["fields"]["segments"][0]
    assert not Experiment.objects.exists()


def test_api_creates_and_lists_an_experiment(api, mobile):
    body = {
        "title": "two laps",
        "segments": [{"velocity_mps": 1, "direction": "ccw", "duration_s": 4}],
    }
    created = api.post("/api/v1/experiments/", body, format="json")
    assert created.status_code == 201
    assert created.json()["duration_s"] == 4.0
    listed = api.get("/api/v1/experiments/").json()["results"]
    assert [e["title"] for e in listed] == ["two laps"]
