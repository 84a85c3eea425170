"""What the portal writes out tells no more than it must and keeps nothing for good.

- Metric labels come from closed sets: a made-up HTTP method counts as ``other``.
- Calendar feed secrets are kept as their SHA-256 only (feeds made before keep working), and
  no log line carries one.
- ``/healthz`` (no login) and the rail relay (any signed-in user) name no internal address
  and no error text.
- Finished dry runs and their samples are deleted after ``DRY_RUN_KEEP_S`` (hourly task).
"""

from __future__ import annotations

import hashlib
import logging
from datetime import timedelta

import pytest
from django.conf import settings as live_settings
from django.db import connection
from django.db.migrations.executor import MigrationExecutor
from django.test import Client
from django.utils import timezone

from bookings.calendar import calendar_feed_renew
from bookings.models import CalendarFeed, SchedulerLink
from bookings.scheduler import config as scheduler_config
from core.metrics import REQUESTS
from portal.runs.models import DryRun
from portal.runs.tasks import dry_runs_delete_expired

pytestmark = pytest.mark.django_db

INTERNAL = "10.42.0.7"


def _method_labels() -> set[str]:
    return {
        sample.labels["method"]
        for metric in REQUESTS.collect()
        for sample in metric.samples
        if "method" in sample.labels
    }


def test_a_made_up_method_is_counted_as_other(client):
    for method in ("FOOBAR", "X" * 200, "get"):
        client.generic(method, "/healthz")
    labels = _method_labels()
    assert "other" in labels
    assert labels <= {"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "other"}


def test_a_feed_secret_is_kept_as_its_digest_only(client, owner):
    token = calendar_feed_renew(user=owner)
    feed = CalendarFeed.objects.get(user=owner)
    assert feed.token_digest == hashlib.sha256(token.encode()).hexdigest()
    row = [str(value) for value in CalendarFeed.objects.values_list().get()]
    assert not any(token in value for value in row)
    assert client.get(f"/calendar/feed/{token}.ics").status_code == 200


def test_the_feeds_page_shows_the_addresses_only_when_made(client, owner):
    client.force_login(owner)
    first = client.get("/calendar/feeds/")
    assert first["Cache-Control"] == "no-store"
    assert "/calendar/feed/" in first.content.decode()
    again = client.get("/calendar/feeds/").content.decode()
    assert "/calendar/feed/" not in again
    assert "shown only when made" in again


def test_no_log_line_carries_a_feed_secret(owner, settings, caplog):
    settings.ACCESS_LOG = True
    token = calendar_feed_renew(user=owner)
    client = Client()  # its middleware built now, with the access log on
    with caplog.at_level(logging.DEBUG):
        assert client.get(f"/calendar/feed/{token}.ics").status_code == 200
        assert client.get(f"/calendar/feed/{token}/node-1.ics").status_code == 404
        calendar_feed_renew(user=owner)  # the old secret is now a revoked one
        assert client.get(f"/calendar/feed/{token}.ics").status_code == 404
    access = [r for r in caplog.records if r.name == "portal.access"]
    assert len(access) == 3
    assert all("[redacted]" in r.getMessage() for r in access)
    assert all(r.path.startswith("/calendar/feed/[redacted]") for r in access)
    for record in caplog.records:
        assert token not in record.getMessage()
        assert token not in str(record.__dict__)


def test_the_proxy_log_format_redacts_feed_addresses():
    """nginx writes its own access line (not run here: the format is read)."""
    nginx = (live_settings.BASE_DIR / "deploy" / "nginx.conf").read_text()
    assert "/calendar/feed/[redacted]" in nginx
    assert "access_log /var/log/nginx/access.log amazing;" in nginx
    assert "$request_method $amazing_logged_uri" in nginx


MIGRATED = [("bookings", "0012_calendar_feed_token_digest")]
BEFORE_DIGESTS = [("bookings", "0011_agent_credential")]


@pytest.mark.django_db(transaction=True)
def test_feed_addresses_made_before_digests_keep_working(client):
    executor = MigrationExecutor(connection)
    executor.migrate(BEFORE_DIGESTS)
    try:
        old = executor.loader.project_state(BEFORE_DIGESTS).apps
        user = old.get_model("accounts", "User").objects.create(username="dana", is_active=True)
        old.get_model("bookings", "CalendarFeed").objects.create(user=user, token="an-old-secret")
    finally:
        executor = MigrationExecutor(connection)
        executor.migrate(executor.loader.graph.leaf_nodes())
    assert CalendarFeed.objects.get().token_digest == hashlib.sha256(b"an-old-secret").hexdigest()
    assert client.get("/calendar/feed/an-old-secret.ics").status_code == 200


def test_healthz_tells_no_error_text_of_the_scheduler(client, settings):
    settings.SCHEDULER = scheduler_config.from_env({"SCHEDULER_URL": f"http://{INTERNAL}:9"})
    SchedulerLink.objects.create(
        pk=1,
        last_error=f"GET http://{INTERNAL}:9/leases: ConnectionRefusedError",
        last_error_at=timezone.now(),
    )
    body = client.get("/healthz").content.decode()
    assert INTERNAL not in body
    assert "ConnectionRefused" not in body
    assert '"testbed_scheduler": {"configured": true, "ok": false' in body


@pytest.mark.parametrize("path", ["/api/v1/resources/{name}/rail/", "/rails/{name}.json"])
def test_the_rail_relay_names_no_agent_address(client, owner, mobile, settings, path):
    """The agent does not answer (a closed port): the error names its address."""
    settings.AGENT_TOKENS = {"default": "rail-test-token"}
    mobile.agent_url = "http://127.0.0.1:1"  # refused at once
    mobile.save()
    client.force_login(owner)
    answer = client.get(path.format(name=mobile.name))
    assert answer.status_code in (200, 503)
    assert "did not give its rail" in answer.content.decode()
    assert "127.0.0.1" not in answer.content.decode()
    assert "Connection" not in answer.content.decode()


def _dry_run(owner, state: str, *, ended_days_ago: float | None) -> DryRun:
    ended = None if ended_days_ago is None else timezone.now() - timedelta(days=ended_days_ago)
    return DryRun.objects.create(
        owner=owner,
        title="try",
        segments=[],
        limits={},
        rail_length_m=100.0,
        state=state,
        slot=0 if state == DryRun.State.RUNNING else None,
        samples=[{"seq": 1}],
        ended_at=ended,
    )


def test_finished_dry_runs_are_deleted_after_the_time_kept(owner, settings):
    settings.DRY_RUN_KEEP_S = 7 * 24 * 3600.0
    old = _dry_run(owner, DryRun.State.COMPLETED, ended_days_ago=8)
    old_failed = _dry_run(owner, DryRun.State.FAILED, ended_days_ago=30)
    recent = _dry_run(owner, DryRun.State.COMPLETED, ended_days_ago=1)
    running = _dry_run(owner, DryRun.State.RUNNING, ended_days_ago=None)
    DryRun.objects.filter(pk=running.pk).update(created_at=timezone.now() - timedelta(days=30))
    assert dry_runs_delete_expired.apply().get() == 2
    kept = set(DryRun.objects.values_list("pk", flat=True))
    assert kept == {recent.pk, running.pk}
    assert not DryRun.objects.filter(pk__in=[old.pk, old_failed.pk]).exists()


def test_the_deletion_runs_hourly():
    entry = live_settings.CELERY_BEAT_SCHEDULE["dry-runs-delete-expired"]
    assert entry["task"] == "portal.runs.tasks.dry_runs_delete_expired"
    assert entry["schedule"] <= 3600
