"""The scale benchmark's smoke: one robot for a few seconds through the real collection path
(agent, worker, collector, beat), every sample stored and announced once."""

from __future__ import annotations

import pytest
from django.conf import settings

from bench import scale

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]


def test_the_scale_bench_collects_one_robot_exactly_once():
    db = settings.DATABASES["default"]
    url = f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}"
    report, [round_] = scale.run(database_url=url, robots=[1], program_s=3.0)
    # Every sample the agent stored was stored once by the portal and announced once. How many
    # the loop recorded in 3 s is its rate, which ``make bench`` measures: a busy machine
    # misses ticks (36 of 60 once, beside the rest of the suite), so only "some" is asserted.
    assert round_.exact, report
    assert round_.samples > 0, report
    assert 0 < round_.lag_p95_s < 30
    assert "| 1 |" in report
