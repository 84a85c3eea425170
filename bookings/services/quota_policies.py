"""Quota policies: created and changed by an admin, the old and new values audited."""

from __future__ import annotations

from typing import Any

from django.db import transaction

from bookings.models import QuotaPolicy
from core.accounts.models import User
from core.audit.services import audit_record
from core.errors import InvalidInput, NotAllowed

QUOTA_FIELDS = (
    "name",
    "user",
    "group",
    "resource",
    "resource_group",
    "period",
    "max_hours",
    "max_count",
    "max_length_s",
    "min_notice_s",
    "max_advance_s",
    "max_future",
    "active",
)


def quota_policy_save(
    *, by: User, policy: QuotaPolicy | None = None, ip: str | None = None, **fields: Any
) -> QuotaPolicy:
    """Create or change a quota policy; the audit log keeps the old and new values."""
    if not by.is_testbed_admin:
        raise NotAllowed("Only admins set quotas.")
    unknown = set(fields) - set(QUOTA_FIELDS)
    if unknown:
        raise InvalidInput(f"Unknown quota fields: {', '.join(sorted(unknown))}.")
    creating = policy is None
    policy = policy or QuotaPolicy()
    before = {f: _plain(getattr(policy, f, None)) for f in QUOTA_FIELDS} if not creating else {}
    for name, value in fields.items():
        setattr(policy, name, value)
    if (policy.max_hours is not None or policy.max_count is not None) and not policy.period:
        raise InvalidInput.on_field("period", "A limit in hours or count needs a period.")
    with transaction.atomic():
        policy.full_clean()
        policy.save()
        audit_record(
            actor=by,
            action="quota.create" if creating else "quota.change",
            target=policy,
            ip=ip,
            before=before,
            after={f: _plain(getattr(policy, f, None)) for f in QUOTA_FIELDS},
        )
    return policy


def _plain(value: Any) -> Any:
    return str(value) if hasattr(value, "pk") else value
