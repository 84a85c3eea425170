"""Staff powers: the one question every door asks before a staff action.

A staff account (``is_staff`` or ``is_superuser``) has its powers only in a request whose
session passed its second factor (allauth keeps the session's authentication records; an
``mfa`` record is there once the TOTP or a recovery code was given at sign-in or
reauthentication), or with an API token minted from such a session. Otherwise it acts as
the plain user it also is, and a staff page or API action refuses it.

The door marks the request's user with the answer (``User.staff_verified``): the session
middleware here, and the API token authentication (``core.accounts.tokens``). Services read
``User.is_testbed_admin`` (the role and that mark) and never derive it again.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import wraps
from typing import Any

from allauth.account.authentication import get_authentication_records
from asgiref.sync import sync_to_async
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.core.exceptions import PermissionDenied
from django.http import HttpRequest, HttpResponse, HttpResponseRedirect
from django.urls import reverse
from django.utils.functional import SimpleLazyObject
from django.utils.http import urlencode

from core.accounts.mfa import mfa_enabled, mfa_setup_redirect
from core.accounts.models import ApiToken

SIGN_IN_WITH_SECOND_FACTOR = (
    "Staff actions need a session signed in with your second factor: sign in with it."
)
ADMINS_ONLY = "This is for the testbed's admins."
REAUTHENTICATE_URL_NAME = "mfa_reauthenticate"


def has_staff_role(user: Any) -> bool:
    """An active, signed-in staff account, whatever its session passed."""
    return bool(
        user is not None
        and user.is_authenticated
        and user.is_active
        and (user.is_staff or user.is_superuser)
    )


def session_passed_mfa(request: HttpRequest, user: Any) -> bool:
    """This session's sign-in (or a reauthentication in it) took ``user``'s second factor,
    and the account still has one."""
    if not hasattr(request, "session"):
        return False
    records = get_authentication_records(request, user)
    return any(r.get("method") == "mfa" for r in records) and mfa_enabled(user)


def staff_verified(request: Any) -> bool:
    """Is this request by staff whose session passed its second factor, or by a staff API
    token minted from such a session? (A Django request or DRF's.)"""
    user = getattr(request, "user", None)
    if not has_staff_role(user):
        return False
    auth = getattr(request, "auth", None)
    if isinstance(auth, ApiToken):
        return bool(auth.mfa_verified)
    return session_passed_mfa(getattr(request, "_request", request), user)


def _marked(request: HttpRequest, user: Any) -> Any:
    if has_staff_role(user):
        user.staff_verified = session_passed_mfa(request, user)
    return user


class StaffSessionMiddleware:
    """Marks a session's user with ``staff_verified`` (after Django's authentication)."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        user = request.user
        request.user = SimpleLazyObject(lambda: _marked(request, user))  # type: ignore[assignment]
        auser = request.auser

        async def marked_auser() -> Any:
            return await sync_to_async(_marked)(request, await auser())

        request.auser = marked_auser
        return self.get_response(request)


def staff_refusal(request: HttpRequest) -> HttpResponse | None:
    """Nothing when the request may use staff powers; else where a page sends it: staff
    without MFA to set it up, staff whose session did not pass it to give the code, anyone
    else a 403."""
    if staff_verified(request):
        return None
    user = request.user
    if not has_staff_role(user):
        raise PermissionDenied(ADMINS_ONLY)
    if not mfa_enabled(user):
        return mfa_setup_redirect(request)
    messages.warning(request, SIGN_IN_WITH_SECOND_FACTOR)
    query = urlencode({"next": request.get_full_path()})
    return HttpResponseRedirect(f"{reverse(REAUTHENTICATE_URL_NAME)}?{query}")


def staff_required(view: Callable[..., HttpResponse]) -> Callable[..., HttpResponse]:
    """A staff page: anonymous visitors to the sign-in, then ``staff_refusal``."""

    @wraps(view)
    @login_required
    def wrapper(request: HttpRequest, *args: Any, **kwargs: Any) -> HttpResponse:
        refusal = staff_refusal(request)
        if refusal is not None:
            return refusal
        return view(request, *args, **kwargs)

    # Read by the URL table of staff actions (tests/security).
    wrapper.staff_only = True  # type: ignore[attr-defined]
    return wrapper
