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

import hashlib
from typing import Any

from django.core.cache import cache
from django.db import connection, transaction
from django.db.models.signals import post_delete, post_save
from django.dispatch import receiver
from rest_framework import exceptions
from rest_framework.authentication import TokenAuthentication
from rest_framework.authtoken.models import Token

from core.accounts.models import User
from core.cache import database_namespace

TOKEN_USER_CACHE_S = 60


def _cache_key(token_key: str) -> str:
    # A digest: the cache never holds a usable token.
    digest = hashlib.blake2b(token_key.encode(), digest_size=16).hexdigest()
    return f"token-user:{database_namespace()}:{digest}"


class CachedTokenAuthentication(TokenAuthentication):
    """``Authorization: Token <key>``, as DRF's, answered from the cache when it can."""

    def authenticate_credentials(self, key: str) -> tuple[User, Token]:
        cache_key = _cache_key(key)
        user = cache.get(cache_key)
        if not isinstance(user, User):
            try:
                token = Token.objects.select_related("user").defer("user__password").get(key=key)
            except Token.DoesNotExist:
                raise exceptions.AuthenticationFailed("Invalid token.") from None
            user = token.user
            if user.is_active:
                cache.set(cache_key, user, TOKEN_USER_CACHE_S)
        if not user.is_active:
            raise exceptions.AuthenticationFailed("User inactive or deleted.")
        # The token object as DRF hands it on (``request.auth``), without a second read.
        return user, Token(key=key, user=user)


def forget_tokens(*token_keys: str) -> None:
    """Drop the cached users of ``token_keys``, now and once the transaction commits."""
    keys = [_cache_key(k) for k in token_keys]
    if not keys:
        return
    cache.delete_many(keys)
    if not connection.get_autocommit():
        transaction.on_commit(lambda: cache.delete_many(keys))


@receiver(post_delete, sender=Token, dispatch_uid="tokens:forget-deleted")
def _token_deleted(sender: type[Token], instance: Token, **_: Any) -> None:
    forget_tokens(instance.key)


@receiver(post_save, sender=User, dispatch_uid="tokens:forget-saved-user")
def _user_saved(sender: type[User], instance: User, created: bool, **_: Any) -> None:
    if not created:
        forget_tokens(*Token.objects.filter(user=instance).values_list("key", flat=True))
