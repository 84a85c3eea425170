from __future__ import annotations

import time
from datetime import timedelta
from typing import Any

import factory
from allauth.mfa import app_settings as mfa_settings
from allauth.mfa.models import Authenticator
from allauth.mfa.recovery_codes.internal.auth import RecoveryCodes
from allauth.mfa.totp.internal.auth import (
    TOTP,
    format_hotp_value,
    generate_totp_secret,
    hotp_value,
)
from allauth.mfa.utils import decrypt
from django.conf import settings

from bookings.choices import ResourceKind
from bookings.models import Resource
from core.accounts.models import ApiToken, User
from portal.experiments.models import Experiment


class UserFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = User
        django_get_or_create = ("username",)
        skip_postgeneration_save = True

    username = factory.Sequence(lambda n: f"user{n}")
    email = factory.LazyAttribute(lambda u: f"{u.username}@example.org")
    password = factory.PostGenerationMethodCall("set_password", "correct horse battery")

    @factory.post_generation
    def _save(self, create: bool, extracted: Any, **kwargs: Any) -> None:
        if create:
            self.save()

    @factory.post_generation
    def mfa(self, create: bool, extracted: Any, **kwargs: Any) -> None:
        """Staff have TOTP on, as they must to reach the robot and approvals; ``mfa=False``
        makes one without."""
        wanted = self.has_staff_role if extracted is None else bool(extracted)
        if create and wanted:
            mfa_on(self)


class MobileResourceFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Resource
        django_get_or_create = ("name",)

    name = "mobile-1"
    kind = ResourceKind.MOBILE
    agent_url = "http://127.0.0.1:1"
    max_velocity_mps = 2.0
    max_accel_mps2 = 1.0


class FixedResourceFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Resource
        django_get_or_create = ("name",)

    name = factory.Sequence(lambda n: f"node-{n + 1:02d}")
    kind = ResourceKind.FIXED


class ExperimentFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Experiment

    owner = factory.SubFactory(UserFactory)
    title = factory.Sequence(lambda n: f"experiment {n}")
    segments = factory.LazyFunction(
        lambda: [
            {"velocity_mps": 0.5, "direction": "cw", "duration_s": 3.0},
            {"velocity_mps": 0.8, "direction": "ccw", "duration_s": 3.0},
        ]
    )


def mfa_on(user: User) -> str:
    """Turn on TOTP and recovery codes for ``user`` (as its set-up page does); the TOTP
    secret, to make codes with."""
    secret = generate_totp_secret()
    TOTP.activate(user, secret)
    RecoveryCodes.activate(user)
    return secret


def totp_code(secret: str) -> str:
    """The code an authenticator app shows now for ``secret``."""
    return format_hotp_value(hotp_value(secret, int(time.time()) // mfa_settings.TOTP_PERIOD))


def next_totp_code(secret: str, given: str) -> str:
    """The code an authenticator app shows once ``given`` (taken already: allauth refuses a
    code a second time) has made way for the next, as a person waits for it."""
    deadline = time.monotonic() + mfa_settings.TOTP_PERIOD + 5
    while (code := totp_code(secret)) == given:
        assert time.monotonic() < deadline, "the authenticator's code did not change"
        time.sleep(0.1)
    return code


# The last code each secret was signed in with here: allauth refuses a code a second time.
_CODES_GIVEN: dict[str, str] = {}


def unused_totp_code(secret: str) -> str:
    """The code to sign in with now: the authenticator's, or, when that one was given here
    already (a second sign-in of the same user within one period), the next, waited for."""
    code = totp_code(secret)
    if _CODES_GIVEN.get(secret) == code:
        code = next_totp_code(secret, code)
    _CODES_GIVEN[secret] = code
    return code


def totp_secret_of(username: str) -> str | None:
    """The TOTP secret of ``username``'s authenticator app, if it has one."""
    found = Authenticator.objects.filter(
        user__username=username, type=Authenticator.Type.TOTP
    ).first()
    return decrypt(found.data["secret"]) if found is not None else None


def api_token(user: User, *, name: str = "test") -> str:
    """A new API token of ``user``; a staff user's is one minted with its second factor (MFA
    on first), expiring as a staff token does."""
    if not user.has_staff_role:
        return ApiToken.objects.create(user=user, name=name)[1]
    if not Authenticator.objects.filter(user=user).exists():
        mfa_on(user)
    return ApiToken.objects.create(
        user=user,
        name=name,
        mfa_verified=True,
        expiry=timedelta(days=settings.STAFF_API_TOKEN_DAYS),
    )[1]
