"""Multi-factor authentication (allauth's TOTP and recovery codes), required of staff.

A testbed admin moves a real robot and decides who may use it: before any robot control,
approval or admin page, and the API actions behind them, an admin must have MFA turned on.
Without it the pages send them to set it up and the API answers 403. A staff account's API
tokens work only while it has MFA (``core.accounts.tokens``), so a request with a token
needs no second check here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from allauth.mfa.utils import is_mfa_enabled
from django.contrib import messages
from django.http import HttpRequest, HttpResponse, HttpResponseRedirect
from django.urls import reverse
from django.utils.http import urlencode

MFA_SETUP_URL_NAME = "mfa_activate_totp"


def mfa_enabled(user: Any) -> bool:
    """The user has an authenticator (TOTP; recovery codes come with it)."""
    return bool(is_mfa_enabled(user))


def needs_mfa_setup(user: Any) -> bool:
    """A signed-in testbed admin who has not turned MFA on yet."""
    return bool(
        user.is_authenticated and (user.is_staff or user.is_superuser) and not mfa_enabled(user)
    )


def mfa_setup_redirect(request: HttpRequest) -> HttpResponse:
    """To the TOTP set-up page, and back to where the admin was going once it is done."""
    messages.warning(request, "Staff accounts need two-factor authentication: set it up first.")
    query = urlencode({"next": request.get_full_path()})
    return HttpResponseRedirect(f"{reverse(MFA_SETUP_URL_NAME)}?{query}")


class AdminMfaMiddleware:
    """The admin site is for staff with MFA: others are sent to set it up first."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        return self.get_response(request)

    def process_view(
        self, request: HttpRequest, view: Callable[..., Any], args: Any, kwargs: Any
    ) -> HttpResponse | None:
        match = request.resolver_match
        if match is None or "admin" not in match.namespaces:
            return None
        if needs_mfa_setup(request.user):
            return mfa_setup_redirect(request)
        return None
