from __future__ import annotations

from typing import Any

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse, JsonResponse, StreamingHttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.utils import timezone

from bookings.selectors import reservations_visible
from bookings.services import reservation_cancel, reservation_create
from portal.audit.services import client_ip
from portal.errors import DomainError
from portal.experiments.apis import is_asgi, samples_csv_response
from portal.experiments.choices import RUN_ACTIVE_STATES, RunState
from portal.experiments.selectors import experiments_visible, run_velocity_series, runs_visible
from portal.experiments.services import experiment_create, experiment_update
from portal.web.forms import BookingForm, ExperimentForm


def _user(request: HttpRequest) -> Any:
    return request.user


def _form_error(form: Any, exc: DomainError) -> None:
    """Show a service's refusal on the form, next to the field it names when the form has it."""
    for field, errors in (exc.fields or {"__all__": [exc.message]}).items():
        for message in errors:
            form.add_error(field if field in form.fields else None, message)


@login_required
def home(request: HttpRequest) -> HttpResponse:
    user = _user(request)
    now = timezone.now()
    context = {
        "upcoming": reservations_visible(user=user).filter(end_at__gte=now, state="confirmed")[:20],
        "recent_runs": runs_visible(user=user).filter(start_at__lt=now)[:10],
        "experiments": experiments_visible(user=user).filter(owner=user)[:20],
    }
    return render(request, "web/home.html", context)


@login_required
def experiment_edit(request: HttpRequest, pk: int | None = None) -> HttpResponse:
    user = _user(request)
    experiment = get_object_or_404(experiments_visible(user=user), pk=pk) if pk else None
    if request.method == "POST":
        form = ExperimentForm(request.POST)
        segments = form.segments_from(request.POST)
        if form.is_valid():
            try:
                if experiment is None:
                    experiment = experiment_create(
                        owner=user, title=form.cleaned_data["title"], segments=segments
                    )
                else:
                    experiment_update(
                        experiment=experiment, title=form.cleaned_data["title"], segments=segments
                    )
            except DomainError as exc:
                _form_error(form, exc)
            else:
                messages.success(request, f"Experiment “{experiment.title}” saved.")
                return redirect("home")
        rows = form.segment_rows
    else:
        form = ExperimentForm(initial={"title": experiment.title} if experiment else None)
        rows = [dict(s) for s in experiment.segments] if experiment else []
    while len(rows) < 3:
        rows.append({"velocity_mps": "", "direction": "cw", "duration_s": ""})
    return render(
        request, "web/experiment_form.html", {"form": form, "rows": rows, "experiment": experiment}
    )


@login_required
def book(request: HttpRequest) -> HttpResponse:
    user = _user(request)
    if request.method == "POST":
        form = BookingForm(request.POST, user=user)
        if form.is_valid():
            try:
                reservation = reservation_create(
                    owner=user, ip=client_ip(request), **form.cleaned_data
                )
            except DomainError as exc:
                _form_error(form, exc)
            else:
                messages.success(request, f"Booked {reservation}.")
                run = getattr(reservation, "run", None)
                return redirect("run", pk=run.pk) if run else redirect("home")
    else:
        initial: dict[str, Any] = {}
        if "experiment" in request.GET:
            initial["experiment"] = request.GET["experiment"]
        form = BookingForm(initial=initial, user=user)
    return render(request, "web/book.html", {"form": form})


@login_required
def reservation_cancel_view(request: HttpRequest, pk: int) -> HttpResponse:
    reservation = get_object_or_404(reservations_visible(user=_user(request)), pk=pk)
    if request.method == "POST":
        try:
            reservation_cancel(
                reservation=reservation,
                by=_user(request),
                reason=request.POST.get("reason", ""),
                ip=client_ip(request),
            )
        except DomainError as exc:
            messages.error(request, exc.message)
        else:
            messages.success(request, f"Cancelled {reservation}.")
        return redirect("home")
    return render(request, "web/confirm_cancel.html", {"reservation": reservation})


@login_required
def run_page(request: HttpRequest, pk: int) -> HttpResponse:
    run = get_object_or_404(runs_visible(user=_user(request)), pk=pk)
    return render(
        request,
        "web/run.html",
        {
            "run": run,
            "events": run.events.all(),
            "live": run.state in (RunState.SCHEDULED, *RUN_ACTIVE_STATES),
        },
    )


@login_required
def run_data(request: HttpRequest, pk: int) -> JsonResponse:
    """What the run page's chart and status need, polled while the run is live."""
    run = get_object_or_404(runs_visible(user=_user(request)), pk=pk)
    return JsonResponse(
        {
            "state": run.state,
            "state_label": run.get_state_display(),
            "reason": run.reason,
            "sample_count": run.samples.count(),
            "live": run.state in (RunState.SCHEDULED, *RUN_ACTIVE_STATES),
            "series": run_velocity_series(run=run),
        }
    )


@login_required
def run_csv(request: HttpRequest, pk: int) -> StreamingHttpResponse:
    run = get_object_or_404(runs_visible(user=_user(request)), pk=pk)
    return samples_csv_response(run, asynchronous=is_asgi(request))
