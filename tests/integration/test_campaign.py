"""Two researchers' campaigns through the queue to the end, with real processes: the web
server, Celery's workers and beat, the agent and its simulated robot.

An admin pauses the queue, two researchers each submit a sweep of 2 velocities by 2 directions
by 2 repeats through the API, the admin resumes it: one allocator pass books the sixteen runs
back to back in fair-share order, the robot drives them, the workers collect them, and each
campaign is done. The booking order is checked against the rule worked out here, and the
results table against the statistics computed here from the stored samples.
"""

from __future__ import annotations

import statistics
import time
from datetime import timedelta
from typing import Any

import pytest
import requests
from django.conf import settings
from django.utils import timezone

from core.events.models import Event
from portal.queue.models import Campaign, QueueRequest
from portal.runs.analysis import signed
from portal.runs.models import Run, Sample
from portal.runs.states import RUN_END_STATES, RunState
from tests.factories import MobileResourceFactory, UserFactory, api_token
from tests.integration.stack import running_stack

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

PROGRAM_S = 1.5
# Each run's booking: its program rounded up to this (QUEUE_SLOT_S), so sixteen take 80 s.
# The room after the program is for a busy machine: a run its agent starts late must still
# end inside its booking (seen: a 3 s slot, one run of sixteen failed beside a busy suite).
SLOT_S = 5
QUEUE_ENV = {
    "QUEUE_SLOT_S": str(SLOT_S),
    "QUEUE_LEAD_S": "6",  # the first run staged on the agent before it starts
    "QUEUE_PASS_INTERVAL_S": "2",
}
RUNS = 16
# Sixteen runs of 5 s and their collection; the bound only ends a hang.
DONE_WITHIN_S = 300.0


@pytest.fixture
def queue_stack(tmp_path):
    with running_stack(
        tmp_path / "var", broker_url=settings.CELERY_BROKER_URL, extra_env=QUEUE_ENV
    ) as running:
        yield running


def _sweep(title: str) -> dict[str, Any]:
    now = timezone.now()
    return {
        "title": title,
        "robot": "mobile-1",
        "parameters": {
            "velocity_mps": [0.3, 0.6],
            "direction": ["cw", "ccw"],
            "duration_s": PROGRAM_S,
        },
        "repeats": 2,
        "earliest_at": now.isoformat(),
        "latest_end_at": (now + timedelta(hours=1)).isoformat(),
    }


def _post(web: str, path: str, token: str, body: Any = None) -> dict[str, Any]:
    answer = requests.post(
        f"{web}{path}", json=body, headers={"Authorization": f"Token {token}"}, timeout=30
    )
    assert answer.status_code in (200, 201), answer.text
    result: dict[str, Any] = answer.json()
    return result


def _fair_share_order(campaigns: list[Campaign]) -> list[int]:
    """The rule, worked out here: each next slot to whoever has the least robot time booked
    (all of it within the window), then to whoever asked first; each person's runs in the
    order their campaign listed them."""
    used = {c.owner_id: 0 for c in campaigns}
    waiting = {c.owner_id: list(c.requests.order_by("submitted_at", "pk")) for c in campaigns}
    order = []
    while any(waiting.values()):
        who = min(
            (o for o in waiting if waiting[o]),
            key=lambda o: (used[o], waiting[o][0].submitted_at, waiting[o][0].pk),
        )
        request = waiting[who].pop(0)
        order.append(request.pk)
        used[who] += request.duration_s
    return order


def _wait_for_runs(deadline_s: float) -> list[Run]:
    deadline = time.monotonic() + deadline_s
    states: dict[int, str] = {}
    while time.monotonic() < deadline:
        runs = list(Run.objects.filter(reservation__queue_request__campaign__isnull=False))
        states = {run.pk: run.state for run in runs}
        if len(runs) == RUNS and all(state in RUN_END_STATES for state in states.values()):
            return runs
        time.sleep(1.0)
    raise AssertionError(f"not every run ended in {deadline_s:.0f} s: {states}")


def _from_samples(campaign: Campaign) -> dict[tuple[float, str], tuple[float, float]]:
    """Per (velocity, direction): the mean over the repeats of each run's mean measured
    velocity (signed) in its segment, and the repeats' sample sd, from the stored samples."""
    means: dict[tuple[float, str], list[float]] = {}
    for request in campaign.requests.select_related("reservation__run"):
        assert request.reservation is not None
        assert request.parameters is not None
        samples = Sample.objects.filter(run=request.reservation.run, segment=0)
        measured = [signed(s.velocity_mps, s.direction) for s in samples]
        assert measured, f"run {request.reservation.run.pk} stored no sample in its segment"
        key = (request.parameters["velocity_mps"], request.parameters["direction"])
        means.setdefault(key, []).append(statistics.fmean(measured))
    return {key: (statistics.fmean(v), statistics.stdev(v)) for key, v in means.items()}


@pytest.mark.timeout(DONE_WITHIN_S + 180)
def test_two_campaigns_run_to_the_end_in_fair_share_order_with_the_stored_samples_numbers(
    queue_stack,
):
    web = queue_stack["web"]
    MobileResourceFactory(agent_url=queue_stack["agent_url"])
    admin = api_token(UserFactory(username="ada", is_staff=True, is_superuser=True))
    tokens = [api_token(UserFactory(username=name)) for name in ("ines", "joao")]

    _post(web, "/api/v1/queue/pause/", admin, {"reason": "two campaigns to come"})
    made = [_post(web, "/api/v1/campaigns/", t, _sweep(f"sweep {n}")) for n, t in enumerate(tokens)]
    assert all(m["progress"]["queue"] == {"waiting": 8} for m in made)
    campaigns = [Campaign.objects.get(pk=m["id"]) for m in made]
    expected = _fair_share_order(campaigns)
    _post(web, "/api/v1/queue/resume/", admin, {"reason": "go"})

    runs = _wait_for_runs(DONE_WITHIN_S)
    assert {run.state for run in runs} == {RunState.COMPLETED}, [
        (r.pk, r.state, r.reason) for r in runs if r.state != RunState.COMPLETED
    ]
    booked = QueueRequest.objects.filter(campaign__in=campaigns).order_by("reservation__start_at")
    assert [r.pk for r in booked] == expected
    # Taking turns: neither researcher waits for the other's whole campaign.
    assert len({r.owner_id for r in booked[:2]}) == 2

    for campaign, token in zip(campaigns, tokens, strict=True):
        answer = requests.get(
            f"{web}/api/v1/campaigns/{campaign.pk}/results/",
            headers={"Authorization": f"Token {token}"},
            timeout=30,
        )
        assert answer.status_code == 200, answer.text
        results = answer.json()
        assert results["completed"] == 8
        computed = _from_samples(campaign)
        assert len(results["groups"]) == len(computed) == 4
        for group in results["groups"]:
            mean, sd = computed[(group["velocity_mps"], group["direction"])]
            assert group["metrics"]["mean_mps"]["n"] == 2
            assert group["metrics"]["mean_mps"]["mean"] == pytest.approx(mean, abs=1e-4)
            assert group["metrics"]["mean_mps"]["sd"] == pytest.approx(sd, abs=1e-4)

    # Each campaign recorded done once, by the handler its last run's end woke.
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        done = list(Event.objects.filter(type="campaign.done").order_by("position"))
        if len(done) == 2:
            break
        time.sleep(0.5)
    assert sorted(e.payload["campaign"] for e in done) == sorted(c.pk for c in campaigns)
    assert all(e.payload["ended"] == {"completed": 8} for e in done)
