from __future__ import annotations

from datetime import datetime

from django.conf import settings
from django.contrib.auth.models import AbstractUser
from django.db import models
from knox.models import AbstractAuthToken


class User(AbstractUser):  # type: ignore[django-manager-missing]
    """A person who uses the testbed.

    Experimenters book and run experiments; staff users (``is_staff``) are the testbed's
    admins. Kept as our own model from the first migration so that profile fields (group,
    affiliation, quota policy) can be added without a painful swap later.
    """

    @property
    def is_testbed_admin(self) -> bool:
        return self.is_staff or self.is_superuser


class ApiToken(AbstractAuthToken):
    """A named API token of a user: ``Authorization: Token <token>``.

    django-rest-knox's model, for what a self-service token needs and DRF's ``authtoken``
    lacks: only a SHA-512 digest is stored (the token itself is shown once, at creation), a
    user holds any number of them, each with an optional expiry. Knox's own authentication
    is not used: it reads the database and hashes on every request, where ours
    (``core.accounts.tokens``) answers from the cache and looks a digest up by its key.
    """

    # Annotated: mypy sees knox's base as untyped.
    user: models.ForeignKey[User, User] = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="api_tokens"
    )
    name: models.CharField[str, str] = models.CharField(max_length=100)
    # When the token was last used, to the minute: written at most once a minute per token.
    last_used_at: models.DateTimeField[datetime | None, datetime | None] = models.DateTimeField(
        null=True, blank=True
    )

    class Meta:
        ordering = ["-created"]
        verbose_name = "API token"

    def __str__(self) -> str:
        return f"{self.name} ({self.token_key}…)"
