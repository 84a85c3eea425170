"""Every endpoint against anonymous, owner, other experimenter and admin."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone

from bookings.models import Reservation
from portal.runs.services.reservations import reservation_create
from tests.factories import FixedResourceFactory

pytestmark = pytest.mark.django_db


@pytest.fixture
def booked(owner, mobile, experiment):
    start = timezone.now() + timedelta(hours=2)
    return reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=20),
        experiment=experiment,
    )


READ_URLS = [
    "/api/v1/experiments/{experiment}/",
    "/api/v1/reservations/{reservation}/",
    "/api/v1/runs/{run}/",
    "/api/v1/runs/{run}/samples/",
    "/api/v1/runs/{run}/samples.csv",
]


def _urls(booked):
    ids = {"experiment": booked.run.experiment_id, "reservation": booked.pk, "run": booked.run.pk}
    return [u.format(**ids) for u in READ_URLS]


@pytest.mark.parametrize("who", ["anonymous", "owner", "other", "admin"])
def test_read_endpoints_by_role(who, booked, owner, other, admin_user, client_for):
    user = {"anonymous": None, "owner": owner, "other": other, "admin": admin_user}[who]
    expected = {"anonymous": 401, "owner": 200, "other": 404, "admin": 200}[who]
    client = client_for(user)
    for url in _urls(booked):
        response = client.get(url)
        assert response.status_code == expected, url
        if user is None:
            assert response["WWW-Authenticate"] == "Token", url


@pytest.mark.parametrize("who", ["anonymous", "owner", "other", "admin"])
def test_list_endpoints_show_only_what_the_user_may_see(
    who, booked, owner, other, admin_user, client_for
):
    user = {"anonymous": None, "owner": owner, "other": other, "admin": admin_user}[who]
    client = client_for(user)
    for url in ("/api/v1/experiments/", "/api/v1/reservations/", "/api/v1/runs/"):
        response = client.get(url)
        if user is None:
            assert response.status_code == 401
            continue
        assert response.status_code == 200
        page = response.json()
        assert len(page["results"]) == page["count"] == (0 if who == "other" else 1), url
    resources = client.get("/api/v1/resources/")
    assert resources.status_code == (401 if user is None else 200)


@pytest.mark.parametrize("who", ["anonymous", "other", "owner", "admin"])
def test_cancel_by_role(who, booked, owner, other, admin_user, client_for):
    user = {"anonymous": None, "owner": owner, "other": other, "admin": admin_user}[who]
    response = client_for(user).delete(
        f"/api/v1/reservations/{booked.pk}/", {"reason": "roof inspection"}, format="json"
    )
    assert response.status_code == {"anonymous": 401, "other": 404, "owner": 200, "admin": 200}[who]
    booked.refresh_from_db()
    assert booked.state == ("cancelled" if who in ("owner", "admin") else "confirmed")


def test_booking_someone_elses_experiment_over_the_api_is_not_found(
    other, mobile, experiment, client_for
):
    start = timezone.now() + timedelta(hours=1)
    response = client_for(other).post(
        "/api/v1/reservations/",
        {
            "resource": "mobile-1",
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(minutes=10)).isoformat(),
            "experiment": experiment.pk,
        },
        format="json",
    )
    assert response.status_code == 404


def test_an_overlapping_booking_over_the_api_is_a_409_with_a_message(booked, other, client_for):
    from tests.factories import ExperimentFactory

    theirs = ExperimentFactory(owner=other)
    response = client_for(other).post(
        "/api/v1/reservations/",
        {
            "resource": "mobile-1",
            "start_at": booked.start_at.isoformat(),
            "end_at": booked.end_at.isoformat(),
            "experiment": theirs.pk,
        },
        format="json",
    )
    assert response.status_code == 409
    assert "already booked" in response.json()["detail"]


def test_schema_and_docs_are_served(owner, client_for):
    client = client_for(owner)
    schema = client.get("/api/schema/")
    assert schema.status_code == 200
    assert b"/api/v1/reservations/" in schema.content
    docs = client.get("/api/docs/")
    assert docs.status_code == 200
    assert b"/static/vendor/swagger-ui-dist/swagger-ui-bundle.js" in docs.content


ROLES = ["anonymous", "owner", "other", "admin"]


@pytest.fixture
def world(owner, other, admin_user, booked):
    from bookings.models import QuotaPolicy

    node = FixedResourceFactory(name="node-05", requires_approval=True)
    start = timezone.now() + timedelta(days=2)
    pending = reservation_create(
        owner=owner, resource=node, start_at=start, end_at=start + timedelta(hours=1)
    )
    policy = QuotaPolicy.objects.create(name="p", period="week", max_hours=100)
    return {
        "users": {"anonymous": None, "owner": owner, "other": other, "admin": admin_user},
        "booked": booked,
        "pending": pending,
        "policy": policy,
        "start": start,
    }


def _requests(world):
    start = world["start"] + timedelta(days=1)
    window = {"start": start.isoformat(), "end": (start + timedelta(days=1)).isoformat()}
    slot = {"start_at": start.isoformat(), "end_at": (start + timedelta(hours=1)).isoformat()}
    # The maintenance window goes elsewhere, or it would block the bookings of the table.
    later = start + timedelta(hours=3)
    later_slot = {"start_at": later.isoformat(), "end_at": (later + timedelta(hours=1)).isoformat()}
    booked, pending, policy = world["booked"], world["pending"], world["policy"]
    return [
        # (name, method, url, body, expected status by role)
        ("resources", "get", "/api/v1/resources/", None, (401, 200, 200, 200)),
        (
            "availability",
            "get",
            "/api/v1/resources/node-05/availability/",
            window,
            (401, 200, 200, 200),
        ),
        ("busy", "get", "/api/v1/reservations/busy/", window, (401, 200, 200, 200)),
        ("quota", "get", "/api/v1/quota/", None, (401, 200, 200, 200)),
        (
            "booking check",
            "post",
            "/api/v1/reservations/check/",
            {"resources": ["node-05"], **slot},
            (401, 200, 200, 200),
        ),
        (
            "booking check, deprecated path",
            "post",
            "/api/v1/quota/check/",
            {"resources": ["node-05"], **slot},
            (401, 200, 200, 200),
        ),
        ("blackouts", "get", "/api/v1/blackouts/", None, (401, 200, 200, 200)),
        (
            "blackout create",
            "post",
            "/api/v1/blackouts/",
            {"resources": ["node-05"], "reason": "service", **later_slot},
            (401, 403, 403, 201),
        ),
        ("policies", "get", "/api/v1/quota-policies/", None, (401, 403, 403, 200)),
        (
            "policy create",
            "post",
            "/api/v1/quota-policies/",
            {"name": "q", "max_future": 3},
            (401, 403, 403, 201),
        ),
        (
            "policy change",
            "patch",
            f"/api/v1/quota-policies/{policy.pk}/",
            {"max_hours": 50},
            (401, 403, 403, 200),
        ),
        (
            "decision",
            "post",
            f"/api/v1/reservations/{pending.pk}/decision/",
            {"approve": True},
            (401, 403, 403, 200),
        ),
        (
            "reschedule",
            "patch",
            f"/api/v1/reservations/{booked.pk}/",
            {
                "start_at": booked.start_at.isoformat(),
                "end_at": (booked.end_at + timedelta(minutes=5)).isoformat(),
            },
            (401, 200, 404, 200),
        ),
        (
            "create",
            "post",
            "/api/v1/reservations/",
            {"resource": "node-05", **slot},
            (401, 201, 201, 201),
        ),
    ]


@pytest.mark.parametrize("who", ROLES)
def test_every_booking_endpoint_by_role(who, world, client_for):
    client = client_for(world["users"][who])
    failures = []
    for name, method, url, body, expected in _requests(world):
        kwargs = {"format": "json"} if method != "get" else {}
        response = getattr(client, method)(url, body, **kwargs)
        want = expected[ROLES.index(who)]
        if response.status_code != want:
            failures.append(
                f"{name}: {response.status_code} != {want} ({response.content[:200]!r})"
            )
        if response.status_code == 201 and name == "create":
            # Each role books its own slot; free it for the next role's run of the table.
            Reservation.objects.filter(pk=response.json()["id"]).delete()
    assert not failures, failures
