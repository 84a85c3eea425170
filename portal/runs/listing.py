"""Reads behind a researcher's list of runs: filters, search, and the runs chosen from it to
download together or compare.

Every read starts from :func:`portal.runs.selectors.runs_visible`, so a filter never shows,
and a choice never reaches, a run the user may not see.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import date, datetime, time, timedelta
from typing import Any, Final
from zoneinfo import ZoneInfo

from django.conf import settings
from django.db.models import Q, QuerySet

from core.accounts.models import User
from core.errors import InvalidInput
from portal.runs.analysis import SegmentStats
from portal.runs.models import MeasurementSeries, Run
from portal.runs.selectors import RunReport, run_report, runs_visible

# A download of several runs streams each CSV in turn; past this it is a job for the API.
DOWNLOAD_MAX_RUNS: Final = 50
# More curves than this on one chart cannot be told apart.
COMPARE_MAX_RUNS: Final = 6


@dataclass(frozen=True)
class RunFilter:
    """What the list shows: every field left empty shows every run the user may see.

    ``started_from`` and ``started_to`` are days in the testbed's time zone, both included.
    ``text`` matches the run's title, its experiment's title, its robot, or its number.
    """

    states: tuple[str, ...] = ()
    resource: str = ""
    experiment_id: int | None = None
    started_from: date | None = None
    started_to: date | None = None
    text: str = ""
    owner: str = ""


def _day_start(day: date) -> datetime:
    return datetime.combine(day, time(0), tzinfo=ZoneInfo(settings.TIME_ZONE))


def runs_filtered(*, user: User, filters: RunFilter) -> QuerySet[Run]:
    """The user's runs (every run for admins) that pass ``filters``, newest first."""
    qs = runs_visible(user=user).select_related("experiment")
    if filters.states:
        qs = qs.filter(state__in=filters.states)
    if filters.resource:
        qs = qs.filter(resource__name=filters.resource)
    if filters.experiment_id is not None:
        qs = qs.filter(experiment_id=filters.experiment_id)
    if filters.owner:
        qs = qs.filter(reservation__owner__username=filters.owner)
    if filters.started_from is not None:
        qs = qs.filter(start_at__gte=_day_start(filters.started_from))
    if filters.started_to is not None:
        qs = qs.filter(start_at__lt=_day_start(filters.started_to + timedelta(days=1)))
    text = filters.text.strip()
    if text:
        match = (
            Q(title__icontains=text)
            | Q(experiment__title__icontains=text)
            | Q(resource__name__icontains=text)
        )
        number = text.removeprefix("#")
        if number.isdigit():
            match |= Q(pk=int(number))
        qs = qs.filter(match)
    return qs.order_by("-start_at", "-pk")


def runs_chosen(*, user: User, ids: Sequence[int], at_least: int, at_most: int) -> list[Run]:
    """The runs ``ids`` names, in the order named (each once), all visible to ``user``.

    Raises :class:`InvalidInput` (nothing chosen yet, too few, too many, or a run the user may
    not see or that does not exist) with a message for the page.
    """
    unique = list(dict.fromkeys(ids))
    if len(unique) < at_least:
        raise InvalidInput(f"Choose at least {at_least} run{'s' if at_least > 1 else ''}.")
    if len(unique) > at_most:
        raise InvalidInput(f"Choose at most {at_most} runs at a time.")
    found = {run.pk: run for run in runs_visible(user=user).filter(pk__in=unique)}
    unknown = [pk for pk in unique if pk not in found]
    if unknown:
        raise InvalidInput("No run " + ", ".join(str(pk) for pk in unknown) + " among your runs.")
    return [found[pk] for pk in unique]


@dataclass(frozen=True)
class ComparedRun:
    """One run of a comparison with what its charts and statistics need."""

    run: Run
    report: RunReport


@dataclass(frozen=True)
class Comparison:
    """Runs side by side: each run's report, and segment by segment the statistics of every
    run (``None`` where a run's program has fewer segments)."""

    runs: list[ComparedRun]
    segments: list[tuple[int, list[SegmentStats | None]]]


def runs_compared(*, runs: Sequence[Run]) -> Comparison:
    """The reports of ``runs`` (each from the cache when unchanged), segments lined up by
    their index in the program."""
    compared = [ComparedRun(run, run_report(run=run)) for run in runs]
    count = max((len(c.report.analysis.segments) for c in compared), default=0)
    segments = [
        (
            index,
            [
                c.report.analysis.segments[index]
                if index < len(c.report.analysis.segments)
                else None
                for c in compared
            ],
        )
        for index in range(count)
    ]
    return Comparison(compared, segments)


def comparison_series(comparison: Comparison) -> list[dict[str, Any]]:
    """The compare page's curves, every run aligned on its first sample: measured velocity
    (signed, cw +) and the distance travelled along the rail from where the run started
    (unwrapped, cw +), so runs that began at different places still overlay."""
    out = []
    for compared in comparison.runs:
        series = compared.report.series
        velocity = series.get("measured_mps", {"t": [], "y": []})
        track = series.get("track_m", {"t": [], "y": []})
        origin_m = track["y"][0] if track["y"] else 0.0
        out.append(
            {
                "run": compared.run.pk,
                "label": f"run {compared.run.pk}: {compared.run.title}",
                "velocity": {"t": velocity["t"], "y": velocity["y"]},
                "position": {
                    "t": track["t"],
                    "y": [round(y - origin_m, 3) for y in track["y"]],
                },
            }
        )
    return out


def comparison_measurements(comparison: Comparison) -> list[dict[str, Any]]:
    """The compare page's measurements overlaid by position: for each series name and value
    column that any of the runs holds, each run's mean per metre of rail and its statistics
    (``None`` for a run without it), in the runs' order. From the summaries stored with the
    series, so comparing reads no point."""
    order = {c.run.pk: index for index, c in enumerate(comparison.runs)}
    found: dict[tuple[str, str], dict[str, Any]] = {}
    rows = MeasurementSeries.objects.filter(run__in=list(order)).order_by("name")
    for series in rows.only("run_id", "name", "unit", "summary"):
        for column, summary in series.summary.get("columns", {}).items():
            entry = found.setdefault(
                (series.name, column),
                {
                    "name": series.name,
                    "column": column,
                    "unit": series.unit,
                    "runs": [None] * len(order),
                },
            )
            entry["runs"][order[series.run_id]] = {
                "by_metre": [[row[0], row[2]] for row in summary.get("by_metre", [])],
                "stats": summary.get("stats", {}),
            }
    return [found[key] for key in sorted(found)]
