"""The live bus: what one process publishes, another hears — through Redis, or through files
when there is no Redis (``make run``) — and publishing never fails its caller."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from typing import Any

import pytest
from asgiref.sync import async_to_sync, sync_to_async
from django.db import connection

from core import live

WAIT_S = 5.0


@pytest.fixture(params=["redis", "files"])
def bus_settings(request, settings, tmp_path):
    """Each test on both transports: Redis (the test Redis) and files (no Redis)."""
    settings.LIVE_DIR = tmp_path / "live"
    if request.param == "files":
        settings.REDIS_URL = ""
    return request.param


async def _next(events: AsyncIterator[dict[str, Any] | None]) -> dict[str, Any]:
    """The next event, skipping keep-alives; fails after ``WAIT_S``."""
    while True:
        event = await asyncio.wait_for(anext(events), WAIT_S)
        if event is not None:
            return event


def test_a_subscriber_hears_what_is_published_on_its_channels_only(bus_settings):
    async def scenario() -> list[dict[str, Any]]:
        events = live.subscribe([live.run_channel(7), live.CALENDAR], idle_s=60)
        assert await anext(events) is None  # subscribed
        assert live.publish(live.run_channel(8), {"type": "samples", "last_seq": 1})
        assert live.publish(live.run_channel(7), {"type": "samples", "last_seq": 40})
        assert live.publish(live.CALENDAR, {"type": "changed"})
        try:
            return [await _next(events), await _next(events)]
        finally:
            await events.aclose()

    heard = async_to_sync(scenario)()
    assert heard == [{"type": "samples", "last_seq": 40}, {"type": "changed"}]


def test_a_portal_on_another_database_sharing_the_redis_is_not_heard(monkeypatch):
    """Redis's pub/sub is one for all its numbered databases, and run ids repeat between
    databases (two portals, two test workers): each database's channels are its own."""

    def published_from_another_database() -> None:
        with monkeypatch.context() as elsewhere:
            elsewhere.setitem(connection.settings_dict, "NAME", "another_portal")
            assert live.publish(live.run_channel(7), {"type": "samples", "last_seq": 99})

    async def scenario() -> dict[str, Any]:
        events = live.subscribe([live.run_channel(7)], idle_s=60)
        assert await anext(events) is None  # subscribed
        await sync_to_async(published_from_another_database)()
        assert live.publish(live.run_channel(7), {"type": "samples", "last_seq": 40})
        try:
            return await _next(events)
        finally:
            await events.aclose()

    assert async_to_sync(scenario)() == {"type": "samples", "last_seq": 40}


def test_a_quiet_channel_yields_keepalives(bus_settings):
    async def scenario() -> list[Any]:
        events = live.subscribe([live.CALENDAR], idle_s=0.3)
        try:
            return [await anext(events), await asyncio.wait_for(anext(events), WAIT_S)]
        finally:
            await events.aclose()

    assert async_to_sync(scenario)() == [None, None]


def test_publishing_to_a_redis_that_is_down_returns_false_and_raises_nothing(settings, caplog):
    settings.REDIS_URL = "redis://127.0.0.1:9/0"  # nothing listens there
    assert live.publish(live.CALENDAR, {"type": "changed"}) is False
    assert "not published" in caplog.text


def test_subscribing_to_a_redis_that_is_down_says_live_is_unavailable(settings):
    settings.REDIS_URL = "redis://127.0.0.1:9/0"

    async def scenario() -> None:
        events = live.subscribe([live.CALENDAR], idle_s=1)
        try:
            await anext(events)
        finally:
            await events.aclose()

    with pytest.raises(live.LiveUnavailable):
        async_to_sync(scenario)()


def test_the_file_bus_skips_unreadable_lines_and_starts_over_when_emptied(settings, tmp_path):
    settings.REDIS_URL = ""
    settings.LIVE_DIR = tmp_path / "live"
    path = tmp_path / "live" / "calendar.jsonl"
    path.parent.mkdir()

    async def scenario() -> list[dict[str, Any]]:
        events = live.subscribe([live.CALENDAR], idle_s=60)
        assert await anext(events) is None
        with path.open("a") as file:
            file.write("not json\n" + json.dumps({"type": "changed", "n": 1}) + "\n")
        first = await _next(events)
        path.write_text("")  # a publisher emptied the file (it had grown too long)
        live.publish(live.CALENDAR, {"type": "changed", "n": 2})
        second = await _next(events)
        await events.aclose()
        return [first, second]

    assert async_to_sync(scenario)() == [{"type": "changed", "n": 1}, {"type": "changed", "n": 2}]


def test_a_channel_file_is_emptied_when_it_grows_too_long(settings, tmp_path, monkeypatch):
    settings.REDIS_URL = ""
    settings.LIVE_DIR = tmp_path / "live"
    monkeypatch.setattr(live, "FILE_MAX_BYTES", 200)
    for n in range(50):
        live.publish(live.CALENDAR, {"type": "changed", "n": n})
    size = (tmp_path / "live" / "calendar.jsonl").stat().st_size
    assert 0 < size <= 200 + 40
