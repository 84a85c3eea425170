"""The `amazing` command against a live portal: login, each command, errors and exit codes.

The CLI runs in this process (typer's runner) and talks HTTP to the real ASGI server on the
test database. Every request it makes is recorded, and each must be an operation that
`/api/schema/` describes.
"""

from __future__ import annotations

import json
import queue
import stat
import subprocess
import sys
import threading
import zipfile
from datetime import timedelta
from pathlib import Path

import pytest
import requests
from django.utils import timezone
from typer.testing import CliRunner

from amazing_cli.api import OPERATIONS, Api
from amazing_cli.errors import CliError
from amazing_cli.main import app
from bookings.models import Reservation, Resource
from core.accounts.models import ApiToken
from core.audit.models import AuditEvent
from portal.runs.models import Run
from portal.runs.services.reservations import reservation_create
from tests.cli.schema_paths import undocumented
from tests.factories import (
    ExperimentFactory,
    FixedResourceFactory,
    MobileResourceFactory,
    UserFactory,
    api_token,
    mfa_on,
    totp_code,
)

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

EXPERIMENT = """\
title: there and back
segments:
  - {velocity_mps: 0.5, direction: cw, duration_s: 3}
  - {velocity_mps: 0.8, direction: ccw, duration_s: 2.5}
"""


@pytest.fixture
def calls(monkeypatch):
    """Every HTTP request made in this process, as (method, URL)."""
    made: list[tuple[str, str]] = []
    send = requests.Session.request

    def recording(self, method, url, *args, **kwargs):
        made.append((method.upper(), url))
        return send(self, method, url, *args, **kwargs)

    monkeypatch.setattr(requests.Session, "request", recording)
    return made


@pytest.fixture
def portal(live_web, monkeypatch, tmp_path):
    """The live portal with a robot, a fixed node and erin's token in the environment."""
    MobileResourceFactory(agent_url="http://127.0.0.1:9")
    FixedResourceFactory(name="node-01")
    erin = UserFactory(username="erin")
    monkeypatch.setenv("AMAZING_URL", live_web.url)
    token = api_token(erin)
    monkeypatch.setenv("AMAZING_TOKEN", token)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "config"))
    monkeypatch.setenv("COLUMNS", "160")
    monkeypatch.chdir(tmp_path)
    return {"url": live_web.url, "erin": erin, "token": token}


def amazing(*args: str):
    return CliRunner().invoke(app, list(args), catch_exceptions=False)


def _one_line_error(result, exit_code: int) -> str:
    assert result.exit_code == exit_code, (result.exit_code, result.stdout, result.stderr)
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("amazing: ")
    return lines[0]


def _schema(url: str) -> dict:
    return requests.get(
        f"{url}/api/schema/", headers={"Accept": "application/json"}, timeout=10
    ).json()


def test_the_cli_imports_nothing_of_django_or_the_portal():
    probe = (
        "import sys, amazing_cli.main; "
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('django', 'rest_framework', 'portal', 'bookings', 'basestation', 'celery')); "
        "print(bad); sys.exit(1 if bad else 0)"
    )
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    script = Path(sys.executable).parent / "amazing"
    assert subprocess.run([str(script), "--help"], capture_output=True).returncode == 0


def test_every_operation_the_cli_knows_is_in_the_schema(portal):
    schema = _schema(portal["url"])
    paths = [(method, template) for method, template in OPERATIONS.values()]
    # The schema document itself is the one path it does not list.
    assert not undocumented([p for p in paths if p[1] != "/api/schema/"], schema)


def test_login_stores_the_token_for_the_user_alone_and_the_environment_wins(portal, monkeypatch):
    token = portal["token"]
    monkeypatch.delenv("AMAZING_TOKEN")
    monkeypatch.delenv("AMAZING_URL")
    result = amazing("login", "--url", portal["url"], "--token", token)
    assert result.exit_code == 0, result.stderr
    assert "as erin" in result.stdout
    stored = Path(portal_config_dir()) / "credentials.json"
    assert stat.S_IMODE(stored.stat().st_mode) == 0o600
    assert stat.S_IMODE(stored.parent.stat().st_mode) == 0o700
    assert json.loads(stored.read_text()) == {"url": portal["url"], "token": token}
    # The stored login serves the next commands...
    assert amazing("quota").exit_code == 0
    # ...but AMAZING_TOKEN takes precedence over it.
    monkeypatch.setenv("AMAZING_TOKEN", "not-a-token")
    line = _one_line_error(amazing("quota"), 3)
    assert "Invalid token" in line
    logout = amazing("logout")
    assert logout.exit_code == 0, logout.output
    assert not stored.exists()


def test_login_with_a_password_and_the_code_asked_for_then_logout_revokes(portal, monkeypatch):
    """``amazing login --username``: the portal makes a token for this computer, the
    two-factor code asked for when the account has MFA; ``amazing logout`` revokes it."""
    secret = mfa_on(portal["erin"])
    monkeypatch.delenv("AMAZING_TOKEN")
    monkeypatch.setenv("AMAZING_PASSWORD", "correct horse battery")
    result = CliRunner().invoke(
        app, ["login", "--username", "erin", "--name", "ci laptop"], input=totp_code(secret) + "\n"
    )
    assert result.exit_code == 0, result.output
    assert "Two-factor code" in result.output
    assert "as erin" in result.output
    made = ApiToken.objects.get(name="ci laptop")
    stored = json.loads((Path(portal_config_dir()) / "credentials.json").read_text())
    assert stored["token"].startswith(made.token_key)
    assert amazing("quota").exit_code == 0
    logout = amazing("logout")
    assert logout.exit_code == 0, logout.output
    assert "revoked" in logout.output
    assert not ApiToken.objects.filter(name="ci laptop").exists()
    monkeypatch.setenv("AMAZING_TOKEN", stored["token"])
    assert "Invalid token" in _one_line_error(amazing("quota"), 3)


def test_login_with_a_wrong_password_stores_nothing(portal, monkeypatch):
    monkeypatch.delenv("AMAZING_TOKEN")
    monkeypatch.setenv("AMAZING_PASSWORD", "not it")
    line = _one_line_error(amazing("login", "--username", "erin"), 2)
    assert "username or the password is wrong" in line
    assert not (Path(portal_config_dir()) / "credentials.json").exists()


def portal_config_dir() -> str:
    from amazing_cli.config import config_dir

    return str(config_dir())


def test_login_with_a_wrong_token_is_refused_and_stores_nothing(portal):
    line = _one_line_error(amazing("login", "--token", "wrong"), 3)
    assert "Invalid token" in line
    assert not (Path(portal_config_dir()) / "credentials.json").exists()


def test_a_campaign_step_by_step_calls_only_what_the_schema_describes(portal, calls, tmp_path):
    (tmp_path / "e.yaml").write_text(EXPERIMENT)
    assert "mobile-1" in amazing("resources").stdout
    assert amazing("availability", "node-01", "--days", "1").exit_code == 0
    assert amazing("quota").exit_code == 0

    created = amazing("experiment", "create", "e.yaml", "--json")
    assert created.exit_code == 0, created.stderr
    experiment = json.loads(created.stdout)
    assert experiment["duration_s"] == 5.5
    assert "there and back" in amazing("experiment", "list").stdout

    first = amazing("book", "--experiment", str(experiment["id"]), "--node", "node-01", "--json")
    assert first.exit_code == 0, first.stderr
    booking = json.loads(first.stdout)
    assert booking["resources"] == ["mobile-1", "node-01"]
    length_s = (
        timezone.datetime.fromisoformat(booking["end_at"])
        - timezone.datetime.fromisoformat(booking["start_at"])
    ).total_seconds()
    assert length_s == 6 + 5  # the program, rounded up, and the margin
    run = booking["run"]["id"]
    second = amazing("book", "--experiment", str(experiment["id"]), "--after", str(run), "--quiet")
    assert second.exit_code == 0, second.stderr
    next_run = int(second.stdout)
    runs = json.loads(amazing("runs", "--json").stdout)
    assert {r["id"] for r in runs} == {run, next_run}
    by_id = {r["id"]: r for r in runs}
    assert by_id[next_run]["start_at"] == by_id[run]["end_at"]
    assert amazing("runs", "--quiet").stdout.split() == [str(next_run), str(run)]

    # Taken: the same slot again is refused; the check says so first, and books nothing.
    before = amazing("runs", "--quiet").stdout.split()
    checked = amazing("book", "--experiment", str(experiment["id"]), "--after", str(run), "--check")
    assert checked.exit_code == 3, (checked.stdout, checked.stderr)
    assert checked.stdout.startswith("booked: mobile-1 is already booked from ")
    taken = amazing("book", "--experiment", str(experiment["id"]), "--after", str(run))
    assert "already booked" in _one_line_error(taken, 3)
    free = amazing("book", "--experiment", str(experiment["id"]), "--check", "--json")
    assert free.exit_code == 0, free.stderr
    assert json.loads(free.stdout)["fits"] is True
    assert amazing("runs", "--quiet").stdout.split() == before

    assert amazing("cancel", str(next_run)).exit_code == 0
    watched = amazing("watch", str(next_run), "--interval", "0.2")
    assert watched.exit_code == 1  # cancelled, not completed
    assert "cancelled" in watched.stdout
    for fmt in ("csv", "json"):
        downloaded = amazing("download", str(next_run), "--format", fmt, "--json")
        assert downloaded.exit_code == 0, downloaded.stderr
        assert json.loads(downloaded.stdout)["samples"] == 0
    assert (tmp_path / f"amazing-run-{next_run}.csv").read_text().startswith("seq,t,")

    assert len(calls) > 15
    schema = _schema(portal["url"])
    assert not undocumented([c for c in calls if not c[1].endswith("/api/schema/")], schema)


def test_watch_follows_a_run_to_its_end_and_download_streams_every_sample(portal, tmp_path):
    from tests.runs.driving import completed_run

    run = completed_run(portal["erin"], MobileResourceFactory(), [(0.5, "cw", 2.0)])
    watched = amazing("watch", str(run.pk))
    assert watched.exit_code == 0, watched.stderr
    assert f"Run {run.pk} completed: 40 samples." in watched.stdout
    downloaded = amazing("download", str(run.pk), "-o", "out.csv")
    assert downloaded.exit_code == 0, downloaded.stderr
    assert "Wrote out.csv: 40 samples" in downloaded.stdout
    assert len((tmp_path / "out.csv").read_text().splitlines()) == 41
    as_json = amazing("download", str(run.pk), "--format", "json", "-o", "out.json")
    assert as_json.exit_code == 0, as_json.stderr
    assert len(json.loads((tmp_path / "out.json").read_text())["samples"]) == 40


@pytest.mark.parametrize(
    ("case", "exit_code", "says"),
    [
        ("missing file", 2, "no-such.yaml: no such file"),
        ("invalid YAML", 2, "not valid YAML at line 4"),
        ("invalid JSON", 2, "not valid JSON"),
        ("schema-invalid", 2, "segments.0: 'duration_s' is a required property"),
        ("over-limit velocity", 2, "velocity 5 m/s is faster than every robot you may book"),
        ("no token", 3, "no token: run `amazing login` or set AMAZING_TOKEN"),
        ("portal down", 5, "cannot reach the portal at http://127.0.0.1:9"),
        ("unknown run", 4, "No Run matches the given query."),
        ("unknown format", 2, "--format 'xml': give csv, json, zip or parquet"),
        ("bad time", 2, "--start 'tomorrow'"),
    ],
)
def test_bad_input_gives_one_clear_line_and_its_exit_code(
    case, exit_code, says, portal, calls, tmp_path, monkeypatch
):
    (tmp_path / "bad.yaml").write_text("title: x\nsegments:\n  - [velocity_mps: 1\n")
    (tmp_path / "bad.json").write_text('{"title": "x", "segments": [}')
    (tmp_path / "short.yaml").write_text(
        "title: x\nsegments:\n  - {velocity_mps: 1, direction: cw}\n"
    )
    (tmp_path / "fast.yaml").write_text(
        "title: x\nsegments:\n  - {velocity_mps: 5, direction: cw, duration_s: 3}\n"
    )
    experiment = ExperimentFactory(owner=portal["erin"])
    argv = {
        "missing file": ["experiment", "create", "no-such.yaml"],
        "invalid YAML": ["experiment", "create", "bad.yaml"],
        "invalid JSON": ["experiment", "create", "bad.json"],
        "schema-invalid": ["experiment", "create", "short.yaml"],
        "over-limit velocity": ["experiment", "create", "fast.yaml"],
        "no token": ["runs"],
        "portal down": ["runs"],
        "unknown run": ["watch", "999999"],
        "unknown format": ["download", "1", "--format", "xml"],
        "bad time": ["book", "--experiment", str(experiment.pk), "--start", "tomorrow"],
    }[case]
    if case == "no token":
        monkeypatch.delenv("AMAZING_TOKEN")
    if case == "portal down":
        monkeypatch.setenv("AMAZING_URL", "http://127.0.0.1:9")
    line = _one_line_error(amazing(*argv), exit_code)
    assert says in line, line
    # Nothing the portal refused was made, and files were checked before anything was sent.
    assert not [c for c in calls if c[0] == "POST" and case != "over-limit velocity"]


def test_a_slot_in_the_past_is_refused_by_the_portal_with_exit_code_2(portal):
    experiment = ExperimentFactory(owner=portal["erin"])
    past = (timezone.now() - timedelta(hours=1)).isoformat()
    line = _one_line_error(amazing("book", "--experiment", str(experiment.pk), "--start", past), 2)
    assert "The start is in the past." in line


def test_another_users_run_is_not_found(portal):
    other = UserFactory(username="bob")
    start = timezone.now() + timedelta(hours=2)
    theirs = reservation_create(
        owner=other,
        resource=MobileResourceFactory(),
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=other),
    )
    run_before = Run.objects.filter(pk=theirs.run.pk).values().get()
    booking_before = Reservation.objects.filter(pk=theirs.pk).values().get()
    audit_before = list(AuditEvent.objects.order_by("pk").values())
    _one_line_error(amazing("watch", str(theirs.run.pk)), 4)
    _one_line_error(amazing("cancel", str(theirs.run.pk)), 4)
    _one_line_error(amazing("cancel", "--reservation", str(theirs.pk)), 4)
    # Refused, and nothing of theirs touched: the run, the booking, the history.
    assert Run.objects.filter(pk=theirs.run.pk).values().get() == run_before
    assert Reservation.objects.filter(pk=theirs.pk).values().get() == booking_before
    assert list(AuditEvent.objects.order_by("pk").values()) == audit_before


def test_a_script_retrying_with_its_key_books_once_and_sees_the_portals_status(portal):
    """The client's ``create`` with a key of the script's own: sent again (its answer lost),
    the portal replays the first booking instead of making a second; a refusal carries the
    portal's status, which tells a taken slot (409) from a portal that did not answer."""
    api = Api(portal["url"], portal["token"])
    start = (timezone.now() + timedelta(hours=3)).replace(microsecond=0)
    body = {
        "resources": ["node-01"],
        "start_at": start.isoformat(),
        "end_at": (start + timedelta(minutes=30)).isoformat(),
    }
    first = api.create("reservation_create", body, key="campaign-7-slot-1")
    again = api.create("reservation_create", body, key="campaign-7-slot-1")
    assert again == first
    assert Reservation.objects.filter(owner=portal["erin"]).count() == 1
    with pytest.raises(CliError) as taken:
        api.create("reservation_create", body, key="campaign-7-slot-2")
    assert taken.value.status == 409
    with pytest.raises(CliError) as down:
        Api("http://127.0.0.1:9", "token").call("me")
    assert down.value.status is None


def test_book_again_books_the_next_free_slot_and_the_new_run_links_the_old_one(portal):
    from portal.runs.models import Run
    from tests.runs.driving import completed_run

    robot = Resource.objects.get(name="mobile-1")
    run = completed_run(portal["erin"], robot, [(0.5, "cw", 2.0)])
    booked = amazing("book", "--again", str(run.pk), "--quiet")
    assert booked.exit_code == 0, booked.stderr
    again = Run.objects.get(pk=int(booked.stdout.strip()))
    assert again.repeat_of_id == run.pk
    assert again.segments == run.segments
    assert again.resource_id == robot.pk
    assert again.end_at - again.start_at == run.end_at - run.start_at
    # The first free slot: the robot is free now, so as soon as the lead allows.
    assert again.start_at < run.start_at
    line = _one_line_error(amazing("book", "--again", str(run.pk), "--start", "+1h"), 2)
    assert "--again takes the run's own program, robot and length: drop --start" in line
    _one_line_error(amazing("book", "--again", "999999"), 4)


def test_download_zip_writes_the_package_and_checks_it(portal, tmp_path):
    from tests.runs.driving import completed_run

    run = completed_run(portal["erin"], Resource.objects.get(name="mobile-1"), [(0.5, "cw", 2.0)])
    downloaded = amazing("download", str(run.pk), "--format", "zip")
    assert downloaded.exit_code == 0, downloaded.stderr
    assert f"Wrote amazing-run-{run.pk}.zip: 40 samples" in downloaded.stdout
    with zipfile.ZipFile(tmp_path / f"amazing-run-{run.pk}.zip") as package:
        assert sorted(package.namelist()) == ["README.md", "datapackage.json", "samples.csv"]


def test_events_follow_prints_a_runs_events_as_it_runs_and_stops_at_its_end(portal):
    """`amazing events --follow --run N`, a process of its own, prints each state the moment
    the portal commits it (a long poll), and exits once the run has ended."""
    from portal.runs.services import collection
    from portal.runs.services.transitions import run_transition
    from portal.runs.states import Cause, RunState
    from tests.runs.driving import ingest

    erin = portal["erin"]
    start = timezone.now().replace(microsecond=0) + timedelta(hours=1)
    reservation = reservation_create(
        owner=erin,
        resource=Resource.objects.get(name="mobile-1"),
        start_at=start,
        end_at=start + timedelta(minutes=10),
        experiment=ExperimentFactory(owner=erin, title="followed"),
    )
    run = Run.objects.get(reservation=reservation)
    script = Path(sys.executable).parent / "amazing"
    lines: queue.Queue[str] = queue.Queue()
    with subprocess.Popen(
        [str(script), "events", "--follow", "--run", str(run.pk)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    ) as follower:
        reader = threading.Thread(target=lambda: [lines.put(line) for line in follower.stdout])
        reader.start()
        try:
            assert "run.scheduled" in lines.get(timeout=30)
            for state in (RunState.STAGED, RunState.RUNNING, RunState.COLLECTING):
                assert run_transition(run_id=run.pk, to_state=state, cause=Cause.DISPATCH)
                line = lines.get(timeout=30)
                assert f"run.{state} run:{run.pk}" in line, line
            # Collected: completed, and its data ready in the same commit, shown before it exits.
            ingest(run, [(0.5, "cw", 1.0)])
            assert collection._end(run, RunState.COMPLETED, "20 samples collected", [])
            assert f"run.completed run:{run.pk}" in lines.get(timeout=30)
            ready = lines.get(timeout=30)
            assert f"run.data_ready run:{run.pk}" in ready, ready
            assert "mobile-1 completed: 20 samples;" in ready
            assert follower.wait(timeout=30) == 0, follower.stderr.read()
        finally:
            follower.kill()
            reader.join(10)
    assert lines.empty()  # the reservation's own events were not the run's


def test_webhook_commands_make_list_test_log_resume_and_delete(portal, calls):
    """`amazing webhook …` through the API: the secret printed once, a test event sent and its
    delivery in the log, a paused webhook resumed, another user's not found, one deleted."""
    from core.events.dispatch import events_dispatch
    from core.events.sequence import events_sequence
    from core.webhooks import delivery
    from core.webhooks.models import WebhookSubscription

    made = amazing("webhook", "create", "http://127.0.0.1:9/hook", "--type", "run.completed",
                   "--description", "lab bot", "-q")  # fmt: skip
    assert made.exit_code == 0, made.stderr
    webhook = int(made.stdout.strip())
    assert "Its secret (shown this once" in made.stderr
    assert "whsec_" in made.stderr
    listed = amazing("webhook", "list")
    assert f"{webhook}" in listed.stdout
    assert "run.completed" in listed.stdout
    assert "active" in listed.stdout
    assert "whsec_" not in listed.stdout

    tested = amazing("webhook", "test", str(webhook), "-q")
    assert tested.exit_code == 0, tested.stderr
    event = int(tested.stdout)
    # The mail worker's pass and one try of the sender, here: port 9 does not answer.
    events_sequence()
    events_dispatch(name="webhooks")
    delivery.webhook_deliveries_send()
    log = amazing("webhook", "log", str(webhook), "--json")
    assert log.exit_code == 0, log.stderr
    (tried,) = json.loads(log.stdout)
    assert (tried["event"], tried["type"], tried["state"]) == (event, "webhook.test", "pending")
    assert tried["attempts"] == 1
    assert tried["last_error"].startswith("no answer")
    assert "webhook.test" in amazing("webhook", "log", str(webhook)).stdout

    WebhookSubscription.objects.filter(pk=webhook).update(
        paused_at=timezone.now(), pause_reason="failed for a day"
    )
    assert "paused: failed for a day" in amazing("webhook", "list").stdout
    resumed = amazing("webhook", "resume", str(webhook))
    assert resumed.exit_code == 0, resumed.stderr
    assert WebhookSubscription.objects.get(pk=webhook).paused_at is None

    theirs = WebhookSubscription.objects.create(
        owner=UserFactory(username="bob"), url="http://127.0.0.1:9/theirs", secret_encrypted="x"
    )
    for command in ("log", "test", "resume"):
        _one_line_error(amazing("webhook", command, str(theirs.pk)), 4)
    _one_line_error(amazing("webhook", "delete", str(theirs.pk), "--yes"), 4)
    assert WebhookSubscription.objects.filter(pk=theirs.pk).exists()

    kept = CliRunner().invoke(app, ["webhook", "delete", str(webhook)], input="n\n")
    assert "Kept it." in kept.stdout
    assert WebhookSubscription.objects.filter(pk=webhook).exists()
    deleted = amazing("webhook", "delete", str(webhook), "--yes")
    assert deleted.exit_code == 0, deleted.stderr
    assert not WebhookSubscription.objects.filter(pk=webhook).exists()
    schema = Api(portal["url"], portal["token"]).schema()
    assert not undocumented([c for c in calls if not c[1].endswith("/api/schema/")], schema)


def test_measurements_commands_add_list_offset_and_delete(portal, calls, tmp_path):
    """`amazing measurements …` through the API: a Parquet file added as a series and added
    again (stored once), listed with where its points fell, an offset set, a bad file refused
    with exit 2, another user's run not found, the series deleted after asking."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from portal.runs.models import MeasurementPoint, MeasurementSeries
    from tests.runs.driving import completed_run

    run = completed_run(portal["erin"], MobileResourceFactory(), [(0.5, "cw", 2.0)])
    t0_s = run.start_at.timestamp()
    pq.write_table(
        pa.table(
            {"unix_s": [t0_s + 0.25 * i for i in range(8)], "rssi": [-50.0 - i for i in range(8)]}
        ),
        tmp_path / "walk.parquet",
    )
    for stored in (8, 0):
        added = amazing("measurements", "add", str(run.pk), "walk.parquet", "--name", "rssi",
                        "--unit", "dBm")  # fmt: skip
        assert added.exit_code == 0, added.stderr
        assert f"Stored {stored} values in rssi of run {run.pk}" in added.stdout
    assert "8 were there already" in added.stdout
    assert MeasurementPoint.objects.count() == 8
    listed = amazing("measurements", "list", str(run.pk))
    assert "rssi [dBm]: 8 points of rssi (8 on the path)" in listed.stdout
    moved = amazing("measurements", "offset", str(run.pk), "rssi", "--", "-60")
    assert moved.exit_code == 0, moved.stderr
    assert "8 before" in moved.stdout
    assert "clock offset -60 s" in moved.stdout
    (tmp_path / "bad.csv").write_text("t,rssi\n2027-01-01T10:00:00,-50\n")
    said = _one_line_error(amazing("measurements", "add", str(run.pk), "bad.csv", "--name", "x"), 2)
    assert "UTC offset" in said
    robot = MobileResourceFactory(name="mobile-2")
    theirs = completed_run(UserFactory(username="bob"), robot, [(0.5, "cw", 2.0)])
    _one_line_error(amazing("measurements", "list", str(theirs.pk)), 4)
    parquet = amazing("download", str(run.pk), "--format", "parquet", "-o", "run.parquet")
    assert parquet.exit_code == 0, parquet.stderr
    assert "Wrote run.parquet: 40 samples" in parquet.stdout
    assert "Wrote run-rssi.parquet: 8 rows." in parquet.stdout
    assert pq.read_table(tmp_path / "run-rssi.parquet").column("rssi").to_pylist()[0] == -50.0
    kept = CliRunner().invoke(app, ["measurements", "delete", str(run.pk), "rssi"], input="n\n")
    assert "Kept it." in kept.stdout
    deleted = amazing("measurements", "delete", str(run.pk), "rssi", "--yes")
    assert deleted.exit_code == 0, deleted.stderr
    assert not MeasurementSeries.objects.exists()
    assert not MeasurementPoint.objects.exists()
    schema = _schema(portal["url"])
    assert not undocumented([c for c in calls if not c[1].endswith("/api/schema/")], schema)
