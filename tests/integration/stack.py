"""The system's processes as pytest fixtures: agent(s), web servers, Celery workers, beat.

``stack`` is one fresh system per test on the test database and Redis; ``module_stack`` the
same system once for a module whose tests can share it. ``fault_stack`` is one per module, for
tests that break its parts on purpose: it runs on a Redis server of its own
(a test may stop it; the machine's shared one is never touched), with a second robot, and
every process can be killed and started again (``Stack.kill``, ``Stack.start``). The
processes themselves are started by ``bench/stack.py``, which the soak shares.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import redis
from django.conf import settings

from bench import stack as processes
from bench.stack import METRICS_TOKEN, RedisServer, Stack

__all__ = [
    "FAULT_ENV",
    "METRICS_TOKEN",
    "PRIVATE_REDIS_STACKS",
    "TEST_WEB",
    "RedisServer",
    "Stack",
    "private_stack",
    "running_stack",
]

# The web server's size in the suite's systems.
TEST_WEB = {"WEB_WORKERS": "1", "WEB_THREADS": "8"}

# The stacks that outlive a test (one a module) on a Redis server of their own.
PRIVATE_REDIS_STACKS = ("fault_stack", "live_stack", "module_stack")


def _test_database_url() -> str:
    db = settings.DATABASES["default"]
    assert db["ENGINE"].endswith("postgresql"), "the integration test runs on PostgreSQL"
    return f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}"


@contextlib.contextmanager
def running_stack(
    var_dir: Path,
    *,
    broker_url: str,
    redis_url: str | None = None,
    second_robot: bool = False,
    with_scheduler: bool = False,
    extra_env: dict[str, str] | None = None,
    process_env: dict[str, dict[str, str]] | None = None,
) -> Iterator[Stack]:
    """Every process of ``system_processes`` on the test database, started and ready."""
    with processes.running_stack(
        var_dir,
        database_url=_test_database_url(),
        broker_url=broker_url,
        redis_url=redis_url,
        second_robot=second_robot,
        with_scheduler=with_scheduler,
        extra_env={
            # The test's key: the processes read what the test wrote under it (MFA secrets
            # are encrypted with a key derived from it, core/crypto.py), the test what they
            # wrote.
            "DJANGO_SECRET_KEY": settings.SECRET_KEY,
            # One web process, as `make run` starts (each costs seconds of CPU to start, and
            # the suite starts dozens of systems); its threads serve a test's requests.
            **TEST_WEB,
            **(extra_env or {}),
        },
        process_env=process_env,
    ) as stack:
        yield stack


@pytest.fixture
def stack(tmp_path):
    """Agent, web servers, Celery workers and beat on the test database and Redis."""
    with running_stack(tmp_path / "var", broker_url=settings.CELERY_BROKER_URL) as running:
        yield running


@pytest.fixture
def stack_with_scheduler(tmp_path):
    """The same, with the stand-in scheduler (its test controls on) owning the fixed nodes,
    swept every second."""
    with running_stack(
        tmp_path / "var", broker_url=settings.CELERY_BROKER_URL, with_scheduler=True
    ) as running:
        yield running


@pytest.fixture
def flashed_stack(tmp_path):
    """The same, with the flashed image as the robot's firmware: robot.elf on an emulated
    ATmega328P (``AGENT_ROBOT=sim-flashed``, basestation/sim/flashed.py)."""
    with running_stack(
        tmp_path / "var",
        broker_url=settings.CELERY_BROKER_URL,
        extra_env={"AGENT_ROBOT": "sim-flashed"},
    ) as running:
        yield running


# What the fault tests need to see their faults through in seconds, not minutes.
FAULT_ENV = {
    "HEALTH_POLL_INTERVAL_S": "1",
    # An agent killed on purpose comes back long before this: no hold from those tests.
    "HEALTH_UNREACHABLE_S": "120",
    "RUN_START_GRACE_S": "3",
    "RUN_COLLECT_GRACE_S": "120",
    # A webhook's failed delivery tried again within two seconds, not minutes.
    "WEBHOOK_RETRY_FIRST_S": "0.5",
    "WEBHOOK_RETRY_MAX_S": "2",
}


@contextlib.contextmanager
def private_stack(base: Path, **options: Any) -> Iterator[Stack]:
    """``running_stack`` on a Redis server of its own under ``base`` (the cache on its
    database 0, the broker on 1), for a stack that outlives a test: the suite's shared Redis
    database is flushed before each test (``tests/conftest.py``), which would take the
    broker's queues from under the stack's workers."""
    server = RedisServer(base / "redis")
    server.start()
    try:
        with running_stack(
            base / "var", broker_url=server.url(1), redis_url=server.url(0), **options
        ) as running:
            running.redis = server
            yield running
    finally:
        server.stop()


@pytest.fixture(scope="module")
def fault_stack(tmp_path_factory, django_db_setup):
    """One system per module on a private Redis server, with two robots, to break on purpose.

    After the test database is made (``django_db_setup``): the processes are pointed at it.
    """
    with private_stack(
        tmp_path_factory.mktemp("fault-stack"), second_robot=True, extra_env=FAULT_ENV
    ) as running:
        yield running


@pytest.fixture(scope="module")
def module_stack(tmp_path_factory, django_db_setup):
    """``stack`` once for a module's tests: what a test changes in the processes (a robot
    driven and stopped, a process killed) is the module's to put right, its rows are deleted
    after it as any other test's, and its cache is emptied before the next
    (``_fresh_private_cache``)."""
    with private_stack(tmp_path_factory.mktemp("module-stack")) as running:
        yield running


@pytest.fixture(autouse=True)
def _fresh_private_cache(request: pytest.FixtureRequest) -> None:
    """Each test on a stack that outlives it starts with that stack's cache empty, as every
    other test starts with its own (``tests/conftest.py``): tokens, calendars and robots
    cached there would otherwise outlive the rows the previous test's end deleted.

    Only ``REDIS_URL``'s database (the cache, and the live bus's marks of what it announced)
    is flushed. The broker's stays: a worker holds the unacknowledged tasks it is running
    there, and beat's next ones wait in it; flushing them under the worker would lose them,
    and what they act on is gone from the tables anyway."""
    for name in PRIVATE_REDIS_STACKS:
        if name not in request.fixturenames:
            continue
        running: Stack = request.getfixturevalue(name)
        if running.redis is not None and running.redis.alive:
            redis.Redis.from_url(running.env["REDIS_URL"]).flushdb()
