"""A run as one self-describing download: a zip holding a Frictionless Data Package.

``amazing-run-<id>.zip`` holds:

- ``samples.csv``: every sample, exactly the CSV download (streamed from PostgreSQL's ``COPY``
  through the zip's deflate, never held whole);
- ``datapackage.json``: the Data Package descriptor (https://datapackage.org): the CSV as a
  tabular resource with its Table Schema (a field per contract column: type, unit, meaning,
  constraints), its size and SHA-256, and under ``amazing`` the run's metadata document: the
  run, the experiment program, the reservation, the owner, how the run was made
  (``portal/runs/provenance.py``) and the analysis summary, with the format's name and
  version (:data:`FORMAT_VERSION`);
- ``README.md``: the same for people, every column named with its unit and meaning;
- ``measurements/<name>.csv``: each of the run's measurement series placed on the robot's
  path (``portal/runs/measurement_tables.py``), a resource of its own with its Table Schema
  and a foreign key to the samples.

Columns, types, units and meanings come from ``basestation/contract.py`` ``SAMPLE_COLUMNS``
and nowhere else, so the package cannot describe a column the CSV does not have. The
descriptor goes last: it carries the CSV's size and hash, known only once the CSV is written.
Several runs download as one zip (:func:`runs_package_zip`): each run's package in a folder
``run-<id>/`` and a ``manifest.json`` listing the folders.

Docs: docs/run-package.md.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from collections.abc import Generator, Iterator, Mapping, Sequence
from datetime import UTC, datetime
from typing import Any, Final

from django.utils import timezone

from basestation.contract import SAMPLE_COLUMNS, SampleColumn
from portal.runs.measurement_tables import series_csv, series_schema
from portal.runs.measurements import run_track
from portal.runs.models import MeasurementSeries, Run
from portal.runs.provenance import PORTAL_VERSION, provenance_summary, provenance_view
from portal.runs.selectors import CSV_TIME_FORMAT, run_report, run_report_json, run_samples_csv

FORMAT: Final = "amazing-run-package"
# Bump when a reader of the previous version would misread a package; keep an example of
# each version in tests/data (tests/runs/test_package.py reads them all).
FORMAT_VERSION: Final = 1
SAMPLES_FILE: Final = "samples.csv"
DESCRIPTOR_FILE: Final = "datapackage.json"
README_FILE: Final = "README.md"
# A download of several runs: one package per folder and a manifest of them.
MANIFEST_FORMAT: Final = "amazing-runs-manifest"
MANIFEST_FILE: Final = "manifest.json"
MEASUREMENTS_FOLDER: Final = "measurements/"
# Deflate's fastest level keeps up with the database; the CSV still shrinks about fourfold.
ZIP_LEVEL: Final = 1

_TABLE_TYPE: Final = {"int": "integer", "float": "number", "text": "string", "epoch": "datetime"}


def field_descriptor(column: SampleColumn) -> dict[str, Any]:
    """One contract column as a Table Schema field (with ``unit``, a custom property)."""
    field: dict[str, Any] = {
        "name": column.name,
        "type": _TABLE_TYPE[column.kind],
        "description": column.doc,
    }
    if column.kind == "epoch":
        field["format"] = CSV_TIME_FORMAT
    if column.unit:
        field["unit"] = column.unit
    constraints: dict[str, Any] = {}
    if not column.nullable:
        constraints["required"] = True
    if column.choices is not None:
        constraints["enum"] = list(column.choices)
    elif column.max_length is not None:
        constraints["maxLength"] = column.max_length
    if column.minimum is not None:
        constraints["minimum"] = column.minimum
    if constraints:
        field["constraints"] = constraints
    return field


def table_schema() -> dict[str, Any]:
    return {
        "fields": [field_descriptor(column) for column in SAMPLE_COLUMNS],
        "primaryKey": ["seq"],
        "missingValues": [""],
    }


def _iso(value: datetime | None) -> str | None:
    return None if value is None else value.astimezone(UTC).isoformat()


def run_metadata(run: Run, *, url: str | None, now: datetime) -> dict[str, Any]:
    """The metadata document: what the run was, who booked it, how it was made, what the
    analysis found (the ``amazing`` part of the descriptor)."""
    reservation = run.reservation
    report = run_report(run=run)
    analysis = run_report_json(report)
    # Passes depend on a position the reader chooses: not part of the summary.
    analysis.pop("passes", None)
    analysis.pop("pass_at_m", None)
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "generated_at": _iso(now),
        "generated_by": {"portal_version": PORTAL_VERSION},
        "run": {
            "id": run.pk,
            "url": url,
            "title": run.title,
            "resource": run.resource.name,
            "state": run.state,
            "reason": run.reason,
            "start_at": _iso(run.start_at),
            "end_at": _iso(run.end_at),
            "samples": report.analysis.samples,
            "agent_sample_count": run.agent_sample_count,
            "last_seq": run.last_seq,
            "rail_length_m": run.rail_length_m,
            "missing": run.missing,
            "repeat_of": run.repeat_of_id,
            "events": [
                {
                    "from_state": event.from_state,
                    "to_state": event.to_state,
                    "at": _iso(event.at),
                    "reason": event.reason,
                }
                for event in run.events.all()
            ],
        },
        "experiment": {
            "id": run.experiment_id,
            "title": run.title,
            "segments": run.segments,
            "limits": run.limits,
        },
        "reservation": {
            "id": reservation.pk,
            "public_id": str(reservation.public_id),
            "title": reservation.title,
            "state": reservation.state,
            "start_at": _iso(reservation.start_at),
            "end_at": _iso(reservation.end_at),
            "resources": [item.resource.name for item in reservation.items.all()],
            "created_at": _iso(reservation.created_at),
        },
        "owner": {"username": reservation.owner.get_username()},
        "provenance": provenance_view(run.provenance),
        "analysis": analysis,
    }


def series_file(series: MeasurementSeries) -> str:
    return f"{MEASUREMENTS_FOLDER}{series.name}.csv"


def series_resource(series: MeasurementSeries, *, csv_bytes: int, csv_sha256: str) -> dict:
    """A measurement series as a tabular resource of the package."""
    unit = f" ({series.unit})" if series.unit else ""
    return {
        "name": f"measurement-{series.name}",
        "path": series_file(series),
        "profile": "tabular-data-resource",
        "title": f"{series.name}{unit}: {', '.join(series.columns)}, placed on the robot's path",
        "description": series.description or f"The measurement series {series.name}.",
        "format": "csv",
        "mediatype": "text/csv",
        "encoding": "utf-8",
        "bytes": csv_bytes,
        "hash": f"sha256:{csv_sha256}",
        "schema": series_schema(series),
        "amazing": {
            "unit": series.unit,
            "source_node": series.source_node,
            "columns": list(series.columns),
            "clock_offset_s": series.clock_offset_s,
            "points": series.point_count,
        },
    }


def package_descriptor(
    run: Run,
    *,
    metadata: dict[str, Any],
    csv_bytes: int,
    csv_sha256: str,
    series: Sequence[dict[str, Any]] = (),
) -> dict[str, Any]:
    """The Data Package descriptor: the samples as a tabular resource, the metadata beside."""
    owner = metadata["owner"]["username"]
    return {
        "profile": "tabular-data-package",
        "name": f"amazing-run-{run.pk}",
        "id": metadata["run"]["url"] or f"amazing-run-{run.pk}",
        "title": f"AMazING run {run.pk}: {run.title}",
        "description": (
            f"Telemetry of run {run.pk} of the AMazING testbed's mobile node "
            f"{run.resource.name}, {metadata['run']['start_at']} to {metadata['run']['end_at']}."
        ),
        "created": metadata["generated_at"],
        "contributors": [{"title": owner, "role": "author"}],
        "keywords": ["AMazING", "mobile node", "robot", "telemetry"],
        "resources": [
            {
                "name": "samples",
                "path": SAMPLES_FILE,
                "profile": "tabular-data-resource",
                "title": "Telemetry samples, one per control tick",
                "format": "csv",
                "mediatype": "text/csv",
                "encoding": "utf-8",
                "bytes": csv_bytes,
                "hash": f"sha256:{csv_sha256}",
                "schema": table_schema(),
            },
            *series,
        ],
        "amazing": metadata,
    }


def _cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def column_rows() -> list[tuple[str, str, str, str]]:
    """(column, type, unit, meaning) of every CSV column, as the README lists them."""
    rows = []
    for column in SAMPLE_COLUMNS:
        meaning = column.doc
        if column.nullable:
            meaning += " (empty: null)"
        rows.append((column.name, _TABLE_TYPE[column.kind], column.unit or "–", meaning))
    return rows


def _value(value: Any, unit: str = "") -> str:
    if value is None:
        return "not recorded"
    if isinstance(value, bool):
        return "yes" if value else "no"
    return f"{value:g} {unit}".strip() if isinstance(value, float) else f"{value} {unit}".strip()


def _files_lines() -> list[str]:
    """The README's list of the package's files."""
    return [
        "## Files",
        "",
        f"- `{SAMPLES_FILE}`: one row per telemetry sample, in sequence order; the columns "
        "are below.",
        f"- `{DESCRIPTOR_FILE}`: a Frictionless Data Package descriptor "
        "(<https://datapackage.org>): the CSV's Table Schema, size and SHA-256, and under "
        f"`amazing` the run's metadata (format `{FORMAT}`, version {FORMAT_VERSION}): the run, "
        "the program, the reservation, the owner, how the run was made and the analysis "
        "summary.",
        f"- `{MEASUREMENTS_FOLDER}<name>.csv`: each measurement series of the run (if any), "
        "placed on the robot's path: `t` (the measuring clock), `t_base` (the base station's), "
        "the values, and `robot_*`, where the robot was then; `robot_sample_seq` is the nearer "
        f"sample's `seq` in `{SAMPLES_FILE}`. Each one's columns are in `{DESCRIPTOR_FILE}`.",
        f"- `{README_FILE}`: this file.",
    ]


def package_readme(run: Run, metadata: dict[str, Any]) -> str:
    """README.md: what the package holds, every column, and how the run was made."""
    info = metadata["run"]
    summary = provenance_summary(metadata["provenance"])
    collected = summary["collected"] or {}
    agent = summary["agent"] or {}
    rail = agent.get("rail") or {}
    firmware = summary["firmware"] or {}
    link = collected.get("link") or {}
    lines = [
        f"# AMazING run {run.pk}: {run.title}",
        "",
        f"Robot {info['resource']}, booked by {metadata['owner']['username']}, "
        f"{info['start_at']} to {info['end_at']} (UTC); ended {info['state']}"
        + (f" ({info['reason']})" if info["reason"] else "")
        + f"; {info['samples']} samples.",
        "",
        *_files_lines(),
        "",
        "Check the package with Frictionless: `frictionless validate datapackage.json`.",
        "",
        f"## Columns of {SAMPLES_FILE}",
        "",
        "Times are UTC (ISO 8601 with microseconds); an empty cell is a missing value.",
        "",
        "| column | type | unit | meaning |",
        "| --- | --- | --- | --- |",
        *(f"| {' | '.join(_cell(part) for part in row)} |" for row in column_rows()),
        "",
        "## How this run was made",
        "",
        f"- Robot firmware: build {_value(firmware.get('build_id'))}",
        f"- Base station agent: version {_value(agent.get('version'))}, "
        f"{_value(agent.get('control_hz'), 'Hz')} control rate, "
        f"limits {_value(agent.get('max_velocity_mps'), 'm/s')} and "
        f"{_value(agent.get('max_accel_mps2'), 'm/s²')}",
        f"- Run limits sent: {_value((summary['limits'] or {}).get('max_velocity_mps'), 'm/s')}, "
        f"{_value((summary['limits'] or {}).get('max_accel_mps2'), 'm/s²')}",
        f"- Rail: {_value(rail.get('name'))}, {_value(rail.get('length_m'), 'm')}, "
        f"SHA-256 {_value(rail.get('sha256'))}",
        f"- Base station clock synchronised at start / end: "
        f"{_value((collected.get('clock_at_start') or {}).get('synchronized'))} / "
        f"{_value((collected.get('clock_at_end') or {}).get('synchronized'))}",
        f"- Radio link over the run: {_value(link.get('loss_pct'), '%')} of "
        f"{_value(link.get('exchanges'))} exchanges lost",
        f"- Portal: version {PORTAL_VERSION}",
        "",
        "Everything in full is in `datapackage.json` (`amazing.provenance`).",
        "",
    ]
    return "\n".join(lines)


class _Sink(io.RawIOBase):
    """Where the zip writes: hands its bytes on as they come. It can tell its position but
    not seek, so ``zipfile`` streams (sizes and CRCs after each file's data)."""

    def __init__(self) -> None:
        self._chunks: list[bytes] = []
        self._position = 0

    def writable(self) -> bool:
        return True

    def write(self, data: Any) -> int:
        chunk = bytes(data)
        self._chunks.append(chunk)
        self._position += len(chunk)
        return len(chunk)

    def tell(self) -> int:
        return self._position

    def take(self) -> bytes:
        taken = b"".join(self._chunks)
        self._chunks.clear()
        return taken


def _open_archive(sink: _Sink) -> zipfile.ZipFile:
    return zipfile.ZipFile(
        sink, mode="w", compression=zipfile.ZIP_DEFLATED, compresslevel=ZIP_LEVEL
    )


def _series_members(
    archive: zipfile.ZipFile, sink: _Sink, *, run: Run, folder: str, stamp: Any
) -> Generator[bytes, None, list[dict[str, Any]]]:
    """Each measurement series of the run as its CSV in ``archive``; their resources."""
    resources = []
    track = None
    for series in run.measurements.order_by("name"):
        track = track if track is not None else run_track(run)
        data = series_csv(series, track)
        archive.writestr(
            zipfile.ZipInfo(folder + series_file(series), date_time=stamp),
            data,
            compress_type=zipfile.ZIP_DEFLATED,
        )
        yield sink.take()
        resources.append(
            series_resource(
                series, csv_bytes=len(data), csv_sha256=hashlib.sha256(data).hexdigest()
            )
        )
    return resources


def _package_members(
    archive: zipfile.ZipFile,
    sink: _Sink,
    *,
    run: Run,
    url: str | None,
    now: datetime,
    folder: str = "",
) -> Generator[bytes, None, dict[str, Any]]:
    """Write one run's package into ``archive`` under ``folder`` (``""`` or ending in
    ``/``), handing on the zip's bytes as they come; returns the descriptor written."""
    run = (
        Run.objects.select_related("resource", "reservation__owner", "experiment")
        .prefetch_related("events", "reservation__items__resource")
        .get(pk=run.pk)
    )
    metadata = run_metadata(run, url=url, now=now)
    stamp = now.astimezone(UTC).timetuple()[:6]
    archive.writestr(
        zipfile.ZipInfo(folder + README_FILE, date_time=stamp),
        package_readme(run, metadata),
        compress_type=zipfile.ZIP_DEFLATED,
    )
    yield sink.take()
    digest = hashlib.sha256()
    size = 0
    info = zipfile.ZipInfo(folder + SAMPLES_FILE, date_time=stamp)
    info.compress_type = zipfile.ZIP_DEFLATED
    with archive.open(info, mode="w", force_zip64=True) as entry:
        for chunk in run_samples_csv(run=run):
            digest.update(chunk)
            size += len(chunk)
            entry.write(chunk)
            taken = sink.take()
            if taken:
                yield taken
    resources = yield from _series_members(archive, sink, run=run, folder=folder, stamp=stamp)
    descriptor = package_descriptor(
        run,
        metadata=metadata,
        csv_bytes=size,
        csv_sha256=digest.hexdigest(),
        series=resources,
    )
    archive.writestr(
        zipfile.ZipInfo(folder + DESCRIPTOR_FILE, date_time=stamp),
        json.dumps(descriptor, indent=2, ensure_ascii=False) + "\n",
        compress_type=zipfile.ZIP_DEFLATED,
    )
    yield sink.take()
    return descriptor


def run_package_zip(*, run: Run, url: str | None = None) -> Iterator[bytes]:
    """The package as zip bytes, streamed: README, then the CSV as the database writes it,
    then the descriptor with the CSV's size and hash."""
    sink = _Sink()
    archive = _open_archive(sink)
    yield from _package_members(archive, sink, run=run, url=url, now=timezone.now())
    archive.close()
    yield sink.take()


def run_folder(run: Run) -> str:
    """Where a run's package sits inside a download of several runs."""
    return f"run-{run.pk}/"


def _manifest_entry(
    run: Run, folder: str, url: str | None, descriptor: dict[str, Any]
) -> dict[str, Any]:
    """A run's line in ``manifest.json``: its folder, files, and its CSV's size and hash."""
    samples = descriptor["resources"][0]
    info = descriptor["amazing"]["run"]
    return {
        "folder": folder,
        "run": run.pk,
        "url": url,
        "title": info["title"],
        "resource": info["resource"],
        "state": info["state"],
        "start_at": info["start_at"],
        "end_at": info["end_at"],
        "samples": info["samples"],
        "files": [
            folder + name
            for name in (
                README_FILE,
                SAMPLES_FILE,
                *(r["path"] for r in descriptor["resources"][1:]),
                DESCRIPTOR_FILE,
            )
        ],
        "samples_bytes": samples["bytes"],
        "samples_hash": samples["hash"],
    }


def runs_package_zip(
    *,
    runs: Sequence[Run],
    urls: Mapping[int, str] | None = None,
    extra: Mapping[str, dict[str, Any]] | None = None,
) -> Iterator[bytes]:
    """Several runs as one zip, streamed: each run's package in a folder of its own
    (:func:`run_folder`), then ``manifest.json`` listing every folder with the run it holds
    and its CSV's size and hash (known only once the CSVs are written, so it goes last), then
    each of ``extra``'s documents as JSON under its name (a campaign's ``campaign.json``)."""
    now = timezone.now()
    sink = _Sink()
    archive = _open_archive(sink)
    entries = []
    for run in runs:
        folder = run_folder(run)
        url = (urls or {}).get(run.pk)
        descriptor = yield from _package_members(
            archive, sink, run=run, url=url, now=now, folder=folder
        )
        entries.append(_manifest_entry(run, folder, url, descriptor))
    manifest = {
        "format": MANIFEST_FORMAT,
        "format_version": FORMAT_VERSION,
        "generated_at": _iso(now),
        "generated_by": {"portal_version": PORTAL_VERSION},
        "runs": entries,
    }
    for name, document in {MANIFEST_FILE: manifest, **(extra or {})}.items():
        archive.writestr(
            zipfile.ZipInfo(name, date_time=now.astimezone(UTC).timetuple()[:6]),
            json.dumps(document, indent=2, ensure_ascii=False) + "\n",
            compress_type=zipfile.ZIP_DEFLATED,
        )
    archive.close()
    yield sink.take()
