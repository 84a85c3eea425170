"""Every benchmark run through at tiny sizes (``bench.__main__.SMOKE``), figures unchecked:
a benchmark the code has moved away from fails the build here instead of at ``make bench``."""

from __future__ import annotations

import importlib

import pytest
from django.conf import settings as django_settings

from bench.__main__ import BENCHMARKS, ON_DATABASE, SMOKE, WHOLE_SYSTEM
from bench.stats import ms, percentile


def _run(name: str, **extra: object) -> str:
    module = importlib.import_module(f"bench.{name}")
    report = getattr(module, "run_rates", module.run)(**SMOKE[name], **extra)
    assert isinstance(report, str)
    return report


def test_every_benchmark_has_a_smoke_size():
    assert set(SMOKE) == set(BENCHMARKS)


@pytest.mark.parametrize("name", [n for n in BENCHMARKS if n not in ON_DATABASE])
def test_a_benchmark_of_the_base_station_runs_through(name):
    assert _run(name).startswith("## ")


@pytest.mark.django_db
@pytest.mark.parametrize("name", [n for n in ON_DATABASE if n not in WHOLE_SYSTEM])
def test_a_benchmark_of_the_portal_runs_through(name, settings):
    # The conftest's settings override is active: what a benchmark sets is undone after it.
    assert settings.API_THROTTLE_USER is None
    assert _run(name).startswith("## ")


@pytest.mark.integration
@pytest.mark.django_db(transaction=True)
def test_the_live_benchmark_runs_through_the_whole_system():
    db = django_settings.DATABASES["default"]
    url = f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}"
    report = _run("live", database_url=url)
    # A bench that saw nothing says so, with the stack's last log lines: shown here.
    assert "nothing to measure" not in report, report
    assert "| SSE event |" in report


@pytest.mark.integration
@pytest.mark.django_db(transaction=True)
def test_the_load_benchmark_runs_through_the_web_server():
    """locust against the web server as compose runs it, on the test database."""
    db = django_settings.DATABASES["default"]
    url = f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}"
    report = _run("load", database_url=url)
    rows = [line for line in report.splitlines() if line.startswith("| 5 | 1 |")]
    assert len(rows) == 3, report  # the floor, the reads and the day
    for row in rows:
        assert "| 0 of " in row, report  # no call failed
        assert "| 0 of 0 |" not in row, report  # and there were calls
    # The smoke's day users call each kind once first (``each_first``), the quick ones first:
    # their rows are there. The booking's may not be: on a fresh clone's bench server a
    # booking took 3.5 s (docs/reliability.md, ninth session), which a short round can end
    # before; its path is the live check's, with the write.
    for kind in ("run analysis", "live check", "runs, filtered"):
        assert f"| {kind} |" in report, report


def test_a_percentile_of_nothing_is_reported_as_nothing_not_an_error():
    assert percentile([], 0.95) is None
    assert ms(percentile([], 0.5)) == "—"
    assert percentile([3.0, 1.0, 2.0], 0.5) == 2.0
    assert ms(percentile([0.010, 0.020], 0.95)) == "20 ms"
