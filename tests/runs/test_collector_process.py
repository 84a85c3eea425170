"""``manage.py collect_live`` as its own process: it stops on a signal, however many come."""

from __future__ import annotations

import os
import signal

import pytest
from django.conf import settings

from bench.stack import Proc, python

pytestmark = pytest.mark.django_db(transaction=True)


def test_a_burst_of_sigterms_stops_the_collector(tmp_path):
    """A stop of its process group on top of its supervisor's sends several at once: a signal
    arriving while the handler of the one before runs must still stop it, not hang it."""
    db = settings.DATABASES["default"]
    env = {
        **os.environ,
        "DJANGO_DEBUG": "1",
        "DATABASE_URL": f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}",
        "AMAZING_VAR_DIR": str(tmp_path),
        "PYTHONUNBUFFERED": "1",
    }
    collector = Proc("collector", [python(), "manage.py", "collect_live"], env)
    try:
        collector.wait_for_line(lambda line: "collector ready" in line, 60)
        for _ in range(2000):
            try:
                os.kill(collector.popen.pid, signal.SIGTERM)
            except ProcessLookupError:
                break
        assert collector.popen.wait(timeout=15) == 0, collector.output()
    finally:
        collector.stop(signal.SIGKILL)
