"""The API mixes of ``bench/load.py``, run by locust in a process of its own.

Each simulated user signs in with a token of its own (one line each in the file named by
``LOAD_TOKENS_FILE``: the token, then the id of a completed run of that user's) and calls, as
fast as the throttle lets one user, one of three mixes, named by the user class given to
locust:

- ``Floor``: ``GET /api/v1/me/`` only, the least an authenticated call costs;
- ``Reads``: what a researcher's pages and scripts read: the resources, a week of busy slots,
  a week of a robot's availability, their reservations, their runs and their quota;
- ``Day``: a researcher's day, per hundred calls: 80 of those reads, 10 live checks of a
  booking, 4 analyses of a run, 4 filtered run lists and 2 bookings (a booking refused
  because the slot was taken meanwhile, 409, is part of the day, not a failure).

With ``LOAD_EACH_FIRST`` set (the smoke test's tiny round), each ``Day`` user first makes one
call of every kind the day has, so that a round of a hundred calls shows each row for certain
instead of by chance (2 bookings in a hundred: none at all about one short round in sixteen).
"""

from __future__ import annotations

import itertools
import os
import random
from datetime import UTC, datetime, timedelta
from pathlib import Path

from locust import FastHttpUser, constant_throughput, task

USERS = [line.split() for line in Path(os.environ["LOAD_TOKENS_FILE"]).read_text().splitlines()]
NODES = os.environ.get("LOAD_NODES", "node-01").split(",")
EACH_FIRST = bool(os.environ.get("LOAD_EACH_FIRST"))
_NEXT = itertools.count()
_START = datetime.now(UTC).replace(minute=0, second=0, microsecond=0)
WEEK = f"start={_START.isoformat()}&end={(_START + timedelta(days=7)).isoformat()}".replace(
    "+", "%2B"
)
# Bookings and checks ask for half an hour on a fixed node, in the second and third weeks
# ahead: past any notice a policy asks, inside any advance.
_SLOTS = 14 * 48


# At most this many calls a second from one user: under the API's per-user throttle
# (API_THROTTLE_USER, 50/second by default), so that a fast server shows as throughput, not
# as 429s; 50 users may still ask for 1500 a second, far above what the server answers.
CALLS_PER_USER_S = 30


class _Researcher(FastHttpUser):
    abstract = True
    wait_time = constant_throughput(CALLS_PER_USER_S)

    def on_start(self) -> None:
        token, self.run_id = USERS[next(_NEXT) % len(USERS)]
        self.headers = {"Authorization": f"Token {token}", "Accept": "application/json"}

    def _get(self, path: str, name: str) -> None:
        self.client.get(path, headers=self.headers, name=name)

    def _slot(self) -> dict[str, object]:
        start = _START + timedelta(days=7, minutes=30 * random.randrange(_SLOTS))
        return {
            "resources": [random.choice(NODES)],
            "start_at": start.isoformat(),
            "end_at": (start + timedelta(minutes=30)).isoformat(),
        }


class Floor(_Researcher):
    @task
    def me(self) -> None:
        self._get("/api/v1/me/", "me")


class _ReadTasks(_Researcher):
    abstract = True

    def _resources(self) -> None:
        self._get("/api/v1/resources/", "resources")

    def _busy_week(self) -> None:
        self._get(f"/api/v1/reservations/busy/?{WEEK}", "busy, a week")

    def _availability_week(self) -> None:
        self._get(f"/api/v1/resources/mobile-1/availability/?{WEEK}", "availability, a week")

    def _reservations(self) -> None:
        self._get("/api/v1/reservations/", "own reservations")

    def _runs(self) -> None:
        self._get("/api/v1/runs/", "own runs")

    def _quota(self) -> None:
        self._get("/api/v1/quota/", "quota")


class Reads(_ReadTasks):
    @task(1)
    def resources(self) -> None:
        self._resources()

    @task(2)
    def busy_week(self) -> None:
        self._busy_week()

    @task(2)
    def availability_week(self) -> None:
        self._availability_week()

    @task(2)
    def reservations(self) -> None:
        self._reservations()

    @task(2)
    def runs(self) -> None:
        self._runs()

    @task(1)
    def quota(self) -> None:
        self._quota()


class Day(_ReadTasks):
    """Per hundred calls: the reads in the read mix's proportions (80), then the rest."""

    def on_start(self) -> None:
        super().on_start()
        if EACH_FIRST:
            # The quick calls first: a booking took 3.5 s on a fresh clone's bench server
            # (docs/reliability.md, ninth session), and five of them first left the round's
            # CSV empty.
            for call in (self.check, self.analysis, self.filtered_runs, self.book):
                call()

    @task(8)
    def resources(self) -> None:
        self._resources()

    @task(16)
    def busy_week(self) -> None:
        self._busy_week()

    @task(16)
    def availability_week(self) -> None:
        self._availability_week()

    @task(16)
    def reservations(self) -> None:
        self._reservations()

    @task(16)
    def runs(self) -> None:
        self._runs()

    @task(8)
    def quota(self) -> None:
        self._quota()

    @task(10)
    def check(self) -> None:
        self.client.post(
            "/api/v1/reservations/check/", json=self._slot(), headers=self.headers,
            name="live check",
        )  # fmt: skip

    @task(4)
    def analysis(self) -> None:
        self._get(f"/api/v1/runs/{self.run_id}/analysis/", "run analysis")

    @task(4)
    def filtered_runs(self) -> None:
        self._get("/api/v1/runs/?state=completed&resource=mobile-1", "runs, filtered")

    @task(2)
    def book(self) -> None:
        with self.client.post(
            "/api/v1/reservations/", json=self._slot(), headers=self.headers,
            name="booking", catch_response=True,
        ) as answer:  # fmt: skip
            if answer.status_code in (201, 409):
                answer.success()  # taken meanwhile: the calendar's answer, not a failure
            else:
                answer.failure(f"{answer.status_code}: {answer.text[:300]}")
