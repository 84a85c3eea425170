"""Dry-run pages: "Try on the simulator" from the experiment page, and the dry run's own page,
which shows its place in line while it waits and then the run page's charts and statistics."""

from __future__ import annotations

from typing import Any

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.db import transaction
from django.http import HttpRequest, HttpResponse, JsonResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.template.loader import render_to_string

from core.accounts.models import User
from core.api import page_throttled
from core.errors import DomainError
from portal.experiments.selectors import experiments_visible
from portal.runs.models import DryRun
from portal.runs.selectors import dry_run_report
from portal.runs.services.dry_run import dry_run_place, dry_run_request
from portal.runs.tasks import dry_run_execute
from portal.web.views import report_context


def _user(request: HttpRequest) -> User:
    assert isinstance(request.user, User)
    return request.user


def _visible(request: HttpRequest, pk: int) -> DryRun:
    user = _user(request)
    dry_runs = DryRun.objects.all() if user.is_testbed_admin else DryRun.objects.filter(owner=user)
    return get_object_or_404(dry_runs, pk=pk)


@login_required
def dry_run_start(request: HttpRequest, pk: int) -> HttpResponse:
    if request.method != "POST":
        return redirect("experiment-edit", pk=pk)
    user = _user(request)
    experiment = get_object_or_404(experiments_visible(user=user), pk=pk)
    try:
        with transaction.atomic():
            dry_run = dry_run_request(user=user, experiment=experiment)
            transaction.on_commit(lambda: dry_run_execute.delay(dry_run.pk))
    except DomainError as exc:
        messages.error(request, f"Not tried: {exc.message}")
        return redirect("experiment-edit", pk=pk)
    return redirect("dry-run", pk=dry_run.pk)


def _context(request: HttpRequest, dry_run: DryRun) -> dict[str, Any]:
    return {
        "dry_run": dry_run,
        "place": dry_run_place(dry_run),
        "waiting": dry_run.state in (DryRun.State.QUEUED, DryRun.State.RUNNING),
        "missing": [],
        **report_context(request, lambda at_m: dry_run_report(dry_run=dry_run, pass_at_m=at_m)),
    }


@login_required
def dry_run_page(request: HttpRequest, pk: int) -> HttpResponse:
    return render(request, "web/dry_run.html", _context(request, _visible(request, pk)))


@page_throttled
@login_required
def dry_run_data(request: HttpRequest, pk: int) -> JsonResponse:
    """The dry run's state while it waits, then what the run page's script draws."""
    dry_run = _visible(request, pk)
    context = _context(request, dry_run)
    report = context["report"]
    return JsonResponse(
        {
            "state": dry_run.state,
            "state_label": dry_run.get_state_display(),
            "place": context["place"],
            "reason": dry_run.reason,
            "missing": [],
            "sample_count": report.analysis.samples,
            "live": context["waiting"],
            "series": report.series,
            "rail_length_m": dry_run.rail_length_m,
            "analysis_html": render_to_string("web/_run_analysis.html", context, request),
        }
    )
