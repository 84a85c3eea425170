"""``X-Idempotency-Key`` on creating POSTs: a replay gets the stored answer.

A client that lost the answer to a POST sends it again with the same key and gets the same
answer, marked ``Idempotent-Replayed: true``, instead of a second booking. The same key with a
different body gets 422; a duplicate sent while the first is still being handled gets 409.
Only successful answers are stored, so a request that failed can be retried with its key.
Keys are kept for ``IDEMPOTENCY_KEY_TTL_S`` (beat deletes older ones); an expired key is new.

The key is stored with the work, in one transaction
---------------------------------------------------
The view runs inside a transaction that also stores the key with its answer. A request killed
half-way (SIGKILL, out of memory, eviction) therefore leaves nothing behind: the database rolls
back its booking and its key together, and a retry with the same key does the work once.
Whatever the view queued with ``transaction.on_commit`` runs only once the answer is stored,
and a replay never calls the view, so it queues nothing.

We chose this over claiming the key first with a lease (``locked_until``) because a lease must
be longer than the slowest request yet short enough for a client to wait out: a retry after a
kill gets 409 until the lease runs out, and a request slower than its lease runs twice. Here a
retry succeeds as soon as the killed request's connection is gone.

A duplicate that arrives while the first is still running is recognised without waiting:

- PostgreSQL: the request first takes a transaction-level advisory lock on a hash of
  (user, key) with ``pg_try_advisory_xact_lock``; a duplicate that cannot take it gets 409 at
  once. The lock ends with the transaction, also when the server drops the connection of a
  killed process, so no key stays locked (and it is safe with pooled connections). A host
  that vanishes without closing its connections is noticed through TCP keepalives or the
  server's ``idle_in_transaction_session_timeout``; production should set one of them.
- SQLite (the embedded mode of ``make run``): every transaction begins IMMEDIATE (see
  settings), so writing requests already run one at a time; a duplicate waits for the first
  to commit and then gets its replay.

The unique constraint on (user, key) backs both: one key never gets two answers, and a
request that loses such a race rolls its work back.

Inside this transaction the services' own ``atomic()`` blocks become savepoints and their row
locks are held until the answer is stored. A view whose service needs a durable transaction
cannot be decorated.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Callable
from datetime import datetime, timedelta
from functools import wraps
from typing import Any

from django.conf import settings
from django.db import transaction
from django.utils import timezone
from rest_framework.request import Request
from rest_framework.response import Response

from core import sql
from core.accounts.models import User
from core.audit.models import IdempotencyKey

logger = logging.getLogger(__name__)

HEADER = "X-Idempotency-Key"
MAX_KEY_LENGTH = 128
# Printable ASCII, as the OpenAPI description states it (HTTP headers carry no more safely).
KEY_PATTERN = re.compile(r"[ -~]+")
# A row without an answer was written by the previous release, which committed the key before
# the work. During a rolling upgrade its request may still be running: such a row answers 409
# for this long after it was written and is then taken over. No request runs this long.
UNANSWERED_LEASE_S = 600.0
EXPIRE_BATCH_SIZE = 1000

ViewMethod = Callable[..., Response]


def _request_hash(request: Request) -> str:
    body = json.dumps(request.data, sort_keys=True, default=str)
    return hashlib.sha256(f"{request.method} {request.path}\n{body}".encode()).hexdigest()


def _ttl() -> timedelta:
    return timedelta(seconds=settings.IDEMPOTENCY_KEY_TTL_S)


def _lock_id(*, user_id: int, key: str) -> int:
    """A signed 64-bit advisory lock id; a collision only costs a spurious 409."""
    digest = hashlib.sha256(f"idempotency-key\0{user_id}\0{key}".encode()).digest()
    return sql.advisory_key(digest)


def _key_lock(*, user_id: int, key: str) -> bool:
    """Take the key for this transaction; False if a concurrent request holds it (on SQLite
    the IMMEDIATE transaction already holds the database: always True)."""
    return sql.try_advisory_xact_lock(_lock_id(user_id=user_id, key=key))


def _in_progress() -> Response:
    return Response(
        {"error": "conflict", "detail": f"A request with this {HEADER} is still being handled."},
        status=409,
    )


def _answer(*, stored: IdempotencyKey, digest: str, now: datetime) -> Response | None:
    """The answer a stored key gives, or None when the request is to be handled as new."""
    if stored.request_hash != digest:
        return Response(
            {
                "error": "idempotency_key_reused",
                "detail": f"This {HEADER} was used for a different request.",
            },
            status=422,
        )
    if stored.status is None:
        if stored.created_at > now - timedelta(seconds=UNANSWERED_LEASE_S):
            return _in_progress()
        return None
    return Response(stored.response, status=stored.status, headers={"Idempotent-Replayed": "true"})


def idempotent(method: ViewMethod) -> ViewMethod:
    @wraps(method)
    def wrapper(view: Any, request: Request, *args: Any, **kwargs: Any) -> Response:
        key = request.headers.get(HEADER)
        if key is None:
            return method(view, request, *args, **kwargs)
        # Present but empty is refused like any other malformed key (the schema's minLength).
        if len(key) > MAX_KEY_LENGTH or not KEY_PATTERN.fullmatch(key):
            return Response(
                {
                    "error": "invalid",
                    "detail": f"{HEADER} must be printable ASCII, ≤ {MAX_KEY_LENGTH} characters.",
                },
                status=400,
            )
        digest = _request_hash(request)
        user = request.user
        assert isinstance(user, User)  # creating views require authentication
        with transaction.atomic():
            if not _key_lock(user_id=user.pk, key=key):
                return _in_progress()
            now = timezone.now()
            stored = IdempotencyKey.objects.filter(user=user, key=key).first()
            if stored is not None and stored.created_at > now - _ttl():
                answer = _answer(stored=stored, digest=digest, now=now)
                if answer is not None:
                    return answer
            # New, expired or abandoned: the view does the work.
            response = method(view, request, *args, **kwargs)
            if 200 <= response.status_code < 300:
                if stored is not None:
                    # Replaced only now, with the new answer: a failed view leaves it as it was.
                    IdempotencyKey.objects.filter(pk=stored.pk).delete()
                IdempotencyKey.objects.create(
                    user=user,
                    key=key,
                    method=str(request.method),
                    path=request.path[:255],
                    request_hash=digest,
                    status=response.status_code,
                    response=json.loads(json.dumps(response.data, default=str)),
                )
        return response

    # Read by the OpenAPI description (core.openapi): the header, 409 and 422 apply here.
    wrapper.idempotency_key = True  # type: ignore[attr-defined]
    return wrapper


def idempotency_keys_delete_expired(
    *, now: datetime | None = None, batch_size: int = EXPIRE_BATCH_SIZE
) -> int:
    """Delete the keys older than ``IDEMPOTENCY_KEY_TTL_S``; the number deleted.

    One short DELETE per batch, each its own transaction, so the clean-up never holds many
    row locks at once against the requests that write keys.
    """
    now = now or timezone.now()
    expired = IdempotencyKey.objects.filter(created_at__lte=now - _ttl())
    deleted_total = 0
    while True:
        batch = list(expired.order_by("pk").values_list("pk", flat=True)[:batch_size])
        if not batch:
            break
        # The cut-off again in the DELETE: a key stored anew since the SELECT stays.
        deleted, _ = expired.filter(pk__in=batch).delete()
        deleted_total += deleted
        if len(batch) < batch_size:
            break
    if deleted_total:
        logger.info("deleted %d expired idempotency keys", deleted_total)
    return deleted_total
