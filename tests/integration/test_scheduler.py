"""The scheduler integration with real processes: web, worker, beat, agent, stand-in broker."""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from datetime import timedelta
from typing import Any

import pytest
import requests
from django.utils import timezone

from bookings.models import Reservation, SchedulerLink
from bookings.notifications import reservation_message
from tests.factories import FixedResourceFactory, MobileResourceFactory, UserFactory, api_token

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]


def _until(what: str, check: Callable[[], Any], timeout_s: float, stack: dict) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.2)
    logs = "\n".join(p.output() for p in stack["procs"])
    raise AssertionError(f"{what} did not happen in {timeout_s:g} s\n{logs}")


def _broker_leases(stack: dict) -> list[dict]:
    answer = requests.get(
        f"{stack['standin']}/resources/leases",
        params={"status": "pending,accepted,active,past,cancelled"},
        timeout=10,
    )
    body = answer.json()
    if answer.status_code == 404:
        return []
    return body["resource_response"]["resources"]


def _live(stack: dict) -> list[dict]:
    return [x for x in _broker_leases(stack) if x["status"] in ("accepted", "active")]


@pytest.fixture
def world(stack_with_scheduler):
    stack = stack_with_scheduler
    MobileResourceFactory(agent_url=stack["agent_url"])
    for i in range(1, 7):
        FixedResourceFactory(name=f"node-{i:02d}")
    user = UserFactory(username="erin")
    headers = {"Authorization": f"Token {api_token(user)}"}
    return stack, user, headers


def test_a_booking_of_the_robot_and_four_nodes_holds_one_lease_and_its_run_completes(world):
    stack, _, headers = world
    web = stack["web"]
    segments = [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0}]
    experiment = requests.post(
        f"{web}/api/v1/experiments/",
        json={"title": "with the nodes", "segments": segments},
        headers=headers,
        timeout=10,
    ).json()
    start = timezone.now() + timedelta(seconds=4)
    booking = requests.post(
        f"{web}/api/v1/reservations/",
        json={
            "resources": ["mobile-1", "node-01", "node-02", "node-03", "node-04"],
            "experiment": experiment["id"],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(seconds=8)).isoformat(),
        },
        headers=headers,
        timeout=20,
    )
    assert booking.status_code == 201, booking.text
    [lease] = _live(stack)
    assert sorted(c["name"] for c in lease["components"]) == [
        "node-01",
        "node-02",
        "node-03",
        "node-04",
    ]
    reservation = Reservation.objects.get(pk=booking.json()["id"])
    assert lease["uuid"] == reservation.lease_uuid
    run_id = booking.json()["run"]["id"]
    run = _until(
        "the run's end",
        lambda: (
            (r := requests.get(f"{web}/api/v1/runs/{run_id}/", headers=headers, timeout=10).json())[
                "state"
            ]
            in ("completed", "failed", "interrupted")
            and r
        ),
        60,
        stack,
    )
    assert run["state"] == "completed", run
    assert run["sample_count"] == stack["agent"].get_run(f"run-{run_id}")["sample_count"] > 0


def _kill_web_between_lease_and_commit(
    stack: Any, body: dict[str, Any], headers: dict[str, str]
) -> dict[str, Any]:
    """POST ``body`` and kill the web process (SIGKILL) once its lease is on the broker, before
    the portal commits; the orphan lease."""
    # The broker makes the lease, then holds its answer: the portal waits, uncommitted.
    requests.post(f"{stack['standin']}/_standin/faults", json={"answer_delay_s": 8}, timeout=5)
    outcome: dict[str, Any] = {}

    def book() -> None:
        try:
            outcome["response"] = requests.post(
                f"{stack['web']}/api/v1/reservations/", json=body, headers=headers, timeout=30
            )
        except requests.RequestException as exc:
            outcome["error"] = exc

    booking = threading.Thread(target=book)
    booking.start()
    [orphan] = _until("the lease on the broker", lambda: _live(stack), 20, stack)
    stack.kill("web", signal.SIGKILL)
    booking.join(timeout=30)
    assert "error" in outcome  # the client never got an answer
    requests.post(f"{stack['standin']}/_standin/faults", json={"answer_delay_s": 0}, timeout=5)
    assert not Reservation.objects.exists(), (
        list(Reservation.objects.values()),
        outcome,
        "\n".join(p.output() for p in stack["procs"]),
    )
    return orphan


def test_the_web_killed_between_lease_and_commit_leaves_an_orphan_the_sweep_or_a_retry_cancels(
    world,
):
    stack, _, headers = world
    start = timezone.now() + timedelta(hours=3)
    orphan = _kill_web_between_lease_and_commit(
        stack,
        {
            "resources": ["node-05"],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(hours=1)).isoformat(),
        },
        headers,
    )
    # Beat sweeps every second; the killed process's transaction (and its lock) is gone.
    _until("the orphan's cancellation", lambda: not _live(stack), 15, stack)
    [cancelled] = [x for x in _broker_leases(stack) if x["uuid"] == orphan["uuid"]]
    assert cancelled["status"] == "cancelled"
    # The sweep counts what it cancelled after cancelling it (bookings/leases.py): read the
    # count before the next part once the sweep has written it, or a count written late by
    # this sweep looks like a sweep in the next part.
    _until(
        "the sweep's count of the orphan",
        lambda: SchedulerLink.objects.get(pk=1).orphans_cancelled >= 1,
        15,
        stack,
    )

    # Again, the robot and a node with an idempotency key, and no sweep this time: the
    # client's retry with the same key, as soon as a web process answers, clears the orphan
    # of its own first attempt itself and books.
    stack.kill("beat", signal.SIGKILL)
    stack.start("web")
    stack.wait_ready("web")
    swept = SchedulerLink.objects.get(pk=1).orphans_cancelled
    experiment = requests.post(
        f"{stack['web']}/api/v1/experiments/",
        json={
            "title": "retried",
            "segments": [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0}],
        },
        headers=headers,
        timeout=10,
    ).json()
    body = {
        "resources": ["mobile-1", "node-02"],
        "experiment": experiment["id"],
        "start_at": start.isoformat(),
        "end_at": (start + timedelta(minutes=30)).isoformat(),
    }
    keyed = {**headers, "X-Idempotency-Key": "book-once-7f3a"}
    orphan = _kill_web_between_lease_and_commit(stack, body, keyed)
    stack.start("web")
    stack.wait_ready("web")
    retry = requests.post(
        f"{stack['web']}/api/v1/reservations/", json=body, headers=keyed, timeout=30
    )
    assert retry.status_code == 201, (retry.text, stack.output())
    [reservation] = Reservation.objects.all()
    assert reservation.pk == retry.json()["id"]
    [live] = _live(stack)
    assert live["uuid"] == reservation.lease_uuid != orphan["uuid"]
    [cancelled] = [x for x in _broker_leases(stack) if x["uuid"] == orphan["uuid"]]
    assert cancelled["status"] == "cancelled"
    assert SchedulerLink.objects.get(pk=1).orphans_cancelled == swept  # not by a sweep
    replay = requests.post(
        f"{stack['web']}/api/v1/reservations/", json=body, headers=keyed, timeout=30
    )
    assert (replay.status_code, replay.headers.get("Idempotent-Replayed")) == (201, "true")
    assert Reservation.objects.count() == 1


def test_a_lease_made_on_the_broker_blocks_the_node_shows_busy_and_a_late_one_is_flagged(world):
    stack, user, headers = world
    web = stack["web"]
    start = (timezone.now() + timedelta(hours=5)).replace(microsecond=0)
    end = start + timedelta(hours=1)
    theirs = requests.post(
        f"{stack['standin']}/resources/leases",
        json={
            "name": "fit-campaign",
            "valid_from": start.isoformat(),
            "valid_until": end.isoformat(),
            "account_attributes": {"name": "fit"},
            "components": [{"name": "node-06"}],
        },
        timeout=10,
    )
    assert theirs.status_code == 200, theirs.text
    refused = requests.post(
        f"{web}/api/v1/reservations/",
        json={"resources": ["node-06"], "start_at": start.isoformat(), "end_at": end.isoformat()},
        headers=headers,
        timeout=20,
    )
    assert refused.status_code == 409, refused.text
    assert "fit-campaign" in refused.json()["detail"]
    session = requests.Session()
    session.get(f"{web}/accounts/login/", timeout=10)
    user.set_password("pw-for-the-calendar")
    user.save()
    session.post(
        f"{web}/accounts/login/",
        data={
            "login": "erin",
            "password": "pw-for-the-calendar",
            "csrfmiddlewaretoken": session.cookies["csrftoken"],
        },
        headers={"Referer": f"{web}/accounts/login/"},
        timeout=10,
    )

    def lease_titles() -> list[str]:
        events = session.get(
            f"{web}/calendar/events.json",
            params={"start": (start - timedelta(hours=1)).isoformat(), "end": end.isoformat()},
            timeout=10,
        ).json()
        return [e["title"] for e in events if e["extendedProps"]["kind"] == "lease"]

    # The sweep (every second here) keeps the mirror the calendar shows.
    assert _until("the lease on the calendar", lease_titles, 10, stack) == [
        "Leased on the testbed scheduler: fit-campaign [node-06]"
    ]

    # A booking first, then a lease written into the scheduler around its rules.
    later = end + timedelta(hours=1)
    mine = requests.post(
        f"{web}/api/v1/reservations/",
        json={
            "resources": ["node-01"],
            "start_at": later.isoformat(),
            "end_at": (later + timedelta(hours=1)).isoformat(),
        },
        headers=headers,
        timeout=20,
    )
    assert mine.status_code == 201, mine.text
    mail = stack.procs["mail"]
    since = mail.mark()  # the booking's own confirmation is not the mail looked for
    requests.post(
        f"{stack['standin']}/_standin/leases",
        json={
            "name": "sneaky",
            "valid_from": later.isoformat(),
            "valid_until": (later + timedelta(minutes=30)).isoformat(),
            "account_attributes": {"name": "elsewhere"},
            "components": [{"name": "node-01"}],
        },
        timeout=10,
    )
    flagged = _until(
        "the booking's flag",
        lambda: Reservation.objects.get(pk=mine.json()["id"]).conflict,
        15,
        stack,
    )
    assert "“sneaky”" in flagged
    # The owner is told: the mail worker sends the e-mail (the console backend prints it).
    told = mail.wait_for_mail(
        lambda m: m["Subject"].startswith("A lease on the testbed scheduler overlaps"),
        15,
        since=since,
    )
    booked = Reservation.objects.get(pk=mine.json()["id"])
    assert told["Subject"] == reservation_message("lease_conflict", booked)[0]
    assert told["To"] == "erin@example.org"  # the only user: no admin to copy
    assert "there is a problem with your booking of node-01" in told.get_content()
    assert "“sneaky”" in told.get_content()
