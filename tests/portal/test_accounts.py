"""Log in, log out and reset a forgotten password through the pages (django-allauth)."""

from __future__ import annotations

import re

import pytest
from django.core import mail

from tests.factories import api_token

pytestmark = pytest.mark.django_db


def test_pages_need_a_login(client):
    for path in ("/", "/experiments/new/", "/book/"):
        response = client.get(path)
        assert response.status_code == 302
        assert response["Location"].startswith("/accounts/login/")


def test_log_in_and_out(client, owner):
    response = client.post(
        "/accounts/login/", {"login": "alice", "password": "correct horse battery"}, follow=True
    )
    assert b"Hello, alice" in response.content
    client.post("/accounts/logout/")
    assert client.get("/").status_code == 302


def test_a_wrong_password_is_refused_with_a_message(client, owner):
    response = client.post("/accounts/login/", {"login": "alice", "password": "nope"})
    assert response.status_code == 200
    assert b"not correct" in response.content
    assert client.get("/").status_code == 302


def test_a_forgotten_password_is_reset_by_email(client, owner):
    client.post("/accounts/password/reset/", {"email": "alice@example.org"})
    assert len(mail.outbox) == 1
    link = re.search(r"https?://[^/\s]+(/accounts/password/reset/key/\S+)", mail.outbox[0].body)
    assert link, mail.outbox[0].body
    form = client.get(link.group(1), follow=True)
    action = form.redirect_chain[-1][0] if form.redirect_chain else link.group(1)
    done = client.post(
        action, {"password1": "a new long passphrase", "password2": "a new long passphrase"}
    )
    assert done.status_code == 302
    client.logout()
    response = client.post(
        "/accounts/login/", {"login": "alice", "password": "a new long passphrase"}, follow=True
    )
    assert b"Hello, alice" in response.content


def test_the_api_takes_a_token_or_a_session(client, owner):
    token = api_token(owner)
    assert client.get("/api/v1/runs/").status_code == 401
    assert client.get("/api/v1/runs/", HTTP_AUTHORIZATION=f"Token {token}").status_code == 200
    client.force_login(owner)
    assert client.get("/api/v1/runs/").status_code == 200
    # A session-authenticated write needs the CSRF token, like any form.
    from django.test import Client

    strict = Client(enforce_csrf_checks=True)
    strict.force_login(owner)
    refused = strict.post("/api/v1/experiments/", {}, content_type="application/json")
    assert refused.status_code == 403
    assert "CSRF" in refused.json()["detail"]
