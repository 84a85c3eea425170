"""The calendar's events, the iCalendar feeds, the approvals queue and the usage report."""

from __future__ import annotations

import csv
import io
from datetime import timedelta

import pytest
from django.contrib.auth.models import Group
from django.utils import timezone
from icalendar import Calendar

from bookings.calendar import calendar_feed_renew
from bookings.services import blackout_create, reservation_create
from tests.conftest import sign_in_with_second_factor
from tests.factories import FixedResourceFactory

pytestmark = pytest.mark.django_db


@pytest.fixture
def week(owner, other, admin_user):
    node = FixedResourceFactory(name="node-11")
    start = timezone.now().replace(microsecond=0) + timedelta(days=1)
    mine = reservation_create(
        owner=owner,
        resource=node,
        start_at=start,
        end_at=start + timedelta(hours=1),
        title="alice's antenna test",
    )
    theirs = reservation_create(
        owner=other,
        resource=node,
        start_at=start + timedelta(hours=2),
        end_at=start + timedelta(hours=3),
        title="bob's secret",
    )
    blackout, _ = blackout_create(
        by=admin_user,
        start_at=start + timedelta(hours=5),
        end_at=start + timedelta(hours=6),
        reason="mast repair",
        resources=[node],
    )
    return {"node": node, "start": start, "mine": mine, "theirs": theirs, "blackout": blackout}


def _events(client, week, **extra):
    params = {
        "start": (week["start"] - timedelta(days=1)).isoformat(),
        "end": (week["start"] + timedelta(days=2)).isoformat(),
        **extra,
    }
    response = client.get("/calendar/events.json", params)
    assert response.status_code == 200
    return response.json()


def test_the_calendar_shows_own_bookings_others_as_busy_and_maintenance(client, owner, week):
    client.force_login(owner)
    events = {e["extendedProps"]["kind"]: e for e in _events(client, week)}
    assert set(events) == {"own", "busy", "blackout"}
    assert "alice's antenna test" in events["own"]["title"]
    assert events["own"]["editable"] is True
    assert events["busy"]["title"] == "Busy [node-11]"
    assert "secret" not in str(events["busy"])
    assert events["blackout"]["display"] == "background"


def test_admins_see_every_booking_in_full(client, admin_user, week):
    # Signed in without the second factor, an admin is the plain user it also is.
    client.force_login(admin_user)
    titles = [e["title"] for e in _events(client, week)]
    assert "Busy [node-11]" in titles
    assert not any("secret" in t for t in titles)
    sign_in_with_second_factor(client, admin_user)
    titles = [e["title"] for e in _events(client, week)]
    assert any("bob: bob's secret" in t for t in titles)


def test_the_calendar_filters_by_resource_and_rejects_bad_ranges(client, owner, week):
    client.force_login(owner)
    FixedResourceFactory(name="node-12")
    assert _events(client, week, resource="node-12") == []
    assert client.get("/calendar/events.json", {"start": "x", "end": "y"}).status_code == 400
    assert client.get("/calendar/events.json").status_code == 400


def test_the_personal_feed_holds_exactly_my_bookings(client, owner, week):
    token = calendar_feed_renew(user=owner)
    response = client.get(f"/calendar/feed/{token}.ics")  # no login: the token is the key
    assert response.status_code == 200
    assert response["Content-Type"].startswith("text/calendar")
    calendar = Calendar.from_ical(response.content)
    events = calendar.walk("VEVENT")
    assert [str(e["summary"]) for e in events] == ["alice's antenna test [node-11]"]
    assert events[0].decoded("dtstart") == week["mine"].start_at
    assert events[0].decoded("dtend") == week["mine"].end_at
    assert str(events[0]["uid"]) == f"reservation-{week['mine'].pk}@amazing-testbed"


def test_the_resource_feed_shows_others_as_busy_and_maintenance(client, owner, week):
    token = calendar_feed_renew(user=owner)
    response = client.get(f"/calendar/feed/{token}/node-11.ics")
    events = Calendar.from_ical(response.content).walk("VEVENT")
    assert sorted(str(e["summary"]) for e in events) == [
        "Busy [node-11]",
        "Maintenance: mast repair [node-11]",
        "alice's antenna test [node-11]",
    ]


def test_renewing_the_feed_revokes_the_old_address(client, owner, week):
    client.force_login(owner)
    first = client.get("/calendar/feeds/").context["personal"]
    assert client.get("/calendar/feeds/").context.get("personal") is None  # shown once
    renewed = client.post("/calendar/feeds/").context["personal"]
    assert renewed != first
    client.logout()
    assert client.get(first).status_code == 404
    assert client.get(renewed).status_code == 200


def test_the_approvals_queue_is_for_admins(client, owner, admin_user):
    node = FixedResourceFactory(requires_approval=True)
    start = timezone.now() + timedelta(days=1)
    pending = reservation_create(
        owner=owner, resource=node, start_at=start, end_at=start + timedelta(hours=1)
    )
    client.force_login(owner)
    assert client.get("/approvals/").status_code == 403
    sign_in_with_second_factor(client, admin_user)
    assert f'data-reservation="{pending.pk}"' in client.get("/approvals/").content.decode()
    refused = client.post(
        "/approvals/", {"reservation": pending.pk, "decision": "reject"}, follow=True
    )
    assert "Say why the request is rejected" in refused.content.decode()
    client.post("/approvals/", {"reservation": pending.pk, "decision": "approve"})
    pending.refresh_from_db()
    assert pending.state == "confirmed"


def test_the_usage_report_sums_clipped_hours_and_exports_csv(client, owner, other, admin_user):
    students = Group.objects.create(name="students")
    other.groups.add(students)
    a, b = FixedResourceFactory(name="node-01"), FixedResourceFactory(name="node-02")
    day = timezone.localdate() + timedelta(days=2)
    start = timezone.make_aware(
        timezone.datetime.combine(day, timezone.datetime.min.time())
    ) + timedelta(hours=9)
    reservation_create(
        owner=owner, resources=[a, b], start_at=start, end_at=start + timedelta(hours=2)
    )
    reservation_create(
        owner=other,
        resource=a,
        start_at=start + timedelta(hours=3),
        end_at=start + timedelta(hours=4),
    )
    sign_in_with_second_factor(client, admin_user)
    params = {"from": day.isoformat(), "to": day.isoformat()}
    page = client.get("/usage/", {**params, "by": "user"})
    assert page.status_code == 200
    rows = list(
        csv.reader(
            io.StringIO(
                client.get("/usage/", {**params, "by": "user", "format": "csv"}).content.decode()
            )
        )
    )
    assert rows == [["user", "hours", "reservations"], ["alice", "4.0", "1"], ["bob", "1.0", "1"]]
    rows = list(
        csv.reader(
            io.StringIO(
                client.get(
                    "/usage/", {**params, "by": "resource", "format": "csv"}
                ).content.decode()
            )
        )
    )
    assert rows[1:] == [["node-01", "3.0", "2"], ["node-02", "2.0", "1"]]
    rows = list(
        csv.reader(
            io.StringIO(
                client.get("/usage/", {**params, "by": "group", "format": "csv"}).content.decode()
            )
        )
    )
    assert rows[1:] == [["(no group)", "4.0", "1"], ["students", "1.0", "1"]]
    # The day before holds nothing.
    before = (day - timedelta(days=1)).isoformat()
    assert (
        "No bookings in this period"
        in client.get("/usage/", {"from": before, "to": before}).content.decode()
    )
    assert client.get("/usage/", {"from": "garbage"}).status_code == 400
    client.force_login(owner)
    assert client.get("/usage/").status_code == 403


def test_the_booking_pages_show_the_remaining_quota(client, owner):
    from bookings.models import QuotaPolicy

    QuotaPolicy.objects.create(name="Weekly robot time", user=owner, period="week", max_hours=4)
    client.force_login(owner)
    for path in ("/book/", "/calendar/"):
        page = client.get(path).content.decode()
        assert "Weekly robot time" in page, path
        assert "4.0 of 4.0 h left this week" in page, path
