"""The page that attaches an experiment to a booking made through the lease API."""

from __future__ import annotations

from typing import Any

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404, redirect, render

from bookings.choices import Channel
from core.audit.services import client_ip
from core.errors import DomainError
from portal.experiments.selectors import experiments_visible
from portal.runs.selectors import reservations_with_runs_visible
from portal.runs.services.reservations import reservation_attach


@login_required
def reservation_attach_view(request: HttpRequest, pk: int) -> HttpResponse:
    user: Any = request.user
    reservation = get_object_or_404(reservations_with_runs_visible(user=user), pk=pk)
    experiments = experiments_visible(user=user).filter(owner=user).order_by("title")
    if request.method == "POST":
        experiment = experiments.filter(pk=request.POST.get("experiment") or 0).first()
        if experiment is None:
            messages.error(request, "Choose one of your experiments.")
        else:
            try:
                run = reservation_attach(
                    reservation=reservation,
                    experiment=experiment,
                    by=user,
                    ip=client_ip(request),
                    via=Channel.WEB,
                )
            except DomainError as exc:
                messages.error(request, exc.message)
            else:
                messages.success(request, f"{run.resource.name} will run “{run.title}”.")
                return redirect("run", run.pk)
    return render(
        request,
        "web/attach.html",
        {"reservation": reservation, "experiments": experiments},
    )
