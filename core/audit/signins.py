"""Sign-ins and their failures in the audit log: password, MFA code and API token sign-ins.

Loaded by ``AuditConfig.ready`` once the models are (its receivers write ``AuditEvent``s).
"""

from __future__ import annotations

from typing import Any

from allauth.mfa import signals as mfa_signals
from django.contrib.auth import signals as auth_signals

from core.accounts.models import User
from core.audit.services import audit_record, client_ip


def signed_in(sender: Any, request: Any, user: User, **_: Any) -> None:
    audit_record(actor=user, action="account.sign_in", ip=client_ip(request))


def sign_in_failed(sender: Any, credentials: dict[str, Any], request: Any = None, **_: Any) -> None:
    # Django hands on the credentials with the password already masked; only the name is kept.
    name = str(credentials.get("username") or credentials.get("email") or "")[:150]
    user = User.objects.filter(username=name).first() if name else None
    audit_record(actor=user, action="account.sign_in_failed", ip=client_ip(request), username=name)


def mfa_failed(sender: Any, request: Any, user: User, **kwargs: Any) -> None:
    authenticator = kwargs.get("authenticator")
    audit_record(
        actor=user,
        action="account.mfa_failed",
        ip=client_ip(request),
        kind=getattr(authenticator, "type", ""),
    )


def signed_out(sender: Any, request: Any, user: User | None, **_: Any) -> None:
    if user is not None:
        audit_record(actor=user, action="account.sign_out", ip=client_ip(request))


def connect() -> None:
    auth_signals.user_logged_in.connect(signed_in, dispatch_uid="audit:sign-in")
    auth_signals.user_login_failed.connect(sign_in_failed, dispatch_uid="audit:sign-in-failed")
    auth_signals.user_logged_out.connect(signed_out, dispatch_uid="audit:sign-out")
    mfa_signals.authentication_failed.connect(mfa_failed, dispatch_uid="audit:mfa-failed")
