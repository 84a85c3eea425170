"""The resource timeline page: its rows, grouped, with health holds; login required."""

from __future__ import annotations

import json
from datetime import timedelta

import pytest
from django.utils import timezone

from tests.factories import FixedResourceFactory, MobileResourceFactory

pytestmark = pytest.mark.django_db


def _rows(html: str) -> list[dict]:
    start = html.index('<script id="timeline-rows" type="application/json">')
    body = html[html.index(">", start) + 1 : html.index("</script>", start)]
    return json.loads(body)


def test_anonymous_visitors_are_sent_to_log_in(client):
    response = client.get("/calendar/timeline/")
    assert response.status_code == 302
    assert response["Location"].startswith("/accounts/login/")


def test_the_rows_are_robots_then_fixed_nodes_with_holds_and_no_disabled_resource(client, owner):
    held_at = timezone.now() - timedelta(minutes=5)
    MobileResourceFactory(name="mobile-1", held_at=held_at, hold_reason="agent unreachable")
    FixedResourceFactory(name="node-02")
    FixedResourceFactory(name="node-01")
    FixedResourceFactory(name="node-09", enabled=False)
    client.force_login(owner)
    response = client.get("/calendar/timeline/")
    assert response.status_code == 200
    rows = _rows(response.content.decode())
    assert [(g["title"], [c["id"] for c in g["children"]]) for g in rows] == [
        ("Robots", ["mobile-1"]),
        ("Fixed nodes", ["node-01", "node-02"]),
    ]
    robot = rows[0]["children"][0]["extendedProps"]
    assert robot["mobile"] is True
    assert robot["hold_reason"] == "agent unreachable"
    assert robot["held_at"] == held_at.isoformat()
    assert rows[1]["children"][0]["extendedProps"]["hold_reason"] == ""
