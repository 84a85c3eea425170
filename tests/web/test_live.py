"""The pages' live streams (Server-Sent Events): who may follow what, and that what the
workers publish (a run's state, its samples, a robot's hold, a booking) reaches the stream:
the samples as they are stored, the rest through their events' handler, whose pass the runs
worker makes (``runs_worker_pass`` here)."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from datetime import timedelta
from typing import Any

import pytest
from asgiref.sync import async_to_sync, sync_to_async
from django.test import AsyncClient
from django.utils import timezone

from bookings.services import resource_hold
from core.accounts.staff import has_staff_role
from core.events.dispatch import events_dispatch_all
from portal.processes import RUNS_QUEUE
from portal.runs.measurements import measurement_add, rows_points
from portal.runs.models import Run
from portal.runs.services.collection import samples_ingest
from portal.runs.services.reservations import reservation_create
from portal.runs.services.transitions import run_transition
from portal.runs.states import Cause, RunState
from portal.web.live import KEEPALIVE_S
from tests.conftest import sign_in_with_second_factor
from tests.factories import ExperimentFactory, FixedResourceFactory

# The view reads the database from another thread: the test's rows must be committed.
pytestmark = pytest.mark.django_db(transaction=True)

WAIT_S = 5.0


def _signed_in(user: Any, *, second_factor: bool = True) -> AsyncClient:
    """A client as ``user``; staff in a session that passed its second factor unless
    ``second_factor`` is off. (Signed in before the scenario: the session is saved here.)"""
    client = AsyncClient()
    if user is None:
        return client
    if second_factor and has_staff_role(user):
        return sign_in_with_second_factor(client, user)
    client.force_login(user)
    return client


def _status(user: Any, url: str, *, second_factor: bool = True) -> int:
    client = _signed_in(user, second_factor=second_factor)

    async def scenario() -> int:
        response = await client.get(url)
        if response.streaming:
            await response.streaming_content.aclose()
        return response.status_code

    return async_to_sync(scenario)()


def runs_worker_pass() -> None:
    """What the runs worker does when woken after a commit that wrote events: the live
    pushes' pass (``portal/web/handlers.py``)."""
    done = events_dispatch_all(queue=RUNS_QUEUE)
    assert done["live-pushes"] > 0, done


def _follow(user: Any, url: str, then: Callable[[], Any], count: int) -> list[str]:
    """Open ``url`` as ``user``, do ``then`` (in a thread, as a worker would), and return the
    first ``count`` events after the stream's opening one."""
    client = _signed_in(user)

    async def scenario() -> list[str]:
        response = await client.get(url)
        assert response.status_code == 200
        assert response["Content-Type"] == "text/event-stream"
        assert response["Cache-Control"] == "no-cache"
        chunks = aiter(response.streaming_content)
        opening = (await asyncio.wait_for(anext(chunks), WAIT_S)).decode()
        assert opening.startswith("retry: ")
        assert "event: open" in opening
        await sync_to_async(then)()
        events = []
        try:
            while len(events) < count:
                chunk = (await asyncio.wait_for(anext(chunks), WAIT_S)).decode()
                if not chunk.startswith(":"):
                    events.append(chunk)
        finally:
            await response.streaming_content.aclose()
        return events

    return async_to_sync(scenario)()


@pytest.fixture
def run(owner, mobile) -> Run:
    start = timezone.now() + timedelta(hours=1)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=owner),
    )
    Run.objects.filter(reservation=reservation).update(state=RunState.RUNNING)
    events_dispatch_all(queue=RUNS_QUEUE)  # the booking's pushes, before any stream opens
    return Run.objects.get(reservation=reservation)


def test_a_run_stream_is_for_those_who_may_see_the_run(run, owner, other, admin_user):
    url = f"/live/runs/{run.pk}/"
    assert _status(None, url) == 403
    assert _status(other, url) == 404
    assert _status(owner, url) == 200
    assert _status(admin_user, url, second_factor=False) == 404  # a plain user without it
    assert _status(admin_user, url) == 200


def test_the_run_stream_carries_its_state_changes_and_new_samples(run, owner):
    def collect() -> None:
        samples_ingest(run=run, samples=[_sample(1), _sample(2)])
        run_transition(
            run_id=run.pk,
            to_state=RunState.COLLECTING,
            cause=Cause.DISPATCH,
            from_states=[RunState.RUNNING],
            reason="ended on the base station (completed)",
        )
        runs_worker_pass()

    samples, state = _follow(owner, f"/live/runs/{run.pk}/", collect, 2)
    assert samples.startswith("event: samples\n")
    assert '"last_seq":2' in samples
    assert '"count":2' in samples
    assert state.startswith("event: state\n")
    assert '"state":"collecting"' in state
    assert '"live":true' in state


def test_the_run_stream_tells_of_a_batch_of_measurements(run, owner):
    def measure() -> None:
        t0_s = run.start_at.timestamp()
        points = rows_points([{"t": t0_s + i, "rssi": -50.0 - i} for i in range(3)])
        measurement_add(run=run, by=owner, name="rssi", points=points, via="api")
        runs_worker_pass()

    (pushed,) = _follow(owner, f"/live/runs/{run.pk}/", measure, 1)
    assert pushed.startswith("event: measurements\n")
    assert '"series":"rssi"' in pushed
    assert '"change":"added"' in pushed
    assert '"points":3' in pushed


def test_a_robots_stream_is_for_admins_and_carries_its_hold(owner, admin_user, mobile):
    url = f"/live/robots/{mobile.name}/"
    assert _status(None, url) == 403
    assert _status(owner, url) == 403
    assert _status(admin_user, url, second_factor=False) == 403
    assert _status(admin_user, url) == 200
    assert _status(admin_user, "/live/robots/no-such-robot/") == 404

    def hold() -> None:
        assert resource_hold(resource_id=mobile.pk, reason="battery low: 48.0 V, under 50 V")
        runs_worker_pass()

    [event] = _follow(admin_user, url, hold, 1)
    assert event.startswith("event: hold\n")
    assert '"reason":"battery low: 48.0 V, under 50 V"' in event
    assert '"in_service":false' in event


def test_the_calendar_stream_hears_bookings_made_anywhere(owner, other):
    assert _status(None, "/live/calendar/") == 403
    node = FixedResourceFactory()

    def book() -> None:
        start = timezone.now() + timedelta(days=1)
        reservation_create(
            owner=other,
            resource=node,
            start_at=start,
            end_at=start + timedelta(hours=1),
        )
        runs_worker_pass()

    [event] = _follow(owner, "/live/calendar/", book, 1)
    assert event == 'event: changed\ndata: {"type":"changed"}\n\n'


def test_a_stream_with_the_bus_down_is_refused_at_once(owner, settings):
    settings.REDIS_URL = "redis://127.0.0.1:9/0"
    assert _status(owner, "/live/calendar/") == 503


def test_a_stream_keeps_itself_alive(owner, monkeypatch):
    monkeypatch.setattr("portal.web.live.KEEPALIVE_S", 0.2)
    assert KEEPALIVE_S > 0.2

    async def scenario() -> str:
        client = AsyncClient()
        await client.aforce_login(owner)
        response = await client.get("/live/calendar/")
        chunks = aiter(response.streaming_content)
        await anext(chunks)
        try:
            return (await asyncio.wait_for(anext(chunks), WAIT_S)).decode()
        finally:
            await response.streaming_content.aclose()

    assert async_to_sync(scenario)() == ": keepalive\n\n"


def _sample(seq: int) -> dict[str, Any]:
    return {
        "seq": seq,
        "t": timezone.now().timestamp() + seq * 0.05,
        "segment": 0,
        "commanded_velocity_mps": 0.5,
        "velocity_mps": 0.5,
        "direction": "cw",
        "battery_v": 59.0,
        "track_m": 1.0 + seq * 0.025,
    }


def test_a_wsgi_server_answers_no_stream_and_the_page_polls(client, owner):
    """A stream would hold a WSGI thread for good: 204 tells the browser not to reconnect."""
    client.force_login(owner)
    assert client.get("/live/calendar/").status_code == 204


def _headers(user: Any, url: str, origin: str) -> dict[str, str]:
    """The answer's headers for a stream opened from a page of ``origin``."""

    async def scenario() -> dict[str, str]:
        client = AsyncClient()
        if user is not None:
            await client.aforce_login(user)
        response = await client.get(url, headers={"Origin": origin})
        if response.streaming:
            await response.streaming_content.aclose()
        return dict(response.headers)

    return async_to_sync(scenario)()


def test_pages_of_the_same_host_may_read_a_stream_served_on_another_port(owner):
    # The test client's host is "testserver": its pages are on port 8000, its streams not.
    same_host = _headers(owner, "/live/calendar/", "http://testserver:8000")
    assert same_host["Access-Control-Allow-Origin"] == "http://testserver:8000"
    assert same_host["Access-Control-Allow-Credentials"] == "true"
    assert "Origin" in same_host["Vary"]
    elsewhere = _headers(owner, "/live/calendar/", "http://attacker.example")
    assert "Access-Control-Allow-Origin" not in elsewhere
    refused = _headers(None, "/live/calendar/", "http://testserver:8000")
    assert refused["Access-Control-Allow-Origin"] == "http://testserver:8000"  # 403, readable


def test_a_page_learns_the_streams_port_when_they_have_their_own(client, owner, settings):
    client.force_login(owner)
    settings.LIVE_STREAM_PORT = None
    assert 'name="live-stream-port"' not in client.get("/calendar/").content.decode()
    settings.LIVE_STREAM_PORT = 8001
    page = client.get("/calendar/").content.decode()
    assert '<meta name="live-stream-port" content="8001">' in page
