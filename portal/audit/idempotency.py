"""``X-Idempotency-Key`` on creating POSTs: a replay gets the stored answer.

A client that lost the answer to a POST sends it again with the same key and gets the same
answer instead of a second booking. A concurrent duplicate (the first still running) gets 409;
the same key with a different body gets 422. Only successful answers are stored, so a request
that failed can be retried with its key.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from functools import wraps
from typing import Any

from django.db import IntegrityError, transaction
from rest_framework.request import Request
from rest_framework.response import Response

from portal.accounts.models import User
from portal.audit.models import IdempotencyKey

HEADER = "X-Idempotency-Key"
MAX_KEY_LENGTH = 128

ViewMethod = Callable[..., Response]


def _request_hash(request: Request) -> str:
    body = json.dumps(request.data, sort_keys=True, default=str)
    return hashlib.sha256(f"{request.method} {request.path}\n{body}".encode()).hexdigest()


def idempotent(method: ViewMethod) -> ViewMethod:
    @wraps(method)
    def wrapper(view: Any, request: Request, *args: Any, **kwargs: Any) -> Response:
        key = request.headers.get(HEADER)
        if not key:
            return method(view, request, *args, **kwargs)
        if len(key) > MAX_KEY_LENGTH or not key.isprintable():
            return Response(
                {
                    "error": "invalid",
                    "detail": f"{HEADER} must be printable, ≤ {MAX_KEY_LENGTH} characters.",
                },
                status=400,
            )
        digest = _request_hash(request)
        user = request.user
        assert isinstance(user, User)  # creating views require authentication
        try:
            with transaction.atomic():
                record = IdempotencyKey.objects.create(
                    user=user,
                    key=key,
                    method=str(request.method),
                    path=request.path[:255],
                    request_hash=digest,
                )
        except IntegrityError:
            existing = IdempotencyKey.objects.get(user=user, key=key)
            if existing.request_hash != digest:
                return Response(
                    {
                        "error": "idempotency_key_reused",
                        "detail": f"This {HEADER} was used for a different request.",
                    },
                    status=422,
                )
            if existing.status is None:
                return Response(
                    {
                        "error": "conflict",
                        "detail": f"A request with this {HEADER} is still being handled.",
                    },
                    status=409,
                )
            return Response(
                existing.response, status=existing.status, headers={"Idempotent-Replayed": "true"}
            )
        try:
            response = method(view, request, *args, **kwargs)
        except BaseException:
            record.delete()
            raise
        if 200 <= response.status_code < 300:
            record.status = response.status_code
            record.response = json.loads(json.dumps(response.data, default=str))
            record.save(update_fields=["status", "response"])
        else:
            record.delete()
        return response

    return wrapper
