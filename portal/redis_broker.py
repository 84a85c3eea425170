"""The task transport on Redis: kombu's, with one fault of its reconnection fixed.

When a worker loses Redis, Celery closes the broker connection and opens a new one. kombu
closes the connection's transport first (dropping its link to the connection's settings) and
may then close a channel of it, which puts its unacknowledged messages back — on a new Redis
client built from those settings. kombu's channel reads them from the transport's ``client``,
which is ``None`` by then, and raises ``AttributeError``. Celery treats that as an
unrecoverable error and the worker exits in the middle of the outage (seen about one Redis
outage in five).

Here a channel whose connection is gone raises Redis's ``ConnectionError`` instead: a
connection error, which Celery expects while it reconnects, so the worker waits for Redis and
goes on. The messages it could not put back stay in Redis's unacknowledged set and return
after the visibility timeout (and the sweeps redo a run's lost tasks long before that).

Used through ``broker_transport`` naming this class, with the usual ``redis://`` URL
(``portal/settings.py``).
"""

from __future__ import annotations

from typing import Any

from kombu.transport import redis as kombu_redis
from redis.exceptions import ConnectionError as RedisConnectionError


class Channel(kombu_redis.Channel):
    def _connparams(self, asynchronous: bool = False) -> dict[str, Any]:
        if self.connection is None or self.connection.client is None:
            raise RedisConnectionError("the broker connection is closed")
        params: dict[str, Any] = super()._connparams(asynchronous=asynchronous)  # type: ignore[misc]
        return params


class Transport(kombu_redis.Transport):
    Channel = Channel
