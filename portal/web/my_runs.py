"""A researcher's runs: the list with its filters and search, several runs downloaded as one
zip, and two or more runs compared (``portal/runs/listing.py`` holds the reads)."""

from __future__ import annotations

from typing import Any, cast

from django import forms
from django.contrib import messages
from django.contrib.auth.decorators import login_required
from django.core.paginator import Paginator
from django.http import HttpRequest, HttpResponse, QueryDict, StreamingHttpResponse
from django.shortcuts import redirect, render
from django.urls import reverse

from bookings.models import Resource
from core.accounts.models import User
from core.api import page_throttled
from core.errors import InvalidInput
from portal.experiments.selectors import experiments_visible
from portal.runs.downloads import runs_package_response
from portal.runs.listing import (
    COMPARE_MAX_RUNS,
    DOWNLOAD_MAX_RUNS,
    RunFilter,
    comparison_measurements,
    comparison_series,
    runs_chosen,
    runs_compared,
    runs_filtered,
)
from portal.runs.states import RunState

RUNS_PER_PAGE = 25


class RunFilterForm(forms.Form):
    """The list's filters, all optional; read from the query string."""

    q = forms.CharField(label="Search", required=False, max_length=200, widget=forms.SearchInput())
    state = forms.ChoiceField(
        label="State", required=False, choices=[("", "any state"), *RunState.choices]
    )
    robot = forms.ChoiceField(label="Robot", required=False)
    experiment = forms.TypedChoiceField(
        label="Experiment", required=False, coerce=int, empty_value=None
    )
    started_from = forms.DateField(
        label="Started from", required=False, widget=forms.DateInput(attrs={"type": "date"})
    )
    started_to = forms.DateField(
        label="Started until", required=False, widget=forms.DateInput(attrs={"type": "date"})
    )

    def __init__(self, *args: Any, user: User, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        robots = Resource.objects.filter(kind="mobile").order_by("name")
        robot = cast(forms.ChoiceField, self.fields["robot"])
        robot.choices = [("", "any robot")] + [(r.name, r.name) for r in robots]
        experiments = (
            experiments_visible(user=user).filter(runs__isnull=False).distinct().order_by("title")
        )
        experiment = cast(forms.TypedChoiceField, self.fields["experiment"])
        experiment.choices = [("", "any experiment")] + [
            (e.pk, f"{e.title} (#{e.pk})") for e in experiments
        ]

    def clean(self) -> dict[str, Any]:
        cleaned = super().clean() or {}
        first, last = cleaned.get("started_from"), cleaned.get("started_to")
        if first and last and last < first:
            self.add_error("started_to", "The last day comes on or after the first.")
        return cleaned

    def run_filter(self) -> RunFilter:
        data = self.cleaned_data
        return RunFilter(
            states=(data["state"],) if data.get("state") else (),
            resource=data.get("robot") or "",
            experiment_id=data.get("experiment"),
            started_from=data.get("started_from"),
            started_to=data.get("started_to"),
            text=data.get("q") or "",
        )


def chosen_ids(query: QueryDict) -> list[int]:
    """The run numbers of ``?ids=`` (repeated, as checkboxes send them, or comma-separated,
    as links write them). Raises :class:`InvalidInput` for anything but whole numbers."""
    ids = []
    for value in query.getlist("ids"):
        for part in value.split(","):
            part = part.strip()
            if not part:
                continue
            if not part.isdigit():
                raise InvalidInput(f"“{part[:20]}” is not a run number.")
            ids.append(int(part))
    return ids


def _back_to_list(request: HttpRequest, message: str) -> HttpResponse:
    messages.error(request, message)
    return redirect("my-runs")


@login_required
def my_runs(request: HttpRequest) -> HttpResponse:
    user: Any = request.user
    filtered = {k: v for k, v in request.GET.items() if k != "page"}
    form = RunFilterForm(filtered or None, user=user)
    runs = runs_filtered(user=user, filters=form.run_filter() if form.is_valid() else RunFilter())
    if form.is_bound and not form.is_valid():
        # A filter that cannot be read shows nothing rather than everything.
        runs = runs.none()
    page = Paginator(runs, RUNS_PER_PAGE).get_page(request.GET.get("page"))
    query = request.GET.copy()
    query.pop("page", None)
    return render(
        request,
        "web/my_runs.html",
        {
            "form": form,
            "page": page,
            "filter_query": query.urlencode(),
            "filtered": bool(filtered),
            "download_max": DOWNLOAD_MAX_RUNS,
            "compare_max": COMPARE_MAX_RUNS,
        },
    )


@page_throttled
@login_required
def runs_package(request: HttpRequest) -> HttpResponse | StreamingHttpResponse:
    """The chosen runs as one zip: a folder per run (its package) and ``manifest.json``."""
    try:
        runs = runs_chosen(
            user=request.user,  # type: ignore[arg-type]
            ids=chosen_ids(request.GET),
            at_least=1,
            at_most=DOWNLOAD_MAX_RUNS,
        )
    except InvalidInput as exc:
        return _back_to_list(request, f"Nothing downloaded: {exc.message}")
    return runs_package_response(request, runs)


@login_required
def runs_compare(request: HttpRequest) -> HttpResponse:
    """Two or more runs: velocity and position overlaid from each run's start, and their
    statistics side by side."""
    try:
        runs = runs_chosen(
            user=request.user,  # type: ignore[arg-type]
            ids=chosen_ids(request.GET),
            at_least=2,
            at_most=COMPARE_MAX_RUNS,
        )
    except InvalidInput as exc:
        return _back_to_list(request, f"Nothing to compare: {exc.message}")
    comparison = runs_compared(runs=runs)
    return render(
        request,
        "web/compare_runs.html",
        {
            "comparison": comparison,
            "series": comparison_series(comparison),
            "measurements": comparison_measurements(comparison),
            "package_url": reverse("runs-package") + "?ids=" + ",".join(str(r.pk) for r in runs),
        },
    )
