"""API token authentication that remembers whom a token belongs to.

Tokens are ``ApiToken`` rows (django-rest-knox's model: a SHA-512 digest, never the token).
Reading one and its user from the database on every call would cost about half of what a
small API answer costs, so the user a token names is kept in the cache for
``TOKEN_USER_CACHE_S`` under the token's digest, without its password hash (deferred: a
save of the cached user never writes it). A hit is one cache GET and one SHA-512 of the
token, no database at all. The entry goes when the token is deleted (or its user), whenever
the user is saved (deactivated, made staff or not) and when the user's MFA changes, at once
and again when the transaction commits. A bulk update of users bypasses that: it takes
effect within ``TOKEN_USER_CACHE_S``.

Since a token is read from the database at most once per ``TOKEN_USER_CACHE_S``, that read
is also when its last use is written: at most once a minute per token, never per request.
"""

from __future__ import annotations

from datetime import datetime, timedelta

from django.core.cache import cache
from django.utils import timezone
from knox.crypto import hash_token
from rest_framework import exceptions
from rest_framework.authentication import TokenAuthentication

from core.accounts.mfa import mfa_enabled
from core.accounts.models import ApiToken, User
from core.accounts.staff import has_staff_role
from core.accounts.token_cache import TOKEN_USER_CACHE_S, cache_key


def token_digest(token: str) -> str:
    """The digest an ``ApiToken`` is stored under (knox's hash)."""
    return hash_token(token)


class CachedTokenAuthentication(TokenAuthentication):
    """``Authorization: Token <token>``, as DRF's, answered from the cache when it can."""

    def authenticate_credentials(self, key: str) -> tuple[User, ApiToken]:
        digest = token_digest(key)
        entry = cache_key(digest)
        now = timezone.now()
        cached = cache.get(entry)
        if isinstance(cached, tuple) and len(cached) == 3 and isinstance(cached[0], User):
            user, expiry, mfa_verified = cached
        else:
            user, expiry, mfa_verified = _token_user(digest, now)
            ttl_s = TOKEN_USER_CACHE_S
            if expiry is not None:
                ttl_s = min(ttl_s, max(1, int((expiry - now).total_seconds())))
            cache.set(entry, (user, expiry, mfa_verified), ttl_s)
        if expiry is not None and expiry <= now:
            raise exceptions.AuthenticationFailed("Token expired.")
        # The door's answer for the services (core/accounts/staff.py): a staff account's
        # powers come only with a token minted from a session that passed its second factor.
        user.staff_verified = mfa_verified and has_staff_role(user)
        # The token as DRF hands it on (``request.auth``), without a second read.
        return user, ApiToken(digest=digest, user=user, expiry=expiry, mfa_verified=mfa_verified)


def _token_user(digest: str, now: datetime) -> tuple[User, datetime | None, bool]:
    """The token's user from the database, refused unless it may use the API now."""
    try:
        token = ApiToken.objects.select_related("user").defer("user__password").get(digest=digest)
    except ApiToken.DoesNotExist:
        raise exceptions.AuthenticationFailed("Invalid token.") from None
    if token.expiry is not None and token.expiry <= now:
        raise exceptions.AuthenticationFailed("Token expired.")
    user = token.user
    if not user.is_active:
        raise exceptions.AuthenticationFailed("User inactive or deleted.")
    if user.has_staff_role and not mfa_enabled(user):
        raise exceptions.AuthenticationFailed("A staff account's token needs MFA turned on.")
    ApiToken.objects.filter(digest=digest).exclude(
        last_used_at__gt=now - timedelta(seconds=TOKEN_USER_CACHE_S)
    ).update(last_used_at=now)
    return user, token.expiry, token.mfa_verified
