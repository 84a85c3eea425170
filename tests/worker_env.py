"""Each pytest-xdist worker gets its own Redis database and database names.

Loaded with ``-p`` (pyproject.toml) so that it runs before pytest-django sets Django up: the
settings read ``REDIS_URL``, ``CELERY_BROKER_URL`` and ``DATABASE_URL`` once, at import.
pytest-django already gives each worker its own test database (``test_<name>_gw<N>``); the
Redis database, ``DATABASE_URL`` (which the benchmarks' scratch databases and the child
processes started with this environment are named after) and the data folder
(``AMAZING_VAR_DIR``: the file live bus, the development key) are this module's part. Worker
N uses the Redis database N below the one given, so two workers never share a broker queue, a
cache or a live bus.

Without xdist (``-p no:xdist``, or one worker) nothing changes.
"""

from __future__ import annotations

import os
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

REPO = Path(__file__).resolve().parent.parent


def _worker_index() -> int | None:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")  # "gw0", "gw1", ...
    return int(worker[2:]) if worker.startswith("gw") and worker[2:].isdigit() else None


def _redis_for_worker(url: str, index: int) -> str:
    parts = urlsplit(url)
    given = int(parts.path.strip("/") or 0)
    if index > given:
        raise RuntimeError(f"{url}: too few Redis databases below it for worker {index}")
    return urlunsplit(parts._replace(path=f"/{given - index}"))


def _database_for_worker(url: str, index: int) -> str:
    parts = urlsplit(url)
    name = parts.path.strip("/") or "amazing"
    return urlunsplit(parts._replace(path=f"/{name}_gw{index}"))


def _apply() -> None:
    index = _worker_index()
    if index is None:
        return
    for key in ("REDIS_URL", "CELERY_BROKER_URL"):
        if os.environ.get(key, "").startswith("redis://"):
            os.environ[key] = _redis_for_worker(os.environ[key], index)
    if os.environ.get("DATABASE_URL", "").startswith(("postgres://", "postgresql://")):
        os.environ["DATABASE_URL"] = _database_for_worker(os.environ["DATABASE_URL"], index)
    var_dir = Path(os.environ.get("AMAZING_VAR_DIR") or REPO / "var")
    os.environ["AMAZING_VAR_DIR"] = str(var_dir / f"test-gw{index}")


_apply()
