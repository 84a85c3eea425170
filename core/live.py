"""Live pushes: what just changed, published for the pages that watch it.

Publishers (the workers collecting runs and checking robots, the web process booking) call
:func:`publish_on_commit`; the web process streams what it hears to the browser over
Server-Sent Events (``portal/web/live.py``). An event is a small JSON object with a
``type``; it says *that* something changed and the newest numbers, and a page that missed
some (the stream dropped) catches up by reading its data once more. So losing an event is
never worse than the polling the pages fall back to.

Channels: ``run-<id>`` (state changes, new samples), ``robot-<name>`` (status, hold),
``calendar`` (bookings, maintenance, holds).

Two transports, chosen by ``REDIS_URL``:

- Redis pub/sub (production, tests): ``PUBLISH amazing:live:<channel>``; the web process
  subscribes with ``redis.asyncio``, one connection per open stream, no thread.
- Files (``make run``, no Redis): each channel is a file of JSON lines under
  ``var/live/``; publishers append, the web process reads what was added since it last
  looked, four times a second. Processes on one machine only.

Publishing never fails its caller: a bus that is down costs the pages their pushes, never a
run its samples.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import time
from collections.abc import AsyncGenerator, AsyncIterator, Mapping
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import redis
import redis.asyncio as aredis
from django.conf import settings
from django.db import transaction

logger = logging.getLogger(__name__)

CALENDAR = "calendar"
REDIS_PREFIX = "amazing:live:"
# A channel's file is emptied when it grows past this; readers start over from the top.
FILE_MAX_BYTES = 256 * 1024
FILE_POLL_S = 0.25
# Publishing waits at most this long for Redis: a run's collection must not stall on it.
PUBLISH_TIMEOUT_S = 0.5


def run_channel(run_id: int) -> str:
    return f"run-{run_id}"


def robot_channel(name: str) -> str:
    return f"robot-{name}"


def hold_event(resource: Any) -> dict[str, Any]:
    """A robot held by its health check, or back in service (a ``bookings.Resource``)."""
    return {
        "type": "hold",
        "resource": resource.name,
        "reason": resource.hold_reason,
        "held_at": resource.held_at.isoformat() if resource.held_at else None,
        "in_service": resource.in_service,
    }


def hold_publish(resource: Any) -> None:
    """Tell the calendars and the robot's console that its hold was made or lifted."""
    event = hold_event(resource)
    publish_on_commit(CALENDAR, event)
    publish_on_commit(robot_channel(resource.name), event)


class LiveUnavailable(Exception):
    """The bus cannot be reached: the stream ends and the page polls until it is back."""


class _Bus(Protocol):
    def publish(self, channel: str, payload: str) -> None: ...

    def subscribe(self, channels: list[str], *, idle_s: float) -> AsyncIterator[str | None]: ...


class RedisBus:
    def __init__(self, url: str) -> None:
        self.url = url
        self._client = redis.Redis.from_url(
            url, socket_connect_timeout=PUBLISH_TIMEOUT_S, socket_timeout=PUBLISH_TIMEOUT_S
        )

    def publish(self, channel: str, payload: str) -> None:
        self._client.publish(REDIS_PREFIX + channel, payload)

    async def subscribe(self, channels: list[str], *, idle_s: float) -> AsyncIterator[str | None]:
        client = aredis.Redis.from_url(self.url, socket_connect_timeout=2.0)
        pubsub = client.pubsub(ignore_subscribe_messages=True)
        try:
            try:
                await pubsub.subscribe(*(REDIS_PREFIX + c for c in channels))
            except (redis.RedisError, OSError) as exc:
                raise LiveUnavailable(str(exc)) from exc
            yield None  # subscribed: nothing published from here on is missed
            while True:
                try:
                    message = await pubsub.get_message(timeout=idle_s)
                except (redis.RedisError, OSError) as exc:
                    raise LiveUnavailable(str(exc)) from exc
                if message is None:
                    yield None
                elif message["type"] == "message":
                    data = message["data"]
                    yield data.decode() if isinstance(data, bytes) else str(data)
        finally:
            with contextlib.suppress(redis.RedisError, OSError):
                await pubsub.aclose()
            with contextlib.suppress(redis.RedisError, OSError):
                await client.aclose()


class FileBus:
    def __init__(self, directory: Path) -> None:
        self.directory = directory

    def _path(self, channel: str) -> Path:
        return self.directory / f"{channel}.jsonl"

    def publish(self, channel: str, payload: str) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        path = self._path(channel)
        line = (payload.replace("\n", " ") + "\n").encode()
        # O_APPEND: lines from several processes never interleave (each is one short write).
        fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o600)
        try:
            if os.fstat(fd).st_size > FILE_MAX_BYTES:
                os.ftruncate(fd, 0)
            os.write(fd, line)
        finally:
            os.close(fd)

    def _size(self, channel: str) -> int:
        try:
            return self._path(channel).stat().st_size
        except FileNotFoundError:
            return 0

    def _read(self, channel: str, offset: int) -> tuple[int, list[str]]:
        size = self._size(channel)
        if size < offset:
            offset = 0  # emptied by a publisher: start over
        if size == offset:
            return offset, []
        with self._path(channel).open("rb") as file:
            file.seek(offset)
            data = file.read(size - offset)
        complete = data.rfind(b"\n") + 1  # a line still being written waits for next time
        lines = data[:complete].decode(errors="replace").splitlines()
        return offset + complete, [line for line in lines if line.strip()]

    async def subscribe(self, channels: list[str], *, idle_s: float) -> AsyncIterator[str | None]:
        offsets = {c: self._size(c) for c in channels}
        yield None
        idle_since = time.monotonic()
        while True:
            fresh: list[str] = []
            for channel in channels:
                offsets[channel], lines = self._read(channel, offsets[channel])
                fresh += lines
            for line in fresh:
                yield line
            now = time.monotonic()
            if fresh:
                idle_since = now
            elif now - idle_since >= idle_s:
                idle_since = now
                yield None
            await asyncio.sleep(FILE_POLL_S)


_bus: _Bus | None = None
_bus_key: tuple[str, str] | None = None


def bus() -> _Bus:
    """The transport the settings name (rebuilt if they change, as tests do)."""
    global _bus, _bus_key
    key = (settings.REDIS_URL, str(settings.LIVE_DIR))
    if _bus is None or _bus_key != key:
        _bus = RedisBus(settings.REDIS_URL) if settings.REDIS_URL else FileBus(settings.LIVE_DIR)
        _bus_key = key
    return _bus


def publish(channel: str, event: Mapping[str, Any]) -> bool:
    """Send ``event`` to whoever watches ``channel`` now; False (logged) if the bus is down."""
    payload = json.dumps(event, separators=(",", ":"), default=str)
    try:
        bus().publish(channel, payload)
    except (redis.RedisError, OSError) as exc:
        logger.info("live: %s not published (%s)", event.get("type"), exc)
        return False
    return True


def publish_on_commit(channel: str, event: Mapping[str, Any]) -> None:
    """Publish once the change it announces is committed (at once outside a transaction)."""
    transaction.on_commit(partial(publish, channel, dict(event)))


async def subscribe(
    channels: list[str], *, idle_s: float
) -> AsyncGenerator[dict[str, Any] | None, None]:
    """Events on ``channels`` as they come; ``None`` first once subscribed, then after every
    ``idle_s`` without one (for keep-alives). Raises :class:`LiveUnavailable` when the bus
    cannot be reached or drops."""
    async for payload in bus().subscribe(channels, idle_s=idle_s):
        if payload is None:
            yield None
            continue
        try:
            event = json.loads(payload)
        except ValueError:
            logger.warning("live: dropped an unreadable event on %s", channels)
            continue
        if isinstance(event, dict):
            yield event
