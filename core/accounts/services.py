"""Writes on accounts: API tokens (created, revoked), sessions ended, the audit of sign-ins."""

from __future__ import annotations

from datetime import timedelta

from allauth.core import ratelimit
from allauth.mfa import signals as mfa_signals
from allauth.mfa.models import Authenticator
from django.conf import settings
from django.contrib.auth import SESSION_KEY, authenticate
from django.contrib.sessions.models import Session
from django.db import transaction
from django.http import HttpRequest
from django.utils import timezone

from core.accounts.mfa import mfa_code_check, mfa_enabled
from core.accounts.models import ApiToken, User
from core.audit.services import audit_record, client_ip
from core.errors import Busy, DomainError, InvalidInput, NotAllowed

TOKEN_NAME_MAX_LENGTH = ApiToken._meta.get_field("name").max_length or 100
# Up to ten years; without a number of days a token lasts until it is revoked.
TOKEN_EXPIRY_MAX_DAYS = 3650


def api_token_create(
    *,
    user: User,
    name: str,
    expires_in_days: int | None = None,
    mfa_verified: bool = False,
    ip: str | None = None,
) -> tuple[ApiToken, str]:
    """A new token for ``user``: the row, and the token itself (shown once, never stored).

    ``mfa_verified``: the door's answer (``core.accounts.staff.staff_verified``, or the code
    given with the password): a staff account gets a token only so, and it expires within
    ``STAFF_API_TOKEN_DAYS``."""
    name = name.strip()
    if not name:
        raise InvalidInput.on_field("name", "Give the token a name.")
    if len(name) > TOKEN_NAME_MAX_LENGTH:
        raise InvalidInput.on_field(
            "name", f"A token's name is at most {TOKEN_NAME_MAX_LENGTH} characters."
        )
    if expires_in_days is not None and not 1 <= expires_in_days <= TOKEN_EXPIRY_MAX_DAYS:
        raise InvalidInput.on_field(
            "expires_in_days", f"A token expires in 1 to {TOKEN_EXPIRY_MAX_DAYS} days."
        )
    if user.has_staff_role:
        if not (mfa_verified and mfa_enabled(user)):
            raise NotAllowed(
                "A staff account gets API tokens only in a session signed in with its second "
                "factor: sign in with it."
            )
        staff_days = settings.STAFF_API_TOKEN_DAYS
        if expires_in_days is None:
            expires_in_days = staff_days
        elif expires_in_days > staff_days:
            raise InvalidInput.on_field(
                "expires_in_days", f"A staff account's token expires within {staff_days} days."
            )
    mfa_verified = mfa_verified and user.has_staff_role
    expiry = timedelta(days=expires_in_days) if expires_in_days is not None else None
    with transaction.atomic():
        token, secret = ApiToken.objects.create(
            user=user, expiry=expiry, name=name, mfa_verified=mfa_verified
        )
        audit_record(
            actor=user,
            action="api_token.create",
            # Named by its first characters: its key (a digest) is longer than a target id.
            ip=ip,
            name=name,
            token_key=token.token_key,
            expiry=token.expiry.isoformat() if token.expiry else None,
        )
    return token, secret


def api_token_revoke(*, user: User, digest: str, ip: str | None = None) -> None:
    """Revoke one of ``user``'s own tokens; it is refused at once (its cache entry goes)."""
    with transaction.atomic():
        token = ApiToken.objects.filter(user=user, digest=digest).first()
        if token is None:
            raise InvalidInput("No such token of yours.")
        audit_record(
            actor=user,
            action="api_token.revoke",
            ip=ip,
            name=token.name,
            token_key=token.token_key,
        )
        token.delete()


class SignInFailed(DomainError):
    # 400, not 401: the request carried no credentials of the API's kind (a token).
    http_status = 400
    code = "sign_in_failed"


class MfaCodeRequired(DomainError):
    """The account has MFA: the same request again, with the code from the app."""

    http_status = 400
    code = "mfa_required"


# The sign-in limits' shortest window (ACCOUNT_RATE_LIMITS): the least a client must wait.
SIGN_IN_RETRY_AFTER_S = 60


class TooManyAttempts(Busy):
    """The sign-in limits refuse: 429 with ``Retry-After``, as every other throttle."""

    def __init__(self, message: str) -> None:
        super().__init__(message, retry_after_s=SIGN_IN_RETRY_AFTER_S)


def api_token_sign_in(
    *,
    request: HttpRequest,
    username: str,
    password: str,
    code: str = "",
    name: str,
    expires_in_days: int | None = None,
) -> tuple[ApiToken, str]:
    """A new token for whoever signs in with ``username``/``password`` (and an MFA code when
    the account has MFA): ``amazing login``. The sign-in rate limits of the pages apply."""
    key = username.strip().lower()
    if not ratelimit.consume(request, action="login", key=key) or not ratelimit.consume(
        request, action="login_failed", key=key, dry_run=True
    ):
        raise TooManyAttempts("Too many sign-in attempts: wait a minute and try again.")
    user = authenticate(request, username=username.strip(), password=password)
    if not isinstance(user, User):
        ratelimit.consume(request, action="login_failed", key=key)
        raise SignInFailed("The username or the password is wrong.")
    verified = mfa_enabled(user)
    if verified:
        if not code.strip():
            raise MfaCodeRequired(
                "This account has two-factor authentication: give the code from its app."
            )
        if not _mfa_code_valid(request, user, code.strip()):
            ratelimit.consume(request, action="login_failed", key=key)
            raise SignInFailed("The two-factor code is wrong or was used already.")
    ratelimit.clear(request, action="login_failed", key=key)
    token, secret = api_token_create(
        user=user,
        name=name,
        expires_in_days=expires_in_days,
        mfa_verified=verified,
        ip=client_ip(request),
    )
    audit_record(actor=user, action="account.sign_in", ip=client_ip(request), via="api")
    return token, secret


def _mfa_code_valid(request: HttpRequest, user: User, code: str) -> bool:
    """A TOTP code (each accepted once) or an unused recovery code, as the pages take them."""
    if mfa_code_check(user, code) is not None:
        return True
    mfa_signals.authentication_failed.send(
        sender=Authenticator, request=request, user=user, authenticator=None
    )
    return False


def api_token_sign_out(*, user: User, token: ApiToken, ip: str | None = None) -> None:
    """Revoke the token a request came with (``amazing logout``)."""
    api_token_revoke(user=user, digest=token.digest, ip=ip)


def staff_tokens_revoke(*, user_id: int, why: str) -> int:
    """Revoke every token minted with the second factor of an account whose MFA is off:
    a staff token is only as good as the factor it was minted with."""
    with transaction.atomic():
        tokens = list(ApiToken.objects.filter(user_id=user_id, mfa_verified=True))
        for token in tokens:
            audit_record(
                actor=None,
                action="api_token.revoke",
                name=token.name,
                token_key=token.token_key,
                owner_id=user_id,
                why=why,
            )
            token.delete()
    return len(tokens)


def user_sessions_end(*, user_id: int, keep_session_key: str | None = None) -> int:
    """End every session of the account but ``keep_session_key`` (the one that asked)."""
    ended = []
    for session in Session.objects.filter(expire_date__gt=timezone.now()).iterator():
        if session.session_key == keep_session_key:
            continue
        if str(session.get_decoded().get(SESSION_KEY)) == str(user_id):
            ended.append(session.session_key)
    Session.objects.filter(session_key__in=ended).delete()
    return len(ended)
