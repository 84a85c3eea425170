"""The ``amazing`` command: book the mobile node, run experiments, get their data.

Everything goes through the portal's public REST API (:mod:`amazing_cli.api`). Output is for
people by default; ``--json`` prints the API's JSON for scripts and ``--quiet`` only the id a
command made. Exit codes: 0 ok, 2 bad input, 3 refused, 4 not found, 5 server or network
(``watch``: 1 when the run ended without completing). ``docs/cli.md`` is the manual.

This module builds the app and its root options; the commands are in :mod:`amazing_cli.commands`,
by what they act on.
"""

from __future__ import annotations

from typing import Annotated

import typer

from amazing_cli.commands import (
    account,
    bookings,
    campaigns,
    events,
    experiments,
    measurements,
    queue,
    resources,
    runs,
    webhooks,
)
from amazing_cli.errors import OK

app = typer.Typer(
    name="amazing",
    help="Book the AMazING testbed's mobile node, run experiments on it and get their data.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
experiment_app = typer.Typer(help="Experiments: the programs the robot runs.", no_args_is_help=True)
app.add_typer(experiment_app, name="experiment")
webhook_app = typer.Typer(
    help="Webhooks: your events sent to a URL of yours, signed.", no_args_is_help=True
)
app.add_typer(webhook_app, name="webhook")
measurements_app = typer.Typer(
    help="Your own measurements on a run, placed where the robot was.", no_args_is_help=True
)
app.add_typer(measurements_app, name="measurements")
queue_app = typer.Typer(
    help="The queue: runs asked for as soon as possible, booked in fair-share order.",
    no_args_is_help=True,
)
app.add_typer(queue_app, name="queue")
campaign_app = typer.Typer(
    help="Campaigns: a sweep over parameter values, queued as one.", no_args_is_help=True
)
app.add_typer(campaign_app, name="campaign")


@app.callback()
def root(
    ctx: typer.Context,
    url: Annotated[
        str | None,
        typer.Option(
            metavar="URL", help="The portal's address (else AMAZING_URL, else the stored login)."
        ),
    ] = None,
    token: Annotated[
        str | None,
        typer.Option(
            metavar="TOKEN", help="An API token (else AMAZING_TOKEN, else the stored login)."
        ),
    ] = None,
) -> None:
    ctx.obj = {"url": url, "token": token}


# The commands, in the order `amazing --help` lists them.
app.command()(account.login)
app.command()(account.logout)
app.command()(resources.resources)
app.command()(resources.availability)
app.command()(resources.quota)
app.command()(bookings.book)
app.command()(bookings.cancel)
app.command()(bookings.attach)
app.command()(runs.runs)
app.command()(runs.watch)
app.command()(runs.download)
app.command()(events.events)
experiment_app.command("create")(experiments.experiment_create)
experiment_app.command("list")(experiments.experiment_list)
webhook_app.command("create")(webhooks.webhook_create)
webhook_app.command("list")(webhooks.webhook_list)
webhook_app.command("log")(webhooks.webhook_log)
webhook_app.command("test")(webhooks.webhook_test)
webhook_app.command("resume")(webhooks.webhook_resume)
webhook_app.command("delete")(webhooks.webhook_delete)
measurements_app.command("add")(measurements.measurements_add)
measurements_app.command("list")(measurements.measurements_list)
measurements_app.command("offset")(measurements.measurements_offset)
measurements_app.command("delete")(measurements.measurements_delete)
queue_app.command("list")(queue.queue_list)
queue_app.command("add")(queue.queue_add)
queue_app.command("cancel")(queue.queue_cancel)
campaign_app.command("create")(campaigns.campaign_create)
campaign_app.command("status")(campaigns.campaign_status)
campaign_app.command("cancel")(campaigns.campaign_cancel)
campaign_app.command("pause")(campaigns.campaign_pause)
campaign_app.command("resume")(campaigns.campaign_resume)
campaign_app.command("download")(campaigns.campaign_download)


def main() -> int:
    try:
        app()
    except SystemExit as exc:
        code = exc.code
        return code if isinstance(code, int) else (0 if code is None else 1)
    return OK
