"""Settings come from the environment; production refuses to start without its secrets."""

from __future__ import annotations

import os
import re
import secrets
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CHECK = "import django; django.setup(); print('started')"
_NOT_INHERITED = ("DJANGO_", "AGENT_", "DATABASE_", "CELERY_", "REDIS_")


def _start(
    env_changes: dict[str, str], tmp_path: Path, check: str = CHECK
) -> subprocess.CompletedProcess[str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("DJANGO_", "AGENT_", "DATABASE_", "CELERY_", "REDIS_"))
    }
    env.update({"DJANGO_SETTINGS_MODULE": "portal.settings", "AMAZING_VAR_DIR": str(tmp_path)})
    env.update(env_changes)
    return subprocess.run(
        [sys.executable, "-c", check], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )


PRODUCTION = {
    "DJANGO_DEBUG": "0",
    "DJANGO_SECRET_KEY": "x" * 50,
    "DJANGO_ALLOWED_HOSTS": "amazing.example.org",
    "AGENT_TOKEN": "t" * 32,
}


@pytest.mark.parametrize("missing", ["DJANGO_SECRET_KEY", "DJANGO_ALLOWED_HOSTS"])
def test_production_refuses_to_start_without(missing, tmp_path):
    env = {k: v for k, v in PRODUCTION.items() if k != missing}
    result = _start(env, tmp_path)
    assert result.returncode != 0
    assert "ImproperlyConfigured" in result.stderr
    assert missing in result.stderr


def test_production_starts_with_its_settings_and_reads_secrets_from_files(tmp_path):
    secret = tmp_path / "secret"
    secret.write_text("s" * 50 + "\n")
    env = {k: v for k, v in PRODUCTION.items() if k != "DJANGO_SECRET_KEY"}
    env["DJANGO_SECRET_KEY_FILE"] = str(secret)
    result = _start(env, tmp_path)
    assert result.returncode == 0, result.stderr
    assert "started" in result.stdout


def test_secrets_are_read_as_given_even_starting_with_a_dollar(tmp_path):
    # Django's key generator draws from "$" among others; django-environ would read
    # "$name" as the value of the variable "name" (here none: no key at all).
    key, old = "$" + "k" * 49, "$" + "o" * 49
    env = dict(PRODUCTION, DJANGO_SECRET_KEY=key, DJANGO_SECRET_KEY_FALLBACKS=old, AGENT_TOKEN=key)
    check = (
        "import django; django.setup(); from django.conf import settings as s; "
        "print(s.SECRET_KEY, s.SECRET_KEY_FALLBACKS, s.AGENT_TOKEN)"
    )
    result = _start(env, tmp_path, check)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [key, f"['{old}']", key]


def test_production_starts_without_an_agent_token_in_the_environment(tmp_path):
    # Each robot's token may be stored by the portal (manage.py agent_token) instead.
    env = {k: v for k, v in PRODUCTION.items() if k != "AGENT_TOKEN"}
    result = _start(env, tmp_path)
    assert result.returncode == 0, result.stderr


def test_an_unreadable_secret_file_is_a_clear_error(tmp_path):
    env = dict(PRODUCTION, AGENT_TOKEN="")
    env["AGENT_TOKEN_FILE"] = str(tmp_path / "nope")
    result = _start(env, tmp_path)
    assert result.returncode != 0
    assert "AGENT_TOKEN_FILE" in result.stderr


def test_the_readme_documents_every_setting():
    sources = [REPO / "portal" / "settings.py", REPO / "portal" / "launcher.py"]
    sources += sorted((REPO / "basestation").glob("*.py"))
    sources += sorted((REPO / "amazing_cli").rglob("*.py"))
    names: set[str] = set()
    for source in sources:
        text = source.read_text()
        names |= set(re.findall(r'env\.\w+\(\s*"([A-Z][A-Z0-9_]+)"', text))
        names |= set(re.findall(r'env_secret\(\s*"([A-Z][A-Z0-9_]+)"', text))
        names |= set(re.findall(r'_throttle_rate\(\s*"([A-Z][A-Z0-9_]+)"', text))
        names |= set(re.findall(r'environ\.get\(\s*"([A-Z][A-Z0-9_]+)"', text))
        names |= set(re.findall(r'env\.setdefault\(\s*"([A-Z][A-Z0-9_]+)"', text))
        # The agent's variables: AGENT_ + the name its config reader is given.
        names |= {"AGENT_" + n for n in re.findall(r"\{ENV_PREFIX\}([A-Z][A-Z0-9_]+)", text)}
        names |= {"AGENT_" + n for n in re.findall(r'_float_env\(env, "([A-Z][A-Z0-9_]+)"', text)}
    assert len(names) > 10
    readme = (REPO / "README.md").read_text()
    undocumented = sorted(n for n in names if f"`{n}`" not in readme)
    assert not undocumented, f"README.md does not document {undocumented}"


def test_check_deploy_is_clean_in_production_behind_a_tls_proxy(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith(_NOT_INHERITED)}
    env.update(PRODUCTION, AMAZING_VAR_DIR=str(tmp_path))
    env["DJANGO_SECRET_KEY"] = secrets.token_urlsafe(50)
    # The operator's one decision left: asking browsers to preload HSTS for the domain.
    env["DJANGO_HSTS_PRELOAD"] = "1"
    result = subprocess.run(
        [sys.executable, "manage.py", "check", "--deploy", "--fail-level", "WARNING"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    assert "no issues" in result.stdout


def test_production_sends_plain_http_to_https_but_for_the_health_check(tmp_path):
    script = (
        "import django; django.setup()\n"
        "from django.test import Client\n"
        "c = Client(HTTP_HOST='amazing.example.org')\n"
        "print(c.get('/accounts/login/').status_code, c.get('/accounts/login/').get('Location'))\n"
        "print(c.get('/accounts/login/', headers={'X-Forwarded-Proto': 'https'}).status_code)\n"
        "print(c.get('/healthz').status_code != 301)\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith(_NOT_INHERITED)}
    env.update(PRODUCTION, AMAZING_VAR_DIR=str(tmp_path), DJANGO_SETTINGS_MODULE="portal.settings")
    result = subprocess.run(
        [sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=120,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = result.stdout.split("\n")
    assert lines[0] == "301 https://amazing.example.org/accounts/login/"
    assert lines[1] == "200"
    assert lines[2] == "True"


@pytest.mark.django_db
def test_every_answer_carries_the_security_headers(client):
    for path in ("/accounts/login/", "/api/v1/resources/"):
        response = client.get(path)
        policy = response["Content-Security-Policy"]
        assert "script-src 'self'" in policy
        assert "unsafe-inline" not in policy.split("style-src")[0]
        assert "frame-ancestors 'none'" in policy
        assert "object-src 'none'" in policy
        assert response["X-Frame-Options"] == "DENY"
        assert response["Referrer-Policy"] == "same-origin"
        assert "camera=()" in response["Permissions-Policy"]
        assert response["X-Content-Type-Options"] == "nosniff"


def test_production_limits_sign_ins_and_sessions_last_session_age_s(tmp_path):
    env = {**PRODUCTION, "SESSION_AGE_S": "3600"}
    check = (
        "import django; django.setup(); from django.conf import settings; "
        "from allauth.account import app_settings as a; "
        "print(settings.SESSION_COOKIE_AGE, sorted(a.RATE_LIMITS))"
    )
    clean = {k: v for k, v in os.environ.items() if not k.startswith(_NOT_INHERITED)}
    result = subprocess.run(
        [sys.executable, "-c", check],
        cwd=REPO,
        env={
            **clean,
            "DJANGO_SETTINGS_MODULE": "portal.settings",
            "AMAZING_VAR_DIR": str(tmp_path),
            **env,
        },
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    age, limits = result.stdout.strip().split(" ", 1)
    assert age == "3600"
    for action in ("login", "login_failed", "reset_password"):
        assert f"'{action}'" in limits
