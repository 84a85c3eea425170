"""Booking with scheduler-owned nodes against a mobile-only booking, in one run.

A booking of the robot and four fixed nodes asks the testbed's scheduler twice (the leases
over its window, then one lease of the four nodes); the stand-in broker runs as its own
process on 127.0.0.1, so the difference is the cost of those two HTTP round trips and the
mirror's writes, without a real network's latency.
"""

from __future__ import annotations

import io
import re
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import replace
from datetime import timedelta
from typing import Any

from bench.bookings import _interleaved, _ms

CALLS = 60
LISTENING = re.compile(r"listening on (http://127\.0\.0\.1:\d+)")


def _start_standin() -> tuple[subprocess.Popen[str], str, threading.Thread]:
    standin = subprocess.Popen(
        [sys.executable, "-m", "bookings.scheduler.standin", "--host", "127.0.0.1", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert standin.stdout is not None
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        line = standin.stdout.readline()
        match = LISTENING.search(line)
        if match:
            # Keep reading its log so that its pipe never fills up.
            reader = threading.Thread(target=standin.stdout.read, daemon=True)
            reader.start()
            return standin, match.group(1), reader
    standin.kill()
    standin.wait()
    standin.stdout.close()
    raise RuntimeError("the stand-in scheduler did not start")


def run(*, calls: int = CALLS) -> str:
    from django.conf import settings
    from django.test import Client
    from django.utils import timezone

    from bookings.scheduler.config import SchedulerConfig
    from bookings.services import TestbedSpec, testbed_resources_ensure
    from core.accounts.models import ApiToken, User
    from portal.experiments.models import Experiment

    settings.DEBUG = False
    settings.ALLOWED_HOSTS = ["testserver"]
    standin, url, reader = _start_standin()
    try:
        settings.SCHEDULER = replace(SchedulerConfig(base_url=url), read_timeout_s=10.0)
        testbed_resources_ensure(TestbedSpec(agent_url="http://127.0.0.1:1"))
        user = User.objects.create_user("bench-scheduler")
        experiment = Experiment.objects.create(
            owner=user,
            title="one lap",
            segments=[{"velocity_mps": 0.5, "direction": "cw", "duration_s": 60.0}],
        )
        client = Client(
            HTTP_AUTHORIZATION="Token " + ApiToken.objects.create(user=user, name="bench")[1]
        )
        base = timezone.now().replace(microsecond=0) + timedelta(days=1)

        def booking(resources: list[str], slot: int) -> None:
            start = base + timedelta(hours=2 * slot)
            body: dict[str, Any] = {
                "resources": resources,
                "experiment": experiment.pk,
                "start_at": start.isoformat(),
                "end_at": (start + timedelta(hours=1)).isoformat(),
            }
            response = client.post("/api/v1/reservations/", body, content_type="application/json")
            assert response.status_code == 201, response.content

        def mobile_only(i: int) -> None:
            booking(["mobile-1"], 2 * i)

        def with_nodes(i: int) -> None:
            nodes = [f"node-{(4 * i + k) % 24 + 1:02d}" for k in range(4)]
            booking(["mobile-1", *nodes], 2 * i + 1)

        mobile_only(10_000)  # warm up both paths
        with_nodes(10_001)
        mobile_s, nodes_s = _interleaved(mobile_only, with_nodes, calls)
    finally:
        standin.terminate()
        standin.wait(timeout=10)
        reader.join(timeout=10)  # it reads to the end of the log, then the pipe can close
        assert standin.stdout is not None
        standin.stdout.close()
    ratio = statistics.median(nodes_s) / statistics.median(mobile_s)
    out = io.StringIO()
    out.write("## Booking with fixed nodes through the testbed scheduler\n\n")
    out.write(
        f"{calls} bookings of each kind, interleaved, through the whole Django stack with token "
        "authentication (a one-segment experiment on the robot); the stand-in scheduler in its "
        "own process on 127.0.0.1. Median and 95th percentile.\n\n"
    )
    out.write("| booking | time | vs. mobile only |\n| --- | --- | --- |\n")
    out.write(f"| the robot alone | {_ms(mobile_s)} | 1× |\n")
    out.write(
        f"| the robot and 4 scheduler-owned nodes (one lease) | {_ms(nodes_s)} | {ratio:.1f}× |\n"
    )
    return out.getvalue()
