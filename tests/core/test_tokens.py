"""API tokens answered from the cache, and forgotten when their token or user changes
(``core/accounts/tokens.py``)."""

from __future__ import annotations

import pytest
from django.core.cache import cache
from django.db import connection
from django.test.utils import CaptureQueriesContext
from rest_framework.authtoken.models import Token
from rest_framework.test import APIClient

from core.accounts.token_cache import cache_key as _cache_key
from tests.factories import UserFactory

pytestmark = pytest.mark.django_db

PASSWORD = "correct horse battery"


@pytest.fixture
def person():
    return UserFactory(username="dana", password=PASSWORD)


@pytest.fixture
def token(person) -> Token:
    return Token.objects.create(user=person)


def _client(token: Token) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {token.key}")
    return client


def _token_reads(client: APIClient) -> int:
    with CaptureQueriesContext(connection) as queries:
        assert client.get("/api/v1/quota/").status_code == 200
    return sum('"authtoken_token"' in q["sql"] for q in queries.captured_queries)


def test_a_token_is_read_from_the_database_once_then_from_the_cache(token):
    client = _client(token)
    assert _token_reads(client) == 1
    assert _token_reads(client) == 0


def test_the_cache_never_holds_the_password_hash_nor_the_token(token, person):
    _client(token).get("/api/v1/quota/")
    cached = cache.get(_cache_key(token.key))
    assert cached.pk == person.pk
    assert "password" in cached.get_deferred_fields()
    cached.first_name = "Dana"
    cached.save()  # a deferred field is not written
    person.refresh_from_db()
    assert person.check_password(PASSWORD)
    assert token.key not in _cache_key(token.key)


def test_a_deactivated_user_is_refused_at_once(token, person):
    client = _client(token)
    assert client.get("/api/v1/quota/").status_code == 200
    person.is_active = False
    person.save()
    assert client.get("/api/v1/quota/").status_code == 401


def test_a_deleted_token_is_refused_at_once(token):
    client = _client(token)
    assert client.get("/api/v1/quota/").status_code == 200
    token.delete()
    assert client.get("/api/v1/quota/").status_code == 401


def test_a_staff_flag_taken_away_applies_at_once(token, person):
    person.is_staff = True
    person.save()
    client = _client(token)
    assert client.get("/api/v1/audit/").status_code == 200
    person.is_staff = False
    person.save()
    assert client.get("/api/v1/audit/").status_code == 403


def test_an_unknown_token_is_refused():
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION="Token " + "0" * 40)
    assert client.get("/api/v1/quota/").status_code == 401
