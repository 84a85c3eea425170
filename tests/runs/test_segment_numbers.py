"""Segments are numbered from 0 in every output (``bookings.rules.FIRST_SEGMENT``): the CSV,
the JSON samples and analysis, the package, the run page, the comparison, the experiment's
form and the messages about a segment. A researcher quoting "segment 1" from the page finds
the same rows in the file."""

from __future__ import annotations

import csv
import io
import json
import re
import zipfile

import pytest

from bookings.rules import FIRST_SEGMENT
from portal.experiments.services import experiment_create
from tests.runs.driving import completed_run

pytestmark = pytest.mark.django_db

PROGRAM = [(0.5, "cw", 2.0), (0.0, "cw", 1.0), (0.8, "ccw", 2.0)]
NUMBERS = list(range(FIRST_SEGMENT, FIRST_SEGMENT + len(PROGRAM)))


def _body(response) -> bytes:
    assert response.status_code == 200, response
    return b"".join(response.streaming_content) if response.streaming else response.content


def _first_cells(html: str, table_id: str) -> list[str]:
    table = html.split(f'id="{table_id}"', 1)[1].split("</table>", 1)[0]
    body = table.split("<tbody>", 1)[1]
    return [re.search(r"<td>(.*?)</td>", row).group(1) for row in body.split("<tr")[1:]]


@pytest.fixture
def run(owner, mobile):
    return completed_run(owner, mobile, PROGRAM)


def test_the_files_the_api_and_the_page_number_segments_alike(run, client):
    client.force_login(run.reservation.owner)
    base = f"/api/v1/runs/{run.pk}"

    rows = list(csv.DictReader(io.StringIO(_body(client.get(f"{base}/samples.csv")).decode())))
    assert sorted({int(row["segment"]) for row in rows}) == NUMBERS

    samples = json.loads(_body(client.get(f"{base}/samples.json")))["samples"]
    assert sorted({s["segment"] for s in samples}) == NUMBERS

    analysis = json.loads(_body(client.get(f"{base}/analysis/")))
    assert [s["index"] for s in analysis["segments"]] == NUMBERS

    with zipfile.ZipFile(io.BytesIO(_body(client.get(f"{base}/package.zip")))) as package:
        names = package.namelist()
        csv_name = next(n for n in names if n.endswith("samples.csv"))
        in_package = csv.DictReader(io.StringIO(package.read(csv_name).decode()))
        assert sorted({int(row["segment"]) for row in in_package}) == NUMBERS
        descriptor_name = next(n for n in names if n.endswith("datapackage.json"))
        descriptor = json.loads(package.read(descriptor_name))
        packaged = descriptor["amazing"]["analysis"]["segments"]
        assert [s["index"] for s in packaged] == NUMBERS

    page = client.get(f"/runs/{run.pk}/").content.decode()
    assert _first_cells(page, "segment-stats") == [str(n) for n in NUMBERS]


def test_the_experiment_form_and_its_messages_number_segments_alike(owner, mobile, client):
    experiment = experiment_create(
        owner=owner,
        title="three",
        segments=[{"velocity_mps": v, "direction": d, "duration_s": s} for v, d, s in PROGRAM],
    )
    client.force_login(owner)
    form = client.get(f"/experiments/{experiment.pk}/").content.decode()
    assert re.findall(r'<td class="index">(\d+)</td>', form) == [str(n) for n in NUMBERS]

    answer = client.post(
        "/api/v1/experiments/",
        {
            "title": "bad second",
            "segments": [
                {"velocity_mps": 0.5, "direction": "cw", "duration_s": 1},
                {"velocity_mps": 9, "direction": "cw", "duration_s": 1},
            ],
        },
        content_type="application/json",
    )
    assert answer.status_code == 400
    assert f"Segment {FIRST_SEGMENT + 1}: velocity 9 m/s is faster" in json.dumps(answer.json())
