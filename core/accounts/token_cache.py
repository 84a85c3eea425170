"""Where the API token cache keeps a token's user, and when it forgets it
(``core/accounts/tokens.py`` reads it; the receivers are connected in ``apps.py``)."""

from __future__ import annotations

import hashlib
from typing import Any

from django.core.cache import cache
from django.core.exceptions import ObjectDoesNotExist
from django.db import connection, transaction

from core.cache import database_namespace

TOKEN_USER_CACHE_S = 60


def cache_key(token_key: str) -> str:
    # A digest: the cache never holds a usable token.
    digest = hashlib.blake2b(token_key.encode(), digest_size=16).hexdigest()
    return f"token-user:{database_namespace()}:{digest}"


def forget_tokens(*token_keys: str) -> None:
    """Drop the cached users of ``token_keys``, now and once the transaction commits."""
    keys = [cache_key(k) for k in token_keys]
    if not keys:
        return
    cache.delete_many(keys)
    if not connection.get_autocommit():
        transaction.on_commit(lambda: cache.delete_many(keys))


def token_deleted(sender: Any, instance: Any, **_: Any) -> None:
    forget_tokens(instance.key)


def user_saved(sender: Any, instance: Any, created: bool, **_: Any) -> None:
    """A user saved (deactivated, made staff or not, renamed): its token's entry goes."""
    if created:
        return
    try:
        key = instance.auth_token.key
    except ObjectDoesNotExist:
        return
    forget_tokens(key)
