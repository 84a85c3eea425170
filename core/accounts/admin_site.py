"""The Django admin behind the one sign-in door.

Its own login form (a password alone, no rate limit) is never shown: an anonymous visitor is
sent to allauth's sign-in, which asks for the second factor and counts attempts; a signed-in
account goes where ``core.accounts.staff.staff_refusal`` sends it. Every admin page needs
``staff_verified``.
"""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.contrib.admin import AdminSite
from django.contrib.auth import REDIRECT_FIELD_NAME
from django.http import HttpRequest, HttpResponse, HttpResponseRedirect
from django.shortcuts import resolve_url
from django.urls import reverse
from django.utils.http import url_has_allowed_host_and_scheme, urlencode

from core.accounts.staff import staff_refusal, staff_verified


class StaffAdminSite(AdminSite):
    def has_permission(self, request: HttpRequest) -> bool:
        return staff_verified(request)

    def login(self, request: HttpRequest, extra_context: Any = None) -> HttpResponse:
        target = request.GET.get(REDIRECT_FIELD_NAME) or request.POST.get(REDIRECT_FIELD_NAME)
        if not target or not url_has_allowed_host_and_scheme(
            target, allowed_hosts={request.get_host()}, require_https=request.is_secure()
        ):
            target = reverse("admin:index", current_app=self.name)
        if not request.user.is_authenticated:
            query = urlencode({REDIRECT_FIELD_NAME: target})
            return HttpResponseRedirect(f"{resolve_url(settings.LOGIN_URL)}?{query}")
        refusal = staff_refusal(request)
        return refusal if refusal is not None else HttpResponseRedirect(target)
