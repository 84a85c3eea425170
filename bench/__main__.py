"""``make bench``: measure the numbers of DESIGN §6 and write them to docs/performance.md.

``python -m bench`` runs every benchmark; ``python -m bench agent`` (or ``telemetry``) only
the ones named. The telemetry benchmark runs on a scratch PostgreSQL database
(``<name>_bench`` next to the one in DATABASE_URL), created afresh and dropped at the end;
the agent benchmark needs no database. ``live`` (sample to browser, SSE against polling)
starts the whole system on such a scratch database and a redis-server of its own. Each
benchmark compares the system with a baseline measured in the same run on the same machine,
so the ratios travel between machines.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

REPO = Path(__file__).resolve().parent.parent
REPORT = REPO / "docs" / "performance.md"


def _scratch_database() -> tuple[str, str]:
    url = os.environ.get("DATABASE_URL", "")
    if not url.startswith(("postgres://", "postgresql://")):
        sys.exit("make bench needs DATABASE_URL pointing at PostgreSQL")
    parts = urlsplit(url)
    name = (parts.path.lstrip("/") or "amazing") + "_bench"
    return urlunsplit(parts._replace(path="/" + name)), name


def _recreate(url: str, name: str) -> None:
    import psycopg

    admin = urlunsplit(urlsplit(url)._replace(path="/postgres"))
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
        conn.execute(f'CREATE DATABASE "{name}"')


def _drop(url: str, name: str) -> None:
    import psycopg
    from django.db import connections

    connections.close_all()
    admin = urlunsplit(urlsplit(url)._replace(path="/postgres"))
    with psycopg.connect(admin, autocommit=True) as conn:
        conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def machine() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, {platform.system()}"


def write_section(key: str, body: str) -> None:
    """Replace (or append) the report section between this benchmark's markers."""
    begin, end = f"<!-- bench:{key} -->", f"<!-- /bench:{key} -->"
    text = REPORT.read_text() if REPORT.exists() else "# Performance\n"
    block = f"{begin}\n{body.rstrip()}\n{end}"
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        text = head + block + rest.split(end, 1)[1]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    REPORT.write_text(text)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench")
    parser.add_argument(
        "benchmarks",
        nargs="*",
        help="which to run: telemetry, bookings, scheduler, agent, timing, live (default: all)",
    )
    parser.add_argument("--samples", type=int, default=72_000, help="samples of the long run")
    parser.add_argument(
        "--agent-seconds", type=float, default=60.0, help="length of the agent's load phase"
    )
    parser.add_argument("--no-report", action="store_true", help="print only")
    args = parser.parse_args()
    known = ["telemetry", "bookings", "scheduler", "agent", "timing", "live"]
    # Checked here: argparse rejects an empty list against ``choices`` with nargs="*".
    unknown = sorted(set(args.benchmarks) - set(known))
    if unknown:
        parser.error(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(known)}")
    which = args.benchmarks or known
    if "telemetry" in which:
        _telemetry(args.samples, report=not args.no_report)
    if "bookings" in which:
        _bookings(report=not args.no_report)
    if "scheduler" in which:
        _scheduler(report=not args.no_report)
    if "agent" in which:
        _agent(args.agent_seconds, report=not args.no_report)
    if "timing" in which:
        _timing(report=not args.no_report)
    if "live" in which:
        _live(report=not args.no_report)


def _on_scratch_database(key: str, run: Callable[[], str], *, report: bool) -> None:
    """Run one portal benchmark on a fresh PostgreSQL database, dropped afterwards."""
    url, name = _scratch_database()
    _recreate(url, name)
    os.environ["DATABASE_URL"] = url
    os.environ.setdefault("DJANGO_SETTINGS_MODULE", "portal.settings")
    os.environ.setdefault("DJANGO_DEBUG", "1")
    # One client calling as fast as it can is not abuse: the throttles still count every
    # call (their cost is measured), but never refuse one.
    os.environ.setdefault("API_THROTTLE_USER", "1000000/second")
    os.environ.setdefault("API_THROTTLE_ANON", "1000000/second")
    import django
    from django.core.management import call_command
    from django.db import connections

    django.setup()
    # A second benchmark in the same process finds Django set up on the previous database.
    connections["default"].close()
    connections["default"].settings_dict["NAME"] = name
    call_command("migrate", verbosity=0)
    stamp = f"Measured {datetime.now(UTC):%Y-%m-%d %H:%M} UTC on {machine()}."
    try:
        results = run()
    finally:
        _drop(url, name)
    print(stamp)
    print(results)
    if report:
        write_section(key, f"{results}\n\n{stamp}")
        print(f"written to {REPORT.relative_to(REPO)}")


def _telemetry(samples: int, *, report: bool) -> None:
    def run() -> str:
        from bench import telemetry

        return telemetry.run(samples=samples)

    _on_scratch_database("telemetry", run, report=report)


def _bookings(*, report: bool) -> None:
    def run() -> str:
        from bench import bookings

        return bookings.run()

    _on_scratch_database("bookings", run, report=report)


def _scheduler(*, report: bool) -> None:
    def run() -> str:
        from bench import scheduler

        return scheduler.run()

    _on_scratch_database("scheduler", run, report=report)


def _agent(seconds: float, *, report: bool) -> None:
    from bench import agent

    stamp = f"Measured {datetime.now(UTC):%Y-%m-%d %H:%M} UTC on {machine()}."
    results = agent.run(duration_s=seconds, idle_s=seconds)
    print(stamp)
    print(results)
    if report:
        write_section("agent", f"{results}\n\n{stamp}")
        print(f"written to {REPORT.relative_to(REPO)}")


def _timing(*, report: bool) -> None:
    from bench import timing

    stamp = f"Measured {datetime.now(UTC):%Y-%m-%d %H:%M} UTC on {machine()}."
    results = timing.run()
    print(stamp)
    print(results)
    if report:
        write_section("timing", f"{results}\n\n{stamp}")
        print(f"written to {REPORT.relative_to(REPO)}")


def _live(*, report: bool) -> None:
    url, _ = _scratch_database()

    def run() -> str:
        from bench import live

        return live.run(database_url=url)

    _on_scratch_database("live", run, report=report)


if __name__ == "__main__":
    main()
