"""What one client can make the portal spend is bounded.

- The passes at a position (``?at_m=`` on the run page and ``data.json``, ``pass_at_m`` in the
  API) are found from the run's cached report: a new position computes no report and adds
  nothing to the cache.
- The run page, its ``data.json`` and the downloads count against the API's throttles, in
  the same buckets.
- A user has at most ``DOWNLOADS_IN_FLIGHT_MAX`` downloads in flight; the next is 429 with
  ``Retry-After``.
"""

from __future__ import annotations

import random
from typing import Any

import pytest
from django.core.cache import cache as django_cache

from portal.runs import selectors
from tests.runs.driving import RAIL_M, completed_run

pytestmark = pytest.mark.django_db

# Two minutes of driving, laps both ways: enough crossings of any position.
PROGRAM = [(1.0, "cw", 60.0), (0.8, "ccw", 60.0)]


@pytest.fixture
def run(owner, mobile):
    return completed_run(owner, mobile, PROGRAM)


class _CacheSpy:
    """The cache as the selectors see it, with the keys written to it."""

    def __init__(self) -> None:
        self.keys: list[str] = []

    def get(self, key: str, *args: Any, **kwargs: Any) -> Any:
        return django_cache.get(key, *args, **kwargs)

    def set(self, key: str, *args: Any, **kwargs: Any) -> None:
        self.keys.append(key)
        django_cache.set(key, *args, **kwargs)


def test_random_pass_positions_compute_the_report_once_and_grow_no_cache(run, client, monkeypatch):
    computed: list[float | None] = []
    compute = selectors._run_report_computed

    def counting(run: Any, pass_at_m: float | None, max_points: int) -> Any:
        computed.append(pass_at_m)
        return compute(run, pass_at_m, max_points)

    spy = _CacheSpy()
    monkeypatch.setattr(selectors, "_run_report_computed", counting)
    monkeypatch.setattr(selectors, "cache", spy)
    client.force_login(run.reservation.owner)
    positions = [round(random.uniform(0, RAIL_M), 6) for _ in range(15)]
    for at_m in positions:
        assert client.get(f"/runs/{run.pk}/data.json", {"at_m": at_m}).status_code == 200
        api = client.get(f"/api/v1/runs/{run.pk}/analysis/", {"pass_at_m": at_m})
        assert api.status_code == 200
        assert api.json()["pass_at_m"] == at_m
    assert len(computed) == 1
    assert len({key for key in spy.keys if key.startswith("run-report")}) == 1


@pytest.mark.parametrize("at_m", [25.0, 40.0, 55.5, 65.0])
def test_passes_from_the_cached_report_are_the_computed_ones(run, at_m):
    cached = selectors.run_report(run=run, pass_at_m=at_m)
    afresh = selectors.run_report(run=run, pass_at_m=at_m, cached=False)
    assert cached.analysis.passes
    assert cached.analysis.passes == afresh.analysis.passes
    assert cached.analysis.pass_at_m == at_m


def test_a_position_off_the_rail_is_still_refused(run):
    with pytest.raises(ValueError, match="from 0 up to"):
        selectors.run_report(run=run, pass_at_m=RAIL_M)


def test_the_run_pages_count_against_the_api_throttle(run, client, settings):
    settings.API_THROTTLE_USER = "3/minute"
    client.force_login(run.reservation.owner)
    codes = [
        client.get(f"/runs/{run.pk}/data.json").status_code,
        client.get(f"/api/v1/runs/{run.pk}/").status_code,
        client.get(f"/runs/{run.pk}/").status_code,
    ]
    assert codes == [200, 200, 200]
    for path in ("data.json", "samples.csv", "samples.json", "package.zip"):
        refused = client.get(f"/runs/{run.pk}/{path}")
        assert refused.status_code == 429, path
        assert int(refused["Retry-After"]) >= 1
    assert client.get(f"/api/v1/runs/{run.pk}/").status_code == 429


def test_anonymous_page_requests_count_per_address(run, client, settings):
    settings.API_THROTTLE_ANON = "2/minute"
    codes = [client.get(f"/runs/{run.pk}/data.json").status_code for _ in range(3)]
    assert codes == [302, 302, 429]


def _finish(response: Any) -> None:
    """Reads the download to its end: the test client then closes it, as a server does."""
    b"".join(response.streaming_content)


def test_downloads_past_the_limit_in_flight_get_429(run, client, settings, other):
    settings.DOWNLOADS_IN_FLIGHT_MAX = 2
    client.force_login(run.reservation.owner)
    first = client.get(f"/runs/{run.pk}/samples.csv")
    second = client.get(f"/api/v1/runs/{run.pk}/samples.json")
    assert (first.status_code, second.status_code) == (200, 200)
    for path in (f"/runs/{run.pk}/package.zip", f"/api/v1/runs/{run.pk}/samples.csv"):
        refused = client.get(path)
        assert refused.status_code == 429, path
        assert refused["Retry-After"] == "5"
        assert refused.json()["error"] == "throttled"
    _finish(first)
    third = client.get(f"/runs/{run.pk}/samples.json")
    assert third.status_code == 200
    _finish(second)
    _finish(third)
    after = [client.get(f"/runs/{run.pk}/samples.csv") for _ in range(2)]
    assert [answer.status_code for answer in after] == [200, 200]
    for answer in after:
        _finish(answer)
