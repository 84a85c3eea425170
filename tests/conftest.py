"""Shared fixtures: the permission trio (owner, other experimenter, admin) and API clients."""

from __future__ import annotations

import os
import sys
import time

import psycopg
import pytest
from allauth.account.authentication import AUTHENTICATION_METHODS_SESSION_KEY
from django.core.cache import cache
from django.db import OperationalError
from django.db.backends.postgresql.operations import DatabaseOperations
from hypothesis import settings as hypothesis_settings
from rest_framework.test import APIClient

from core.accounts.staff import has_staff_role
from portal.celery import app as celery_app
from tests.durations import UNKNOWN_LONG_S, UNKNOWN_S, UNKNOWN_SLOW_S, file_durations
from tests.factories import ExperimentFactory, MobileResourceFactory, UserFactory

# The real-process stack (agent, web, worker, beat) for integration and browser tests.
pytest_plugins = ["tests.integration.stack", "tests.integration.live"]

# Property tests run real code (SQLite, codecs, the firmware core through ctypes) on a shared
# machine: how long one example takes says nothing about correctness, so no example has a
# deadline. Registered here, before any test module is imported, so that every ``@settings``
# inherits it.
hypothesis_settings.register_profile("suite", deadline=None)
hypothesis_settings.load_profile("suite")


def pytest_report_header(config: pytest.Config) -> list[str]:
    from django.conf import settings
    from django.db import connection

    db = settings.DATABASES["default"]
    where = f"{db.get('HOST') or 'local'}:{db.get('PORT') or ''}" if db.get("HOST") else db["NAME"]
    return [
        f"database engine: {connection.vendor} ({db['ENGINE']}) at {where}",
        f"celery broker: {settings.CELERY_BROKER_URL}",
    ]


def pytest_configure(config: pytest.Config) -> None:
    from django.conf import settings

    # Users are made and signed in by the thousand: hash their passwords cheaply
    # (tests/hashers.py says why the real processes still check them as in production).
    settings.PASSWORD_HASHERS = ["tests.hashers.QuickPBKDF2PasswordHasher"]

    # `make test` demands the real servers; a run that fell back to SQLite is a failure,
    # not a quiet pass on a different database.
    if os.environ.get("AMAZING_TEST_REQUIRE_POSTGRES") == "1":
        engine = settings.DATABASES["default"]["ENGINE"]
        if "postgresql" not in engine:
            raise pytest.UsageError(f"tests must run on PostgreSQL, got {engine}")
        if not settings.CELERY_BROKER_URL.startswith("redis://"):
            raise pytest.UsageError(f"tests must use Redis, got {settings.CELERY_BROKER_URL}")


@pytest.fixture(scope="session")
def django_db_setup(django_db_setup):
    """pytest-django's test databases; before they are dropped, this process's connection
    pools are closed (a pool refills itself to its minimum) and any other connection still
    open on them is ended and named. ``DROP DATABASE`` would otherwise fail the session's
    last test with "being accessed by other users"."""
    yield
    import psycopg
    from django.db import connections

    for alias in connections:
        wrapper = connections[alias]
        wrapper.close()
        if hasattr(wrapper, "close_pool"):
            wrapper.close_pool()
    db = connections["default"].settings_dict
    if "postgresql" not in db["ENGINE"]:
        return
    with psycopg.connect(
        host=db["HOST"], port=db["PORT"] or None, user=db["USER"], dbname="postgres",
        password=db.get("PASSWORD") or None, autocommit=True,
    ) as maintenance:  # fmt: skip
        ended = maintenance.execute(
            "SELECT pid, application_name, state, left(query, 120), pg_terminate_backend(pid)"
            " FROM pg_stat_activity WHERE datname = %s",
            [db["NAME"]],
        ).fetchall()
        for pid, application, state, query, _ in ended:
            sys.stderr.write(
                f"test database still in use at the end, connection ended: pid {pid} "
                f"{application!r} {state} {query!r}\n"
            )
        # pg_terminate_backend only signals: wait (a hang bounded) until they have gone.
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            left = maintenance.execute(
                "SELECT count(*) FROM pg_stat_activity WHERE datname = %s", [db["NAME"]]
            ).fetchone()
            if not left or left[0] == 0:
                break
            time.sleep(0.05)


# How often a test's end empties the tables again after a deadlock with a system's process.
FLUSH_TRIES = 5


def flush_tried_again(flush):
    """``execute_sql_flush`` that tries again when PostgreSQL broke a deadlock by aborting it.

    A transactional test's end empties every table with one ``TRUNCATE``, which locks them one
    after the other, while the processes of a system still running (a module's stack: its
    worker, collector, beat) read some of them in their own transactions: one that holds a
    table the ``TRUNCATE`` reaches later and waits for one it has already locked closes a
    cycle, and PostgreSQL aborts one of the two. When that is the ``TRUNCATE``, the tables
    stay full, and the module's next tests meet the rows of this one."""

    def execute_sql_flush(self, sql_list):
        for attempt in range(1, FLUSH_TRIES + 1):
            try:
                return flush(self, sql_list)
            except OperationalError as exc:
                if attempt == FLUSH_TRIES or not isinstance(
                    exc.__cause__, psycopg.errors.DeadlockDetected
                ):
                    raise
                time.sleep(0.1 * attempt)  # the other transaction ends meanwhile
        return None

    return execute_sql_flush


DatabaseOperations.execute_sql_flush = flush_tried_again(DatabaseOperations.execute_sql_flush)


@pytest.fixture(autouse=True)
def _fresh_cache(settings, tmp_path):
    """Each test starts with an empty cache: robot health, throttle counts and heartbeats
    kept there have no expiry, and a test must not pass or fail by what an earlier one left.

    The Redis database is the test run's own; a cache in files (no Redis configured) is
    moved to the test's directory instead of emptying the one ``make run`` uses."""
    if settings.CACHES["default"]["BACKEND"].endswith("RedisCache"):
        cache.clear()
    else:
        settings.CACHES = {
            "default": {**settings.CACHES["default"], "LOCATION": str(tmp_path / "cache")}
        }


@pytest.fixture(autouse=True)
def _api_throttles_off(settings):
    """The throttles count in the shared cache across tests; their own tests turn them on."""
    settings.API_THROTTLE_ANON = None
    settings.API_THROTTLE_USER = None


@pytest.fixture
def owner():
    return UserFactory(username="alice")


@pytest.fixture
def other():
    return UserFactory(username="bob")


@pytest.fixture
def admin_user():
    """An admin with MFA, as a door that checked the second factor hands it to a service."""
    return staff_verified(UserFactory(username="charlie", is_staff=True, is_superuser=True))


def staff_verified(user):
    """``user`` marked as the door marks staff whose session passed the second factor
    (``core.accounts.staff``): for a service called directly."""
    user.staff_verified = True
    return user


def sign_in_with_second_factor(client, user):
    """``client`` signed in as ``user`` in a session whose records show the password and the
    second factor, as allauth's sign-in leaves them: staff powers through the real door."""
    client.force_login(user)
    session = client.session
    now = time.time()
    session[AUTHENTICATION_METHODS_SESSION_KEY] = [
        {"method": "password", "at": now, "username": user.get_username()},
        {"method": "mfa", "at": now, "type": "totp"},
    ]
    session["account_authentication_methods_user"] = str(user.pk)
    session.save()
    return client


@pytest.fixture
def staff_verified_client(admin_user) -> APIClient:
    """The admin, signed in with its second factor (pages and API)."""
    return sign_in_with_second_factor(APIClient(), admin_user)


@pytest.fixture
def mobile():
    return MobileResourceFactory()


@pytest.fixture
def experiment(owner):
    return ExperimentFactory(owner=owner)


def _client(user) -> APIClient:
    """An API client as ``user``; staff sign in with their second factor (the guard of staff
    actions reads the session's records, never a forced user)."""
    client = APIClient()
    if user is not None and has_staff_role(user):
        return sign_in_with_second_factor(client, user)
    if user is not None:
        client.force_authenticate(user=user)
    return client


@pytest.fixture
def api(owner) -> APIClient:
    return _client(owner)


@pytest.fixture
def client_for():
    return _client


@pytest.fixture
def eager_tasks():
    """Run queued tasks in-process, so a unit test sees their effects and e-mails (the
    integration tests exercise the real worker). Celery's eager ``apply_async`` sends each
    task's arguments through the task's serializer and back first, so an argument the
    broker cannot carry fails here too (``tests/test_eager_tasks.py`` holds it to that)."""
    celery_app.conf.task_always_eager = True
    celery_app.conf.task_eager_propagates = True
    yield
    celery_app.conf.task_always_eager = False
    celery_app.conf.task_eager_propagates = False


@pytest.hookimpl(trylast=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The longest files first (their seconds in ``tests/durations.json``; a file not there
    by its markers: ``long`` first, then the files that start real processes, then the rest):
    the workers (pytest-xdist, a file each, handed out in this order: ``--no-loadscope-reorder``
    in pyproject.toml) take the long files while the short ones are left to fill the end,
    instead of one worker finishing a long file alone. Within a file the order is unchanged.
    (After pytest-django's ordering: under xdist a file runs whole on one worker anyway, so
    its database groups already interleave with other files'.)"""

    def files_marked(*names: str) -> set[str]:
        return {
            item.nodeid.partition("::")[0]
            for item in items
            if any(item.get_closest_marker(name) for name in names)
        }

    long_files, slow_files = files_marked("long"), files_marked("integration", "browser")
    known = file_durations()

    def seconds(file: str) -> float:
        if file in known:
            return known[file]
        if file in long_files:
            return UNKNOWN_LONG_S
        return UNKNOWN_SLOW_S if file in slow_files else UNKNOWN_S

    cost = {file: seconds(file) for file in {item.nodeid.partition("::")[0] for item in items}}
    items.sort(key=lambda item: -cost[item.nodeid.partition("::")[0]])
