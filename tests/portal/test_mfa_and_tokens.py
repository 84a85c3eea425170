"""Staff need MFA before robot control, approvals and the admin site; API tokens made,
used, revoked; sign-ins audited and rate limited (core/accounts)."""

from __future__ import annotations

import importlib
import io
import secrets

import pytest
from django.apps import apps as django_apps
from django.core.management import CommandError, call_command
from django.db import connection
from rest_framework.test import APIClient

from core.accounts.models import ApiToken
from core.audit.models import AuditEvent
from tests.conftest import sign_in_with_second_factor
from tests.factories import MobileResourceFactory, UserFactory, api_token, mfa_on, totp_code

pytestmark = pytest.mark.django_db

PASSWORD = "correct horse battery"
STAFF_PAGES = ("/robot/mobile-1/", "/approvals/", "/admin/", "/admin/accounts/user/")


@pytest.fixture
def staff_without_mfa():
    MobileResourceFactory(name="mobile-1")
    return UserFactory(username="sam", is_staff=True, is_superuser=True, mfa=False)


def _token_client(token: str) -> APIClient:
    client = APIClient()
    client.credentials(HTTP_AUTHORIZATION=f"Token {token}")
    return client


def test_staff_without_mfa_are_sent_to_set_it_up_before_any_staff_page(client, staff_without_mfa):
    client.force_login(staff_without_mfa)
    for path in STAFF_PAGES:
        response = client.get(path)
        if path.startswith("/admin/"):  # through the admin's login, which sends on
            assert response["Location"].startswith("/admin/login/"), path
            response = client.get(response["Location"])
        assert response.status_code == 302, path
        assert response["Location"].startswith("/accounts/2fa/totp/activate/?next="), path
    # Their own pages stay open.
    assert client.get("/").status_code == 200


def test_staff_with_mfa_reach_the_staff_pages(client, staff_without_mfa):
    mfa_on(staff_without_mfa)
    sign_in_with_second_factor(client, staff_without_mfa)
    for path in ("/approvals/", "/admin/"):
        assert client.get(path).status_code == 200, path


def test_the_robot_and_approval_api_refuse_a_staff_session_without_mfa(staff_without_mfa):
    api = APIClient()
    api.force_login(staff_without_mfa)
    for path in ("/api/v1/resources/mobile-1/robot/", "/api/v1/resources/mobile-1/robot/logs/x/"):
        response = api.get(path)
        assert response.status_code == 403, path
        assert "second factor" in response.json()["detail"]
    assert api.post("/api/v1/reservations/1/decision/", {}, format="json").status_code == 403


def test_a_staff_account_gets_no_token_without_mfa(client, staff_without_mfa):
    client.force_login(staff_without_mfa)
    response = client.post("/account/tokens/", {"name": "laptop"})
    assert b"two-factor authentication on" in response.content
    assert not ApiToken.objects.exists()
    # Nor a token made behind the page's back: it is refused while the account has no MFA.
    token = ApiToken.objects.create(user=staff_without_mfa, name="sneaked")[1]
    assert _token_client(token).get("/api/v1/me/").status_code == 401


def test_a_user_makes_a_token_on_the_page_sees_it_once_and_revokes_it(client, owner):
    client.force_login(owner)
    made = client.post("/account/tokens/", {"name": "laptop", "expires_in_days": "30"}, follow=True)
    token = made.context["created"]
    assert token.startswith("amz_")
    stored = ApiToken.objects.get()
    assert (stored.name, stored.user) == ("laptop", owner)
    assert stored.expiry is not None
    assert _token_client(token).get("/api/v1/me/").json()["username"] == "alice"
    listed = client.get("/account/tokens/")
    assert token.encode() not in listed.content  # shown once
    assert b"laptop" in listed.content
    client.post("/account/tokens/", {"revoke": stored.digest})
    assert not ApiToken.objects.exists()
    assert _token_client(token).get("/api/v1/me/").status_code == 401
    actions = list(AuditEvent.objects.order_by("pk").values_list("action", flat=True))
    assert actions[-2:] == ["api_token.create", "api_token.revoke"]


def test_a_token_form_with_bad_input_changes_nothing(client, owner):
    client.force_login(owner)
    response = client.post("/account/tokens/", {"name": " ", "expires_in_days": "0"})
    assert response.context["created"] is None
    assert set(response.context["form"].errors) == {"name", "expires_in_days"}
    assert not ApiToken.objects.exists()


def test_no_one_revokes_anothers_token(client, owner, other):
    theirs = ApiToken.objects.create(user=other, name="theirs")[0]
    client.force_login(owner)
    client.post("/account/tokens/", {"revoke": theirs.digest})
    assert ApiToken.objects.filter(pk=theirs.pk).exists()


def test_sign_in_for_a_token_with_password_and_mfa_code(owner):
    secret = mfa_on(owner)
    api = APIClient()
    body = {"username": "alice", "password": PASSWORD, "name": "cli"}
    asked = api.post("/api/v1/auth/token/", body, format="json")
    assert asked.status_code == 400
    assert asked.json()["error"] == "mfa_required"
    wrong = api.post("/api/v1/auth/token/", {**body, "code": "000000"}, format="json")
    assert wrong.json()["error"] == "sign_in_failed"
    assert not ApiToken.objects.exists()
    made = api.post("/api/v1/auth/token/", {**body, "code": totp_code(secret)}, format="json")
    assert made.status_code == 201, made.content
    token = made.json()["token"]
    signed_in = _token_client(token)
    assert signed_in.get("/api/v1/me/").json()["username"] == "alice"
    assert signed_in.delete("/api/v1/auth/token/").status_code == 204
    assert signed_in.get("/api/v1/me/").status_code == 401
    assert AuditEvent.objects.filter(action="account.mfa_failed", actor=owner).exists()


def test_a_wrong_password_gets_no_token_and_is_audited(owner):
    response = APIClient().post(
        "/api/v1/auth/token/",
        {"username": "alice", "password": "nope", "name": "cli"},
        format="json",
    )
    assert response.status_code == 400
    assert response.json()["error"] == "sign_in_failed"
    assert not ApiToken.objects.exists()
    failed = AuditEvent.objects.get(action="account.sign_in_failed")
    assert (failed.actor, failed.data["username"]) == (owner, "alice")


def test_page_sign_ins_and_failures_are_audited(client, owner):
    client.post("/accounts/login/", {"login": "alice", "password": "nope"})
    client.post("/accounts/login/", {"login": "alice", "password": PASSWORD})
    actions = list(
        AuditEvent.objects.filter(actor=owner).order_by("pk").values_list("action", flat=True)
    )
    assert actions == ["account.sign_in_failed", "account.sign_in"]


def test_sign_in_attempts_are_rate_limited_with_429(client, owner, settings):
    settings.ACCOUNT_RATE_LIMITS = {"login": "2/m/ip"}
    for _ in range(2):
        assert (
            client.post("/accounts/login/", {"login": "alice", "password": "no"}).status_code == 200
        )
    assert (
        client.post("/accounts/login/", {"login": "alice", "password": PASSWORD}).status_code == 429
    )
    api = APIClient().post(
        "/api/v1/auth/token/",
        {"username": "alice", "password": PASSWORD, "name": "c"},
        format="json",
    )
    assert api.status_code == 429
    # As every throttle's answer, and as the API's description says: when to try again.
    assert api["Retry-After"] == "60", api.headers
    assert api.json()["error"] == "throttled"
    assert not ApiToken.objects.exists()


def test_failed_sign_ins_of_one_account_are_limited(client, owner, settings):
    settings.ACCOUNT_RATE_LIMITS = {"login_failed": "2/m/ip"}
    for _ in range(2):
        client.post("/accounts/login/", {"login": "alice", "password": "no"})
    refused = client.post("/accounts/login/", {"login": "alice", "password": PASSWORD})
    assert b"Too many failed login attempts" in refused.content
    assert "_auth_user_id" not in client.session
    api = APIClient().post(
        "/api/v1/auth/token/",
        {"username": "alice", "password": PASSWORD, "name": "c"},
        format="json",
    )
    assert api.status_code == 429


def test_password_reset_is_rate_limited(client, owner, settings):
    settings.ACCOUNT_RATE_LIMITS = {"reset_password": "1/m/ip"}
    body = {"email": "alice@example.org"}
    assert client.post("/accounts/password/reset/", body).status_code == 302
    assert client.post("/accounts/password/reset/", body).status_code == 429


def test_the_api_token_command_prints_a_working_token(owner):
    out = io.StringIO()
    call_command(
        "api_token", "create", "alice", "--name", "ops", "--expires-in-days", "7", stdout=out
    )
    token = out.getvalue().strip()
    assert _token_client(token).get("/api/v1/me/").json()["username"] == "alice"
    assert ApiToken.objects.get().name == "ops"
    with pytest.raises(CommandError, match="no user"):
        call_command("api_token", "create", "nobody", stdout=out)
    with pytest.raises(CommandError, match="1 to 3650 days"):
        call_command("api_token", "create", "alice", "--expires-in-days", "0", stdout=out)


def test_tokens_of_drf_authtoken_are_copied_as_digests_and_keep_working(owner):
    key = secrets.token_hex(20)
    with connection.cursor() as cursor:
        cursor.execute(
            "CREATE TABLE authtoken_token (key varchar(40) PRIMARY KEY, "
            "created timestamp with time zone NOT NULL, user_id bigint NOT NULL)"
        )
        cursor.execute(
            "INSERT INTO authtoken_token VALUES (%s, now() - interval '1 day', %s)",
            [key, owner.pk],
        )
    migration = importlib.import_module("core.accounts.migrations.0003_api_tokens_from_authtoken")
    with connection.schema_editor() as editor:
        migration.copy_tokens(django_apps, editor)
    assert "authtoken_token" not in connection.introspection.table_names()
    copied = ApiToken.objects.get()
    assert key not in copied.digest
    assert copied.expiry is None
    assert _token_client(key).get("/api/v1/me/").json()["username"] == "alice"


def test_an_admin_sees_and_revokes_anyones_token_in_the_admin(client, owner, admin_user):
    token = api_token(owner, name="laptop")
    stored = ApiToken.objects.get(user=owner)
    sign_in_with_second_factor(client, admin_user)
    listed = client.get("/admin/accounts/apitoken/")
    assert b"laptop" in listed.content
    assert token.encode() not in listed.content
    assert _token_client(token).get("/api/v1/me/").status_code == 200
    client.post(
        "/admin/accounts/apitoken/",
        {"action": "delete_selected", "_selected_action": [stored.pk], "post": "yes"},
    )
    assert not ApiToken.objects.filter(user=owner).exists()
    assert _token_client(token).get("/api/v1/me/").status_code == 401
