"""``amazing measurements …``: your own measurements on a run (``/api/v1/runs/{id}/measurements/``):
add a file (CSV, JSON or Parquet) as a series, list a run's series with where their points fell
on the robot's path, set a series's clock offset, delete one."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from amazing_cli.commands._common import (
    JsonOption,
    QuietOption,
    out,
    portal_api,
    print_json,
    reports_errors,
)
from amazing_cli.errors import BAD_INPUT, CliError

RunId = Annotated[int, typer.Argument(metavar="RUN", min=1, help="The run.")]
SeriesName = Annotated[str, typer.Argument(metavar="NAME", help="The series's name.")]


def _where(series: dict[str, Any]) -> str:
    """How the series's points fell, summed over its columns' first."""
    columns = series["summary"].get("columns", {})
    if not columns:
        return "no points"
    where = next(iter(columns.values()))["where"]
    told = [f"{where['placed']} on the path"]
    told += [f"{where[key]} {key}" for key in ("before", "after", "gap") if where[key]]
    return ", ".join(told)


def _line(series: dict[str, Any]) -> str:
    unit = f" [{series['unit']}]" if series["unit"] else ""
    offset = f", clock offset {series['clock_offset_s']:g} s" if series["clock_offset_s"] else ""
    suggested = series["summary"].get("suggested_offset_s")
    if suggested is not None and suggested != series["clock_offset_s"]:
        offset += f"; your marker suggests an offset of {suggested:g} s"
    return (
        f"{series['name']}{unit}: {series['point_count']} points of "
        f"{', '.join(series['columns'])} ({_where(series)}){offset}"
    )


@reports_errors
def measurements_add(
    ctx: typer.Context,
    run: RunId,
    file: Annotated[
        Path,
        typer.Argument(
            metavar="FILE", exists=True, dir_okay=False, help="CSV, JSON or Parquet points."
        ),
    ],
    name: Annotated[str, typer.Option(metavar="NAME", help="The series's name (rssi, …).")],
    unit: Annotated[str, typer.Option(metavar="UNIT", help="The values' unit (dBm, …).")] = "",
    description: Annotated[str, typer.Option(metavar="TEXT", help="What was measured.")] = "",
    source_node: Annotated[
        str, typer.Option(metavar="NODE", help="The node that measured (node-07, …).")
    ] = "",
    time_column: Annotated[
        str, typer.Option(metavar="COLUMN", help="The time column (default: t, time, …).")
    ] = "",
    column: Annotated[
        list[str] | None,
        typer.Option(
            "--column", metavar="COLUMN", help="A value column (repeatable; default: all)."
        ),
    ] = None,
    clock_offset_s: Annotated[
        float | None,
        typer.Option(metavar="SECONDS", help="Added to the file's times (your clock's lag)."),
    ] = None,
    marker_at: Annotated[
        str,
        typer.Option(
            metavar="WHEN",
            help="When your machine saw the first segment begin (RFC 3339): offers the offset.",
        ),
    ] = "",
    format: Annotated[
        str, typer.Option(metavar="FORMAT", help="csv, json or parquet (default: by the name).")
    ] = "",
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Add FILE's points to the run's series NAME (made the first time). Points sent before
    are stored once."""
    form: dict[str, Any] = {
        "name": name,
        "unit": unit,
        "description": description,
        "source_node": source_node,
        "time_column": time_column,
        "columns": ",".join(column or []),
    }
    if clock_offset_s is not None:
        form["clock_offset_s"] = repr(clock_offset_s)
    if format:
        form["format"] = format
    if marker_at:
        form["marker_at"] = marker_at
    try:
        content = file.read_bytes()
    except OSError as exc:
        raise CliError(f"cannot read {file}: {exc.strerror}", exit_code=BAD_INPUT) from exc
    added = portal_api(ctx).call(
        "measurement_upload",
        path={"id": run},
        data=form,
        files={"file": (file.name, content)},
    )
    if as_json:
        print_json(added)
        return
    series = added["series"]
    if quiet:
        out.print(series["name"])
        return
    again = f"; {added['already']} were there already" if added["already"] else ""
    out.print(f"Stored {added['stored']} values in {series['name']} of run {run}{again}.")
    out.print(_line(series), markup=False)


@reports_errors
def measurements_list(ctx: typer.Context, run: RunId, as_json: JsonOption = False) -> None:
    """The run's measurement series, with where their points fell on the robot's path."""
    listed = portal_api(ctx).call("measurements", path={"id": run})
    if as_json:
        print_json(listed)
        return
    if not listed:
        out.print(f"Run {run} has no measurements: `amazing measurements add {run} FILE` adds one.")
        return
    for series in listed:
        out.print(_line(series), markup=False)


@reports_errors
def measurements_offset(
    ctx: typer.Context,
    run: RunId,
    name: SeriesName,
    seconds: Annotated[float, typer.Argument(metavar="SECONDS", help="The new clock offset.")],
    as_json: JsonOption = False,
) -> None:
    """Set the series's clock offset (added to its times) and place its points again."""
    series = portal_api(ctx).call(
        "measurement_offset", path={"id": run, "name": name}, json={"clock_offset_s": seconds}
    )
    if as_json:
        print_json(series)
        return
    out.print(_line(series), markup=False)


@reports_errors
def measurements_delete(
    ctx: typer.Context,
    run: RunId,
    name: SeriesName,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="Do not ask.")] = False,
) -> None:
    """Delete the series and its points."""
    api = portal_api(ctx)
    if not yes:
        shown = api.call("measurement", path={"id": run, "name": name})
        question = f"Delete {shown['name']} of run {run} ({shown['point_count']} points)?"
        if not typer.confirm(question, default=False):
            out.print("Kept it.")
            return
    api.call("measurement_delete", path={"id": run, "name": name})
    out.print(f"Deleted {name} of run {run}.")
