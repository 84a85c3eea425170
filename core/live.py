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

- Redis pub/sub (production, tests): ``PUBLISH amazing:live:<database>:<channel>``
  (:func:`redis_channel`; ids repeat between databases, and Redis's pub/sub is one for all
  its numbered databases, so two portals or two tests sharing a server never hear each
  other's runs); the web process subscribes with ``redis.asyncio``, one connection per open
  stream, no thread.
- Files (``make run``, no Redis): each channel is a file of JSON lines under
  ``var/live/``; publishers append, the web process reads what was added since it last
  looked, four times a second. Processes on one machine only.

Publishing never fails its caller: a bus that is down costs the pages their pushes, never a
run its samples.

A run's new samples are announced with a mark per sequence number, set by the same Redis
script that announces them (both happen or neither): a publisher killed between storing
samples and announcing them leaves stored samples without their mark, which the collector
finds and announces when it takes the run up again (``samples_announce_missed``). Setting the
mark is the claim: the script announces only the samples whose mark it set, so two publishers
of the same samples (the sweep's commit and a restarted collector's catching up, racing) say
each once between them. So every stored sample is announced once even across a crash. The
file transport keeps no marks.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import time
from collections.abc import AsyncGenerator, AsyncIterator, Callable, Mapping, Sequence
from datetime import datetime
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import redis
import redis.asyncio as aredis
from django.conf import settings
from django.db import transaction

from core.cache import database_namespace

logger = logging.getLogger(__name__)

CALENDAR = "calendar"
REDIS_PREFIX = "amazing:live:"
# A channel's file is emptied when it grows past this; readers start over from the top.
FILE_MAX_BYTES = 256 * 1024
FILE_POLL_S = 0.25
# Publishing waits at most this long for Redis: a run's collection must not stall on it.
PUBLISH_TIMEOUT_S = 0.5
# A run's announced-sample marks: one bit per sequence number, kept this long after the last.
ANNOUNCED_PREFIX = "amazing:live:announced:"
ANNOUNCED_TTL_S = 7 * 24 * 3600


def redis_channel(channel: str) -> str:
    """``channel``'s name on Redis: this database's own (a pattern too: ``run-*``)."""
    return f"{REDIS_PREFIX}{database_namespace()}:{channel}"


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


def announced_key(run_id: int, created_at: datetime) -> str:
    # Run ids repeat between databases (a test's, a restore) that may share one Redis, and in
    # one database made again or restored from a backup: the run's creation time tells it
    # from an earlier run of its id, whose marks would claim its samples as announced.
    created_us = round(created_at.timestamp() * 1_000_000)
    return f"{ANNOUNCED_PREFIX}{database_namespace()}:{run_id}:{created_us}"


class _Bus(Protocol):
    def publish(self, channel: str, payload: str) -> None: ...

    def publish_samples(
        self, channel: str, key: str, first_seq: int, times_s: Sequence[float]
    ) -> None: ...

    def marks(self, key: str) -> bytes | None: ...

    def subscribe(self, channels: list[str], *, idle_s: float) -> AsyncIterator[str | None]: ...


def samples_event(first_seq: int, last_seq: int, last_t_s: float) -> dict[str, Any]:
    """A ``samples`` event: the run's samples ``first_seq``…``last_seq`` are stored."""
    return {
        "type": "samples",
        "count": last_seq - first_seq + 1,
        "first_seq": first_seq,
        "last_seq": last_seq,
        "last_t": last_t_s,
    }


# KEYS[1]: the run's marks. ARGV: the channel, the marks' lifetime (s), the first sequence
# number, how many follow it, then the time of the last of them, or of each. Each sample whose
# mark this sets is claimed; each unbroken range of claimed ones is announced as one
# samples_event (the same JSON). Samples marked already (announced by another publisher) are
# passed over. The usual page, none of it marked, is marked a whole byte at a time where it
# can be (one SETRANGE, not thousands of SETBITs) and announced as one event, for which the
# last time is enough; otherwise, given only that, the script changes nothing and answers -1,
# asking for every time. (BITCOUNT's BIT unit: Redis 7, as the compose file runs; an older
# server refuses the script and the samples are announced without marks: samples_publish.)
_CLAIM_AND_ANNOUNCE = """
local key, first, count = KEYS[1], tonumber(ARGV[3]), tonumber(ARGV[4])
local last_seq = first + count - 1
local claimed, from, last, last_t = 0, nil, nil, nil
local function announce()
  redis.call('PUBLISH', ARGV[1], '{"type":"samples","count":' .. (last - from + 1)
    .. ',"first_seq":' .. from .. ',"last_seq":' .. last .. ',"last_t":' .. last_t .. '}')
end
if count > 0 and redis.call('BITCOUNT', key, first, last_seq, 'BIT') == 0 then
  local bytes_first, bytes_stop = math.ceil(first / 8), math.floor((last_seq + 1) / 8)
  if bytes_stop > bytes_first then
    redis.call('SETRANGE', key, bytes_first, string.rep('\\255', bytes_stop - bytes_first))
    for seq = first, bytes_first * 8 - 1 do redis.call('SETBIT', key, seq, 1) end
    for seq = bytes_stop * 8, last_seq do redis.call('SETBIT', key, seq, 1) end
  else
    for seq = first, last_seq do redis.call('SETBIT', key, seq, 1) end
  end
  from, last, last_t, claimed = first, last_seq, ARGV[#ARGV], count
  announce()
elseif #ARGV - 4 < count then
  return -1
else
  for i = 5, #ARGV do
    local seq = first + i - 5
    if redis.call('SETBIT', key, seq, 1) == 0 then
      if from == nil then from = seq end
      last, last_t, claimed = seq, ARGV[i], claimed + 1
    elseif from ~= nil then
      announce()
      from = nil
    end
  end
  if from ~= nil then announce() end
end
redis.call('EXPIRE', key, ARGV[2])
return claimed
"""


class RedisBus:
    def __init__(self, url: str, prefix: str) -> None:
        self.url = url
        # REDIS_PREFIX and the database's namespace (redis_channel).
        self.prefix = prefix
        self._client = redis.Redis.from_url(
            url, socket_connect_timeout=PUBLISH_TIMEOUT_S, socket_timeout=PUBLISH_TIMEOUT_S
        )
        self._claim_and_announce = self._client.register_script(_CLAIM_AND_ANNOUNCE)

    def publish(self, channel: str, payload: str) -> None:
        self._client.publish(self.prefix + channel, payload)

    def publish_samples(
        self, channel: str, key: str, first_seq: int, times_s: Sequence[float]
    ) -> None:
        """Announce the samples from ``first_seq`` on (``times_s``, one each) not announced
        yet and mark them, in one script (atomic: both or neither, and one publisher each)."""
        if not times_s:
            return
        head: list[str | int] = [self.prefix + channel, ANNOUNCED_TTL_S, first_seq, len(times_s)]
        # The last time is enough for the usual page; the script asks for each (-1) only when
        # some of these samples were announced already.
        if self._claim_and_announce(keys=[key], args=[*head, repr(times_s[-1])]) == -1:
            self._claim_and_announce(keys=[key], args=[*head, *map(repr, times_s)])

    def marks(self, key: str) -> bytes | None:
        """The bitmap (bit ``n`` is sequence number ``n``, most significant bit first)."""
        value = self._client.get(key)
        if value is None:
            return b""
        return value if isinstance(value, bytes) else str(value).encode("latin-1")

    async def subscribe(self, channels: list[str], *, idle_s: float) -> AsyncIterator[str | None]:
        client = aredis.Redis.from_url(self.url, socket_connect_timeout=2.0)
        pubsub = client.pubsub(ignore_subscribe_messages=True)
        try:
            try:
                await pubsub.subscribe(*(self.prefix + c for c in channels))
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

    def publish_samples(
        self, channel: str, key: str, first_seq: int, times_s: Sequence[float]
    ) -> None:
        # One machine, no crash-proof marks: see the module.
        if times_s:
            event = samples_event(first_seq, first_seq + len(times_s) - 1, times_s[-1])
            self.publish(channel, json.dumps(event, separators=(",", ":")))

    def marks(self, key: str) -> bytes | None:
        return None

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
_bus_key: tuple[str, str, str] | None = None


def bus() -> _Bus:
    """The transport the settings name (rebuilt if they change, as tests do)."""
    global _bus, _bus_key
    prefix = redis_channel("")
    key = (settings.REDIS_URL, str(settings.LIVE_DIR), prefix)
    if _bus is None or _bus_key != key:
        if settings.REDIS_URL:
            _bus = RedisBus(settings.REDIS_URL, prefix)
        else:
            _bus = FileBus(settings.LIVE_DIR)
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


def samples_publish(
    run_id: int, created_at: datetime, first_seq: int, times_s: Sequence[float]
) -> bool:
    """Announce the stored samples from ``first_seq`` on (``times_s``, the time of each) of
    the run ``run_id`` created at ``created_at`` in ``samples`` events, those not announced
    yet, marking them; False (logged) if the bus is down."""
    channel = run_channel(run_id)
    try:
        bus().publish_samples(channel, announced_key(run_id, created_at), first_seq, times_s)
    except redis.ResponseError as exc:
        # Redis refused the script (not the connection): the pages still hear of the samples;
        # only a crash before the next announcement could now repeat these.
        logger.warning("live: samples of run %s announced without marks (%s)", run_id, exc)
        last_seq = first_seq + len(times_s) - 1
        return publish(channel, samples_event(first_seq, last_seq, times_s[-1]))
    except (redis.RedisError, OSError) as exc:
        logger.info("live: samples of run %s not published (%s)", run_id, exc)
        return False
    return True


def samples_publish_on_commit(
    run_id: int, created_at: datetime, first_seq: int, times_s: Sequence[float]
) -> None:
    """:func:`samples_publish` once the samples are committed."""
    transaction.on_commit(partial(samples_publish, run_id, created_at, first_seq, list(times_s)))


def samples_announced(run_id: int, created_at: datetime) -> Callable[[int], bool] | None:
    """Whether each sequence number of the run was announced; None when the bus keeps no
    marks (files) or cannot be reached."""
    try:
        marks = bus().marks(announced_key(run_id, created_at))
    except (redis.RedisError, OSError) as exc:
        logger.info("live: marks of run %s not read (%s)", run_id, exc)
        return None
    if marks is None:
        return None

    def announced(seq: int) -> bool:
        index, bit = divmod(seq, 8)
        return index < len(marks) and bool(marks[index] >> (7 - bit) & 1)

    return announced


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
