"""A researcher booking the robot over the REST API, as a script would: the tests' one way to
put a run on a running system (``tests/integration/stack.py``)."""

from __future__ import annotations

from datetime import datetime, timedelta
from typing import Any

import requests
from django.contrib.auth.models import Permission
from django.utils import timezone

from bench.stack import Stack
from tests.factories import UserFactory, api_token


def there_and_back(seconds: float, velocity_mps: float = 0.4) -> list[dict[str, Any]]:
    """A program of ``seconds``: half clockwise, half back."""
    half = seconds / 2
    return [
        {"velocity_mps": velocity_mps, "direction": "cw", "duration_s": half},
        {"velocity_mps": velocity_mps, "direction": "ccw", "duration_s": half},
    ]


class Experimenter:
    """A user (made on the test database) with an API token and a session that sends it."""

    def __init__(self, stack: Stack, username: str) -> None:
        self.user = UserFactory(username=username)
        self.stack = stack
        self.session = requests.Session()
        token = api_token(self.user)
        self.session.headers["Authorization"] = f"Token {token}"

    def book(
        self,
        resource: str,
        *,
        ahead_s: float,
        program_s: float,
        slack_s: float = 4.0,
        start: datetime | None = None,
        segments: list[dict[str, Any]] | None = None,
    ) -> requests.Response:
        """Saves an experiment (``segments``, there and back by default) and books ``resource``
        for it from ``start`` (``ahead_s`` from now) for ``program_s`` plus ``slack_s``."""
        web = self.stack.web
        experiment = self.session.post(
            f"{web}/api/v1/experiments/",
            json={
                "title": f"{resource} test run",
                "segments": segments or there_and_back(program_s),
            },
            timeout=10,
        )
        assert experiment.status_code == 201, experiment.text
        start = start or timezone.now() + timedelta(seconds=ahead_s)
        return self.session.post(
            f"{web}/api/v1/reservations/",
            json={
                "resource": resource,
                "experiment": experiment.json()["id"],
                "start_at": start.isoformat(),
                "end_at": (start + timedelta(seconds=program_s + slack_s)).isoformat(),
            },
            timeout=10,
        )

    def run(
        self,
        resource: str,
        *,
        ahead_s: float = 3.0,
        program_s: float = 4.0,
        start: datetime | None = None,
        segments: list[dict[str, Any]] | None = None,
    ) -> int:
        """Books as ``book`` does; the run's id."""
        booking = self.book(
            resource, ahead_s=ahead_s, program_s=program_s, start=start, segments=segments
        )
        assert booking.status_code == 201, booking.text
        return int(booking.json()["run"]["id"])


def all_samples(web: str, run_id: int, headers: dict[str, str]) -> list[dict[str, Any]]:
    """Every sample of the run, page after page, as the API gives them."""
    samples: list[dict[str, Any]] = []
    after = 0
    while True:
        page = requests.get(
            f"{web}/api/v1/runs/{run_id}/samples/",
            params={"after": after, "limit": 1000},
            headers=headers,
            timeout=10,
        ).json()
        if not page["samples"]:
            return samples
        samples += page["samples"]
        after = page["last_seq"]


def lease_robot_session(web: str, owner: str, *, ahead_s: float) -> requests.Response:
    """The testbed's scheduler (an account allowed to lease inbound) leases mobile-1 for
    ``owner`` over the lease API, without a program: 10 s from ``ahead_s`` from now, in whole
    seconds, as the lease vocabulary has them."""
    account = UserFactory(username="testbed-scheduler")
    account.user_permissions.add(Permission.objects.get(codename="lease_inbound"))
    start = (timezone.now() + timedelta(seconds=ahead_s)).replace(microsecond=0)
    return requests.post(
        f"{web}/scheduler/resources/leases",
        json={
            "name": "robot-session",
            "valid_from": start.strftime("%Y-%m-%dT%H:%M:%SZ"),
            "valid_until": (start + timedelta(seconds=10)).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "account_attributes": {"name": owner},
            "components": [{"name": "mobile-1"}],
        },
        headers={"Authorization": f"Token {api_token(account)}"},
        timeout=20,
    )
