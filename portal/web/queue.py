"""The queue's page: ask for a run as soon as possible, see each request's place and estimated
start (or why it waits), withdraw one. The same services as ``/api/v1/queue/``."""

from __future__ import annotations

from typing import Any

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.utils import timezone
from django.views.decorators.cache import never_cache
from django.views.decorators.http import require_POST

from core.audit.services import client_ip
from core.errors import DomainError
from portal.queue.campaigns import campaign_progress
from portal.queue.selectors import (
    campaigns_visible,
    queue_control,
    queue_places,
    queue_requests_visible,
)
from portal.queue.services import queue_request_cancel, queue_request_submit
from portal.web.forms import QueueRequestForm, form_refusal

# Requests the page lists, the newest first.
LISTED = 50


@login_required
@never_cache
def queue_page(request: HttpRequest) -> HttpResponse:
    user: Any = request.user
    form = QueueRequestForm(user=user)
    if request.method == "POST":
        form = QueueRequestForm(request.POST, user=user)
        if form.is_valid():
            data = {k: v for k, v in form.cleaned_data.items() if v is not None}
            try:
                queued = queue_request_submit(owner=user, ip=client_ip(request), **data)
            except DomainError as exc:
                form_refusal(form, exc)
            else:
                messages.success(request, f"Request {queued.pk} is in the queue.")
                return redirect("queue")
    places = queue_places(now=timezone.now())
    requests = list(queue_requests_visible(user=user).order_by("-submitted_at", "-pk")[:LISTED])
    rows = [(r, places.get(r.pk)) for r in requests]
    if request.GET.get("part") == "requests":
        # The page's script reads the table again when the calendar changes (queue.js).
        return render(request, "web/_queue_requests.html", {"rows": rows})
    campaigns = [
        (c, campaign_progress(c))
        for c in campaigns_visible(user=user).filter(owner=user).order_by("-created_at")[:LISTED]
    ]
    return render(
        request,
        "web/queue.html",
        {
            "form": form,
            "rows": rows,
            "campaigns": campaigns,
            "control": queue_control(),
            "waiting": len(places),
        },
    )


@login_required
@require_POST
def queue_cancel_view(request: HttpRequest, pk: int) -> HttpResponse:
    user: Any = request.user
    queued = get_object_or_404(queue_requests_visible(user=user), pk=pk)
    try:
        queue_request_cancel(request=queued, by=user, ip=client_ip(request))
    except DomainError as exc:
        messages.error(request, exc.message)
    else:
        messages.success(request, f"Request {pk} withdrawn.")
    return redirect("queue")
