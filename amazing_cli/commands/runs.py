"""The runs: ``amazing runs``, ``watch`` (a progress bar until the run ends) and ``download``
(its samples, streamed)."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import requests
import typer
from rich.progress import (
    BarColumn,
    DownloadColumn,
    Progress,
    SpinnerColumn,
    TaskProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TransferSpeedColumn,
)
from rich.table import Table

from amazing_cli import times
from amazing_cli.api import Api
from amazing_cli.commands._common import (
    JsonOption,
    QuietOption,
    err,
    out,
    portal_api,
    print_json,
    reports_errors,
)
from amazing_cli.commands.events import events_page
from amazing_cli.errors import OK, RUN_NOT_COMPLETED, UNAVAILABLE, CliError, bad_input
from amazing_cli.package import read_package

RUN_END_STATES = ("completed", "cancelled", "failed", "interrupted")


@reports_errors
def runs(
    ctx: typer.Context,
    state: Annotated[
        str | None, typer.Option(metavar="STATE", help="Only runs in this state.")
    ] = None,
    limit: Annotated[
        int, typer.Option(metavar="N", min=1, help="At most this many, latest first.")
    ] = 50,
    as_json: JsonOption = False,
    quiet: QuietOption = False,
) -> None:
    """Your runs, latest first."""
    listed = list(
        portal_api(ctx).pages("runs", params={"state": state} if state else None, limit=limit)
    )
    if as_json:
        print_json(listed)
        return
    if quiet:
        for r in listed:
            out.print(r["id"])
        return
    table = Table("run", "title", "robot", "state", "start", "samples", box=None)
    for r in listed:
        table.add_row(
            str(r["id"]),
            r["title"],
            r["resource"],
            r["state"],
            times.local(r["start_at"]),
            str(r["sample_count"]),
        )
    out.print(table)


def _program_s(run: dict[str, Any]) -> float:
    return float(sum(s["duration_s"] for s in run["segments"]))


def _polls(api: Api, run_id: int, interval_s: float) -> Iterator[dict[str, Any]]:
    """The run, read again as soon as its next event commits (the events' long poll), or after
    ``interval_s`` for its progress: a new state shows at once, not at the next look."""
    after = 0
    while True:
        yield api.call("run", path={"id": run_id})
        after = events_page(api, after=after, wait_s=interval_s, subject=f"run:{run_id}")["last"]


def _progress_of(run: dict[str, Any]) -> tuple[float, str]:
    """How far into its program a run is (seconds), and a word on it."""
    state, samples = run["state"], run["sample_count"]
    elapsed_s = (times.now() - times.parse_api(run["start_at"])).total_seconds()
    if state in ("scheduled", "staged"):
        return 0.0, f"{state}, starts in {times.seconds(max(0, round(-elapsed_s)))}"
    if state == "running":
        return min(max(0.0, elapsed_s), _program_s(run)), f"running, {samples} samples"
    return _program_s(run), f"{state}, {samples} samples"


@reports_errors
def watch(
    ctx: typer.Context,
    run: Annotated[int, typer.Argument(metavar="RUN", help="The run to follow.")],
    interval: Annotated[
        float, typer.Option(metavar="SECONDS", min=0.2, help="Seconds between looks.")
    ] = 1.0,
    as_json: JsonOption = False,
) -> None:
    """Follow a run's state with a progress bar until it ends (exit 1 unless completed)."""
    api = portal_api(ctx)
    progress = Progress(
        SpinnerColumn(),
        TextColumn("{task.description}"),
        BarColumn(),
        TaskProgressColumn(),
        TextColumn("{task.fields[info]}"),
        console=err,
        disable=as_json,
    )
    current: dict[str, Any] = {}
    last_state = None
    with progress:
        task = None
        for current in _polls(api, run, interval):
            if task is None:
                task = progress.add_task(f"run {run}", total=_program_s(current) or 1, info="")
            if current["state"] != last_state and not as_json:
                progress.console.print(f"run {run}: {current['state']}", markup=False)
            last_state = current["state"]
            done, info = _progress_of(current)
            progress.update(task, completed=done, info=info)
            if current["state"] in RUN_END_STATES:
                break
    if as_json:
        print_json(current)
    else:
        reason = f" ({current['reason']})" if current.get("reason") else ""
        out.print(
            f"Run {run} {current['state']}{reason}: {current['sample_count']} samples.",
            markup=False,
        )
    raise typer.Exit(OK if current["state"] == "completed" else RUN_NOT_COMPLETED)


# What --format asks for, and the API's operation that gives it.
FORMATS = {
    "csv": "samples_csv",
    "json": "samples_json",
    "zip": "run_package",
    "parquet": "samples_parquet",
}


@reports_errors
def download(
    ctx: typer.Context,
    run: Annotated[int, typer.Argument(metavar="RUN", help="The run whose samples to download.")],
    format: Annotated[
        str, typer.Option("--format", "-f", metavar="FORMAT", help="csv, json, zip or parquet.")
    ] = "csv",
    output: Annotated[
        Path | None,
        typer.Option(
            "--output",
            "-o",
            metavar="FILE",
            help="File to write; `-` for stdout. Default: amazing-run-RUN.csv (or .json) here.",
        ),
    ] = None,
    as_json: JsonOption = False,
) -> None:
    """Download every sample of a run, streamed, with a progress bar; `--format zip` is the
    self-describing package (samples, metadata, a README of every column, each measurement
    series); `--format parquet` the samples as Parquet, and each measurement series beside
    them (FILE-NAME.parquet)."""
    if format not in FORMATS:
        raise bad_input(f"--format {format!r}: give csv, json, zip or parquet")
    api = portal_api(ctx)
    details = api.call("run", path={"id": run})
    target = output or Path(f"amazing-run-{run}.{format}")
    to_stdout = str(target) == "-"
    if format in ("zip", "parquet") and to_stdout:
        raise bad_input(f"--format {format}: give a file with --output (not for a terminal)")
    operation = FORMATS[format]
    response = api.stream(operation, path={"id": run})
    total = details["sample_count"] if format == "csv" else None
    newlines, size = save_download(
        response, target, what=f"run {run}", format=format, total=total, quiet=as_json
    )
    samples = _samples(target, format, newlines)
    if (
        details["state"] in RUN_END_STATES
        and samples is not None
        and samples != details["sample_count"]
    ):
        raise CliError(
            f"run {run}: downloaded {samples} samples, the portal holds "
            f"{details['sample_count']}; download it again",
            exit_code=UNAVAILABLE,
        )
    series = _series_beside(api, run, target, quiet=as_json) if format == "parquet" else []
    summary = {"run": run, "format": format, "path": str(target), "samples": samples, "bytes": size}
    if series:
        summary["measurements"] = series
    if as_json:
        (err if to_stdout else out).print_json(json.dumps(summary))
    else:
        (err if to_stdout else out).print(
            f"Wrote {target}: {samples if samples is not None else '?'} samples, {size} bytes.",
            markup=False,
        )
        for written in series:
            out.print(f"Wrote {written['path']}: {written['rows']} rows.", markup=False)


def _series_beside(api: Api, run: int, target: Path, *, quiet: bool) -> list[dict[str, Any]]:
    """Each measurement series of the run as Parquet next to ``target`` (its name added)."""
    written = []
    for series in api.call("measurements", path={"id": run}):
        path = target.with_name(f"{target.stem}-{series['name']}.parquet")
        response = api.stream("measurement_parquet", path={"id": run, "name": series["name"]})
        save_download(response, path, what=f"run {run}", format="parquet", total=None, quiet=quiet)
        written.append({"name": series["name"], "path": str(path), "rows": _parquet_rows(path)})
    return written


def _parquet_rows(path: Path) -> int:
    """The rows of a Parquet file, from its footer (a file cut short has none: refused)."""
    # Imported here: pyarrow is a third of every command's start, and only this reads Parquet.
    import pyarrow.parquet as pq

    try:
        return int(pq.ParquetFile(path).metadata.num_rows)
    except (OSError, ValueError) as exc:
        raise CliError(f"{path} is not a whole Parquet file: {exc}", exit_code=UNAVAILABLE) from exc


def save_download(
    response: requests.Response,
    target: Path,
    *,
    what: str,
    format: str,
    total: int | None,
    quiet: bool,
) -> tuple[int, int]:
    """Write the streamed answer to ``target`` (a ``.part`` file until it is whole), with a
    progress bar of samples (``total``) or bytes; its newlines and bytes. ``what`` names the
    download in its progress and its errors ("run 12")."""
    to_stdout = str(target) == "-"
    newlines = 0
    size = 0
    columns = (
        [
            TextColumn("{task.description}"),
            BarColumn(),
            TaskProgressColumn(),
            TextColumn("{task.completed:.0f}/{task.total:.0f} samples"),
        ]
        if total is not None
        else [
            SpinnerColumn(),
            TextColumn("{task.description}"),
            DownloadColumn(),
            TransferSpeedColumn(),
        ]
    )
    partial = target.with_name(target.name + ".part") if not to_stdout else None
    try:
        with Progress(*columns, TimeElapsedColumn(), console=err, disable=quiet) as progress:
            task = progress.add_task(f"{what} {format}", total=total)
            sink = sys.stdout.buffer if to_stdout else open(partial, "wb")  # type: ignore[arg-type]  # noqa: SIM115
            try:
                for chunk in response.iter_content(chunk_size=64 * 1024):
                    sink.write(chunk)
                    size += len(chunk)
                    newlines += chunk.count(b"\n")
                    done = max(0, newlines - 1) if total is not None else size
                    progress.update(task, completed=done)
            finally:
                if not to_stdout:
                    sink.close()
    except OSError as exc:
        raise bad_input(f"cannot write {target}: {exc}") from exc
    except Exception as exc:
        if partial is not None:
            partial.unlink(missing_ok=True)
        if isinstance(exc, CliError):
            raise
        raise CliError(f"the download of {what} broke off: {exc}", exit_code=UNAVAILABLE) from exc
    finally:
        response.close()
    if partial is not None:
        partial.replace(target)
    return newlines, size


def _samples(target: Path, format: str, newlines: int) -> int | None:
    """How many samples the written file holds (``None`` for JSON on stdout)."""
    if format == "zip":
        # Checked as a reader would: a format it knows, the columns, every sample.
        return read_package(target).rows
    if format == "csv":
        return max(0, newlines - 1)
    if format == "parquet":
        return _parquet_rows(target)
    return len(json.loads(target.read_bytes())["samples"]) if str(target) != "-" else None
