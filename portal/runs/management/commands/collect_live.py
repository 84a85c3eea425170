"""``manage.py collect_live``: the collector process (``portal/runs/collector.py``)."""

from __future__ import annotations

import signal
import types
from typing import Any

from django.core.management.base import BaseCommand

from portal.runs.collector import collector_from_settings


class Command(BaseCommand):
    help = "Follow every staged or running run and store its samples as the agent has them."

    def handle(self, *args: Any, **options: Any) -> None:
        collector = collector_from_settings()

        def stop(signum: int, frame: types.FrameType | None) -> None:
            collector.request_stop()

        signal.signal(signal.SIGTERM, stop)
        signal.signal(signal.SIGINT, stop)
        collector.run()
