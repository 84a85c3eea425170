"""The list of runs: filters, search, choosing runs, comparing them and downloading several
as one zip of packages with a manifest."""

from __future__ import annotations

import io
import json
import zipfile
from datetime import date, datetime, timedelta
from zoneinfo import ZoneInfo

import pytest

from core.errors import InvalidInput
from portal.runs.listing import (
    RunFilter,
    comparison_series,
    runs_chosen,
    runs_compared,
    runs_filtered,
)
from portal.runs.package import runs_package_zip
from portal.runs.selectors import run_samples_csv
from portal.runs.states import RunState
from tests.factories import ExperimentFactory, MobileResourceFactory
from tests.runs.history import past_run

pytestmark = pytest.mark.django_db

LISBON = ZoneInfo("Europe/Lisbon")


@pytest.fixture
def history(owner, other, mobile, settings):
    settings.TIME_ZONE = "Europe/Lisbon"
    second = MobileResourceFactory(name="mobile-2")
    shared = ExperimentFactory(owner=owner, title="corner passes")
    return {
        "early": past_run(
            owner, mobile, started_at=datetime(2026, 3, 1, 9, 0, tzinfo=LISBON), title="dawn lap"
        ),
        # 23:30 in Lisbon on 2 March (summer time has not begun: UTC+0).
        "late": past_run(
            owner,
            second,
            started_at=datetime(2026, 3, 2, 23, 30, tzinfo=LISBON),
            title="night lap",
            state=RunState.FAILED,
            experiment=shared,
        ),
        "shared": past_run(
            owner,
            mobile,
            started_at=datetime(2026, 3, 5, 12, 0, tzinfo=LISBON),
            title="noon lap",
            experiment=shared,
        ),
        "bobs": past_run(
            other, mobile, started_at=datetime(2026, 3, 5, 13, 0, tzinfo=LISBON), title="dawn lap"
        ),
    }


def _ids(qs) -> list[int]:
    return [run.pk for run in qs]


def test_an_experimenter_lists_only_their_runs_newest_first(history, owner):
    assert _ids(runs_filtered(user=owner, filters=RunFilter())) == [
        history["shared"].pk,
        history["late"].pk,
        history["early"].pk,
    ]


def test_an_admin_lists_everyones_runs_and_can_narrow_to_one_owner(history, admin_user):
    everyone = _ids(runs_filtered(user=admin_user, filters=RunFilter()))
    assert history["bobs"].pk in everyone
    assert len(everyone) == 4
    assert _ids(runs_filtered(user=admin_user, filters=RunFilter(owner="bob"))) == [
        history["bobs"].pk
    ]


@pytest.mark.parametrize(
    ("filters", "expected"),
    [
        (RunFilter(states=(RunState.FAILED,)), ["late"]),
        (RunFilter(resource="mobile-2"), ["late"]),
        (RunFilter(started_from=date(2026, 3, 2), started_to=date(2026, 3, 2)), ["late"]),
        (RunFilter(started_from=date(2026, 3, 3)), ["shared"]),
        (RunFilter(started_to=date(2026, 3, 1)), ["early"]),
        (RunFilter(text="DAWN"), ["early"]),
        (RunFilter(text="corner"), ["shared", "late"]),
        (RunFilter(text="mobile-2"), ["late"]),
    ],
)
def test_each_filter_narrows_the_list(history, owner, filters, expected):
    assert _ids(runs_filtered(user=owner, filters=filters)) == [history[k].pk for k in expected]


def test_the_experiment_filter_and_a_run_number_search(history, owner):
    shared = history["shared"].experiment_id
    assert _ids(runs_filtered(user=owner, filters=RunFilter(experiment_id=shared))) == [
        history["shared"].pk,
        history["late"].pk,
    ]
    number = f"#{history['early'].pk}"
    assert _ids(runs_filtered(user=owner, filters=RunFilter(text=number))) == [history["early"].pk]
    # Another's run is not found by its number either.
    bobs = str(history["bobs"].pk)
    assert _ids(runs_filtered(user=owner, filters=RunFilter(text=bobs))) == []


def test_runs_are_chosen_in_the_order_named_once_each(history, owner):
    early, late = history["early"], history["late"]
    chosen = runs_chosen(user=owner, ids=[late.pk, early.pk, late.pk], at_least=2, at_most=6)
    assert [run.pk for run in chosen] == [late.pk, early.pk]


@pytest.mark.parametrize(
    ("which", "message"),
    [
        ([], "Choose at least 2 runs."),
        (["early"], "Choose at least 2 runs."),
        (["early", "late", "shared"], "Choose at most 2 runs at a time."),
        (["early", "bobs"], "among your runs"),
    ],
)
def test_a_choice_outside_the_bounds_or_the_users_runs_is_refused(history, owner, which, message):
    with pytest.raises(InvalidInput, match=message):
        runs_chosen(user=owner, ids=[history[k].pk for k in which], at_least=2, at_most=2)
    with pytest.raises(InvalidInput, match="No run 999999 among your runs"):
        runs_chosen(user=owner, ids=[history["early"].pk, 999999], at_least=1, at_most=5)


def test_a_comparison_lines_up_segments_and_starts_every_curve_at_zero(owner, mobile):
    start = datetime(2026, 3, 1, 9, 0, tzinfo=LISBON)
    two = past_run(owner, mobile, started_at=start)
    three = past_run(
        owner,
        mobile,
        started_at=start + timedelta(days=1),
        program=[(1.0, "ccw", 2.0), (0.5, "cw", 1.0), (0.25, "cw", 1.0)],
    )
    comparison = runs_compared(runs=[two, three])
    assert [index for index, _ in comparison.segments] == [0, 1, 2]
    first, _, third = (stats for _, stats in comparison.segments)
    assert [s.commanded_mps for s in first if s] == [0.5, -1.0]
    assert third[0] is None
    assert third[1] is not None
    assert third[1].mean_mps == pytest.approx(0.25)
    series = comparison_series(comparison)
    assert [s["run"] for s in series] == [two.pk, three.pk]
    for curve in series:
        assert curve["velocity"]["t"][0] == 0.0
        assert curve["position"]["y"][0] == 0.0
    # Two seconds clockwise at 0.5 m/s, then back at 0.25 m/s; and 2 s ccw at 1 m/s.
    assert max(series[0]["position"]["y"]) == pytest.approx(1.0, abs=0.03)
    assert min(series[1]["position"]["y"]) == pytest.approx(-2.0, abs=0.06)


def test_several_runs_download_as_their_packages_in_folders_with_a_manifest(history, owner):
    runs = [history["late"], history["early"]]
    urls = {run.pk: f"https://testbed.example/runs/{run.pk}/" for run in runs}
    archive = zipfile.ZipFile(io.BytesIO(b"".join(runs_package_zip(runs=runs, urls=urls))))
    folders = [f"run-{run.pk}/" for run in runs]
    assert archive.namelist() == [
        *(
            folder + name
            for folder in folders
            for name in ("README.md", "samples.csv", "datapackage.json")
        ),
        "manifest.json",
    ]
    manifest = json.loads(archive.read("manifest.json"))
    assert manifest["format"] == "amazing-runs-manifest"
    assert [entry["run"] for entry in manifest["runs"]] == [run.pk for run in runs]
    for run, entry in zip(runs, manifest["runs"], strict=True):
        csv_bytes = b"".join(run_samples_csv(run=run))
        assert archive.read(entry["folder"] + "samples.csv") == csv_bytes
        assert entry["samples_bytes"] == len(csv_bytes)
        assert entry["samples"] == 60
        assert entry["url"] == urls[run.pk]
        descriptor = json.loads(archive.read(entry["folder"] + "datapackage.json"))
        assert descriptor["amazing"]["run"]["id"] == run.pk
        assert descriptor["resources"][0]["hash"] == entry["samples_hash"]
    assert manifest["runs"][0]["state"] == "failed"


def _api_ids(response) -> list[int]:
    assert response.status_code == 200, response.content
    return [run["id"] for run in response.json()["results"]]


def test_the_api_lists_runs_with_the_pages_filters(history, owner, client_for):
    api = client_for(owner)
    assert _api_ids(api.get("/api/v1/runs/?resource=mobile-2")) == [history["late"].pk]
    assert _api_ids(api.get("/api/v1/runs/?started_from=2026-03-02&started_to=2026-03-02")) == [
        history["late"].pk
    ]
    experiment = history["shared"].experiment_id
    assert _api_ids(api.get(f"/api/v1/runs/?experiment={experiment}&state=completed")) == [
        history["shared"].pk
    ]
    assert _api_ids(api.get("/api/v1/runs/?q=dawn")) == [history["early"].pk]
    # An experiment renamed after a search: the next search finds it by its new name.
    ExperimentFactory._meta.model.objects.filter(pk=experiment).update(title="roof edge")
    assert _api_ids(api.get("/api/v1/runs/?q=roof%20edge")) == [
        history["shared"].pk,
        history["late"].pk,
    ]


@pytest.mark.parametrize(
    ("query", "field"),
    [
        ("started_from=2026-03-05&started_to=2026-03-01", "started_to"),
        ("started_from=March", "started_from"),
        ("experiment=0", "experiment"),
        ("state=exploded", "state"),
    ],
)
def test_the_api_refuses_a_filter_it_cannot_read(owner, client_for, query, field):
    response = client_for(owner).get(f"/api/v1/runs/?{query}")
    assert response.status_code == 400
    assert field in response.json()["fields"]
