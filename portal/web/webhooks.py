"""The webhooks pages: a user's webhooks (make one, its secret shown once), each one's
delivery log, a test event, a resume after a pause, and deleting one after a confirmation.
The same services as ``/api/v1/webhooks/`` (``core.webhooks.services``)."""

from __future__ import annotations

from typing import Any

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.core.paginator import Paginator
from django.http import HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.views.decorators.cache import never_cache
from django.views.decorators.http import require_POST

from core.audit.services import client_ip
from core.errors import DomainError
from core.webhooks import services
from core.webhooks.models import WebhookSubscription
from core.webhooks.selectors import webhook_deliveries, webhooks_visible
from portal.web.forms import WebhookForm, form_refusal

# Deliveries one page of a webhook's log shows, the newest event first.
LOG_PAGE_SIZE = 50


def _user(request: HttpRequest) -> Any:
    return request.user


def _mine(request: HttpRequest, pk: int) -> WebhookSubscription:
    return get_object_or_404(webhooks_visible(user=_user(request)), pk=pk)


@login_required
@never_cache
def webhooks_page(request: HttpRequest) -> HttpResponse:
    """The user's webhooks, and the form that makes one (its secret shown by this answer only)."""
    user = _user(request)
    form = WebhookForm(staff=user.is_testbed_admin)
    created = secret = None
    if request.method == "POST":
        form = WebhookForm(request.POST, staff=user.is_testbed_admin)
        if form.is_valid():
            try:
                created, secret = services.webhook_create(
                    owner=user, ip=client_ip(request), **form.cleaned_data
                )
            except DomainError as exc:
                form_refusal(form, exc)
            else:
                form = WebhookForm(staff=user.is_testbed_admin)
    response = render(
        request,
        "web/webhooks.html",
        {
            "form": form,
            "created": created,
            "secret": secret,
            "webhooks": webhooks_visible(user=user),
        },
    )
    if secret is not None:
        response["Cache-Control"] = "no-store"
    return response


@login_required
@never_cache
def webhook_page(request: HttpRequest, pk: int) -> HttpResponse:
    """One webhook: what it takes, whether it is paused and why, and its delivery log."""
    subscription = _mine(request, pk)
    log = Paginator(webhook_deliveries(subscription=subscription), LOG_PAGE_SIZE)
    page = log.get_page(request.GET.get("page"))
    return render(
        request,
        "web/webhook.html",
        {"webhook": subscription, "deliveries": page},
    )


@login_required
@require_POST
def webhook_test_view(request: HttpRequest, pk: int) -> HttpResponse:
    subscription = _mine(request, pk)
    try:
        event = services.webhook_test(
            subscription=subscription, by=_user(request), ip=client_ip(request)
        )
    except DomainError as exc:
        messages.error(request, exc.message)
    else:
        messages.success(
            request,
            f"Test event {event.position} is on its way: its delivery shows below within seconds.",
        )
    return redirect("webhook", pk=subscription.pk)


@login_required
@require_POST
def webhook_resume_view(request: HttpRequest, pk: int) -> HttpResponse:
    subscription = _mine(request, pk)
    try:
        services.webhook_resume(subscription=subscription, by=_user(request), ip=client_ip(request))
    except DomainError as exc:
        messages.error(request, exc.message)
    else:
        messages.success(request, "Resumed: what failed is sent again first, then what waited.")
    return redirect("webhook", pk=subscription.pk)


@login_required
def webhook_delete_view(request: HttpRequest, pk: int) -> HttpResponse:
    """Asks first (GET); deletes on the confirmation (POST), with its log."""
    subscription = _mine(request, pk)
    if request.method == "POST":
        try:
            services.webhook_delete(
                subscription=subscription, by=_user(request), ip=client_ip(request)
            )
        except DomainError as exc:
            messages.error(request, exc.message)
            return redirect("webhook", pk=subscription.pk)
        messages.success(request, f"Deleted the webhook to {subscription.url}.")
        return redirect("webhooks")
    return render(request, "web/confirm_webhook_delete.html", {"webhook": subscription})
