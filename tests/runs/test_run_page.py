"""The run page and its API: a one-hour run's charts, segment statistics, laps and passes."""

from __future__ import annotations

import json
import re
from datetime import timedelta

import pytest

from portal.runs.models import Run
from portal.runs.selectors import run_report, run_report_json
from portal.runs.states import RunState
from tests.factories import UserFactory
from tests.runs.driving import RAIL_M, completed_run, ingest

pytestmark = pytest.mark.django_db

# An hour at 20 Hz on a 100 m rail from 10 m: 1200 m clockwise, 2400 m back, 600 m on.
HOUR = [(1.0, "cw", 1200.0), (2.0, "ccw", 1200.0), (0.5, "cw", 1200.0)]


@pytest.fixture
def hour_run(owner, mobile):
    return completed_run(owner, mobile, HOUR)


def test_a_one_hour_run_reaches_the_page_downsampled(hour_run, client):
    client.force_login(hour_run.reservation.owner)
    data = client.get(f"/runs/{hour_run.pk}/data.json").json()
    assert data["sample_count"] == 72_000
    for name in ("measured_mps", "battery_v", "track_m"):
        assert len(data["series"][name]["t"]) == len(data["series"][name]["y"]) == 2000
    # The command is a step function: its three steps and the end, exactly.
    assert data["series"]["commanded_mps"]["y"] == [1.0, -2.0, 0.5, 0.5]
    html = data["analysis_html"]
    # 4200 m of path on a 100 m rail: 41 whole laps; net progress -600 m: -6 laps.
    assert len(re.findall(r"<tr><td>\d+</td><td>\d\d:\d\d:\d\d", html)) == 41
    assert 'id="net-laps">-6<' in html


def test_the_page_shows_segments_laps_and_passes_at_a_chosen_position(hour_run, client):
    client.force_login(hour_run.reservation.owner)
    page = client.get(f"/runs/{hour_run.pk}/", {"at_m": "50"}).content.decode()
    table = page[page.index('id="segment-stats"') : page.index("</table>")]
    assert table.count("<tr>") == 4  # the header and three segments
    passes = page[page.index('id="passes"') : page.index("</table>", page.index('id="passes"'))]
    # Out 10 → 1210 m passes 50 m + k·100 m twelve times, back to -1190 m 24 times, then
    # on to -590 m six times.
    assert passes.count("<td>cw</td>") == 18
    assert passes.count("<td>ccw</td>") == 24
    assert "At 50.0 m along the rail" in page
    # The live poll carries the chosen position, so the tables it redraws keep the passes.
    assert f"/runs/{hour_run.pk}/data.json?at_m=50" in page


@pytest.mark.parametrize(
    ("value", "message"),
    [("150", "from 0 up to 100 m"), ("-1", "greater than or equal to 0"), ("abc", "number")],
)
def test_a_position_off_the_rail_is_explained_next_to_the_field(hour_run, client, value, message):
    client.force_login(hour_run.reservation.owner)
    response = client.get(f"/runs/{hour_run.pk}/", {"at_m": value})
    assert response.status_code == 200
    page = response.content.decode()
    assert 'id="pass-error"' in page
    assert message in page
    assert 'id="passes"' not in page  # everything else is still shown
    assert 'id="segment-stats"' in page


def test_the_api_gives_the_analysis_as_json(hour_run, client):
    client.force_login(hour_run.reservation.owner)
    body = client.get(f"/api/v1/runs/{hour_run.pk}/analysis/", {"pass_at_m": 50}).json()
    assert body["samples"] == 72_000
    assert body["missing"] == 0
    assert body["net_laps"] == -6
    assert len(body["laps"]) == 41
    assert [s["commanded_mps"] for s in body["segments"]] == [1.0, -2.0, 0.5]
    assert body["segments"][1]["mean_mps"] == pytest.approx(-2.0)
    assert [p["direction"] for p in body["passes"]].count("ccw") == 24
    first = body["passes"][0]
    assert first["t_s"] == pytest.approx(40.0)  # 10 → 50 m at 1 m/s
    assert first["at"].startswith((hour_run.start_at + timedelta(seconds=40)).isoformat()[:19])
    refused = client.get(f"/api/v1/runs/{hour_run.pk}/analysis/", {"pass_at_m": 100})
    assert refused.status_code == 400
    assert "from 0 up to 100 m" in refused.json()["fields"]["pass_at_m"][0]


def test_without_a_rail_length_laps_and_passes_are_explained_not_guessed(owner, mobile, client):
    run = completed_run(owner, mobile, [(1.0, "cw", 30.0)], rail_length_m=None)
    client.force_login(owner)
    page = client.get(f"/runs/{run.pk}/", {"at_m": "5"}).content.decode()
    assert "did not report its rail length" in page
    assert "Passes need the rail length" in page
    assert 'id="segment-stats"' in page


def test_missing_samples_are_shown(owner, mobile, client):
    run = completed_run(owner, mobile, [(1.0, "cw", 1.0)])
    run.samples.filter(seq__in=[3, 4, 9]).delete()
    client.force_login(owner)
    page = client.get(f"/runs/{run.pk}/").content.decode()
    assert "3 missing" in page
    assert "3–4, 9" in page


def test_a_live_run_is_reanalysed_when_samples_arrive_even_below_its_last_seq(
    owner, mobile, client
):
    run = completed_run(owner, mobile, [(1.0, "cw", 10.0)])
    Run.objects.filter(pk=run.pk).update(state=RunState.RUNNING)
    run.samples.filter(seq__in=[10, 11]).delete()  # a gap the next page fills
    client.force_login(owner)

    def analysis():
        return client.get(f"/api/v1/runs/{run.pk}/analysis/").json()

    assert (analysis()["samples"], analysis()["missing"]) == (198, 2)
    ingest(run, [(1.0, "cw", 10.0)])  # the same 200 again: only seq 10 and 11 are new
    assert (analysis()["samples"], analysis()["missing"]) == (200, 0)


def test_a_finished_runs_analysis_is_read_from_the_cache_as_computed_and_follows_the_run(
    owner, mobile, client, django_assert_num_queries
):
    run = completed_run(owner, mobile, [(1.0, "cw", 10.0)])
    client.force_login(owner)
    url = f"/api/v1/runs/{run.pk}/analysis/"
    first = client.get(url).json()
    fresh = run_report_json(run_report(run=run, cached=False))
    assert first == {"run": run.pk, "state": "completed", **fresh}
    # The kept answer: the session, its user and the run are read; no sample.
    with django_assert_num_queries(3):
        assert client.get(url).json() == first
    # A rail measured again (the run's own row changes): the answer is computed again.
    Run.objects.filter(pk=run.pk).update(rail_length_m=RAIL_M / 2)
    assert client.get(url).json()["rail_length_m"] == RAIL_M / 2


def test_the_whole_run_downloads_as_one_json_document(owner, mobile, client):
    run = completed_run(owner, mobile, [(1.0, "cw", 100.0)])  # 2000 samples: more than one chunk
    client.force_login(owner)
    for url in (f"/runs/{run.pk}/samples.json", f"/api/v1/runs/{run.pk}/samples.json"):
        response = client.get(url)
        assert (
            response["Content-Disposition"] == f'attachment; filename="amazing-run-{run.pk}.json"'
        )
        document = json.loads(b"".join(response.streaming_content))
        assert document["rail_length_m"] == RAIL_M
        assert document["segments"] == run.segments
        assert [s["seq"] for s in document["samples"]] == list(range(1, 2001))
        assert document["samples"][0]["t"].endswith("Z")


def test_an_empty_run_downloads_as_an_empty_list(owner, mobile, client):
    run = completed_run(owner, mobile, [(1.0, "cw", 1.0)])
    run.samples.all().delete()
    client.force_login(owner)
    document = json.loads(b"".join(client.get(f"/runs/{run.pk}/samples.json").streaming_content))
    assert document["samples"] == []


def test_someone_elses_run_is_not_found(hour_run, client):
    client.force_login(UserFactory(username="mallory"))
    for url in (
        f"/runs/{hour_run.pk}/",
        f"/runs/{hour_run.pk}/data.json",
        f"/runs/{hour_run.pk}/samples.json",
        f"/api/v1/runs/{hour_run.pk}/analysis/",
        f"/api/v1/runs/{hour_run.pk}/samples.json",
    ):
        assert client.get(url).status_code == 404, url
