"""The researcher's API mix for ``bench/load.py``, run by locust in a process of its own.

Each simulated user signs in with a token of its own (one line each in the file named by
``LOAD_TOKENS_FILE``) and calls, as fast as the throttle lets one user, what a researcher's
pages and scripts call: the resources, a week of busy slots, a week of a robot's
availability, their reservations, their runs and their quota.
"""

from __future__ import annotations

import itertools
import os
from datetime import UTC, datetime, timedelta
from pathlib import Path

from locust import FastHttpUser, constant_throughput, task

TOKENS = Path(os.environ["LOAD_TOKENS_FILE"]).read_text().split()
_NEXT = itertools.count()
_START = datetime.now(UTC).replace(minute=0, second=0, microsecond=0)
WEEK = f"start={_START.isoformat()}&end={(_START + timedelta(days=7)).isoformat()}".replace(
    "+", "%2B"
)


# At most this many calls a second from one user: under the API's per-user throttle
# (API_THROTTLE_USER, 50/second by default), so that a fast server shows as throughput, not
# as 429s; 50 users may still ask for 1500 a second, far above what the server answers.
CALLS_PER_USER_S = 30


class Researcher(FastHttpUser):
    wait_time = constant_throughput(CALLS_PER_USER_S)

    def on_start(self) -> None:
        token = TOKENS[next(_NEXT) % len(TOKENS)]
        self.headers = {"Authorization": f"Token {token}", "Accept": "application/json"}

    def _get(self, path: str, name: str) -> None:
        self.client.get(path, headers=self.headers, name=name)

    @task(1)
    def resources(self) -> None:
        self._get("/api/v1/resources/", "resources")

    @task(2)
    def busy_week(self) -> None:
        self._get(f"/api/v1/reservations/busy/?{WEEK}", "busy, a week")

    @task(2)
    def availability_week(self) -> None:
        self._get(f"/api/v1/resources/mobile-1/availability/?{WEEK}", "availability, a week")

    @task(2)
    def reservations(self) -> None:
        self._get("/api/v1/reservations/", "own reservations")

    @task(2)
    def runs(self) -> None:
        self._get("/api/v1/runs/", "own runs")

    @task(1)
    def quota(self) -> None:
        self._get("/api/v1/quota/", "quota")
