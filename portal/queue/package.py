"""A campaign as one download: every completed run's package in a folder of its own with the
manifest (``portal/runs/package.py`` ``runs_package_zip``), and ``campaign.json``, a Frictionless
Data Package of two inline tables: every run of the campaign with its parameters' values
(``runs``) and the results over the repeats (``results``, ``portal/queue/results.py``). Each
``datapackage.json`` and ``campaign.json`` pass ``frictionless validate``.

Docs: docs/run-package.md ("A campaign's download").
"""

from __future__ import annotations

from typing import Any, Final

from django.http import HttpRequest, StreamingHttpResponse
from django.utils import timezone
from rest_framework.request import Request

from portal.queue.campaigns import campaign_requests
from portal.queue.models import Campaign
from portal.queue.results import (
    METRICS,
    CampaignRun,
    ResultGroup,
    campaign_results,
    campaign_runs_completed,
)
from portal.runs.downloads import runs_package_response
from portal.runs.package import run_folder
from portal.runs.provenance import PORTAL_VERSION

CAMPAIGN_FILE: Final = "campaign.json"
CAMPAIGN_FORMAT: Final = "amazing-campaign"
# Bump when a reader of the previous version would misread a campaign.json.
CAMPAIGN_FORMAT_VERSION: Final = 1

_RUN_FIELDS: Final = [
    ("request", "integer", "The queued request's id."),
    ("run", "integer", "The run's id, once booked (empty: not booked)."),
    ("folder", "string", "The run's package in this zip (empty: the run did not complete)."),
    ("velocity_mps", "number", "Commanded velocity (m/s)."),
    ("direction", "string", "cw or ccw."),
    ("duration_s", "number", "The program's duration (s)."),
    ("repeat", "integer", "Which repeat of these values (1 on)."),
    ("queue_state", "string", "The request's state in the queue."),
    ("run_state", "string", "The run's state (empty: not booked)."),
]


def _schema(fields: list[tuple[str, str, str]]) -> dict[str, Any]:
    return {
        "fields": [
            {"name": name, "type": kind, "description": meaning} for name, kind, meaning in fields
        ]
    }


def _results_fields() -> list[tuple[str, str, str]]:
    fields = [
        ("velocity_mps", "number", "Commanded velocity (m/s)."),
        ("direction", "string", "cw or ccw."),
        ("duration_s", "number", "The program's duration (s)."),
        ("repeats", "integer", "Completed runs with these values."),
    ]
    for name, title in METRICS:
        fields.append((f"{name}_mean", "number", f"{title}: the mean over the repeats."))
        fields.append(
            (f"{name}_sd", "number", f"{title}: the sample sd over the repeats (empty: one).")
        )
    return fields


def _runs_rows(campaign: Campaign, completed: set[int]) -> list[list[Any]]:
    rows: list[list[Any]] = [[name for name, _, _ in _RUN_FIELDS]]
    for request in campaign_requests(campaign):
        run = getattr(request.reservation, "run", None) if request.reservation else None
        parameters = request.parameters or {}
        rows.append(
            [
                request.pk,
                run.pk if run else None,
                run_folder(run) if run is not None and run.pk in completed else None,
                parameters.get("velocity_mps"),
                parameters.get("direction"),
                parameters.get("duration_s"),
                parameters.get("repeat"),
                request.state,
                run.state if run else None,
            ]
        )
    return rows


def _results_rows(groups: list[ResultGroup]) -> list[list[Any]]:
    rows: list[list[Any]] = [[name for name, _, _ in _results_fields()]]
    for group in groups:
        row: list[Any] = [group.velocity_mps, group.direction, group.duration_s, len(group.runs)]
        for name, _ in METRICS:
            spread = group.metrics.get(name)
            row += [spread.mean, spread.sd] if spread is not None else [None, None]
        rows.append(row)
    return rows


def campaign_descriptor(
    campaign: Campaign, completed: list[CampaignRun], groups: list[ResultGroup]
) -> dict[str, Any]:
    """``campaign.json``: the campaign's runs and results as inline tables, and under
    ``amazing`` the campaign itself with the file it was made from."""
    done = {one.run.pk for one in completed}
    return {
        "profile": "tabular-data-package",
        "name": f"amazing-campaign-{campaign.pk}",
        "title": f"AMazING campaign {campaign.pk}: {campaign.title}",
        "created": timezone.now().isoformat(),
        "resources": [
            {
                "name": "runs",
                "profile": "tabular-data-resource",
                "title": "Every run of the campaign with its parameters' values",
                "data": _runs_rows(campaign, done),
                "schema": _schema(_RUN_FIELDS),
            },
            {
                "name": "results",
                "profile": "tabular-data-resource",
                "title": "Per combination of values: the run's statistics over the repeats",
                "data": _results_rows(groups),
                "schema": _schema(_results_fields()),
            },
        ],
        "amazing": {
            "format": CAMPAIGN_FORMAT,
            "format_version": CAMPAIGN_FORMAT_VERSION,
            "generated_by": {"portal_version": PORTAL_VERSION},
            "campaign": {
                "id": campaign.pk,
                "title": campaign.title,
                "owner": campaign.owner.get_username(),
                "robot": campaign.robot.name,
                "state": campaign.state,
                "created_at": campaign.created_at.isoformat(),
                "file": campaign.spec,
            },
        },
    }


def campaign_package_response(
    request: HttpRequest | Request, campaign: Campaign
) -> StreamingHttpResponse:
    """The campaign's zip, streamed: its completed runs' packages, then ``campaign.json``."""
    completed = campaign_runs_completed(campaign)
    descriptor = campaign_descriptor(campaign, completed, campaign_results(completed))
    return runs_package_response(
        request,
        [one.run for one in completed],
        name=f"amazing-campaign-{campaign.pk}",
        extra={CAMPAIGN_FILE: descriptor},
    )
