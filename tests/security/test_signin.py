"""The sign-in door and the guard of every staff action, attacked from outside.

The table of staff actions is generated from the URL configuration: a route is a staff action
when its page is ``staff_required``, its API view has ``StaffVerified``, or it is the admin
site's; every other route is listed in ``NOT_STAFF`` with what guards it instead. A new route
that is in neither fails ``test_every_route_is_a_staff_action_or_listed_as_not_one``.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterator
from datetime import timedelta

import pytest
from allauth.account.authentication import AUTHENTICATION_METHODS_SESSION_KEY
from allauth.mfa.models import Authenticator
from allauth.mfa.recovery_codes.internal.auth import RecoveryCodes
from django.db import close_old_connections, connection
from django.test import Client
from django.urls import URLPattern, URLResolver, get_resolver
from django.utils import timezone
from rest_framework.test import APIClient

from core.accounts.mfa import mfa_code_check
from core.accounts.models import ApiToken
from core.accounts.permissions import StaffVerified
from core.accounts.staff import ADMINS_ONLY, SIGN_IN_WITH_SECOND_FACTOR
from core.audit.models import AuditEvent
from tests.factories import MobileResourceFactory, UserFactory, totp_code, totp_secret_of

pytestmark = pytest.mark.django_db

PASSWORD = "correct horse battery"

# Routes that are not staff actions, and what guards them instead.
NOT_STAFF = {
    # Public or their own guard.
    "healthz", "metrics", "schema", "swagger-ui", None,  # None: the API's JSON 404
    "inbound-nodes", "inbound-leases",  # the scheduler account's permission
    "ical-personal", "ical-resource",  # a feed's secret address; a plain user's view
    # allauth: the sign-in door itself and one's own account.
    "account_login", "account_logout", "account_inactive", "account_signup",
    "account_reauthenticate", "account_email", "account_email_verification_sent",
    "account_change_password", "account_set_password", "account_reset_password",
    "account_confirm_login_code", "account_confirm_email",
    "account_reset_password_from_key_done", "account_reset_password_from_key",
    "account_reset_password_done", "mfa_index", "mfa_authenticate", "mfa_reauthenticate",
    "mfa_activate_totp", "mfa_deactivate_totp", "mfa_view_recovery_codes",
    "mfa_generate_recovery_codes", "mfa_download_recovery_codes",
    # Any signed-in user; a staff branch inside is decided by the service with the door's
    # mark (User.is_testbed_admin), attacked in STAFF_BY_SERVICE and the services' tests.
    "api-experiments", "api-experiment", "api-runs", "api-run", "api-run-samples",
    "api-run-samples-csv", "api-run-samples-json", "api-run-analysis", "api-run-again",
    "api-run-package", "api-reservations", "api-reservations-check", "api-reservation",
    "api-reservation-attach", "api-quota-check", "api-rail", "api-resources",
    "api-resource-availability", "api-reservations-busy", "api-quota", "api-blackouts",
    "api-me", "api-token", "api-events", "api-webhooks", "api-webhook", "api-webhook-resume",
    "api-webhook-test", "api-webhook-deliveries", "api-run-measurements", "api-run-measurement",
    "api-run-samples-parquet", "api-run-measurement-parquet",
    "home", "experiment-new", "experiment-edit", "dry-run-start", "dry-run", "dry-run-data",
    "book", "reservation-cancel", "reservation-attach", "my-runs", "runs-package",
    "runs-compare", "run", "run-data", "run-csv", "run-json", "run-package", "run-again",
    "calendar", "timeline", "calendar-events", "calendar-feeds", "api-tokens", "rail-json",
    "webhooks", "webhook", "webhook-test", "webhook-resume", "webhook-delete",
    "run-measurement-add", "run-measurement-series", "run-measurement-offset",
    "run-measurement-delete",
    # The queue and campaigns: one's own requests (an admin's branch by the door's mark);
    # pausing, resuming and reordering the queue are staff actions (StaffVerified).
    "api-queue", "api-queue-state", "api-queue-request", "queue", "queue-cancel",
    "api-campaigns", "api-campaign", "api-campaign-pause", "api-campaign-resume",
    "api-campaign-cancel", "api-campaign-results", "api-campaign-package", "campaign",
    "campaign-pause", "campaign-resume", "campaign-cancel", "campaign-package",
    # Live streams (ASGI only): robot_stream reads the door's mark, tests/web/test_live.py.
    "live-run", "live-robot", "live-calendar",
    "logout",  # the admin's sign-out
}  # fmt: skip

# Staff actions decided inside a service (the door's mark handed on), tried the same way.
STAFF_BY_SERVICE = [
    (
        "post",
        "/api/v1/blackouts/",
        lambda: {
            "all_resources": True,
            "start_at": (timezone.now() + timedelta(days=1)).isoformat(),
            "end_at": (timezone.now() + timedelta(days=1, hours=1)).isoformat(),
            "reason": "maintenance",
        },
    ),
    # A webhook that takes staff's events (robots, the scheduler link).
    ("post", "/api/v1/webhooks/", lambda: {"url": "http://127.0.0.1:9/", "staff_events": True}),
]

ARGUMENTS = {"pk": "1", "name": "mobile-1", "day": "2026-01-01"}
METHODS = ("get", "post", "put", "patch", "delete")


def _walk(patterns: list, prefix: str = "", admin: bool = False) -> Iterator[tuple]:
    for p in patterns:
        if isinstance(p, URLResolver):
            yield from _walk(
                p.url_patterns, prefix + str(p.pattern), admin or p.namespace == "admin"
            )
        elif isinstance(p, URLPattern):
            yield prefix + str(p.pattern), p.name, p.callback, admin


def _is_staff(callback: object, admin: bool, name: str | None = None) -> bool:
    cls = getattr(callback, "cls", None)
    return (
        (admin and name != "logout")
        or bool(getattr(callback, "staff_only", False))
        or StaffVerified in getattr(cls, "permission_classes", ())
    )


def _path(route: str) -> str | None:
    """The route with sample arguments; None for a regular expression with groups (the admin's
    object pages: its guard is the site's, tried on the pages without arguments)."""
    names = re.findall(r"<(?:\w+:)?(\w+)>", route)
    if "(?P<" in route or (route.startswith("admin/") and set(names) - set(ARGUMENTS)):
        return None
    path = re.sub(r"<(?:\w+:)?(\w+)>", lambda m: ARGUMENTS[m.group(1)], route)
    return "/" + path.replace("^", "").replace("$", "")


def _methods(callback: object) -> list[str]:
    cls = getattr(callback, "cls", None)
    if cls is None:
        return ["get", "post"]
    return [m for m in METHODS if hasattr(cls, m)]


def staff_actions() -> list[tuple[str, str]]:
    found = []
    for route, _name, callback, admin in _walk(get_resolver().url_patterns):
        path = _path(route) if _is_staff(callback, admin, _name) else None
        if path is not None:
            found += [(method, path) for method in _methods(callback)]
    return found


STAFF_ACTIONS = staff_actions()


def test_every_route_is_a_staff_action_or_listed_as_not_one():
    unlisted = [
        (route, name)
        for route, name, callback, admin in _walk(get_resolver().url_patterns)
        if not _is_staff(callback, admin, name) and name not in NOT_STAFF
    ]
    assert not unlisted, f"a new route: make it a staff action or list it in NOT_STAFF: {unlisted}"
    assert len(STAFF_ACTIONS) > 20
    assert ("post", "/api/v1/resources/mobile-1/robot/control/") in STAFF_ACTIONS
    assert ("get", "/admin/") in STAFF_ACTIONS


def _state() -> tuple:
    """What a staff action changes: the audit log (every staff service writes it) and the
    robots' service state, tokens and policies."""
    from bookings.models import Blackout, QuotaPolicy, Resource

    return (
        AuditEvent.objects.count(),
        list(Resource.objects.values_list("name", "enabled", "hold_reason")),
        Blackout.objects.count(),
        QuotaPolicy.objects.count(),
        ApiToken.objects.count(),
    )


def _refused(response, *, staff: bool) -> bool:
    if response.status_code in (401, 403):
        return True
    if response.status_code == 302:
        where = response["Location"]
        return where.startswith(("/admin/login/", "/accounts/")) and (
            not staff or "2fa" in where or "/admin/login/" in where
        )
    return False


def sign_in_with_password(client, user):
    """``client`` signed in as ``user`` just now, with its password alone (as allauth records
    it: recent enough to set up a factor without signing in again)."""
    client.force_login(user)
    session = client.session
    session[AUTHENTICATION_METHODS_SESSION_KEY] = [
        {"method": "password", "at": time.time(), "reauthenticated": True}
    ]
    session["account_authentication_methods_user"] = str(user.pk)
    session.save()
    return client


@pytest.fixture
def staff_password_only(db):
    """A staff account with TOTP, signed in with its password alone (no ``mfa`` record)."""
    staff = UserFactory(username="sam", is_staff=True, is_superuser=True)
    return sign_in_with_password(APIClient(), staff)


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("method", "path"), STAFF_ACTIONS + [(m, p) for m, p, _ in STAFF_BY_SERVICE]
)
def test_a_staff_action_refuses_staff_without_the_second_factor_and_plain_users(
    method, path, staff_password_only, api
):
    MobileResourceFactory()
    body = next((b() for m, p, b in STAFF_BY_SERVICE if (m, p) == (method, path)), {})
    before = _state()
    for client, staff in ((staff_password_only, True), (api, False)):
        response = getattr(client, method)(path, body, format="json")
        if (method, path) in [(m, p) for m, p, _ in STAFF_BY_SERVICE]:
            refused = response.status_code == 403
        else:
            refused = _refused(response, staff=staff)
        assert refused, (method, path, staff, response.status_code)
        assert _state() == before, (method, path, staff)


# Driving and stopping reach the agent: that staff with the second factor pass their guard is
# shown by tests/runs/test_robot.py and tests/security/test_stop.py against a real agent.
DRIVES_THE_AGENT = ("/robot/control/", "/robot/stop/")


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("method", "path"),
    [
        (method, path)
        for method, path in STAFF_ACTIONS + [(m, p) for m, p, _ in STAFF_BY_SERVICE]
        if not path.endswith(DRIVES_THE_AGENT)
    ],
)
def test_a_staff_action_lets_staff_with_the_second_factor_pass(method, path, staff_verified_client):
    MobileResourceFactory()
    body = next((b() for m, p, b in STAFF_BY_SERVICE if (m, p) == (method, path)), {})
    # The robot's views call its agent, absent here: a 500 from there is past the guard.
    staff_verified_client.raise_request_exception = False
    response = getattr(staff_verified_client, method)(path, body, format="json")
    # Past the guard: a 403 may still be the page's own rule (the admin adds no tokens).
    guard = (ADMINS_ONLY, SIGN_IN_WITH_SECOND_FACTOR)
    refused_by_guard = _refused(response, staff=True) and (
        response.status_code != 403 or any(m.encode() in response.content for m in guard)
    )
    assert not refused_by_guard, (method, path, response.status_code)


def test_the_admins_password_form_is_never_shown_nor_taken(db):
    """(a) A staff account with TOTP posts its password to the admin's login: no session."""
    staff = UserFactory(username="sam", is_staff=True, is_superuser=True)
    MobileResourceFactory()
    browser = Client()
    answer = browser.post("/admin/login/", {"username": "sam", "password": PASSWORD})
    assert answer.status_code == 302
    assert answer["Location"].startswith("/accounts/login/")
    assert "_auth_user_id" not in browser.session
    assert browser.get("/robot/mobile-1/").status_code == 302
    drive = APIClient(enforce_csrf_checks=True)
    drive.cookies = browser.cookies
    assert drive.post("/api/v1/resources/mobile-1/robot/control/", {}).status_code in (401, 403)
    browser.post("/account/tokens/", {"name": "laptop"})
    assert not ApiToken.objects.filter(user=staff).exists()


def test_a_password_only_session_of_staff_with_totp_gets_no_staff_power(staff_password_only):
    """(a) However it got a session without the second factor: no console, drive, token."""
    MobileResourceFactory()
    console = staff_password_only.get("/robot/mobile-1/")
    assert console.status_code == 302
    assert "2fa/reauthenticate" in console["Location"]
    drive = staff_password_only.post("/api/v1/resources/mobile-1/robot/control/", {}, format="json")
    assert drive.status_code == 403
    assert "second factor" in drive.json()["detail"]
    staff_password_only.post("/account/tokens/", {"name": "laptop"})
    assert not ApiToken.objects.exists()


def test_allauths_sign_in_with_totp_gives_the_staff_powers(db):
    """(d) The whole door: password, then the TOTP code (decrypted from its stored form)."""
    UserFactory(username="sam", is_staff=True, is_superuser=True)
    MobileResourceFactory()
    browser = Client()
    first = browser.post("/accounts/login/", {"login": "sam", "password": PASSWORD})
    assert first["Location"].startswith("/accounts/2fa/authenticate/")
    assert browser.get("/robot/mobile-1/").status_code == 302
    code = totp_code(totp_secret_of("sam") or "")
    second = browser.post("/accounts/2fa/authenticate/", {"code": code})
    assert second.status_code == 302
    assert browser.get("/robot/mobile-1/").status_code == 200
    assert browser.get("/admin/").status_code == 200


def test_a_staff_token_is_minted_only_with_the_second_factor_and_expires(
    staff_verified_client, admin_user, settings
):
    """(c) Minted from a verified session: expiring by default, shown in its own answer."""
    made = staff_verified_client.post("/account/tokens/", {"name": "laptop"})
    assert made.status_code == 200
    token = ApiToken.objects.get(user=admin_user)
    assert token.mfa_verified
    days = (token.expiry - timezone.now()).total_seconds() / 86400
    assert settings.STAFF_API_TOKEN_DAYS - 1 < days <= settings.STAFF_API_TOKEN_DAYS
    secret = re.search(
        rb'data-testid="new-token-value"[^>]*value="([^"]+)"', made.content
    ) or re.search(rb'value="(amz_[^"]+)"', made.content)
    assert secret is not None
    assert "no-store" in made["Cache-Control"]
    assert all(
        secret.group(1).decode() not in str(v) for v in staff_verified_client.session.values()
    )
    longer = staff_verified_client.post("/account/tokens/", {"name": "x", "expires_in_days": "365"})
    assert b"within" in longer.content
    assert ApiToken.objects.filter(user=admin_user).count() == 1
    with_token = APIClient()
    with_token.credentials(HTTP_AUTHORIZATION=f"Token {secret.group(1).decode()}")
    assert with_token.get("/api/v1/audit/").status_code == 200


def test_turning_mfa_off_revokes_the_staff_tokens(admin_user):
    """(c) The factor a token was minted with goes: so does the token."""
    from tests.factories import api_token

    secret = api_token(admin_user)
    with_token = APIClient()
    with_token.credentials(HTTP_AUTHORIZATION=f"Token {secret}")
    assert with_token.get("/api/v1/audit/").status_code == 200
    for authenticator in Authenticator.objects.filter(user=admin_user):
        authenticator.delete()
    assert not ApiToken.objects.filter(user=admin_user).exists()
    assert with_token.get("/api/v1/audit/").status_code == 401


def test_an_old_staff_token_minted_without_the_second_factor_has_no_staff_power(admin_user):
    """(c) A token from before (or of a user made staff later) acts as a plain user's."""
    _, secret = ApiToken.objects.create(user=admin_user, name="old")
    with_token = APIClient()
    with_token.credentials(HTTP_AUTHORIZATION=f"Token {secret}")
    assert with_token.get("/api/v1/me/").json()["is_admin"] is False
    assert with_token.get("/api/v1/audit/").status_code == 403


def test_mfa_secrets_are_stored_encrypted(admin_user):
    """(d) The database holds neither the TOTP secret nor the recovery seed in clear."""
    secret = totp_secret_of(admin_user.username)
    with connection.cursor() as cursor:
        cursor.execute(
            "SELECT data::text FROM mfa_authenticator WHERE user_id = %s", [admin_user.pk]
        )
        stored = " ".join(row[0] for row in cursor.fetchall())
    assert secret
    assert secret not in stored
    rc = Authenticator.objects.get(user=admin_user, type=Authenticator.Type.RECOVERY_CODES)
    seed = RecoveryCodes(rc).instance.data["seed"]
    assert seed.startswith("gAAAA")  # a Fernet token, not the hex seed


@pytest.mark.django_db(transaction=True)
def test_one_recovery_code_used_twice_at_once_passes_once(monkeypatch):
    """(e) Two checks of the same recovery code, forced to overlap: the first has taken the
    code and not yet committed when the second starts. The second must wait for the first's
    lock (seen in PostgreSQL's ``pg_blocking_pids``), then read the code as used. Without the
    transaction that holds the lock (``mfa_code_check``) nothing waits, and this fails."""
    staff = UserFactory(username="sam", is_staff=True, is_superuser=True)
    code = RecoveryCodes(
        Authenticator.objects.get(user=staff, type=Authenticator.Type.RECOVERY_CODES)
    ).get_unused_codes()[0]
    first_took_it = threading.Event()
    second_waited = threading.Event()
    backends: dict[str, int] = {}
    results: dict[str, bool] = {}
    record_usage = Authenticator.record_usage

    def record_then_hold(self: Authenticator) -> None:
        record_usage(self)
        if threading.current_thread().name == "first":
            # The code is marked used in this transaction, which stays open until the
            # second check is seen waiting.
            first_took_it.set()
            assert second_waited.wait(30), "the second check was never seen waiting"

    monkeypatch.setattr(Authenticator, "record_usage", record_then_hold)

    def use() -> None:
        name = threading.current_thread().name
        try:
            with connection.cursor() as cursor:
                cursor.execute("SELECT pg_backend_pid()")
                backends[name] = cursor.fetchone()[0]
            results[name] = mfa_code_check(staff, code) is not None
        finally:
            close_old_connections()

    first = threading.Thread(target=use, name="first")
    first.start()
    assert first_took_it.wait(30), "the first check never took the code"
    second = threading.Thread(target=use, name="second")
    second.start()
    try:
        deadline = time.monotonic() + 10
        waiting = False
        while not waiting and time.monotonic() < deadline:
            if "second" in backends:
                with connection.cursor() as cursor:
                    cursor.execute("SELECT pg_blocking_pids(%s)", [backends["second"]])
                    waiting = backends["first"] in cursor.fetchone()[0]
            if not waiting:
                time.sleep(0.05)
        assert waiting, "the second check did not wait for the first's lock on the code"
    finally:
        second_waited.set()
        first.join(timeout=30)
        second.join(timeout=30)
    assert results == {"first": True, "second": False}


def test_turning_mfa_on_ends_the_accounts_other_sessions(db, django_capture_on_commit_callbacks):
    """A password-only session (someone else's, perhaps) ends when MFA is turned on."""
    staff = UserFactory(username="sam", is_staff=True, is_superuser=True, mfa=False)
    staff.mfa_enrolment_allowed = True
    staff.save()
    other = Client()
    other.force_login(staff)
    mine = sign_in_with_password(Client(), staff)
    page = mine.get("/accounts/2fa/totp/activate/")
    assert page.status_code == 200, page.get("Location")
    secret = page.context["form"].secret
    with django_capture_on_commit_callbacks(execute=True):  # allauth signals after commit
        done = mine.post("/accounts/2fa/totp/activate/", {"code": totp_code(secret)})
    assert done.status_code == 302
    assert other.get("/").status_code == 302  # signed out
    assert mine.get("/").status_code == 200
    staff.refresh_from_db()
    assert not staff.mfa_enrolment_allowed


def test_a_staff_account_enrols_its_first_factor_only_with_an_admins_leave(db):
    staff = UserFactory(username="sam", is_staff=True, is_superuser=True, mfa=False)
    browser = sign_in_with_password(Client(), staff)
    page = browser.get("/accounts/2fa/totp/activate/")
    secret = page.context["form"].secret
    refused = browser.post("/accounts/2fa/totp/activate/", {"code": totp_code(secret)})
    assert refused.status_code == 200
    assert b"another admin" in refused.content
    assert not Authenticator.objects.filter(user=staff).exists()
