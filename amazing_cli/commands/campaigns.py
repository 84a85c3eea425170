"""``amazing campaign …``: a sweep over parameter values queued as one campaign
(``/api/v1/campaigns/``): create it from a file, follow its runs, pause, resume or cancel it."""

from __future__ import annotations

from datetime import date, datetime
from pathlib import Path
from typing import Annotated, Any

import typer

from amazing_cli import programs, times
from amazing_cli.commands._common import (
    JsonOption,
    QuietOption,
    out,
    portal_api,
    print_json,
    reports_errors,
)
from amazing_cli.errors import bad_input

CampaignId = Annotated[int, typer.Argument(metavar="ID", min=1, help="The campaign's id.")]


def _as_json(value: Any) -> Any:
    """YAML's own timestamps (an unquoted 2027-05-01T10:00:00+01:00) as the RFC 3339 text the
    API reads."""
    if isinstance(value, datetime):
        if value.tzinfo is None:
            raise bad_input(f"{value}: give the instant with its offset (+01:00, Z)")
        return times.iso(value)
    if isinstance(value, date):
        raise bad_input(f"{value}: give an instant (a date and a time with its offset)")
    if isinstance(value, dict):
        return {key: _as_json(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_as_json(item) for item in value]
    return value


def _summary(campaign: dict[str, Any]) -> str:
    progress = campaign["progress"]
    queue = ", ".join(f"{n} {state}" for state, n in sorted(progress["queue"].items()))
    runs = ", ".join(f"{n} {state}" for state, n in sorted(progress["run_states"].items()))
    return (
        f"Campaign {campaign['id']} “{campaign['title']}” on {campaign['robot']} "
        f"({campaign['state']}): {progress['runs']} runs; queue: {queue or 'none'}"
        + (f"; runs: {runs}" if runs else "")
    )


@reports_errors
def campaign_create(
    ctx: typer.Context,
    file: Annotated[
        Path,
        typer.Argument(
            metavar="FILE",
            help="A YAML or JSON file: title, robot, parameters, repeats, latest_end_at…",
        ),
    ],
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Queue every run of a campaign file, or none (a bad file is refused, exit code 2)."""
    document = _as_json(programs.load(file))
    made = portal_api(ctx).create("campaign_create", document)
    if as_json:
        print_json(made)
    elif quiet:
        out.print(made["id"])
    else:
        out.print(_summary(made), markup=False)


@reports_errors
def campaign_status(
    ctx: typer.Context, campaign_id: CampaignId, as_json: JsonOption = False
) -> None:
    """A campaign's runs: each one's parameters, its place in the queue or its run's state."""
    campaign = portal_api(ctx).call("campaign", path={"id": campaign_id})
    if as_json:
        print_json(campaign)
        return
    out.print(_summary(campaign), markup=False)
    for run in campaign["runs"]:
        p = run["parameters"]
        where = (
            f"run {run['run']['id']} {run['run']['state']}"
            if run["run"]
            else run["state"] + (f": {run['reason']}" if run["reason"] else "")
        )
        out.print(
            f"  {run['request']}  {p['velocity_mps']:g} m/s {p['direction']} "
            f"{p['duration_s']:g} s, repeat {p['repeat']}: {where}",
            markup=False,
        )


@reports_errors
def campaign_cancel(
    ctx: typer.Context,
    campaign_id: CampaignId,
    cancel_booked: Annotated[
        bool, typer.Option("--cancel-booked", help="Also cancel the runs already booked.")
    ] = False,
    reason: Annotated[str, typer.Option(metavar="TEXT", help="Why (kept with it).")] = "",
    as_json: JsonOption = False,
) -> None:
    """Withdraw a campaign's waiting runs; its booked ones are kept unless --cancel-booked."""
    cancelled = portal_api(ctx).call(
        "campaign_cancel",
        path={"id": campaign_id},
        json={"cancel_booked": cancel_booked, "reason": reason},
    )
    if as_json:
        print_json(cancelled)
    else:
        out.print(_summary(cancelled), markup=False)
