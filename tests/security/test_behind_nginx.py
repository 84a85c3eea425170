"""The compose file's nginx in front of the web server, as processes: who is asking.

``deploy/nginx.conf`` as the proxy container mounts it (its upstreams pointed at this test's
servers, its access log at a file of the test's), in front of the real web server with
``TRUSTED_PROXY_COUNT=1``. Clients come from addresses of their own on the loopback network
(each binds its own 127.x.y.z), as clients of a real deployment come from theirs: the
sign-in limit and the audit rows are per client, not per proxy, and a forged
``X-Forwarded-For`` changes nothing. nginx is Debian's binary, unpacked by the Makefile
(``make test`` gets it; never installed as a service).
"""

from __future__ import annotations

import random
import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import requests
from requests.adapters import HTTPAdapter

from bench.stack import REPO, Proc, free_port, wait_http, wait_until
from bookings.calendar import calendar_feed_renew
from core.audit.models import AuditEvent
from tests.factories import UserFactory
from tests.integration.live import live_portal

pytestmark = [pytest.mark.integration, pytest.mark.django_db(transaction=True)]

NGINX_CONF = REPO / "deploy" / "nginx.conf"
# The allauth limit on failed sign-ins per client address (portal/settings.py).
FAILED_SIGN_INS_PER_ADDRESS = 10
PASSWORD = "correct horse battery"


def _nginx_binary() -> str:
    unpacked = REPO / "var" / "tools" / "nginx" / "usr" / "sbin" / "nginx"
    found = str(unpacked) if unpacked.exists() else shutil.which("nginx")
    assert found, "nginx is missing: `make test` unpacks it into var/tools/nginx"
    return found


def _proxy_config(scratch: Path, *, listen_port: int, web_port: int) -> Path:
    """The deployed server block, pointed at this test's servers, inside the ``http`` block
    the nginx image's own nginx.conf gives it."""
    server = NGINX_CONF.read_text()
    replacements = [
        ("server web:8000;", f"server 127.0.0.1:{web_port};"),
        # The streams are not part of this test; the upstream must still name an address.
        ("server streams:8001;", f"server 127.0.0.1:{web_port};"),
        ("listen 80;", f"listen 127.0.0.1:{listen_port};"),
        ("/var/log/nginx/access.log", str(scratch / "access.log")),
    ]
    for old, new in replacements:
        assert old in server, f"deploy/nginx.conf no longer has {old!r}: update this test"
        server = server.replace(old, new)
    (scratch / "amazing.conf").write_text(server)
    main = scratch / "nginx.conf"
    temp = scratch / "temp"
    temp.mkdir()
    main.write_text(
        f"""daemon off;
worker_processes 1;
pid {scratch / "nginx.pid"};
error_log stderr warn;
events {{ worker_connections 256; }}
http {{
    client_body_temp_path {temp};
    proxy_temp_path {temp};
    fastcgi_temp_path {temp};
    uwsgi_temp_path {temp};
    scgi_temp_path {temp};
    include {scratch / "amazing.conf"};
}}
"""
    )
    return main


class _FromAddress(HTTPAdapter):
    """Connections from one source address (a client of its own on the loopback network)."""

    def __init__(self, address: str) -> None:
        self.address = address
        super().__init__()

    def init_poolmanager(self, *args: Any, **kwargs: Any) -> None:
        kwargs["source_address"] = (self.address, 0)
        super().init_poolmanager(*args, **kwargs)


def _client_at(address: str) -> requests.Session:
    session = requests.Session()
    adapter = _FromAddress(address)
    session.mount("http://", adapter)
    return session


def _addresses(count: int) -> list[str]:
    """Loopback addresses no other run of this test used a minute ago (the limits count per
    address in the cache, which outlives a test)."""
    picked = random.sample(range(2, 250 * 250), count)
    return [f"127.{200 + n // 250 % 50}.{n % 250}.{1 + n % 200}" for n in picked]


def _sign_in(
    client: requests.Session, base: str, login: str, password: str, forged: str | None = None
) -> requests.Response:
    page = client.get(f"{base}/accounts/login/", timeout=30)
    assert page.status_code == 200, page.status_code
    match = re.search(r'name="csrfmiddlewaretoken" value="([^"]+)"', page.text)
    assert match, "the sign-in form has no CSRF token"
    headers = {"Referer": f"{base}/accounts/login/"}
    if forged is not None:
        headers["X-Forwarded-For"] = forged
    return client.post(
        f"{base}/accounts/login/",
        data={"csrfmiddlewaretoken": match.group(1), "login": login, "password": password},
        headers=headers,
        allow_redirects=False,
        timeout=30,
    )


@pytest.fixture
def behind_nginx(tmp_path) -> Iterator[dict[str, Any]]:
    with live_portal(tmp_path, TRUSTED_PROXY_COUNT="1", SIGN_IN_LIMITS="1") as portal:
        web_port = int(portal.url.rsplit(":", 1)[1])
        listen_port = free_port()
        scratch = tmp_path / "nginx"
        scratch.mkdir()
        config = _proxy_config(scratch, listen_port=listen_port, web_port=web_port)
        nginx = _nginx_binary()
        checked = subprocess.run(
            [nginx, "-t", "-c", str(config), "-p", str(scratch)],
            capture_output=True,
            text=True,
            timeout=30,
        )
        assert checked.returncode == 0, checked.stderr
        proxy = Proc("nginx", [nginx, "-c", str(config), "-p", str(scratch)], {})
        try:
            url = f"http://127.0.0.1:{listen_port}"
            wait_http(f"{url}/healthz", 30, [proxy, *portal.procs], server=proxy)
            yield {"url": url, "access_log": scratch / "access.log", "portal": portal}
        finally:
            proxy.stop()


def test_behind_nginx_each_client_has_its_own_sign_in_limit_and_a_forged_address_changes_nothing(
    behind_nginx,
):
    url = behind_nginx["url"]
    alice = UserFactory(username="alice-nginx", password=PASSWORD)
    bob = UserFactory(username="bob-nginx", password=PASSWORD)
    mallory_at, bob_at = _addresses(2)
    mallory = _client_at(mallory_at)
    # Mallory guesses, a new invented address in front of each guess, each for another name
    # (the per-name limit is not what this test is about).
    for k in range(FAILED_SIGN_INS_PER_ADDRESS):
        guess = _sign_in(mallory, url, f"nobody-{k}", "guess", forged=f"192.0.2.{k + 1}")
        assert guess.status_code == 200, guess.status_code
        assert "Too many failed login attempts" not in guess.text
    # Her address is spent, whatever she writes in the header, even with a right password.
    refused = _sign_in(mallory, url, alice.username, PASSWORD, forged="192.0.2.250")
    assert "Too many failed login attempts" in refused.text
    # Bob, behind the same proxy, is another client: he signs in.
    signed_in = _sign_in(_client_at(bob_at), url, bob.username, PASSWORD)
    assert signed_in.status_code == 302, signed_in.text[-500:]

    failed_ips = {
        str(ip)
        for ip in AuditEvent.objects.filter(action="account.sign_in_failed").values_list(
            "ip", flat=True
        )
    }
    assert failed_ips == {mallory_at}, "every failed sign-in is Mallory's own address"
    bob_ips = [
        str(ip)
        for ip in AuditEvent.objects.filter(action="account.sign_in", actor=bob).values_list(
            "ip", flat=True
        )
    ]
    assert bob_ips == [bob_at]


def test_behind_nginx_a_calendar_feeds_secret_never_reaches_the_access_log(behind_nginx):
    url = behind_nginx["url"]
    token = calendar_feed_renew(user=UserFactory(username="carol-nginx"))
    answer = requests.get(f"{url}/calendar/feed/{token}.ics", timeout=30)
    assert answer.status_code == 200, answer.status_code
    assert answer.text.startswith("BEGIN:VCALENDAR")
    proxy_log = behind_nginx["access_log"]

    def feed_lines() -> list[str]:
        text = proxy_log.read_text() if proxy_log.exists() else ""
        return [line for line in text.splitlines() if "/calendar/feed/" in line]

    # nginx writes its line as the answer leaves: the file is read until the line is there.
    lines = wait_until("nginx's access line for the feed", feed_lines, 10)
    assert token not in proxy_log.read_text()
    assert 'GET /calendar/feed/[redacted].ics HTTP/1.1" 200' in lines[0], lines
