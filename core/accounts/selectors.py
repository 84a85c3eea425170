"""Reads on accounts."""

from __future__ import annotations

from django.db.models import QuerySet

from core.accounts.models import ApiToken, User


def api_tokens_of(user: User) -> QuerySet[ApiToken]:
    """A user's API tokens, newest first (expired ones too, until revoked)."""
    return ApiToken.objects.filter(user=user).order_by("-created")
