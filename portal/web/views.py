from __future__ import annotations

from collections.abc import Callable
from datetime import date, datetime, time, timedelta
from typing import Any
from zoneinfo import ZoneInfo

from django.conf import settings
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.core.exceptions import BadRequest
from django.http import HttpRequest, HttpResponse, JsonResponse, StreamingHttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.template.loader import render_to_string
from django.urls import reverse
from django.utils import timezone
from django.views.decorators.cache import never_cache

from basestation.contract import CsvWriter
from bookings.choices import Channel, ReservationState
from bookings.leases import scheduler_link_status, scheduler_overview
from bookings.models import Reservation, Resource
from bookings.quotas import quota_summary
from bookings.reports import GROUPINGS, usage_hours
from bookings.rules import velocity_limit
from core.accounts.mfa import mfa_enabled
from core.accounts.selectors import api_tokens_of
from core.accounts.services import api_token_create, api_token_revoke
from core.accounts.staff import staff_required, staff_verified
from core.api import page_throttled
from core.audit.services import client_ip
from core.errors import DomainError
from core.health import health
from core.wall_clock import wall_with_offset
from portal.experiments.selectors import experiment_fits, experiments_visible, fits_summary
from portal.experiments.services import experiment_create, experiment_update
from portal.runs.downloads import (
    run_package_response,
    samples_csv_response,
    samples_json_response,
)
from portal.runs.measurements import clock_state
from portal.runs.models import Run
from portal.runs.provenance import provenance_summary
from portal.runs.selectors import (
    RunReport,
    reservations_with_runs_visible,
    run_report,
    runs_visible,
)
from portal.runs.services.collection import missing_described
from portal.runs.services.reservations import (
    reservation_cancel,
    reservation_create,
    reservation_decide,
    reservation_repeat,
)
from portal.runs.services.robot import HOLD_REPEAT_MS, HOLD_TTL_S
from portal.runs.states import RUN_ACTIVE_STATES, RunState
from portal.web.builder import builder_context
from portal.web.forms import (
    ApiTokenForm,
    BookingForm,
    ExperimentForm,
    MeasurementForm,
    MeasurementOffsetForm,
    PassForm,
    form_refusal,
)


@never_cache
def healthz(request: HttpRequest) -> JsonResponse:
    """Liveness for supervisors and monitoring: no login, no internals (``core/health.py``)."""
    ok, body = health()
    if body["database"] == "ok":
        # Reported, not judged: the portal works (without fixed nodes) while it is down.
        # Whether it works and how late, not why not: the error's text names the scheduler's
        # address and answers, which the admins' page shows (scheduler_overview).
        link = scheduler_link_status()
        body["testbed_scheduler"] = {k: v for k, v in link.items() if k in HEALTH_LINK_FIELDS}
    return JsonResponse(body, status=200 if ok else 503)


HEALTH_LINK_FIELDS = frozenset({"configured", "ok", "last_sync_age_s"})


def _user(request: HttpRequest) -> Any:
    return request.user


@login_required
def home(request: HttpRequest) -> HttpResponse:
    user = _user(request)
    now = timezone.now()
    context = {
        "upcoming": reservations_with_runs_visible(user=user).filter(
            end_at__gte=now, state="confirmed"
        )[:20],
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
                form_refusal(form, exc)
            else:
                fits = fits_summary(experiment_fits(experiment))
                messages.success(request, f"Experiment “{experiment.title}” saved. {fits}".strip())
                # Back to the experiment, where trying it and booking it are the next steps.
                return redirect("experiment-edit", pk=experiment.pk)
        rows = form.segment_rows
    else:
        form = ExperimentForm(initial={"title": experiment.title} if experiment else None)
        rows = [dict(s) for s in experiment.segments] if experiment else []
    while len(rows) < 3:
        rows.append({"velocity_mps": "", "direction": "cw", "duration_s": ""})
    return render(
        request,
        "web/experiment_form.html",
        {"form": form, "rows": rows, "experiment": experiment, "builder": builder_context()},
    )


@login_required
def book(request: HttpRequest) -> HttpResponse:
    user = _user(request)
    if request.method == "POST":
        form = BookingForm(request.POST, user=user)
        if form.is_valid():
            try:
                reservation = reservation_create(
                    owner=user, ip=client_ip(request), via=Channel.WEB, **form.cleaned_data
                )
            except DomainError as exc:
                form_refusal(form, exc)
            else:
                messages.success(request, f"Booked {_booked(reservation)}.")
                run = getattr(reservation, "run", None)
                return redirect("run", pk=run.pk) if run else redirect("home")
    else:
        form = BookingForm(initial=_booking_initial(request, user), user=user)
    return render(
        request,
        "web/book.html",
        {"form": form, "quota": quota_summary(user=user, now=timezone.now())},
    )


def _booking_initial(request: HttpRequest, user: Any) -> dict[str, Any]:
    """The book page's first values: an experiment named in the link (from its page, a dry
    run, home), with the first robot its program fits ticked."""
    experiment_id = request.GET.get("experiment", "")
    experiment = (
        experiments_visible(user=user).filter(owner=user, pk=experiment_id).first()
        if experiment_id.isdigit()
        else None
    )
    if experiment is None:
        return {}
    fitting = [fit.limit.resource for fit in experiment_fits(experiment) if fit.fits]
    return {"experiment": experiment.pk, "resources": fitting[:1]}


def _booked(reservation: Reservation) -> str:
    """What and when, in the testbed's zone with the UTC offset: a time typed in the hour the
    clocks pass twice shows which of the two was booked."""
    zone = ZoneInfo(settings.TIME_ZONE)
    names = ", ".join(item.resource.name for item in reservation.items.all())
    start = wall_with_offset(reservation.start_at, zone)
    end = wall_with_offset(reservation.end_at, zone)
    return f"{names} from {start} to {end}"


@login_required
def reservation_cancel_view(request: HttpRequest, pk: int) -> HttpResponse:
    reservation = get_object_or_404(reservations_with_runs_visible(user=_user(request)), pk=pk)
    if request.method == "POST":
        try:
            reservation_cancel(
                reservation=reservation,
                by=_user(request),
                reason=request.POST.get("reason", ""),
                ip=client_ip(request),
                via=Channel.WEB,
            )
        except DomainError as exc:
            messages.error(request, exc.message)
        else:
            messages.success(request, f"Cancelled {reservation}.")
        return redirect("home")
    return render(request, "web/confirm_cancel.html", {"reservation": reservation})


def report_context(
    request: HttpRequest, report_for: Callable[[float | None], RunReport]
) -> dict[str, Any]:
    """A report's analysis with its passes form (``?at_m=``), for the run page, the dry run's
    page and their polls: ``report_for(pass_at_m)`` computes it (``ValueError`` for a position
    off the rail, shown on the form)."""
    form = PassForm(request.GET or None)
    pass_at_m = form.cleaned_data["at_m"] if form.is_valid() else None
    try:
        report = report_for(pass_at_m)
    except ValueError as exc:
        form.add_error("at_m", str(exc))
        report = report_for(None)

    def at(t_s: float) -> datetime | None:
        return None if report.first_at is None else report.first_at + timedelta(seconds=t_s)

    return {
        "report": report,
        "analysis": report.analysis,
        "laps": [(lap, at(lap.end_s)) for lap in report.analysis.laps],
        "passes": [(p, at(p.t_s)) for p in report.analysis.passes],
        "pass_form": form,
    }


def _run_context(request: HttpRequest, run: Run) -> dict[str, Any]:
    """The run page's analysis and its passes form, for the page and its poll."""
    return {
        "run": run,
        "live": run.state in (RunState.SCHEDULED, *RUN_ACTIVE_STATES),
        "missing": missing_described(run.missing),
        **report_context(request, lambda at_m: run_report(run=run, pass_at_m=at_m)),
    }


def visible_run(request: HttpRequest, pk: int, *related: str) -> Run:
    """The run ``pk`` if the signed-in user may see it, else 404 (never 403: whether another's
    run exists is not told)."""
    runs = runs_visible(user=_user(request))
    # select_related() without names would follow every foreign key.
    return get_object_or_404(runs.select_related(*related) if related else runs, pk=pk)


def measurements_context(run: Run, form: MeasurementForm | None) -> dict[str, Any]:
    """The run page's measurements section: each series with its columns' summaries, the
    charts' data, and the form that adds one."""
    series = list(run.measurements.order_by("name"))
    return {
        "run": run,
        "measurements": [
            {"series": s, "columns": list(s.summary.get("columns", {}).items())} for s in series
        ],
        "measurements_charts": [
            {"name": s.name, "unit": s.unit, "columns": s.summary.get("columns", {})}
            for s in series
        ],
        "measurement_form": form or MeasurementForm(),
        "offset_form": MeasurementOffsetForm(),
        "clock_state": clock_state(run.provenance),
    }


def run_page_response(
    request: HttpRequest,
    run: Run,
    *,
    measurement_form: MeasurementForm | None = None,
    status: int = 200,
) -> HttpResponse:
    """The run page; ``measurement_form`` with its errors when an upload was refused."""
    context = _run_context(request, run)
    context["events"] = run.events.all()
    context["provenance"] = provenance_summary(run.provenance)
    context["repeats"] = list(run.repeats.order_by("start_at").values_list("pk", flat=True))
    # "Compare the two runs" links from a repeated run (`?ids=A,B`).
    context["compare_path"] = reverse("runs-compare")
    # Before its start a run has nothing to repeat: the page counts down instead.
    context["not_started"] = run.state in (RunState.SCHEDULED, RunState.STAGED)
    context.update(measurements_context(run, measurement_form))
    return render(request, "web/run.html", context, status=status)


@page_throttled
@login_required
def run_page(request: HttpRequest, pk: int) -> HttpResponse:
    return run_page_response(request, visible_run(request, pk))


@login_required
def run_again(request: HttpRequest, pk: int) -> HttpResponse:
    """ "Run again": the same program with the same limits, the robot's next free slot."""
    if request.method != "POST":
        return redirect("run", pk=pk)
    user = _user(request)
    run = visible_run(request, pk, "experiment")
    try:
        reservation = reservation_repeat(run=run, by=user, ip=client_ip(request), via=Channel.WEB)
    except DomainError as exc:
        messages.error(request, f"Not booked again: {exc.message}")
        return redirect("run", pk=pk)
    again = reservation.run
    start = timezone.localtime(again.start_at)
    messages.success(
        request,
        f"Booked run {again.pk}, repeating run {run.pk}: {start:%Y-%m-%d %H:%M:%S} on "
        f"{run.resource.name}.",
    )
    return redirect("run", pk=again.pk)


@page_throttled
@login_required
def run_package(request: HttpRequest, pk: int) -> StreamingHttpResponse:
    run = visible_run(request, pk)
    return run_package_response(request, run)


@page_throttled
@login_required
def run_data(request: HttpRequest, pk: int) -> JsonResponse:
    """What the run page's charts, status and tables need, polled while the run is live."""
    run = visible_run(request, pk)
    context = _run_context(request, run)
    report = context["report"]
    return JsonResponse(
        {
            "state": run.state,
            "state_label": run.get_state_display(),
            "reason": run.reason,
            "missing": context["missing"],
            "sample_count": report.analysis.samples,
            "live": context["live"],
            "series": report.series,
            "rail_length_m": run.rail_length_m,
            "analysis_html": render_to_string("web/_run_analysis.html", context, request),
        }
    )


@page_throttled
@login_required
def run_json(request: HttpRequest, pk: int) -> StreamingHttpResponse:
    run = visible_run(request, pk)
    return samples_json_response(request, run)


@page_throttled
@login_required
def run_csv(request: HttpRequest, pk: int) -> StreamingHttpResponse:
    run = visible_run(request, pk)
    return samples_csv_response(request, run)


# --- Calendar, feeds, approvals, usage ---------------------------------------------------


@login_required
@never_cache
def api_tokens_page(request: HttpRequest) -> HttpResponse:
    """The user's API tokens: make one (shown once), see when each was last used, revoke."""
    user = _user(request)
    form = ApiTokenForm()
    created = None
    if request.method == "POST" and "revoke" in request.POST:
        try:
            api_token_revoke(user=user, digest=request.POST["revoke"], ip=client_ip(request))
        except DomainError as exc:
            messages.error(request, exc.message)
        else:
            messages.success(request, "Token revoked: it no longer works.")
        return redirect("api-tokens")
    if request.method == "POST":
        form = ApiTokenForm(request.POST)
        if form.is_valid():
            try:
                _, created = api_token_create(
                    user=user,
                    name=form.cleaned_data["name"],
                    expires_in_days=form.cleaned_data["expires_in_days"],
                    mfa_verified=staff_verified(request),
                    ip=client_ip(request),
                )
            except DomainError as exc:
                form_refusal(form, exc)
            else:
                form = ApiTokenForm()
    response = render(
        request,
        "web/tokens.html",
        {
            "form": form,
            # Shown by this answer only, never kept (not in the session, not in a cache).
            "created": created,
            "portal_url": request.build_absolute_uri("/").rstrip("/"),
            "tokens": api_tokens_of(user),
            "needs_mfa": user.has_staff_role and not mfa_enabled(user),
            "needs_second_factor": user.has_staff_role and not staff_verified(request),
        },
    )
    if created is not None:
        response["Cache-Control"] = "no-store"
    return response


@staff_required
def robot_console(request: HttpRequest, name: str) -> HttpResponse:
    resource = get_object_or_404(Resource, name=name, kind="mobile")
    # Manual drive obeys the same limit as programs: the stricter of the portal's and the agent's.
    return render(
        request,
        "web/robot.html",
        {
            "resource": resource,
            "limit": velocity_limit(resource),
            "hold_ttl_s": HOLD_TTL_S,
            "hold_repeat_ms": HOLD_REPEAT_MS,
            # The base station keeps its log by UTC day: today's is that day, not Lisbon's
            # (which is a day ahead between midnight and 01:00 in summer).
            "log_day": timezone.now().date(),
        },
    )


@staff_required
def approvals(request: HttpRequest) -> HttpResponse:
    if request.method == "POST":
        reservation = get_object_or_404(Reservation, pk=request.POST.get("reservation"))
        try:
            reservation_decide(
                reservation=reservation,
                by=_user(request),
                approve=request.POST.get("decision") == "approve",
                reason=request.POST.get("reason", ""),
                ip=client_ip(request),
                via=Channel.WEB,
            )
        except DomainError as exc:
            messages.error(request, exc.message)
        else:
            messages.success(request, f"Decision recorded for reservation {reservation.pk}.")
        return redirect("approvals")
    pending = (
        Reservation.objects.filter(state=ReservationState.REQUESTED)
        .select_related("owner")
        .prefetch_related("items__resource")
        .order_by("start_at")
    )
    return render(request, "web/approvals.html", {"pending": pending})


@staff_required
def scheduler_link(request: HttpRequest) -> HttpResponse:
    """The link to the testbed's scheduler: health, the portal's leases, the others'."""
    return render(request, "web/scheduler.html", scheduler_overview(now=timezone.now()))


@staff_required
def usage_report(request: HttpRequest) -> HttpResponse:
    zone = ZoneInfo(settings.TIME_ZONE)
    today = timezone.localdate()
    try:
        first = date.fromisoformat(request.GET.get("from") or today.replace(day=1).isoformat())
        last = date.fromisoformat(request.GET.get("to") or today.isoformat())
    except ValueError as exc:
        raise BadRequest("Dates are YYYY-MM-DD.") from exc
    by = request.GET.get("by", "user")
    if by not in GROUPINGS or last < first:
        raise BadRequest("Group by user, group or resource; 'to' not before 'from'.")
    start = datetime.combine(first, time(0), tzinfo=zone)
    end = datetime.combine(last + timedelta(days=1), time(0), tzinfo=zone)
    rows = usage_hours(start_at=start, end_at=end, by=by)
    if request.GET.get("format") == "csv":
        response = HttpResponse(content_type="text/csv; charset=utf-8")
        response["Content-Disposition"] = f'attachment; filename="usage-{by}-{first}-{last}.csv"'
        writer = CsvWriter(response)
        writer.writerow([by, "hours", "reservations"])
        writer.writerows(rows)
        return response
    return render(
        request,
        "web/usage.html",
        {"rows": rows, "by": by, "first": first, "last": last, "groupings": GROUPINGS},
    )
