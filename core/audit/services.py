from __future__ import annotations

from typing import Any

from django.db import models
from django.http import HttpRequest

from core.accounts.models import User
from core.audit.models import AuditEvent
from core.audit.text import storable_text
from core.http import client_address


def client_ip(request: HttpRequest | Any | None) -> str | None:
    """The client's address for an audit row: ``core.http.client_address``, the same as the
    sign-in limits and the throttles count by."""
    if request is None:
        return None
    return client_address(request)


def audit_record(
    *,
    actor: User | None,
    action: str,
    target: models.Model | None = None,
    reason: str = "",
    ip: str | None = None,
    **data: Any,
) -> AuditEvent:
    return AuditEvent.objects.create(
        actor=actor,
        actor_name=actor.get_username() if actor is not None else "system",
        action=action,
        target_type=target._meta.label_lower if target is not None else "",
        target_id=str(target.pk) if target is not None else "",
        ip=ip,
        reason=storable_text(reason),
        data=data,
    )
