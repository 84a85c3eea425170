"""A campaign's page: its progress, each run with its parameters' values and where it stands,
the results over the repeats with every completed run's velocity overlaid, the download; and
pausing, resuming and cancelling it. The same services as ``/api/v1/campaigns/``."""

from __future__ import annotations

from typing import Any

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse, StreamingHttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.views.decorators.cache import never_cache
from django.views.decorators.http import require_POST

from core.api import page_throttled
from core.audit.services import client_ip
from core.errors import DomainError
from portal.queue.campaigns import (
    campaign_cancel,
    campaign_pause,
    campaign_progress,
    campaign_requests,
    campaign_resume,
)
from portal.queue.models import Campaign
from portal.queue.package import campaign_package_response
from portal.queue.results import (
    METRICS,
    campaign_chart,
    campaign_results,
    campaign_runs_completed,
)
from portal.queue.selectors import campaigns_visible


def _visible(request: HttpRequest, pk: int) -> Campaign:
    return get_object_or_404(campaigns_visible(user=request.user), pk=pk)  # type: ignore[arg-type]


@login_required
@never_cache
def campaign_page(request: HttpRequest, pk: int) -> HttpResponse:
    campaign = _visible(request, pk)
    completed = campaign_runs_completed(campaign)
    groups = campaign_results(completed)
    progress = campaign_progress(campaign)
    finished = progress["run_states"].get("completed", 0)
    return render(
        request,
        "web/campaign.html",
        {
            "campaign": campaign,
            "progress": progress,
            "finished": finished,
            "requests": campaign_requests(campaign),
            "groups": groups,
            "metrics": METRICS,
            "chart": campaign_chart(completed, groups),
        },
    )


def _changed(request: HttpRequest, pk: int, change: Any, done: str) -> HttpResponse:
    try:
        change(campaign=_visible(request, pk), by=request.user, ip=client_ip(request))
    except DomainError as exc:
        messages.error(request, exc.message)
    else:
        messages.success(request, done)
    return redirect("campaign", pk=pk)


@login_required
@require_POST
def campaign_pause_view(request: HttpRequest, pk: int) -> HttpResponse:
    return _changed(request, pk, campaign_pause, "Campaign paused: its waiting runs are held back.")


@login_required
@require_POST
def campaign_resume_view(request: HttpRequest, pk: int) -> HttpResponse:
    return _changed(request, pk, campaign_resume, "Campaign resumed: its runs are queued again.")


@login_required
@require_POST
def campaign_cancel_view(request: HttpRequest, pk: int) -> HttpResponse:
    cancel_booked = request.POST.get("cancel_booked") == "on"
    reason = request.POST.get("reason", "").strip()[:1000]

    def cancel(**kwargs: Any) -> Campaign:
        return campaign_cancel(cancel_booked=cancel_booked, reason=reason, **kwargs)

    done = "Campaign cancelled: its waiting runs are withdrawn" + (
        ", and its booked runs cancelled." if cancel_booked else "; its booked runs are kept."
    )
    return _changed(request, pk, cancel, done)


@page_throttled
@login_required
def campaign_package(request: HttpRequest, pk: int) -> StreamingHttpResponse:
    return campaign_package_response(request, _visible(request, pk))
