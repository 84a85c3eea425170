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
    assert round_.exact, report
    assert round_.samples >= 50  # 3 s at 20 Hz
    assert 0 < round_.lag_p95_s < 30
    assert "| 1 |" in report
