from __future__ import annotations

import pytest

from core.errors import InvalidInput
from portal.experiments.models import Experiment
from portal.experiments.selectors import experiment_fits, fits_summary
from portal.experiments.services import experiment_create, segments_validate
from tests.factories import MobileResourceFactory

pytestmark = pytest.mark.django_db


def test_it_normalises_a_valid_program():
    clean = segments_validate(
        [{"velocity_mps": "0.5", "direction": "cw", "duration_s": 3}],
        robots=[MobileResourceFactory()],
    )
    assert clean == [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0}]


@pytest.mark.parametrize(
    ("segments", "message"),
    [
        ([], "at least one segment"),
        ("fast", "at least one segment"),
        ([{"velocity_mps": 3.0, "direction": "cw", "duration_s": 1}], "faster than every robot"),
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
        segments_validate(segments, robots=[MobileResourceFactory()])
    assert message in " ".join(excinfo.value.fields["segments"])


def test_it_names_the_segment_at_fault():
    segments = [
        {"velocity_mps": 1, "direction": "cw", "duration_s": 1},
        {"velocity_mps": 9, "direction": "cw", "duration_s": 1},
    ]
    with pytest.raises(InvalidInput, match="Segment 1"):
        segments_validate(segments, robots=[MobileResourceFactory()])


def test_experiment_velocity_is_checked_against_the_robots(owner, mobile):
    with pytest.raises(InvalidInput, match="faster than every robot you may book"):
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
    assert response.json()["fields"]["segments"] == [
        "Segment 0: velocity 5 m/s is faster than every robot you may book "
        "(mobile-1: 2 m/s, the portal's limit for it)."
    ]
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


def test_a_program_is_checked_against_each_robot_not_the_fastest(api):
    MobileResourceFactory(name="mobile-1", max_velocity_mps=2.0, agent_max_velocity_mps=1.5)
    MobileResourceFactory(name="mobile-2", max_velocity_mps=1.2)
    MobileResourceFactory(name="mobile-off", max_velocity_mps=3.0, enabled=False)
    body = {
        "title": "brisk",
        "segments": [{"velocity_mps": 1.4, "direction": "cw", "duration_s": 2}],
    }
    created = api.post("/api/v1/experiments/", body, format="json")
    assert created.status_code == 201, created.json()
    # Out of service by an admin: not a robot its author may book.
    assert created.json()["robots"] == [
        {"name": "mobile-1", "fits": True, "max_velocity_mps": 1.5, "limited_by": "agent"},
        {"name": "mobile-2", "fits": False, "max_velocity_mps": 1.2, "limited_by": "portal"},
    ]
    body["segments"][0]["velocity_mps"] = 1.6  # above the agent's 1.5 and mobile-2's 1.2
    refused = api.post("/api/v1/experiments/", body, format="json")
    assert refused.status_code == 400
    assert refused.json()["fields"]["segments"] == [
        "Segment 0: velocity 1.6 m/s is faster than every robot you may book (mobile-1: "
        "1.5 m/s, the limit its base station reports; mobile-2: 1.2 m/s, the portal's limit "
        "for it)."
    ]


def test_the_page_says_which_robots_a_saved_program_fits(owner):
    MobileResourceFactory(name="mobile-1", max_velocity_mps=2.0)
    MobileResourceFactory(name="mobile-2", max_velocity_mps=1.2, agent_max_velocity_mps=1.0)
    experiment = experiment_create(
        owner=owner,
        title="brisk",
        segments=[{"velocity_mps": 1.4, "direction": "cw", "duration_s": 2}],
    )
    assert fits_summary(experiment_fits(experiment)) == (
        "Fits mobile-1; not mobile-2 (1 m/s, the limit its base station reports)."
    )


def test_the_experiment_page_says_which_robots_the_saved_program_fits(owner, client):
    MobileResourceFactory(name="mobile-1", max_velocity_mps=2.0)
    MobileResourceFactory(name="mobile-2", max_velocity_mps=1.2)
    client.force_login(owner)
    response = client.post(
        "/experiments/new/",
        {"title": "brisk", "velocity_mps": ["1.4"], "direction": ["cw"], "duration_s": ["2"]},
        follow=True,
    )
    assert response.status_code == 200
    assert [str(m) for m in response.context["messages"]] == [
        "Experiment “brisk” saved. Fits mobile-1; not mobile-2 (1.2 m/s, the portal's limit "
        "for it)."
    ]
