"""``amazing experiment create`` and ``amazing experiment list``: the programs the robot runs."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from amazing_cli import programs, times
from amazing_cli.commands._common import (
    JsonOption,
    QuietOption,
    out,
    portal_api,
    print_json,
    reports_errors,
)


@reports_errors
def experiment_create(
    ctx: typer.Context,
    file: Annotated[
        Path, typer.Argument(metavar="FILE", help="A YAML or JSON file: title and segments.")
    ],
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Create an experiment from a file, checked against the portal's schema first."""
    document = programs.load(file)
    api = portal_api(ctx)
    body = programs.validate(document, schema=api.schema(), source=file)
    created = api.call("experiment_create", json=body)
    if as_json:
        print_json(created)
    elif quiet:
        out.print(created["id"])
    else:
        out.print(
            f"Created experiment {created['id']}: {created['title']} "
            f"({len(created['segments'])} segments, {times.seconds(created['duration_s'])})."
        )


@reports_errors
def experiment_list(
    ctx: typer.Context,
    limit: Annotated[
        int, typer.Option(metavar="N", min=1, help="At most this many, newest first.")
    ] = 50,
    as_json: JsonOption = False,
) -> None:
    """Your experiments."""
    listed = list(portal_api(ctx).pages("experiments", limit=limit))
    if as_json:
        print_json(listed)
        return
    table = Table("id", "title", "segments", "lasts", "created", box=None)
    for e in listed:
        table.add_row(
            str(e["id"]),
            e["title"],
            str(len(e["segments"])),
            times.seconds(e["duration_s"]),
            times.local(e["created_at"]),
        )
    out.print(table)
