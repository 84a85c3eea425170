"""Where the API token cache keeps a token's user, and when it forgets it
(``core/accounts/tokens.py`` reads it; the receivers are connected in ``apps.py``)."""

from __future__ import annotations

from typing import Any

from django.apps import apps
from django.core.cache import cache
from django.db import connection, transaction

from core.cache import database_namespace

TOKEN_USER_CACHE_S = 60


def cache_key(digest: str) -> str:
    # By the token's digest, as the database keeps it: the cache never holds a usable token.
    return f"token-user:{database_namespace()}:{digest}"


def forget_tokens(*digests: str) -> None:
    """Drop the cached users of the tokens ``digests``, now and once the transaction commits."""
    keys = [cache_key(d) for d in digests]
    if not keys:
        return
    cache.delete_many(keys)
    if not connection.get_autocommit():
        transaction.on_commit(lambda: cache.delete_many(keys))


def forget_user_tokens(user_id: int) -> None:
    """Drop the cached entries of every token of a user (its account or MFA changed)."""
    # By name: this module is imported by the app config, before the models are.
    tokens = apps.get_model("accounts", "ApiToken").objects.filter(user_id=user_id)
    forget_tokens(*tokens.values_list("digest", flat=True))


def token_deleted(sender: Any, instance: Any, **_: Any) -> None:
    forget_tokens(instance.digest)


def user_saved(
    sender: Any, instance: Any, created: bool, update_fields: Any = None, **_: Any
) -> None:
    """A user saved (deactivated, made staff or not, renamed): its tokens' entries go."""
    if created or (update_fields is not None and set(update_fields) == {"last_login"}):
        return
    forget_user_tokens(instance.pk)


def authenticator_changed(sender: Any, instance: Any, **_: Any) -> None:
    """MFA added or removed: a staff user's tokens work only with it (``tokens.py``)."""
    forget_user_tokens(instance.user_id)
