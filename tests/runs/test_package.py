"""The run package: a zip holding a Frictionless Data Package of the run, checked by
Frictionless's own validator, its README against the contract, every format version kept
readable (tests/data)."""

from __future__ import annotations

import io
import json
import re
import zipfile
from pathlib import Path
from typing import Any

import pytest
from django.http import StreamingHttpResponse
from frictionless import validate

from amazing_cli.package import KNOWN_VERSIONS, read_package
from basestation.contract import SAMPLE_COLUMNS, SAMPLE_FIELDS
from portal.runs.models import Run
from portal.runs.package import FORMAT_VERSION, column_rows
from tests.runs.driving import completed_run

pytestmark = pytest.mark.django_db

DATA = Path(__file__).resolve().parents[1] / "data"
PROGRAM = [(0.5, "cw", 2.0), (0.25, "ccw", 1.0)]


def _zip(response: StreamingHttpResponse) -> zipfile.ZipFile:
    assert response.status_code == 200, response
    assert response.streaming
    assert response["Content-Type"] == "application/zip"
    return zipfile.ZipFile(io.BytesIO(b"".join(response.streaming_content)))  # type: ignore[arg-type]


def _package(client: Any, run: Run) -> zipfile.ZipFile:
    return _zip(client.get(f"/api/v1/runs/{run.pk}/package.zip"))


def _readme_columns(readme: str) -> list[tuple[str, ...]]:
    section = readme.split("## Columns of samples.csv", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if line.startswith("| ")]
    return [tuple(cell.strip() for cell in re.split(r"(?<!\\)\|", row)[1:-1]) for row in rows[2:]]


def test_the_package_holds_the_csv_download_its_metadata_and_a_readme(api, owner, mobile):
    run = completed_run(owner, mobile, PROGRAM)
    Run.objects.filter(pk=run.pk).update(
        provenance={
            "format_version": 1,
            "staged": {
                "at": "2026-11-25T10:00:00+00:00",
                "portal_version": "0.1.0",
                "limits": {"max_velocity_mps": 1.5, "max_accel_mps2": 0.5},
                "agent": None,
                "firmware": {"build_id": "bench-7", "protocol_version": 1, "config": {}},
            },
        }
    )
    package = _package(api, run)
    assert package.namelist() == ["README.md", "samples.csv", "datapackage.json"]
    csv_download = b"".join(api.get(f"/api/v1/runs/{run.pk}/samples.csv").streaming_content)
    assert package.read("samples.csv") == csv_download

    descriptor = json.loads(package.read("datapackage.json"))
    metadata = descriptor["amazing"]
    assert metadata["format"] == "amazing-run-package"
    assert metadata["format_version"] == FORMAT_VERSION == max(KNOWN_VERSIONS)
    assert metadata["run"]["id"] == run.pk
    assert metadata["run"]["samples"] == 60
    assert metadata["run"]["url"] == f"http://testserver/runs/{run.pk}/"
    assert metadata["experiment"]["segments"] == run.segments
    assert metadata["reservation"]["resources"] == [mobile.name]
    assert metadata["owner"] == {"username": "alice"}
    assert metadata["provenance"]["staged"]["firmware"]["build_id"] == "bench-7"
    assert [s["index"] for s in metadata["analysis"]["segments"]] == [0, 1]
    resource = descriptor["resources"][0]
    assert resource["bytes"] == len(csv_download)
    assert [f["name"] for f in resource["schema"]["fields"]] == list(SAMPLE_FIELDS)

    readme = package.read("README.md").decode()
    assert "build bench-7" in readme
    assert "limits sent: 1.5 m/s, 0.5 m/s²".lower() in readme.lower()


def test_the_package_is_valid_by_frictionless_and_its_readme_is_the_contract(
    api, owner, mobile, tmp_path
):
    run = completed_run(owner, mobile, PROGRAM)
    _package(api, run).extractall(tmp_path)
    report = validate(tmp_path / "datapackage.json")
    assert report.valid, report.flatten(["rowNumber", "fieldName", "type", "note"])
    # Frictionless checks the CSV against the schema and the declared size and hash: a
    # changed byte fails it.
    csv_path = tmp_path / "samples.csv"
    csv_path.write_bytes(csv_path.read_bytes().replace(b",cw,", b",cx,", 1))
    assert not validate(tmp_path / "datapackage.json").valid

    readme = (tmp_path / "README.md").read_text()
    expected = [
        (
            c.name,
            {"int": "integer", "float": "number", "text": "string", "epoch": "datetime"}[c.kind],
            c.unit or "–",
            c.doc + (" (empty: null)" if c.nullable else ""),
        )
        for c in SAMPLE_COLUMNS
    ]
    assert _readme_columns(readme) == expected == column_rows()
    # Units follow the columns' names: the contract cannot say m/s of a column in volts.
    suffix_unit = {"_mps": "m/s", "_v": "V", "_m": "m", "_deg": "°"}
    for column in SAMPLE_COLUMNS:
        for suffix, unit in suffix_unit.items():
            if column.name.endswith(suffix):
                assert column.unit == unit, column.name
        assert column.doc, column.name


@pytest.mark.parametrize("version", sorted(KNOWN_VERSIONS))
def test_every_package_format_version_stays_readable(version, tmp_path):
    """tests/data keeps a package of each version the readers know; a new version adds one."""
    example = DATA / f"run-package-v{version}.zip"
    summary = read_package(example)
    assert summary.format_version == version
    assert summary.rows == summary.metadata["run"]["samples"] > 0
    assert set(summary.columns) <= set(SAMPLE_FIELDS) | {"t"}
    with zipfile.ZipFile(example) as package:
        package.extractall(tmp_path)
    report = validate(tmp_path / "datapackage.json")
    assert report.valid, report.flatten(["rowNumber", "fieldName", "type", "note"])


def test_a_package_of_a_newer_format_is_refused_by_name(tmp_path):
    with zipfile.ZipFile(DATA / "run-package-v1.zip") as old:
        files = {name: old.read(name) for name in old.namelist()}
    descriptor = json.loads(files["datapackage.json"])
    descriptor["amazing"]["format_version"] = max(KNOWN_VERSIONS) + 1
    files["datapackage.json"] = json.dumps(descriptor).encode()
    newer = tmp_path / "newer.zip"
    with zipfile.ZipFile(newer, "w") as package:
        for name, data in files.items():
            package.writestr(name, data)
    from amazing_cli.errors import CliError

    with pytest.raises(CliError) as caught:
        read_package(newer)
    assert f"package format version {max(KNOWN_VERSIONS) + 1}" in caught.value.message


def test_only_who_may_see_the_run_gets_its_package(client_for, owner, other, admin_user, mobile):
    run = completed_run(owner, mobile, PROGRAM)
    url = f"/api/v1/runs/{run.pk}/package.zip"
    assert client_for(other).get(url).status_code == 404
    assert client_for(None).get(url).status_code in (401, 403)
    assert _zip(client_for(admin_user).get(url)).namelist()[1] == "samples.csv"
