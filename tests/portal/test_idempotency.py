"""``X-Idempotency-Key``: replays, reuse, concurrent duplicates, killed requests and expiry."""

from __future__ import annotations

import json
import os
import signal
import sys
import threading
import time
from datetime import timedelta
from typing import Any

import pytest
from django.conf import settings
from django.db import connection
from django.test.utils import CaptureQueriesContext
from django.utils import timezone

from bench.stack import Proc
from bookings.models import Reservation
from core.audit import tasks
from core.audit.idempotency import UNANSWERED_LEASE_S, idempotency_keys_delete_expired
from core.audit.models import IdempotencyKey
from core.events.services import _Wakes
from tests.factories import FixedResourceFactory
from tests.sqlite import run_on_sqlite

URL = "/api/v1/reservations/"
# The statement that stores the answer: after it, the request's work is done but not committed.
STORE_ANSWER_SQL = 'INSERT INTO "audit_idempotencykey"'
# A child process that sends one request with a key and stops just after the answer is stored,
# before the commit, until it is killed. Arguments: username, key, body as JSON, and the start
# of the statement that stores the answer.
HOLDING_REQUEST = r"""
import json, sys, time
import django
django.setup()
from django.db import connection
from rest_framework.test import APIClient
from core.accounts.models import User


def hold_before_commit(execute, sql, params, many, context):
    result = execute(sql, params, many, context)
    if sql.startswith(sys.argv[4]):
        pid = connection.connection.info.backend_pid if connection.vendor == "postgresql" else 0
        print("holding", pid, flush=True)
        time.sleep(600)
    return result


client = APIClient(SERVER_NAME="localhost")
client.force_authenticate(User.objects.get(username=sys.argv[1]))
with connection.execute_wrapper(hold_before_commit):
    response = client.post(
        "/api/v1/reservations/", json.loads(sys.argv[3]), format="json",
        HTTP_X_IDEMPOTENCY_KEY=sys.argv[2],
    )
print("not held:", response.status_code, flush=True)
"""


def _holding_request_argv(username: str, key: str, body: dict[str, str]) -> list[str]:
    return [
        sys.executable,
        "-c",
        HOLDING_REQUEST,
        username,
        key,
        json.dumps(body),
        STORE_ANSWER_SQL,
    ]


def _body(node: Any, hours_ahead: float = 24) -> dict[str, str]:
    start = timezone.now().replace(microsecond=0) + timedelta(hours=hours_ahead)
    return {
        "resource": node.name,
        "start_at": start.isoformat(),
        "end_at": (start + timedelta(hours=1)).isoformat(),
    }


def _post(client: Any, body: dict[str, str], key: str) -> Any:
    return client.post(URL, body, format="json", HTTP_X_IDEMPOTENCY_KEY=key)


def _age(*, by_s: float) -> None:
    IdempotencyKey.objects.update(created_at=timezone.now() - timedelta(seconds=by_s))


@pytest.mark.django_db
def test_a_replay_gets_the_stored_answer_and_queues_nothing(
    owner, client_for, django_capture_on_commit_callbacks
):
    body = _body(FixedResourceFactory())
    client = client_for(owner)
    with django_capture_on_commit_callbacks() as first_tasks:
        first = _post(client, body, "k-1")
    with django_capture_on_commit_callbacks() as replay_tasks:
        replay = _post(client, body, "k-1")
    assert first.status_code == replay.status_code == 201
    assert "Idempotent-Replayed" not in first
    assert replay["Idempotent-Replayed"] == "true"
    assert replay.json() == first.json()
    assert Reservation.objects.count() == 1
    # The booking's events woke their handlers once, from the request that did the work: the
    # mail worker's (its e-mail) and the runs worker's (the live push that tells open
    # calendars to read again), in one callback at the commit. (The calendar's cache
    # generations moving on at commit is not a task.)
    wakes = [c for c in first_tasks if isinstance(c, _Wakes)]
    assert [sorted(str(queue) for queue in c.queues) for c in wakes] == [["None", "runs"]]
    assert replay_tasks == []


@pytest.mark.django_db
def test_the_same_key_with_another_body_gets_422_and_books_nothing(owner, client_for):
    node = FixedResourceFactory()
    client = client_for(owner)
    assert _post(client, _body(node), "k-1").status_code == 201
    reused = _post(client, _body(node, hours_ahead=48), "k-1")
    assert reused.status_code == 422
    assert reused.json()["error"] == "idempotency_key_reused"
    assert Reservation.objects.count() == 1


@pytest.mark.django_db
def test_a_refused_request_stores_no_key_so_its_retry_is_handled(owner, client_for):
    node = FixedResourceFactory()
    client = client_for(owner)
    body = _body(node)
    backwards = dict(body, end_at=body["start_at"], start_at=body["end_at"])
    assert _post(client, backwards, "k-1").status_code == 400
    assert not IdempotencyKey.objects.exists()
    retried = _post(client, body, "k-1")
    assert retried.status_code == 201
    assert "Idempotent-Replayed" not in retried


@pytest.mark.django_db
def test_keys_belong_to_their_user(owner, other, client_for):
    node = FixedResourceFactory()
    assert _post(client_for(owner), _body(node), "k-1").status_code == 201
    theirs = _post(client_for(other), _body(node, hours_ahead=48), "k-1")
    assert theirs.status_code == 201
    assert "Idempotent-Replayed" not in theirs
    assert Reservation.objects.count() == 2


@pytest.mark.django_db(transaction=True)
def test_a_duplicate_sent_while_the_first_runs_gets_409_then_the_replay(owner, client_for):
    node = FixedResourceFactory()
    body = _body(node)
    answered, release = threading.Event(), threading.Event()
    first: dict[str, Any] = {}

    def hold_before_commit(execute: Any, sql: str, params: Any, many: bool, context: Any) -> Any:
        result = execute(sql, params, many, context)
        if sql.startswith(STORE_ANSWER_SQL):
            answered.set()
            release.wait(timeout=60)
        return result

    def send_first() -> None:
        # Its own thread, so its own database connection and transaction.
        try:
            with connection.execute_wrapper(hold_before_commit):
                first["response"] = _post(client_for(owner), body, "k-1")
        finally:
            connection.close()

    thread = threading.Thread(target=send_first)
    thread.start()
    try:
        assert answered.wait(timeout=60), "the first request never reached its answer"
        client = client_for(owner)
        duplicate = _post(client, body, "k-1")
        assert duplicate.status_code == 409
        assert "still being handled" in duplicate.json()["detail"]
        # Until the first commits even another body cannot be told apart: also 409.
        assert _post(client, _body(node, hours_ahead=48), "k-1").status_code == 409
        assert not Reservation.objects.exists()
    finally:
        release.set()
        thread.join(timeout=60)
    assert first["response"].status_code == 201
    replay = _post(client_for(owner), body, "k-1")
    assert replay.status_code == 201
    assert replay["Idempotent-Replayed"] == "true"
    assert replay.json()["id"] == first["response"].json()["id"]
    assert Reservation.objects.count() == 1


def _backend_alive(pid: int) -> bool:
    with connection.cursor() as cursor:
        cursor.execute("SELECT 1 FROM pg_stat_activity WHERE pid = %s", [pid])
        return cursor.fetchone() is not None


@pytest.mark.django_db(transaction=True)
def test_a_request_killed_before_its_commit_leaves_nothing_and_its_retry_books_once(
    owner, client_for
):
    body = _body(FixedResourceFactory())
    db = settings.DATABASES["default"]
    env = dict(os.environ)
    env.update(
        {
            "DJANGO_SETTINGS_MODULE": "portal.settings",
            "DJANGO_DEBUG": "1",
            "DATABASE_URL": f"postgres://{db['USER']}@{db['HOST']}:{db['PORT']}/{db['NAME']}",
        }
    )
    child = Proc(
        "request",
        _holding_request_argv(owner.username, "k-1", body),
        env,
    )
    try:
        line = child.wait_for_line(lambda s: s.startswith(("holding", "not held")), 60)
        assert line.startswith("holding"), child.output()
        backend_pid = int(line.split()[1])
        # The child has booked and stored its answer but not committed: a duplicate gets 409.
        client = client_for(owner)
        assert _post(client, body, "k-1").status_code == 409
        assert not Reservation.objects.exists()
    finally:
        child.stop(signal.SIGKILL)
    assert child.popen.returncode == -signal.SIGKILL
    # PostgreSQL ends the dead client's session (and its transaction and lock) on its own.
    deadline = time.monotonic() + 30
    while _backend_alive(backend_pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _backend_alive(backend_pid)
    assert not Reservation.objects.exists()
    assert not IdempotencyKey.objects.exists()

    retried = _post(client, body, "k-1")
    assert retried.status_code == 201, retried.json()
    assert "Idempotent-Replayed" not in retried
    replay = _post(client, body, "k-1")
    assert replay["Idempotent-Replayed"] == "true"
    assert replay.json()["id"] == retried.json()["id"]
    assert Reservation.objects.count() == 1


@pytest.mark.django_db
def test_an_expired_key_is_handled_as_a_new_one(owner, client_for, settings):
    settings.IDEMPOTENCY_KEY_TTL_S = 60.0
    node = FixedResourceFactory()
    client = client_for(owner)
    body = _body(node)
    first = _post(client, body, "k-1")
    assert first.status_code == 201
    _age(by_s=61)
    # Not a replay: the booking is attempted again and meets the first one.
    again = _post(client, body, "k-1")
    assert again.status_code == 409
    assert "already booked" in again.json()["detail"]
    # Another body under the expired key is no reuse either: it books.
    later = _post(client, _body(node, hours_ahead=48), "k-1")
    assert later.status_code == 201
    assert "Idempotent-Replayed" not in later
    assert Reservation.objects.count() == 2
    stored = IdempotencyKey.objects.get()
    assert stored.response["id"] == later.json()["id"]


@pytest.mark.django_db
def test_an_unanswered_key_of_the_previous_release_answers_409_until_its_lease_ends(
    owner, client_for
):
    client = client_for(owner)
    body = _body(FixedResourceFactory())
    first = _post(client, body, "k-1")
    assert first.status_code == 201
    # The previous release committed the key (status null) before the work.
    IdempotencyKey.objects.update(status=None, response=None)
    assert client.delete(f"{URL}{first.json()['id']}/").status_code == 200
    assert _post(client, body, "k-1").status_code == 409
    _age(by_s=UNANSWERED_LEASE_S + 1)
    taken_over = _post(client, body, "k-1")
    assert taken_over.status_code == 201
    assert "Idempotent-Replayed" not in taken_over
    assert IdempotencyKey.objects.get().status == 201


def _key(owner: Any, name: str, *, age_s: float) -> IdempotencyKey:
    key = IdempotencyKey.objects.create(
        user=owner, key=name, method="POST", path=URL, request_hash="0" * 64, status=201
    )
    IdempotencyKey.objects.filter(pk=key.pk).update(
        created_at=timezone.now() - timedelta(seconds=age_s)
    )
    return key


@pytest.mark.django_db
def test_expired_keys_are_deleted_in_batches_and_fresh_ones_kept(owner, settings):
    settings.IDEMPOTENCY_KEY_TTL_S = 3600.0
    for i in range(5):
        _key(owner, f"old-{i}", age_s=3601 + i)
    fresh = {_key(owner, f"new-{i}", age_s=3599).key for i in range(2)}
    with CaptureQueriesContext(connection) as queries:
        deleted = idempotency_keys_delete_expired(batch_size=2)
    assert deleted == 5
    assert set(IdempotencyKey.objects.values_list("key", flat=True)) == fresh
    deletes = [q["sql"] for q in queries.captured_queries if q["sql"].startswith("DELETE")]
    assert len(deletes) == 3  # 2 + 2 + 1


@pytest.mark.django_db
def test_beat_runs_the_expiry_task_which_deletes_expired_keys(owner, settings):
    entries = [e for e in settings.CELERY_BEAT_SCHEDULE.values() if "idempotency" in e["task"]]
    assert [e["task"] for e in entries] == [tasks.idempotency_keys_delete_expired.name]
    _key(owner, "old", age_s=settings.IDEMPOTENCY_KEY_TTL_S + 1)
    _key(owner, "new", age_s=0)
    assert tasks.idempotency_keys_delete_expired.apply().get() == 1
    assert list(IdempotencyKey.objects.values_list("key", flat=True)) == ["new"]


# SQLite, the embedded mode of ``make run``: no advisory locks, IMMEDIATE transactions instead.
SQLITE_PRELUDE = (
    f"STORE_ANSWER_SQL = {STORE_ANSWER_SQL!r}\n"
    + r"""
import json, sys, threading
from datetime import timedelta
from django.db import connection
from django.utils import timezone
from rest_framework.test import APIClient
from bookings.models import Reservation, Resource
from core.accounts.models import User
from core.audit.idempotency import idempotency_keys_delete_expired
from core.audit.models import IdempotencyKey
from core.events.services import _Wakes

alice, _ = User.objects.get_or_create(username="alice")
Resource.objects.get_or_create(name="node-01", kind="fixed")
START = timezone.now().replace(microsecond=0) + timedelta(days=1)


def body(hours):
    start = START + timedelta(hours=hours)
    return {"resource": "node-01", "start_at": start.isoformat(),
            "end_at": (start + timedelta(hours=1)).isoformat()}


def post(b, key):
    client = APIClient(SERVER_NAME="localhost")
    client.force_authenticate(alice)
    r = client.post("/api/v1/reservations/", b, format="json", HTTP_X_IDEMPOTENCY_KEY=key)
    return [r.status_code, r.get("Idempotent-Replayed"), r.json().get("id")]
"""
)

SQLITE_REPLAYS = r"""
results = {"first": post(body(0), "k-1"), "replay": post(body(0), "k-1"),
           "reused": post(body(5), "k-1")}
IdempotencyKey.objects.update(created_at=timezone.now() - timedelta(days=2))
results["expired"] = post(body(5), "k-1")

# A duplicate sent while the first holds the database waits for it, then gets the replay.
answered, release, duplicate_begins = threading.Event(), threading.Event(), threading.Event()


def hold_before_commit(execute, sql, params, many, context):
    result = execute(sql, params, many, context)
    if sql.startswith(STORE_ANSWER_SQL):
        answered.set()
        release.wait(timeout=60)
    return result


def see_begin(execute, sql, params, many, context):
    if sql.startswith("BEGIN"):
        duplicate_begins.set()
    return execute(sql, params, many, context)


def in_thread(name, wrapper):
    def send():
        try:
            with connection.execute_wrapper(wrapper):
                results[name] = post(body(10), "k-2")
        finally:
            connection.close()
    thread = threading.Thread(target=send)
    thread.start()
    return thread


first = in_thread("held", hold_before_commit)
assert answered.wait(timeout=60)
duplicate = in_thread("duplicate", see_begin)
assert duplicate_begins.wait(timeout=60)
release.set()
first.join(timeout=60)
duplicate.join(timeout=60)
results["reservations"] = Reservation.objects.count()
IdempotencyKey.objects.update(created_at=timezone.now() - timedelta(days=2))
results["deleted"] = idempotency_keys_delete_expired()
print("results:", json.dumps(results))
"""


def _sqlite_results(lines: list[str]) -> dict[str, Any]:
    return json.loads(next(s for s in lines if s.startswith("results:")).split(":", 1)[1])


def test_on_sqlite_replays_reuse_expiry_and_a_waiting_duplicate_behave_alike(tmp_path):
    results = _sqlite_results(run_on_sqlite(SQLITE_PRELUDE + SQLITE_REPLAYS, tmp_path))
    status, replayed, first_id = results["first"]
    assert (status, replayed) == (201, None)
    assert results["replay"] == [201, "true", first_id]
    assert results["reused"][0] == 422
    status, replayed, expired_id = results["expired"]
    assert (status, replayed) == (201, None)
    assert expired_id != first_id
    status, replayed, held_id = results["held"]
    assert (status, replayed) == (201, None)
    assert results["duplicate"] == [201, "true", held_id]
    assert results["reservations"] == 3
    assert results["deleted"] == 2


def test_on_sqlite_a_request_killed_before_its_commit_leaves_nothing(tmp_path):
    run_on_sqlite(SQLITE_PRELUDE, tmp_path)  # the database, alice and node-01
    body = {
        "resource": "node-01",
        "start_at": (timezone.now() + timedelta(days=1)).replace(microsecond=0).isoformat(),
        "end_at": (timezone.now() + timedelta(days=1, hours=1)).replace(microsecond=0).isoformat(),
    }
    env = {k: v for k, v in os.environ.items() if k not in {"DATABASE_URL", "CELERY_BROKER_URL"}}
    env.update(
        {
            "DJANGO_SETTINGS_MODULE": "portal.settings",
            "DJANGO_DEBUG": "1",
            "AMAZING_VAR_DIR": str(tmp_path),
        }
    )
    child = Proc("request", _holding_request_argv("alice", "k-1", body), env)
    try:
        line = child.wait_for_line(lambda s: s.startswith(("holding", "not held")), 60)
        assert line.startswith("holding"), child.output()
    finally:
        child.stop(signal.SIGKILL)
    assert child.popen.returncode == -signal.SIGKILL
    retry = f"""
before = [Reservation.objects.count(), IdempotencyKey.objects.count()]
b = {body!r}
print("results:", json.dumps({{"before": before, "retry": post(b, "k-1"),
      "replay": post(b, "k-1"), "after": Reservation.objects.count()}}))
"""
    results = _sqlite_results(run_on_sqlite(SQLITE_PRELUDE + retry, tmp_path))
    assert results["before"] == [0, 0]
    status, replayed, reservation_id = results["retry"]
    assert (status, replayed) == (201, None)
    assert results["replay"] == [201, "true", reservation_id]
    assert results["after"] == 1
