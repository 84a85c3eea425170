"""Reactions to MFA changing: turned on, the account's other sessions end; turned off, its
staff tokens go.

Loaded by ``AccountsConfig.ready`` once the models are.
"""

from __future__ import annotations

from typing import Any

from allauth.mfa import signals as mfa_signals
from allauth.mfa.models import Authenticator
from django.db.models.signals import post_delete

from core.accounts.models import User
from core.accounts.services import staff_tokens_revoke, user_sessions_end


def mfa_added(
    sender: Any, request: Any, user: User, authenticator: Authenticator, **_: Any
) -> None:
    """A first factor set up: any session signed in before it (a password alone, perhaps
    someone else's) ends; the enrolment an admin allowed is used up."""
    if authenticator.type != Authenticator.Type.TOTP:
        return
    session = getattr(request, "session", None)
    user_sessions_end(user_id=user.pk, keep_session_key=getattr(session, "session_key", None))
    User.objects.filter(pk=user.pk, mfa_enrolment_allowed=True).update(mfa_enrolment_allowed=False)


def authenticator_deleted(sender: Any, instance: Authenticator, **_: Any) -> None:
    """MFA turned off (by its owner or in the admin site): the tokens minted with it go."""
    left = Authenticator.objects.filter(user_id=instance.user_id).exclude(
        type=Authenticator.Type.RECOVERY_CODES
    )
    if not left.exists():
        staff_tokens_revoke(user_id=instance.user_id, why="mfa turned off")


def connect() -> None:
    mfa_signals.authenticator_added.connect(mfa_added, dispatch_uid="accounts:mfa-added")
    post_delete.connect(
        authenticator_deleted, sender=Authenticator, dispatch_uid="accounts:mfa-deleted"
    )
