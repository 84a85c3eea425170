"""The booking form on the two clock-change days of 2027 in Europe/Lisbon: a time in the
repeated hour (31 October, 01:00-01:59 twice) is its first occurrence and the confirmation
shows its UTC offset; a time in the skipped hour (28 March, 01:00-01:59 never) is refused on
its field and nothing is booked."""

from __future__ import annotations

import re
from datetime import UTC, datetime

import pytest
import time_machine

from bookings.models import Reservation
from tests.factories import ExperimentFactory, FixedResourceFactory, MobileResourceFactory

pytestmark = pytest.mark.django_db


@pytest.fixture(autouse=True)
def _lisbon(settings):
    settings.TIME_ZONE = "Europe/Lisbon"


@pytest.fixture
def node():
    return FixedResourceFactory(name="node-01")


def _book(client, owner, start_at: str, end_at: str):
    client.force_login(owner)
    return client.post(
        "/book/",
        {"resources": ["node-01"], "start_at": start_at, "end_at": end_at},
        follow=True,
    )


@time_machine.travel(datetime(2027, 10, 25, 9, 0, tzinfo=UTC))
@pytest.mark.parametrize(
    ("start_at", "end_at", "booked", "shown"),
    [
        # Typed in the repeated hour: its first occurrence, summer time.
        (
            "2027-10-31T01:30",
            "2027-10-31T01:50",
            (datetime(2027, 10, 31, 0, 30, tzinfo=UTC), datetime(2027, 10, 31, 0, 50, tzinfo=UTC)),
            "from 2027-10-31 01:30 (UTC+01:00) to 2027-10-31 01:50 (UTC+01:00)",
        ),
        # From the first 01:30 to the 02:30 after the clocks went back: two hours.
        (
            "2027-10-31T01:30",
            "2027-10-31T02:30",
            (datetime(2027, 10, 31, 0, 30, tzinfo=UTC), datetime(2027, 10, 31, 2, 30, tzinfo=UTC)),
            "from 2027-10-31 01:30 (UTC+01:00) to 2027-10-31 02:30 (UTC+00:00)",
        ),
        # The second occurrence, named by its offset.
        (
            "2027-10-31T01:30:00+00:00",
            "2027-10-31T01:50:00+00:00",
            (datetime(2027, 10, 31, 1, 30, tzinfo=UTC), datetime(2027, 10, 31, 1, 50, tzinfo=UTC)),
            "from 2027-10-31 01:30 (UTC+00:00) to 2027-10-31 01:50 (UTC+00:00)",
        ),
    ],
)
def test_a_time_in_the_repeated_hour_books_its_first_occurrence_and_says_which(
    client, owner, node, start_at, end_at, booked, shown
):
    answer = _book(client, owner, start_at, end_at)
    reservation = Reservation.objects.get()
    assert (reservation.start_at, reservation.end_at) == booked
    assert f"Booked node-01 {shown}." in answer.content.decode()


@time_machine.travel(datetime(2027, 3, 22, 9, 0, tzinfo=UTC))
def test_a_time_in_the_skipped_hour_is_refused_on_its_field_and_nothing_is_booked(
    client, owner, node
):
    answer = _book(client, owner, "2027-03-28T01:30", "2027-03-28T03:00")
    assert answer.status_code == 200
    errors = answer.context["form"].errors
    assert errors == {
        "start_at": [
            "01:30 does not exist on 28 March 2027 in Europe/Lisbon: "
            "clocks go forward from 01:00 to 02:00"
        ]
    }
    assert "01:30 does not exist on 28 March 2027" in answer.content.decode()
    assert not Reservation.objects.exists()


def test_the_form_says_how_it_reads_the_hours_the_clocks_change(client, owner):
    client.force_login(owner)
    page = client.get("/book/").content.decode()
    assert "happens twice" in page
    assert "first occurrence" in page


def test_the_robot_is_listed_first_and_ticked_for_an_experiment_it_fits(client, owner):
    for name in ("node-01", "node-02"):
        FixedResourceFactory(name=name)
    MobileResourceFactory(name="mobile-1", max_velocity_mps=1.0)
    fits = ExperimentFactory(
        owner=owner, segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 5}]
    )
    client.force_login(owner)

    page = client.get(f"/book/?experiment={fits.pk}").content.decode()
    boxes = re.findall(r'<input type="checkbox" name="resources" value="([^"]+)"([^>]*)>', page)
    assert [name for name, _ in boxes] == ["mobile-1", "node-01", "node-02"]
    assert [name for name, rest in boxes if "checked" in rest] == ["mobile-1"]
    assert f'<option value="{fits.pk}" selected>' in page

    # Nothing named: nothing ticked. Another's experiment or a bad id: as if none were named.
    for query in ("", "?experiment=abc", f"?experiment={ExperimentFactory().pk}"):
        page = client.get(f"/book/{query}").content.decode()
        assert "checked" not in page


def test_the_robot_and_two_nodes_are_one_booking_with_the_robots_run(client, owner):
    for name in ("node-01", "node-02"):
        FixedResourceFactory(name=name)
    MobileResourceFactory(name="mobile-1")
    experiment = ExperimentFactory(owner=owner)
    with time_machine.travel(datetime(2027, 5, 3, 9, 0, tzinfo=UTC)):
        client.force_login(owner)
        answer = client.post(
            "/book/",
            {
                "resources": ["mobile-1", "node-01", "node-02"],
                "experiment": experiment.pk,
                "start_at": "2027-05-04T10:00",
                "end_at": "2027-05-04T11:00",
            },
        )
    reservation = Reservation.objects.get()
    assert sorted(i.resource.name for i in reservation.items.all()) == [
        "mobile-1",
        "node-01",
        "node-02",
    ]
    # To the run's page, which shows its start and counts down to it.
    assert answer.headers["Location"] == f"/runs/{reservation.run.pk}/"
