"""No CSV of the portal or the agent hands a spreadsheet a formula (CSV injection).

Every CSV is written by ``basestation.contract.CsvWriter``; a text cell that starts with
``=``, ``+``, ``-``, ``@``, a tab or a carriage return gets a leading apostrophe, numbers stay
numbers. The CSVs, from the code:

- the agent's day log, ``GET /api/v1/logs/<day>`` (``Accept: text/csv``): user and title;
- the portal's copy of it, ``/robot/<name>/log.csv`` (robot console): the same columns;
- the usage report, ``/usage/?format=csv``: user, group and resource names;
- a run's samples: ``/runs/<pk>/samples.csv``, ``/api/v1/runs/<pk>/samples.csv`` and the run
  package's ``samples.csv`` (one function: PostgreSQL's ``COPY … CSV``, its text columns
  escaped in SQL), and the agent's samples page (the writer): ``grid_id`` is text the agent
  sends, the rest numbers, instants and a direction from a closed set.
"""

from __future__ import annotations

import csv
import io
import time
from datetime import UTC, datetime, timedelta
from typing import cast

import pytest
import requests
from django.contrib.auth.models import Group
from django.utils import timezone

from basestation.contract import CsvWriter, csv_cell
from bookings.models import Resource
from bookings.services import reservations as without_run
from core.accounts.models import User
from portal.runs.services.collection import samples_ingest
from portal.runs.services.reservations import reservation_create
from tests.basestation.conftest import run_body
from tests.conftest import sign_in_with_second_factor
from tests.factories import FixedResourceFactory, UserFactory
from tests.runs.conftest import TOKEN, agent  # noqa: F401  (the in-process agent fixture)

pytestmark = pytest.mark.django_db

FORMULAS = ('=HYPERLINK("http://x","y")', "+1", "@SUM(A1)", "\t=1", "-2+3", "\r=1")


def _rows(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text)))


def _written(row: list[object]) -> str:
    buffer = io.StringIO()
    CsvWriter(buffer).writerow(row)
    return buffer.getvalue()


@pytest.mark.parametrize("text", FORMULAS)
def test_a_text_cell_that_starts_a_formula_is_written_as_text(text):
    assert _rows(_written([text]))[0] == ["'" + text]


def test_numbers_and_plain_text_are_written_as_they_are():
    assert _written([-0.5, 3, 0.0, None, "sweep", "cw", "2026-01-01T00:00:00Z"]) == (
        "-0.5,3,0.0,,sweep,cw,2026-01-01T00:00:00Z\r\n"
    )
    assert csv_cell(-1) == -1


SHORT_FORMULAS = ("=1+1", "+1", "@SUM(A1)", "\t=1", "-2+3", "\r=1")  # grid_id holds 8


@pytest.fixture
def run_with_formulas(owner, mobile, experiment):
    """A run whose agent sent a formula in its one free-text sample column (``grid_id``)."""
    start = timezone.now() + timedelta(hours=1)
    reservation = reservation_create(
        owner=owner,
        resource=mobile,
        start_at=start,
        end_at=start + timedelta(minutes=5),
        experiment=experiment,
    )
    t0 = time.time()
    samples = [
        {"seq": i + 1, "t": t0 + i, "segment": 0, "commanded_velocity_mps": 0.5,
         "velocity_mps": 0.25, "direction": "cw", "battery_v": 60.0, "track_m": 1.0,
         "fix_quality": 4, "lat_deg": 40.6, "lon_deg": -8.6, "grid_id": text, "lap": -1}
        for i, text in enumerate(SHORT_FORMULAS)
    ]  # fmt: skip
    samples_ingest(run=reservation.run, samples=samples)
    return reservation.run


@pytest.mark.parametrize("path", ["/runs/{pk}/samples.csv", "/api/v1/runs/{pk}/samples.csv"])
def test_the_run_downloads_escape_text_samples_and_keep_numbers(client, run_with_formulas, path):
    client.force_login(run_with_formulas.reservation.owner)
    answer = client.get(path.format(pk=run_with_formulas.pk), HTTP_ACCEPT_ENCODING="identity")
    body = b"".join(answer.streaming_content).decode()
    rows = list(csv.DictReader(io.StringIO(body)))
    assert [row["grid_id"] for row in rows] == ["'" + text for text in SHORT_FORMULAS]
    assert {(row["lon_deg"], row["lap"]) for row in rows} == {("-8.6", "-1")}


@pytest.fixture
def day_log(agent, mobile):  # noqa: F811
    """The agent ran one run per formula, each owned by a formula too; returns the UTC day."""
    mobile.agent_url = agent.url
    mobile.save()
    start_s = time.time() + 2.0
    segments = [{"velocity_mps": 0.2, "direction": "cw", "duration_s": 0.3}]
    for index, text in enumerate(FORMULAS):
        body = run_body(
            start_s + index, window_s=0.8, segments=segments, owner=f"@{index}", title=text
        )
        answer = requests.put(
            f"{agent.url}/api/v1/runs/run-{index}",
            json=body,
            headers={"Authorization": f"Bearer {TOKEN}"},
            timeout=5,
        )
        assert answer.status_code in (200, 201), answer.text
    agent.run_clock(start_s - 0.1, start_s + len(FORMULAS) + 0.5)
    return datetime.fromtimestamp(start_s, UTC).date().isoformat()


def _titles_and_users(rows: list[list[str]]) -> tuple[list[str], list[str]]:
    header, *entries = rows
    title, user = header.index("title"), header.index("user")
    return [row[title] for row in entries], [row[user] for row in entries]


def test_the_agents_day_log_escapes_titles_and_users(agent, day_log):  # noqa: F811
    answer = requests.get(
        f"{agent.url}/api/v1/logs/{day_log}",
        headers={"Authorization": f"Bearer {TOKEN}", "Accept": "text/csv"},
        timeout=5,
    )
    assert answer.headers["Content-Type"].startswith("text/csv")
    titles, users = _titles_and_users(_rows(answer.text))
    assert titles == ["'" + text for text in FORMULAS]
    assert users == [f"'@{index}" for index in range(len(FORMULAS))]


def test_the_portals_day_log_escapes_titles_and_users(client, mobile, admin_user, day_log):
    sign_in_with_second_factor(client, admin_user)
    answer = client.get(f"/robot/{mobile.name}/log.csv?day={day_log}")
    assert answer.status_code == 200
    titles, users = _titles_and_users(_rows(answer.content.decode()))
    assert titles == ["'" + text for text in FORMULAS]
    assert users == [f"'@{index}" for index in range(len(FORMULAS))]


def test_the_usage_report_escapes_user_and_group_names(client, admin_user):
    day = timezone.localdate() + timedelta(days=2)
    start = timezone.make_aware(datetime.combine(day, datetime.min.time())) + timedelta(hours=1)
    for index, text in enumerate(FORMULAS):
        person = cast(User, UserFactory(username=text))
        person.groups.add(Group.objects.create(name=text))
        at = start + timedelta(hours=2 * index)
        without_run.reservation_create(
            owner=person,
            resource=cast(Resource, FixedResourceFactory()),
            start_at=at,
            end_at=at + timedelta(hours=1),
        )
    sign_in_with_second_factor(client, admin_user)
    params = {"from": day.isoformat(), "to": day.isoformat(), "format": "csv"}
    for by, expected in (
        ("user", {"'" + text for text in FORMULAS}),
        ("group", {"'" + text for text in FORMULAS}),
    ):
        answer = client.get("/usage/", {**params, "by": by})
        assert answer.status_code == 200
        rows = _rows(answer.content.decode())
        assert rows[0] == [by, "hours", "reservations"]
        assert {row[0] for row in rows[1:]} == expected
        assert {row[1] for row in rows[1:]} == {"1.0"}  # numbers stay numbers
