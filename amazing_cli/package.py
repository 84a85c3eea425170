"""Reading a run package (the zip of ``amazing download --format zip``), every format version.

The portal writes a Frictionless Data Package in a zip (docs/run-package.md): ``samples.csv``,
``datapackage.json`` with the run's metadata under ``amazing`` (its ``format_version``) and a
``README.md``. :func:`read_package` checks one the way a reader months later would: it knows
the format's version, the CSV has the columns its schema names and as many rows as the
metadata says. A package of a version this command does not know is refused with a clear
message, never half-read. ``tests/data`` keeps an example of each version, read by the tests.
"""

from __future__ import annotations

import csv
import io
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from amazing_cli.errors import BAD_INPUT, CliError, bad_input

FORMAT: Final = "amazing-run-package"
# The versions this command reads; what changed in each is in docs/run-package.md.
KNOWN_VERSIONS: Final = frozenset({1})
DESCRIPTOR: Final = "datapackage.json"


@dataclass(frozen=True)
class PackageSummary:
    format_version: int
    run: int
    title: str
    columns: tuple[str, ...]
    rows: int
    metadata: dict[str, Any]


def _samples_resource(descriptor: dict[str, Any]) -> dict[str, Any]:
    for resource in descriptor.get("resources") or []:
        if isinstance(resource, dict) and resource.get("name") == "samples":
            return resource
    raise bad_input("the package names no samples resource")


def read_package(path: Path) -> PackageSummary:
    """The package at ``path``, checked: its version, its columns, its row count."""
    try:
        with zipfile.ZipFile(path) as archive:
            descriptor = json.loads(archive.read(DESCRIPTOR))
            if not isinstance(descriptor, dict):
                raise bad_input(f"{path}: {DESCRIPTOR} is not a JSON object")
            metadata = descriptor.get("amazing")
            if not isinstance(metadata, dict) or metadata.get("format") != FORMAT:
                raise bad_input(f"{path}: not an AMazING run package")
            version = metadata.get("format_version")
            if version not in KNOWN_VERSIONS:
                raise CliError(
                    f"{path}: package format version {version!r}; this amazing command reads "
                    f"{', '.join(map(str, sorted(KNOWN_VERSIONS)))}: update it",
                    exit_code=BAD_INPUT,
                )
            resource = _samples_resource(descriptor)
            columns = tuple(field["name"] for field in resource["schema"]["fields"])
            with archive.open(resource["path"]) as raw:
                reader = csv.reader(io.TextIOWrapper(raw, encoding="utf-8", newline=""))
                header = tuple(next(reader, ()))
                rows = sum(1 for _ in reader)
    except (OSError, zipfile.BadZipFile, KeyError, ValueError, TypeError) as exc:
        raise bad_input(f"{path}: not a readable run package ({exc})") from exc
    if header != columns:
        raise bad_input(f"{path}: the CSV's columns {header} differ from its schema {columns}")
    run = metadata["run"]
    return PackageSummary(
        format_version=int(version),
        run=int(run["id"]),
        title=str(run["title"]),
        columns=columns,
        rows=rows,
        metadata=metadata,
    )
