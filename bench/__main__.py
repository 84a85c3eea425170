"""``make bench``: measure the numbers of DESIGN §6 and write them to docs/performance.md.

``python -m bench`` runs every benchmark; ``python -m bench agent`` (or ``telemetry``) only
the ones named. The telemetry benchmark runs on a scratch PostgreSQL database
(``<name>_bench`` next to the one in DATABASE_URL), created afresh and dropped at the end;
the agent benchmark needs no database. ``live`` (sample to browser, SSE against polling)
starts the whole system on such a scratch database and a redis-server of its own. Each
benchmark compares the system with a baseline measured in the same run on the same machine,
so the ratios travel between machines. ``python -m bench --smoke`` runs each at tiny sizes
(the test suite does the same in ``tests/bench``): it checks that they run, nothing more.
"""

from __future__ import annotations

import argparse
import importlib
import os
import platform
import sys
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from bench import sections

REPO = Path(__file__).resolve().parent.parent
REPORT = REPO / "docs" / "performance.md"


def _scratch_database() -> tuple[str, str]:
    url = os.environ.get("DATABASE_URL", "")
    if not url.startswith(("postgres://", "postgresql://")):
        sys.exit("make bench needs DATABASE_URL pointing at PostgreSQL")
    parts = urlsplit(url)
    name = parts.path.lstrip("/") or "amazing"
    # A benchmark run before this one pointed DATABASE_URL at its scratch database already.
    name = name if name.endswith("_bench") else name + "_bench"
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
    # Closing gives pooled connections back to the pool; dropping the database would kill
    # them there, and the next benchmark would borrow a dead one.
    for connection in connections.all():
        if hasattr(connection, "close_pool"):
            connection.close_pool()
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
    sections.write_section(
        REPORT,
        begin=f"<!-- bench:{key} -->",
        end=f"<!-- /bench:{key} -->",
        body=body,
        title="# Performance",
    )


# Every benchmark, in the order ``python -m bench`` runs them.
BENCHMARKS = (
    "telemetry",
    "bookings",
    "measurements",
    "scheduler",
    "agent",
    "stop",
    "timing",
    "live",
    "scale",
    "load",
)
# Those that measure the portal on a scratch database of their own.
ON_DATABASE = ("telemetry", "bookings", "measurements", "scheduler", "live", "scale", "load")
# Those that start the whole system on it: they are handed its address.
WHOLE_SYSTEM = ("live", "scale", "load")
# Sizes small enough to run each benchmark through in seconds, figures meaningless:
# ``python -m bench --smoke`` and the test suite (``tests/bench``) use them, so that a
# benchmark the code has moved away from fails the build instead of rotting.
SMOKE: dict[str, dict[str, Any]] = {
    "telemetry": {"samples": 600, "repeats": 1},
    # 16 bookings a node: the refused overlaps (from the 10th hour on) find one.
    "bookings": {"existing": 24 * 16, "calls": 3},
    "measurements": {"points": 3000, "samples": 600, "repeats": 1},
    "scheduler": {"calls": 2},
    "agent": {"duration_s": 1.0, "idle_s": 1.0, "clients": 2},
    # The agent as it runs only: each further variant starts two more processes for the same
    # path with other flags (a third of the smoke's longest test on a busy machine each).
    "stop": {"stops": 2, "clients": 2, "variants": 1},
    "timing": {"starts": 1, "stops": 2},
    "live": {"program_s": 3.0, "open_streams": 3, "probes": 3},
    "scale": {"robots": [1], "program_s": 3.0},
    # Locust writes its CSV every second and not again when it stops: a round must outlast
    # a few of those writes, or a busy machine's first answers miss the last one (seen: 9
    # calls made, the CSV said none).
    # Each day user first calls each kind once: 2 % bookings in a round of ~140 calls made
    # none about one round in sixteen, and the smoke asks for every kind's row. 8 s: beside a
    # busy suite, no day user's first booking had answered within a 6 s round.
    "load": {"users": [5], "workers": [1], "duration_s": 8.0, "each_first": True},
}


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench")
    parser.add_argument(
        "benchmarks",
        nargs="*",
        help=f"which to run: {', '.join(BENCHMARKS)} (default: all)",
    )
    parser.add_argument("--samples", type=int, default=72_000, help="samples of the long run")
    parser.add_argument(
        "--agent-seconds",
        type=float,
        default=300.0,
        help="length of the agent's load phase (DESIGN §6: five minutes at 50 Hz)",
    )
    parser.add_argument(
        "--robots", type=int, nargs="+", default=[1, 4, 8], help="scale: robot counts"
    )
    parser.add_argument(
        "--program-s", type=float, default=30.0, help="scale: each robot's program length"
    )
    parser.add_argument("--no-report", action="store_true", help="print only")
    parser.add_argument(
        "--smoke", action="store_true", help="tiny sizes: check that each runs through (no report)"
    )
    args = parser.parse_args()
    # Checked here: argparse rejects an empty list against ``choices`` with nargs="*".
    unknown = sorted(set(args.benchmarks) - set(BENCHMARKS))
    if unknown:
        parser.error(f"unknown benchmark {', '.join(unknown)}; choose from {', '.join(BENCHMARKS)}")
    chosen = args.benchmarks or BENCHMARKS
    sizes: dict[str, dict[str, Any]] = {
        "telemetry": {"samples": args.samples},
        "agent": {"duration_s": args.agent_seconds, "idle_s": min(60.0, args.agent_seconds)},
        "scale": {"robots": args.robots, "program_s": args.program_s},
    }
    for name in BENCHMARKS:
        if name in chosen:
            params = SMOKE[name] if args.smoke else sizes.get(name, {})
            run_benchmark(name, params, report=not (args.no_report or args.smoke))


def run_benchmark(name: str, params: dict[str, Any], *, report: bool) -> None:
    """Run one benchmark (``bench/<name>.py``'s ``run``), print its figures and, with
    ``report``, write them into docs/performance.md."""
    module = importlib.import_module(f"bench.{name}")
    # A benchmark with several rounds of one measurement names the function that runs them.
    entry = getattr(module, "run_rates", module.run)
    if name in WHOLE_SYSTEM:
        url, _ = _scratch_database()
        params = {"database_url": url, **params}
    if name in ON_DATABASE:
        _on_scratch_database(name, lambda: _markdown(entry(**params)), report=report)
        return
    stamp = f"Measured {datetime.now(UTC):%Y-%m-%d %H:%M} UTC on {machine()}."
    results = _markdown(entry(**params))
    print(stamp)
    print(results)
    if report:
        write_section(name, f"{results}\n\n{stamp}")
        print(f"written to {REPORT.relative_to(REPO)}")


def _markdown(result: object) -> str:
    """A benchmark's report: its ``run`` returns the markdown, or the markdown and its data."""
    return str(result[0] if isinstance(result, tuple) else result)


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


if __name__ == "__main__":
    main()
