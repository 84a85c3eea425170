"""``amazing campaign …``: a sweep over parameter values queued as one campaign
(``/api/v1/campaigns/``): create it from a file, follow its runs and results, download it,
pause, resume or cancel it."""

from __future__ import annotations

import json
import zipfile
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
from amazing_cli.commands.runs import save_download
from amazing_cli.errors import UNAVAILABLE, CliError, bad_input

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


def _spread(metric: dict[str, Any] | None) -> str:
    if metric is None:
        return "—"
    sd = metric["sd"]
    return f"{metric['mean']:.3f}" + (f" ± {sd:.3f}" if sd is not None else "")


def _print_results(results: dict[str, Any]) -> None:
    """The results table: per combination of values, the measured velocity and the mean
    |error| over the repeats (mean ± sample sd)."""
    if not results["groups"]:
        return
    out.print(
        f"Results of {results['completed']} completed runs (mean ± sd over the repeats):",
        markup=False,
    )
    out.print("  velocity  direction  duration  repeats  measured (m/s)    |error| (m/s)")
    for group in results["groups"]:
        metrics = group["metrics"]
        out.print(
            f"  {group['velocity_mps']:>6g}    {group['direction']:<9}  "
            f"{group['duration_s']:>6g} s  {len(group['runs']):>7}  "
            f"{_spread(metrics.get('mean_mps')):<16}  "
            f"{_spread(metrics.get('mean_abs_error_mps'))}",
            markup=False,
        )


@reports_errors
def campaign_status(
    ctx: typer.Context, campaign_id: CampaignId, as_json: JsonOption = False
) -> None:
    """A campaign's runs: each one's parameters, its place in the queue or its run's state;
    then the results of those completed."""
    api = portal_api(ctx)
    campaign = api.call("campaign", path={"id": campaign_id})
    results = api.call("campaign_results", path={"id": campaign_id})
    if as_json:
        print_json({**campaign, "results": results})
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
    _print_results(results)


@reports_errors
def campaign_pause(
    ctx: typer.Context, campaign_id: CampaignId, as_json: JsonOption = False
) -> None:
    """Hold a campaign's waiting runs back: the queue passes over them until resumed."""
    paused = portal_api(ctx).call("campaign_pause", path={"id": campaign_id})
    print_json(paused) if as_json else out.print(_summary(paused), markup=False)


@reports_errors
def campaign_resume(
    ctx: typer.Context, campaign_id: CampaignId, as_json: JsonOption = False
) -> None:
    """Let a paused campaign's waiting runs be booked again."""
    resumed = portal_api(ctx).call("campaign_resume", path={"id": campaign_id})
    print_json(resumed) if as_json else out.print(_summary(resumed), markup=False)


@reports_errors
def campaign_download(
    ctx: typer.Context,
    campaign_id: CampaignId,
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            metavar="FILE",
            help="File to write. Default: amazing-campaign-ID.zip here.",
        ),
    ] = None,
    as_json: JsonOption = False,
) -> None:
    """Download a campaign as one zip, streamed: every completed run's package in a folder
    of its own, and campaign.json (every run's parameters and the results, a Frictionless
    Data Package)."""
    target = output or Path(f"amazing-campaign-{campaign_id}.zip")
    if str(target) == "-":
        raise bad_input("--output -: give a file (a zip is not for a terminal)")
    response = portal_api(ctx).stream("campaign_package", path={"id": campaign_id})
    what = f"campaign {campaign_id}"
    _, size = save_download(response, target, what=what, format="zip", total=None, quiet=as_json)
    try:
        with zipfile.ZipFile(target) as archive:
            descriptor = json.loads(archive.read("campaign.json"))
    except (zipfile.BadZipFile, KeyError, ValueError) as exc:
        raise CliError(
            f"{target} is not a whole campaign download ({exc}); download it again",
            exit_code=UNAVAILABLE,
        ) from exc
    runs = descriptor["resources"][0]["data"][1:]
    header = descriptor["resources"][0]["data"][0]
    packaged = sum(1 for row in runs if row[header.index("folder")])
    summary = {"campaign": campaign_id, "path": str(target), "runs": len(runs),
               "packaged": packaged, "bytes": size}  # fmt: skip
    if as_json:
        print_json(summary)
    else:
        out.print(
            f"Wrote {target}: {packaged} of {len(runs)} runs' packages and campaign.json, "
            f"{size} bytes.",
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
