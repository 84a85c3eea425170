"""API tokens answered from the cache, and forgotten when their token or user changes
(``core/accounts/tokens.py``)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.core.cache import cache
from django.db import connection
from django.test.utils import CaptureQueriesContext
from django.utils import timezone
from rest_framework.test import APIClient

from core.accounts.models import ApiToken
from core.accounts.token_cache import cache_key as _cache_key
from core.accounts.tokens import token_digest
from tests.factories import UserFactory, api_token

pytestmark = pytest.mark.django_db

PASSWORD = "correct horse battery"


@pytest.fixture
def person():
    return UserFactory(username="dana", password=PASSWORD)


@pytest.fixture
def token(person) -> str:
    return api_token(person)


def _client(token: str) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {token}")
    return client


def _token_reads(client: APIClient) -> int:
    with CaptureQueriesContext(connection) as queries:
        assert client.get("/api/v1/quota/").status_code == 200
    return sum(
        '"accounts_apitoken"' in q["sql"] and q["sql"].startswith("SELECT")
        for q in queries.captured_queries
    )


def test_a_token_is_read_from_the_database_once_then_from_the_cache(token):
    client = _client(token)
    assert _token_reads(client) == 1
    assert _token_reads(client) == 0


def test_only_a_digest_of_the_token_is_stored(token):
    stored = ApiToken.objects.get()
    assert token not in stored.digest
    assert stored.digest == token_digest(token)
    assert token.startswith(stored.token_key)


def test_the_cache_never_holds_the_password_hash_nor_the_token(token, person):
    _client(token).get("/api/v1/quota/")
    cached, _expiry, _verified = cache.get(_cache_key(token_digest(token)))
    assert cached.pk == person.pk
    assert "password" in cached.get_deferred_fields()
    cached.first_name = "Dana"
    cached.save()  # a deferred field is not written
    person.refresh_from_db()
    assert person.check_password(PASSWORD)
    assert token not in _cache_key(token_digest(token))


def test_last_use_is_written_once_a_minute_not_per_request(token):
    client = _client(token)
    with CaptureQueriesContext(connection) as queries:
        for _ in range(3):
            assert client.get("/api/v1/quota/").status_code == 200
    writes = [q for q in queries.captured_queries if q["sql"].startswith("UPDATE")]
    assert len(writes) == 1
    first_use = ApiToken.objects.get().last_used_at
    assert first_use is not None
    # The cache entry gone (a minute later), the next read finds the use recent: no write.
    cache.clear()
    with CaptureQueriesContext(connection) as queries:
        assert client.get("/api/v1/quota/").status_code == 200
    assert ApiToken.objects.get().last_used_at == first_use


def test_an_expired_token_is_refused_even_from_the_cache(person):
    token = ApiToken.objects.create(user=person, name="short", expiry=timedelta(hours=1))[1]
    client = _client(token)
    assert client.get("/api/v1/quota/").status_code == 200
    ApiToken.objects.update(expiry=timezone.now() - timedelta(seconds=1))
    cached_user, _, verified = cache.get(_cache_key(token_digest(token)))
    cache.set(_cache_key(token_digest(token)), (cached_user, timezone.now(), verified), 60)
    assert client.get("/api/v1/quota/").status_code == 401
    cache.clear()
    assert client.get("/api/v1/quota/").status_code == 401


def test_a_deactivated_user_is_refused_at_once(token, person):
    client = _client(token)
    assert client.get("/api/v1/quota/").status_code == 200
    person.is_active = False
    person.save()
    assert client.get("/api/v1/quota/").status_code == 401


def test_a_deleted_token_is_refused_at_once(token):
    client = _client(token)
    assert client.get("/api/v1/quota/").status_code == 200
    ApiToken.objects.get().delete()
    assert client.get("/api/v1/quota/").status_code == 401


def test_a_staff_flag_taken_away_applies_at_once(person):
    person.is_staff = True
    person.save()
    client = _client(api_token(person))
    assert client.get("/api/v1/audit/").status_code == 200
    person.is_staff = False
    person.save()
    assert client.get("/api/v1/audit/").status_code == 403


def test_a_staff_token_stops_working_at_once_when_mfa_is_turned_off(person):
    person.is_staff = True
    person.save()
    client = _client(api_token(person))
    assert client.get("/api/v1/audit/").status_code == 200
    person.authenticator_set.all().delete()
    assert client.get("/api/v1/audit/").status_code == 401


def test_an_unknown_token_is_refused():
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION="Token " + "0" * 40)
    assert client.get("/api/v1/quota/").status_code == 401
