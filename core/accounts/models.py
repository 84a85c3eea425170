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

    # Another admin (the admin site, or ``manage.py mfa_enrolment_allow``) lets this staff
    # account set up its first factor: a password alone must not choose the second factor.
    # Cleared once it has.
    # A database default too: rows written by code that predates the column (a migration's
    # historical model, another version during a rolling deploy) still insert.
    mfa_enrolment_allowed: models.BooleanField[bool, bool] = models.BooleanField(
        default=False,
        db_default=False,
        help_text="A staff account may set up its first second factor (cleared once it has).",
    )

    # Set by the door a request came through (``core.accounts.staff``): its session passed
    # the second factor, or its API token was minted from such a session. Never stored; a
    # user read outside a request (a task, a command) has no staff powers through it.
    staff_verified: bool = False

    @property
    def has_staff_role(self) -> bool:
        """The account is an admin's: what it may do depends on how it signed in."""
        return self.is_staff or self.is_superuser

    @property
    def is_testbed_admin(self) -> bool:
        """An admin with its powers now: the staff role, through a door that checked the
        second factor (``core.accounts.staff.staff_verified``)."""
        return self.has_staff_role and self.staff_verified


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

    # Minted from a session that passed its second factor (or with its code): only such a
    # token of a staff account carries the staff powers, and it always expires.
    mfa_verified: models.BooleanField[bool, bool] = models.BooleanField(
        default=False, db_default=False
    )

    class Meta:
        ordering = ["-created"]
        verbose_name = "API token"

    def __str__(self) -> str:
        return f"{self.name} ({self.token_key}…)"
