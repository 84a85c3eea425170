"""The robot console's daily log download: the base station's log of a day as CSV, for
admins only, a bad day refused."""

from __future__ import annotations

import csv
import io
from datetime import UTC, datetime

import pytest
import time_machine

from basestation.api.logs import LOG_CSV_COLUMNS
from portal.web.console import DAY_LOG_COLUMNS
from tests.conftest import sign_in_with_second_factor
from tests.runs.conftest import agent  # noqa: F401  (the in-process agent fixture)

pytestmark = pytest.mark.django_db


def test_the_portal_writes_the_agents_columns():
    assert DAY_LOG_COLUMNS == LOG_CSV_COLUMNS


def test_an_admin_downloads_a_days_log(client, agent, mobile, admin_user):  # noqa: F811
    mobile.agent_url = agent.url
    mobile.save()

    def agent_day() -> str:
        return datetime.fromtimestamp(agent.client.status()["clock"], UTC).date().isoformat()

    day_before = agent_day()
    agent.client.control(user="charlie", velocity_mps=0.2, direction="cw", ttl_s=1)
    sign_in_with_second_factor(client, admin_user)
    # The log is by the agent's date: if its midnight passed meanwhile, the entry is in either.
    users = []
    for day in sorted({day_before, agent_day()}):
        response = client.get(f"/robot/{mobile.name}/log.csv?day={day}")
        assert response.status_code == 200
        assert f'filename="{mobile.name}-log-{day}.csv"' in response["Content-Disposition"]
        rows = list(csv.reader(io.StringIO(response.content.decode())))
        assert rows[0] == list(DAY_LOG_COLUMNS)
        users += [row[0] for row in rows[1:]]
    assert users == ["charlie"]


@pytest.mark.parametrize("day", ["", "2026-02-30", "yesterday", "2026-1-1"])
def test_a_bad_day_is_refused(client, mobile, admin_user, day):
    sign_in_with_second_factor(client, admin_user)
    assert client.get(f"/robot/{mobile.name}/log.csv?day={day}").status_code == 400


def test_experimenters_and_visitors_get_no_log(client, mobile, owner):
    assert client.get(f"/robot/{mobile.name}/log.csv?day=2026-01-01").status_code == 302
    client.force_login(owner)
    assert client.get(f"/robot/{mobile.name}/log.csv?day=2026-01-01").status_code == 403


@pytest.mark.parametrize(
    ("utc_now", "day"),
    [
        # 00:30 in Lisbon (summer time): the base station's day is still the 14th.
        (datetime(2027, 7, 14, 23, 30, tzinfo=UTC), "2027-07-14"),
        # The same hour in winter, when Lisbon keeps UTC: both the 15th.
        (datetime(2027, 1, 15, 0, 30, tzinfo=UTC), "2027-01-15"),
    ],
)
def test_the_console_opens_the_log_on_the_base_stations_day(
    client, mobile, admin_user, utc_now, day
):
    with time_machine.travel(utc_now, tick=False):
        sign_in_with_second_factor(client, admin_user)
        page = client.get(f"/robot/{mobile.name}/").content.decode()
    assert f'<input type="date" name="day" value="{day}"' in page
