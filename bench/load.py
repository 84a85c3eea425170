"""The portal under load: the researcher's API mix (``bench/locustfile.py``) from many users,
each with a token of their own, against the web server as ``docker-compose.yml`` runs it
(``portal/processes.py`` ``web_process``: granian's threads, pooled PostgreSQL connections,
production settings, throttles as configured), with one web process and with one per core.

The load generator (locust, headless) runs on the same machine and takes CPU from the server:
the figures are a floor, and each row of one run shares it alike.
"""

from __future__ import annotations

import csv
import os
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from datetime import UTC, datetime, timedelta
from pathlib import Path

import requests

from bench.stack import free_port

REPO = Path(__file__).resolve().parent.parent
USERS = (50, 200)
WORKERS = (1, os.cpu_count() or 1)
DURATION_S = 30.0
# A researcher's calendar: this many bookings each over the coming week.
BOOKINGS_PER_USER = 3


def _seed(users: int) -> list[str]:
    """Resources, users with their tokens and bookings, runs; the tokens."""

    from bookings.models import Reservation, ReservationItem, Resource
    from bookings.services import TestbedSpec, testbed_resources_ensure
    from core.accounts.models import ApiToken, User

    testbed_resources_ensure(TestbedSpec(agent_url="http://127.0.0.1:9"))
    nodes = list(Resource.objects.filter(kind="fixed").order_by("name"))
    people = User.objects.bulk_create(User(username=f"researcher{i}") for i in range(users))
    base = datetime.now(UTC).replace(minute=0, second=0, microsecond=0) + timedelta(hours=1)
    bookings = []
    for i, person in enumerate(people):
        for k in range(BOOKINGS_PER_USER):
            start = base + timedelta(hours=i * BOOKINGS_PER_USER + k)
            bookings.append(
                (
                    Reservation(owner=person, start_at=start, end_at=start + timedelta(hours=1)),
                    nodes[(i + k) % len(nodes)],
                )
            )
    Reservation.objects.bulk_create([r for r, _ in bookings])
    ReservationItem.objects.bulk_create(
        ReservationItem(reservation=r, resource=n, start_at=r.start_at, end_at=r.end_at)
        for r, n in bookings
    )
    return [ApiToken.objects.create(user=person, name="bench")[1] for person in people]


def _start_web(database_url: str, workers: int, port: int, log: Path) -> subprocess.Popen[bytes]:
    from portal.processes import web_process

    spec = web_process(python=sys.executable, port=port, access_log=False)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("DJANGO_", "API_THROTTLE_"))}
    env.update(
        {
            "DJANGO_DEBUG": "0",
            # Plain HTTP on loopback, as inside a deployment behind its TLS proxy.
            "DJANGO_SSL_REDIRECT": "0",
            "DJANGO_SECRET_KEY": secrets.token_urlsafe(50),
            "DJANGO_ALLOWED_HOSTS": "127.0.0.1",
            "AGENT_TOKEN": secrets.token_urlsafe(24),
            "DATABASE_URL": database_url,
            "WEB_WORKERS": str(workers),
            "LOG_LEVEL": "WARNING",
        }
    )
    with log.open("ab") as out:
        process = subprocess.Popen(
            list(spec.argv), cwd=REPO, env=env, stdout=out, stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            if requests.get(f"http://127.0.0.1:{port}/healthz", timeout=2).status_code == 200:
                return process
        except requests.RequestException:
            pass
        if process.poll() is not None:
            break
        time.sleep(0.3)
    _stop(process)
    raise RuntimeError(f"the web server did not start: {log.read_text()[-2000:]}")


# What each round calls (bench/locustfile.py), asked once before it: the first answers of a
# process (its URLs, its pool's connections) are not what a round measures, and a busy machine
# took its whole 3 s round to give them.
WARM_PATHS = ("/api/v1/resources/", "/api/v1/reservations/", "/api/v1/runs/", "/api/v1/quota/")


def _warm(port: int, token: str, workers: int) -> None:
    headers = {"Authorization": f"Token {token}", "Accept": "application/json"}
    for _ in range(2 * workers):  # each process, most likely
        for path in WARM_PATHS:
            answer = requests.get(f"http://127.0.0.1:{port}{path}", headers=headers, timeout=60)
            if answer.status_code != 200:
                raise RuntimeError(f"warming {path}: {answer.status_code} {answer.text[:300]}")


def _stop(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def _locust(
    port: int, users: int, duration_s: float, tokens: Path, prefix: Path
) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, LOAD_TOKENS_FILE=str(tokens))
    return subprocess.run(
        [
            sys.executable, "-m", "locust", "-f", str(REPO / "bench" / "locustfile.py"),
            "--headless", "--users", str(users), "--spawn-rate", str(users),
            "--run-time", f"{max(1, round(duration_s))}s", "--host", f"http://127.0.0.1:{port}",
            "--csv", str(prefix), "--only-summary", "--loglevel", "WARNING",
        ],
        cwd=REPO, env=env, check=False, capture_output=True, text=True,
        timeout=duration_s + 120,
    )  # fmt: skip


def _stats(prefix: Path) -> list[dict[str, str]]:
    with open(f"{prefix}_stats.csv", newline="") as f:
        return list(csv.DictReader(f))


def run(
    *,
    database_url: str,
    users: Sequence[int] = USERS,
    workers: Sequence[int] = WORKERS,
    duration_s: float = DURATION_S,
) -> str:
    """One round per (users, web processes); the report's markdown."""
    work = Path(tempfile.mkdtemp(prefix="bench-load-"))
    try:
        tokens_file = work / "tokens"
        tokens = _seed(max(users))
        tokens_file.write_text("\n".join(tokens) + "\n")
        from django.db import connections

        connections.close_all()
        rows: list[str] = []
        detail: list[dict[str, str]] = []
        for count in workers:
            port = free_port()
            web = _start_web(database_url, count, port, work / "web.log")
            try:
                _warm(port, tokens[0], count)
                for n in users:
                    prefix = work / f"w{count}-u{n}"
                    locust = _locust(port, n, duration_s, tokens_file, prefix)
                    stats = _stats(prefix)
                    total = next(s for s in stats if s["Name"] == "Aggregated")
                    if total["Request Count"] == "0":
                        # Nothing measured: say what locust and the web server said instead.
                        raise RuntimeError(
                            f"locust made no call in {duration_s:g} s ({n} users, {count} web "
                            f"processes; exit {locust.returncode}):\n{locust.stderr[-3000:]}\n"
                            f"web server:\n{(work / 'web.log').read_text()[-2000:]}"
                        )
                    rows.append(
                        f"| {n} | {count} | {float(total['Requests/s']):.0f} "
                        f"| {total['50%']} ms | {total['95%']} ms "
                        f"| {total['Failure Count']} of {total['Request Count']} |"
                    )
                    if count == max(workers) and n == min(users):
                        detail = [s for s in stats if s["Name"] != "Aggregated"]
            finally:
                _stop(web)
        lines = [
            "## Portal under load: the researcher's API mix",
            "",
            f"locust (headless, {duration_s:g} s a round, after each path was asked twice per "
            "web process) on the same machine, each user with "
            "a token of its own calling back to back (resources, a week of busy slots, a week "
            "of availability, own reservations, own runs, quota — weights 1:2:2:2:2:1); the "
            "web server as docker-compose.yml runs it (granian, WEB_THREADS threads "
            "a process, PostgreSQL through the pool, production settings, throttles as "
            "configured).",
            "",
            "| users | web processes | req/s | p50 | p95 | failures |",
            "| --- | --- | --- | --- | --- | --- |",
            *rows,
        ]
        if detail:
            lines += [
                "",
                f"Per call, {min(users)} users, {max(workers)} web processes:",
                "",
                "| call | req/s | p50 | p95 |",
                "| --- | --- | --- | --- |",
                *(
                    f"| {s['Name']} | {float(s['Requests/s']):.0f} | {s['50%']} ms "
                    f"| {s['95%']} ms |"
                    for s in detail
                ),
            ]
        return "\n".join(lines)
    finally:
        shutil.rmtree(work, ignore_errors=True)
