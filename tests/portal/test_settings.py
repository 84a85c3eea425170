"""Settings come from the environment; production refuses to start without its secrets."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CHECK = "import django; django.setup(); print('started')"


def _start(env_changes: dict[str, str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("DJANGO_", "AGENT_", "DATABASE_", "CELERY_", "REDIS_"))
    }
    env.update({"DJANGO_SETTINGS_MODULE": "portal.settings", "AMAZING_VAR_DIR": str(tmp_path)})
    env.update(env_changes)
    return subprocess.run(
        [sys.executable, "-c", CHECK], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )


PRODUCTION = {
    "DJANGO_DEBUG": "0",
    "DJANGO_SECRET_KEY": "x" * 50,
    "DJANGO_ALLOWED_HOSTS": "amazing.example.org",
    "AGENT_TOKEN": "t" * 32,
}


@pytest.mark.parametrize("missing", ["DJANGO_SECRET_KEY", "DJANGO_ALLOWED_HOSTS", "AGENT_TOKEN"])
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


def test_an_unreadable_secret_file_is_a_clear_error(tmp_path):
    env = dict(PRODUCTION, AGENT_TOKEN="")
    env["AGENT_TOKEN_FILE"] = str(tmp_path / "nope")
    result = _start(env, tmp_path)
    assert result.returncode != 0
    assert "AGENT_TOKEN_FILE" in result.stderr


def test_the_readme_documents_every_setting():
    sources = [REPO / "portal" / "settings.py", REPO / "portal" / "launcher.py"]
    sources += sorted((REPO / "basestation").glob("*.py"))
    sources += sorted((REPO / "amazing_cli").glob("*.py"))
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
