"""Django's Redis cache, with one Redis client per connection pool instead of one per call.

Django builds a new ``redis.Redis`` object around its pool for every cache operation; with
redis-py 8 that costs more than the round trip itself (measured: 258 µs a ``get`` through
Django against 90 µs on a kept client, on loopback). A client over a pool is safe to share
between threads, so each process keeps one per pool.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from django.core.cache.backends import redis as django_redis


class RedisCacheClient(django_redis.RedisCacheClient):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._clients: dict[int, Any] = {}

    def get_client(self, key: Any = None, *, write: bool = False) -> Any:
        pool = self._get_connection_pool(write)  # type: ignore[attr-defined]
        client = self._clients.get(id(pool))
        if client is None:
            # Two threads may both build one here: either serves, the other is dropped.
            client = self._clients[id(pool)] = self._client(connection_pool=pool)  # type: ignore[attr-defined]
        return client


class RedisCache(django_redis.RedisCache):
    def __init__(self, server: Any, params: dict[str, Any]) -> None:
        super().__init__(server, params)
        self._class = RedisCacheClient

    def incr_many_from(self, keys: Sequence[str], start: int) -> None:
        """Add one to each of ``keys``, first setting one to ``start`` where it is absent.
        One round trip for them all (Django's ``incr`` asks whether a key exists first, and
        raises when it does not)."""
        full_keys = [self.make_and_validate_key(key) for key in keys]
        if not full_keys:
            return
        client = self._cache.get_client(full_keys[0], write=True)  # type: ignore[attr-defined]
        pipeline = client.pipeline(transaction=False)
        for full_key in full_keys:
            pipeline.set(full_key, start, nx=True).incr(full_key)
        pipeline.execute()
