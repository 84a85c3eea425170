"""Multi-factor authentication (allauth's TOTP and recovery codes), required of staff.

A staff account's powers need a session that passed its second factor
(``core.accounts.staff``); one without MFA is sent to set it up first. Its secrets are
stored encrypted (``core.accounts.adapter.MfaAdapter``), and a code is checked under a row
lock on the account's authenticators, so that one recovery code cannot pass twice.
"""

from __future__ import annotations

from typing import Any

from allauth.mfa.base.forms import AuthenticateForm, ReauthenticateForm
from allauth.mfa.models import Authenticator
from allauth.mfa.totp.forms import ActivateTOTPForm
from allauth.mfa.utils import is_mfa_enabled
from django import forms
from django.contrib import messages
from django.db import transaction
from django.http import HttpRequest, HttpResponse, HttpResponseRedirect
from django.urls import reverse
from django.utils.http import urlencode

MFA_SETUP_URL_NAME = "mfa_activate_totp"
CODE_KINDS = (Authenticator.Type.TOTP, Authenticator.Type.RECOVERY_CODES)


def mfa_enabled(user: Any) -> bool:
    """The user has an authenticator (TOTP; recovery codes come with it)."""
    return bool(is_mfa_enabled(user))


def mfa_setup_redirect(request: HttpRequest) -> HttpResponse:
    """To the TOTP set-up page, and back to where the admin was going once it is done."""
    messages.warning(request, "Staff accounts need two-factor authentication: set it up first.")
    query = urlencode({"next": request.get_full_path()})
    return HttpResponseRedirect(f"{reverse(MFA_SETUP_URL_NAME)}?{query}")


def authenticators_locked(user: Any) -> list[Authenticator]:
    """The user's code authenticators, locked until the transaction ends: a second check of
    the same code waits, then reads the recovery code as used."""
    return list(
        Authenticator.objects.select_for_update().filter(user_id=user.pk, type__in=CODE_KINDS)
    )


def mfa_code_check(user: Any, code: str) -> Authenticator | None:
    """The authenticator that accepts ``code`` (a TOTP code, each once, or an unused recovery
    code, then marked used), checked under the row lock."""
    with transaction.atomic():
        for authenticator in authenticators_locked(user):
            if authenticator.wrap().validate_code(code):
                authenticator.record_usage()
                return authenticator
    return None


class LockedAuthenticateForm(AuthenticateForm):
    """allauth's code form at sign-in, with its check under the row lock."""

    def clean_code(self) -> str:
        with transaction.atomic():
            authenticators_locked(self.user)
            return super().clean_code()


class LockedReauthenticateForm(ReauthenticateForm):
    """allauth's code form to reauthenticate, with its check under the row lock."""

    def clean_code(self) -> str:
        with transaction.atomic():
            authenticators_locked(self.user)
            return super().clean_code()


STAFF_ENROLMENT_REFUSED = (
    "A staff account sets up its first second factor only once another admin allowed it "
    "(the admin site, or manage.py mfa_enrolment_allow): ask one."
)


class StaffGatedActivateTOTPForm(ActivateTOTPForm):
    """allauth's TOTP set-up, refused to a staff account no other admin allowed: whoever has
    only its password must not choose its second factor."""

    def clean_code(self) -> str:
        user = self.user
        if getattr(user, "has_staff_role", False) and not user.mfa_enrolment_allowed:
            raise forms.ValidationError(STAFF_ENROLMENT_REFUSED)
        return super().clean_code()
