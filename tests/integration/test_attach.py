"""A booking made through the lease API, given an experiment by its owner, runs: real web
server, Celery worker and beat, agent and simulated robot."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest
import requests

from bookings.choices import BookedVia
from bookings.models import Reservation
from tests.factories import MobileResourceFactory, UserFactory, api_token
from tests.integration.experimenter import lease_robot_session

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]


def _until(what: str, check: Callable[[], Any], timeout_s: float, stack: Any) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"{what} did not happen in {timeout_s:g} s\n{stack.output()}")


def test_a_lease_api_booking_given_an_experiment_runs_it(stack):
    MobileResourceFactory(agent_url=stack.agent_url)
    owner = UserFactory(username="erin")
    web = stack.web
    as_owner = {"Authorization": f"Token {api_token(owner)}"}
    experiment = requests.post(
        f"{web}/api/v1/experiments/",
        json={
            "title": "attached later",
            "segments": [{"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0}],
        },
        headers=as_owner,
        timeout=10,
    )
    assert experiment.status_code == 201, experiment.text
    # Far enough ahead to attach first.
    lease = lease_robot_session(web, "erin", ahead_s=8)
    assert lease.status_code == 200, lease.text
    reservation = Reservation.objects.get(
        public_id=lease.json()["resource_response"]["resource"]["uuid"]
    )
    assert reservation.booked_via == BookedVia.SCHEDULER

    attached = requests.post(
        f"{web}/api/v1/reservations/{reservation.pk}/attach/",
        json={"experiment": experiment.json()["id"]},
        headers=as_owner,
        timeout=20,
    )
    assert attached.status_code == 201, attached.text
    run_id = attached.json()["run"]["id"]
    run = _until(
        "the run's end",
        lambda: (
            (
                r := requests.get(
                    f"{web}/api/v1/runs/{run_id}/", headers=as_owner, timeout=10
                ).json()
            )["state"]
            in ("completed", "failed", "interrupted", "cancelled")
            and r
        ),
        60,
        stack,
    )
    assert run["state"] == "completed", run
    assert run["sample_count"] == stack.agent.get_run(f"run-{run_id}")["sample_count"] > 0
