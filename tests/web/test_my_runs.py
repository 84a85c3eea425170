"""The My runs pages for the owner, another experimenter, an admin and an anonymous visitor:
the list and its filters, several runs as one zip, and the comparison."""

from __future__ import annotations

import io
import json
import zipfile
from datetime import UTC, datetime, timedelta

import pytest

from portal.runs.measurements import measurement_add, rows_points
from tests.conftest import sign_in_with_second_factor
from tests.runs.driving import run_round_the_rail
from tests.runs.history import past_run

pytestmark = pytest.mark.django_db

START = datetime(2026, 3, 1, 9, 0, tzinfo=UTC)


@pytest.fixture
def runs(owner, mobile):
    return [
        past_run(owner, mobile, started_at=START, title="first lap"),
        past_run(owner, mobile, started_at=START + timedelta(days=1), title="second lap"),
    ]


def _listed(response) -> list[int]:
    html = response.content.decode()
    return [int(part.split('"')[0]) for part in html.split('<tr data-run="')[1:]]


def test_anonymous_visitors_are_sent_to_log_in(client, runs):
    for path in ("/runs/", "/runs/package.zip?ids=1", "/runs/compare/?ids=1,2"):
        response = client.get(path)
        assert response.status_code == 302
        assert response["Location"].startswith("/accounts/login/")


def test_the_owner_an_other_and_an_admin_each_see_whose_runs_they_may(
    client, runs, other, admin_user
):
    client.force_login(runs[0].reservation.owner)
    assert _listed(client.get("/runs/")) == [runs[1].pk, runs[0].pk]
    client.force_login(other)
    response = client.get("/runs/")
    assert _listed(response) == []
    assert "No runs yet." in response.content.decode()
    # An admin sees everyone's runs only in a session that passed its second factor.
    client.force_login(admin_user)
    assert _listed(client.get("/runs/")) == []
    sign_in_with_second_factor(client, admin_user)
    assert _listed(client.get("/runs/")) == [runs[1].pk, runs[0].pk]


def test_filters_narrow_the_list_and_a_bad_one_says_why_and_shows_nothing(client, runs):
    client.force_login(runs[0].reservation.owner)
    assert _listed(client.get("/runs/?q=second")) == [runs[1].pk]
    assert _listed(client.get("/runs/?started_to=2026-03-01")) == [runs[0].pk]
    response = client.get("/runs/?started_from=2026-03-05&started_to=2026-03-01")
    assert response.status_code == 200
    assert "The last day comes on or after the first." in response.content.decode()
    assert _listed(response) == []
    response = client.get("/runs/?state=exploded")
    assert "Select a valid choice" in response.content.decode()
    assert _listed(response) == []


def test_the_chosen_runs_download_as_one_zip(client, runs):
    client.force_login(runs[0].reservation.owner)
    response = client.get(f"/runs/package.zip?ids={runs[0].pk}&ids={runs[1].pk}")
    assert response.status_code == 200
    assert response["Content-Type"] == "application/zip"
    assert f"amazing-runs-{runs[0].pk}-{runs[1].pk}.zip" in response["Content-Disposition"]
    archive = zipfile.ZipFile(io.BytesIO(b"".join(response.streaming_content)))
    manifest = json.loads(archive.read("manifest.json"))
    assert [entry["run"] for entry in manifest["runs"]] == [runs[0].pk, runs[1].pk]
    assert manifest["runs"][0]["url"] == f"http://testserver/runs/{runs[0].pk}/"


@pytest.mark.parametrize(
    ("query", "message"),
    [
        ("", "Nothing downloaded: Choose at least 1 run."),
        ("?ids=abc", "Nothing downloaded: “abc” is not a run number."),
    ],
)
def test_a_download_of_nothing_or_of_nonsense_goes_back_to_the_list_saying_why(
    client, runs, query, message
):
    client.force_login(runs[0].reservation.owner)
    response = client.get(f"/runs/package.zip{query}", follow=True)
    assert response.redirect_chain == [("/runs/", 302)]
    assert message in response.content.decode()


def test_another_experimenters_runs_are_neither_downloaded_nor_compared(client, runs, other):
    client.force_login(other)
    ids = f"{runs[0].pk},{runs[1].pk}"
    for path in (f"/runs/package.zip?ids={ids}", f"/runs/compare/?ids={ids}"):
        response = client.get(path, follow=True)
        assert response.redirect_chain == [("/runs/", 302)]
        assert f"No run {runs[0].pk}, {runs[1].pk} among your runs." in response.content.decode()


def test_the_comparison_shows_both_runs_curves_and_statistics(client, runs, admin_user):
    for user in (runs[0].reservation.owner, admin_user):
        if user is admin_user:
            sign_in_with_second_factor(client, user)
        else:
            client.force_login(user)
        response = client.get(f"/runs/compare/?ids={runs[0].pk},{runs[1].pk}")
        assert response.status_code == 200
        html = response.content.decode()
        assert html.count('<th scope="col" data-run=') == 2
        assert html.count('data-metric="mean"') == 2  # two segments
        series = json.loads(
            html.split('id="compare-series" type="application/json">')[1].split("</script>")[0]
        )
        assert [s["run"] for s in series] == [runs[0].pk, runs[1].pk]
    response = client.get(f"/runs/compare/?ids={runs[0].pk}", follow=True)
    assert "Nothing to compare: Choose at least 2 runs." in response.content.decode()


def test_the_comparison_overlays_a_measurement_series_by_position(client, owner):
    runs = [run_round_the_rail(owner, seconds=5.0, hours_ahead=h) for h in (1.0, 2.0)]
    for run, offset_db in ((runs[0], 0.0), (runs[1], -10.0)):
        t0_s = run.start_at.timestamp()
        rows = [{"t": t0_s + 0.5 * i, "rssi": -50.0 + offset_db} for i in range(1, 8)]
        measurement_add(run=run, by=owner, name="rssi", unit="dBm", points=rows_points(rows))
    t0_s = runs[0].start_at.timestamp()
    measurement_add(
        run=runs[0], by=owner, name="snr", points=rows_points([{"t": t0_s, "snr": 20.0}])
    )
    client.force_login(owner)
    html = client.get(f"/runs/compare/?ids={runs[0].pk},{runs[1].pk}").content.decode()
    assert 'id="compare-measurements-heading"' in html
    measured = json.loads(
        html.split('id="compare-measurements-data" type="application/json">')[1].split("</script>")[
            0
        ]
    )
    assert [(m["name"], m["unit"]) for m in measured] == [("rssi", "dBm"), ("snr", "")]
    rssi = measured[0]["runs"]
    assert [r["stats"]["mean"] for r in rssi] == [-50.0, -60.0]
    for one in rssi:
        assert one["by_metre"]
        assert {mean for _, mean in one["by_metre"]} == {one["stats"]["mean"]}
    # The second run has no snr: drawn as nothing, "—" in its table.
    assert measured[1]["runs"][1] is None
    snr_table = html.split('data-series="snr"')[1].split("</table>")[0]
    assert snr_table.count("<td>—</td>") == 4
