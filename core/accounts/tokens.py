"""API token authentication that remembers whom a token belongs to.

DRF's ``TokenAuthentication`` reads the token and its user from the database on every call:
a join the ORM builds afresh each time, about half of what a small API answer costs. Here the
user a token names is kept in the cache for ``TOKEN_USER_CACHE_S``, without its password
hash (deferred: a save of the cached user never writes it). The entry goes when the token is
deleted (or its user, which deletes the token) and whenever the user is saved (deactivated,
made staff or not), at once and again when the transaction commits. A bulk update of users
bypasses that: it takes effect within ``TOKEN_USER_CACHE_S``.
"""

from __future__ import annotations

from django.core.cache import cache
from rest_framework import exceptions
from rest_framework.authentication import TokenAuthentication
from rest_framework.authtoken.models import Token

from core.accounts.models import User
from core.accounts.token_cache import TOKEN_USER_CACHE_S, cache_key


class CachedTokenAuthentication(TokenAuthentication):
    """``Authorization: Token <key>``, as DRF's, answered from the cache when it can."""

    def authenticate_credentials(self, key: str) -> tuple[User, Token]:
        entry = cache_key(key)
        user = cache.get(entry)
        if not isinstance(user, User):
            try:
                token = Token.objects.select_related("user").defer("user__password").get(key=key)
            except Token.DoesNotExist:
                raise exceptions.AuthenticationFailed("Invalid token.") from None
            user = token.user
            if user.is_active:
                cache.set(entry, user, TOKEN_USER_CACHE_S)
        if not user.is_active:
            raise exceptions.AuthenticationFailed("User inactive or deleted.")
        # The token object as DRF hands it on (``request.auth``), without a second read.
        return user, Token(key=key, user=user)
