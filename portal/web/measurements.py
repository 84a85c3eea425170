"""The run page's measurements: a file added as a series, a series's clock offset set again,
a series deleted after a confirmation. The same service as
``/api/v1/runs/{id}/measurements/`` (``portal.runs.measurements``), for whoever may see the
run (its owner and staff)."""

from __future__ import annotations

from typing import Any

from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.http import HttpRequest, HttpResponse
from django.shortcuts import get_object_or_404, redirect, render
from django.urls import reverse
from django.views.decorators.http import require_POST

from bookings.choices import Channel
from core.api import page_throttled
from core.audit.services import client_ip
from core.errors import DomainError
from portal.runs import measurements
from portal.runs.measurement_files import format_of
from portal.runs.models import MeasurementSeries, Run
from portal.web.forms import MeasurementForm, MeasurementOffsetForm, form_refusal
from portal.web.views import measurements_context, run_page_response, visible_run


def _back(run: Run) -> str:
    return reverse("run", args=[run.pk]) + "#measurements"


def _series(request: HttpRequest, pk: int, name: str) -> MeasurementSeries:
    run = visible_run(request, pk)
    return get_object_or_404(MeasurementSeries.objects.select_related("run"), run=run, name=name)


def _door(request: HttpRequest) -> dict[str, Any]:
    return {"ip": client_ip(request), "via": str(Channel.WEB)}


@login_required
@require_POST
def measurement_add_view(request: HttpRequest, pk: int) -> HttpResponse:
    """A file added as a series; the run page again with the form's errors if refused."""
    run = visible_run(request, pk)
    limit = measurements.max_upload_bytes()
    if int(request.META.get("CONTENT_LENGTH") or 0) > limit:
        # Said before the body is read: the file is not written to disk first.
        messages.error(request, f"The file is larger than {limit // (1024 * 1024)} MiB.")
        return redirect(_back(run))
    form = MeasurementForm(request.POST, request.FILES)
    if form.is_valid():
        data = form.cleaned_data
        upload = data["file"]
        try:
            points = measurements.read_file_points(
                upload.read(), format_of(upload.name or ""), time_column=data["time_column"]
            )
            added = measurements.measurement_add(
                run=run,
                by=request.user,  # type: ignore[arg-type]
                name=data["name"],
                points=points,
                unit=data["unit"],
                description=data["description"],
                source_node=data["source_node"],
                clock_offset_s=data["clock_offset_s"],
                **_door(request),
            )
        except ValueError as exc:
            # format_of's refusal, or a service's (DomainError is not a ValueError).
            form.add_error("file", str(exc))
        except DomainError as exc:
            form_refusal(form, exc)
        else:
            again = f"; {added.already} were there already" if added.already else ""
            messages.success(
                request, f"Stored {added.stored} values in {added.series.name}{again}."
            )
            return redirect(_back(run))
    return run_page_response(request, run, measurement_form=form, status=400)


@page_throttled
@login_required
def measurement_series_part(request: HttpRequest, pk: int) -> HttpResponse:
    """The run page's series, as the page has them: read again when one changes while the run
    is live (a ``measurements`` push, web/measurements.js)."""
    run = visible_run(request, pk)
    response = render(request, "web/_run_measurement_series.html", measurements_context(run, None))
    response["Cache-Control"] = "private, no-store"
    return response


@login_required
@require_POST
def measurement_offset_view(request: HttpRequest, pk: int, name: str) -> HttpResponse:
    series = _series(request, pk, name)
    form = MeasurementOffsetForm(request.POST)
    if not form.is_valid():
        messages.error(request, "The clock offset is a number of seconds.")
        return redirect(_back(series.run))
    try:
        measurements.measurement_update(
            series=series,
            by=request.user,  # type: ignore[arg-type]
            clock_offset_s=form.cleaned_data["clock_offset_s"],
            **_door(request),
        )
    except DomainError as exc:
        messages.error(request, exc.message)
    else:
        offset_s = form.cleaned_data["clock_offset_s"]
        messages.success(
            request, f"{series.name} placed again with a clock offset of {offset_s:g} s."
        )
    return redirect(_back(series.run))


@login_required
def measurement_delete_view(request: HttpRequest, pk: int, name: str) -> HttpResponse:
    """Asks first (GET), deletes on the answer (POST)."""
    series = _series(request, pk, name)
    if request.method == "POST":
        measurements.measurement_delete(
            series=series,
            by=request.user,  # type: ignore[arg-type]
            **_door(request),
        )
        messages.success(request, f"Deleted {series.name} and its {series.point_count} points.")
        return redirect(_back(series.run))
    return render(request, "web/confirm_measurement_delete.html", {"series": series})
