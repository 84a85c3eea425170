"""Who is asking: the client's address comes from the proxies of ours only (TRUSTED_PROXY_COUNT).

The sign-in limits (allauth), the API throttles (DRF) and the audit rows count by the same
address. Without a proxy a forged ``X-Forwarded-For`` is ignored; behind one proxy (the
compose file's nginx, which appends the address it saw) the rightmost entry is the client and
whatever the client wrote left of it changes nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from allauth.account.adapter import get_adapter
from django.conf import settings as live_settings
from django.test import Client, RequestFactory
from rest_framework.test import APIClient

from core.audit.models import AuditEvent
from core.http import client_address

pytestmark = pytest.mark.django_db

REPO = Path(__file__).resolve().parents[2]
NGINX = "10.0.0.2"  # the proxy's address, as the web server sees every request behind it
ALICE_AT = "198.51.100.1"
BOB_AT = "198.51.100.2"
FORGED = "203.0.113.9"


@pytest.fixture
def proxies(settings):
    """Sets the one count the deployment configures; allauth's follows it as in settings.py."""

    def set_count(count: int) -> None:
        settings.TRUSTED_PROXY_COUNT = count
        settings.ALLAUTH_TRUSTED_PROXY_COUNT = count

    return set_count


def _client(remote: str, forwarded: str | None = None) -> Client:
    if forwarded is None:
        return Client(REMOTE_ADDR=remote)
    return Client(REMOTE_ADDR=remote, HTTP_X_FORWARDED_FOR=forwarded)


def _failed_sign_in(client: Client) -> int:
    return client.post("/accounts/login/", {"login": "alice", "password": "no"}).status_code


def _failure_ips() -> list[str]:
    rows = AuditEvent.objects.filter(action="account.sign_in_failed").order_by("pk")
    return [str(ip) for ip in rows.values_list("ip", flat=True)]


def test_without_a_proxy_a_forged_forwarded_for_is_ignored(owner, settings, proxies):
    proxies(0)
    settings.ACCOUNT_RATE_LIMITS = {"login_failed": "2/m/ip"}
    # One client inventing a new address for each try: still one bucket, its own address.
    assert _failed_sign_in(_client(ALICE_AT, "192.0.2.1")) == 200
    assert _failed_sign_in(_client(ALICE_AT, "192.0.2.2")) == 200
    refused = _client(ALICE_AT, "192.0.2.3").post(
        "/accounts/login/", {"login": "alice", "password": "correct horse battery"}
    )
    assert b"Too many failed login attempts" in refused.content
    assert _failure_ips() == [ALICE_AT, ALICE_AT]


def test_behind_one_proxy_each_client_has_its_own_sign_in_limit_and_audit_ip(
    owner, settings, proxies
):
    proxies(1)
    settings.ACCOUNT_RATE_LIMITS = {"login_failed": "2/m/ip"}
    for _ in range(2):
        _failed_sign_in(_client(NGINX, ALICE_AT))
    # Alice's bucket is full; Bob, behind the same proxy, still signs in.
    bob = _client(NGINX, BOB_AT).post(
        "/accounts/login/", {"login": "alice", "password": "correct horse battery"}
    )
    assert bob.status_code == 302
    assert _failure_ips() == [ALICE_AT, ALICE_AT]
    sign_in = AuditEvent.objects.get(action="account.sign_in")
    assert str(sign_in.ip) == BOB_AT


def test_behind_one_proxy_a_forged_leftmost_address_is_ignored(owner, settings, proxies):
    proxies(1)
    settings.ACCOUNT_RATE_LIMITS = {"login_failed": "2/m/ip"}
    # Alice writes a new address of her own each time; nginx appends the one it saw.
    for n in range(2):
        _failed_sign_in(_client(NGINX, f"192.0.2.{n}, {ALICE_AT}"))
    refused = _client(NGINX, f"{FORGED}, {ALICE_AT}").post(
        "/accounts/login/", {"login": "alice", "password": "correct horse battery"}
    )
    assert b"Too many failed login attempts" in refused.content
    assert _failure_ips() == [ALICE_AT, ALICE_AT]


def _anonymous_codes(client: APIClient, count: int) -> list[int]:
    return [client.get("/api/v1/runs/").status_code for _ in range(count)]


def test_without_a_proxy_the_api_throttle_ignores_a_forged_forwarded_for(settings, proxies):
    proxies(0)
    settings.API_THROTTLE_ANON = "2/minute"
    codes = [
        APIClient(REMOTE_ADDR=ALICE_AT, HTTP_X_FORWARDED_FOR=f"192.0.2.{n}").get("/api/v1/runs/")
        for n in range(3)
    ]
    assert [answer.status_code for answer in codes] == [401, 401, 429]


def test_behind_one_proxy_the_api_throttle_counts_per_client(settings, proxies):
    proxies(1)
    settings.API_THROTTLE_ANON = "2/minute"
    alice = [
        APIClient(REMOTE_ADDR=NGINX, HTTP_X_FORWARDED_FOR=f"192.0.2.{n}, {ALICE_AT}")
        for n in range(3)
    ]
    assert [c.get("/api/v1/runs/").status_code for c in alice] == [401, 401, 429]
    bob = APIClient(REMOTE_ADDR=NGINX, HTTP_X_FORWARDED_FOR=BOB_AT)
    assert _anonymous_codes(bob, 1) == [401]


@pytest.mark.parametrize(
    ("count", "remote", "forwarded", "client"),
    [
        (0, ALICE_AT, None, ALICE_AT),
        (0, ALICE_AT, FORGED, ALICE_AT),
        (1, NGINX, None, NGINX),
        (1, NGINX, ALICE_AT, ALICE_AT),
        (1, NGINX, f"{FORGED}, {ALICE_AT}", ALICE_AT),
        (1, NGINX, f"{FORGED},{ALICE_AT}", ALICE_AT),
        (2, NGINX, f"{FORGED}, {ALICE_AT}, 10.0.0.1", ALICE_AT),
        (1, NGINX, "2001:db8::1", "2001:db8::1"),
    ],
)
def test_allauth_and_the_portal_name_the_same_client(
    settings, proxies, count, remote, forwarded, client
):
    """allauth reads its own copy of the rule (ALLAUTH_TRUSTED_PROXY_COUNT): same cases."""
    proxies(count)
    extra: dict[str, Any] = {"REMOTE_ADDR": remote}
    if forwarded is not None:
        extra["HTTP_X_FORWARDED_FOR"] = forwarded
    request = RequestFactory().get("/", **extra)
    assert client_address(request) == client
    assert get_adapter(request).get_client_ip(request) == client


def test_the_settings_give_one_count_to_allauth_and_drf():
    assert live_settings.ALLAUTH_TRUSTED_PROXY_COUNT == live_settings.TRUSTED_PROXY_COUNT
    assert live_settings.REST_FRAMEWORK["NUM_PROXIES"] == live_settings.TRUSTED_PROXY_COUNT


def test_the_compose_profile_counts_its_nginx_and_no_server_rewrites_the_address():
    compose = yaml.safe_load((REPO / "docker-compose.yml").read_text())
    assert compose["x-portal"]["environment"]["TRUSTED_PROXY_COUNT"] == "1"
    streams = compose["services"]["streams"]["command"]
    assert "--no-proxy-headers" in streams
    assert "--forwarded-allow-ips" not in streams
    nginx = (REPO / "deploy" / "nginx.conf").read_text()
    assert nginx.count("X-Forwarded-For $proxy_add_x_forwarded_for") == 2
