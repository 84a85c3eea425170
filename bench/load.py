"""The portal under load: the API mixes of ``bench/locustfile.py`` from many users, each with
a token of their own, against the web server as ``docker-compose.yml`` runs it
(``portal/processes.py`` ``web_process``: granian's threads, pooled PostgreSQL connections,
production settings, throttles as configured), with one web process and with one per core.

Three mixes in each round, one after another on the same server: the least an authenticated
call costs (the floor), the researcher's reads, and a researcher's day (reads with live
checks, run analyses, filtered lists and bookings). Their ratios are the figures: the load
generator (locust, headless) runs on the same machine and takes CPU from the server, so each
absolute figure is a floor, shared alike by every row of one run.
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
MIXES = ("Floor", "Reads", "Day")
MIX_NAMES = {"Floor": "floor: `GET /me/`", "Reads": "the read mix", "Day": "a researcher's day"}
DURATION_S = 30.0
# A researcher's calendar: this many bookings each over the coming week, and one completed
# run of a minute at 20 Hz the day before (what the day's mix analyses).
BOOKINGS_PER_USER = 3
RUN_SAMPLES = 1200


def _seed(users: int) -> tuple[list[str], list[str]]:
    """Resources, users with their tokens, bookings and a completed run each; one line per
    user (the token and the run's id) and the fixed nodes' names."""

    from bookings.choices import ResourceKind
    from bookings.models import Reservation, ReservationItem, Resource
    from bookings.services import TestbedSpec, testbed_resources_ensure
    from core.accounts.models import ApiToken, User
    from portal.experiments.models import Experiment
    from portal.runs.models import Run
    from portal.runs.services.collection import samples_ingest
    from portal.runs.states import RunState

    testbed_resources_ensure(TestbedSpec(agent_url="http://127.0.0.1:9"))
    nodes = list(Resource.objects.filter(kind=ResourceKind.FIXED).order_by("name"))
    robot = Resource.objects.filter(kind=ResourceKind.MOBILE).order_by("name")[0]
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
    lines = []
    duration_s = RUN_SAMPLES / 20.0
    segments = [{"velocity_mps": 0.8, "direction": "cw", "duration_s": duration_s}]
    yesterday = base - timedelta(days=1)
    for i, person in enumerate(people):
        start = yesterday + timedelta(minutes=2 * i)
        end = start + timedelta(seconds=duration_s + 30)
        experiment = Experiment.objects.create(owner=person, title="a lap", segments=segments)
        reservation = Reservation.objects.create(owner=person, start_at=start, end_at=end)
        run = Run.objects.create(
            reservation=reservation, resource=robot, experiment=experiment, title="a lap",
            segments=segments, start_at=start, end_at=end, rail_length_m=120.0,
            state=RunState.COMPLETED,
        )  # fmt: skip
        samples_ingest(run=run, samples=_samples(start.timestamp()))
        token = ApiToken.objects.create(user=person, name="bench")[1]
        lines.append(f"{token} {run.pk}")
    return lines, [node.name for node in nodes]


def _samples(t0_s: float) -> list[dict[str, object]]:
    samples = []
    for seq in range(1, RUN_SAMPLES + 1):
        t_s = (seq - 1) / 20.0
        track_m = (0.8 * t_s) % 120.0
        samples.append(
            {
                "seq": seq, "t": t0_s + t_s, "segment": 0, "commanded_velocity_mps": 0.8,
                "velocity_mps": 0.8, "direction": "cw", "battery_v": 60.0, "track_m": track_m,
                "fix_quality": 4, "lat_deg": 40.63, "lon_deg": -8.66, "grid_id": None,
                "lap": int(0.8 * t_s // 120.0),
            }
        )  # fmt: skip
    return samples


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
# process (its URLs, its pool's connections, the booking path's first run) are not what a
# round measures, and a busy machine took its whole round to give them (3 s; then 6 s for a
# day's first bookings). The live check is the booking's own path without the write.
WARM_PATHS = (
    "/api/v1/me/",
    "/api/v1/resources/",
    "/api/v1/reservations/",
    "/api/v1/runs/",
    "/api/v1/quota/",
)


def _warm(port: int, token: str, workers: int, node: str) -> None:
    headers = {"Authorization": f"Token {token}", "Accept": "application/json"}
    start = datetime.now(UTC).replace(minute=0, second=0, microsecond=0) + timedelta(days=8)
    slot = {
        "resources": [node],
        "start_at": start.isoformat(),
        "end_at": (start + timedelta(minutes=30)).isoformat(),
    }
    for _ in range(2 * workers):  # each process, most likely
        for path in WARM_PATHS:
            answer = requests.get(f"http://127.0.0.1:{port}{path}", headers=headers, timeout=60)
            if answer.status_code != 200:
                raise RuntimeError(f"warming {path}: {answer.status_code} {answer.text[:300]}")
        check = requests.post(
            f"http://127.0.0.1:{port}/api/v1/reservations/check/",
            json=slot,
            headers=headers,
            timeout=60,
        )
        if check.status_code != 200:
            raise RuntimeError(f"warming the live check: {check.status_code} {check.text[:300]}")


def _stop(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def _locust(
    port: int, users: int, mix: str, duration_s: float, tokens: Path, nodes: Sequence[str],
    prefix: Path, each_first: bool,
) -> subprocess.CompletedProcess[str]:  # fmt: skip
    env = dict(os.environ, LOAD_TOKENS_FILE=str(tokens), LOAD_NODES=",".join(nodes))
    env.pop("LOAD_EACH_FIRST", None)
    if each_first:
        env["LOAD_EACH_FIRST"] = "1"
    return subprocess.run(
        [
            sys.executable, "-m", "locust", "-f", str(REPO / "bench" / "locustfile.py"),
            "--headless", "--users", str(users), "--spawn-rate", str(users),
            "--run-time", f"{max(1, round(duration_s))}s", "--host", f"http://127.0.0.1:{port}",
            "--csv", str(prefix), "--only-summary", "--loglevel", "WARNING", mix,
        ],
        cwd=REPO, env=env, check=False, capture_output=True, text=True,
        timeout=duration_s + 120,
    )  # fmt: skip


# Rounds tried before "locust made no call" fails the bench, each one duration longer.
EMPTY_ROUND_ATTEMPTS = 3


def _stats(prefix: Path) -> list[dict[str, str]]:
    with open(f"{prefix}_stats.csv", newline="") as f:
        return list(csv.DictReader(f))


def run(
    *,
    database_url: str,
    users: Sequence[int] = USERS,
    workers: Sequence[int] = WORKERS,
    mixes: Sequence[str] = MIXES,
    duration_s: float = DURATION_S,
    each_first: bool = False,
) -> str:
    """One round per (web processes, users, mix); the report's markdown. ``each_first``: every
    user of the day's mix first makes one call of each kind (a smoke's round, too short to
    show each kind by chance)."""
    work = Path(tempfile.mkdtemp(prefix="bench-load-"))
    try:
        tokens_file = work / "tokens"
        lines, nodes = _seed(max(users))
        tokens_file.write_text("\n".join(lines) + "\n")
        from django.db import connections

        connections.close_all()
        rows: list[str] = []
        detail: list[dict[str, str]] = []
        for count in workers:
            port = free_port()
            web = _start_web(database_url, count, port, work / "web.log")
            try:
                _warm(port, lines[0].split()[0], count, nodes[0])
                for n in users:
                    measured: dict[str, dict[str, str]] = {}
                    for mix in mixes:
                        prefix = work / f"w{count}-u{n}-{mix}"
                        for attempt in range(1, EMPTY_ROUND_ATTEMPTS + 1):
                            # A round that measured nothing (a machine too busy for a short
                            # smoke round) is run again, longer, before the bench gives up.
                            round_s = duration_s * attempt
                            locust = _locust(
                                port, n, mix, round_s, tokens_file, nodes, prefix, each_first
                            )
                            stats = _stats(prefix)
                            total = next(s for s in stats if s["Name"] == "Aggregated")
                            if total["Request Count"] != "0":
                                break
                        else:
                            # Nothing measured: say what locust and the web server said.
                            raise RuntimeError(
                                f"locust made no call in {EMPTY_ROUND_ATTEMPTS} rounds of up to "
                                f"{round_s:g} s ({mix}, {n} users, {count} web processes; "
                                f"exit {locust.returncode}):\n{locust.stderr[-3000:]}\n"
                                f"web server:\n{(work / 'web.log').read_text()[-2000:]}"
                            )
                        measured[mix] = total
                        if count == max(workers) and n == min(users) and mix == mixes[-1]:
                            detail = [s for s in stats if s["Name"] != "Aggregated"]
                    rows += _rows(n, count, measured)
            finally:
                _stop(web)
        lines_out = [
            "## Portal under load: the researcher's API mixes",
            "",
            f"locust (headless, {duration_s:g} s a round, after each read was asked twice per "
            "web process) on the same machine, each user with a token of its own calling back "
            "to back, the mixes one after another on the same server: the floor (`GET "
            "/api/v1/me/` only), the read mix (resources, a week of busy slots, a week of "
            "availability, own reservations, own runs, quota — weights 1:2:2:2:2:1) and a "
            "researcher's day (per hundred calls: 80 of those reads, 10 live checks of a "
            "booking, 4 analyses of a run of 1200 samples, 4 filtered run lists, 2 bookings of "
            "half an hour on a fixed node; a booking refused as taken, 409, counts as an "
            "answer). The web server as docker-compose.yml runs it (granian, WEB_THREADS "
            "threads a process, PostgreSQL through the pool, production settings, throttles "
            "as configured). Ratios are to the read mix of the same round.",
            "",
            "| users | web processes | mix | req/s | p50 | p95 | failures | req/s ÷ reads "
            "| p95 ÷ reads |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
            *rows,
        ]
        if detail:
            lines_out += [
                "",
                f"Per call of {MIX_NAMES[mixes[-1]]}, {min(users)} users, {max(workers)} web "
                "processes:",
                "",
                "| call | req/s | p50 | p95 |",
                "| --- | --- | --- | --- |",
                *(
                    f"| {s['Name']} | {float(s['Requests/s']):.0f} | {s['50%']} ms "
                    f"| {s['95%']} ms |"
                    for s in detail
                ),
            ]
        return "\n".join(lines_out)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _rows(users: int, workers: int, measured: dict[str, dict[str, str]]) -> list[str]:
    reads = measured.get("Reads")
    rows = []
    for mix, total in measured.items():
        rate, p95 = float(total["Requests/s"]), float(total["95%"])
        if reads is not None and float(reads["Requests/s"]) and float(reads["95%"]):
            ratios = f"{rate / float(reads['Requests/s']):.2f} | {p95 / float(reads['95%']):.2f}"
        else:
            ratios = "— | —"
        rows.append(
            f"| {users} | {workers} | {MIX_NAMES[mix]} | {rate:.0f} | {total['50%']} ms "
            f"| {total['95%']} ms | {total['Failure Count']} of {total['Request Count']} "
            f"| {ratios} |"
        )
    return rows
